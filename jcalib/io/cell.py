"""The cell spec (``cell.yaml``, schema ``jcalib.cell/1``): what is in the cell and what is unknown.

See docs/design.md, "File formats and entry points". Loading validates everything a later stage relies
on and raises :class:`~jcalib.errors.BadInputError` naming the file, the key and what to do.

Robots: a cell has no robot, one robot (``robot: {...}``, as always) or named robots
(``robots: {r1: {...}, r2: {...}}``, each with the keys of ``robot:`` plus an optional known base
pose ``base: [[4x4]]`` = ``T_world_<robot>``, m). ``robot:`` and ``robots:`` are mutually exclusive.

- One robot (``robot:``, or ``robots:`` with one entry): the cell's frame is the robot ``base``
  exactly as before (``mount: base``, names ``T_base_<x>``, ``T_flange_<x>``); a one-entry
  ``robots:`` only names the robot (flange entries may say ``robot: <name>``; it is the default),
  so ``mount: world`` and ``base:`` are refused there (a one-robot cell is solved in its base frame).
- Several robots: the cell's frame is ``world``. Fixed cameras / targets use ``mount: world``
  (``mount: base`` is refused: whose base?), flange cameras / targets and tools name their robot
  with ``robot: <name>`` (required), cell points are in the world frame. Robot names must differ
  from the camera, target, tool and point names and from ``world``, ``base``, ``flange``.

Sensors (``sensors: {tracker: {kind: pose, mount: base}}``): measuring sensors with no lens (a laser
tracker, a metrology or motion-capture system) whose stations' ``poses`` give 6-DOF target poses. They are
mounted as cameras are (``base`` / ``world`` / ``flange`` with ``robot:``), and have no model and no image size.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.assumptions import assumptions_to_dict, parse_assumptions
from jcalib.io.goals import Goal, parse_goals
from jcalib.io.schema.cell import validate_cell_document
from jcalib.io.schema.reading import read_document
from jcalib.io.target_files import expand_target_files

SCHEMA = "jcalib.cell/1"
CAMERA_MODELS = ("pinhole", "opencv4", "opencv5", "opencv8", "opencv12", "opencv14", "fisheye", "splined")
CAMERA_MOUNTS = ("flange", "base", "world", "free")
TARGET_MOUNTS = ("flange", "base", "world", "free")
#: Names a robot cannot take (frame names).
RESERVED_ROBOT_NAMES = ("world", "base", "flange", "free")
TARGET_TYPES = ("checkerboard", "charuco", "circles", "aprilgrid", "apriltag", "points")


@dataclass(frozen=True)
class CameraSpec:
    """One camera of the cell.

    Attributes:
        name: camera id, e.g. ``"cam0"``.
        model: lens model name (one of ``CAMERA_MODELS``).
        mount: ``"flange"`` (eye-in-hand), ``"base"`` (fixed, one-robot cell), ``"world"`` (fixed,
            several robots) or ``"free"`` (no robot).
        skew: whether the skew coefficient is estimated.
        fix: intrinsic names held fixed (e.g. ``("p1", "p2")`` or ``("aspect",)``).
        K: optional (3, 3) initial camera matrix in OpenCV form, pixels.
        dist: optional OpenCV distortion vector (initial values).
        pose: optional (4, 4) known pose of the camera in its mount frame, metres.
        robot: the robot whose flange carries the camera (``mount: flange`` in a cell with named
            ``robots:``); None otherwise.
        settings: GenICam features set at capture, name -> number or string (e.g.
            ``{"ExposureTime": 5000, "Gain": 2}``; ExposureTime in us).
        lens: a zoom (focus) lens whose settings the intrinsics depend on (:class:`LensSpec`), or None.
    """

    name: str
    model: str
    mount: str
    skew: bool = False
    fix: tuple[str, ...] = ()
    K: np.ndarray | None = None
    dist: np.ndarray | None = None
    pose: np.ndarray | None = None
    robot: str | None = None
    settings: dict[str, Any] = field(default_factory=dict)
    lens: LensSpec | None = None


@dataclass(frozen=True)
class LensSpec:
    """A zoom (focus) lens: the camera's intrinsics and axial position are functions of ``settings``
    (GenICam feature names; one so far), each a clamped B-spline of ``degree`` with ``knots`` uniform
    interior knots in the setting normalised over the calibrated range (:mod:`jcalib.geometry.cameras.zoom`)."""

    settings: tuple[str, ...]
    degree: int = 3
    knots: int = 0


@dataclass(frozen=True)
class TargetSpec:
    """One calibration target: its type, geometry parameters (as in the spec) and mount (``robot``:
    the robot whose flange carries it, in a cell with named ``robots:``)."""

    name: str
    type: str
    mount: str
    params: dict[str, Any]
    pose: np.ndarray | None = None
    robot: str | None = None
    warp: bool = False

    def geometry(self):
        """The target's geometry object (:mod:`jcalib.geometry.targets`)."""
        from jcalib.geometry.targets import target_from_spec

        return target_from_spec({"type": self.type, **self.params})


