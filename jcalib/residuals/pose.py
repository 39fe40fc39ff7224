"""Residuals between poses: tool-tip contacts, 6-DOF pose measurements (pose loops), 3-D tool-tip positions
measured by a point sensor, a robot's flange pose against its kinematic model and a prior on a translation
component.
"""

from __future__ import annotations

import functools
import hashlib

import jax
import jax.numpy as jnp
import numpy as np

from jcalib.geometry import kinematic_models, lie
from jcalib.geometry.lie_kernels import se3_right_jacobian_inverse
from jcalib.residuals.chain import Chain, chain_apply, chain_jacobian, chain_pose
from jcalib.residuals.reprojection import recipe


@functools.cache
def contact(chain: Chain):
    """``(fn, jacobian)``: tool tip minus a cell point, metres, ``(3,)``.

    ``fn(*poses, point, obs)``: the chain carries the tool frame's origin (its tip) into the cell
    frame (e.g. ``T_base_flange_i · T_flange_tool``); ``point (3,)`` is the touched cell point in that
    frame; ``obs`` is unused (a ``(1,)`` placeholder). This one residual covers pivot calibration, the
    robot 4-point TCP method and touched work-object points.
    """

    def fn(*rest):
        *poses, point, _ = rest
        return chain_apply(poses, chain, jnp.zeros((3,), point.dtype)) - point

    def jacobian(*rest):
        *poses, point, _ = rest
        tip, blocks, _ = chain_jacobian(poses, chain, jnp.zeros((3,), point.dtype))
        return tip - point, (*blocks, -jnp.eye(3, dtype=point.dtype))

    fn.__jcalib_key__ = jacobian.__jcalib_key__ = recipe("contact", chain)
    return fn, jacobian


@functools.cache
def position_measurement(chain: Chain):
    """``(fn, jacobian)``: a tool tip's predicted position in a point sensor's frame minus the measured one, m,
    ``(3,)``.

    ``fn(*poses, obs)``: the chain carries the tool frame's origin (its tip) into the sensor frame (e.g.
    ``T_base_sensor⁻¹ · T_base_flange_i · T_flange_tool``); ``obs`` is the measured ``p_sensor_tool (3,)``
    (a laser tracker's reflector position).
    """

    def fn(*rest):
        *poses, p_meas = rest
        return chain_apply(poses, chain, jnp.zeros((3,), p_meas.dtype)) - p_meas

    def jacobian(*rest):
        *poses, p_meas = rest
        tip, blocks, _ = chain_jacobian(poses, chain, jnp.zeros((3,), p_meas.dtype))
        return tip - p_meas, tuple(blocks)

    fn.__jcalib_key__ = jacobian.__jcalib_key__ = recipe("position_measurement", chain)
    return fn, jacobian


@functools.cache
def pose_measurement(chain: Chain, part: str):
    """The rotation (``part="rotation"``, rad) or translation (``"translation"``, m) half of
    ``Log(T_meas⁻¹ · T_pred)``, ``(3,)``, where ``T_pred`` is the chain's composed pose.

    ``fn(*poses, obs)`` with ``obs = T_meas (7,)`` (``wxyz_xyz``): a sensor's measurement of a pose
    (a camera's PnP of a marker, a laser tracker, another tool's pose-pair file). To first order the
    residual is the measurement error as a right perturbation ``T_meas = T_true · Exp(−r)`` in the
    measured frame; the two halves are separate factor groups so that each gets its own noise σ
    (and its own variance component). Hand-eye from pose pairs (``A X = Y B``) is this residual.
    """
    sl = slice(0, 3) if part == "rotation" else slice(3, 6)

    def fn(*rest):
        *poses, T_meas = rest
        return lie.se3_log(lie.se3_compose(lie.se3_inverse(T_meas), chain_pose(poses, chain)))[sl]

    fn.__name__ = f"pose_measurement_{part}"
    fn.__jcalib_key__ = recipe("pose_measurement", chain, part)
    return fn


