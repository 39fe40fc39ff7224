"""The camera factor's hand-derived Jacobian (``FactorGroup.jacobian``) against autodiff.

The engine linearises the reprojection with autodiff through the lens model and the chain rule for
the poses (:func:`jcalib.problems.camera._reprojection_jacobian`). The references here are
independent of it: forward-mode autodiff of the residual through the manifolds' exact retraction
``x ⊞ δ`` (exp maps, not the first-order one the engine uses), and the engine's own linearisation
with the hand-derived Jacobian removed.
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
from jcalib.problems import camera as C
from jcalib.sim.scene import project_target, random_calibration_views
from jcalib.solve import SE3, Euclidean, FactorGroup, linear

MODELS = ("pinhole", "opencv4", "opencv5", "opencv8", "opencv12", "opencv14", "fisheye")
SIZE = (1280, 960)
BOARD = Checkerboard(cols=9, rows=6, square=0.03)


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


@functools.cache
def _both(model_cls, skew):
    """Jitted: the hand-derived Jacobian, and forward-mode autodiff through the exact retraction."""
    fn = C._reprojection_fn(model_cls, SIZE, skew)
    jac = C._reprojection_jacobian(model_cls, SIZE, skew)

    def both(intr, T_cam_ref, T_ref_target, obs):
        r, hand = jac(intr, T_cam_ref, T_ref_target, obs)
        se3, euc = SE3(), Euclidean(intr.shape[0])

        def through_retract(d_intr, d_rig, d_target):
            return fn(euc.retract(intr, d_intr), se3.retract(T_cam_ref, d_rig), se3.retract(T_ref_target, d_target),
                      obs)

        zeros = (jnp.zeros(intr.shape[0]), jnp.zeros(6), jnp.zeros(6))
        return r, hand, through_retract(*zeros), jax.jacfwd(through_retract, argnums=(0, 1, 2))(*zeros)

    return jax.jit(both)


@given(st.sampled_from(MODELS), st.booleans(), st.booleans(), st.integers(0, 2**31 - 1))
def test_hand_jacobian_equals_autodiff_through_the_exact_retraction(name, skew, aspect, seed):
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

    r, hand, r_ref, ref = _both(model_cls, skew)(jnp.asarray(intr), jnp.asarray(T_cam_ref),
                                                   jnp.asarray(T_ref_target), obs)
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-9)  # pixels
    scale = max(float(jnp.max(jnp.abs(x))) for x in ref)
    for mine, theirs in zip(hand, ref):
        # float64 rounding of two different derivative programs, relative to the largest entry
        np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-9 * scale)


def test_engine_linearisation_with_the_hand_jacobian_equals_autodiff():
    """Whole normal equations (weights, padding, fixed coordinates, rig) with and without the hook."""
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
    p = C._prepare(cell, obs, C.CameraCalibrationOptions())
    a = C._start_arrays(p)
    a["weight0"][5] = 0.0  # an outlier mask
    problem = C._problem_from_arrays(p.config, a)
    assert all(f.jacobian is not None for f in problem.factors)
    plain = tuple(FactorGroup(f.name, f.fn, f.args, f.indices, f.observations, f.sigma, f.sqrt_weight, f.loss,
                              f.chunk, jacobian=None) for f in problem.factors)
    autodiff = eqx.tree_at(lambda q: q.factors, problem, plain)
    assert all(f.jacobian is None for f in autodiff.factors)
    layout, free = linear.make_layout(problem), linear.free_masks(problem)
    x = problem.initial_values()
    _, sys_hand, m_hand = jax.jit(lambda q: linear.linearize(q, layout, x, free))(problem)
    _, sys_ad, m_ad = jax.jit(lambda q: linear.linearize(q, layout, x, free))(autodiff)
    assert int(m_hand) == int(m_ad)
    for mine, theirs in zip(jax.tree.leaves(sys_hand), jax.tree.leaves(sys_ad)):
        scale = max(float(jnp.max(jnp.abs(theirs))), 1e-300)
        np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-10 * scale)


@functools.cache
def _both_hand_eye(model_cls, skew, mount):
    """Jitted: the hand-eye factor's hand-derived Jacobian, and autodiff through the exact retraction."""
    from jcalib.problems.handeye import (
        _handeye_reprojection_fn,
        _handeye_reprojection_jacobian,
    )

    fn = _handeye_reprojection_fn(model_cls, SIZE, skew, mount)
    jac = _handeye_reprojection_jacobian(model_cls, SIZE, skew, mount)

    def both(intr, A, B, F, obs):
        r, hand = jac(intr, A, B, F, obs)
        se3, euc = SE3(), Euclidean(intr.shape[0])

        def through_retract(d_intr, d_a, d_b, d_f):
            return fn(euc.retract(intr, d_intr), se3.retract(A, d_a), se3.retract(B, d_b), se3.retract(F, d_f), obs)

        zeros = (jnp.zeros(intr.shape[0]), jnp.zeros(6), jnp.zeros(6), jnp.zeros(6))
        return r, hand, through_retract(*zeros), jax.jacfwd(through_retract, argnums=(0, 1, 2, 3))(*zeros)

    return jax.jit(both)


def _matrix(pose):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.asarray(lie.so3_to_matrix(pose[:4])), pose[4:]
    return T


@given(st.sampled_from(("opencv5", "fisheye", "opencv14")), st.sampled_from(("flange", "base")),
       st.integers(0, 2**31 - 1))
def test_hand_eye_jacobian_equals_autodiff_through_the_exact_retraction(name, mount, seed):
    """Both chains: ``X⁻¹ F⁻¹ Y p`` (camera on the flange) and ``C⁻¹ F T p`` (fixed camera)."""
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
    r, hand, r_ref, ref = _both_hand_eye(model_cls, False, mount)(
        jnp.asarray(intr), jnp.asarray(A), jnp.asarray(B), jnp.asarray(F), obs)
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-9)  # pixels
    scale = max(float(jnp.max(jnp.abs(x))) for x in ref)
    for mine, theirs in zip(hand, ref):
        np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-9 * scale)
