"""Export calibrated robot kinematics: the cell-spec table (YAML) and a URDF.

Both read a result's ``kinematics`` section (:class:`~jcalib.io.result.KinematicsResult`); a result
without one is refused, so what was not calibrated is never exported as if it were.

- ``kinematics`` (YAML, ``jcalib.kinematics/1``): per robot the calibrated model as a cell-spec
  ``kinematics:`` table (:func:`jcalib.geometry.kinematic_tables.to_spec` layout; ``from_spec`` of it has
  the FK of the calibrated parameters, so it can be pasted into the cell spec as the new nominal), every
  calibrated parameter with nominal, calibrated value, change and σ (mm / deg), the held parameters with
  the reason, and the controller joint-zero offsets (deg / mm) with their sign convention.
- ``urdf`` (XML): one robot as ``base_link -> link_1 .. link_n -> flange -> tool0``: one link per joint
  frame, revolute/prismatic joints about/along their z axis (``0 0 -1`` where the joint sign is -1),
  ``<origin xyz rpy>`` the joint frame in its parent link frame at zero joints (m, URDF's fixed-axis
  roll-pitch-yaw: ``R = Rz(yaw) Ry(pitch) Rx(roll)``, rad), limits from the model. ``flange`` and
  ``tool0`` are jcalib's flange frame; a URDF parser's FK of ``tool0`` is
  :func:`~jcalib.geometry.kinematic_models.forward` of the calibrated parameters.

Numbers are written with the shortest exact float text, so a reader gets the float64 values back.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry import kinematic_models as km
from jcalib.geometry import kinematic_tables as kt
from jcalib.io.atomic import write_text_atomic
from jcalib.io.export._common import (
    checked_export,
    comment_text,
    exact_float,
    provenance_lines,
)
from jcalib.io.result import KinematicsResult, ResultFile, load_result
from jcalib.io.schema.common import max_reach_m

__all__ = ["CONTROLLER_OFFSET_CONVENTION", "calibrated_model", "kinematics_spec", "kinematics_urdf", "kinematics_yaml",
           "pick_robot", "rpy_from_matrix", "write_kinematics_yaml", "write_urdf"]

KINEMATICS_SCHEMA = "jcalib.kinematics/1"

#: What ``controller_offsets`` mean (:func:`jcalib.geometry.kinematic_models.controller_offsets`).
CONTROLLER_OFFSET_CONVENTION = (
    "offset = joint sign x (calibrated - nominal) of the joint's zero parameter (dh/mdh theta for revolute, d for "
    "prismatic joints; poe rz / tz), in deg (revolute) or mm (prismatic). The calibrated arm at the controller "
    "reading q is the nominal arm at q + offset: shift each joint's zero (mastering / calibration offset) so that "
    "the same physical position reads q + offset, and the controller's nominal model fits again (poe: to first "
    "order when the joint's other parameters moved too). Whether that adds or subtracts offset on a given "
    "controller's zero-offset parameter depends on how it enters the joint value there: check the controller's "
    "manual. Apply the offsets OR paste the calibrated table as the new nominal, never both; the offsets correct "
    "the joint zeros only, not the link lengths or twists.")

_LENGTH_SUFFIXES = ("a", "d", "tx", "ty", "tz")


def _entries(result: ResultFile, fmt: str) -> Mapping[str, KinematicsResult]:
    if not result.kinematics:
        raise BadInputError(
            f"format {fmt!r}: the result has no 'kinematics' section: no robot kinematics was calibrated, so there is "
            "no calibrated model to export. Calibrate it: name kinematics: and calibrate_kinematics: for the robot in "
            "the cell spec and give joints_deg at every station")
    return result.kinematics


def pick_robot(result: ResultFile, robot: str | None, fmt: str) -> str:
    """``robot``, or the result's only robot with calibrated kinematics; :class:`BadInputError` otherwise (and for a
    result without kinematics, naming export format ``fmt``)."""
    entries = _entries(result, fmt)
    if robot is None:
        if len(entries) != 1:
            raise BadInputError(f"robot: the result has calibrated kinematics for {len(entries)} robots "
                                f"({', '.join(entries)}); name the one to export")
        return next(iter(entries))
    if robot not in entries:
        raise BadInputError(f"robot: the result has no calibrated kinematics for {robot!r}; robots with calibrated "
                            f"kinematics: {', '.join(entries)}")
    return robot


def kinematics_spec(k: KinematicsResult, robot: str) -> dict:
    """The calibrated model of ``k`` as a cell-spec ``kinematics:`` table (to_spec layout).

    Taken from the entry's ``spec`` (when the result holds one), else rebuilt from its ``table``
    (dh, mdh: the joint rows and the effective base and flange matrices).

    Raises:
        BadInputError: neither is usable (a poe entry without ``spec``: its table lacks the flange
            pose at zero joints, whose rotation about the last joint axis it does not give).
    """
    where = f"result: kinematics.{robot}"
    spec = k.extra.get("spec")
    if isinstance(spec, Mapping):
        return json.loads(json.dumps(spec))  # a deep, plain copy
    if k.convention == "poe":
        raise BadInputError(
            f"{where}: a poe model's export needs its calibrated table with the flange pose at zero joints "
            "('spec'), which this result does not hold (its 'table' gives the joint axes but not the zero pose); "
            "calibrate again with a jcalib that writes kinematics.<robot>.spec")
    table = k.extra.get("table")
    if not isinstance(table, list) or not all(isinstance(r, Mapping) for r in table):
        raise BadInputError(f"{where}: no 'table' of the calibrated model (a list of joint rows, then base and "
                            "flange); calibrate again to write it")
    joints = [dict(r) for r in table if "matrix" not in r]
    frames = {r.get("name"): r.get("matrix") for r in table if "matrix" in r}
    if set(frames) != {"base", "flange"}:
        raise BadInputError(f"{where}: table: expected the rows 'base' and 'flange' with a 'matrix' after the "
                            f"joints, got {sorted(map(str, frames))}")
    return {"convention": k.convention, "joints": joints, "base": frames["base"], "flange": frames["flange"]}


def calibrated_model(k: KinematicsResult, robot: str) -> km.Kinematics:
    """The :class:`~jcalib.geometry.kinematic_models.Kinematics` whose nominal is the calibration of ``k``.

    Its ``forward(model, model.nominal, q)`` is ``forward`` of the original model at the calibrated
    parameters (``base.*``/``flange.*`` are folded into the base and flange frames, so their nominal is 0).

    Raises:
        BadInputError: as :func:`kinematics_spec`, or an entry whose table does not match its values.
    """
    where = f"result: kinematics.{robot}"
    model = kt.from_spec(kinematics_spec(k, robot), robot, source="result", max_length_m=max_reach_m())
    n_joint = model.num_params - 12
    if model.convention != k.convention or tuple(model.param_names) != tuple(k.names):
        raise BadInputError(f"{where}: its table describes the parameters {list(model.param_names)} "
                            f"({model.convention}), not the entry's {list(k.names)} ({k.convention})")
    if model.convention != "poe":
        bad = np.abs(np.asarray(model.nominal)[:n_joint] - k.values[:n_joint])
        if bad.max(initial=0.0) > 1e-9:
            i = int(np.argmax(bad))
            raise BadInputError(f"{where}: the table's {k.names[i]} differs from the parameter value by "
                                f"{bad[i]:.3g} (m or rad); the entry was edited: calibrate again")
    return model


# ----------------------------------------------------------------------------------------------
# YAML: the cell-spec table with σ, held parameters and controller offsets
# ----------------------------------------------------------------------------------------------


def _unit(name: str) -> tuple[str, float]:
    return ("mm", 1e3) if name.rsplit(".", 1)[-1] in _LENGTH_SUFFIXES else ("deg", 180.0 / math.pi)


def _plain(x: Any) -> Any:
    """``x`` with numpy scalars and arrays as Python floats and lists (what yaml.safe_dump takes)."""
    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_plain(v) for v in (x.tolist() if isinstance(x, np.ndarray) else x)]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(exact_float(x))  # refuses non-finite numbers
    return x


def _block(key: str, value: Any, indent: int, comments: Sequence[str] = (), flow: bool | None = None) -> list[str]:
    """YAML lines of ``{key: value}`` indented by ``indent``, after ``comments``; ``flow`` as PyYAML's
    ``default_flow_style`` (None: innermost collections on one line)."""
    import yaml

    pad = " " * indent
    text = yaml.safe_dump({key: _plain(value)}, sort_keys=False, default_flow_style=flow, width=4096,
                          allow_unicode=True)
    return [f"{pad}# {c}" for c in comments] + [pad + line for line in text.rstrip("\n").split("\n")]


def _parameters(k: KinematicsResult) -> dict[str, dict[str, float]]:
    std = k.std
    index = {n: i for i, n in enumerate(k.names)}
    out = {}
    for name in k.calibrated:
        unit, scale = _unit(name)
        nominal, value = float(k.nominal[index[name]]), float(k.values[index[name]])
        row = {f"nominal_{unit}": nominal * scale, f"calibrated_{unit}": value * scale,
               f"change_{unit}": (value - nominal) * scale}
        if name in std:
            row[f"std_{unit}"] = std[name] * scale
        out[name] = row
    return out


def _offsets(k: KinematicsResult, model: km.Kinematics) -> dict[str, dict[str, Any]]:
    """Joint -> offset (deg / mm) with its σ, or 0 and why where the joint's zero parameter was held."""
    nominal_model = dataclasses.replace(model, nominal=np.asarray(k.nominal, np.float64))
    offsets = km.controller_offsets(nominal_model, k.values)
    zero = km.parameter_groups(model)["joint_offsets"]
    held, std = k.extra.get("held") or {}, k.std
    out = {}
    for joint, name in zip(model.joint_names, zero):
        unit, scale = ("deg", 180.0 / math.pi) if name.endswith((".theta", ".rz")) else ("mm", 1e3)
        row: dict[str, Any] = {f"offset_{unit}": offsets[joint]}
        if name in std:
            row[f"std_{unit}"] = std[name] * scale
        elif name not in k.calibrated:
            row["held"] = str(held.get(name, "not calibrated (held at its nominal value)"))
        out[joint] = row
    return out