@dataclass(frozen=True)
class ToolSpec:
    """A tool whose TCP (``T_flange_<name>``) is unknown; ``observed_by`` lists camera ids;
    ``robot``: the robot that carries it (cells with named ``robots:``). A known orientation of the
    TCP in the flange frame: ``orientation`` (3, 3), or ``axis`` (3,), the tool's z axis (the rotation
    about it by the convention "smallest rotation from the flange z"); otherwise it is estimated where
    imaged tool axes determine it and reported as not calibrated where nothing does."""

    name: str
    observed_by: tuple[str, ...] = ()
    robot: str | None = None
    orientation: np.ndarray | None = None
    axis: np.ndarray | None = None


@dataclass(frozen=True)
class PointSpec:
    """A fixed cell point (e.g. a pivot divot), unknown unless ``position`` is given (m, in the cell's
    frame: ``base`` with one robot, ``world`` with several)."""

    name: str
    position: np.ndarray | None = None


@dataclass(frozen=True)
class SensorSpec:
    """A measuring sensor with no lens (``sensors:``): a laser tracker, a metrology or motion-capture system.

    Attributes:
        name: sensor id, e.g. ``"tracker"``.
        kind: ``"pose"``: it measures targets' 6-DOF poses (stations' ``poses: [{sensor, target,
            T_sensor_target}]``); ``"point"``: it measures tool tips' 3-D positions (stations' ``positions:
            [{sensor, tool, p_sensor_tool}]``).
        mount: ``"base"`` (fixed, one-robot cell: unknown ``T_base_<name>``), ``"world"`` (fixed, several
            robots) or ``"flange"`` (on a robot: unknown ``T_flange_<name>``).
        pose: optional (4, 4) known pose in its mount frame, m.
        robot: the robot whose flange carries it (``mount: flange`` with named ``robots:``).
    """

    name: str
    kind: str = "pose"
    mount: str = "base"
    pose: np.ndarray | None = None
    robot: str | None = None


@dataclass(frozen=True)
class RobotSpec:
    """Robot settings. ``pose_noise`` is None when flange poses are taken as exact; ``model`` names a
    kinematics preset (:data:`jcalib.geometry.ROBOT_PRESETS`) for planning and simulation.
    ``name``: the key under ``robots:`` (None for ``robot:``); ``base``: optional known
    ``T_world_<name>`` (4, 4), m (several robots only). ``kinematics``: the robot's kinematic model
    (:class:`jcalib.geometry.kinematic_models.Kinematics`, from the spec's ``kinematics:`` preset or
    table, else from the ``model`` preset when that names a kinematics preset) or None;
    ``calibrate_kinematics``: the parameter names or groups to estimate (empty: the kinematics is taken as
    exact); ``kinematics_from_model``: the kinematics is the ``model`` preset (the spec has no ``kinematics:``);
    ``error_model``: the robot error model (:mod:`jcalib.problems.error_model`; ``auto`` chooses it by held-out
    prediction)."""

    model: str | None = None
    pose_noise_translation_m: np.ndarray | None = None  # (3,) per axis
    pose_noise_rotation_deg: np.ndarray | None = None  # (3,) per axis
    name: str | None = None
    base: np.ndarray | None = None
    kinematics: Any = None
    calibrate_kinematics: tuple[str, ...] = ()
    kinematics_spec: Any = None  # the spec's kinematics: entry as written (preset name or table)
    kinematics_from_model: bool = False
    error_model: str = "auto"  # auto | exact | pose_noise | kinematics (jcalib.problems.error_model)


