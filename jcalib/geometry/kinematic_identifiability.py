"""Which kinematic parameters any motion can determine: the structural scan shared by the builder
(:mod:`jcalib.problems.kinematics`) and the station planner (:mod:`jcalib.planning.kinematic_design`).

A robot's kinematic parameters (:mod:`jcalib.geometry.kinematic_models`) are never all separable from
what else a cell estimates: whatever sits on the robot's base side (a fixed camera, board or sensor:
an unknown pose in the base frame) absorbs any change of the base transform, whatever sits on the
flange absorbs any change of the flange transform, and within the chain some parameters trade off
exactly (the first joint's offset against the base yaw; consecutive parallel axes' offsets in DH). At
generic joint values (seeded random configurations within the limits) the flange pose's Jacobian
columns, whitened by the robot's repeatability and normalised, are scanned in parameter order after the
12 columns of those two unknown poses; a parameter whose column lies in the span of the columns kept
before it is held, and the scan names what reproduces it.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.geometry import kinematic_models, lie
from jcalib.geometry.se3 import adjoint

__all__ = ["DEFAULT_REPEATABILITY_DEG", "DEFAULT_REPEATABILITY_M", "GAUGE_COLUMNS", "GAUGE_LABELS",
           "GENERIC_CONFIGURATIONS", "GENERIC_SEED", "INDEPENDENCE_TOLERANCE", "flange_jacobians", "gauge_columns",
           "generic_joints", "repeatability_sqrt_info", "structural_scan", "unit_columns"]

#: Generic joint configurations of the structural scan, and their seed.
GENERIC_CONFIGURATIONS = 60
GENERIC_SEED = 20261126
#: A column is independent of the kept ones when its normalised distance from their span exceeds this.
INDEPENDENCE_TOLERANCE = 1e-6
#: Default repeatability σ of a robot whose cell states no ``pose_noise`` (per axis: m, degrees).
DEFAULT_REPEATABILITY_M = 2e-5
DEFAULT_REPEATABILITY_DEG = 0.002
#: The unknown poses on either side of the robot: base-side (6) then flange-side (6) columns.
GAUGE_COLUMNS = 12
GAUGE_LABELS = {"base": "the pose of what is fixed in the base frame (fixed cameras, targets, sensors)",
                "flange": "the pose of what the flange carries (hand-eye camera, tool, target)"}
#: Joint vectors per call of the compiled Jacobian (one compilation per robot structure).
CHUNK = 64


@eqx.filter_jit
def _flange_jacobians(model, params, q):
    def one(qi):
        T = kinematic_models.forward(model, params, qi)
        T0 = lie.se3_from_matrix(T)

        def tangent(p, dq):
            return lie.local(T0, lie.se3_from_matrix(kinematic_models.forward(model, p, qi + dq)))

        Jp, Jq = jax.jacfwd(tangent, argnums=(0, 1))(params, jnp.zeros_like(qi))
        return T, Jp, Jq, kinematic_models.joint_frames(model, params, qi)[:, :3, 3]

    return jax.vmap(one)(q)


def flange_jacobians(model, q, params=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(T (M, 4, 4), J_params (M, 6, P), J_joints (M, 6, n), joint_origins (M, n, 3))``: flange poses at
    joints ``q (M, n)`` (rad, m) and parameters ``params (P,)`` (default nominal), the right-perturbation
    tangent of each per unit of each parameter and joint value, and the joint frames' origins in the base
    frame (m). Computed in chunks of :data:`CHUNK` joint vectors (one compilation per robot structure)."""
    params = jnp.asarray(model.nominal if params is None else params, jnp.float64)
    q = np.asarray(q, np.float64).reshape(-1, model.num_joints)
    m = q.shape[0]
    parts = []
    for k in range(0, max(m, 1), CHUNK):
        chunk = q[k:k + CHUNK] if m else np.zeros((1, model.num_joints))
        padded = np.concatenate([chunk, np.repeat(chunk[:1], CHUNK - len(chunk), axis=0)])
        parts.append([np.asarray(x) for x in _flange_jacobians(model, params, jnp.asarray(padded))])
    return tuple(np.concatenate([p[i] for p in parts])[:m] for i in range(4))  # type: ignore[return-value]


def gauge_columns(T: np.ndarray) -> np.ndarray:
    """``(M, 6, 12)``: the flange tangent per unit of a base-side pose change (left perturbation,
    ``Exp(e) T = T Exp(Ad(T⁻¹) e)``) and of a flange-side one (identity), at flange poses ``T (M, 4, 4)``."""
    M = T.shape[0]
    return np.concatenate([adjoint(np.linalg.inv(T)), np.broadcast_to(np.eye(6), (M, 6, 6))], axis=2)