_COMMENTS = {
    "kinematics": "the calibrated model: paste it as this robot's kinematics: in the cell spec (the new nominal)",
    "parameters": ("every calibrated parameter: nominal, calibrated, change = calibrated - nominal, std = 1 σ "
                   "(sampling noise of the measurements, not model error); mm or deg"),
    "held": "requested parameters the data cannot separate from other unknowns, held at their nominal value, and why",
    "controller_offsets": "per joint, the controller joint-zero (mastering) correction, deg or mm:",
    "fit": ("flange corrections per station the kinematics does not explain (RMS per flange axis), against the stated "
            "repeatability; held-out prediction error (calibrated and nominal model) where computed"),
}


def _robot_yaml(robot: str, k: KinematicsResult) -> list[str]:
    model = calibrated_model(k, robot)
    held = {str(n): str(why) for n, why in (k.extra.get("held") or {}).items()}
    lines = [f"  {json.dumps(robot, ensure_ascii=False)}:"]
    lines += _block("kinematics", kinematics_spec(k, robot), 4, [_COMMENTS["kinematics"]])
    lines += _block("parameters", _parameters(k), 4, [_COMMENTS["parameters"]])
    lines += _block("held", held, 4, [_COMMENTS["held"]], flow=False)
    lines += _block("controller_offsets", _offsets(k, model), 4,
                    [_COMMENTS["controller_offsets"], *_wrap(CONTROLLER_OFFSET_CONVENTION)])
    fit = {key: k.extra[key] for key in ("correction_rms_translation_m", "correction_rms_rotation_deg", "repeatability",
                                         "heldout") if key in k.extra}
    if fit:
        lines += _block("fit", fit, 4, [_COMMENTS["fit"]])
    return lines


