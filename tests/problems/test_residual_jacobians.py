"""The residual library's hand-derived Jacobians (``FactorGroup.jacobian``) against autodiff.

The engine linearises the pose-chain reprojection with autodiff through the lens model and the
closed-form chain rule for the poses (:func:`jcalib.residuals.chain.chain_jacobian`), and contacts
by the chain rule alone. The references here are independent of it: forward-mode autodiff of the
residual through the manifolds' exact retraction ``x ⊞ δ`` (exp maps, not the first-order one the
engine uses), and the engine's own linearisation of a whole cell problem with the hand-derived
Jacobians removed.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

import jcalib  # noqa: F401  (float64)
from jcalib.geometry import Checkerboard, camera_from_opencv, lie
from jcalib.geometry.cameras import camera_model_from_name
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.problems.calibrate import prepare
from jcalib.residuals.chain import chain_apply, chain_jacobian
from jcalib.residuals.pose import contact
from jcalib.residuals.reprojection import reprojection, tool_axis
from jcalib.sim.scene import project_target, random_calibration_views
from jcalib.solve import SE3, Euclidean, FactorGroup, linear

MODELS = ("pinhole", "opencv4", "opencv5", "opencv8", "opencv12", "opencv14", "fisheye")
SIZE = (1280, 960)
BOARD = Checkerboard(cols=9, rows=6, square=0.03)
#: p_cam = T_cam_ref · T_ref_target · p (a camera of a rig)
RIG = ((0, False), (1, False))
#: p_cam = X⁻¹ · F⁻¹ · Y · p (eye-in-hand: X = T_flange_cam, F = T_base_flange, Y = T_base_target); args (X, Y, F)
EYE_IN_HAND = ((0, True), (2, True), (1, False))
#: p_cam = X⁻¹ · F · Y · p (eye-to-hand: X = T_base_cam, Y = T_flange_target)
EYE_TO_HAND = ((0, True), (2, False), (1, False))


def _intrinsics(name: str, skew: bool, rng) -> tuple[type, np.ndarray]:
    model = camera_model_from_name(name, SIZE, skew=skew)
    names = model.param_names
    base = {"fx": 900.0, "fy": 880.0, "cx": 640.0, "cy": 480.0, "skew": 0.5, "alpha": 5e-4}
    p = np.array([base.get(n, 0.0) for n in names]) * (1.0 + 0.05 * rng.standard_normal(len(names)))
    for i, n in enumerate(names):
        if n not in base:  # distortion, thin prism, tilt: small, both signs
            p[i] = 0.05 * rng.standard_normal() * (0.2 if n in ("tx", "ty", "s1", "s2", "s3", "s4") else 1.0)
    return type(model), p


def _pose(rng, scale_t: float) -> np.ndarray:
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    return np.concatenate([q * np.sign(q[0]), scale_t * rng.standard_normal(3)])


def _matrix(pose):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.asarray(lie.so3_to_matrix(pose[:4])), pose[4:]
    return T


def _with_value(r):
    """``(r, r)``: a reference function for ``jax.jacfwd(..., has_aux=True)``, which then returns the residual
    from the same forward pass as its derivative (the residual program is traced and compiled once, not twice)."""
    return r, r


@functools.cache
def _both(model_cls, skew, chain):
    """Jitted: the hand-derived Jacobian, and forward-mode autodiff through the exact retraction."""
    fn, jac = reprojection(model_cls, SIZE, skew, chain)
    num = 1 + max(a for a, _ in chain)

    def both(intr, poses, obs):
        r, hand = jac(intr, *poses, obs)
        se3, euc = SE3(), Euclidean(intr.shape[0])

        def through_retract(d_intr, *d_poses):
            return _with_value(fn(euc.retract(intr, d_intr), *[se3.retract(T, d) for T, d in zip(poses, d_poses)], obs))

        zeros = (jnp.zeros(intr.shape[0]),) + (jnp.zeros(6),) * num
        ref, r_ref = jax.jacfwd(through_retract, argnums=tuple(range(num + 1)), has_aux=True)(*zeros)
        return r, hand, r_ref, ref

    return jax.jit(both)


def _compare(r, hand, r_ref, ref):
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-9)  # pixels
    scale = max(float(jnp.max(jnp.abs(x))) for x in ref)
    assert len(hand) == len(ref)
    for mine, theirs in zip(hand, ref):
        # float64 rounding of two different derivative programs, relative to the largest entry
        np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-9 * scale)


@given(st.sampled_from(MODELS), st.booleans(), st.booleans(), st.integers(0, 2**31 - 1))
def test_rig_reprojection_jacobian_equals_autodiff_through_the_exact_retraction(name, skew, aspect, seed):
    rng = np.random.default_rng(seed)
    model_cls, intr = _intrinsics(name, skew, rng)
    T_cam_ref = _pose(rng, 0.05)
    # a target point 0.4-1 m in front of the camera, near the optical axis (inside the valid disc)
    p_cam_wanted = np.array([*(0.15 * rng.uniform(-1, 1, 2)), rng.uniform(0.4, 1.0)])
    R_cr = np.asarray(lie.so3_to_matrix(T_cam_ref[:4]))
    p_ref = R_cr.T @ (p_cam_wanted - T_cam_ref[4:])
    T_ref_target = _pose(rng, 0.0)
    R_rt = np.asarray(lie.so3_to_matrix(T_ref_target[:4]))
    T_ref_target[4:] = p_ref - R_rt @ np.array([0.01, -0.02, 0.0])
    obs = (jnp.array([0.01, -0.02, 0.0]), jnp.array([600.0, 500.0]),
           jnp.array([1.0 if aspect else 0.0, 1.02]))
    _compare(*_both(model_cls, skew, RIG)(jnp.asarray(intr), (jnp.asarray(T_cam_ref), jnp.asarray(T_ref_target)), obs))


@given(st.sampled_from(("opencv5", "fisheye", "opencv14")), st.sampled_from(("flange", "base")),
       st.integers(0, 2**31 - 1))
def test_hand_eye_reprojection_jacobian_equals_autodiff_through_the_exact_retraction(name, mount, seed):
    """Both chains: ``X⁻¹ F⁻¹ Y p`` (camera on the flange) and ``X⁻¹ F Y p`` (fixed camera)."""
    rng = np.random.default_rng(seed)
    model_cls, intr = _intrinsics(name, False, rng)
    A, F = _pose(rng, 0.1), _pose(rng, 0.5)  # hand-eye transform, flange pose
    p = np.array([0.01, -0.02, 0.0])
    p_cam = np.array([*(0.15 * rng.uniform(-1, 1, 2)), rng.uniform(0.4, 1.0)])  # inside the valid disc
    # choose the target pose B so that p lands at p_cam: solve the chain for B's translation
    B = _pose(rng, 0.0)
    T_A, T_F, R_B = _matrix(A), _matrix(F), _matrix(B)[:3, :3]
    if mount == "flange":  # p_cam = A⁻¹ F⁻¹ B p  ->  B p = F A p_cam
        want = (T_F @ T_A @ np.append(p_cam, 1.0))[:3]
    else:  # p_cam = A⁻¹ F B p  ->  B p = F⁻¹ A p_cam
        want = (np.linalg.inv(T_F) @ T_A @ np.append(p_cam, 1.0))[:3]
    B[4:] = want - R_B @ p
    obs = (jnp.asarray(p), jnp.array([600.0, 500.0]), jnp.array([0.0, 1.0]))
    chain = EYE_IN_HAND if mount == "flange" else EYE_TO_HAND
    _compare(*_both(model_cls, False, chain)(jnp.asarray(intr), (jnp.asarray(A), jnp.asarray(B), jnp.asarray(F)),
                                            obs))


@functools.cache
def _chain_both(chain, num):
    def both(poses, p):
        q, blocks, dp = chain_jacobian(poses, chain, p)

        def through_retract(*deltas):  # the poses' tangents, then the point's
            *d_poses, d_p = deltas
            return _with_value(chain_apply([SE3().retract(T, d) for T, d in zip(poses, d_poses)], chain, p + d_p))

        zeros = (jnp.zeros(6),) * num + (jnp.zeros(3),)
        (*ref, dp_ref), q_ref = jax.jacfwd(through_retract, argnums=tuple(range(num + 1)), has_aux=True)(*zeros)
        return q, blocks, dp, q_ref, ref, dp_ref

    return jax.jit(both)


#: Chains of up to 5 poses over 3 arguments: inverted or not, a pose used twice (B·A⁻¹·B), a pose
#: and its own inverse next to each other, every argument unused somewhere.
CHAINS = (
    ((0, False),),
    ((1, True),),
    ((0, True), (2, True), (1, False)),
    ((0, True), (2, False), (1, False)),
    ((2, False), (0, True), (2, False)),
    ((1, False), (1, True), (0, False), (2, True)),
    ((0, True), (1, False), (2, True), (1, True), (0, False)),
)


@given(st.sampled_from(CHAINS), st.integers(0, 2**31 - 1))
def test_chain_rule_of_any_chain_equals_autodiff(chain, seed):
    """Chains of poses (inverted or not, a pose used several times), as every residual of a cell is
    built from: the point and its derivatives by the pose tangents and by the input point."""
    rng = np.random.default_rng(seed)
    poses = [jnp.asarray(_pose(rng, 0.3)) for _ in range(3)]
    p = jnp.asarray(rng.uniform(-0.2, 0.2, 3))
    q, blocks, dp, q_ref, ref, dp_ref = _chain_both(chain, 3)(poses, p)
    np.testing.assert_allclose(q, q_ref, rtol=0, atol=1e-12)  # m
    for a in range(3):
        np.testing.assert_allclose(blocks[a], ref[a], rtol=0, atol=1e-11)
    np.testing.assert_allclose(dp, dp_ref, rtol=0, atol=1e-12)


@functools.cache
def _contact_both(chain):
    fn, jac = contact(chain)

    def both(poses, point, obs):
        def through_retract(*deltas):
            *d_poses, d_point = deltas
            return _with_value(fn(*[SE3().retract(T, d) for T, d in zip(poses, d_poses)], point + d_point, obs))

        zeros = (jnp.zeros(6),) * len(poses) + (jnp.zeros(3),)
        r, hand = jac(*poses, point, obs)
        ref, r_ref = jax.jacfwd(through_retract, argnums=tuple(range(len(zeros))), has_aux=True)(*zeros)
        return r, hand, r_ref, ref

    return jax.jit(both)


@given(st.booleans(), st.integers(0, 2**31 - 1))
def test_contact_jacobian_equals_autodiff(with_base, seed):
    """A tool tip touching a cell point: ``(B ·) F · T · 0 − p`` (with a robot base for several robots)."""
    rng = np.random.default_rng(seed)
    chain = ((0, False), (1, False), (2, False)) if with_base else ((0, False), (1, False))
    poses = tuple(jnp.asarray(_pose(rng, 0.5)) for _ in range(len(chain)))
    r, hand, r_ref, ref = _contact_both(chain)(poses, jnp.asarray(rng.uniform(-1, 1, 3)), jnp.zeros(1))
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-12)
    assert len(hand) == len(ref)
    for mine, theirs in zip(hand, ref):
        np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-11)


def test_engine_linearisation_with_the_hand_jacobian_equals_autodiff():
    """Whole normal equations of a stereo rig built by the one builder (weights, view runs, fixed
    coordinates, the rig chain) with and without the hand-derived Jacobians."""
    rng = np.random.default_rng(3)
    cams = {}
    for i, name in enumerate(("cam0", "cam1")):
        K = np.array([[900.0 + 20 * i, 0, 640.0], [0, 905.0, 480.0], [0, 0, 1]])
        cams[name] = camera_from_opencv(K, np.array([-0.1, 0.02, 1e-3, -1e-3, 0.0]), SIZE)
    poses = random_calibration_views(cams["cam0"], BOARD.points, 8, rng=rng)
    T_c1_c0 = np.eye(4)
    T_c1_c0[0, 3] = -0.1
    stations = []
    for i, T in enumerate(poses):
        dets = []
        for name, T_cam_target in (("cam0", T), ("cam1", T_c1_c0 @ T)):
            pix, _ = project_target(cams[name], T_cam_target, BOARD.points)
            dets.append({"camera": name, "target": "board", "point_index": list(range(len(BOARD.points))),
                         "pixels": (pix + 0.3 * rng.standard_normal(pix.shape)).tolist()})
        stations.append({"id": f"v{i:03d}", "detections": dets})
    obs = parse_observations({"schema": "jcalib.observations/1",
                              "cameras": {n: {"image_size": list(SIZE)} for n in cams},
                              "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations})
    cell = parse_cell({"schema": "jcalib.cell/1",
                       "cameras": {n: {"model": "opencv5", "fix": ["k3"]} for n in cams},
                       "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}})
    _, _, built = prepare(cell, obs)
    weights = built.unit_weights()
    weights["corners:cam1/board"][5] = 0.0  # an outlier mask
    problem = built.with_weights(weights)
    assert len(problem.factors) == 2 and all(f.jacobian is not None for f in problem.factors)
    plain = tuple(FactorGroup(f.name, f.fn, f.args, f.indices, f.observations, f.sigma, f.sqrt_weight, f.loss,
                              f.chunk, jacobian=None) for f in problem.factors)
    autodiff = eqx.tree_at(lambda q: q.factors, problem, plain)
    assert all(f.jacobian is None for f in autodiff.factors)
    layout, free = linear.make_layout(problem), linear.free_masks(problem)
    x = jax.tree.map(jnp.asarray, problem.initial_values())  # the builder's start values are NumPy
    _, sys_hand, m_hand, _ = jax.jit(lambda q: linear.linearize(q, layout, x, free))(problem)
    _, sys_ad, m_ad, _ = jax.jit(lambda q: linear.linearize(q, layout, x, free))(autodiff)
    assert int(m_hand) == int(m_ad)
    for mine, theirs in zip(jax.tree.leaves(sys_hand), jax.tree.leaves(sys_ad)):
        scale = max(float(jnp.max(jnp.abs(theirs))), 1e-300)
        np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-10 * scale)


#: p_cam = X⁻¹ · F · T · p (a fixed camera seeing a tool: X = T_base_cam, F = T_base_flange, T = T_flange_tool)
TOOL_IN_FIXED_CAMERA = ((0, True), (1, False), (2, False))


@functools.cache
def _axis_both(model_cls):
    fn, jac = tool_axis(model_cls, SIZE, False, TOOL_IN_FIXED_CAMERA)

    def both(intr, poses, obs):
        r, hand = jac(intr, *poses, obs)
        se3, euc = SE3(), Euclidean(intr.shape[0])

        def through_retract(d_intr, *d_poses):  # autodiff through the foot's iterations
            return _with_value(fn(euc.retract(intr, d_intr), *[se3.retract(T, d) for T, d in zip(poses, d_poses)], obs))

        zeros = (jnp.zeros(intr.shape[0]),) + (jnp.zeros(6),) * 3
        ref, r_ref = jax.jacfwd(through_retract, argnums=(0, 1, 2, 3), has_aux=True)(*zeros)
        return r, hand, r_ref, ref

    return jax.jit(both)


@given(st.sampled_from(("opencv5", "opencv8", "fisheye")), st.floats(-8.0, 8.0), st.floats(-0.03, 0.03),
       st.integers(0, 2**31 - 1))
def test_tool_axis_jacobian_equals_autodiff_through_the_foot(name, offset_px, along_m, seed):
    """The tool axis's envelope-theorem Jacobian (a point reprojection's derivative at the foot, along the
    curve's normal) against forward-mode autodiff of the residual through its foot iterations."""
    rng = np.random.default_rng(seed)
    model_cls, intr = _intrinsics(name, False, rng)
    model = model_cls.from_params(SIZE, jnp.asarray(intr), skew=False)
    tip_cam = np.array([*(0.1 * rng.uniform(-1, 1, 2)), rng.uniform(0.5, 0.9)])
    # the tool's z at least 30° from the viewing ray (an edge-on axis is the safe branch, not this test)
    while True:
        z_cam = rng.standard_normal(3)
        z_cam /= np.linalg.norm(z_cam)
        if abs(z_cam @ tip_cam) / np.linalg.norm(tip_cam) < np.cos(np.radians(30)):
            break
    x_cam = np.cross(z_cam, rng.standard_normal(3))
    x_cam /= np.linalg.norm(x_cam)
    T_cam_tool = np.eye(4)
    T_cam_tool[:3, :3], T_cam_tool[:3, 3] = np.stack([x_cam, np.cross(z_cam, x_cam), z_cam], 1), tip_cam
    X, T = _pose(rng, 0.8), _pose(rng, 0.15)
    F_m = _matrix(X) @ T_cam_tool @ np.linalg.inv(_matrix(T))
    F = np.concatenate([np.asarray(lie.so3_from_matrix(F_m[:3, :3])), F_m[:3, 3]])
    # an observed axis point: the image of a point along the axis, moved off the curve by offset_px
    on = np.asarray(model.project(jnp.asarray(tip_cam + along_m * z_cam)))
    nxt = np.asarray(model.project(jnp.asarray(tip_cam + (along_m + 1e-4) * z_cam)))
    t = (nxt - on) / np.linalg.norm(nxt - on)
    point = on + offset_px * np.array([-t[1], t[0]])
    obs = (jnp.asarray(point), jnp.asarray(0.04), jnp.array([0.0, 1.0]))
    r, hand, r_ref, ref = _axis_both(model_cls)(jnp.asarray(intr), tuple(jnp.asarray(a) for a in (X, F, T)), obs)
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-12)  # pixels: the same forward computation
    np.testing.assert_allclose(abs(float(r[0])), abs(offset_px), rtol=0, atol=0.05)  # the distance it was built with
    scale = max(float(jnp.max(jnp.abs(x))) for x in ref)
    assert len(hand) == len(ref)
    for mine, theirs in zip(hand, ref):
        # equal at the exact foot; the foot's three Gauss–Newton steps leave far less than this
        np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-8 * scale)