def unit_columns(A: np.ndarray) -> np.ndarray:
    """``A`` with each non-zero column scaled to unit norm."""
    n = np.linalg.norm(A, axis=0)
    return A / np.where(n > 0, n, 1.0)


def generic_joints(model, count: int = GENERIC_CONFIGURATIONS, seed: int = GENERIC_SEED) -> np.ndarray:
    """``(count, n)`` joint values spread over the limits (revolute ranges clipped to one turn), rad and m."""
    lo, hi = np.asarray(model.lower, np.float64), np.asarray(model.upper, np.float64)
    revolute = np.array([t == "revolute" for t in model.joint_types])
    lo = np.where(revolute, np.maximum(lo, -np.pi), lo)
    hi = np.where(revolute, np.minimum(hi, np.pi), hi)
    return np.random.default_rng(seed).uniform(lo, hi, size=(count, lo.size))


def repeatability_sqrt_info(spec) -> tuple[np.ndarray, str]:
    """``(S (6, 6), where it came from)``: the square-root information of one flange pose (rad, m) of a
    robot whose kinematics is calibrated: its cell ``pose_noise`` (its repeatability), else the default."""
    if spec is not None and spec.pose_noise_translation_m is not None and spec.pose_noise_rotation_deg is not None:
        t = np.asarray(spec.pose_noise_translation_m, np.float64)
        r = np.radians(np.asarray(spec.pose_noise_rotation_deg, np.float64))
        how = "pose_noise"
    else:
        t = np.full(3, DEFAULT_REPEATABILITY_M)
        r = np.full(3, math.radians(DEFAULT_REPEATABILITY_DEG))
        how = f"default repeatability ({DEFAULT_REPEATABILITY_M * 1e3:g} mm, {DEFAULT_REPEATABILITY_DEG:g} deg)"
    return np.diag(1.0 / np.concatenate([r, t])), how


def whitened(model, q: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whitened ``(6M, 12)`` gauge columns and ``(6M, P)`` parameter columns at joints ``q (M, n)``."""
    T, J, _, _ = flange_jacobians(model, q)
    M = T.shape[0]
    return (np.einsum("ab,mbc->mac", S, gauge_columns(T)).reshape(6 * M, GAUGE_COLUMNS),
            np.einsum("ab,mbc->mac", S, J).reshape(6 * M, -1))


def _confounders(kept_cols: np.ndarray, kept_names: list[str], col: np.ndarray) -> list[str]:
    """The kept columns that reproduce ``col`` (largest contributions first, at most three names)."""
    x, *_ = np.linalg.lstsq(kept_cols, col, rcond=None)
    weight = np.abs(x) * np.linalg.norm(kept_cols, axis=0)
    names: list[str] = []
    for i in np.argsort(-weight):
        if weight[i] > 1e-3 * weight.max() and kept_names[i] not in names:
            names.append(kept_names[i])
    return names[:3]


def structural_scan(model, want: np.ndarray, S: np.ndarray, gauge: np.ndarray | None = None,
                    cols: np.ndarray | None = None) -> tuple[np.ndarray, dict[str, str]]:
    """The minimal identifiable subset of the parameters in ``want (P,)`` (see the module docstring).

    Args:
        model: the :class:`~jcalib.geometry.kinematic_models.Kinematics`; S: ``(6, 6)`` square-root
            information of one flange pose; gauge, cols: whitened columns at :func:`generic_joints`
            (:func:`whitened`) when the caller has them.

    Returns:
        ``(free (P,) bool, held: name -> "not separable from ...")``.
    """
    if gauge is None or cols is None:
        gauge, cols = whitened(model, generic_joints(model), S)
    gauge, cols = unit_columns(gauge), unit_columns(cols)
    names = list(model.param_names)
    Q, _ = np.linalg.qr(gauge)
    kept_cols, kept_names = [gauge], ["base"] * 6 + ["flange"] * 6
    free = np.zeros(len(names), bool)
    held: dict[str, str] = {}
    for i in np.flatnonzero(want):
        c = cols[:, i]
        r = c - Q @ (Q.T @ c)
        r = r - Q @ (Q.T @ r)
        if np.linalg.norm(r) > INDEPENDENCE_TOLERANCE:
            Q = np.concatenate([Q, (r / np.linalg.norm(r))[:, None]], axis=1)
            kept_cols.append(c[:, None])
            kept_names.append(names[i])
            free[i] = True
            continue
        with_ = [GAUGE_LABELS.get(n, n) for n in _confounders(np.concatenate(kept_cols, axis=1), kept_names, c)]
        held[names[i]] = "not separable from " + " and ".join(with_)
    return free, held
