"""Closed-form baselines of a study (no builder): what the joint solve is compared against.

- Hand-eye ``tsai_lenz``, ``park_martin``, ``horaud``, ``andreff``, ``daniilidis``
  (:func:`jcalib.init.solve_hand_eye`, each equal to ``cv2.calibrateHandEye`` with its method) and
  robot-world ``shah``, ``li`` (:func:`jcalib.init.solve_robot_world_hand_eye`, as
  ``cv2.calibrateRobotWorldHandEye``), on the first pair block whose camera or target a robot carries
  (one-robot cells): the recorded flange poses and ``T_cam_target`` from ``cv2.solvePnP`` (or the
  measured poses of a ``measure: poses`` block). PnP uses the camera's intrinsics from the trial's cell
  spec when it holds them all fixed, else ``cv2.calibrateCameraExtended`` on the same views. They
  estimate the hand-eye transform and the other end of the loop (``T_base_<target>`` or
  ``T_flange_<target>``), without covariance.
- TCP ``three_pose`` (the thesis' closed form, :func:`jcalib.init.tcp_three_pose`) and ``ray_lsq``
  (:func:`jcalib.init.tcp_from_camera_ray`) on the first ``tcp_three_pose`` (or, for ``ray_lsq``,
  ``tcp_random``) block: the recorded flange poses of its stations and the camera's orientation and the
  servo's goal pixel ray from the trial's cell spec (the camera's ``pose`` and intrinsics must be stated
  there, e.g. ``fixed`` or ``given``). Covariance: the method's error amplification with the robot's
  translation noise and the servo residual (taken isotropic) and its rotation noise.
- ``pivot`` (:func:`jcalib.init.pivot_calibration`) on the stations with the first (tool, point) contact:
  tip and point, with its a-posteriori covariance.
- ``opencv``: ``cv2.calibrateCameraExtended`` per camera on all its views of its first target
  (models ``pinhole``, ``opencv4``, ``opencv5``, ``opencv8``); σ from OpenCV's standard deviations.
"""

from __future__ import annotations

import math

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.study.estimate import Estimate
from jcalib.study.scenario import HANDEYE_CLOSED_FORMS, ROBOT_WORLD_CLOSED_FORMS, Scenario
from jcalib.study.simulate import Trial, observation_noise
from jcalib.study.stations import holder

__all__ = ["closed_form", "opencv_intrinsics"]

_CV_FLAGS = {"opencv4": "CALIB_FIX_K3", "opencv5": None, "opencv8": "CALIB_RATIONAL_MODEL",
             "pinhole": ("CALIB_FIX_K1", "CALIB_FIX_K2", "CALIB_FIX_K3", "CALIB_ZERO_TANGENT_DIST")}
_ALL = ["rx", "ry", "rz", "tx", "ty", "tz"]


def _flags(model: str) -> int:
    import cv2

    if model not in _CV_FLAGS:
        raise BadInputError(f"the opencv estimator supports camera models {sorted(_CV_FLAGS)}, got {model!r}")
    f = _CV_FLAGS[model]
    names = () if f is None else (f,) if isinstance(f, str) else f
    out = 0
    for n in names:
        out |= getattr(cv2, n)
    return out


def _views(trial: Trial, camera: str, target: str, ids: list[str] | None = None):
    """``(station ids, point index arrays, pixel arrays)`` of a camera's corner views of a target."""
    out = ([], [], [])
    for s in trial.observations.stations:
        if ids is not None and s.id not in ids:
            continue
        for d in s.detections:
            if d.camera == camera and d.target == target:
                out[0].append(s.id)
                out[1].append(np.asarray(d.point_index))
                out[2].append(np.asarray(d.pixels, np.float64))
                break
    return out


def opencv_intrinsics(model: str, image_size, points: np.ndarray, index: list, pixels: list):
    """``cv2.calibrateCameraExtended`` on views: ``(K, dist, std of (fx, fy, cx, cy, dist...), rms px)``."""
    import cv2

    flags = _flags(model)
    if len(pixels) < 3:
        raise NotObservableError(f"only {len(pixels)} views of the target", unknowns=["intrinsics"])
    obj = [points[i].astype(np.float32) for i in index]
    img = [np.asarray(p, np.float32) for p in pixels]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, _, _, std, _, _ = cv2.calibrateCameraExtended(obj, img, tuple(int(v) for v in image_size), None, None,
                                                                flags=flags, criteria=crit)
    return K, dist.ravel(), std.ravel(), float(rms)


def _params(model: str, K: np.ndarray, dist: np.ndarray, n: int) -> np.ndarray:
    return np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dist])[:n]