@st.composite
def _tangents(draw):
    """SE(3) tangents with rotations from 0 through the series threshold (0.1 rad) to near π."""
    axis = np.array(draw(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3)))
    n = np.linalg.norm(axis)
    axis = axis / n if n > 1e-3 else np.array([0.0, 0.0, 1.0])
    angle = draw(st.sampled_from([0.0, 1e-8, 1e-4, 0.05, 0.0999, 0.1001, 0.5, 2.0, 3.0]))
    v = np.array(draw(st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3)))
    return np.r_[angle * axis, v]


@jax.jit
def _jr_inv_both(xi):
    from jcalib.geometry import lie_kernels as K

    T = K.se3_exp(xi, jnp)
    ref = jax.jacfwd(lambda d: K.se3_log(K.se3_compose(T, K.se3_exp(d, jnp), jnp), jnp))(jnp.zeros(6))
    return K.se3_right_jacobian_inverse(xi, jnp), ref, K.so3_right_jacobian_inverse(xi[:3], jnp)


@given(_tangents())
def test_se3_right_jacobian_inverse_is_the_derivative_of_the_log(xi):
    """``J_r(ξ)⁻¹`` (closed form and series) against autodiff of ``Log(Exp(ξ) Exp(δ))`` at ``δ = 0``."""
    mine, ref, so3 = _jr_inv_both(jnp.asarray(xi))
    np.testing.assert_allclose(mine, ref, rtol=0, atol=1e-12 * max(1.0, float(np.abs(xi[3:]).max())))
    np.testing.assert_allclose(so3, mine[:3, :3], rtol=0, atol=1e-15)


