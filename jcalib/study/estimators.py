"""Estimators of a study and the table rows they produce (one row per trial and estimator).

Columns (:func:`columns`): ``trial``, ``estimator``, ``status`` (``ok``, ``not_observable: ...``,
``bad_input: ...``, ``error: ...``), ``num_stations`` (stations used after dropouts), ``runtime_s``
(wall time of the estimator alone: simulation and the PnP poses the closed forms share are not
counted; in a vmapped batch, the batch time divided by its size; the first call of a process
includes JAX's compilation), then per cell:

- ``handeye`` (unknown ``T_flange_cam``): ``err_rot_deg`` (rotation angle), ``err_trans_mm`` (distance),
  ``err_r{x,y,z}_deg`` and ``err_t{x,y,z}_mm``: the tangent error ``δ = Log(T_est⁻¹ · T_true)`` (right
  perturbation, camera frame; the tangent of the reported covariance), ``sigma_*`` the reported
  standard deviation of each component (NaN for closed forms, which report none), ``nees`` =
  ``δᵀ Σ⁻¹ δ`` (χ²(6) when the covariance is honest).
- ``tcp`` (unknown ``p_flange_tip``): ``err_{x,y,z}_mm`` (estimate − truth, flange frame),
  ``err_norm_mm``, ``sigma_{x,y,z}_mm`` from the method's error amplification with the stated robot
  noise plus the servo residual (taken isotropic), ``nees`` (χ²(3)).
- ``camera``: ``err_<param>`` (estimate − truth; ``_px`` for fx, fy, cx, cy; distortion unitless),
  ``sigma_<param>`` (reported), ``rms_px``, ``nees`` over the intrinsics (χ²(p)).

Failures are rows too (status says why, numbers NaN): a study counts how often a strategy fails.

The camera and hand-eye joint estimators solve a batch's trials together (vmapped, padded to the
batch's largest shape), so their numbers depend on the batch composition at solver tolerance only
(~1e-5 of their σ): the same ``batch_size`` gives bit-identical tables on every backend.
"""

from __future__ import annotations

import math
import time

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.study.scenario import HANDEYE_CLOSED_FORMS, Scenario
from jcalib.study.simulate import (
    CameraTrial,
    HandEyeTrial,
    TCPTrial,
    camera_model,
    simulate_trial,
)

__all__ = ["columns", "run_trials"]

COMMON = ["trial", "estimator", "status", "num_stations", "runtime_s"]
_HE_AXES = ["rx_deg", "ry_deg", "rz_deg", "tx_mm", "ty_mm", "tz_mm"]
_TCP_AXES = ["x_mm", "y_mm", "z_mm"]
_PX = {"fx", "fy", "cx", "cy"}


def _param_cols(scenario: Scenario) -> list[str]:
    return [f"{p}_px" if p in _PX else p for p in camera_model(scenario).param_names]


def columns(scenario: Scenario) -> list[str]:
    """The table's columns, in order, for this scenario's cell."""
    if scenario.cell == "handeye":
        extra = ["err_rot_deg", "err_trans_mm", *(f"err_{a}" for a in _HE_AXES), *(f"sigma_{a}" for a in _HE_AXES),
                 "nees"]
    elif scenario.cell == "tcp":
        extra = [*(f"err_{a}" for a in _TCP_AXES), "err_norm_mm", *(f"sigma_{a}" for a in _TCP_AXES), "nees"]
    else:
        p = _param_cols(scenario)
        extra = [*(f"err_{c}" for c in p), *(f"sigma_{c}" for c in p), "rms_px", "nees"]
    return COMMON + extra


def _row(scenario: Scenario, trial: int, estimator: str, num_stations: int) -> dict:
    row = dict.fromkeys(columns(scenario), math.nan)
    row.update(trial=int(trial), estimator=estimator, status="ok", num_stations=int(num_stations))
    return row


def _status(err: Exception) -> str:
    kind = ("not_observable" if isinstance(err, NotObservableError) else
            "bad_input" if isinstance(err, BadInputError) else f"error ({type(err).__name__})")
    return f"{kind}: {' '.join(str(err).split())}"


def _nees(delta: np.ndarray, cov: np.ndarray) -> float:
    try:
        return float(delta @ np.linalg.solve(cov, delta))
    except np.linalg.LinAlgError:
        return math.nan


# ------------------------------------------------------------------------------------ hand-eye


