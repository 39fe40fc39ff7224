"""Calibrated robot kinematics in the report: per robot every calibrated parameter (nominal, calibrated,
change, σ in mm / deg), the held parameters with the reason, the controller joint-zero offsets, and what the
kinematics does not explain (the stations' flange corrections, the held-out prediction error).

Everything comes from the result file's ``kinematics`` section
(:class:`~jcalib.io.result.KinematicsResult`); :func:`parameter_rows` and :func:`fit_lines` feed both the
console table (:func:`jcalib.report.console.kinematics_table`) and the HTML section (:func:`section`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from jcalib.io.export.kinematics import CONTROLLER_OFFSET_CONVENTION
from jcalib.io.result import KinematicsResult, ResultFile
from jcalib.report.markup import esc, note, table

__all__ = ["OffsetRow", "ParameterRow", "fit_lines", "offset_rows", "parameter_rows", "section"]

_LENGTH_SUFFIXES = ("a", "d", "tx", "ty", "tz")
_ZERO_PARAMETER = {("revolute", "poe"): "rz", ("prismatic", "poe"): "tz", ("revolute", "dh"): "theta",
                   ("prismatic", "dh"): "d", ("revolute", "mdh"): "theta", ("prismatic", "mdh"): "d"}


@dataclass(frozen=True)
class ParameterRow:
    """One calibrated parameter in display units (``unit``: mm or deg); ``std`` None without a covariance."""

    name: str
    unit: str
    nominal: float
    calibrated: float
    change: float
    std: float | None


@dataclass(frozen=True)
class OffsetRow:
    """One joint's controller zero offset (``unit``: deg or mm); ``held``: why its zero was not calibrated."""

    joint: str
    unit: str
    offset: float
    std: float | None
    held: str | None


def _unit(name: str) -> tuple[str, float]:
    return ("mm", 1e3) if name.rsplit(".", 1)[-1] in _LENGTH_SUFFIXES else ("deg", 180.0 / math.pi)


def parameter_rows(k: KinematicsResult) -> list[ParameterRow]:
    """The calibrated parameters of ``k`` in the order of ``k.calibrated``, in mm / deg."""
    index = {n: i for i, n in enumerate(k.names)}
    std = k.std
    rows = []
    for name in k.calibrated:
        unit, scale = _unit(name)
        nominal, value = float(k.nominal[index[name]]), float(k.values[index[name]])
        rows.append(ParameterRow(name, unit, nominal * scale, value * scale, (value - nominal) * scale,
                                 std[name] * scale if name in std else None))
    return rows


def offset_rows(k: KinematicsResult) -> list[OffsetRow]:
    """Per joint of ``k.extra["controller_offsets"]`` (deg / mm): the offset, its σ or why it is held."""
    offsets = k.extra.get("controller_offsets") or {}
    types = {r.get("name"): r.get("type", "revolute") for r in k.extra.get("table") or [] if isinstance(r, Mapping)}
    held, std = k.extra.get("held") or {}, k.std
    rows = []
    for joint, value in offsets.items():
        kind = types.get(joint, "revolute")
        name = f"{joint}.{_ZERO_PARAMETER.get((kind, k.convention), 'theta')}"
        unit, scale = ("deg", 180.0 / math.pi) if kind == "revolute" else ("mm", 1e3)
        why = None
        if name not in k.calibrated:
            why = str(held.get(name, "not calibrated (held at its nominal value)"))
        rows.append(OffsetRow(str(joint), unit, float(value), std[name] * scale if name in std else None, why))
    return rows


def _triple(values, scale: float, digits: str) -> str:
    return " ".join(format(float(v) * scale, digits) for v in values)


def _repeatability(rep) -> str:
    """The stated repeatability: numbers where the result holds them, else where it came from."""
    if isinstance(rep, Mapping) and "translation_m" in rep and "rotation_deg" in rep:
        t, r = rep["translation_m"], rep["rotation_deg"]
        t = t if isinstance(t, (list, tuple)) else [t]
        r = r if isinstance(r, (list, tuple)) else [r]
        source = f" ({rep['source']})" if rep.get("source") else ""
        return f"{_triple(t, 1e3, '.4f')} mm, {_triple(r, 1.0, '.5f')} deg{source}"
    if rep == "pose_noise":
        return "the cell's robot pose_noise"
    return "not recorded" if rep is None else str(rep)


