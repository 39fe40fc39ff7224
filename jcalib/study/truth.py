"""The ground truth of a study's trials: what the scenario states, or drawn from it.

The ``truth`` section of a scenario::

    truth:
      cameras:                      # per camera: true intrinsics (default: the cell's intrinsics, else DEFAULT_CAMERA)
        cam0: {image_size: [1600, 1200], params: [...]}          # in the model's param_names order
        cam1: {image_size: [1600, 1200], K: [[...]], dist: [...]}  # or OpenCV's K and dist
      poses:                        # per camera / target / tool: its pose on its holder
        cam0: [[4x4]]               # exact, every trial
        board: {pose: [[4x4]], rotation_deg: 180, axis: [0, 0, 1], translation_m: 0.0}   # drawn per trial
      bases: {r2: [[4x4]]}          # several robots: T_world_<robot> (exact or drawn, as poses)
      points: {divot: [0.5, 0.0, 0.05]}   # or {position: [...], translation_m: 0.01}
      targets: {marker: {points: [[x, y, z], ...]}}   # the points of a ``type: points`` target

A drawn pose is ``pose · [Exp(θ a) | v]``: ``a`` the given ``axis`` (target or thing frame) or a
uniformly random direction, ``θ`` uniform in ``[0, rotation_deg]``, ``v`` uniform in
``±translation_m`` per axis (m); a missing ``pose`` is the default one of the thing's mount. Things the
section does not name take the cell's stated value (``pose``, ``base``, ``position``, ``intrinsics``)
or the mount's default (:data:`DEFAULTS`): a flange camera with any rotation within 0.1 m of the
flange, a fixed board 0.6 m in front of the base facing up at any yaw, a fixed camera looking at it
from (1.2, 0.5, 0.6) m, a tool tip 0.10–0.25 m along the flange z (±50 mm across), further rig cameras
0.12 m apart, further robots 1.6 m away facing the first.

Every trial draws the same number of random numbers in the same order whatever the values (per thing
in cell order: 3 normal, 1 + 3 uniform), so a trial's truth depends on ``(seed, trial)`` only.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import exp_so3, make_pose, rot_x, rot_z
from jcalib.io.cell import CellSpec
from jcalib.sim.observe import CellTruth
from jcalib.study.checks import check_keys, fail, number, numbers, poses

__all__ = ["DEFAULT_CAMERA", "DEFAULTS", "check_truth", "draw_truth", "reference_camera", "role"]

#: The default true camera: image size and parameters by name (others zero).
DEFAULT_CAMERA = {"image_size": [1600, 1200],
                  "params": {"fx": 1400.0, "fy": 1395.0, "cx": 801.5, "cy": 598.0, "k1": -0.12, "k2": 0.08,
                             "p1": 0.0005, "p2": -0.0003, "k3": -0.02}}


def _look_at(eye, at, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    z = np.asarray(at, np.float64) - np.asarray(eye, np.float64)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    return make_pose(np.stack([x, np.cross(z, x), z], axis=1), np.asarray(eye, np.float64))


#: Mount role -> (default pose, default draw {rotation_deg, axis, translation_m}).
DEFAULTS: dict[str, tuple[np.ndarray, dict]] = {
    "flange_camera": (np.eye(4), {"rotation_deg": 180.0, "axis": None, "translation_m": [0.1] * 3}),
    "fixed_camera": (_look_at([1.2, 0.5, 0.6], [0.6, 0.1, 0.0]), {}),
    "rig_camera": (np.eye(4), {"rotation_deg": 2.0, "axis": None, "translation_m": [0.005] * 3}),
    "fixed_target": (make_pose(rot_x(np.pi), [0.6, 0.1, 0.0]), {"rotation_deg": 180.0, "axis": [0.0, 0.0, 1.0]}),
    "flange_target": (make_pose(np.eye(3), [0.0, 0.0, 0.05]),
                      {"rotation_deg": 180.0, "axis": None, "translation_m": [0.05] * 3}),
    "tool": (make_pose(np.eye(3), [0.0, 0.0, 0.175]), {"translation_m": [0.05, 0.05, 0.075]}),
    "base": (make_pose(rot_z(np.pi), [1.6, 0.0, 0.0]), {}),
}


def reference_camera(cell: CellSpec) -> str | None:
    """The rig's reference camera (the first) of a cell without robots, else None."""
    has_robot = cell.robot is not None or bool(cell.robots)
    return None if has_robot else next(iter(cell.cameras), None)