def _se3_local(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """``Log(T_est⁻¹ · T_true)`` (6,) = (rx, ry, rz, tx, ty, tz), rad and m: the engine's tangent."""
    from jcalib.geometry import lie

    a, b = lie._se3_from_matrix(T_est, np), lie._se3_from_matrix(T_true, np)
    return np.asarray(lie._se3_log(lie._se3_compose(lie._se3_inverse(a, np), b, np), np), dtype=np.float64)


def _handeye_errors(row: dict, T_est: np.ndarray, T_true: np.ndarray, cov: np.ndarray | None) -> None:
    delta = _se3_local(T_est, T_true)
    scale = np.array([180.0 / np.pi] * 3 + [1e3] * 3)  # rad -> deg, m -> mm
    row["err_rot_deg"] = float(np.degrees(np.linalg.norm(delta[:3])))  # the rotation angle, exact near 0
    row["err_trans_mm"] = float(1e3 * np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))
    for a, v in zip(_HE_AXES, delta * scale):
        row[f"err_{a}"] = float(v)
    if cov is not None:
        for a, v in zip(_HE_AXES, np.sqrt(np.diag(cov)) * scale):
            row[f"sigma_{a}"] = float(v)
        row["nees"] = _nees(delta, cov)


def _handeye_cell(scenario: Scenario, pose_model: bool) -> dict:
    cam = {"model": scenario.camera["model"], "mount": "flange"}
    if scenario.intrinsics == "known":
        K, dist = (np.asarray(a) for a in camera_model(scenario).to_opencv())
        cam.update(fix=list(camera_model(scenario).param_names),
                   intrinsics={"K": K.tolist(), "dist": dist.tolist()})
    t = scenario.target
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": cam},
            "targets": {"board": {"type": "checkerboard", "cols": t["cols"], "rows": t["rows"],
                                  "square": t["square"], "mount": "base"}}}
    if pose_model:
        n = scenario.noise
        cell["robot"] = {"pose_noise": {"translation_m": n.robot_translation_m, "rotation_deg": n.robot_rotation_deg}}
    return cell


def _handeye_obs(scenario: Scenario, d: HandEyeTrial) -> dict:
    stations = [{"id": f"s{i:03d}", "T_base_flange": T.tolist(),
                 "detections": [{"camera": "cam0", "target": "board", "point_index": idx.tolist(),
                                 "pixels": pix.tolist()}]}
                for i, (T, idx, pix) in enumerate(zip(d.T_base_flange, d.point_index, d.pixels))]
    return {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(scenario.camera["image_size"])}},
            "targets": {"board": {"points": d.points.tolist()}}, "stations": stations}