def axis_translation_prior(T, obs):
    """``(T (7,) wxyz_xyz, (axis (3,), value (1,))) -> (1,)``: ``axis · t − value`` (m), the translation
    of a transform along a unit axis against a stated value (e.g. a hand-eye translation that
    one-axis robot motion cannot determine)."""
    axis, value = obs
    return jnp.matmul(axis, T[4:7])[None] - value


_KINEMATIC: dict = {}


def _model_key(model) -> str:
    """A process-independent name of a kinematic model: its structure and a digest of its arrays."""
    leaves, treedef = jax.tree_util.tree_flatten(model)
    h = hashlib.sha256(repr(treedef).encode())
    for leaf in leaves:
        h.update(np.asarray(leaf, np.float64).tobytes())
    return h.hexdigest()[:24]


def kinematic(model):
    """A robot's flange pose against its kinematics, whitened, ``(6,)``: ``(fn, jacobian)``.

    ``fn(params (P,), T_base_flange (7,), obs)`` with ``obs = (q (n,), S (6, 6))``: ``S · Log(FK(params, q)⁻¹ ·
    T_base_flange)``, the station's flange pose as a right perturbation of the pose that the kinematic
    model (:func:`jcalib.geometry.kinematic_models.forward`, parameters ``params``) gives at the joint
    values ``q`` (rad, m), whitened by the square-root information ``S`` of the robot's repeatability.
    With the flange poses eliminated per station, this factor carries each station's evidence about
    the flange (from the cameras, contacts, pose sensors) into the kinematic parameters.

    ``jacobian`` is the Lie-group chain rule: with ``ξ = Log(M⁻¹ F)``, ``∂r/∂δ_F = S J_r(ξ)⁻¹`` and
    ``∂r/∂params = −S J_l(ξ)⁻¹ E``, ``E`` the model's own derivative ``(M⁻¹ ∂M/∂params)∨`` by forward-mode
    autodiff of the forward kinematics only (not through the matrix-to-quaternion branches and the
    logarithm's series, which made this factor half of a kinematic cell's compiled program).
    """
    key = _model_key(model)
    if key not in _KINEMATIC:
        def fn(params, T_base_flange, obs):
            q, S = obs
            T_model = lie.se3_from_matrix(kinematic_models.forward(model, params, q))
            return S @ lie.se3_log(lie.se3_compose(lie.se3_inverse(T_model), T_base_flange))

        def jacobian(params, T_base_flange, obs):
            q, S = obs
            M, tangent = jax.linearize(lambda p: kinematic_models.forward(model, p, q), params)  # one primal pass
            dM = jnp.moveaxis(jax.vmap(tangent)(jnp.eye(params.shape[0], dtype=params.dtype)), 0, -1)  # (4, 4, P)
            R = M[:3, :3]
            Z = jnp.einsum("ji,jkp->ikp", R, dM[:3, :3])  # Rᵀ ∂R: skew per parameter
            w = 0.5 * jnp.stack([Z[2, 1] - Z[1, 2], Z[0, 2] - Z[2, 0], Z[1, 0] - Z[0, 1]])
            E = jnp.concatenate([w, jnp.einsum("ji,jp->ip", R, dM[:3, 3])])  # (6, P)
            xi = lie.se3_log(lie.se3_compose(lie.se3_inverse(lie.se3_from_matrix(M)), T_base_flange))
            J_F = S @ se3_right_jacobian_inverse(xi, jnp)
            J_p = -(S @ se3_right_jacobian_inverse(-xi, jnp) @ E)
            return S @ xi, (J_p, J_F)

        fn.__name__ = "kinematic"
        fn.__jcalib_key__ = jacobian.__jcalib_key__ = recipe("kinematic", key)
        _KINEMATIC[key] = (fn, jacobian)
    return _KINEMATIC[key]