def _wrap(text: str, width: int = 110) -> list[str]:
    import textwrap

    return textwrap.wrap(text, width)


def kinematics_yaml(result: ResultFile, robots: str | Sequence[str] | None = None) -> str:
    """The ``jcalib.kinematics/1`` YAML text of the calibrated kinematics (module docstring).

    Args:
        result: the calibration result.
        robots: one robot, a list, or None (every robot with calibrated kinematics).

    Raises:
        BadInputError: no kinematics in the result, an unknown robot, or an unusable entry.
    """
    entries = _entries(result, "kinematics")
    names = list(entries) if robots is None else [pick_robot(result, r, "kinematics") for r in
                                                   ([robots] if isinstance(robots, str) else robots)]
    lines = [f"# {c}" for c in ["jcalib calibrated robot kinematics", *provenance_lines(result)]]
    lines += [f"schema: {KINEMATICS_SCHEMA}", "robots:"]
    for robot in names:
        lines += _robot_yaml(robot, entries[robot])
    return checked_export("\n".join(lines) + "\n", "kinematics")


# ----------------------------------------------------------------------------------------------
# URDF
# ----------------------------------------------------------------------------------------------


def rpy_from_matrix(R: np.ndarray) -> tuple[float, float, float]:
    """URDF ``(roll, pitch, yaw)`` (rad) of a rotation ``R (3, 3)``: ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

    Exact to rounding at and near pitch = ±90 deg (where only roll - yaw or roll + yaw is determined:
    yaw is taken from the first column, then roll from what remains, so an imprecise yaw is absorbed).
    """
    R = np.asarray(R, np.float64)
    c = math.hypot(R[0, 0], R[1, 0])
    pitch = math.atan2(-R[2, 0], c)
    yaw = math.atan2(R[1, 0], R[0, 0])  # any yaw at pitch = ±90 deg: roll takes up the rest
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rx = Ry.T @ Rz.T @ R
    roll = math.atan2(Rx[2, 1], Rx[1, 1])
    return roll + 0.0, pitch + 0.0, yaw + 0.0