def _pnp_poses(d: HandEyeTrial, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    import cv2

    out = []
    for idx, pix in zip(d.point_index, d.pixels):
        ok, r, t = cv2.solvePnP(d.points[idx], np.asarray(pix, np.float64), K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise NotObservableError("cv2.solvePnP failed on a station", unknowns=["T_cam_target"])
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = cv2.Rodrigues(r)[0], t.ravel()
        out.append(T)
    return np.array(out)


def _opencv_intrinsics(scenario: Scenario, d) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``cv2.calibrateCameraExtended`` on the trial's views: (K, dist, std of the intrinsics, rms px)."""
    import cv2

    model = scenario.camera["model"]
    flags = {"opencv4": cv2.CALIB_FIX_K3, "opencv5": 0, "opencv8": cv2.CALIB_RATIONAL_MODEL,
             "pinhole": cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST}
    if model not in flags:
        raise BadInputError(f"scenario.camera.model: got {model!r}, the opencv estimator supports {sorted(flags)}")
    obj = [d.points[idx].astype(np.float32) for idx in d.point_index]
    img = [np.asarray(p, np.float32) for p in d.pixels]
    if len(obj) < 3:
        raise NotObservableError(f"only {len(obj)} views left after dropouts", unknowns=["intrinsics"])
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, _, _, std, _, _ = cv2.calibrateCameraExtended(
        obj, img, tuple(scenario.camera["image_size"]), None, None, flags=flags[model], criteria=crit)
    return K, dist.ravel(), std.ravel(), float(rms)


def _handeye_joint_rows(scenario: Scenario, est: str, trials: list[int], data: list[HandEyeTrial]) -> list[dict]:
    """Rows of joint estimator ``est`` for a batch of trials: one :func:`calibrate_hand_eye_batch`
    call (vmapped solves); ``runtime_s`` of each row is the call's time divided by the batch size."""
    from jcalib.io.cell import load_cell
    from jcalib.io.observations import load_observations
    from jcalib.problems.handeye import (
        HandEyeOptions,
        calibrate_hand_eye,
        calibrate_hand_eye_batch,
    )

    pose_model = est == "joint_pose_model"
    rows = [_row(scenario, k, est, len(d.T_base_flange)) for k, d in zip(trials, data)]
    obs, where = [], []
    try:
        cell = load_cell(_handeye_cell(scenario, pose_model))
        options = HandEyeOptions(sigma_px=max(scenario.noise.pixel_sigma_px, 1e-3), pose_model=pose_model)
    except Exception as err:  # noqa: BLE001  (a failed trial is a row, not a crash)
        for row in rows:
            row["status"] = _status(err)
        return rows
    for j, d in enumerate(data):
        try:
            obs.append(load_observations(_handeye_obs(scenario, d)))
            where.append(j)
        except Exception as err:  # noqa: BLE001
            rows[j]["status"] = _status(err)
    if not obs:
        return rows
    t0 = time.perf_counter()
    try:
        results = calibrate_hand_eye_batch(cell, obs, options, raise_errors=False)
    except Exception:  # noqa: BLE001  (the batched solve itself failed: find the trials one by one)
        results = []
        for o in obs:
            try:
                results.append(calibrate_hand_eye(cell, o, options))
            except Exception as err:  # noqa: BLE001
                results.append(err)
    dt = (time.perf_counter() - t0) / len(obs)
    for j, res in zip(where, results):
        rows[j]["runtime_s"] = dt
        if isinstance(res, Exception):
            rows[j]["status"] = _status(res)
            continue
        _handeye_errors(rows[j], np.asarray(res.T_hand_eye), data[j].T_flange_cam, np.asarray(res.T_hand_eye_covariance))
    return rows


def _handeye_rows(scenario: Scenario, trials: list[int], data: list[HandEyeTrial]) -> list[list[dict]]:
    """Rows of a batch of hand-eye trials, per trial in estimator order: the closed forms trial by
    trial (on PnP poses they share), each joint estimator once over the whole batch."""
    from jcalib.init.handeye import solve_hand_eye

    joint = {est: _handeye_joint_rows(scenario, est, trials, data)
             for est in scenario.estimators if est not in HANDEYE_CLOSED_FORMS}
    rot_noise = max(0.02, scenario.noise.robot_rotation_deg)
    closed = [e for e in scenario.estimators if e in HANDEYE_CLOSED_FORMS]
    out = []
    for j, (trial, d) in enumerate(zip(trials, data)):
        n = len(d.T_base_flange)
        rows = []
        T_ct, pnp_error = None, None
        if closed:
            try:
                if scenario.intrinsics == "known":
                    K, dist = (np.asarray(a, np.float64) for a in camera_model(scenario).to_opencv())
                else:
                    K, dist, _, _ = _opencv_intrinsics(scenario, d)
                T_ct = _pnp_poses(d, K, dist)
            except Exception as err:  # noqa: BLE001  (a failed trial is a row, not a crash)
                pnp_error = err
        for est in scenario.estimators:
            if est in joint:
                rows.append(joint[est][j])
                continue
            row = _row(scenario, trial, est, n)
            t0 = time.perf_counter()
            try:
                if pnp_error is not None:
                    raise pnp_error
                init = solve_hand_eye(d.T_base_flange, T_ct, method=est, mount="flange", rotation_noise_deg=rot_noise)
                row["runtime_s"] = time.perf_counter() - t0
                _handeye_errors(row, init.T, d.T_flange_cam, None)
            except Exception as err:  # noqa: BLE001
                row["status"] = _status(err)
                row["runtime_s"] = time.perf_counter() - t0
            rows.append(row)
        out.append(rows)
    return out


# ------------------------------------------------------------------------------------ TCP


def _tcp_rows(scenario: Scenario, trial: int, d: TCPTrial) -> list[dict]:
    from jcalib.init.tcp_analytic import tcp_from_camera_ray, tcp_three_pose

    n = scenario.noise
    sigma_t = math.hypot(n.robot_translation_m, d.servo_sigma_m)
    rows = []
    for est in scenario.estimators:
        row = _row(scenario, trial, est, len(d.T_base_flange))
        t0 = time.perf_counter()
        try:
            if est == "three_pose":
                res = tcp_three_pose(d.T_base_flange, d.R_base_cam)
            else:
                res = tcp_from_camera_ray(d.T_base_flange, d.ray_base)
            row["runtime_s"] = time.perf_counter() - t0
            err = np.asarray(res.p_flange_tip) - d.p_flange_tip
            cov = res.covariance(sigma_t, math.radians(n.robot_rotation_deg))
            for a, e, s in zip(_TCP_AXES, 1e3 * err, 1e3 * np.sqrt(np.diag(cov))):
                row[f"err_{a}"], row[f"sigma_{a}"] = float(e), float(s)
            row["err_norm_mm"] = float(1e3 * np.linalg.norm(err))
            row["nees"] = _nees(err, cov)
        except Exception as e:  # noqa: BLE001
            row["status"] = _status(e)
            row["runtime_s"] = time.perf_counter() - t0
        rows.append(row)
    return rows


# ------------------------------------------------------------------------------------ camera


def _camera_obs(scenario: Scenario, d: CameraTrial):
    from jcalib.io.observations import parse_observations

    stations = [{"id": f"v{i:03d}", "detections": [{"camera": "cam0", "target": "board",
                                                   "point_index": idx.tolist(), "pixels": pix.tolist()}]}
                for i, (idx, pix) in enumerate(zip(d.point_index, d.pixels))]
    return parse_observations({
        "schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(scenario.camera["image_size"])}},
        "targets": {"board": {"points": d.points.tolist()}}, "stations": stations})


def _camera_errors(scenario: Scenario, row: dict, est: np.ndarray, cov_or_std: np.ndarray, is_cov: bool) -> None:
    truth = np.asarray(scenario.camera["params"], np.float64)
    err = est - truth
    std = np.sqrt(np.diag(cov_or_std)) if is_cov else cov_or_std
    for c, e, s in zip(_param_cols(scenario), err, std):
        row[f"err_{c}"], row[f"sigma_{c}"] = float(e), float(s)
    cov = cov_or_std if is_cov else np.diag(std**2)
    row["nees"] = _nees(err, cov)


def _camera_rows(scenario: Scenario, trials: list[int], data: list[CameraTrial]) -> list[list[dict]]:
    out: list[list[dict]] = [[] for _ in trials]
    for est in scenario.estimators:
        if est == "joint":
            from jcalib.io.cell import parse_cell
            from jcalib.problems.camera import (
                CameraCalibrationOptions,
                calibrate_cameras_batch,
            )

            t = scenario.target
            cell = parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": scenario.camera["model"]}},
                               "targets": {"board": {"type": "checkerboard", "cols": t["cols"], "rows": t["rows"],
                                                     "square": t["square"]}}})
            rows = [_row(scenario, k, est, len(d.pixels)) for k, d in zip(trials, data)]
            obs, where = [], []
            for j, d in enumerate(data):
                try:
                    obs.append(_camera_obs(scenario, d))
                    where.append(j)
                except Exception as e:  # noqa: BLE001
                    rows[j]["status"] = _status(e)
            t0 = time.perf_counter()
            results = calibrate_cameras_batch(cell, obs, CameraCalibrationOptions(
                sigma_px=max(scenario.noise.pixel_sigma_px, 1e-3)), raise_errors=False) if obs else []
            dt = (time.perf_counter() - t0) / max(len(obs), 1)
            for j, res in zip(where, results):
                rows[j]["runtime_s"] = dt
                if isinstance(res, Exception):
                    rows[j]["status"] = _status(res)
                    continue
                _camera_errors(scenario, rows[j], np.asarray(res.cameras["cam0"].params, np.float64),
                               np.asarray(res.intrinsics_covariance["cam0"]), True)
                rows[j]["rms_px"] = float(res.rms_px)
        else:
            rows = []
            for k, d in zip(trials, data):
                row = _row(scenario, k, est, len(d.pixels))
                t0 = time.perf_counter()
                try:
                    K, dist, std, rms = _opencv_intrinsics(scenario, d)
                    row["runtime_s"] = time.perf_counter() - t0
                    p = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dist])
                    n = len(scenario.camera["params"])
                    _camera_errors(scenario, row, p[:n], std[:n], False)
                    row["rms_px"] = rms
                except Exception as e:  # noqa: BLE001
                    row["status"] = _status(e)
                    row["runtime_s"] = time.perf_counter() - t0
                rows.append(row)
        for j, r in enumerate(rows):
            out[j].append(r)
    return out


# ------------------------------------------------------------------------------------ batches


def run_trials(scenario: Scenario, seed: int, trials: list[int]) -> list[dict]:
    """Simulate and estimate the given trials (one batch); rows ordered by trial, then estimator.

    Camera cells solve the batch's trials with one vmapped call (``calibrate_cameras_batch``), the
    hand-eye joint estimators with one ``calibrate_hand_eye_batch`` call each; the closed forms and
    the TCP estimators loop over the trials.
    """
    trials = [int(k) for k in trials]
    data = [simulate_trial(scenario, seed, k) for k in trials]
    if scenario.cell == "camera":
        per_trial = _camera_rows(scenario, trials, data)
    elif scenario.cell == "handeye":
        per_trial = _handeye_rows(scenario, trials, data)
    else:
        per_trial = [_tcp_rows(scenario, k, d) for k, d in zip(trials, data)]
    return [r for rows in per_trial for r in rows]
