"""Preset: pivot calibration (the tip resting in one point while the flange or a tracked marker turns).

:func:`refine_pivot` is a cell with one tool whose tip touches one unknown cell point at every pose,
solved by the one builder: the contact residual ``T_base_flange_i · T_flange_tip · 0 − p_base_pivot``
(base frame, input length unit) with the linear pivot solution
(:func:`jcalib.init.pivot.pivot_calibration`) as the start.

Noise model and what the covariance means: every residual coordinate is independent with one σ
(isotropic in the base frame): the stated ``sigma``, or estimated from the residuals. It does
**not** include model error, nor noise that is correlated from one pose to the next (a tracker streams
poses at tens of Hz, so consecutive poses share most of their error; the stated σ of the tip is then
too small by about ``sqrt(N / N_effective)``). For such a time series ``serial_correlation=True``
replaces the covariance by a heteroscedasticity-and-autocorrelation-consistent (Newey–West) estimate:
the "sandwich" ``B S B`` with ``B = (Σ J_iᵀ J_i)⁻¹``, ``J_i = [R_i, −I]``, and ``S`` the Bartlett-weighted
sum of the lagged products of the per-pose scores ``g_i = J_iᵀ r_i`` (prewhitened by a VAR(1), Andrews
and Monahan 1992) up to a bandwidth chosen by Andrews' (1991) AR(1) plug-in rule. On the NDI data
(lag-1 residual autocorrelation 0.98) it gives a tip σ 4–5x the independent-noise value, close to a
moving-block bootstrap (``benchmarks/bench_pivot.py``).

Units: the unit of the input translations (metres in jcalib; the NDI tracker data is in mm).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.se3 import as_pose_matrices
from jcalib.init.pivot import DEFAULT_MIN_ROTATION_DEG, PivotAccessors, PivotResult, pivot_calibration
from jcalib.io.cell import CellSpec, PointSpec, RobotSpec, ToolSpec
from jcalib.io.observations import Contact, Observations, Station
from jcalib.problems.calibrate import calibrate_cell
from jcalib.problems.options import CalibrationOptions
from jcalib.residuals.losses import CauchyLoss, HuberLoss, Loss

__all__ = ["PivotRefinement", "refine_pivot"]


@dataclass
class PivotRefinement(PivotAccessors):
    """Result of :func:`refine_pivot` (input length unit throughout).

    Attributes:
        p_flange_tip: ``(3,)`` tip in the flange (marker) frame; ``p_base_pivot``: ``(3,)`` pivot point
            in the base (tracker) frame.
        covariance: ``(6, 6)`` joint covariance of ``(p_flange_tip, p_base_pivot)`` (sampling noise only).
        residuals: ``(N, 3)`` ``R_i p_flange_tip + t_i − p_base_pivot``; ``rms``: RMS of the residual
            coordinates; ``rms_distance``: ``sqrt(3) · rms``.
        sigma: noise per coordinate used for the covariance (stated or a-posteriori).
        noise: ``"stated"``, ``"a_posteriori"`` or ``"serial"`` (Newey–West).
        covariance_iid: the independent-noise covariance; serial_bandwidth: the Newey–West bandwidth
            (lags), 0 without; residual_autocorrelation: lag-1 autocorrelation of the residuals.
        init: the closed-form start; iterations, status, calibration, solution.
    """

    p_flange_tip: np.ndarray
    p_base_pivot: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    rms: float
    rms_distance: float
    sigma: float
    noise: str
    init: PivotResult
    covariance_iid: np.ndarray
    serial_bandwidth: int
    residual_autocorrelation: float
    iterations: int
    status: str
    calibration: object = field(default=None, repr=False)
    solution: object = field(default=None, repr=False)


def _loss_options(loss: Loss | None) -> dict:
    if loss is None:
        return {}
    if isinstance(loss, HuberLoss):
        return {"loss": "huber", "loss_scale": float(loss.scale)}
    if isinstance(loss, CauchyLoss):
        return {"loss": "cauchy", "loss_scale": float(loss.scale)}
    return {}


def refine_pivot(
    T_base_flange,
    *,
    sigma: float | None = None,
    loss: Loss | None = None,
    min_rotation_deg: float = DEFAULT_MIN_ROTATION_DEG,
    max_iterations: int = 50,
    serial_correlation: bool = False,
) -> PivotRefinement:
    """Tip in the flange and pivot in the base by a joint solve, started from the linear one.

    Args:
        T_base_flange: ``(N, 4, 4)`` (or ``(N, 7)`` ``wxyz_xyz``) poses of the flange or tracked marker
            with the tip in one fixed point; ``N >= 3``, any length unit.
        sigma: stated noise per residual coordinate (input unit); ``None`` estimates it.
        loss: robust loss on a pose's whitened residual (:mod:`jcalib.residuals.losses`; scale in units
            of ``sigma``, or of the linear solve's σ with ``sigma=None``).
        min_rotation_deg: smallest accepted RMS rotation spread about the weakest direction.
        max_iterations: LM iteration limit.
        serial_correlation: the poses are a time series with correlated errors: report the Newey–West
            covariance (module docstring) instead of the independent-noise one.

    Raises:
        BadInputError: malformed poses, ``sigma`` not positive, a loss with ``serial_correlation``.
        NotObservableError: fewer than 3 poses, or rotations (nearly) about one axis or none.
    """
    T = as_pose_matrices(T_base_flange, "T_base_flange")
    if sigma is not None and not (np.isfinite(sigma) and sigma > 0):
        raise BadInputError(f"sigma: expected a positive noise level (input length unit) or None, got {sigma!r}")
    if serial_correlation and loss is not None:
        raise BadInputError("serial_correlation: the Newey–West covariance is implemented for plain least squares; "
                            f"got a robust loss {loss!r} as well (drop one of them)")
    if not (isinstance(max_iterations, int) and max_iterations > 0):
        raise BadInputError(f"max_iterations: expected a positive int, got {max_iterations!r}")
    init = pivot_calibration(T, sigma=sigma, min_rotation_deg=min_rotation_deg)
    n = T.shape[0]
    if sigma is None and 3 * n - 6 <= 0:
        raise NotObservableError(f"refine_pivot: {n} poses give {3 * n} residuals for 6 unknowns; the a-posteriori "
                                 "noise needs more poses (or pass sigma)", ["noise level sigma"])
    cell = CellSpec(cameras={}, targets={}, tools={"tip": ToolSpec("tip")}, points={"pivot": PointSpec("pivot")},
                    robot=RobotSpec(), source="refine_pivot")
    obs = Observations(cameras={}, targets={}, stations=tuple(
        Station(id=f"pose{i}", T_base_flange=T[i], contacts=(Contact("tip", "pivot"),)) for i in range(n)),
        source="refine_pivot")
    # the whitening σ scales the cost and a robust loss's threshold: the linear solve's σ without a stated one
    sigma_w = float(sigma) if sigma is not None else max(float(init.sigma), 1e-300)
    options = CalibrationOptions(contact_sigma_m=sigma_w, noise="stated" if sigma is not None else "a_posteriori",
                                 outlier_threshold=None, max_iterations=max_iterations, **_loss_options(loss))
    start = np.eye(4)
    start[:3, 3] = init.p_flange_tip
    cal = calibrate_cell(cell, obs, options, known={"T_flange_tip": start})
    tip = cal.transforms["T_flange_tip"][:3, 3].copy()
    piv = cal.points["pivot"].copy()
    sol = cal.solution
    # joint covariance of the tip (the TCP's translation tangent v, rotated: t = R v) and the pivot
    M = sol.joint_covariance(["T_flange_tip", "point:pivot"], noise=options.noise)[3:, 3:]
    B = np.eye(6)
    B[:3, :3] = cal.transforms["T_flange_tip"][:3, :3]
    C = B @ M @ B.T
    C = 0.5 * (C + C.T)
    res = cal.residuals["contacts:tip/pivot"]
    rms = float(np.sqrt(np.mean(res**2)))
    s = float(sigma) if sigma is not None else float(np.sqrt(np.sum(res**2) / (3 * n - 6)))
    rc = res - res.mean(axis=0)
    den = float(np.sum(rc * rc))
    rho1 = float(np.sum(rc[1:] * rc[:-1]) / den) if den > 0 and n > 1 else 0.0
    cov, bandwidth, noise = C, 0, options.noise
    if serial_correlation:
        cov, bandwidth = _newey_west(T[:, :3, :3], res)
        noise = "serial"
    return PivotRefinement(
        p_flange_tip=tip, p_base_pivot=piv, covariance=cov, residuals=res, rms=rms,
        rms_distance=float(np.sqrt(3.0) * rms), sigma=s, noise=noise, init=init, covariance_iid=C,
        serial_bandwidth=bandwidth, residual_autocorrelation=rho1, iterations=cal.iterations, status=cal.status,
        calibration=cal, solution=sol)


def _bartlett(g: np.ndarray, L: int) -> np.ndarray:
    S = g.T @ g
    for lag in range(1, L + 1):
        G = g[lag:].T @ g[:-lag]
        S += (1.0 - lag / (L + 1.0)) * (G + G.T)
    return S


def _andrews_bandwidth(u: np.ndarray) -> int:
    """Andrews' (1991) AR(1) plug-in bandwidth for the Bartlett kernel, pooled over columns."""
    n = u.shape[0]
    uc = u - u.mean(axis=0)
    den = float(np.sum(uc[:-1] * uc[:-1]))
    rho = float(np.sum(uc[1:] * uc[:-1]) / den) if den > 0 else 0.0
    rho = min(max(rho, 0.0), 0.97)
    alpha = 4.0 * rho**2 / ((1.0 - rho) ** 2 * (1.0 + rho) ** 2)
    return int(min(n - 2, np.ceil(1.1447 * (alpha * n) ** (1.0 / 3.0))))


