"""ROS-Industrial ``industrial_calibration`` kinematic-calibration data sets -> capture session.

Layout (the tool's kinematic calibration example: ``KinematicCalibrationProblemPose6D``, a 6-DOF pose
sensor observing a target, one of them on a DH chain)::

    measurements.yaml            a mapping, one entry per observation:
                                   <key>: {target_joints: [...], camera_joints: [...],
                                           pose: {x, y, z, qw, qx, qy, qz}}
    pose_initial_guesses.yaml    optional: camera_mount_to_camera_guess, target_mount_to_target_guess (recorded only)

Conventions assumed (those of the tool's problem):

- ``pose`` is ``camera_to_target``: the target's pose in the sensor frame, metres, Hamilton quaternion by
  named fields. It becomes a station's 6-DOF measurement ``{sensor, target, T_sensor_target}``; the sensor is
  a pose sensor of the cell (``sensors:``, no lens, no image size).
- Joint values are the chain's own (radians; metres for prismatic joints), written as the session's
  ``joints_deg`` (degrees; mm) through the nominal kinematics' joint types.
- Exactly one chain moves: ``target_joints`` (the target on a positioner or arm, the sensor fixed:
  ``mount: base`` sensor, ``mount: flange`` target) or ``camera_joints`` (the sensor on the chain, the target
  fixed). Two moving chains are refused (a cell of two robots; this importer writes one).
- The nominal kinematics are not in the data set (the tool builds its DH chains in code): option
  ``kinematics=<preset>`` or ``kinematics=FILE`` (YAML / JSON: a cell-spec ``kinematics:`` table, or a
  mapping holding one under ``kinematics``), required. The cell calibrates ``calibrate`` (default
  ``joint_offsets,link_lengths,twists``; jcalib holds what the data cannot separate and says why).
- Stations carry joints only: their flange poses are the kinematics at the joints, unknowns tied to it
  by the robot's repeatability (``repeatability_mm`` / ``repeatability_deg``, default jcalib's).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.importers.common import ImportedStation, check_options, natural_key, pose_from_xyz_quat, write_session
from jcalib.io.importers.source import ALLOW_OUTSIDE_HELP, SourceFolder, flag_option

FORMAT = "industrial-calibration"
FILENAME = "measurements.yaml"
OPTIONS = {
    "kinematics": "the chain's nominal kinematics: a preset name or a FILE with a cell-spec kinematics table "
                  "(required)",
    "calibrate": "kinematic parameters or groups to estimate, comma separated (default "
                 "joint_offsets,link_lengths,twists)",
    "repeatability_mm": "the chain's repeatability per axis, mm (the cell's pose_noise; default jcalib's)",
    "repeatability_deg": "the chain's repeatability per axis, degrees (with repeatability_mm)",
    "sensor": "sensor id in the session (default camera)",
    "target": "target id in the session (default target)",
    "allow_outside": ALLOW_OUTSIDE_HELP,
}
_POSE_KEYS = ("x", "y", "z", "qw", "qx", "qy", "qz")


def is_kinematic_source(source: str | os.PathLike) -> bool:
    """Whether ``source`` is a kinematic data set: a ``measurements.yaml``, or a folder holding one and no
    ``cal_data.yaml``."""
    p = Path(source)
    if p.is_dir():
        return (p / FILENAME).is_file() and not (p / "cal_data.yaml").exists()
    return p.name == FILENAME


def _kinematics(value: Any) -> tuple[Any, str]:
    """``(cell-spec kinematics entry, what it was)`` of the ``kinematics`` option."""
    from jcalib.geometry import kinematic_models

    if value is None:
        raise BadInputError(f"import {FORMAT}: {FILENAME} holds no robot model (industrial_calibration builds its DH "
                            "chains in code): give the nominal kinematics with --option kinematics=<preset> (one of "
                            f"{', '.join(kinematic_models.PRESETS)}) or --option kinematics=FILE (a DH table in the "
                            "cell-spec form)")
    text = str(value)
    if text in kinematic_models.PRESETS:
        return text, f"preset {text}"
    path = Path(text)
    if not path.is_file():
        raise BadInputError(f"import {FORMAT}: --option kinematics={text[:80]!r}: not a kinematics preset "
                            f"({', '.join(kinematic_models.PRESETS)}) and not a file")
    from jcalib.io.schema.reading import read_document

    doc = read_document(path, "kinematics table", fmt="json" if path.suffix == ".json" else "yaml")
    if isinstance(doc, dict) and "kinematics" in doc and "joints" not in doc:
        doc = doc["kinematics"]
    if not isinstance(doc, (dict, str)):
        raise BadInputError(f"{path}: expected a cell-spec kinematics table ({{convention, joints: [...], base, "
                            "flange}}) or a preset name")
    return doc, str(path)


def _joints(value: Any, where: str) -> list[float]:
    if value is None:
        return []
    if not isinstance(value, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                              and math.isfinite(v) for v in value):
        raise BadInputError(f"{where}: expected a list of finite joint values (rad; m for prismatic joints)")
    return [float(v) for v in value]


def _pose(entry: Any, where: str) -> np.ndarray:
    if not isinstance(entry, dict) or any(k not in entry for k in _POSE_KEYS):
        missing = "" if not isinstance(entry, dict) else f"; missing {', '.join(k for k in _POSE_KEYS if k not in entry)}"
        raise BadInputError(f"{where}: expected the sensor-to-target pose {{x, y, z, qw, qx, qy, qz}} (m){missing}")
    return pose_from_xyz_quat([entry["x"], entry["y"], entry["z"]], [entry[k] for k in ("qx", "qy", "qz", "qw")],
                              where)


def import_source(source: str | os.PathLike, out: str | os.PathLike, *, mount: str | None = None,
                  **options: Any):
    """Import an industrial_calibration kinematic data set (``measurements.yaml`` or its folder) into ``out``.

    Args:
        mount: where the sensor is, when given: must agree with the chain that moves (``base``: the target
            moves; ``flange``: the sensor moves).
        options: see ``OPTIONS``.
    Returns:
        :class:`jcalib.io.importers.common.ImportSummary`.
    Raises:
        BadInputError: a missing option, a malformed observation (naming its key), joint counts that do not
            match the kinematics, no or two moving chains.
    """
    from jcalib.geometry import kinematic_models, kinematic_tables
    from jcalib.io.schema.common import max_reach_m

    check_options(FORMAT, options, OPTIONS)
    path = Path(source) / FILENAME if Path(source).is_dir() else Path(source)
    root = path.parent
    folder = SourceFolder(root, FORMAT, flag_option(options, "allow_outside", FORMAT))
    doc = folder.read_yaml(path, f"import {FORMAT}: measurements")
    if not isinstance(doc, dict) or not doc:
        raise BadInputError(f"{path}: expected a mapping of observations {{<key>: {{target_joints: [...], "
                            "camera_joints: [...], pose: {x, y, z, qw, qx, qy, qz}}}}}")
    spec, what = _kinematics(options.get("kinematics"))
    model = kinematic_tables.from_spec(spec, "robot", source=f"--option kinematics ({what})", max_length_m=max_reach_m())
    sensor, target = str(options.get("sensor", "camera")), str(options.get("target", "target"))
    keys = sorted(doc, key=lambda k: natural_key(str(k)))
    moving = set()
    stations = []
    for i, key in enumerate(keys):
        entry, where = doc[key], f"{path}: {str(key)[:40]}"
        if not isinstance(entry, dict):
            raise BadInputError(f"{where}: expected {{target_joints, camera_joints, pose}}")
        tj = _joints(entry.get("target_joints"), f"{where}.target_joints")
        cj = _joints(entry.get("camera_joints"), f"{where}.camera_joints")
        moving |= {"target"} if tj else set()
        moving |= {"camera"} if cj else set()
        q = tj or cj
        if len(q) != model.num_joints:
            raise BadInputError(f"{where}: {len(q)} joint values, but the kinematics ({what}) has {model.num_joints} "
                                f"joints ({', '.join(model.joint_names)})")
        joints_deg = np.asarray(kinematic_models.joints_to_controller(model, np.asarray(q, np.float64))).tolist()
        stations.append(ImportedStation(id=f"s{i:03d}", T_base_flange=None, joints_deg=joints_deg,
                                        poses=[{"camera": sensor, "target": target,
                                                "T_cam_target": _pose(entry.get("pose"), f"{where}.pose")}],
                                        source={"key": str(key)[:64]}))
    if len(moving) != 1:
        raise BadInputError(f"{path}: {'both the target and the camera chain move' if moving else 'no chain moves'}; "
                            "this importer takes data sets where exactly one chain (target_joints or camera_joints) "
                            "has joints")
    sensor_mount = "base" if moving == {"target"} else "flange"
    if mount is not None and mount != sensor_mount:
        raise BadInputError(f"{path}: the {'target' if sensor_mount == 'base' else 'camera'} chain moves, so the sensor "
                            f"is on the {sensor_mount}, but --mount {str(mount)[:40]} was given")
    which = [s.strip() for s in str(options.get("calibrate", "joint_offsets,link_lengths,twists")).split(",") if s.strip()]
    robot: dict[str, Any] = {"kinematics": spec, "calibrate_kinematics": which}
    if "repeatability_mm" in options or "repeatability_deg" in options:
        try:
            t, r = float(options["repeatability_mm"]) / 1e3, float(options["repeatability_deg"])
        except (KeyError, TypeError, ValueError):
            raise BadInputError(f"import {FORMAT}: give both repeatability_mm and repeatability_deg as positive "
                                "numbers") from None
        if not (t > 0 and r > 0 and math.isfinite(t) and math.isfinite(r)):
            raise BadInputError(f"import {FORMAT}: repeatability_mm and repeatability_deg must be positive")
        robot["pose_noise"] = {"translation_m": t, "rotation_deg": r}
    cell = {"schema": "jcalib.cell/1",
            "sensors": {sensor: {"kind": "pose", "mount": sensor_mount}},
            "targets": {target: {"type": "points", "mount": "flange" if sensor_mount == "base" else "base"}},
            "robot": robot}
    extra: dict[str, Any] = {"kinematics": what}
    guesses = root / "pose_initial_guesses.yaml"
    if guesses.is_file():
        extra["guesses"] = folder.read_yaml(guesses, f"import {FORMAT}: pose guesses")
    notes = (f"nominal kinematics: {what}; stations carry joints only (their flange poses are the kinematics at "
             "the joints, unknowns within the repeatability)",
             f"the sensor is the cell's pose sensor {sensor!r} (no lens, no image size); the 6-DOF poses are "
             "T_sensor_target; jcalib calibrate solves them directly (no detect step)")
    return write_session(out, cell, stations, fmt=FORMAT, source=path, conventions=(
        "pose = camera_to_target = T_sensor_target (m, quaternion qw qx qy qz); joints rad / m -> joints_deg "
        "deg / mm"), extra=json.loads(json.dumps(extra, default=str)), notes=notes)