def cell_frame(cell: CellSpec) -> str:
    if len(cell.robots) > 1:
        return "world"
    return reference_camera(cell) or "base"


def role(cell: CellSpec, name: str) -> str | None:
    """The mount role of a camera, target or tool (a key of :data:`DEFAULTS`), None for a free target."""
    if name in cell.tools:
        return "tool"
    if name in cell.cameras:
        if reference_camera(cell) is not None:
            return "rig_camera"
        return "flange_camera" if cell.cameras[name].mount == "flange" else "fixed_camera"
    mount = cell.targets[name].mount
    return None if mount == "free" else "flange_target" if mount == "flange" else "fixed_target"


# ------------------------------------------------------------------------------------ validation


def _pose_entry(value: Any, key: str) -> dict:
    if isinstance(value, list):
        return {"pose": poses(value, key)[0].tolist()}
    if not isinstance(value, dict):
        raise fail(key, value, "a 4x4 pose (m) or {pose, rotation_deg, axis, translation_m}")
    check_keys(value, ("pose", "position", "rotation_deg", "axis", "translation_m"), key)
    out: dict[str, Any] = {}
    if value.get("pose") is not None:
        out["pose"] = poses(value["pose"], f"{key}.pose")[0].tolist()
    if value.get("position") is not None:
        if "pose" in out:
            raise fail(f"{key}.position", value["position"], "pose or position, not both")
        out["position"] = numbers(value["position"], f"{key}.position", 3)
    out["rotation_deg"] = number(value.get("rotation_deg", 0.0), f"{key}.rotation_deg", 0.0, 180.0)
    if value.get("axis") is not None:
        a = numbers(value["axis"], f"{key}.axis", 3)
        if not np.linalg.norm(a) > 0:
            raise fail(f"{key}.axis", value["axis"], "a non-zero vector")
        out["axis"] = a
    t = value.get("translation_m", 0.0)
    out["translation_m"] = [number(t, f"{key}.translation_m", 0.0)] * 3 if not isinstance(t, list) else [
        number(v, f"{key}.translation_m[{i}]", 0.0) for i, v in enumerate(numbers(t, f"{key}.translation_m", 3))]
    return out


def _camera_entry(value: Any, key: str, cell: CellSpec, cam: str) -> dict:
    from jcalib.geometry.cameras import camera_from_opencv, camera_model_from_name

    if not isinstance(value, dict):
        raise fail(key, value, "{image_size: [w, h], params: [...]} or {image_size, K, dist}")
    check_keys(value, ("image_size", "params", "K", "dist"), key)
    size = numbers(value.get("image_size", DEFAULT_CAMERA["image_size"]), f"{key}.image_size", 2)
    if any(s < 2 or s != int(s) for s in size):
        raise fail(f"{key}.image_size", value.get("image_size"), "[width, height] in whole pixels")
    spec = cell.cameras[cam]
    out: dict[str, Any] = {"image_size": [int(s) for s in size]}
    try:
        if value.get("params") is not None:
            if "K" in value:
                raise fail(key, sorted(value), "params or K/dist, not both")
            names = camera_model_from_name(spec.model, tuple(out["image_size"]), skew=spec.skew).param_names
            params = numbers(value["params"], f"{key}.params")
            if len(params) != len(names):
                raise fail(f"{key}.params", value["params"],
                           f"{len(names)} values ({', '.join(names)}) for model {spec.model!r}")
            camera_model_from_name(spec.model, tuple(out["image_size"]), np.asarray(params), skew=spec.skew)
            out["params"] = params
        elif value.get("K") is not None:
            model = camera_from_opencv(value["K"], value.get("dist") or [], tuple(out["image_size"]),
                                       fisheye=spec.model == "fisheye")
            out["params"] = np.asarray(model.params, np.float64).tolist()
            if len(out["params"]) != len(camera_model_from_name(spec.model, tuple(out["image_size"]),
                                                                skew=spec.skew).param_names):
                raise fail(f"{key}.dist", value.get("dist"), f"a distortion vector of model {spec.model!r}")
    except BadInputError as err:
        msg = str(err)
        raise BadInputError(msg if msg.startswith(key) else f"{key}: {msg}") from None
    return out


