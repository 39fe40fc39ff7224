"""Joint pivot refinement: tip in the flange and pivot in the base, solved by the engine.

The pivot (4-point sphere) method records ``N`` flange poses ``T_base_flange_i = (R_i, t_i)`` with the
tool tip resting in one fixed point. The unknowns are the tip in the flange frame ``p_flange_tip``
and the pivot point in the base frame ``p_base_pivot``; the residual of pose ``i`` is the 3-vector

    r_i = T_base_flange_i · p_flange_tip − p_base_pivot = R_i p_flange_tip + t_i − p_base_pivot

(base frame, input length unit). :func:`jcalib.init.pivot.pivot_calibration` solves the same least
squares in closed form and is the start; :func:`refine_pivot` hands the problem to the engine
(:mod:`jcalib.solve`), which is what makes the pivot one factor group among others (robust losses,
other unknowns, priors) and gives the covariance the same way as every other problem.

Noise model and what the covariance means: every residual coordinate is taken as independent with
one standard deviation ``σ`` (isotropic in the base frame). Given ``sigma`` it is trusted
(``noise="stated"``); otherwise it is estimated from the residuals, ``σ̂² = Σ‖r_i‖² / (3N − 6)``
(``noise="a_posteriori"``). The covariance is first-order sampling noise under that model. It does
**not** include model error: tracker or robot bias, a tip that slides or wobbles in the divot, and
noise that is correlated from one pose to the next (a tracker streams poses at tens of Hz, so
consecutive poses share most of their error). With correlated poses the stated σ of the tip is too
small by about ``sqrt(N / N_effective)``; ``benchmarks/bench_pivot.py`` compares it with a block
bootstrap on the real tracker data. For such a time series, ``serial_correlation=True`` replaces the
covariance by a heteroscedasticity-and-autocorrelation-consistent (Newey–West) estimate: the
"sandwich" ``B S B`` with ``B = (Σ J_iᵀ J_i)⁻¹``, ``J_i = [R_i, −I]``, and ``S`` the Bartlett-weighted
sum of the lagged products of the per-pose scores ``g_i = J_iᵀ r_i`` (prewhitened by a VAR(1), Andrews
and Monahan 1992) up to a bandwidth chosen by Andrews' (1991) AR(1) plug-in rule. On the NDI data
(lag-1 residual autocorrelation 0.98) it gives a tip σ of ~1.0–1.3 mm, 4–5x the independent-noise
value and close to a moving-block bootstrap; in simulation with AR(1) pose noise it matches the
Monte-Carlo spread (tests/problems/test_pivot_joint.py).

Units: the unit of the input translations (metres in jcalib; the NDI tracker data is in mm).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.init.pivot import (
    DEFAULT_MIN_ROTATION_DEG,
    PivotAccessors,
    PivotResult,
    as_pose_matrices,
    pivot_calibration,
)
from jcalib.residuals.losses import Loss
from jcalib.solve import (
    Euclidean,
    FactorGroup,
    Problem,
    SolveOptions,
    Status,
    Variable,
    solve,
)

__all__ = ["PivotRefinement", "pivot_residual", "refine_pivot"]


def pivot_residual(p_flange_tip, p_base_pivot, obs):
    """One pose's pivot residual ``R p_flange_tip + t − p_base_pivot`` (3,), base frame.

    Args:
        p_flange_tip: ``(3,)`` tip in the flange frame.
        p_base_pivot: ``(3,)`` pivot in the base frame.
        obs: ``(R (3, 3), t (3,))`` the flange pose in the base frame.
    """
    R, t = obs
    return R @ p_flange_tip + t - p_base_pivot


@functools.cache
def _residuals_jit():
    return jax.jit(jax.vmap(pivot_residual, in_axes=(None, None, 0)))


@dataclass
class PivotRefinement(PivotAccessors):
    """Result of :func:`refine_pivot` (input length unit throughout).

    Attributes:
        p_flange_tip: ``(3,)`` tip in the flange (marker) frame.
        p_base_pivot: ``(3,)`` pivot point in the base (tracker) frame.
        covariance: ``(6, 6)`` joint covariance of ``(p_flange_tip, p_base_pivot)``, unit²
            (sampling noise only, see the module docstring).
        residuals: ``(N, 3)`` ``R_i p_flange_tip + t_i − p_base_pivot``, base frame.
        rms: RMS of the residual coordinates ``sqrt(mean(residuals²))``.
        rms_distance: RMS 3-D tip distance from the pivot, ``sqrt(3) · rms``.
        sigma: noise per residual coordinate used for the covariance: the stated ``sigma`` or the
            a-posteriori ``sqrt(Σ‖r‖² / (3N − 6))``.
        noise: ``"stated"``, ``"a_posteriori"`` or ``"serial"`` (Newey–West, ``serial_correlation``).
        covariance_iid: ``(6, 6)`` the independent-noise covariance (equal to ``covariance`` unless
            ``serial_correlation``).
        serial_bandwidth: the Newey–West bandwidth (lags) used, 0 without ``serial_correlation``.
        residual_autocorrelation: lag-1 autocorrelation of the residuals in the given pose order
            (pooled over x, y, z); near 0 for independent poses.
        init: the closed-form start (:class:`jcalib.init.pivot.PivotResult`).
        iterations, status: solver facts (status ``"converged"`` or ``"max_iterations"``).
        solution: the :class:`jcalib.solve.Solution`.
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
    solution: object = field(default=None, repr=False)