def fit_lines(k: KinematicsResult) -> list[str]:
    """Plain-text lines: the stations' flange corrections against the repeatability, and the held-out error."""
    lines = []
    t, r = k.extra.get("correction_rms_translation_m"), k.extra.get("correction_rms_rotation_deg")
    if t is not None and r is not None:
        lines.append(f"flange correction RMS per station (what the kinematics does not explain): translation x y z "
                     f"{_triple(t, 1e3, '.4f')} mm, rotation x y z {_triple(r, 1.0, '.5f')} deg; stated "
                     f"repeatability: {_repeatability(k.extra.get('repeatability'))}")
    held = k.extra.get("heldout")
    if isinstance(held, Mapping) and isinstance(held.get("calibrated"), Mapping):
        c, n = held["calibrated"], held.get("nominal") or {}

        def err(d: Mapping) -> str:
            v = {key: d.get(key, float("nan")) for key in ("position_median_mm", "position_p95_mm",
                                                          "rotation_median_deg", "rotation_p95_deg")}
            return (f"position median {v['position_median_mm']:.4f} mm (p95 {v['position_p95_mm']:.4f}), rotation "
                    f"median {v['rotation_median_deg']:.5f} deg (p95 {v['rotation_p95_deg']:.5f})")

        lines.append(f"held-out prediction error ({held.get('stations', '?')} stations, {held.get('folds', '?')} "
                     f"folds): calibrated {err(c)}" + (f"; nominal {err(n)}" if n else ""))
    return lines


def _std(x: float | None) -> str:
    return "–" if x is None else f"{x:.3g}"


def _robot(robot: str, k: KinematicsResult) -> str:
    out = [(f"<h4>Robot <code>{esc(robot)}</code> ({esc(k.convention)}): {len(k.calibrated)} parameter(s) "
           "calibrated</h4>")]
    rows = [[f"<code>{esc(p.name)}</code>", esc(f"{p.nominal:.5f}"), esc(f"{p.calibrated:.5f}"),
             esc(f"{p.change:+.4g}"), esc(_std(p.std)), esc(p.unit)] for p in parameter_rows(k)]
    out.append(table(["parameter", "nominal", "calibrated", "change", "σ", "unit"], rows, {1, 2, 3, 4})
               if rows else note("No parameter could be calibrated: every requested one is held (below)."))
    held = k.extra.get("held") or {}
    if held:
        out.append(table(["held parameter", "why (held at its nominal value)"],
                         [[f"<code>{esc(n)}</code>", esc(why)] for n, why in held.items()]))
    offsets = offset_rows(k)
    if offsets:
        out.append(table(["joint", "controller zero offset", "σ", "unit"],
                         [[f"<code>{esc(o.joint)}</code>", "–" if o.held is not None else esc(f"{o.offset:+.5f}"),
                           esc(_std(o.std)) if o.held is None else esc(f"held: {o.held}"), esc(o.unit)]
                          for o in offsets], {1}))
        out.append(note("<b>Controller offsets</b>: " + esc(CONTROLLER_OFFSET_CONVENTION)))
    out += [note(esc(line)) for line in fit_lines(k)]
    return "".join(out)


def section(file: ResultFile) -> str:
    """The "Robot kinematics" section (HTML): one block per robot whose kinematics was calibrated."""
    if not file.kinematics:
        return ""
    return ("<h3>Robot kinematics</h3>"
            + note("The calibrated kinematic parameters: change = calibrated − nominal; σ is the sampling noise of "
                   "the measurements propagated to the parameters, not model error. Requested parameters the data "
                   "cannot separate from other unknowns are held at their nominal value. <code>jcalib export -f "
                   "kinematics</code> writes the calibrated model as a cell-spec table, <code>-f urdf</code> as a "
                   "URDF.")
            + "".join(_robot(robot, k) for robot, k in file.kinematics.items()))
