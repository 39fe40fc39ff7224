"""Which kinematic parameters of a robot the builder estimates: a minimal identifiable set.

A robot's kinematic parameters (:mod:`jcalib.geometry.kinematic_models`) are never all separable from
what else the cell estimates. Whatever sits on the robot's base side (a fixed camera, a fixed board, a
pose sensor: an unknown pose in the base frame) absorbs any change of the base transform, whatever
sits on the flange (a hand-eye camera, a tool, a board on a positioner) absorbs any change of the
flange transform, and within the chain some parameters trade off exactly (the first joint's offset
against the base yaw, consecutive parallel axes' link offsets). Kinematic calibration therefore keeps a
*minimal identifiable set*:

1. **Structure.** At generic joint values (seeded random configurations within the joint limits) the
   Jacobian of the flange pose with respect to the parameters, together with the 12 columns of an
   unknown pose on either side of the robot, is scanned column by column in the parameter order; a
   parameter whose column lies in the span of the columns already kept is held at its nominal value
   and the result says with what it cannot be separated. Parameters requested by name (not by group)
   that are held this way are an error (exit 3): the user asked for something no data can give.
2. **Data.** At the stations' joint values, the kept set must still be determined: a joint that never
   moved, or two parameters that always moved together, leave a null direction. Those parameters are
   named (exit 3) with the joint motions to add.

Both scans whiten the rows by the robot's repeatability (so radians and metres weigh as the factor
weighs them) and normalise the columns (so parameter units do not matter).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import NotObservableError
from jcalib.geometry import kinematic_models, lie
from jcalib.geometry.se3 import adjoint

#: Generic joint configurations for the structural scan, and their seed.
GENERIC_CONFIGURATIONS = 60
GENERIC_SEED = 20261126

#: A column is independent of the kept ones when its normalised distance from their span exceeds this.
INDEPENDENCE_TOLERANCE = 1e-6

#: Default repeatability σ of a robot whose cell states no ``pose_noise`` (per axis: m, degrees).
DEFAULT_REPEATABILITY_M = 2e-5
DEFAULT_REPEATABILITY_DEG = 0.002

_GAUGE_LABELS = {"base": "the pose of what is fixed in the base frame (fixed cameras, targets, sensors)",
                 "flange": "the pose of what the flange carries (hand-eye camera, tool, target)"}


@dataclass
class Selection:
    """The kinematic parameters of one robot the builder estimates.

    Attributes:
        free: ``(P,)`` bool, estimated; ``requested``: ``(P,)`` bool, asked for by the cell.
        held: parameter name -> why it is held at its nominal value (requested but not separable).
    """

    free: np.ndarray
    requested: np.ndarray
    held: dict[str, str] = field(default_factory=dict)


@eqx.filter_jit
def _flange_and_jacobian(model, params, q):
    def one(qi):
        T = kinematic_models.forward(model, params, qi)
        T0 = lie.se3_from_matrix(T)
        J = jax.jacfwd(lambda p: lie.local(T0, lie.se3_from_matrix(kinematic_models.forward(model, p, qi))))(params)
        return T, J

    return jax.vmap(one)(q)


#: The flange pose at each joint vector, compiled once per model structure and count.
forward_batch = eqx.filter_jit(jax.vmap(kinematic_models.forward, in_axes=(None, None, 0)))


def pose_jacobian(model, params, q) -> tuple[np.ndarray, np.ndarray]:
    """``(T (M, 4, 4), J (M, 6, P))``: the flange poses at joints ``q (M, n)`` (rad, m) and parameters
    ``params (P,)``, and the right-perturbation tangent of each per unit of each parameter."""
    T, J = _flange_and_jacobian(model, jnp.asarray(params, jnp.float64), jnp.asarray(q, jnp.float64))
    return np.asarray(T), np.asarray(J)


def _stacked(model, q, S) -> tuple[np.ndarray, np.ndarray]:
    """Whitened ``(6M, 12)`` gauge columns (base-side left, flange-side right perturbations) and
    ``(6M, P)`` parameter columns at joints ``q (M, n)``."""
    T, J = pose_jacobian(model, model.nominal, q)
    Tinv = adjoint(np.linalg.inv(T))  # Exp(e) T = T Exp(Ad(T⁻¹) e)
    M = q.shape[0]
    gauge = np.concatenate([Tinv, np.broadcast_to(np.eye(6), (M, 6, 6))], axis=2)
    return (np.einsum("ab,mbc->mac", S, gauge).reshape(6 * M, 12),
            np.einsum("ab,mbc->mac", S, J).reshape(6 * M, -1))


def _unit(A: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(A, axis=0)
    return A / np.where(n > 0, n, 1.0)


def generic_joints(model, count: int = GENERIC_CONFIGURATIONS, seed: int = GENERIC_SEED) -> np.ndarray:
    """``(count, n)`` joint values spread over the limits (revolute ranges clipped to one turn)."""
    lo, hi = np.asarray(model.lower, np.float64), np.asarray(model.upper, np.float64)
    revolute = np.array([t == "revolute" for t in model.joint_types])
    lo = np.where(revolute, np.maximum(lo, -np.pi), lo)
    hi = np.where(revolute, np.minimum(hi, np.pi), hi)
    return np.random.default_rng(seed).uniform(lo, hi, size=(count, lo.size))


def _confounders(kept_cols: np.ndarray, kept_names: list[str], col: np.ndarray) -> list[str]:
    """The kept columns that reproduce ``col`` (largest contributions first)."""
    x, *_ = np.linalg.lstsq(kept_cols, col, rcond=None)
    weight = np.abs(x) * np.linalg.norm(kept_cols, axis=0)
    order = [i for i in np.argsort(-weight) if weight[i] > 1e-3 * weight.max()]
    names: list[str] = []
    for i in order:
        n = kept_names[i]
        if n not in names:
            names.append(n)
    return names[:3]


def select_parameters(model, requested: tuple[str, ...], q: np.ndarray, S: np.ndarray, robot: str) -> Selection:
    """The minimal identifiable subset of the requested parameters (see the module docstring).

    Args:
        model: the robot's :class:`~jcalib.geometry.kinematic_models.Kinematics`; requested: the cell's
            ``calibrate_kinematics`` (names and groups); q: ``(N, n)`` the stations' joint values (rad, m);
            S: ``(6, 6)`` square-root information of one flange pose (rad, m); robot: its label in messages.

    Raises:
        NotObservableError: a parameter requested by name is not separable in any motion, or the
            stations' motion leaves kept parameters undetermined (named, with the joints to move).
    """
    names = list(model.param_names)
    want = np.asarray(kinematic_models.select(model, list(requested)), bool)
    groups = set(kinematic_models.parameter_groups(model))
    explicit = {n for n in requested if n not in groups}
    generic = generic_joints(model)
    gauge_all, cols_all = _stacked(model, np.concatenate([generic, q]), S)  # one compiled call for both scans
    rows = 6 * generic.shape[0]
    gauge, cols = _unit(gauge_all[:rows]), _unit(cols_all[:rows])
    gauge_names = ["base"] * 6 + ["flange"] * 6
    Q, _ = np.linalg.qr(gauge)
    kept_cols, kept_names = [gauge], list(gauge_names)
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
        with_ = [_GAUGE_LABELS.get(n, n) for n in _confounders(np.concatenate(kept_cols, axis=1), kept_names, c)]
        held[names[i]] = "not separable from " + " and ".join(with_)
    bad = [n for n in held if n in explicit]
    if bad:
        raise NotObservableError(
            f"{robot}: the kinematic parameter(s) {', '.join(bad)} cannot be determined by any motion: "
            + "; ".join(f"{n} is {held[n]}" for n in bad)
            + ". Remove them from calibrate_kinematics (name groups such as joint_offsets to let jcalib keep an "
              "identifiable subset)", [f"{robot} kinematics {n}" for n in bad])
    _check_motion(model, q, gauge_all[rows:], cols_all[rows:], free, robot)
    return Selection(free=free, requested=want, held=held)


def _check_motion(model, q: np.ndarray, gauge: np.ndarray, cols: np.ndarray, free: np.ndarray, robot: str) -> None:
    """Raise when the stations' joint values (``q``; whitened columns ``gauge``, ``cols`` at them) leave
    free parameters undetermined."""
    if not free.any():
        return
    A = _unit(np.concatenate([gauge, cols[:, free]], axis=1))
    _, sv, Vt = np.linalg.svd(A, full_matrices=False)
    small = sv < INDEPENDENCE_TOLERANCE * max(sv[0], 1e-300) * np.sqrt(A.shape[1])
    if not small.any():
        return
    names = [n for n, f in zip(model.param_names, free) if f]
    involved: list[str] = []
    for v in Vt[small]:
        w = np.abs(v[12:])
        for j in np.flatnonzero(w > 0.2 * max(w.max(), 1e-300)):
            if names[j] not in involved:
                involved.append(names[j])
    still = [model.joint_names[j] for j in range(q.shape[1]) if np.ptp(q[:, j]) < 1e-9]
    hint = (f"joint(s) {', '.join(still)} never moved; " if still else "") + \
        "move every joint through a good part of its range, in varied combinations (jcalib plan --kind kinematics)"
    raise NotObservableError(
        f"{robot}: the stations' motion cannot determine the kinematic parameter(s) "
        f"{', '.join(involved) or ', '.join(names)} (they move together or not at all in these {q.shape[0]} "
        f"stations): {hint}, or remove them from calibrate_kinematics", [f"{robot} kinematics {n}" for n in involved])


def repeatability_sqrt_info(spec) -> tuple[np.ndarray, str]:
    """``(S (6, 6), where it came from)``: the square-root information of one flange pose of a robot
    whose kinematics is calibrated: its ``pose_noise`` (its repeatability), else the default."""
    if spec.pose_noise_translation_m is not None and spec.pose_noise_rotation_deg is not None:
        t = np.asarray(spec.pose_noise_translation_m, np.float64)
        r = np.radians(np.asarray(spec.pose_noise_rotation_deg, np.float64))
        how = "pose_noise"
    else:
        t = np.full(3, DEFAULT_REPEATABILITY_M)
        r = np.full(3, np.radians(DEFAULT_REPEATABILITY_DEG))
        how = f"default repeatability ({DEFAULT_REPEATABILITY_M * 1e3:g} mm, {DEFAULT_REPEATABILITY_DEG:g} deg)"
    return np.diag(1.0 / np.concatenate([r, t])), how