@functools.cache
def _prior_both(manifold):
    from jcalib.residuals.priors import gaussian_prior_jacobian, gaussian_prior_residual

    fn, jac = gaussian_prior_residual(manifold), gaussian_prior_jacobian(manifold)

    def both(x, obs):
        r, (J,) = jac(x, obs)
        ref, r_ref = jax.jacfwd(lambda d: _with_value(fn(manifold.retract(x, d), obs)), has_aux=True)(
            jnp.zeros(manifold.tangent_dim))
        return r, J, r_ref, ref

    return jax.jit(both)


@given(st.sampled_from(["se3", "so3", "euclidean"]), st.floats(0.0, 3.0), st.integers(0, 2**31 - 1))
def test_prior_jacobian_equals_autodiff(kind, angle, seed):
    from jcalib.solve import SO3

    rng = np.random.default_rng(seed)
    if kind == "euclidean":
        m, mean, x = Euclidean(4), rng.standard_normal(4), rng.standard_normal(4)
    else:
        m = SE3() if kind == "se3" else SO3()
        mean = _pose(rng, 0.5)[: m.param_dim]
        w = rng.standard_normal(3)
        d = np.r_[angle * w / np.linalg.norm(w), 0.3 * rng.standard_normal(3)][: m.tangent_dim]
        x = np.asarray(m.retract(jnp.asarray(mean), jnp.asarray(d)))
    S = np.triu(rng.standard_normal((m.tangent_dim, m.tangent_dim))) + 3.0 * np.eye(m.tangent_dim)
    r, J, r_ref, ref = _prior_both(m)(jnp.asarray(x), (jnp.asarray(mean), jnp.asarray(S)))
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(J, ref, rtol=0, atol=1e-10)