def check_truth(section: Any, cell: CellSpec) -> dict:
    """The validated ``truth`` section (plain data, normalised)."""
    if not isinstance(section, dict):
        raise fail("scenario.truth", section, "a mapping")
    check_keys(section, ("cameras", "poses", "bases", "points", "targets"), "scenario.truth")
    out: dict[str, dict] = {}
    things = set(cell.cameras) | set(cell.tools) | {t for t, s in cell.targets.items() if s.mount != "free"}
    for part, allowed in (("cameras", set(cell.cameras)), ("poses", things), ("bases", set(cell.robots)),
                          ("points", set(cell.points)), ("targets", set(cell.targets))):
        sec = section.get(part) or {}
        if not isinstance(sec, dict):
            raise fail(f"scenario.truth.{part}", sec, "a mapping")
        check_keys(sec, allowed, f"scenario.truth.{part}")
        out[part] = {}
        for name, value in sec.items():
            key = f"scenario.truth.{part}.{name}"
            if part == "cameras":
                out[part][name] = _camera_entry(value, key, cell, name)
            elif part in ("poses", "bases"):
                out[part][name] = _pose_entry(value, key)
            elif part == "points":
                if isinstance(value, list):
                    value = {"position": value}
                if not isinstance(value, dict):
                    raise fail(key, value, "[x, y, z] (m) or {position, translation_m}")
                check_keys(value, ("position", "translation_m"), key)
                entry = {"position": numbers(value.get("position"), f"{key}.position", 3)}
                entry["translation_m"] = number(value.get("translation_m", 0.0), f"{key}.translation_m", 0.0)
                out[part][name] = entry
            else:
                if not isinstance(value, dict) or "points" not in value:
                    raise fail(key, value, "{points: [[x, y, z], ...]} (m, target frame)")
                P = np.asarray(value["points"], np.float64)
                if P.ndim != 2 or P.shape[1] != 3 or len(P) < 6 or not np.all(np.isfinite(P)):
                    raise fail(f"{key}.points", f"shape {P.shape}", "at least 6 finite points (n, 3), m")
                out[part][name] = {"points": P.tolist()}
    for t, spec in cell.targets.items():
        if spec.type == "points" and t not in out["targets"]:
            raise fail(f"scenario.truth.targets.{t}", None, "the points of this type: points target "
                       "({points: [[x, y, z], ...]}, m, target frame)")
    return out


# ------------------------------------------------------------------------------------ drawing


