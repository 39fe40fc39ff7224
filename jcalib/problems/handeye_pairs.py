"""Preset: hand-eye calibration from pose pairs only (no pixels): AX = YB, one loop per station.

For data that holds, per station, a robot flange pose and a sensor's pose of a target but no image
observations (AR markers, trackers, PnP results from another tool, e.g. the camodocal example). It is
a cell whose camera is a pose sensor: station ``i`` carries the 6-DOF measurement ``T_cam_target_i``,
solved by the one builder with the pose-measurement residual ``Log(T_meas⁻¹ · T_pred)`` split in a
rotation half (σ_rot, rad) and a translation half (σ_trans, m):

- ``mode="eye_in_hand"`` (camera on the flange, target fixed): ``X = T_flange_cam``, ``Y = T_base_target``;
- ``mode="eye_to_hand"`` (camera fixed, target on the flange): ``X = T_base_cam``, ``Y = T_flange_target``.

Noise: ``"a_posteriori"`` (default) estimates σ_rot and σ_trans by variance components (the two halves
are two residual kinds, :mod:`jcalib.problems.refine`); ``"stated"`` trusts the given σ, estimates the
components once and warns when they contradict the stated σ. After the solve the motion check is
repeated with the estimated rotation noise (rotations too small for the noise are named).

What the covariance includes: first-order propagation of the station pose noise described by σ_rot,
σ_trans (independent between stations and axes). What it does not: systematic robot errors, a target
pose estimator's bias, noise that is not isotropic per group.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2 as _chi2

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.se3 import log_se3
from jcalib.init.handeye import HAND_EYE_METHODS, HandEyeInit, solve_hand_eye
from jcalib.init.handeye_motion import (
    MotionDiagnostics,
    analyse_motion,
    check_observable,
    checked_stations,
)
from jcalib.init.robot_world import ROBOT_WORLD_METHODS, solve_robot_world_hand_eye
from jcalib.io.cell import CameraSpec, CellSpec, RobotSpec, TargetSpec
from jcalib.io.observations import Observations, PoseMeasurement, Station
from jcalib.problems.calibrate import calibrate_cell
from jcalib.problems.options import CalibrationOptions
from jcalib.problems.refine import MIN_VARIANCE_FACTOR

__all__ = ["MODES", "HandEyePairsCalibration", "PoseNoise", "calibrate_hand_eye_pairs"]

#: ``mode`` -> (jcalib mount of the camera, name of X, name of Y).
MODES: dict[str, tuple[str, str, str]] = {
    "eye_in_hand": ("flange", "T_flange_cam", "T_base_target"),
    "eye_to_hand": ("base", "T_base_cam", "T_flange_target"),
}

#: Per-station squared whitened residual above which a station is flagged (chi2(6), 0.999 quantile).
OUTLIER_CHI2 = float(_chi2.ppf(0.999, 6))
_SIGMA_FLOOR = 1e-12  # rad or m: noise estimates of exact (noise-free) data stop here


@dataclass(frozen=True)
class PoseNoise:
    """Station pose noise: σ per rotation axis (degrees) and per translation axis (m), where it came
    from (``"stated"`` / ``"estimated"``), the redundancy of each group and the iterations used."""

    rotation_deg: float
    translation_m: float
    source: str
    redundancy_rotation: float
    redundancy_translation: float
    iterations: int
    converged: bool


@dataclass
class HandEyePairsCalibration:
    """The outcome of :func:`calibrate_hand_eye_pairs`.

    Attributes:
        mode; hand_eye_name (X) and T_hand_eye, T_hand_eye_covariance (6, 6; right perturbation,
            rx..tz, rad², m²); other_name (Y), T_other, T_other_covariance.
        noise: :class:`PoseNoise` the covariance uses; estimated_noise: estimated from the residuals.
        station_residuals: ``(N, 6)`` ``Log(Y⁻¹ H_i X B_i)`` at the solution (rad, m) (``H_i`` the robot
            pose or its inverse, ``B_i`` the measurement); station_rotation_error_deg,
            station_translation_error_m: their sizes; station_chi2: whitened squared norms (≈ χ²(6)).
        outlier_stations: stations with ``station_chi2 > OUTLIER_CHI2``.
        init, motion, warnings, status, iterations, sigma2, num_stations, calibration, solution.
    """

    mode: str
    hand_eye_name: str
    T_hand_eye: np.ndarray
    T_hand_eye_covariance: np.ndarray
    other_name: str
    T_other: np.ndarray
    T_other_covariance: np.ndarray
    noise: PoseNoise
    estimated_noise: PoseNoise
    station_residuals: np.ndarray
    station_rotation_error_deg: np.ndarray
    station_translation_error_m: np.ndarray
    station_chi2: np.ndarray
    outlier_stations: list[int]
    init: HandEyeInit
    motion: MotionDiagnostics
    warnings: tuple[str, ...]
    status: str
    iterations: int
    sigma2: float
    num_stations: int
    calibration: object = field(default=None, repr=False)
    solution: object = field(default=None, repr=False)

    @property
    def T_hand_eye_std(self) -> np.ndarray:
        """``(6,)`` standard deviations of X (rad, rad, rad, m, m, m)."""
        return np.sqrt(np.diag(self.T_hand_eye_covariance))

    @property
    def T_other_std(self) -> np.ndarray:
        """``(6,)`` standard deviations of Y (rad, rad, rad, m, m, m)."""
        return np.sqrt(np.diag(self.T_other_covariance))


def _positive_or_none(value, name: str, unit: str):
    if value is None:
        return None
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise BadInputError(f"{name}: expected a positive number of {unit} or None, got {value!r}")
    return value


def _nearest_pose(T: np.ndarray) -> np.ndarray:
    """``T`` with its rotation block replaced by the nearest proper rotation (SVD, det +1)."""
    U, _, Vt = np.linalg.svd(T[:3, :3])
    out = np.array(T, np.float64)
    out[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return out


def _closed_form(T_bf, T_ct, mount: str, method: str, rotation_noise_deg: float) -> HandEyeInit:
    if method in ROBOT_WORLD_METHODS:
        return solve_robot_world_hand_eye(T_bf, T_ct, method=method, mount=mount, rotation_noise_deg=rotation_noise_deg)
    return solve_hand_eye(T_bf, T_ct, method=method, mount=mount, rotation_noise_deg=rotation_noise_deg)


def calibrate_hand_eye_pairs(
    T_base_flange,
    T_cam_target,
    *,
    mode: str = "eye_in_hand",
    rotation_sigma_deg: float | None = None,
    translation_sigma_m: float | None = None,
    noise: str = "a_posteriori",
    init_method: str = "park_martin",
    init: tuple[np.ndarray, np.ndarray] | None = None,
    max_iterations: int = 100,
) -> HandEyePairsCalibration:
    """Hand-eye (X) and target/camera (Y) poses from station pose pairs, with covariance.

    Args:
        T_base_flange: ``(N, 4, 4)`` measured flange poses in the robot base, m.
        T_cam_target: ``(N, 4, 4)`` measured target poses in the camera (``p_cam = T p_target``), m.
        mode: ``"eye_in_hand"`` or ``"eye_to_hand"`` (module docstring).
        rotation_sigma_deg, translation_sigma_m: stated σ of each rotation (degrees) and translation (m)
            component of a station's loop error; required with ``noise="stated"``, otherwise the start
            of the estimate (default: the closed form's loop-error RMS).
        noise: ``"a_posteriori"`` (default) or ``"stated"``.
        init_method: closed-form start, a key of :data:`jcalib.init.handeye.HAND_EYE_METHODS` or of
            :data:`jcalib.init.robot_world.ROBOT_WORLD_METHODS`.
        init: optional ``(X, Y)`` (4, 4) start values replacing the closed form's.
        max_iterations: LM iterations per solve.

    Raises:
        BadInputError: malformed poses, mismatched counts, unknown mode / method / noise, missing σ.
        NotObservableError: degenerate motion (before solving with the stated noise, after with the
            estimated one) or a rank-deficient problem, naming what is undetermined.
    """
    if mode not in MODES:
        raise BadInputError(f"mode: expected 'eye_in_hand' or 'eye_to_hand', got {mode!r}")
    if noise not in ("a_posteriori", "stated"):
        raise BadInputError(f"noise: expected 'a_posteriori' or 'stated', got {noise!r}")
    if init_method not in HAND_EYE_METHODS and init_method not in ROBOT_WORLD_METHODS:
        raise BadInputError(f"init_method: expected one of {sorted(HAND_EYE_METHODS) + sorted(ROBOT_WORLD_METHODS)}, "
                            f"got {init_method!r}")
    sig_r_deg = _positive_or_none(rotation_sigma_deg, "rotation_sigma_deg", "degrees")
    sig_t = _positive_or_none(translation_sigma_m, "translation_sigma_m", "metres")
    if noise == "stated" and (sig_r_deg is None or sig_t is None):
        raise BadInputError(f"noise='stated' needs rotation_sigma_deg and translation_sigma_m, got "
                            f"{rotation_sigma_deg!r} and {translation_sigma_m!r}")
    if int(max_iterations) < 1:
        raise BadInputError(f"max_iterations: expected >= 1, got {max_iterations}")
    mount, x_name, y_name = MODES[mode]
    check_noise_deg = sig_r_deg if sig_r_deg is not None else 0.02
    T_bf, T_ct, _ = checked_stations(T_base_flange, T_cam_target, mount, "all", check_noise_deg)
    start = _closed_form(T_bf, T_ct, mount, init_method, check_noise_deg)
    if init is not None:
        X0, Y0 = (np.asarray(T, np.float64) for T in init)
        for name, T in (("init[0] (X)", X0), ("init[1] (Y)", Y0)):
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise BadInputError(f"{name}: expected a finite 4x4 pose, got shape {T.shape}")
    else:  # a closed form on nearly degenerate motion can return a reflection: start from the nearest rotation
        X0, Y0 = _nearest_pose(start.T), _nearest_pose(start.T_other)
    H = T_bf if mount == "flange" else np.linalg.inv(T_bf)
    n = len(T_bf)

    def loops(X, Y):
        return log_se3(np.linalg.inv(Y) @ H @ X @ T_ct)

    r0 = loops(X0, Y0)
    sig_r = np.radians(sig_r_deg) if sig_r_deg is not None else max(float(np.sqrt(np.mean(r0[:, :3] ** 2))),
                                                                   _SIGMA_FLOOR)
    sig_tr = sig_t if sig_t is not None else max(float(np.sqrt(np.mean(r0[:, 3:] ** 2))), _SIGMA_FLOOR)
    target_mount = "base" if mount == "flange" else "flange"
    cell = CellSpec(cameras={"cam": CameraSpec("cam", "pinhole", mount)},
                    targets={"target": TargetSpec("target", "points", target_mount, {})}, robot=RobotSpec(),
                    source="calibrate_hand_eye_pairs")
    obs = Observations(cameras={"cam": (1, 1)}, targets={}, stations=tuple(
        Station(id=f"s{i:03d}", T_base_flange=T_bf[i], poses=(PoseMeasurement("cam", "target", T_ct[i]),))
        for i in range(n)), source="calibrate_hand_eye_pairs")
    options = CalibrationOptions(pose_sigma_deg=float(np.degrees(sig_r)), pose_sigma_m=float(sig_tr), noise=noise,
                                 outlier_threshold=None, max_iterations=int(max_iterations))
    cal = calibrate_cell(cell, obs, options, known={x_name: X0, y_name: Y0})
    X, Y = cal.transforms[x_name], cal.transforms[y_name]
    T_cov, Y_cov = cal.transform_covariance[x_name], cal.transform_covariance[y_name]
    r = loops(X, Y)
    sol = cal.solution
    warnings: list[str] = list(cal.warnings)
    if noise == "a_posteriori":
        comp = cal.variance_components
        red = [float(sol.count[g] - sol.hat[g]) for g in ("pose_rotation:cam/target", "pose_translation:cam/target")]
        est_r = max(float(np.sqrt(comp.get("pose_rotation", 1.0))) * sig_r, _SIGMA_FLOOR)
        est_t = max(float(np.sqrt(comp.get("pose_translation", 1.0))) * sig_tr, _SIGMA_FLOOR)
        est = used = PoseNoise(float(np.degrees(est_r)), float(est_t), "estimated", red[0], red[1], cal.iterations,
                               cal.status == "converged")
        floored = [k for k in ("pose_rotation", "pose_translation")
                   if comp.get(k, 1.0) <= 1.01 * MIN_VARIANCE_FACTOR]
        if est_r <= _SIGMA_FLOOR or est_t <= _SIGMA_FLOOR or floored:
            warnings.append("the stations fit exactly (noise-free data?): the noise estimate sits at its floor "
                            f"(variance factor {MIN_VARIANCE_FACTOR:g} of the stated σ², or σ = {_SIGMA_FLOOR:g})")
    else:
        # one estimate at the stated weights: each half's χ² over its share of the 6N − 12 redundancy
        red = [3.0 * n - 6.0, 3.0 * n - 6.0]
        est = PoseNoise(float(np.degrees(np.sqrt(np.sum(r[:, :3] ** 2) / red[0]))),
                        float(np.sqrt(np.sum(r[:, 3:] ** 2) / red[1])), "estimated", red[0], red[1], 1, True)
        used = PoseNoise(float(sig_r_deg), float(sig_t), "stated", red[0], red[1], 1, True)
        dof = 6 * n - 12
        chi2_stated = float(np.sum((r[:, :3] / np.radians(sig_r_deg)) ** 2) + np.sum((r[:, 3:] / sig_t) ** 2))
        lo, hi = _chi2.ppf(0.0005, dof), _chi2.ppf(0.9995, dof)
        if not lo <= chi2_stated <= hi:
            warnings.append(
                f"the residuals contradict the stated noise (variance factor {chi2_stated / dof:.3g}, outside "
                f"[{lo / dof:.3g}, {hi / dof:.3g}] at 99.9 %): estimated σ {est.rotation_deg:.3g} deg / "
                f"{est.translation_m:.3g} m vs stated {sig_r_deg:.3g} deg / {sig_t:.3g} m")
    motion = analyse_motion(T_bf, frame=mount, pairs="all", rotation_noise_deg=used.rotation_deg)
    check_observable(motion, x_name)
    warnings.extend(w for w in motion.warnings if w not in warnings)
    sigmas = np.array([np.radians(used.rotation_deg)] * 3 + [used.translation_m] * 3)
    station_chi2 = np.sum((r / sigmas[None, :]) ** 2, axis=1)
    outliers = [int(i) for i in np.flatnonzero(station_chi2 > OUTLIER_CHI2)]
    if outliers:
        warnings.append(f"stations {outliers} have loop errors beyond the 99.9 % bound of the noise model (chi2(6) > "
                        f"{OUTLIER_CHI2:.1f}): check them for wrong detections or robot poses")
    if not (np.all(np.isfinite(T_cov)) and np.all(np.isfinite(Y_cov))):
        raise NotObservableError(f"the covariance of {x_name} / {y_name} is not finite: the stations do not "
                                 "determine them", [x_name, y_name])
    return HandEyePairsCalibration(
        mode=mode, hand_eye_name=x_name, T_hand_eye=X, T_hand_eye_covariance=T_cov, other_name=y_name, T_other=Y,
        T_other_covariance=Y_cov, noise=used, estimated_noise=est, station_residuals=r,
        station_rotation_error_deg=np.degrees(np.linalg.norm(r[:, :3], axis=1)),
        station_translation_error_m=np.linalg.norm(r[:, 3:], axis=1), station_chi2=station_chi2,
        outlier_stations=outliers, init=start, motion=motion, warnings=tuple(warnings), status=cal.status.upper(),
        iterations=cal.iterations, sigma2=float(cal.sigma2), num_stations=n, calibration=cal, solution=sol)