def _opencv(scenario: Scenario, trial: Trial) -> Estimate:
    cell = trial.cell
    est = Estimate()
    for cam, spec in cell.cameras.items():
        target = next((t for t in cell.targets if _views(trial, cam, t)[0]), None)
        if target is None:
            continue
        ids, index, pixels = _views(trial, cam, target)
        n = len(trial.truth.cameras[cam].param_names)
        K, dist, std, rms = opencv_intrinsics(spec.model, trial.observations.cameras[cam],
                                              trial.observations.targets[target], index, pixels)
        est.cameras[cam] = _params(spec.model, K, dist, n)
        est.camera_covariance[cam] = np.diag(std[:n] ** 2)
        est.rms_px = rms
        est.num_stations = max(est.num_stations, len(ids))
    if not est.cameras:
        raise BadInputError("the opencv estimator needs cameras that see a target")
    return est


def _known_intrinsics(trial: Trial, cam: str) -> tuple[np.ndarray, np.ndarray] | None:
    spec = trial.cell.cameras[cam]
    names = set(trial.truth.cameras[cam].param_names)
    if spec.K is not None and names <= set(spec.fix):
        return np.asarray(spec.K, np.float64), np.asarray(spec.dist if spec.dist is not None else [], np.float64)
    return None


def _pnp(points: np.ndarray, index: list, pixels: list, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    import cv2

    out = []
    for idx, pix in zip(index, pixels):
        ok, r, t = cv2.solvePnP(points[idx], np.asarray(pix, np.float64), K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise NotObservableError("cv2.solvePnP failed on a station", unknowns=["T_cam_target"])
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = cv2.Rodrigues(r)[0], t.ravel()
        out.append(T)
    return np.array(out)


def _flange(trial: Trial, ids: list[str], robot: str) -> np.ndarray:
    by_id = {s.id: s for s in trial.observations.stations}
    out = []
    for i in ids:
        s = by_id[i]
        out.append(s.T_base_flange if s.T_base_flange is not None else s.flange_poses[robot])
    return np.asarray(out, np.float64)


def hand_eye_data(scenario: Scenario, trial: Trial):
    """``(block, mount, T_base_flange (N, 4, 4), T_cam_target (N, 4, 4))`` of the first hand-eye pair block.

    Raises:
        BadInputError: no such block, or a cell with several robots.
    """
    cell = trial.cell
    if len(cell.robots) > 1:
        raise BadInputError("the hand-eye closed forms take cells with one robot")
    for b in scenario.stations:
        if b.kind != "pair":
            continue
        hc, ht = holder(cell, b.camera), holder(cell, b.target)
        if {hc, ht} & {None} and {hc, ht} - {None, "free"}:
            break
    else:
        raise BadInputError("the hand-eye closed forms need a pair block whose camera or target the robot carries "
                            "(the other fixed)")
    robot = hc if hc is not None else ht
    block_ids = next(r.ids for r in trial.records if r.block is b)
    if b.measure == "poses":
        ids, T_ct = [], []
        for s in trial.observations.stations:
            for m in s.poses:
                if s.id in block_ids and m.camera == b.camera and m.target == b.target:
                    ids.append(s.id)
                    T_ct.append(m.T_cam_target)
        T_ct = np.asarray(T_ct, np.float64)
    else:
        ids, index, pixels = _views(trial, b.camera, b.target, block_ids)
        points = trial.observations.targets[b.target]
        known = _known_intrinsics(trial, b.camera)
        if known is None:
            K, dist, _, _ = opencv_intrinsics(cell.cameras[b.camera].model, trial.observations.cameras[b.camera],
                                              points, index, pixels)
        else:
            K, dist = known
        T_ct = _pnp(points, index, pixels, K, dist)
    if len(ids) < 3:
        raise NotObservableError(f"only {len(ids)} stations of the hand-eye pair", unknowns=["hand-eye"])
    return b, ("flange" if hc is not None else "base"), _flange(trial, ids, robot), T_ct


def _hand_eye(method: str, scenario: Scenario, trial: Trial) -> Estimate:
    from jcalib.init import solve_hand_eye, solve_robot_world_hand_eye

    b, mount, T_bf, T_ct = hand_eye_data(scenario, trial)
    noise = observation_noise(scenario).robot
    rot = max([0.02] + [float(np.max(r)) for _, r in noise.values()])
    if method in HANDEYE_CLOSED_FORMS:
        init = solve_hand_eye(T_bf, T_ct, method=method, mount=mount, rotation_noise_deg=rot)
    else:
        init = solve_robot_world_hand_eye(T_bf, T_ct, method=method, mount=mount, rotation_noise_deg=rot)
    names = ((f"T_flange_{b.camera}", f"T_base_{b.target}") if mount == "flange" else
             (f"T_base_{b.camera}", f"T_flange_{b.target}"))
    return Estimate(transforms={names[0]: np.asarray(init.T), names[1]: np.asarray(init.T_other)},
                    calibrated={names[0]: list(_ALL), names[1]: list(_ALL)}, num_stations=len(T_bf))


def _stated_camera(trial: Trial, cam: str, method: str):
    spec = trial.cell.cameras[cam]
    if spec.pose is None or _known_intrinsics(trial, cam) is None:
        raise BadInputError(f"the {method} closed form needs camera '{cam}''s pose and intrinsics: state them in the "
                            "cell (pose, intrinsics and fix), or hold them fixed / list the camera in the scenario's "
                            "given")
    from jcalib.geometry.cameras import camera_from_opencv

    K, dist = _known_intrinsics(trial, cam)
    return np.asarray(spec.pose, np.float64), camera_from_opencv(K, dist, trial.observations.cameras[cam],
                                                                 fisheye=spec.model == "fisheye")


def _tcp(method: str, scenario: Scenario, trial: Trial) -> Estimate:
    from jcalib.init import tcp_from_camera_ray, tcp_three_pose, viewing_ray_base

    wanted = ("tcp_three_pose",) if method == "three_pose" else ("tcp_three_pose", "tcp_random")
    rec = next((r for r in trial.records if r.block.strategy in wanted), None)
    if rec is None:
        raise BadInputError(f"the {method} closed form needs a {' or '.join(wanted)} station block")
    b = rec.block
    robot = holder(trial.cell, b.tool)
    kept = [i for i in rec.ids if i in set(trial.kept)]
    T_bf = _flange(trial, kept, robot)
    T_base_cam, model = _stated_camera(trial, b.camera, method)
    if method == "three_pose":
        if len(T_bf) != 3:
            raise NotObservableError(f"three_pose needs its 3 stations, {len(T_bf)} were detected",
                                     unknowns=["tip position"])
        res = tcp_three_pose(T_bf, T_base_cam[:3, :3])
    else:
        res = tcp_from_camera_ray(T_bf, viewing_ray_base(model, rec.goal_pixel, T_base_cam[:3, :3]))
    sig_t, sig_r = observation_noise(scenario).robot.get(robot, (np.zeros(3), np.zeros(3)))
    cov3 = res.covariance(math.hypot(float(np.max(sig_t)), rec.servo_sigma_m), math.radians(float(np.max(sig_r))))
    cov = np.zeros((6, 6))
    cov[3:, 3:] = cov3
    name = f"T_flange_{b.tool}"
    return Estimate(transforms={name: np.asarray(res.T_flange_tcp)}, calibrated={name: ["tx", "ty", "tz"]},
                    transform_covariance={name: cov}, tool_orientation={b.tool: "not calibrated"},
                    num_stations=len(T_bf))


def _pivot(scenario: Scenario, trial: Trial) -> Estimate:
    from jcalib.init import pivot_calibration

    pair = next(((c.tool, c.point) for s in trial.observations.stations for c in s.contacts), None)
    if pair is None:
        raise BadInputError("the pivot closed form needs stations with contacts (a pivot or explicit station block)")
    tool, point = pair
    kept = [s.id for s in trial.observations.stations if any((c.tool, c.point) == pair for c in s.contacts)]
    res = pivot_calibration(_flange(trial, kept, holder(trial.cell, tool)))
    name = f"T_flange_{tool}"
    T = np.eye(4)
    T[:3, 3] = res.p_flange_tip
    cov = np.zeros((6, 6))
    cov[3:, 3:] = res.covariance[:3, :3]
    return Estimate(transforms={name: T}, calibrated={name: ["tx", "ty", "tz"]}, transform_covariance={name: cov},
                    tool_orientation={tool: "not calibrated"}, points={point: np.asarray(res.p_base_pivot)},
                    point_covariance={point: np.asarray(res.covariance[3:, 3:])}, num_stations=len(kept))


def closed_form(name: str, scenario: Scenario, trial: Trial) -> Estimate:
    """Run the closed form ``name`` (a key of :data:`jcalib.study.scenario.CLOSED_FORMS`) on one trial."""
    if name in HANDEYE_CLOSED_FORMS or name in ROBOT_WORLD_CLOSED_FORMS:
        return _hand_eye(name, scenario, trial)
    if name in ("three_pose", "ray_lsq"):
        return _tcp(name, scenario, trial)
    if name == "pivot":
        return _pivot(scenario, trial)
    return _opencv(scenario, trial)