def _draw(entry: dict, nominal: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    axis, u_angle, u_t = rng.normal(size=3), rng.random(), rng.random(3)  # always drawn
    T0 = np.asarray(entry["pose"], np.float64) if entry.get("pose") is not None else nominal.copy()
    if entry.get("position") is not None:
        T0[:3, 3] = entry["position"]
    a = np.asarray(entry.get("axis") or axis, np.float64)
    a = a / np.linalg.norm(a)
    angle = np.radians(float(entry.get("rotation_deg", 0.0))) * u_angle
    v = (2.0 * u_t - 1.0) * np.asarray(entry.get("translation_m", [0.0] * 3), np.float64)
    return T0 @ make_pose(exp_so3(angle * a), v)


def camera_truth(cell: CellSpec, section: dict, cam: str):
    """The true camera model of ``cam`` (scenario truth, else the cell's intrinsics, else the default)."""
    from jcalib.geometry.cameras import camera_from_opencv, camera_model_from_name

    spec = cell.cameras[cam]
    entry = section.get("cameras", {}).get(cam)
    if entry is not None:
        return camera_model_from_name(spec.model, tuple(entry["image_size"]), np.asarray(entry["params"]),
                                      skew=spec.skew)
    size = tuple(DEFAULT_CAMERA["image_size"])
    if spec.K is not None:
        dist = [] if spec.dist is None else spec.dist
        return camera_from_opencv(spec.K, dist, size, fisheye=spec.model == "fisheye")
    names = camera_model_from_name(spec.model, size, skew=spec.skew).param_names
    params = np.array([DEFAULT_CAMERA["params"].get(n, 0.0) for n in names])
    return camera_model_from_name(spec.model, size, params, skew=spec.skew)


def target_points(cell: CellSpec, section: dict, target: str) -> np.ndarray:
    spec = cell.targets[target]
    if spec.type == "points":
        return np.asarray(section["targets"][target]["points"], np.float64)
    return np.asarray(spec.geometry().points, np.float64)


def draw_truth(cell: CellSpec, section: dict, rng: np.random.Generator) -> CellTruth:
    """One trial's truth (see the module docstring).

    Raises:
        BadInputError: a camera whose true model is invalid.
    """
    frame = cell_frame(cell)
    ref = reference_camera(cell)
    cameras = {c: camera_truth(cell, section, c) for c in cell.cameras}
    thing_poses: dict[str, np.ndarray] = {}
    specs = list(cell.cameras.values()) + list(cell.targets.values()) + list(cell.tools.values())
    for i, spec in enumerate(specs):
        r = role(cell, spec.name)
        if r is None:
            continue
        nominal, draw = DEFAULTS[r]
        nominal = nominal.copy()
        if r == "rig_camera":
            k = list(cell.cameras).index(spec.name)
            nominal[:3, 3] = [0.12 * k, 0.0, 0.0]
            draw = {} if spec.name == ref else draw
        entry = section.get("poses", {}).get(spec.name)
        if entry is None:
            stated = getattr(spec, "pose", None)
            entry = {"pose": np.asarray(stated).tolist()} if stated is not None else dict(draw)
        if spec.name == ref:
            entry = {"pose": np.eye(4).tolist()}  # the rig frame
        thing_poses[spec.name] = _draw(entry, nominal, rng)
    bases = {}
    for i, (r, spec) in enumerate(cell.robots.items() if len(cell.robots) > 1 else []):
        nominal, draw = DEFAULTS["base"]
        nominal = np.eye(4) if i == 0 else make_pose(nominal[:3, :3], [1.6, 0.9 * i, 0.0])
        entry = section.get("bases", {}).get(r)
        if entry is None:
            entry = {"pose": np.asarray(spec.base).tolist()} if spec.base is not None else {}
        bases[r] = _draw(entry, nominal, rng)
    points = {}
    for j, (p, spec) in enumerate(cell.points.items()):
        u = rng.random(3)
        entry = section.get("points", {}).get(p)
        if entry is not None:
            points[p] = np.asarray(entry["position"], np.float64) + (2 * u - 1) * entry["translation_m"]
        elif spec.position is not None:
            points[p] = np.asarray(spec.position, np.float64)
        else:
            points[p] = np.array([0.5, 0.1 * j, 0.05])
    tpoints = {t: target_points(cell, section, t) for t in cell.targets}
    if frame not in ("base", "world") and not cameras:
        raise BadInputError("truth: a cell without robots needs cameras")
    return CellTruth(cameras=cameras, poses=thing_poses, target_points=tpoints, frame=frame, bases=bases,
                     points=points)