def _numbers(values) -> str:
    return " ".join(exact_float(v) for v in values)


def _origin(T: np.ndarray) -> dict[str, str]:
    return {"xyz": _numbers(T[:3, 3]), "rpy": _numbers(rpy_from_matrix(T[:3, :3]))}


def _xml_comment(text: str) -> ET.Element:
    text = comment_text(text).replace("--", "- -")
    return ET.Comment(f" {text} ")


def _inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def _joint(root: ET.Element, name: str, kind: str, parent: str, child: str, T: np.ndarray) -> ET.Element:
    joint = ET.SubElement(root, "joint", {"name": name, "type": kind})
    ET.SubElement(joint, "parent", {"link": parent})
    ET.SubElement(joint, "child", {"link": child})
    ET.SubElement(joint, "origin", _origin(T))
    return joint


_URDF_FRAMES = ("Joint origins: the joint frame in its parent link frame at zero joints (m; rpy = fixed-axis roll, "
                "pitch, yaw, rad); joints turn about / slide along their z axis (-z where the joint sign is -1). Joint "
                "values: rad (revolute), m (prismatic).")
_URDF_FLANGE = ("flange and tool0: jcalib's flange frame (T_base_flange of the calibration). effort and velocity "
                "are not known to jcalib (written as 0): take them from the manufacturer's description.")


def kinematics_urdf(result: ResultFile, robot: str | None = None) -> str:
    """A URDF (XML text) of one robot's calibrated kinematics (module docstring).

    Joint limits come from the model (rad, m); URDF's ``effort`` and ``velocity`` are not known to jcalib
    and are written as 0: take them from the manufacturer's description.

    Args:
        result: the calibration result.
        robot: the robot; None = the result's only robot with calibrated kinematics.

    Raises:
        BadInputError: no kinematics in the result, an unknown or ambiguous robot, or an unusable entry.
    """
    import jax.numpy as jnp

    robot = pick_robot(result, robot, "urdf")
    k = result.kinematics[robot]
    model = calibrated_model(k, robot)
    n = model.num_joints
    frames = np.asarray(km.joint_frames(model, model.nominal), np.float64)
    home = np.asarray(km.forward(model, model.nominal, jnp.zeros(n, dtype=jnp.float64)), np.float64)
    sign = np.asarray(model.joint_sign)
    lower, upper = np.asarray(model.lower), np.asarray(model.upper)

    root = ET.Element("robot", {"name": robot})
    title = (f"jcalib calibrated kinematics of robot '{robot}' ({k.convention}), {len(k.calibrated)} parameters "
             "calibrated")
    for line in [title, *provenance_lines(result), _URDF_FRAMES, _URDF_FLANGE]:
        root.append(_xml_comment(line))
    links = ["base_link", *(f"link_{i + 1}" for i in range(n)), "flange", "tool0"]
    for link in links:
        ET.SubElement(root, "link", {"name": link})
    previous = np.eye(4)
    for i, (joint, kind) in enumerate(zip(model.joint_names, model.joint_types)):
        el = _joint(root, joint, kind, links[i], links[i + 1], _inv(previous) @ frames[i])
        ET.SubElement(el, "axis", {"xyz": f"0 0 {int(sign[i])}"})
        ET.SubElement(el, "limit", {"lower": exact_float(lower[i]), "upper": exact_float(upper[i]),
                                    "effort": "0", "velocity": "0"})
        previous = frames[i]
    _joint(root, f"{links[n]}-flange", "fixed", links[n], "flange", _inv(previous) @ home)
    _joint(root, "flange-tool0", "fixed", "flange", "tool0", np.eye(4))
    ET.indent(root, "  ")
    text = '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
    return checked_export(text, "urdf")


def write_kinematics_yaml(result: ResultFile | str | os.PathLike, path: str | os.PathLike,
                          robots: str | Sequence[str] | None = None) -> Path:
    """Write :func:`kinematics_yaml` of ``result`` (a :class:`ResultFile` or a path) atomically."""
    return write_text_atomic(path, kinematics_yaml(load_result(result), robots))


def write_urdf(result: ResultFile | str | os.PathLike, path: str | os.PathLike, robot: str | None = None) -> Path:
    """Write :func:`kinematics_urdf` of ``result`` (a :class:`ResultFile` or a path) atomically."""
    return write_text_atomic(path, kinematics_urdf(load_result(result), robot))