@dataclass(frozen=True)
class CellSpec:
    """A parsed, validated cell spec.

    ``robot`` is the robot of a one-robot cell (from ``robot:`` or a one-entry ``robots:``; None
    without a robot and with several robots); ``robots`` holds the named robots of ``robots:`` in
    file order (empty for ``robot:``). ``goals``: accuracy goals for station planning and adaptive capture
    (:mod:`jcalib.io.goals`); they do not change a calibration.
    ``sensors``: measuring sensors with no lens (:class:`SensorSpec`, ``sensors:``), in file order.
    """

    cameras: dict[str, CameraSpec]
    targets: dict[str, TargetSpec]
    tools: dict[str, ToolSpec] = field(default_factory=dict)
    points: dict[str, PointSpec] = field(default_factory=dict)
    robot: RobotSpec | None = None
    fixed: tuple[str, ...] = ()
    source: str = "<dict>"
    robots: dict[str, RobotSpec] = field(default_factory=dict)
    goals: tuple[Goal, ...] = ()
    sensors: dict[str, SensorSpec] = field(default_factory=dict)
    assumptions: tuple = ()  # stated inputs and their uncertainty (jcalib.io.assumptions)

    @property
    def multi_robot(self) -> bool:
        """Several named robots: the cell's frame is ``world``."""
        return len(self.robots) > 1

    @property
    def frame(self) -> str:
        """The frame fixed things and cell points live in: ``"world"`` (several robots) or ``"base"``."""
        return "world" if self.multi_robot else "base"

    def target(self, name: str | None = None) -> TargetSpec:
        """The target called ``name``, or the only target when ``name`` is None."""
        if name is None:
            if len(self.targets) != 1:
                raise BadInputError(
                    f"{self.source}: the cell has {len(self.targets)} targets "
                    f"({', '.join(self.targets) or 'none'}); name one with --target."
                )
            return next(iter(self.targets.values()))
        if name not in self.targets:
            raise BadInputError(
                f"{self.source}: no target '{name}' in the cell; it has: {', '.join(self.targets)}."
            )
        return self.targets[name]

    def camera(self, name: str) -> CameraSpec:
        if name not in self.cameras:
            raise BadInputError(
                f"{self.source}: no camera '{name}' in the cell; it has: {', '.join(self.cameras)}."
            )
        return self.cameras[name]


def _fail(where: str, msg: str) -> BadInputError:
    return BadInputError(f"{where}: {msg}")


