"""Serial-arm kinematics from Denavit-Hartenberg parameters: FK, Jacobian, joint limits, numeric IK.

Convention: **standard (distal) DH**. Joint *i* (1-based) moves frame *i* relative to frame *i-1* by::

    T_{i-1,i} = Rz(theta_i) . Tz(d_i) . Tx(a_i) . Rx(alpha_i),    theta_i = sign_i * q_i + offset_i

where ``q_i`` is the joint value the controller reports (rad here; presets give the controller's
zero and positive direction through ``offset`` and ``sign``). The flange pose is::

    T_base_flange(q) = T_base_link0 . T_0,1 ... T_{n-1},n . T_link_flange

``T_base_link0`` places DH frame 0 in the robot base frame, ``T_link_flange`` places the flange frame
(the frame the controller reports with a null tool: ABB ``tool0``, KUKA ``$FLANGE``) in DH frame n.
Lengths are metres, angles radians.

Everything here is pure ``jax.numpy`` and batched over leading axes of ``q`` (``(..., n)``); it jits,
vmaps (also over robots, e.g. to calibrate DH parameters) and differentiates.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.lie import local, se3_from_matrix, se3_to_matrix

__all__ = [
    "DHRobot",
    "IKResult",
    "check_joint_limits",
    "dh_transform",
    "flange_jacobian",
    "forward_kinematics",
    "forward_kinematics_pose",
    "inverse_kinematics",
    "link_frames",
    "outside_joint_limits",
]


def _is_concrete(x: Any) -> bool:
    return not isinstance(x, jax.core.Tracer)


class DHRobot(eqx.Module):
    """A serial arm with revolute joints in standard DH form.

    Attributes (arrays of shape ``(n,)`` unless said):
        a: link lengths ``a_i`` (m).
        alpha: link twists ``alpha_i`` (rad).
        d: link offsets ``d_i`` (m).
        theta_offset: ``offset_i`` (rad), ``theta_i = sign_i q_i + offset_i``.
        joint_sign: ``sign_i`` (+1 or -1).
        lower, upper: joint limits on ``q`` (rad), ``lower < upper``.
        T_base_link0: ``(4, 4)`` DH frame 0 in the base frame (m).
        T_link_flange: ``(4, 4)`` flange frame in DH frame n (m).
        name: the robot's name (static), used in messages.
        joint_names: one name per joint (static), e.g. ``("A1", ..., "A6")``.
    """

    a: jax.Array
    alpha: jax.Array
    d: jax.Array
    theta_offset: jax.Array
    joint_sign: jax.Array
    lower: jax.Array
    upper: jax.Array
    T_base_link0: jax.Array
    T_link_flange: jax.Array
    name: str = eqx.field(static=True)
    joint_names: tuple[str, ...] = eqx.field(static=True)

    def __init__(
        self,
        a,
        alpha,
        d,
        *,
        theta_offset=None,
        joint_sign=None,
        lower=None,
        upper=None,
        T_base_link0=None,
        T_link_flange=None,
        name: str = "robot",
        joint_names: tuple[str, ...] | None = None,
    ):
        """Build a robot; defaults: offsets 0, signs +1, limits [-pi, pi], identity base and flange.

        Raises:
            BadInputError: arrays of different lengths, non-finite values, ``lower >= upper``,
                a sign other than +-1, a transform that is not 4x4.
        """
        a = jnp.asarray(a, dtype=jnp.float64)
        if a.ndim != 1 or a.shape[0] < 1:
            raise BadInputError(f"a: expected a 1-D array of link lengths (m), got shape {a.shape}")
        n = a.shape[0]

        def vec(x, default, label):
            v = jnp.full((n,), default, dtype=jnp.float64) if x is None else jnp.asarray(
                x, dtype=jnp.float64
            )
            if v.shape != (n,):
                raise BadInputError(f"{label}: expected shape ({n},) like a, got shape {v.shape}")
            return v

        def mat(x, label):
            m = jnp.eye(4, dtype=jnp.float64) if x is None else jnp.asarray(x, dtype=jnp.float64)
            if m.shape != (4, 4):
                raise BadInputError(f"{label}: expected a 4x4 transform, got shape {m.shape}")
            return m

        self.a = a
        self.alpha = vec(alpha, 0.0, "alpha")
        self.d = vec(d, 0.0, "d")
        self.theta_offset = vec(theta_offset, 0.0, "theta_offset")
        self.joint_sign = vec(joint_sign, 1.0, "joint_sign")
        self.lower = vec(lower, -np.pi, "lower")
        self.upper = vec(upper, np.pi, "upper")
        self.T_base_link0 = mat(T_base_link0, "T_base_link0")
        self.T_link_flange = mat(T_link_flange, "T_link_flange")
        self.name = str(name)
        names = tuple(joint_names) if joint_names is not None else tuple(
            f"joint {i + 1}" for i in range(n)
        )
        if len(names) != n:
            raise BadInputError(f"joint_names: expected {n} names, got {len(names)}: {names}")
        self.joint_names = names

        arrays = (self.a, self.alpha, self.d, self.theta_offset, self.joint_sign, self.lower,
                  self.upper, self.T_base_link0, self.T_link_flange)
        if all(_is_concrete(x) for x in arrays):
            labels = ("a", "alpha", "d", "theta_offset", "joint_sign", "lower", "upper",
                      "T_base_link0", "T_link_flange")
            for label, x in zip(labels, arrays):
                if not np.all(np.isfinite(np.asarray(x))):
                    raise BadInputError(f"{label}: expected finite values, got {np.asarray(x)}")
            sign = np.asarray(self.joint_sign)
            if not np.all(np.abs(np.abs(sign) - 1.0) == 0.0):
                raise BadInputError(f"joint_sign: expected +1 or -1 per joint, got {sign.tolist()}")
            lo, hi = np.asarray(self.lower), np.asarray(self.upper)
            if np.any(lo >= hi):
                i = int(np.argmax(lo >= hi))
                raise BadInputError(
                    f"lower/upper: joint {i + 1} ({names[i]}) has lower limit {lo[i]:.6g} rad >= "
                    f"upper limit {hi[i]:.6g} rad"
                )

    @property
    def num_joints(self) -> int:
        return int(self.a.shape[0])


def _per_joint(x: jax.Array, q: jax.Array) -> jax.Array:
    return jnp.broadcast_to(x, q.shape)


def _check_q(robot: DHRobot, q: Any, name: str = "q") -> jax.Array:
    q = jnp.asarray(q, dtype=jnp.float64)
    if q.ndim < 1 or q.shape[-1] != robot.num_joints:
        raise BadInputError(
            f"{name}: expected joint values of shape (..., {robot.num_joints}) (rad) for "
            f"{robot.name}, got shape {q.shape}"
        )
    return q


def dh_transform(a, alpha, d, theta) -> jax.Array:
    """Standard DH link transform ``Rz(theta) Tz(d) Tx(a) Rx(alpha)``, ``(..., 4, 4)``.

    All arguments broadcast to a common shape ``(...)`` (m, rad).
    """
    a, alpha, d, theta = jnp.broadcast_arrays(
        *(jnp.asarray(x, dtype=jnp.float64) for x in (a, alpha, d, theta))
    )
    ct, st = jnp.cos(theta), jnp.sin(theta)
    ca, sa = jnp.cos(alpha), jnp.sin(alpha)
    zero, one = jnp.zeros_like(theta), jnp.ones_like(theta)
    rows = [
        [ct, -st * ca, st * sa, a * ct],
        [st, ct * ca, -ct * sa, a * st],
        [zero, sa, ca, d],
        [zero, zero, zero, one],
    ]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def link_frames(robot: DHRobot, q) -> jax.Array:
    """Poses of DH frames 0..n in the base frame, ``(..., n + 1, 4, 4)`` (m), for joints ``q (..., n)``.

    Frame ``i`` sits on the axis of joint ``i + 1`` (its z axis); frame n is the last link.
    """
    q = _check_q(robot, q)
    theta = _per_joint(robot.joint_sign, q) * q + _per_joint(robot.theta_offset, q)
    links = dh_transform(
        _per_joint(robot.a, q), _per_joint(robot.alpha, q), _per_joint(robot.d, q), theta
    )  # (..., n, 4, 4)
    frame = jnp.broadcast_to(robot.T_base_link0, q.shape[:-1] + (4, 4))
    frames = [frame]
    for i in range(robot.num_joints):
        frame = jnp.einsum("...ij,...jk->...ik", frame, links[..., i, :, :])
        frames.append(frame)
    return jnp.stack(frames, axis=-3)


def forward_kinematics(robot: DHRobot, q) -> jax.Array:
    """Flange poses ``T_base_flange (..., 4, 4)`` (m) for joint values ``q (..., n)`` (rad).

    Does not check joint limits (see :func:`check_joint_limits`).
    """
    last = link_frames(robot, q)[..., -1, :, :]
    return jnp.einsum("...ij,jk->...ik", last, robot.T_link_flange)


def forward_kinematics_pose(robot: DHRobot, q) -> jax.Array:
    """Flange poses ``T_base_flange (..., 7)`` (``wxyz`` with ``w >= 0``, then ``xyz`` m)."""
    return se3_from_matrix(forward_kinematics(robot, q))


def flange_jacobian(robot: DHRobot, q) -> jax.Array:
    """Body Jacobian ``(..., 6, n)`` of the flange pose in jcalib's tangent convention.

    Column ``i`` is ``d local(T(q), T(q + h e_i)) / dh`` at 0: the flange twist per unit of joint ``i``
    in the order ``(rx, ry, rz, tx, ty, tz)`` (rad/rad, m/rad), expressed in the flange frame
    (right perturbation, as :func:`jcalib.geometry.lie.retract`). Computed by autodiff.
    """
    q = _check_q(robot, q)

    def single(qi):
        p0 = forward_kinematics_pose(robot, qi)
        return jax.jacfwd(lambda dq: local(p0, forward_kinematics_pose(robot, qi + dq)))(
            jnp.zeros_like(qi)
        )

    return jnp.vectorize(single, signature="(n)->(m,n)")(q)


def outside_joint_limits(robot: DHRobot, q) -> jax.Array:
    """Boolean ``(..., n)``: True where ``q`` is below ``lower`` or above ``upper`` (jittable)."""
    q = _check_q(robot, q)
    return (q < _per_joint(robot.lower, q)) | (q > _per_joint(robot.upper, q))


def check_joint_limits(robot: DHRobot, q, name: str = "q") -> None:
    """Raise :class:`BadInputError` naming the first joint of ``q (..., n)`` (rad) outside its limits.

    Not traceable (it inspects values); use :func:`outside_joint_limits` inside ``jit``.
    """
    q = _check_q(robot, q, name)
    values = np.asarray(q)
    if not np.all(np.isfinite(values)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(values))[0])
        raise BadInputError(f"{name}{list(bad)}: expected a finite joint value, got {values[bad]}")
    out = np.asarray(outside_joint_limits(robot, q))
    if np.any(out):
        idx = tuple(int(i) for i in np.argwhere(out)[0])
        j = idx[-1]
        lo, hi = float(robot.lower[j]), float(robot.upper[j])
        raise BadInputError(
            f"{name}{list(idx)}: joint {j + 1} ({robot.joint_names[j]}) of {robot.name} is "
            f"{np.degrees(values[idx]):.4f} deg, outside its limits [{np.degrees(lo):.4f}, "
            f"{np.degrees(hi):.4f}] deg"
        )


class IKResult(eqx.Module):
    """Result of :func:`inverse_kinematics` (fields batched like the targets).

    Attributes:
        q: joint values ``(..., n)`` (rad), within the limits; the best seed's when not successful.
        success: ``(...)`` bool, the target was reached within the tolerances.
        position_error_m: ``(...)`` flange position error (m).
        rotation_error_rad: ``(...)`` flange rotation error (rad).
        num_solutions: ``(...)`` number of seeds that reached the target (distinct or not).
    """

    q: jax.Array
    success: jax.Array
    position_error_m: jax.Array
    rotation_error_rad: jax.Array
    num_solutions: jax.Array

    def raise_if_unreachable(self, robot_name: str = "the robot", what: str = "T_base_flange"):
        """Raise :class:`BadInputError` if any target was not reached (concrete results only)."""
        ok = np.asarray(self.success)
        if np.all(ok):
            return
        idx = tuple(int(i) for i in np.argwhere(~np.atleast_1d(ok))[0]) if ok.ndim else ()
        pos = float(np.asarray(self.position_error_m)[idx]) if idx else float(self.position_error_m)
        rot = float(np.asarray(self.rotation_error_rad)[idx]) if idx else float(
            self.rotation_error_rad
        )
        where = f"{what}{list(idx)}" if idx else what
        raise BadInputError(
            f"{where}: unreachable for {robot_name} within its joint limits: the closest flange "
            f"pose found is {pos * 1e3:.3f} mm and {np.degrees(rot):.4f} deg away. Move the target "
            f"into the workspace, change the tool or station, or widen the joint limits."
        )


def _rotation_angle(r_err: jax.Array) -> jax.Array:
    """Angle of a rotation matrix, atan2(sin, cos): accurate near 0 and near pi."""
    skew = jnp.stack(
        [r_err[2, 1] - r_err[1, 2], r_err[0, 2] - r_err[2, 0], r_err[1, 0] - r_err[0, 1]]
    )
    return jnp.arctan2(0.5 * jnp.linalg.norm(skew), 0.5 * (jnp.trace(r_err) - 1.0))


def _ik_residual(robot: DHRobot, r_target: jax.Array, p_target: jax.Array, q: jax.Array):
    """Chordal rotation error (9, ~rad) and position error (3, m): smooth everywhere, zero only at
    the target, and cheap to differentiate (no matrix logarithm)."""
    t = forward_kinematics(robot, q)
    return jnp.concatenate([(t[:3, :3] - r_target).reshape(9), t[:3, 3] - p_target])


def _ik_errors(robot: DHRobot, r_target: jax.Array, p_target: jax.Array, q: jax.Array):
    t = forward_kinematics(robot, q)
    pos = jnp.linalg.norm(t[:3, 3] - p_target)
    return pos, _rotation_angle(r_target.T @ t[:3, :3])


def _ik_one_seed(robot, r_target, p_target, q0, max_iterations, tol_m, tol_rad):
    def residual(q):
        return _ik_residual(robot, r_target, p_target, q)

    def converged(r, scale):
        # |R - R_t|_F = 2 sqrt(2) sin(theta / 2) ~ sqrt(2) theta
        return (jnp.linalg.norm(r[9:]) <= scale * tol_m) & (
            jnp.linalg.norm(r[:9]) <= scale * tol_rad
        )

    q0 = jnp.clip(q0, robot.lower, robot.upper)
    r0 = residual(q0)
    eye = jnp.eye(q0.shape[0], dtype=jnp.float64)

    def cond(state):
        # iterate past the tolerance (to 1e-3 of it, or until no step helps) so that the returned
        # joints are accurate to rounding, not just to the tolerance
        q, r, lam, it = state
        return (~converged(r, 1e-3)) & (it < max_iterations) & (lam < 1e12)

    def body(state):
        q, r, lam, it = state
        jac = jax.jacfwd(residual)(q)
        h = jac.T @ jac
        g = jac.T @ r
        dq = -jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(h + lam * eye), g)
        q_new = jnp.clip(q + dq, robot.lower, robot.upper)
        r_new = residual(q_new)
        better = jnp.sum(r_new * r_new) < jnp.sum(r * r)
        q = jnp.where(better, q_new, q)
        r = jnp.where(better, r_new, r)
        lam = jnp.where(better, jnp.maximum(lam * 0.1, 1e-12), lam * 10.0)
        return q, r, lam, it + 1

    q, r, _, _ = jax.lax.while_loop(cond, body, (q0, r0, jnp.asarray(1e-3), jnp.asarray(0)))
    pos, rot = _ik_errors(robot, r_target, p_target, q)
    return q, pos, rot, (pos <= tol_m) & (rot <= tol_rad)


@eqx.filter_jit
def _ik_batch(robot, targets, q_ref, seeds, max_iterations, tol_m, tol_rad):
    """targets (B, 4, 4), q_ref (B, n), seeds (S, n) -> fields with leading B."""

    def one_target(target, ref, seeds_for_target):
        r_t = target[:3, :3]
        p_t = target[:3, 3]
        qs, pos, rot, oks = jax.vmap(
            lambda s: _ik_one_seed(robot, r_t, p_t, s, max_iterations, tol_m, tol_rad)
        )(seeds_for_target)
        dist = jnp.sum(jnp.square(qs - jnp.broadcast_to(ref, qs.shape)), axis=-1)
        # no seed reached the target: report the one closest to it (1 m ~ 1 rad)
        cost = pos + rot
        idx = jnp.where(jnp.any(oks), jnp.argmin(jnp.where(oks, dist, jnp.inf)), jnp.argmin(cost))
        return IKResult(
            q=qs[idx],
            success=oks[idx],
            position_error_m=pos[idx],
            rotation_error_rad=rot[idx],
            num_solutions=jnp.sum(oks.astype(jnp.int32)),
        )

    def with_ref_seed(ref):
        return jnp.concatenate([ref[None, :], seeds], axis=0)

    return jax.vmap(lambda t, ref: one_target(t, ref, with_ref_seed(ref)))(targets, q_ref)


def inverse_kinematics(
    robot: DHRobot,
    T_base_flange,
    q_init=None,
    *,
    num_seeds: int = 16,
    key: jax.Array | None = None,
    max_iterations: int = 300,
    position_tolerance_m: float = 1e-9,
    rotation_tolerance_rad: float = 1e-9,
) -> IKResult:
    """Joint values that put the flange at ``T_base_flange``, within the joint limits.

    Damped least squares (Levenberg-Marquardt) on the flange error ``(R(q) - R_target, p(q) -
    p_target)`` (chordal rotation error, m), projected onto the joint limits after every step,
    run from several seeds at once: ``q_init`` (or the middle of the limits) plus ``num_seeds``
    uniform random joint vectors. Among the seeds that reach the target, the one closest to
    ``q_init`` (the middle of the limits if None) is returned, so consecutive calls along a path stay
    on one branch. A target that no seed reaches comes back with ``success = False`` and the
    closest pose's errors; ``result.raise_if_unreachable()`` turns that into a clear error.

    Args:
        robot: the arm.
        T_base_flange: targets ``(..., 4, 4)`` (m) or poses ``(..., 7)``.
        q_init: ``(n,)`` or ``(..., n)`` joint values (rad) to stay close to; clipped to the limits.
        num_seeds: random seeds in addition to ``q_init``.
        key: PRNG key for the seeds (default ``PRNGKey(0)``: deterministic).
        max_iterations: LM iterations per seed.
        position_tolerance_m, rotation_tolerance_rad: success thresholds.

    Returns:
        :class:`IKResult` with leading axes ``(...)`` of the targets.
    """
    target = jnp.asarray(T_base_flange, dtype=jnp.float64)
    if target.shape[-1:] == (7,):
        target = se3_to_matrix(target)
    if target.ndim < 2 or target.shape[-2:] != (4, 4):
        raise BadInputError(
            f"T_base_flange: expected transforms (..., 4, 4) or poses (..., 7), got shape "
            f"{target.shape}"
        )
    if _is_concrete(target) and not np.all(np.isfinite(np.asarray(target))):
        raise BadInputError("T_base_flange: expected finite values, got NaN or inf")
    n = robot.num_joints
    batch = target.shape[:-2]
    if q_init is None:
        ref = 0.5 * (robot.lower + robot.upper)
    else:
        ref = _check_q(robot, q_init, "q_init")
    ref = jnp.broadcast_to(ref, batch + (n,))
    ref = jnp.clip(ref, _per_joint(robot.lower, ref), _per_joint(robot.upper, ref))
    if key is None:
        key = jax.random.PRNGKey(0)
    u = jax.random.uniform(key, (int(num_seeds), n), dtype=jnp.float64)
    seeds = _per_joint(robot.lower, u) + u * _per_joint(robot.upper - robot.lower, u)
    flat = _ik_batch(
        robot,
        target.reshape((-1, 4, 4)),
        ref.reshape((-1, n)),
        seeds,
        int(max_iterations),
        float(position_tolerance_m),
        float(rotation_tolerance_rad),
    )
    return jax.tree_util.tree_map(lambda x: x.reshape(batch + x.shape[1:]), flat)
