"""The first scenario form (``cell: handeye | tcp | camera``), read as the cell-spec form.

The first form named one of three cell kinds and described its camera and board by keys of its own::

    schema: jcalib.study/1
    cell: handeye                 # handeye (eye-in-hand) | tcp | camera
    camera: {model: opencv5, image_size: [1600, 1200], params: [...]}
    target: {cols: 9, rows: 6, square: 0.025}
    intrinsics: known             # handeye: known | estimated
    noise: {pixel_sigma_px: 0.2, robot_translation_m: 1.0e-4, robot_rotation_deg: 0.01, dropout_rate: 0.0}
    stations: {strategy: random, count: 15}
    estimators: [park_martin, tsai_lenz, joint, joint_pose_model]

:func:`convert` writes the same study as a cell spec (``cam0``, ``board``, ``tool``), its truth
(the hand-eye transform any rotation within 0.1 m, the board 0.6 m in front of the base facing up at any
yaw; for TCP the camera anywhere at (1, 0, 0.8) m, known to the estimators, and the tip 0.10–0.25 m along
the flange z, ±50 mm across), station blocks and estimators (``joint``: the builder with the robot poses
taken as exact; ``joint_pose_model``: with the robot pose model). Tables change form: their columns are
named after the unknowns (``err_T_flange_cam0_rot_deg`` where the first form wrote ``err_rot_deg``).
"""

from __future__ import annotations

from typing import Any

from jcalib.errors import BadInputError
from jcalib.study.checks import check_keys, fail

__all__ = ["CELL_KINDS", "convert", "is_old_form"]

CELL_KINDS = ("handeye", "tcp", "camera")
_DEFAULT_CAMERA = {"model": "opencv5", "image_size": [1600, 1200],
                   "params": [1400.0, 1395.0, 801.5, 598.0, -0.12, 0.08, 0.0005, -0.0003, -0.02]}
_DEFAULT_TARGET = {"cols": 9, "rows": 6, "square": 0.025}
_DEFAULT_NOISE = {"pixel_sigma_px": 0.2, "robot_translation_m": 1e-4, "robot_rotation_deg": 0.01, "dropout_rate": 0.0}
_ESTIMATORS = {"handeye": ("tsai_lenz", "park_martin", "horaud", "andreff", "daniilidis", "joint", "joint_pose_model"),
               "tcp": ("three_pose", "ray_lsq"), "camera": ("joint", "opencv")}
_STRATEGIES = {"handeye": ("random", "robocalib_handeye", "robocalib_viewsets", "file"),
               "tcp": ("tcp_three_pose", "random"), "camera": ("random", "robocalib_viewsets", "file")}
_DEFAULT_STRATEGY = {"handeye": "random", "tcp": "tcp_three_pose", "camera": "random"}
_TOP = ("schema", "name", "cell", "camera", "target", "intrinsics", "noise", "stations", "estimators")


def is_old_form(data: dict) -> bool:
    """Whether ``data`` is a scenario of the first form (``cell`` names a kind)."""
    return isinstance(data.get("cell"), str) and data["cell"] in CELL_KINDS


def _section(data: dict, key: str, defaults: dict) -> dict:
    sec = data.get(key) or {}
    if not isinstance(sec, dict):
        raise fail(f"scenario.{key}", sec, "a mapping")
    check_keys(sec, defaults, f"scenario.{key}")
    return {**defaults, **sec}


def _stations(kind: str, sec: Any) -> dict:
    sec = sec or {}
    if not isinstance(sec, dict):
        raise fail("scenario.stations", sec, "a mapping")
    sec = dict(sec)
    strategy = sec.pop("strategy", _DEFAULT_STRATEGY[kind])
    if strategy not in _STRATEGIES[kind]:
        raise fail("scenario.stations.strategy", strategy, f"one of {list(_STRATEGIES[kind])} for cell {kind!r}")
    if kind == "tcp":
        if strategy == "random":
            strategy = "tcp_random"
        return {"strategy": strategy, "tool": "tool", "camera": "cam0", **sec}
    sec.pop("rotation_deg", None)  # a TCP option the first form accepted everywhere
    return {"strategy": strategy, "camera": "cam0", "target": "board", **sec}


def _check_camera(camera: dict) -> None:
    from jcalib.geometry.cameras import camera_model_from_name

    size = camera["image_size"]
    if not isinstance(size, (list, tuple)) or len(size) != 2 or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 2 and v == int(v) for v in size):
        raise fail("scenario.camera.image_size", size, "[width, height] in whole pixels")
    try:
        names = camera_model_from_name(str(camera["model"]), (int(size[0]), int(size[1]))).param_names
    except (BadInputError, ValueError, TypeError) as err:
        raise fail("scenario.camera.model", camera["model"], f"a camera model name ({err})") from None
    params = camera["params"]
    if not isinstance(params, (list, tuple)) or len(params) != len(names):
        raise fail("scenario.camera.params", params, f"{len(names)} values ({', '.join(names)}) for model "
                                                     f"{camera['model']!r}")