def refine_pivot(
    T_base_flange,
    *,
    sigma: float | None = None,
    loss: Loss | None = None,
    min_rotation_deg: float = DEFAULT_MIN_ROTATION_DEG,
    max_iterations: int = 50,
    serial_correlation: bool = False,
) -> PivotRefinement:
    """Tip in the flange and pivot in the base by a joint (engine) solve, started from the linear one.

    Args:
        T_base_flange: ``(N, 4, 4)`` (or ``(N, 7)`` ``wxyz_xyz``) poses of the flange or tracked
            marker in the base (tracker) frame with the tip in one fixed point; ``N >= 3``, any
            length unit.
        sigma: stated noise per residual coordinate (input unit); ``None`` estimates it from the
            residuals (a-posteriori).
        loss: robust loss on the whitened residual of a pose (``jcalib.residuals.losses``, scale in
            units of ``sigma``; with ``sigma=None`` the scale is relative to the linear solve's σ).
            ``None``: plain least squares, which equals the linear solve.
        min_rotation_deg: smallest accepted RMS rotation spread about the weakest direction (see
            :func:`jcalib.init.pivot.pivot_calibration`).
        max_iterations: LM iteration limit.
        serial_correlation: the poses are a time series in acquisition order (a tracker or robot
            stream) whose errors are correlated from one pose to the next: report the Newey–West
            covariance (see the module docstring) instead of the independent-noise one.

    Returns:
        :class:`PivotRefinement`.

    Raises:
        BadInputError: malformed poses, ``sigma`` not positive.
        NotObservableError: fewer than 3 poses, or rotations (nearly) about one axis (naming the
            tip direction along that axis) or none.
    """
    T = as_pose_matrices(T_base_flange, "T_base_flange")
    if sigma is not None and not (np.isfinite(sigma) and sigma > 0):
        raise BadInputError(f"sigma: expected a positive noise level (input length unit) or None, got {sigma!r}")
    if serial_correlation and loss is not None:
        raise BadInputError(
            "serial_correlation: the Newey–West covariance is implemented for plain least squares; got a "
            f"robust loss {loss!r} as well (drop one of them)"
        )
    if not (isinstance(max_iterations, int) and max_iterations > 0):
        raise BadInputError(f"max_iterations: expected a positive int, got {max_iterations!r}")
    init = pivot_calibration(T, sigma=sigma, min_rotation_deg=min_rotation_deg)
    R = T[:, :3, :3]
    t = T[:, :3, 3]
    n = R.shape[0]
    # The whitening σ only scales the cost (and a robust loss's threshold): with sigma=None the
    # linear solve's a-posteriori σ is used, so a loss scale of 1 means "one σ".
    sigma_w = float(sigma) if sigma is not None else max(float(init.sigma), 1e-300)
    zeros = np.zeros(n, np.int32)
    problem = Problem(
        [
            Variable("p_flange_tip", Euclidean(3), init.p_flange_tip, coord_names=("x", "y", "z"),
                     entry_label="tip in flange"),
            Variable("p_base_pivot", Euclidean(3), init.p_base_pivot, coord_names=("x", "y", "z"),
                     entry_label="pivot in base"),
        ],
        [FactorGroup("pivot", pivot_residual, ("p_flange_tip", "p_base_pivot"), (zeros, zeros), (R, t),
                     sigma=sigma_w, loss=loss)],
    )
    sol = solve(problem, options=SolveOptions(max_iterations=max_iterations))
    if sol.status == Status.NON_FINITE:
        raise BadInputError("T_base_flange: the pivot residuals are not finite at the start; check the poses")
    noise = "stated" if sigma is not None else "a_posteriori"
    tip = np.asarray(sol.values["p_flange_tip"][0])
    piv = np.asarray(sol.values["p_base_pivot"][0])
    res = np.asarray(_residuals_jit()(jnp.asarray(tip), jnp.asarray(piv), (jnp.asarray(R), jnp.asarray(t))))
    dof = 3 * n - 6
    if sigma is None and dof <= 0:
        raise NotObservableError(
            f"refine_pivot: {n} poses give {3 * n} residuals for 6 unknowns; the a-posteriori noise needs "
            "more poses (or pass sigma)",
            ["noise level sigma"],
        )
    # joint covariance of both unknowns, cross terms included, from the engine's block solver
    cov = np.asarray(sol.propagate(_stack_tip_pivot, noise=noise))
    cov = 0.5 * (cov + cov.T)
    s = float(sigma) if sigma is not None else float(np.sqrt(np.sum(res**2) / dof))
    rms = float(np.sqrt(np.mean(res**2)))
    rc = res - res.mean(axis=0)
    den = float(np.sum(rc * rc))
    rho1 = float(np.sum(rc[1:] * rc[:-1]) / den) if den > 0 and n > 1 else 0.0
    cov_iid = cov
    bandwidth = 0
    if serial_correlation:
        cov, bandwidth = _newey_west(R, res, rho1)
        noise = "serial"
    return PivotRefinement(
        p_flange_tip=tip,
        p_base_pivot=piv,
        covariance=cov,
        residuals=res,
        rms=rms,
        rms_distance=float(np.sqrt(3.0) * rms),
        sigma=s,
        noise=noise,
        init=init,
        covariance_iid=cov_iid,
        serial_bandwidth=bandwidth,
        residual_autocorrelation=rho1,
        iterations=sol.iterations,
        status=sol.status.name.lower(),
        solution=sol,
    )


