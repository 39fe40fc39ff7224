"""A cell spec and observations checked against each other, before any solve.

Observations name cameras, targets, tools and points; a name the cell does not define would
otherwise be dropped without a word (the issue's "silent wrong answers"): every such detection,
contact and pose measurement is refused here, naming the station and offering the closest name.
A target's observed points must match the cell's grid in number (indices would mean other corners);
points that differ from the cell's nominal geometry (a measured board, or a cell edited after
detection) give an :class:`~jcalib.errors.InputWarning`.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from jcalib.errors import InputWarning
from jcalib.io.schema.base import SchemaError, did_you_mean
from jcalib.io.schema.common import norm

__all__ = ["GEOMETRY_TOLERANCE_M", "check_cell_observations"]

#: Observed target points farther than this (m) from the cell's nominal geometry give a warning.
GEOMETRY_TOLERANCE_M = 1e-6


def _unknown(kind: str, name: str, known: dict, cell_source: str) -> str:
    return (f"{kind} {name!r} is not in the cell spec {cell_source}{did_you_mean(name, known)} "
            f"(its {kind}s: {', '.join(known) or 'none'}); add it to the cell or remove these observations")


def _check_target_points(cell: Any, obs: Any, problems: list) -> None:
    for name, points in obs.targets.items():
        spec = cell.targets.get(name)
        if spec is None or spec.type == "points":
            continue
        try:
            nominal = np.asarray(spec.geometry().points, dtype=np.float64)
        except Exception:  # noqa: BLE001 - the cell's own loader reports a bad geometry
            continue
        observed = np.asarray(points, dtype=np.float64)
        if observed.shape != nominal.shape:
            problems.append((f"targets.{name}.points", f"{observed.shape[0]} points, but the cell's {spec.type} target "
                                                       f"{name!r} has {nominal.shape[0]}: the observations were detected "
                                                       "with another target geometry; detect again with this cell"))
            continue
        dev = float(np.max(norm(observed - nominal, axis=1))) if len(nominal) else 0.0
        if dev > GEOMETRY_TOLERANCE_M:
            warnings.warn(
                f"{obs.source}: targets.{name}.points differ from the cell's {spec.type} geometry by up to "
                f"{dev * 1e3:.3g} mm; the calibration uses the observed points (check the cell's target sizes)",
                InputWarning, stacklevel=3)


def check_cell_observations(cell: Any, obs: Any) -> None:
    """Refuse observations that name what the cell does not define.

    Args:
        cell: a :class:`jcalib.io.cell.CellSpec`.
        obs: a :class:`jcalib.io.observations.Observations`.

    Raises:
        SchemaError: naming the observations file, the station and the unknown name.

    Warns:
        InputWarning: observed target points that differ from the cell's nominal geometry.
    """
    problems: list[tuple[str, str]] = []
    src = cell.source
    for st in obs.stations:
        where = f"station {st.id!r}"
        for j, det in enumerate(st.detections):
            at = f"{where}.detections[{j}]"
            if det.camera in getattr(cell, "sensors", {}):
                problems.append((f"{at}.camera", f"{det.camera!r} is a pose sensor of the cell (sensors:), which has no "
                                                 "images: it gives poses ([{sensor, target, T_sensor_target}]), not "
                                                 "detections; list it under cameras: if it is a camera"))
            elif det.camera not in cell.cameras:
                problems.append((f"{at}.camera", _unknown("camera", det.camera, cell.cameras, src)))
            if det.target is not None and det.target not in cell.targets:
                problems.append((f"{at}.target", _unknown("target", det.target, cell.targets, src)))
            if det.tool is not None and det.tool not in cell.tools:
                problems.append((f"{at}.tool", _unknown("tool", det.tool, cell.tools, src)))
        for j, c in enumerate(st.contacts):
            if c.tool not in cell.tools:
                problems.append((f"{where}.contacts[{j}].tool", _unknown("tool", c.tool, cell.tools, src)))
            if c.point not in cell.points:
                problems.append((f"{where}.contacts[{j}].point", _unknown("point", c.point, cell.points, src)))
        for j, pm in enumerate(getattr(st, "poses", ()) or ()):
            if isinstance(pm, dict):
                sensor = "sensor" in pm
                cam, tgt = pm.get("sensor" if sensor else "camera"), pm.get("target")
            else:
                sensor, cam, tgt = getattr(pm, "sensor_form", False), pm.camera, pm.target
            sensors = getattr(cell, "sensors", {})
            if cam in sensors and sensors[cam].kind != "pose":
                problems.append((f"{where}.poses[{j}].sensor", f"sensor {cam!r} is of kind {sensors[cam].kind}: it "
                                 "measures positions ([{sensor, tool, p_sensor_tool}]), not poses"))
                continue
            measuring = {**cell.cameras, **sensors}  # either form may name either
            if cam not in measuring:
                kind = "sensor" if sensor else "camera"
                problems.append((f"{where}.poses[{j}].{kind}", _unknown(kind, cam, measuring, src).replace(
                    f"its {kind}s:", "its cameras and sensors:")))
            if tgt not in cell.targets:
                problems.append((f"{where}.poses[{j}].target", _unknown("target", tgt, cell.targets, src)))
        for j, m in enumerate(getattr(st, "positions", ()) or ()):
            sensors = {n: s for n, s in getattr(cell, "sensors", {}).items() if s.kind == "point"}
            if m.sensor not in sensors:
                problems.append((f"{where}.positions[{j}].sensor", _unknown("point sensor", m.sensor, sensors, src)))
            if m.tool not in cell.tools:
                problems.append((f"{where}.positions[{j}].tool", _unknown("tool", m.tool, cell.tools, src)))
        if len(problems) >= 20:
            break
    _check_target_points(cell, obs, problems)
    if problems:
        raise SchemaError(obs.source, problems)