def convert(data: dict) -> dict:
    """The cell-spec form of a first-form scenario (see the module docstring).

    Raises:
        BadInputError: naming the key of the first form that is malformed.
    """
    check_keys(data, _TOP, "scenario")
    kind = data["cell"]
    camera = _section(data, "camera", _DEFAULT_CAMERA)
    target = _section(data, "target", _DEFAULT_TARGET)
    noise = _section(data, "noise", _DEFAULT_NOISE)
    intrinsics = data.get("intrinsics", "known")
    if intrinsics not in ("known", "estimated"):
        raise fail("scenario.intrinsics", intrinsics, "'known' or 'estimated'")
    _check_camera(camera)
    est = data.get("estimators", list(_ESTIMATORS[kind]))
    if isinstance(est, str):
        est = [est]
    if not isinstance(est, (list, tuple)) or not est:
        raise fail("scenario.estimators", est, f"a non-empty list from {list(_ESTIMATORS[kind])}")
    for i, e in enumerate(est):
        if e not in _ESTIMATORS[kind]:
            raise fail(f"scenario.estimators[{i}]", e, f"one of {list(_ESTIMATORS[kind])} for cell {kind!r}")
    stations = _stations(kind, data.get("stations"))
    if "three_pose" in est and stations["strategy"] != "tcp_three_pose":
        raise fail("scenario.estimators", "three_pose",
                   "the three_pose estimator only with stations.strategy 'tcp_three_pose'")
    try:
        t_m, r_deg = float(noise["robot_translation_m"]), float(noise["robot_rotation_deg"])
    except (TypeError, ValueError):
        raise fail("scenario.noise.robot_translation_m", (noise["robot_translation_m"], noise["robot_rotation_deg"]),
                   "numbers") from None
    noisy = t_m > 0 and r_deg > 0
    if "joint_pose_model" in est and not noisy:
        raise fail("scenario.noise.robot_translation_m", (t_m, r_deg),
                   "positive robot_translation_m and robot_rotation_deg for the joint_pose_model estimator (its prior)")
    robot = {"pose_noise": {"translation_m": t_m, "rotation_deg": r_deg}} if noisy else {}
    all_params = "all"  # resolved below by the model's parameter names
    cam: dict[str, Any] = {"model": camera["model"]}
    truth_cam = {"image_size": camera["image_size"], "params": camera["params"]}
    cell: dict[str, Any] = {"schema": "jcalib.cell/1", "cameras": {"cam0": cam}}
    truth: dict[str, Any] = {"cameras": {"cam0": truth_cam}}
    board = {"type": "checkerboard", **target}
    if kind == "handeye":
        cam["mount"] = "flange"
        if intrinsics == "known":
            cam["fix"] = all_params
        cell["targets"] = {"board": {**board, "mount": "base"}}
        cell["robot"] = robot
        truth["poses"] = {"cam0": {"rotation_deg": 180.0, "translation_m": 0.1},
                          "board": {"pose": [[1.0, 0, 0, 0.6], [0, -1.0, 0, 0.1], [0, 0, -1.0, 0], [0, 0, 0, 1.0]],
                                    "rotation_deg": 180.0, "axis": [0.0, 0.0, 1.0]}}
    elif kind == "camera":
        cam["mount"] = "free"
        cell["targets"] = {"board": {**board, "mount": "free"}}
    else:
        cam.update(mount="base", fix=all_params)
        cell["tools"] = {"tool": {"observed_by": ["cam0"]}}
        cell["robot"] = robot
        cell["fixed"] = ["cam0"]
        truth["poses"] = {"cam0": {"position": [1.0, 0.0, 0.8], "rotation_deg": 180.0},
                          "tool": {"position": [0.0, 0.0, 0.175], "translation_m": [0.05, 0.05, 0.075]}}
    if cam.get("fix") == all_params:
        from jcalib.geometry.cameras import camera_model_from_name

        cam["fix"] = list(camera_model_from_name(camera["model"], (100, 100)).param_names)
    estimators: list[Any] = []
    for e in est:
        if e == "joint":
            estimators.append({"name": "joint", "options": {"pose_model": False} if noisy and kind != "camera" else {}})
        elif e == "joint_pose_model":
            estimators.append({"name": "joint_pose_model", "options": {"pose_model": True}})
        else:
            estimators.append(e)
    out = {"schema": "jcalib.study/1", "name": data.get("name", ""), "cell": cell, "truth": truth,
           "noise": {**noise, "min_points": 8}, "stations": stations, "estimators": estimators}
    return out