def _stack_tip_pivot(values: dict) -> jax.Array:
    """``(6,)`` ``(p_flange_tip, p_base_pivot)`` from the solver's values (module level: one trace)."""
    return jnp.concatenate([values["p_flange_tip"][0], values["p_base_pivot"][0]])


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


def _newey_west(R: np.ndarray, res: np.ndarray, rho1: float) -> tuple[np.ndarray, int]:
    """Newey–West covariance ``(6, 6)`` of ``(tip, pivot)`` with VAR(1) prewhitening, and the bandwidth.

    The per-pose scores ``g_i`` are prewhitened by a fitted VAR(1) ``g_i ≈ A g_{i−1}`` (Andrews and
    Monahan 1992), the long-run covariance of the innovations is estimated with Bartlett weights
    ``1 − l/(L+1)`` and Andrews' AR(1) plug-in bandwidth ``L``, then recoloured with
    ``(I − A)⁻¹ · (I − A)⁻ᵀ``. Prewhitening removes most of the downward bias of plain Newey–West
    when consecutive poses are strongly correlated.
    """
    del rho1
    n = R.shape[0]
    J = np.concatenate([R, -np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2)  # (N, 3, 6)
    g = np.einsum("nij,ni->nj", J, res)  # per-pose scores, sum ~ 0 at the solution
    bread = np.linalg.inv(np.einsum("nij,nik->jk", J, J))
    g0, g1 = g[:-1], g[1:]
    A = np.linalg.lstsq(g0, g1, rcond=None)[0].T  # g1 ≈ g0 Aᵀ
    # keep the VAR(1) stable (eigenvalues inside 0.97), as Andrews and Monahan do
    if np.max(np.abs(np.linalg.eigvals(A))) > 0.97:
        U, sv, Vt = np.linalg.svd(A)
        A = U @ np.diag(np.minimum(sv, 0.97)) @ Vt
    e = g1 - g0 @ A.T
    L = _andrews_bandwidth(e)
    S_e = _bartlett(e, L) * (n / (n - 1.0))
    M = np.linalg.inv(np.eye(6) - A)
    meat = M @ S_e @ M.T
    cov = bread @ meat @ bread
    return 0.5 * (cov + cov.T), L
