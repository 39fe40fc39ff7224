"""Hand-eye calibration from pose pairs only (no pixels): AX = YB on SE(3), one loop per station.

For data that holds, per station, a robot flange pose and a camera's pose of a target but no image
observations (AR markers, trackers, PnP results from another tool, e.g. the camodocal example in
``../shared/data/real/handeye_camodocal_example``). Both unknowns are estimated jointly:

- ``mode="eye_in_hand"`` (camera on the flange, target fixed): ``X = T_flange_cam``,
  ``Y = T_base_target``; station ``i`` closes the loop ``T_base_flange_i · X · T_cam_target_i = Y``.
- ``mode="eye_to_hand"`` (camera fixed, target on the flange): ``X = T_base_cam``,
  ``Y = T_flange_target``; the loop is ``T_base_flange_i⁻¹ · X · T_cam_target_i = Y``.

Both are ``H_i X B_i = Y`` with ``H_i`` the robot pose (or its inverse) and ``B_i`` the camera's
measurement, and the residual of station ``i`` is the SE(3) logarithm of the loop error

    r_i = Log(Y⁻¹ · H_i · X · B_i)  = (rx, ry, rz, tx, ty, tz)   (rad, m; in the target frame)

which is zero for exact data. To first order ``r_i`` is the error of the measured ``T_cam_target_i``
as a right perturbation ``T_cam_target_i = T_true · Exp(r_i)``: all errors of the station (camera
pose estimate and robot pose) folded into one pose error seen at the target. Its rotation components
get one standard deviation ``σ_rot`` (rad) and its translation components another, ``σ_trans`` (m).

Noise (``noise=``):

- ``"a_posteriori"`` (default): ``σ_rot`` and ``σ_trans`` are *estimated* from the data by variance
  component estimation (Förstner / Helmert: ``σ_k² ← σ_k² · Ω_k / r_k`` with ``Ω_k`` the weighted
  squared residuals of group ``k`` and ``r_k`` its redundancy, ``r_k = m_k − tr(J_k N⁻¹ J_kᵀ)``),
  re-solving until both ratios are 1. The stated σ (if any) only start the iteration. The
  covariance is then the inverse information with the estimated σ (variance factor 1).
- ``"stated"``: ``σ_rot``, ``σ_trans`` as given, the covariance scaled by nothing. The variance
  components are still estimated and reported, and a warning says when they contradict the stated σ.

The unknowns start from a closed form (:func:`jcalib.init.handeye.solve_hand_eye` or
:func:`jcalib.init.robot_world.solve_robot_world_hand_eye`), after the motion observability checks of
:mod:`jcalib.init.handeye` (too few stations, pure translations, one rotation axis, planar motion);
after the solve the check is repeated with the *estimated* rotation noise (rotations too small for
the noise), and the engine's rank analysis runs at the solution. Each raises
:class:`jcalib.errors.NotObservableError` naming the undetermined unknowns.

What the covariance includes: first-order propagation of the station pose noise described by
``σ_rot``, ``σ_trans`` (independent between stations and axes). What it does not: systematic robot
errors (kinematic model), a target pose estimator's bias, or noise that is not isotropic per group
(robot rotation noise seen at the target through a lever arm is lumped into ``σ_trans``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import chi2 as _chi2

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import lie
from jcalib.init.handeye import (
    HAND_EYE_METHODS,
    HandEyeInit,
    MotionDiagnostics,
    analyse_motion,
    check_observable,
    checked_stations,
    solve_hand_eye,
)
from jcalib.init.robot_world import ROBOT_WORLD_METHODS, solve_robot_world_hand_eye
from jcalib.solve import (
    SE3,
    FactorGroup,
    Problem,
    SolveOptions,
    Status,
    Variable,
    solve,
)

__all__ = [
    "MODES",
    "HandEyePairsCalibration",
    "PoseNoise",
    "calibrate_hand_eye_pairs",
]

#: ``mode`` -> (jcalib mount of the camera, name of X, name of Y).
MODES: dict[str, tuple[str, str, str]] = {
    "eye_in_hand": ("flange", "T_flange_cam", "T_base_target"),
    "eye_to_hand": ("base", "T_base_cam", "T_flange_target"),
}

#: Per-station squared whitened residual above which a station is flagged (chi2(6), 0.999 quantile).
OUTLIER_CHI2 = float(_chi2.ppf(0.999, 6))
_SIGMA_FLOOR = 1e-12  # rad or m: noise estimates of exact (noise-free) data stop here
_VCE_RTOL = 1e-6


# ------------------------------------------------------------------------------------ residuals


def _loop_error(X, Y, obs):
    """``Log(Y⁻¹ · H · X · B)`` (6,) rad, m for one station; ``obs = (H (7,), B (7,))`` poses ``wxyz_xyz``."""
    H, B = obs
    E = lie.se3_compose(lie.se3_inverse(Y), lie.se3_compose(H, lie.se3_compose(X, B)))
    return lie.se3_log(E)


def _whitened_loop_error(X, Y, obs):
    """The engine's residual: :func:`_loop_error` divided by its σ per component (whitened, (6,)).

    ``obs = (H (7,), B (7,), inv_sigma (6,))``: the two σ travel as data (not as the factor group's
    scalar σ), so one factor group and one compiled solver serve every noise level and both modes.
    """
    H, B, inv_sigma = obs
    return _loop_error(X, Y, (H, B)) * inv_sigma


@jax.jit
def _residuals_and_jacobian(X, Y, H, B):
    """Loop errors ``(N, 6)`` and their Jacobian ``(N, 6, 12)`` w.r.t. the right tangents of X, Y."""

    def all_errors(delta):
        Xp = lie.retract(X, delta[:6])
        Yp = lie.retract(Y, delta[6:])
        return jax.vmap(lambda h, b: _loop_error(Xp, Yp, (h, b)))(H, B)

    zero = jnp.zeros((12,), jnp.float64)
    return all_errors(zero), jax.jacfwd(all_errors)(zero)


# ------------------------------------------------------------------------------------ results


@dataclass(frozen=True)
class PoseNoise:
    """The per-station pose noise of the loop residuals (1σ per axis).

    Attributes:
        rotation_deg: σ of each rotation component of the loop error, degrees.
        translation_m: σ of each translation component, metres.
        source: ``"estimated"`` (variance components from the residuals) or ``"stated"``.
        redundancy_rotation, redundancy_translation: redundancy numbers ``r_k`` of the two groups
            (they sum to ``6 N − 12``).
        iterations: variance-component iterations (re-solves) used.
        converged: both variance ratios reached 1 within 1e-6.
    """

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
        mode: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        hand_eye_name: ``"T_flange_cam"`` or ``"T_base_cam"`` (X).
        T_hand_eye: (4, 4) X, m.
        T_hand_eye_covariance: (6, 6) covariance of X, right perturbation ``X · Exp(δ)``,
            ``(rx, ry, rz, tx, ty, tz)``, rad² and m² (tangent in X's child frame: cam).
        other_name: ``"T_base_target"`` or ``"T_flange_target"`` (Y).
        T_other: (4, 4) Y, m.
        T_other_covariance: (6, 6) covariance of Y, as above (tangent in the target frame).
        noise: :class:`PoseNoise` used for the covariance (estimated unless ``noise="stated"``).
        estimated_noise: :class:`PoseNoise` estimated from the residuals (equals ``noise`` in the
            default mode; in ``"stated"`` mode the variance-component estimate for comparison).
        station_residuals: (N, 6) loop errors ``Log(Y⁻¹ H_i X B_i)`` at the solution (rad, m).
        station_rotation_error_deg: (N,) rotation angle of each loop error, degrees.
        station_translation_error_m: (N,) length of its translation part, m.
        station_chi2: (N,) squared whitened residual of each station (≈ chi2(6) under the model).
        outlier_stations: indices of stations with ``station_chi2 > OUTLIER_CHI2``.
        init: the closed-form start (:class:`jcalib.init.handeye.HandEyeInit`).
        motion: motion analysis with the final rotation noise (:class:`MotionDiagnostics`).
        warnings: what the user should know (weak motion, outliers, stated noise contradicted...).
        status: solver status name of the last solve; iterations: LM iterations summed over solves.
        sigma2: variance factor of the last solve with the noise used (1 after estimation).
        num_stations: N.
        solution: the :class:`jcalib.solve.Solution` of the last solve.
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
    solution: object = field(default=None, repr=False)

    @property
    def T_hand_eye_std(self) -> np.ndarray:
        """(6,) standard deviations of X: ``(rx, ry, rz)`` rad, ``(tx, ty, tz)`` m."""
        return np.sqrt(np.diag(self.T_hand_eye_covariance))

    @property
    def T_other_std(self) -> np.ndarray:
        """(6,) standard deviations of Y: ``(rx, ry, rz)`` rad, ``(tx, ty, tz)`` m."""
        return np.sqrt(np.diag(self.T_other_covariance))


# ------------------------------------------------------------------------------------ helpers


def _positive_or_none(value, name: str, unit: str):
    if value is None:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise BadInputError(f"{name}: expected a positive number of {unit}, got {value!r}") from None
    if not np.isfinite(v) or v <= 0.0:
        raise BadInputError(f"{name}: expected a positive number of {unit}, got {value!r}")
    return v


def _closed_form(T_bf, T_ct, mount: str, method: str, rotation_noise_deg: float) -> HandEyeInit:
    if method in HAND_EYE_METHODS:
        return solve_hand_eye(T_bf, T_ct, method=method, mount=mount, rotation_noise_deg=rotation_noise_deg)
    return solve_robot_world_hand_eye(T_bf, T_ct, method=method, mount=mount, rotation_noise_deg=rotation_noise_deg)


def _variance_components(X, Y, H, B, sigma_rot: float, sigma_trans: float):
    """Loop errors ``r (N, 6)``, and per group (rotation, translation) ``Ω_k`` (weighted squared
    residuals) and the redundancy ``r_k = m_k − tr(J_k N⁻¹ J_kᵀ)`` (whitened Jacobians, ``N = JᵀJ``)."""
    r, J = _residuals_and_jacobian(jnp.asarray(X), jnp.asarray(Y), jnp.asarray(H), jnp.asarray(B))
    r = np.asarray(r)
    J = np.asarray(J)
    w = np.array([1.0 / sigma_rot] * 3 + [1.0 / sigma_trans] * 3)
    Jw = J * w[None, :, None]  # (N, 6, 12)
    info = np.einsum("nia,nib->ab", Jw, Jw)
    try:
        info_inv = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        raise NotObservableError(
            "the information matrix of the hand-eye pose pair problem is singular: the stations do not "
            "determine both transforms",
            ["X", "Y"],
        ) from None
    hat = np.einsum("nia,ab,nib->ni", Jw, info_inv, Jw)  # diagonal of the hat matrix, (N, 6)
    rw = r * w[None, :]
    omega = np.array([np.sum(rw[:, :3] ** 2), np.sum(rw[:, 3:] ** 2)])
    redundancy = np.array([r[:, :3].size - hat[:, :3].sum(), r[:, 3:].size - hat[:, 3:].sum()])
    return r, omega, redundancy


# ------------------------------------------------------------------------------------ API


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
    max_noise_iterations: int = 30,
) -> HandEyePairsCalibration:
    """Hand-eye (X) and target/camera (Y) poses from station pose pairs, with covariance.

    Args:
        T_base_flange: (N, 4, 4) measured flange poses in the robot base, m.
        T_cam_target: (N, 4, 4) measured target poses in the camera (``p_cam = T p_target``), m.
        mode: ``"eye_in_hand"`` (X = ``T_flange_cam``, Y = ``T_base_target``) or ``"eye_to_hand"``
            (X = ``T_base_cam``, Y = ``T_flange_target``).
        rotation_sigma_deg: stated σ of each rotation component of a station's loop error, degrees
            (robot and camera combined). Required with ``noise="stated"``; otherwise only a start
            value (default: from the closed-form residuals). Also sets the threshold of the motion
            check before solving (default 0.02 deg there).
        translation_sigma_m: stated σ of each translation component, metres (as above).
        noise: ``"a_posteriori"`` (estimate both σ by variance components, default) or ``"stated"``.
        init_method: closed-form start: a key of :data:`jcalib.init.handeye.HAND_EYE_METHODS`
            (``"park_martin"`` default, ``"tsai_lenz"``, ``"horaud"``, ``"andreff"``,
            ``"daniilidis"``) or of :data:`jcalib.init.robot_world.ROBOT_WORLD_METHODS`
            (``"shah"``, ``"li"``).
        init: optional ``(X, Y)`` (4, 4) start values replacing the closed form's.
        max_iterations: LM iterations per solve.
        max_noise_iterations: variance-component re-solves at most.

    Returns:
        :class:`HandEyePairsCalibration`.

    Raises:
        BadInputError: malformed poses, mismatched counts, unknown mode / method / noise, missing σ.
        NotObservableError: degenerate motion (before solving, with the stated noise; after, with the
            estimated noise) or a rank-deficient information matrix at the solution; ``unknowns``
            names what is undetermined.
    """
    if mode not in MODES:
        raise BadInputError(f"mode: expected 'eye_in_hand' or 'eye_to_hand', got {mode!r}")
    if noise not in ("a_posteriori", "stated"):
        raise BadInputError(f"noise: expected 'a_posteriori' or 'stated', got {noise!r}")
    if init_method not in HAND_EYE_METHODS and init_method not in ROBOT_WORLD_METHODS:
        raise BadInputError(
            f"init_method: expected one of {sorted(HAND_EYE_METHODS) + sorted(ROBOT_WORLD_METHODS)}, "
            f"got {init_method!r}"
        )
    sig_r_deg = _positive_or_none(rotation_sigma_deg, "rotation_sigma_deg", "degrees")
    sig_t = _positive_or_none(translation_sigma_m, "translation_sigma_m", "metres")
    if noise == "stated" and (sig_r_deg is None or sig_t is None):
        raise BadInputError(
            f"noise='stated' needs rotation_sigma_deg and translation_sigma_m, got {rotation_sigma_deg!r} "
            f"and {translation_sigma_m!r}"
        )
    if int(max_iterations) < 1 or int(max_noise_iterations) < 1:
        raise BadInputError(
            f"max_iterations / max_noise_iterations: expected >= 1, got {max_iterations} / {max_noise_iterations}"
        )
    mount, x_name, y_name = MODES[mode]

    # validation + observability (raises NotObservableError), then the closed-form start
    check_noise_deg = sig_r_deg if sig_r_deg is not None else 0.02
    T_bf, T_ct, _ = checked_stations(T_base_flange, T_cam_target, mount, "all", check_noise_deg)
    start = _closed_form(T_bf, T_ct, mount, init_method, check_noise_deg)
    if init is not None:
        X0 = np.asarray(init[0], dtype=np.float64)
        Y0 = np.asarray(init[1], dtype=np.float64)
        for name, T in (("init[0] (X)", X0), ("init[1] (Y)", Y0)):
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise BadInputError(f"{name}: expected a finite 4x4 pose, got shape {T.shape}")
    else:
        X0, Y0 = start.T, start.T_other

    H_mat = T_bf if mount == "flange" else np.linalg.inv(T_bf)
    H = np.asarray(lie.se3_from_matrix(H_mat))
    B = np.asarray(lie.se3_from_matrix(T_ct))
    X = np.asarray(lie.se3_from_matrix(X0))
    Y = np.asarray(lie.se3_from_matrix(Y0))
    n = len(H)

    # start σ: stated, else the closed form's loop-error RMS per group
    r0, _, _ = _variance_components(X, Y, H, B, 1.0, 1.0)
    sig_r = np.radians(sig_r_deg) if sig_r_deg is not None else max(float(np.sqrt(np.mean(r0[:, :3] ** 2))), _SIGMA_FLOOR)
    sig_tr = sig_t if sig_t is not None else max(float(np.sqrt(np.mean(r0[:, 3:] ** 2))), _SIGMA_FLOOR)

    options = SolveOptions(max_iterations=int(max_iterations))

    def build(sr: float, st: float) -> Problem:
        # generic variable names ("X", "Y") keep the compiled solver the same for both modes;
        # errors from the engine are renamed below
        inv_sigma = jnp.broadcast_to(jnp.asarray([1.0 / sr] * 3 + [1.0 / st] * 3), (n, 6))
        obs = (jnp.asarray(H), jnp.asarray(B), inv_sigma)
        idx = (jnp.zeros((n,), jnp.int32), jnp.zeros((n,), jnp.int32))
        return Problem(
            [Variable("X", SE3(), X), Variable("Y", SE3(), Y)],
            [FactorGroup("loop", _whitened_loop_error, ("X", "Y"), idx, obs)],
        )

    def engine_solve(sr: float, st: float):
        try:
            return solve(build(sr, st), options=options)
        except NotObservableError as err:
            def rename(text: str) -> str:
                return re.sub(r"\bY\.", f"{y_name}.", re.sub(r"\bX\.", f"{x_name}.", text))

            raise NotObservableError(rename(str(err)), [rename(u) for u in err.unknowns]) from None

    warnings: list[str] = []
    total_iterations = 0
    vce_iterations = 0
    converged = False
    sol = None
    for k in range(int(max_noise_iterations)):
        sol = engine_solve(sig_r, sig_tr)
        total_iterations += sol.iterations
        X = np.asarray(sol.values["X"][0])
        Y = np.asarray(sol.values["Y"][0])
        r, omega, red = _variance_components(X, Y, H, B, sig_r, sig_tr)
        vce_iterations = k + 1
        ratio = omega / np.maximum(red, 1e-300)
        new_r = max(sig_r * float(np.sqrt(ratio[0])), _SIGMA_FLOOR)
        new_t = max(sig_tr * float(np.sqrt(ratio[1])), _SIGMA_FLOOR)
        converged = bool(np.all(np.abs(ratio - 1.0) <= _VCE_RTOL)) or (new_r == sig_r and new_t == sig_tr)
        if noise == "stated":
            est = PoseNoise(float(np.degrees(new_r)), float(new_t), "estimated", float(red[0]), float(red[1]), 1, True)
            break
        if converged:
            break
        sig_r, sig_tr = new_r, new_t
    if noise == "a_posteriori":
        if not converged:
            warnings.append(
                f"the noise estimate did not settle in {vce_iterations} re-solves (variance ratios "
                f"{ratio[0]:.4g}, {ratio[1]:.4g}); the covariance may be off by that factor"
            )
        if sig_r <= _SIGMA_FLOOR or sig_tr <= _SIGMA_FLOOR:
            warnings.append("the stations fit exactly (noise-free data?): the noise estimate sits at its floor 1e-12")
        est = PoseNoise(float(np.degrees(sig_r)), float(sig_tr), "estimated", float(red[0]), float(red[1]),
                        vce_iterations, converged)  # fmt: skip
        used = est
    else:
        used = PoseNoise(float(sig_r_deg), float(sig_t), "stated", float(red[0]), float(red[1]), 1, True)
        # both groups together: 2·cost ~ chi2(6N - 12) under the stated noise
        dof = 6 * n - 12
        lo, hi = _chi2.ppf(0.0005, dof), _chi2.ppf(0.9995, dof)
        if not lo <= 2.0 * sol.cost <= hi:
            warnings.append(
                f"the residuals contradict the stated noise (variance factor {sol.sigma2:.3g}, outside "
                f"[{lo / dof:.3g}, {hi / dof:.3g}] at 99.9 %): estimated σ {est.rotation_deg:.3g} deg / "
                f"{est.translation_m:.3g} m vs stated {sig_r_deg:.3g} deg / {sig_t:.3g} m"
            )

    if sol.status == Status.MAX_ITERATIONS:
        warnings.append(f"the solver stopped at its iteration limit ({max_iterations}) before converging")

    # the rotations must stand out of the (estimated) noise: repeat the motion check with it
    motion = analyse_motion(T_bf, frame=mount, pairs="all", rotation_noise_deg=est.rotation_deg)
    check_observable(motion, x_name)
    warnings.extend(motion.warnings)

    sigmas = np.array([np.radians(used.rotation_deg)] * 3 + [used.translation_m] * 3)
    rw = r / sigmas[None, :]
    station_chi2 = np.sum(rw**2, axis=1)
    outliers = [int(i) for i in np.flatnonzero(station_chi2 > OUTLIER_CHI2)]
    if outliers:
        warnings.append(
            f"stations {outliers} have loop errors beyond the 99.9 % bound of the noise model "
            f"(chi2(6) > {OUTLIER_CHI2:.1f}): check them for wrong detections or robot poses"
        )

    cov_X = np.asarray(sol.covariance("X", noise="stated"))
    cov_Y = np.asarray(sol.covariance("Y", noise="stated"))
    if not (np.all(np.isfinite(cov_X)) and np.all(np.isfinite(cov_Y))):
        raise NotObservableError(
            f"the covariance of {x_name} / {y_name} is not finite: the stations do not determine them",
            [x_name, y_name],
        )
    return HandEyePairsCalibration(
        mode=mode,
        hand_eye_name=x_name,
        T_hand_eye=np.asarray(lie.se3_to_matrix(X)),
        T_hand_eye_covariance=cov_X,
        other_name=y_name,
        T_other=np.asarray(lie.se3_to_matrix(Y)),
        T_other_covariance=cov_Y,
        noise=used,
        estimated_noise=est,
        station_residuals=r,
        station_rotation_error_deg=np.degrees(np.linalg.norm(r[:, :3], axis=1)),
        station_translation_error_m=np.linalg.norm(r[:, 3:], axis=1),
        station_chi2=station_chi2,
        outlier_stations=outliers,
        init=start,
        motion=motion,
        warnings=tuple(warnings),
        status=sol.status.name,
        iterations=total_iterations,
        sigma2=float(sol.sigma2),
        num_stations=n,
        solution=sol,
    )