def _newey_west(R: np.ndarray, res: np.ndarray) -> tuple[np.ndarray, int]:
    """Newey–West covariance ``(6, 6)`` of ``(tip, pivot)`` with VAR(1) prewhitening, and the bandwidth.

    The per-pose scores ``g_i`` are prewhitened by a fitted VAR(1) ``g_i ≈ A g_{i−1}`` (Andrews and
    Monahan 1992), the long-run covariance of the innovations is estimated with Bartlett weights
    ``1 − l/(L+1)`` and Andrews' AR(1) plug-in bandwidth ``L``, then recoloured with
    ``(I − A)⁻¹ · (I − A)⁻ᵀ``.
    """
    n = R.shape[0]
    J = np.concatenate([R, -np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2)  # (N, 3, 6)
    g = np.einsum("nij,ni->nj", J, res)  # per-pose scores, sum ~ 0 at the solution
    bread = np.linalg.inv(np.einsum("nij,nik->jk", J, J))
    g0, g1 = g[:-1], g[1:]
    A = np.linalg.lstsq(g0, g1, rcond=None)[0].T  # g1 ≈ g0 Aᵀ
    if np.max(np.abs(np.linalg.eigvals(A))) > 0.97:  # keep the VAR(1) stable, as Andrews and Monahan do
        U, sv, Vt = np.linalg.svd(A)
        A = U @ np.diag(np.minimum(sv, 0.97)) @ Vt
    e = g1 - g0 @ A.T
    L = _andrews_bandwidth(e)
    S_e = _bartlett(e, L) * (n / (n - 1.0))
    M = np.linalg.inv(np.eye(6) - A)
    cov = bread @ (M @ S_e @ M.T) @ bread
    return 0.5 * (cov + cov.T), L