def _matrix(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise _fail(where, f"expected a numeric array of shape {shape}, got {value!r}") from None
    if arr.shape != shape:
        raise _fail(where, f"expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise _fail(where, "contains NaN or infinity")
    return arr


def _pose(value: Any, where: str) -> np.ndarray:
    T = _matrix(value, (4, 4), where)
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise _fail(where, "the rotation part is not a proper rotation matrix")
    if not np.allclose(T[3], [0, 0, 0, 1]):
        raise _fail(where, "the last row of a pose must be [0, 0, 0, 1]")
    return T


def _check_keys(entry: dict, allowed: set[str], where: str) -> None:
    unknown = sorted(set(entry) - allowed)
    if unknown:
        raise _fail(where, f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def _parse_camera(name: str, entry: Any, where: str) -> CameraSpec:
    if not isinstance(entry, dict):
        raise _fail(where, f"expected a mapping, got {entry!r}")
    _check_keys(entry, {"model", "mount", "skew", "fix", "intrinsics", "pose", "robot", "settings", "lens"}, where)
    model = entry.get("model")
    if model not in CAMERA_MODELS:
        raise _fail(where, f"unknown camera model {model!r}; use one of {', '.join(CAMERA_MODELS)}")
    mount = entry.get("mount", "free")
    if mount not in CAMERA_MOUNTS:
        raise _fail(where, f"unknown mount {mount!r}; use one of {', '.join(CAMERA_MOUNTS)}")
    fix = entry.get("fix", []) or []
    if not isinstance(fix, list) or not all(isinstance(f, str) for f in fix):
        raise _fail(where + ".fix", f"expected a list of intrinsic names, got {fix!r}")
    K = dist = None
    if "intrinsics" in entry:
        intr = entry["intrinsics"]
        if not isinstance(intr, dict) or "K" not in intr:
            raise _fail(where + ".intrinsics", "expected {K: [[3x3]], dist: [...]}")
        K = _matrix(intr["K"], (3, 3), where + ".intrinsics.K")
        dist = np.asarray(intr.get("dist", []), dtype=np.float64).ravel()
        if not np.all(np.isfinite(dist)):
            raise _fail(where + ".intrinsics.dist", "contains NaN or infinity")
    pose = _pose(entry["pose"], where + ".pose") if "pose" in entry else None
    settings = entry.get("settings") or {}
    if not isinstance(settings, dict) or not all(
        isinstance(k, str) and (isinstance(v, str) or (isinstance(v, (int, float)) and not isinstance(v, bool)
                                                       and np.isfinite(v)))
        for k, v in settings.items()
    ):  # fmt: skip
        raise _fail(where + ".settings", f"expected GenICam feature names mapped to finite numbers or strings, got {settings!r}")
    return CameraSpec(
        name=name,
        model=model,
        mount=mount,
        skew=bool(entry.get("skew", False)),
        fix=tuple(fix),
        K=K,
        dist=dist,
        pose=pose,
        robot=_robot_ref(entry, where),
        settings=dict(settings),
        lens=_parse_lens(entry.get("lens"), model, where + ".lens"),
    )


def _parse_lens(entry: Any, model: str, where: str) -> LensSpec | None:
    if entry is None:
        return None
    if not isinstance(entry, dict):
        raise _fail(where, f"expected {{settings: [Zoom], degree: 3, knots: 0}}, got {entry!r}")
    _check_keys(entry, {"settings", "degree", "knots"}, where)
    settings = entry.get("settings")
    if not isinstance(settings, list) or not settings or not all(isinstance(x, str) and x for x in settings):
        raise _fail(where + ".settings", f"expected a list of GenICam feature names such as [Zoom], got {settings!r}")
    if len(settings) != 1:
        raise _fail(where + ".settings", f"got {settings}; a lens depends on one setting so far (e.g. [Zoom]): "
                                         "calibrate with the other one held, one cell per value")
    if model == "splined":
        raise _fail(where, "the splined lens model has no zoom functions; use an opencv model or the fisheye")
    degree, knots = entry.get("degree", 3), entry.get("knots", 0)
    for key, value, lo, hi in (("degree", degree, 1, 5), ("knots", knots, 0, 8)):
        if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
            raise _fail(f"{where}.{key}", f"expected an integer in [{lo}, {hi}], got {value!r}")
    return LensSpec(settings=tuple(settings), degree=int(degree), knots=int(knots))


def _parse_target(name: str, entry: Any, where: str) -> TargetSpec:
    if not isinstance(entry, dict):
        raise _fail(where, f"expected a mapping, got {entry!r}")
    ttype = entry.get("type")
    if ttype not in TARGET_TYPES:
        raise _fail(where, f"unknown target type {ttype!r}; use one of {', '.join(TARGET_TYPES)}")
    mount = entry.get("mount", "free")
    if mount not in TARGET_MOUNTS:
        raise _fail(where, f"unknown mount {mount!r}; use one of {', '.join(TARGET_MOUNTS)}")
    pose = _pose(entry["pose"], where + ".pose") if "pose" in entry else None
    params = {k: v for k, v in entry.items() if k not in ("type", "mount", "pose", "robot", "warp")}
    spec = TargetSpec(name=name, type=ttype, mount=mount, params=params, pose=pose, robot=_robot_ref(entry, where),
                      warp=bool(entry.get("warp", False)))
    if ttype == "points":  # the points come with the observations (observations.targets.<id>.points)
        if params:
            raise _fail(where, f"a target of type points takes no grid fields, got {sorted(params)}; its points are "
                               "listed in the observations (targets.<id>.points)")
        return spec
    try:
        spec.geometry()  # validates the geometry fields (cols, rows, square, ...)
    except BadInputError as e:
        raise _fail(where, str(e)) from None
    return spec


def _robot_ref(entry: dict, where: str) -> str | None:
    """The ``robot:`` key of a camera / target / tool entry (a robot name), or None."""
    if "robot" not in entry or entry["robot"] is None:
        return None
    if not isinstance(entry["robot"], str) or not entry["robot"]:
        raise _fail(where + ".robot", f"expected the name of a robot under 'robots', got {entry['robot']!r}")
    return entry["robot"]


def _positive_vector(value: Any, where: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(3, float(arr))
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise _fail(where, f"expected a positive number or 3 positive numbers (x, y, z), got {value!r}")
    return arr


def _parse_robot(entry: Any, where: str, name: str | None = None, base_dir: Path | None = None) -> RobotSpec:
    if entry is None:
        return RobotSpec(name=name)
    if not isinstance(entry, dict):
        raise _fail(where, f"expected a mapping, got {entry!r}")
    _check_keys(entry, {"pose_noise", "model", "kinematics", "calibrate_kinematics", "error_model"}
                | ({"base"} if name is not None else set()), where)
    model = entry.get("model")
    if model is not None and not isinstance(model, str):
        raise _fail(where + ".model", f"expected a robot preset name, got {model!r}")
    base = _pose(entry["base"], where + ".base") if entry.get("base") is not None else None
    kin, which, kin_spec = _parse_kinematics(entry, where, name or "robot", base_dir)
    from_model = kin is not None and entry.get("kinematics") is None
    error_model = entry.get("error_model", "auto")
    if error_model not in ("auto", "exact", "pose_noise", "kinematics"):
        raise _fail(where + ".error_model", f"expected auto, exact, pose_noise or kinematics, got {error_model!r}")
    if error_model == "kinematics" and kin is None:
        raise _fail(where + ".error_model", "kinematics needs the robot's nominal model: add kinematics: <preset> (or a "
                                            "DH / MDH / POE table), or model: <preset>")
    noise = entry.get("pose_noise")
    if noise is None:
        return RobotSpec(model=model, name=name, base=base, kinematics=kin, calibrate_kinematics=which,
                         kinematics_spec=kin_spec, kinematics_from_model=from_model, error_model=error_model)
    _check_keys(noise, {"translation_m", "rotation_deg"}, where + ".pose_noise")
    if "translation_m" not in noise or "rotation_deg" not in noise:
        raise _fail(where + ".pose_noise", "give both translation_m and rotation_deg")
    return RobotSpec(
        model=model,
        pose_noise_translation_m=_positive_vector(noise["translation_m"], where + ".pose_noise.translation_m"),
        pose_noise_rotation_deg=_positive_vector(noise["rotation_deg"], where + ".pose_noise.rotation_deg"),
        name=name,
        base=base,
        kinematics=kin,
        calibrate_kinematics=which,
        kinematics_spec=kin_spec,
        kinematics_from_model=from_model,
        error_model=error_model,
    )


def _ur_calibration(spec: Any, where: str, base_dir: Path | None) -> Any:
    """``spec`` with a ``ur_calibration: FILE`` replaced by the ``delta_dh`` the file holds (so that a cell stored in
    a session does not depend on the file); other specs unchanged."""
    if not isinstance(spec, dict) or "ur_calibration" not in spec:
        return spec
    from jcalib.io.ur_calibration import read_ur_calibration

    if "delta_dh" in spec or "preset" not in spec:
        raise _fail(where + ".kinematics", "ur_calibration: give it with the robot type's preset and without delta_dh, "
                                           "e.g. {preset: ur5e, ur_calibration: calibration.conf}")
    name = spec["ur_calibration"]
    if not isinstance(name, str) or not name:
        raise _fail(where + ".kinematics.ur_calibration", f"expected the path of a UR calibration.conf, got {name!r}")
    path = Path(name) if Path(name).is_absolute() or base_dir is None else base_dir / name
    rest = {k: v for k, v in spec.items() if k != "ur_calibration"}
    return {**rest, "delta_dh": read_ur_calibration(path)}


def _parse_kinematics(entry: dict, where: str, robot: str, base_dir: Path | None = None):
    """``(model or None, names to calibrate, the kinematics entry)`` of a robot entry's ``kinematics:`` and
    ``calibrate_kinematics:`` (a ``ur_calibration`` file is read into the entry's ``delta_dh``). Without
    ``kinematics:``, a ``model:`` that names a kinematics preset is the nominal kinematics."""
    from jcalib.geometry import kinematic_models, kinematic_tables

    spec, which = _ur_calibration(entry.get("kinematics"), where, base_dir), entry.get("calibrate_kinematics")
    if which is not None and (not isinstance(which, list) or not all(isinstance(n, str) and n for n in which)):
        raise _fail(where + ".calibrate_kinematics", "expected a list of parameter names or groups (e.g. "
                                                     f"[joint_offsets, link_lengths]), got {which!r}")
    preset = entry.get("model")
    if spec is None and isinstance(preset, str) and preset in kinematic_models.PRESETS:
        spec = preset  # the robot's model preset is its nominal kinematics
    if spec is None:
        if which:
            named = (f"; its model {preset!r} is not a kinematics preset ({', '.join(kinematic_models.PRESETS)})"
                     if preset is not None else "")
            raise _fail(where + ".calibrate_kinematics", "calibrating kinematics needs the robot's nominal model"
                                                         f"{named}: add kinematics: <preset> (or a DH / MDH / POE "
                                                         "table), or model: <preset>")
        return None, (), None
    from jcalib.io.schema.common import max_reach_m

    model = kinematic_tables.from_spec(spec, robot, source=where + ".kinematics", max_length_m=max_reach_m())
    if which:
        kinematic_models.select(model, list(which), source=where + ".calibrate_kinematics")
    return model, tuple(which or ()), spec


def _parse_robots(data: dict, source: str, base_dir: Path | None = None) -> dict[str, RobotSpec]:
    """The named robots of ``robots:`` (empty without the key)."""
    if "robots" not in data:
        return {}
    if "robot" in data:
        raise _fail(source, "the cell has both 'robot' and 'robots'; use 'robot: {...}' for one robot or "
                            "'robots: {name: {...}, ...}' for named robots, not both")
    entries = data["robots"]
    if not isinstance(entries, dict) or not entries:
        raise _fail(f"{source}: robots", f"expected a mapping of robot names to entries, got {entries!r}")
    robots = {}
    for n, e in entries.items():
        if not isinstance(n, str) or not n or n in RESERVED_ROBOT_NAMES:
            raise _fail(f"{source}: robots", f"robot name {n!r} is not allowed (names other than "
                                             f"{', '.join(RESERVED_ROBOT_NAMES)}, e.g. 'r1')")
        robots[n] = _parse_robot(e, f"{source}: robots.{n}", name=n, base_dir=base_dir)
    if len(robots) == 1:
        r = next(iter(robots.values()))
        if r.base is not None:
            raise _fail(f"{source}: robots.{r.name}.base", "a one-robot cell is solved in its base frame; a known "
                        "base pose (T_world_<robot>) needs two or more robots. Remove 'base'")
    return robots


def _check_robot_refs(cameras: dict, targets: dict, tools: dict, points: dict, robots: dict[str, RobotSpec],
                      source: str, sensors: dict) -> tuple[dict, dict, dict, dict]:
    """Check mounts and ``robot:`` references against the robots; fill the default robot (the only one)."""
    several = len(robots) > 1
    names = ", ".join(robots)
    for n in robots:
        for kind, group in (("camera", cameras), ("target", targets), ("tool", tools), ("point", points),
                            ("sensor", sensors)):
            if n in group:
                raise _fail(f"{source}: robots.{n}", f"robot '{n}' has the name of a {kind}; give it another name "
                                                     "(transform names such as T_world_<name> must be unique)")

    def check(kind: str, spec, mounted: bool):
        where = f"{source}: {kind}s.{spec.name}"
        mount = getattr(spec, "mount", "flange")
        if mount == "world" and not several:
            raise _fail(where + ".mount", "mount 'world' is for cells with several robots (robots: with two or "
                                          "more); a one-robot cell is solved in the robot's base frame: use mount: base")
        if mount == "base" and several:
            raise _fail(where + ".mount", f"mount 'base' is ambiguous in a cell with several robots ({names}): use "
                                          "mount: world for things fixed in the cell (the world frame), or mount: "
                                          "flange with robot: <name>")
        if not mounted:
            if spec.robot is not None:
                raise _fail(where + ".robot", f"robot: applies to flange-mounted things and tools; this {kind} has "
                                              f"mount {mount!r}")
            return spec
        if spec.robot is None:
            if several:
                raise _fail(where + ".robot", f"a cell with several robots ({names}) needs robot: <name> on every "
                                              f"flange-mounted {kind} and tool")
            return replace(spec, robot=next(iter(robots))) if robots else spec
        if not robots:
            raise _fail(where + ".robot", f"robot: {spec.robot!r} names a robot, but the cell has no named robots; "
                                          "name them under robots: {name: {...}} (robot: {...} is one unnamed robot)")
        if spec.robot not in robots:
            raise _fail(where + ".robot", f"robot {spec.robot!r} is not in robots ({names})")
        return spec

    cameras = {n: check("camera", c, c.mount == "flange") for n, c in cameras.items()}
    targets = {n: check("target", t, t.mount == "flange") for n, t in targets.items()}
    tools = {n: check("tool", t, True) for n, t in tools.items()}
    sensors = {n: check("sensor", t, t.mount == "flange") for n, t in sensors.items()}
    return cameras, targets, tools, sensors


def parse_cell(data: Any, source: str = "<dict>", base_dir: str | os.PathLike | None = None) -> CellSpec:
    """Validate a cell spec given as a dict (e.g. loaded YAML).

    Args:
        base_dir: the folder that target files (``targets.<id>.file``, :mod:`jcalib.io.target_files`)
            are relative to (None: the working folder).

    Raises:
        BadInputError: naming ``source`` and the offending key.
    """
    if not isinstance(data, dict):
        raise _fail(source, "a cell spec must be a mapping with 'schema: jcalib.cell/1'")
    data = expand_target_files(data, base_dir, source)
    data = validate_cell_document(data, source)  # types, keys, units, names (jcalib.io.schema.cell)
    schema = data.get("schema")
    if schema != SCHEMA:
        raise _fail(source, f"schema is {schema!r}; expected '{SCHEMA}'")
    _check_keys(data, {"schema", "cameras", "sensors", "targets", "tools", "points", "robot", "robots", "fixed",
                       "goals", "assumptions"}, source)
    # files a cell names (a UR calibration) are relative to the cell file
    base_dir = Path(source).parent if source != "<dict>" and Path(source).is_file() else None
    robots = _parse_robots(data, source, base_dir)
    cameras_in = data.get("cameras") or {}
    if not isinstance(cameras_in, dict) or not (cameras_in or data.get("tools") or data.get("points")
                                                or data.get("sensors")):
        raise _fail(source, "'cameras' must map camera ids to entries (at least one camera, unless the cell "
                            "is calibrated by pose sensors or tool contacts alone: sensors, or tools and points)")
    cameras = {str(n): _parse_camera(str(n), e, f"{source}: cameras.{n}") for n, e in cameras_in.items()}
    targets_in = data.get("targets") or {}
    if not isinstance(targets_in, dict):
        raise _fail(source, "'targets' must map target ids to entries")
    targets = {str(n): _parse_target(str(n), e, f"{source}: targets.{n}") for n, e in targets_in.items()}
    tools = {}
    for n, e in (data.get("tools") or {}).items():
        e = e or {}
        observed = tuple(e.get("observed_by", []) or [])
        for c in observed:
            if c not in cameras:
                raise _fail(f"{source}: tools.{n}.observed_by", f"camera '{c}' is not in 'cameras'")
        where = f"{source}: tools.{n}"
        orientation = axis = None
        if e.get("orientation") is not None:
            orientation = _matrix(e["orientation"], (3, 3), where + ".orientation")
            if not np.allclose(orientation.T @ orientation, np.eye(3), atol=1e-6) or np.linalg.det(orientation) < 0:
                raise _fail(where + ".orientation", "expected a rotation matrix (orthonormal, det +1): the TCP axes in "
                                                    "the flange frame")
        if e.get("axis") is not None:
            axis = _matrix(e["axis"], (3,), where + ".axis")
            if not np.linalg.norm(axis) > 0:
                raise _fail(where + ".axis", "expected a non-zero vector: the tool's z axis in the flange frame")
            axis = axis / np.linalg.norm(axis)
        if orientation is not None and axis is not None:
            raise _fail(where, "give orientation or axis, not both")
        tools[str(n)] = ToolSpec(name=str(n), observed_by=observed, robot=_robot_ref(e, where),
                                 orientation=orientation, axis=axis)
    points = {}
    for n, e in (data.get("points") or {}).items():
        e = e or {}
        pos = _matrix(e["position"], (3,), f"{source}: points.{n}.position") if "position" in e else None
        points[str(n)] = PointSpec(name=str(n), position=pos)
    sensors = {str(n): SensorSpec(name=str(n), kind=e["kind"], mount=e.get("mount", "base"),
                                  pose=_pose(e["pose"], f"{source}: sensors.{n}.pose") if e.get("pose") else None,
                                  robot=_robot_ref(e, f"{source}: sensors.{n}"))
               for n, e in (data.get("sensors") or {}).items()}  # (types and keys checked by the schema)
    robot = _parse_robot(data["robot"], f"{source}: robot", base_dir=base_dir) if "robot" in data else None
    cameras, targets, tools, sensors = _check_robot_refs(cameras, targets, tools, points, robots, source, sensors)
    if len(robots) == 1:
        robot = next(iter(robots.values()))
    fixed = data.get("fixed") or []
    if not isinstance(fixed, list) or not all(isinstance(f, str) for f in fixed):
        raise _fail(f"{source}: fixed", f"expected a list of parameter names, got {fixed!r}")
    goals = data.get("goals") or []
    if not isinstance(goals, list):
        raise _fail(f"{source}: goals", f"expected a list of goals like 'T_flange_cam0:translation_mm<=0.05', got {goals!r}")
    goals = parse_goals(goals, f"{source}: goals")
    needs_robot = any(c.mount != "free" for c in cameras.values()) or any(
        t.mount != "free" for t in targets.values()
    ) or bool(sensors)
    if needs_robot and robot is None and not robots:
        robot = RobotSpec()
    entities = {*cameras, *targets, *tools, *points, *robots, "robot"} | {  # transform names: checked at the solve
        k.split(".")[0] for k in (data.get("assumptions") or {}) if isinstance(k, str) and k.startswith("T_")}
    assumptions = parse_assumptions(data.get("assumptions"), entities, source, base_dir)
    return CellSpec(
        cameras=cameras,
        targets=targets,
        tools=tools,
        points=points,
        robot=robot,
        fixed=tuple(fixed),
        source=source,
        robots=robots,
        goals=goals,
        sensors=sensors,
        assumptions=assumptions,
    )


def load_cell(cell: str | os.PathLike | dict | CellSpec) -> CellSpec:
    """Load and validate a cell spec from a YAML/JSON file, a dict, or pass a CellSpec through."""
    if isinstance(cell, CellSpec):
        return cell
    if isinstance(cell, dict):
        return parse_cell(cell)
    path = Path(cell)
    if not path.exists():
        raise BadInputError(f"cell spec '{path}' does not exist (expected a jcalib.cell/1 YAML file)")
    data = read_document(path, "cell spec", fmt="yaml")  # size, UTF-8, depth and alias limits
    return parse_cell(data, source=str(path), base_dir=path.parent)


def cell_to_dict(cell: CellSpec) -> dict:
    """The cell spec as a plain dict that :func:`parse_cell` reads back."""
    out: dict[str, Any] = {"schema": SCHEMA, "cameras": {}, "targets": {}}
    for c in cell.cameras.values():
        entry: dict[str, Any] = {"model": c.model, "mount": c.mount}
        if c.skew:
            entry["skew"] = True
        if c.fix:
            entry["fix"] = list(c.fix)
        if c.K is not None:
            entry["intrinsics"] = {"K": c.K.tolist(), "dist": [] if c.dist is None else c.dist.tolist()}
        if c.pose is not None:
            entry["pose"] = c.pose.tolist()
        if c.robot is not None:
            entry["robot"] = c.robot
        if c.settings:
            entry["settings"] = dict(c.settings)
        if c.lens is not None:
            entry["lens"] = {"settings": list(c.lens.settings), "degree": c.lens.degree, "knots": c.lens.knots}
        out["cameras"][c.name] = entry
    if cell.sensors:
        out["sensors"] = {n: {"kind": x.kind, "mount": x.mount, **({"pose": x.pose.tolist()} if x.pose is not None else {}),
                              **({"robot": x.robot} if x.robot is not None else {})} for n, x in cell.sensors.items()}
    for t in cell.targets.values():
        entry = {"type": t.type, **t.params, "mount": t.mount}
        if t.pose is not None:
            entry["pose"] = t.pose.tolist()
        if t.robot is not None:
            entry["robot"] = t.robot
        if t.warp:
            entry["warp"] = True
        out["targets"][t.name] = entry
    if cell.tools:
        out["tools"] = {t.name: {"observed_by": list(t.observed_by), **({"robot": t.robot} if t.robot else {}),
                                 **({"orientation": t.orientation.tolist()} if t.orientation is not None else {}),
                                 **({"axis": t.axis.tolist()} if t.axis is not None else {})}
                        for t in cell.tools.values()}
    if cell.points:
        out["points"] = {
            p.name: ({} if p.position is None else {"position": p.position.tolist()})
            for p in cell.points.values()
        }
    if cell.robots:
        out["robots"] = {n: _robot_to_dict(r) for n, r in cell.robots.items()}
    elif cell.robot is not None:
        out["robot"] = _robot_to_dict(cell.robot)
    if cell.fixed:
        out["fixed"] = list(cell.fixed)
    if cell.goals:
        out["goals"] = [g.text for g in cell.goals]
    if cell.assumptions:
        out["assumptions"] = assumptions_to_dict(cell.assumptions)
    return out



def _robot_to_dict(r: RobotSpec) -> dict:
    robot: dict[str, Any] = {}
    if r.model is not None:
        robot["model"] = r.model
    if r.pose_noise_translation_m is not None:
        robot["pose_noise"] = {
            "translation_m": r.pose_noise_translation_m.tolist(),
            "rotation_deg": r.pose_noise_rotation_deg.tolist(),
        }
    if r.base is not None:
        robot["base"] = r.base.tolist()
    if r.kinematics_spec is not None and not r.kinematics_from_model:
        robot["kinematics"] = r.kinematics_spec
    if r.calibrate_kinematics:
        robot["calibrate_kinematics"] = list(r.calibrate_kinematics)
    if r.error_model != "auto":
        robot["error_model"] = r.error_model
    return robot
