"""Study scenarios (``jcalib.study/1``): what a strategy study simulates and compares, as plain data.

A scenario is a dict (or a YAML / JSON file) with these keys; every key but ``cell`` has a default::

    schema: jcalib.study/1
    name: handeye-15-stations           # free text, copied to nothing but the report
    cell: handeye                       # handeye (eye-in-hand) | tcp | camera
    camera:                             # the simulated camera (OpenCV parameters, px / unitless)
      model: opencv5
      image_size: [1600, 1200]
      params: [1400, 1395, 801.5, 598, -0.12, 0.08, 0.0005, -0.0003, -0.02]   # fx fy cx cy k1 k2 p1 p2 k3
    target: {cols: 9, rows: 6, square: 0.025}   # checkerboard inner corners, m
    intrinsics: known                   # handeye: known (held fixed at the truth) | estimated
    noise:
      pixel_sigma_px: 0.2               # corner (or tool-tip) noise, N(0, σ²) per image axis
      robot_translation_m: 1.0e-4       # flange pose noise, N(0, σ²) per axis (flange frame)
      robot_rotation_deg: 0.01
      dropout_rate: 0.0                 # probability that a station's detection is lost
    stations:
      strategy: random                  # random | robocalib_handeye | robocalib_viewsets | tcp_three_pose | file
      count: 15                         # random: number of stations
      ...                               # strategy options, see STRATEGY_OPTIONS
    estimators: [park_martin, tsai_lenz, joint, joint_pose_model]

Estimators by cell (:data:`ESTIMATORS`):

- ``handeye``: the closed forms of :mod:`jcalib.init.handeye` by name (``tsai_lenz``, ``park_martin``,
  ``horaud``, ``andreff``, ``daniilidis``) on ``cv2.solvePnP`` poses, ``joint`` (pixels only, robot
  poses taken as exact) and ``joint_pose_model`` (with the per-station robot pose model), both
  :func:`jcalib.problems.handeye.calibrate_hand_eye`.
- ``tcp``: ``three_pose`` (the thesis' closed form, :func:`jcalib.init.tcp_analytic.tcp_three_pose`,
  needs the ``tcp_three_pose`` strategy) and ``ray_lsq`` (:func:`~jcalib.init.tcp_analytic.tcp_from_camera_ray`).
- ``camera``: ``joint`` (:func:`jcalib.problems.camera.calibrate_cameras_batch`, vmapped over the
  trials of a batch) and ``opencv`` (``cv2.calibrateCameraExtended``).

Strategies: ``random`` (handeye / camera: :func:`jcalib.sim.scene.random_calibration_views`; tcp:
random flange rotations that keep the tip on the camera ray); ``robocalib_handeye`` (RoboCalib
algorithm 5 geometry: a frontal view, then camera rotations about its Z, Y, X axes, re-centred on the
board); ``robocalib_viewsets`` (RoboCalib eqs 4.1–4.4: frontal, four tilted, world-origin and height
views); ``tcp_three_pose`` (initial pose, rotation about the camera z axis, rotation about the camera
x axis, each servoed back to the pixel); ``file`` (a YAML/JSON file with ``T_target_cam``: a list of
4x4 camera poses in the target frame, m; a relative path is taken from the scenario file's folder).
The RoboCalib strategies use the view geometry of :mod:`jcalib.acquisition.robocalib` without a robot
model (every view is taken as reachable).

:func:`load_scenario` validates everything and raises :class:`jcalib.errors.BadInputError` naming
the offending key (``scenario.noise.pixel_sigma_px``, ...), the value and what was expected.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError

__all__ = [
    "CELL_KINDS",
    "ESTIMATORS",
    "STRATEGIES",
    "STRATEGY_OPTIONS",
    "Noise",
    "Scenario",
    "Stations",
    "load_scenario",
]

SCHEMA = "jcalib.study/1"
CELL_KINDS = ("handeye", "tcp", "camera")
HANDEYE_CLOSED_FORMS = ("tsai_lenz", "park_martin", "horaud", "andreff", "daniilidis")
#: cell kind -> estimator names it accepts.
ESTIMATORS: dict[str, tuple[str, ...]] = {
    "handeye": (*HANDEYE_CLOSED_FORMS, "joint", "joint_pose_model"),
    "tcp": ("three_pose", "ray_lsq"),
    "camera": ("joint", "opencv"),
}
DEFAULT_ESTIMATORS: dict[str, tuple[str, ...]] = {
    "handeye": (*HANDEYE_CLOSED_FORMS, "joint", "joint_pose_model"),
    "tcp": ("three_pose", "ray_lsq"),
    "camera": ("joint", "opencv"),
}
#: cell kind -> station strategies it accepts.
STRATEGIES: dict[str, tuple[str, ...]] = {
    "handeye": ("random", "robocalib_handeye", "robocalib_viewsets", "file"),
    "tcp": ("tcp_three_pose", "random"),
    "camera": ("random", "robocalib_viewsets", "file"),
}
DEFAULT_STRATEGY = {"handeye": "random", "tcp": "tcp_three_pose", "camera": "random"}
#: strategy -> {option: default}. Units in the names (m, deg).
STRATEGY_OPTIONS: dict[str, dict[str, Any]] = {
    "random": {"count": 15, "max_tilt_deg": 40.0, "max_roll_deg": 30.0, "fill": [0.35, 0.8],
               "rotation_deg": 30.0},
    "robocalib_handeye": {"distance_m": 0.5, "angles_z_deg": [-90.0, -45.0, 45.0, 90.0],
                          "angles_y_deg": [-30.0, -15.0, 15.0, 30.0], "angles_x_deg": [-30.0, -15.0, 15.0, 30.0]},
    "robocalib_viewsets": {"distance_m": 0.5, "tilt_deg": 30.0, "heights": [0.8, 1.25], "rolls_deg": [0.0, 45.0]},
    "tcp_three_pose": {"alpha_deg": 30.0, "beta_deg": 30.0, "tip_depth_m": 0.4},
    "file": {"path": None},
}
_DEFAULT_CAMERA = {
    "model": "opencv5",
    "image_size": [1600, 1200],
    "params": [1400.0, 1395.0, 801.5, 598.0, -0.12, 0.08, 0.0005, -0.0003, -0.02],
}
_DEFAULT_TARGET = {"cols": 9, "rows": 6, "square": 0.025}
_DEFAULT_NOISE = {"pixel_sigma_px": 0.2, "robot_translation_m": 1e-4, "robot_rotation_deg": 0.01, "dropout_rate": 0.0}
_TOP_KEYS = ("schema", "name", "cell", "camera", "target", "intrinsics", "noise", "stations", "estimators")


@dataclass(frozen=True)
class Noise:
    """Noise model of a study.

    Attributes:
        pixel_sigma_px: corner / tool-tip detection noise, σ per image axis, px.
        robot_translation_m: flange pose noise, σ per translation axis (flange frame), m.
        robot_rotation_deg: flange pose noise, σ per rotation axis (flange frame), deg.
        dropout_rate: probability that a station's detection is lost (target not found), in [0, 1).
    """

    pixel_sigma_px: float = 0.2
    robot_translation_m: float = 1e-4
    robot_rotation_deg: float = 0.01
    dropout_rate: float = 0.0


@dataclass(frozen=True)
class Stations:
    """Station strategy: its name and its options (defaults of :data:`STRATEGY_OPTIONS` filled in)."""

    strategy: str
    options: dict = field(default_factory=dict)
    #: ``file`` strategy: (N, 4, 4) ``T_target_cam`` read from the file, m.
    T_target_cam: np.ndarray | None = None


@dataclass(frozen=True)
class Scenario:
    """A validated study scenario (see the module docstring for the file form).

    Attributes:
        cell: ``"handeye"`` (eye-in-hand), ``"tcp"`` or ``"camera"``.
        camera: ``{"model", "image_size" (w, h) px, "params"}`` (OpenCV order).
        target: ``{"cols", "rows", "square" (m)}`` checkerboard.
        intrinsics: ``"known"`` or ``"estimated"`` (hand-eye).
        noise: :class:`Noise`.
        stations: :class:`Stations`.
        estimators: estimator names, in table order.
        name: free text.
        source: where the scenario came from (file path or ``"<dict>"``).
    """

    cell: str
    camera: dict
    target: dict
    intrinsics: str
    noise: Noise
    stations: Stations
    estimators: tuple[str, ...]
    name: str = ""
    source: str = "<dict>"

    def to_dict(self) -> dict:
        """The scenario as plain data (JSON-able); ``load_scenario(s.to_dict())`` gives ``s`` back."""
        stations = {"strategy": self.stations.strategy, **self.stations.options}
        if self.stations.strategy == "file":
            stations["path"] = None
            stations["T_target_cam"] = np.asarray(self.stations.T_target_cam).tolist()
        return {
            "schema": SCHEMA, "name": self.name, "cell": self.cell, "camera": self.camera, "target": self.target,
            "intrinsics": self.intrinsics,
            "noise": {k: getattr(self.noise, k) for k in _DEFAULT_NOISE},
            "stations": stations, "estimators": list(self.estimators),
        }


def _fail(key: str, value: Any, expected: str) -> BadInputError:
    return BadInputError(f"{key}: got {value!r}, expected {expected}")


def _check_keys(data: dict, allowed, where: str) -> None:
    for k in data:
        if k not in allowed:
            raise BadInputError(f"{where}.{k}: unknown key; expected one of {sorted(allowed)}")


def _number(value: Any, key: str, lo: float | None = None, hi: float | None = None, *, lo_open=False,
            hi_open=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise _fail(key, value, "a finite number")
    v = float(value)
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise _fail(key, value, f"a number {'>' if lo_open else '>='} {lo:g}")
    if hi is not None and (v > hi or (hi_open and v == hi)):
        raise _fail(key, value, f"a number {'<' if hi_open else '<='} {hi:g}")
    return v


def _numbers(value: Any, key: str, n: int | None = None) -> list[float]:
    if not isinstance(value, (list, tuple)) or (n is not None and len(value) != n):
        raise _fail(key, value, f"a list of {n if n is not None else 'some'} numbers")
    return [_number(v, f"{key}[{i}]") for i, v in enumerate(value)]


def _section(data: dict, key: str, defaults: dict) -> dict:
    sec = data.get(key, {})
    if sec is None:
        sec = {}
    if not isinstance(sec, dict):
        raise _fail(f"scenario.{key}", sec, "a mapping")
    _check_keys(sec, defaults, f"scenario.{key}")
    return {**defaults, **sec}


def _read_file(path: str | os.PathLike) -> dict:
    p = Path(path)
    if not p.is_file():
        raise BadInputError(f"scenario: file {str(p)!r} not found")
    text = p.read_text()
    if p.suffix.lower() == ".json":
        return json.loads(text)
    import yaml

    return yaml.safe_load(text)


def _poses(value: Any, key: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise _fail(key, type(value).__name__, "a list of 4x4 poses (m)") from None
    if arr.ndim != 3 or arr.shape[1:] != (4, 4) or len(arr) < 3 or not np.all(np.isfinite(arr)):
        raise _fail(key, f"array of shape {arr.shape}", "a list of at least 3 finite 4x4 poses (m)")
    R = arr[:, :3, :3]
    if np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max() > 1e-6 or np.any(np.linalg.det(R) < 0):
        raise _fail(key, "a matrix that is not a rigid transform", "4x4 poses with orthonormal rotations")
    return arr


def _stations(data: dict, cell: str, base: Path | None) -> Stations:
    sec = data.get("stations", {}) or {}
    if not isinstance(sec, dict):
        raise _fail("scenario.stations", sec, "a mapping")
    strategy = sec.get("strategy", DEFAULT_STRATEGY[cell])
    if strategy not in STRATEGIES[cell]:
        raise _fail("scenario.stations.strategy", strategy, f"one of {list(STRATEGIES[cell])} for cell {cell!r}")
    defaults = STRATEGY_OPTIONS[strategy]
    allowed = {"strategy", *defaults}
    if strategy == "file":
        allowed.add("T_target_cam")
    if cell == "tcp" and strategy == "random":
        allowed.add("tip_depth_m")
    _check_keys(sec, allowed, "scenario.stations")
    opts = {**defaults, **{k: v for k, v in sec.items() if k != "strategy"}}
    where = "scenario.stations"
    T_tc = None
    if strategy == "random":
        count = opts["count"]
        minimum = 3
        if isinstance(count, bool) or not isinstance(count, int) or count < minimum:
            raise _fail(f"{where}.count", count, f"an integer >= {minimum}")
        opts["max_tilt_deg"] = _number(opts["max_tilt_deg"], f"{where}.max_tilt_deg", 0.0, 80.0, hi_open=True)
        opts["max_roll_deg"] = _number(opts["max_roll_deg"], f"{where}.max_roll_deg", 0.0, 90.0, hi_open=True)
        fill = _numbers(opts["fill"], f"{where}.fill", 2)
        if not 0 < fill[0] <= fill[1] <= 1.5:
            raise _fail(f"{where}.fill", opts["fill"], "[min, max] with 0 < min <= max <= 1.5")
        opts["fill"] = fill
        opts["rotation_deg"] = _number(opts["rotation_deg"], f"{where}.rotation_deg", 0.0, 180.0, lo_open=True)
    elif strategy == "robocalib_handeye":
        opts["distance_m"] = _number(opts["distance_m"], f"{where}.distance_m", 0.0, lo_open=True)
        for k in ("angles_z_deg", "angles_y_deg", "angles_x_deg"):
            vals = _numbers(opts[k], f"{where}.{k}")
            if any(v == 0.0 or abs(v) > 180.0 for v in vals):
                raise _fail(f"{where}.{k}", opts[k], "non-zero angles within +-180 deg")
            opts[k] = vals
    elif strategy == "robocalib_viewsets":
        opts["distance_m"] = _number(opts["distance_m"], f"{where}.distance_m", 0.0, lo_open=True)
        opts["tilt_deg"] = _number(opts["tilt_deg"], f"{where}.tilt_deg", 0.0, 90.0, lo_open=True, hi_open=True)
        opts["heights"] = _numbers(opts["heights"], f"{where}.heights")
        if any(not 0.0 < h <= 10.0 for h in opts["heights"]):
            raise _fail(f"{where}.heights", opts["heights"], "scale factors in (0, 10]")
        opts["rolls_deg"] = _numbers(opts["rolls_deg"], f"{where}.rolls_deg")
    elif strategy == "tcp_three_pose":
        for k in ("alpha_deg", "beta_deg"):
            opts[k] = _number(opts[k], f"{where}.{k}", 0.0, 180.0, lo_open=True, hi_open=True)
        opts["tip_depth_m"] = _number(opts["tip_depth_m"], f"{where}.tip_depth_m", 0.0, lo_open=True)
    elif strategy == "file":
        if "T_target_cam" in opts:
            T_tc = _poses(opts.pop("T_target_cam"), f"{where}.T_target_cam")
        else:
            path = opts["path"]
            if not isinstance(path, (str, os.PathLike)):
                raise _fail(f"{where}.path", path, "a YAML/JSON file with T_target_cam (list of 4x4, m)")
            p = Path(path)
            if not p.is_absolute() and base is not None:
                p = base / p
            content = _read_file(p)
            if not isinstance(content, dict) or "T_target_cam" not in content:
                raise _fail(f"{where}.path", str(p), "a file with a T_target_cam key (list of 4x4 poses, m)")
            T_tc = _poses(content["T_target_cam"], f"{where}.path ({p}): T_target_cam")
            opts["path"] = str(p)
    if strategy == "tcp_three_pose" or (cell == "tcp" and strategy == "random"):
        tip = opts.get("tip_depth_m", STRATEGY_OPTIONS["tcp_three_pose"]["tip_depth_m"])
        opts["tip_depth_m"] = _number(tip, f"{where}.tip_depth_m", 0.0, lo_open=True)
    return Stations(strategy=strategy, options=opts, T_target_cam=T_tc)


def load_scenario(scenario: str | os.PathLike | dict | Scenario) -> Scenario:
    """Read and validate a study scenario.

    Args:
        scenario: a :class:`Scenario`, a dict, or a path to a YAML / JSON file (``jcalib.study/1``).

    Returns:
        The validated :class:`Scenario`, defaults filled in.

    Raises:
        BadInputError: unknown or malformed keys; the message names the key (e.g.
            ``scenario.noise.pixl_sigma_px: unknown key``), the value received and what was expected.
    """
    if isinstance(scenario, Scenario):
        return scenario
    base, source = None, "<dict>"
    if isinstance(scenario, (str, os.PathLike)):
        base, source = Path(scenario).resolve().parent, str(scenario)
        scenario = _read_file(scenario)
    if not isinstance(scenario, dict):
        raise _fail("scenario", type(scenario).__name__, "a mapping (YAML/JSON object)")
    data = scenario
    _check_keys(data, _TOP_KEYS, "scenario")
    schema = data.get("schema", SCHEMA)
    if schema != SCHEMA:
        raise _fail("scenario.schema", schema, repr(SCHEMA))
    cell = data.get("cell")
    if cell not in CELL_KINDS:
        raise _fail("scenario.cell", cell, f"one of {list(CELL_KINDS)}")
    name = data.get("name", "")
    if not isinstance(name, str):
        raise _fail("scenario.name", name, "a string")

    camera = _section(data, "camera", _DEFAULT_CAMERA)
    from jcalib.geometry.cameras import camera_model_from_name

    size = _numbers(camera["image_size"], "scenario.camera.image_size", 2)
    if any(s < 2 or s != int(s) for s in size):
        raise _fail("scenario.camera.image_size", camera["image_size"], "[width, height] in whole pixels")
    params = _numbers(camera["params"], "scenario.camera.params")
    try:
        names = camera_model_from_name(str(camera["model"]), tuple(int(s) for s in size)).param_names
    except (BadInputError, ValueError, TypeError) as err:
        raise _fail("scenario.camera.model", camera["model"], f"a camera model name ({err})") from None
    if len(names) != len(params):
        raise _fail("scenario.camera.params", camera["params"],
                    f"{len(names)} values ({', '.join(names)}) for model {camera['model']!r}")
    try:
        camera_model_from_name(str(camera["model"]), tuple(int(s) for s in size), np.asarray(params))
    except (BadInputError, ValueError, TypeError) as err:
        raise BadInputError(f"scenario.camera.params: {err}") from None
    camera = {"model": str(camera["model"]), "image_size": [int(s) for s in size], "params": params}

    target = _section(data, "target", _DEFAULT_TARGET)
    for k in ("cols", "rows"):
        if isinstance(target[k], bool) or not isinstance(target[k], int) or target[k] < 2:
            raise _fail(f"scenario.target.{k}", target[k], "an integer >= 2")
    target["square"] = _number(target["square"], "scenario.target.square", 0.0, lo_open=True)

    intrinsics = data.get("intrinsics", "known")
    if intrinsics not in ("known", "estimated"):
        raise _fail("scenario.intrinsics", intrinsics, "'known' or 'estimated'")

    nz = _section(data, "noise", _DEFAULT_NOISE)
    noise = Noise(
        pixel_sigma_px=_number(nz["pixel_sigma_px"], "scenario.noise.pixel_sigma_px", 0.0),
        robot_translation_m=_number(nz["robot_translation_m"], "scenario.noise.robot_translation_m", 0.0),
        robot_rotation_deg=_number(nz["robot_rotation_deg"], "scenario.noise.robot_rotation_deg", 0.0),
        dropout_rate=_number(nz["dropout_rate"], "scenario.noise.dropout_rate", 0.0, 1.0, hi_open=True),
    )

    stations = _stations(data, cell, base)

    est = data.get("estimators", list(DEFAULT_ESTIMATORS[cell]))
    if isinstance(est, str):
        est = [est]
    if not isinstance(est, (list, tuple)) or not est:
        raise _fail("scenario.estimators", est, f"a non-empty list from {list(ESTIMATORS[cell])}")
    for i, e in enumerate(est):
        if e not in ESTIMATORS[cell]:
            raise _fail(f"scenario.estimators[{i}]", e, f"one of {list(ESTIMATORS[cell])} for cell {cell!r}")
    if len(set(est)) != len(est):
        raise _fail("scenario.estimators", est, "each estimator once")
    if "three_pose" in est and stations.strategy != "tcp_three_pose":
        raise _fail("scenario.estimators", "three_pose",
                    "the three_pose estimator only with stations.strategy 'tcp_three_pose'")
    if "joint_pose_model" in est and not (noise.robot_translation_m > 0 and noise.robot_rotation_deg > 0):
        raise _fail("scenario.noise.robot_translation_m",
                    (noise.robot_translation_m, noise.robot_rotation_deg),
                    "positive robot_translation_m and robot_rotation_deg for the joint_pose_model estimator "
                    "(its prior)")
    return Scenario(cell=cell, camera=camera, target=dict(target), intrinsics=intrinsics, noise=noise,
                    stations=stations, estimators=tuple(est), name=name, source=source)