@functools.cache
def _kinematic_both(preset):
    from jcalib.geometry import kinematic_models
    from jcalib.residuals.pose import kinematic

    model = kinematic_models.PRESETS[preset]()
    fn, jac = kinematic(model)

    def both(params, F, obs):
        r, hand = jac(params, F, obs)

        def through_retract(dp, dF):
            return _with_value(fn(params + dp, SE3().retract(F, dF), obs))

        ref, r_ref = jax.jacfwd(through_retract, argnums=(0, 1), has_aux=True)(jnp.zeros_like(params), jnp.zeros(6))
        return r, hand, r_ref, ref

    return model, jax.jit(both)


@given(st.integers(0, 2**31 - 1))
def test_kinematic_jacobian_equals_autodiff(seed):
    """A flange pose against a 6-axis arm's kinematics: the Lie chain rule (forward-mode FK only) against
    autodiff of the whole residual, at perturbed parameters and a flange pose off the model's."""
    from jcalib.geometry import kinematic_models

    model, both = _kinematic_both("kuka_kr10_r1100_sixx")
    rng = np.random.default_rng(seed)
    params = np.asarray(model.nominal, np.float64) + 1e-3 * rng.standard_normal(model.num_params)
    q = rng.uniform(-1.5, 1.5, 6)
    M = np.asarray(kinematic_models.forward(model, jnp.asarray(params), jnp.asarray(q)))
    off = np.asarray(SE3().retract(jnp.asarray(np.r_[1.0, 0, 0, 0, 0, 0, 0]), jnp.asarray(0.05 * rng.standard_normal(6))))
    F = np.asarray(lie.se3_compose(lie.se3_from_matrix(jnp.asarray(M)), jnp.asarray(off)))
    S = np.diag(1.0 / np.r_[np.full(3, 1e-4), np.full(3, 2e-5)])
    r, hand, r_ref, ref = both(jnp.asarray(params), jnp.asarray(F), (jnp.asarray(q), jnp.asarray(S)))
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-9 * float(np.abs(r_ref).max()))
    for mine, theirs in zip(hand, ref):
        scale = float(jnp.max(jnp.abs(theirs)))
        np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-9 * scale)
