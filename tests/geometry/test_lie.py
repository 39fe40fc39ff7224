"""SO(3)/SE(3): exp/log, matrices, rvecs, retract/local and their derivatives.

Independent references: scipy.spatial.transform.Rotation, scipy.linalg.expm of the twist matrix,
cv2.Rodrigues, finite differences, and closed-form group identities. Tolerances: 1e-12 for float64
identities that chain a few operations (rounding ~1e-15 per op, times the number of ops and |t|),
1e-7 for central finite differences (step 1e-6: truncation ~h^2, rounding ~eps/h).
"""

import cv2
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
import scipy.linalg
from hypothesis import given
from scipy.spatial.transform import Rotation

from jcalib.errors import BadInputError
from jcalib.geometry import lie

PI = np.pi
# angles that stress the small-angle series, their switch-over (1e-2 rad), and the log near pi
SPECIAL_ANGLES = [0.0, 1e-12, 1e-9, 1e-6, 1e-3, 0.00999, 0.01, 0.0101, 0.02, 1.0, 3.0,
                  PI - 1e-3, PI - 1e-6, PI - 1e-9]
angles = st.one_of(st.sampled_from(SPECIAL_ANGLES), st.floats(0.0, PI - 1e-9))
unit_vectors = (
    st.tuples(*[st.floats(-1.0, 1.0, allow_subnormal=False)] * 3)
    .map(np.array)
    .filter(lambda v: np.linalg.norm(v) > 1e-3)
    .map(lambda v: v / np.linalg.norm(v))
)
rvecs = st.builds(lambda ax, th: ax * th, unit_vectors, angles)
translations = st.tuples(*[st.floats(-2.0, 2.0, allow_subnormal=False)] * 3).map(np.array)
tangents = st.builds(lambda r, t: np.concatenate([r, t]), rvecs, translations)
poses = tangents.map(lambda d: np.asarray(lie.se3_exp(d)))


def _twist_expm(delta):
    """Reference SE(3) exp: matrix exponential of the 4x4 twist [[w]x, v; 0, 0]."""
    w, v = delta[:3], delta[3:]
    m = np.zeros((4, 4))
    m[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    m[:3, 3] = v
    return scipy.linalg.expm(m)


def _same_rvec(a, b, tol):
    """rvecs equal, or antipodal when the angle is pi (both represent the same rotation)."""
    if np.abs(a - b).max() <= tol:
        return True
    return abs(np.linalg.norm(a) - PI) < 1e-6 and np.abs(a + b).max() <= tol


# jit once per helper, reuse shapes across examples
_so3_exp_mat = jax.jit(lambda r: lie.so3_to_matrix(lie.so3_from_rvec(r)))
_so3_log_mat = jax.jit(lambda m: lie.so3_to_rvec(lie.so3_from_matrix(m)))
_se3_exp_mat = jax.jit(lambda d: lie.se3_to_matrix(lie.se3_exp(d)))
_se3_log = jax.jit(lie.se3_log)
_se3_exp_log = jax.jit(lambda d: lie.se3_log(lie.se3_exp(d)))
_retract = jax.jit(lie.retract)
_local = jax.jit(lie.local)


def _composite(T, U, d):  # the solver's pattern: residual of a retracted pose against a reference
    return lie.local(U, lie.retract(T, d))


_composite_jit = jax.jit(_composite)
_composite_jacfwd = jax.jit(jax.jacfwd(_composite, argnums=2))
_composite_jacrev = jax.jit(jax.jacrev(_composite, argnums=2))
_rvec_roundtrip_jac = jax.jit(jax.jacfwd(lambda x: lie.so3_to_rvec(lie.so3_from_rvec(x))))
_se3_roundtrip_jac = jax.jit(jax.jacrev(lambda x: lie.se3_log(lie.se3_exp(x))))
_so3_log_mat_jac = jax.jit(jax.jacfwd(_so3_log_mat))


@given(rvecs)
def test_so3_exp_matches_scipy_and_opencv(r):
    m = np.asarray(_so3_exp_mat(r))
    np.testing.assert_allclose(m, Rotation.from_rotvec(r).as_matrix(), rtol=0, atol=1e-14)
    np.testing.assert_allclose(m, cv2.Rodrigues(r)[0], rtol=0, atol=1e-14)
    assert m.dtype == np.float64


@given(rvecs)
def test_so3_log_recovers_rvec_through_matrix(r):
    # ground truth r -> matrix by scipy (independent) -> our log. Exact even at 1e-9 rad and
    # pi - 1e-9, where cv2.Rodrigues(matrix) returns 0 (below 1e-5 rad) or loses 8 digits.
    got = np.asarray(_so3_log_mat(Rotation.from_rotvec(r).as_matrix()))
    assert _same_rvec(got, r, 1e-14 + 1e-15 * np.linalg.norm(r))
    assert np.linalg.norm(got) <= PI + 1e-15
    # and OpenCV maps our rvec back to the same matrix
    np.testing.assert_allclose(cv2.Rodrigues(got)[0], cv2.Rodrigues(r)[0], rtol=0, atol=1e-14)


@given(st.builds(lambda ax, th: ax * th, unit_vectors, st.floats(1e-3, PI - 1e-2)))
def test_so3_log_matches_opencv_where_opencv_is_accurate(r):
    m = cv2.Rodrigues(r)[0]
    np.testing.assert_allclose(_so3_log_mat(m), cv2.Rodrigues(m)[0].ravel(), rtol=0, atol=1e-11)


@given(tangents)
def test_se3_exp_matches_matrix_exponential(delta):
    np.testing.assert_allclose(_se3_exp_mat(delta), _twist_expm(delta), rtol=0, atol=1e-12)


@given(tangents)
def test_se3_log_inverts_exp(delta):
    got = np.asarray(_se3_exp_log(delta))
    if np.linalg.norm(delta[:3]) < PI - 1e-6:
        np.testing.assert_allclose(got, delta, rtol=0, atol=1e-12)
    # whatever the branch, exp(log(exp(d))) == exp(d)
    np.testing.assert_allclose(_se3_exp_mat(got), _twist_expm(delta), rtol=0, atol=1e-12)


@given(poses)
def test_exp_log_pose_roundtrip(pose):
    back = lie.se3_exp(_se3_log(pose))
    np.testing.assert_allclose(lie.se3_to_matrix(back), lie.se3_to_matrix(pose), atol=1e-12)


def test_se3_exp_matches_jaxlie_with_reordered_tangent():
    rng = np.random.default_rng(0)
    delta = rng.normal(size=(16, 6))
    ours = lie.se3_exp(delta)
    # jaxlie's batched SE3 needs the default promotion rules; its tangent is (v, omega)
    with jax.numpy_dtype_promotion("standard"), jax.numpy_rank_promotion("allow"):
        ref = jaxlie.SE3.exp(jnp.concatenate([delta[:, 3:], delta[:, :3]], axis=-1)).wxyz_xyz
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-14)


@given(poses)
def test_matrix_roundtrip_and_quaternion_layout(pose):
    m = np.asarray(lie.se3_to_matrix(pose))
    q = pose[:4]
    np.testing.assert_allclose(
        m[:3, :3], Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix(), atol=1e-14
    )
    np.testing.assert_allclose(m[:3, 3], pose[4:], atol=0)
    np.testing.assert_array_equal(m[3], [0.0, 0.0, 0.0, 1.0])
    back = np.asarray(lie.se3_from_matrix(m))
    assert back[0] >= 0.0
    expect = pose.copy()
    if pose[0] < 0:
        expect[:4] = -expect[:4]
    # at w == 0 exactly either sign is valid
    if abs(pose[0]) < 1e-12:
        if np.abs(back[:4] - expect[:4]).max() > 1e-6:
            expect[:4] = -expect[:4]
    np.testing.assert_allclose(back, expect, atol=1e-14)


@given(st.tuples(*[st.floats(-2.0, 2.0, allow_subnormal=False)] * 4).filter(lambda q: np.linalg.norm(q) > 1e-3))
def test_quat_normalize_sign(q):
    q = np.array(q)
    out = np.asarray(lie.quat_normalize_sign(q))
    assert out[0] >= 0.0
    np.testing.assert_allclose(np.abs(out), np.abs(q), atol=0)
    np.testing.assert_allclose(lie.so3_to_matrix(out), lie.so3_to_matrix(q), atol=1e-15)


@given(rvecs, translations)
def test_rvec_tvec_against_opencv(r, t):
    pose = lie.se3_from_rvec_tvec(r, t)
    assert float(pose[0]) >= 0.0
    m = np.asarray(lie.se3_to_matrix(pose))
    np.testing.assert_allclose(m[:3, :3], cv2.Rodrigues(r)[0], atol=1e-14)
    r2, t2 = lie.se3_to_rvec_tvec(pose)
    assert _same_rvec(np.asarray(r2), r, 1e-14)
    np.testing.assert_array_equal(t2, t)


@given(poses, tangents)
def test_retract_and_local_are_inverse(pose, delta):
    moved = _retract(pose, delta)
    np.testing.assert_allclose(np.linalg.norm(moved[:4]), 1.0, atol=1e-15)
    # T . Exp(d) against the matrix product with the matrix exponential
    np.testing.assert_allclose(
        lie.se3_to_matrix(moved), lie.se3_to_matrix(pose) @ _twist_expm(delta), atol=1e-12
    )
    back = np.asarray(_local(pose, moved))
    if np.linalg.norm(delta[:3]) < PI - 1e-6:
        np.testing.assert_allclose(back, delta, atol=1e-12)
    np.testing.assert_allclose(
        lie.se3_to_matrix(_retract(pose, back)), lie.se3_to_matrix(moved), atol=1e-12
    )


def _central_diff(f, x, h=1e-6):
    cols = []
    for i in range(x.shape[0]):
        e = np.zeros_like(x)
        e[i] = h
        cols.append((np.asarray(f(x + e)) - np.asarray(f(x - e))) / (2 * h))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 0.3, PI - 1e-9])
def test_retract_local_jacobians_agree_with_finite_differences(angle):
    rng = np.random.default_rng(1)
    ax = rng.normal(size=3)
    ax /= np.linalg.norm(ax)
    T = np.asarray(lie.se3_exp(np.concatenate([angle * ax, [0.3, -0.2, 0.5]])))
    U = np.asarray(lie.se3_exp(np.concatenate([(angle * 0.5) * ax[::-1], [0.1, 0.4, -0.3]])))

    for d0 in (np.zeros(6), 1e-3 * rng.normal(size=6)):
        jf = np.asarray(_composite_jacfwd(T, U, d0))
        jr = np.asarray(_composite_jacrev(T, U, d0))
        fd = _central_diff(lambda d: _composite_jit(T, U, d), d0)
        assert np.all(np.isfinite(jf)) and np.all(np.isfinite(jr))
        np.testing.assert_allclose(jf, jr, atol=1e-12)
        np.testing.assert_allclose(jf, fd, atol=1e-7)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-9, 0.01, PI - 1e-9, PI])
def test_rvec_derivatives_finite_near_zero_and_pi(angle):
    r = angle * np.array([0.6, -0.8, 0.0])
    jac = np.asarray(_rvec_roundtrip_jac(r))
    np.testing.assert_allclose(jac, np.eye(3), atol=1e-12)
    jac = np.asarray(_se3_roundtrip_jac(np.r_[r, 1.0, 2.0, 3.0]))
    np.testing.assert_allclose(jac, np.eye(6), atol=1e-11)
    # the matrix route: d rvec / d R is finite too (Shepperd pivot >= 1)
    m = Rotation.from_rotvec(r).as_matrix()
    assert np.all(np.isfinite(np.asarray(_so3_log_mat_jac(m))))


def test_adjoint_moves_perturbation_to_the_left():
    rng = np.random.default_rng(2)
    T = lie.se3_exp(rng.normal(size=6))
    d = 0.3 * rng.normal(size=6)
    ad = lie.se3_adjoint(T)
    lhs = lie.se3_to_matrix(lie.se3_compose(T, lie.se3_exp(d)))
    rhs = lie.se3_to_matrix(lie.se3_compose(lie.se3_exp(ad @ d), T))
    np.testing.assert_allclose(lhs, rhs, atol=1e-13)


def test_compose_inverse_apply_match_matrices():
    rng = np.random.default_rng(3)
    a = lie.se3_exp(rng.normal(size=(5, 6)))
    b = lie.se3_exp(rng.normal(size=(5, 6)))
    ma, mb = np.asarray(lie.se3_to_matrix(a)), np.asarray(lie.se3_to_matrix(b))
    np.testing.assert_allclose(lie.se3_to_matrix(lie.se3_compose(a, b)), ma @ mb, atol=1e-13)
    np.testing.assert_allclose(lie.se3_to_matrix(lie.se3_inverse(a)), np.linalg.inv(ma), atol=1e-13)
    pts = rng.normal(size=(7, 3))
    got = lie.se3_apply(a[:, None, :], pts)  # (5, 1, 7) with (7, 3) -> (5, 7, 3)
    ref = np.einsum("vij,nj->vni", ma[:, :3, :3], pts) + ma[:, None, :3, 3]
    np.testing.assert_allclose(got, ref, atol=1e-13)
    np.testing.assert_allclose(lie.quat_rotate(a[0, :4], pts), pts @ ma[0, :3, :3].T, atol=1e-14)
    np.testing.assert_allclose(
        lie.so3_to_matrix(lie.quat_multiply(a[:, :4], lie.quat_inverse(a[:, :4]))),
        np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-14,
    )


def test_batched_and_vmapped_agree_with_single():
    rng = np.random.default_rng(4)
    d = rng.normal(size=(2, 3, 6))
    batched = _se3_exp_log(d)
    vmapped = jax.jit(jax.vmap(jax.vmap(_se3_exp_log)))(d)
    single = _se3_exp_log(d[1, 2])
    assert batched.shape == (2, 3, 6)
    np.testing.assert_allclose(batched, vmapped, atol=1e-15)
    np.testing.assert_allclose(batched[1, 2], single, atol=1e-15)
    assert lie.se3_identity((4,)).shape == (4, 7)


def test_so3_retract_local():
    rng = np.random.default_rng(5)
    q = lie.so3_exp(rng.normal(size=(4, 3)))
    w = 0.5 * rng.normal(size=(4, 3))
    moved = lie.so3_retract(q, w)
    np.testing.assert_allclose(
        lie.so3_to_matrix(moved), lie.so3_to_matrix(q) @ Rotation.from_rotvec(w).as_matrix(),
        atol=1e-14,
    )
    np.testing.assert_allclose(lie.so3_local(q, moved), w, atol=1e-14)


@given(rvecs, rvecs)
def test_rotation_angle_between_matches_scipy(r1, r2):
    a, b = Rotation.from_rotvec(r1), Rotation.from_rotvec(r2)
    ref = (a.inv() * b).magnitude()
    qa, qb = lie.so3_from_rvec(r1), lie.so3_from_rvec(r2)
    for x, y in ((qa, qb), (a.as_matrix(), b.as_matrix())):
        got = float(lie.rotation_angle_between(x, y))
        assert abs(got - ref) < 1e-12


def test_rotation_angle_between_is_accurate_at_tiny_angles_and_differentiable():
    q = lie.so3_from_rvec(np.array([0.1, 0.2, 0.3]))
    q2 = lie.so3_retract(q, np.array([1e-10, 0.0, 0.0]))
    # quaternion components carry ~1e-16 absolute rounding, so ~1e-16 absolute is the limit;
    # arccos((trace - 1) / 2) would be off by ~1e-8 here
    assert abs(float(lie.rotation_angle_between(q, q2)) - 1e-10) < 1e-15
    g = jax.grad(lambda x: lie.rotation_angle_between(x, x))(q)
    assert np.all(np.isfinite(np.asarray(g)))


def test_bad_shapes_raise():
    with pytest.raises(BadInputError, match="pose"):
        lie.se3_to_matrix(np.zeros(6))
    with pytest.raises(BadInputError, match="rvec"):
        lie.se3_from_rvec_tvec(np.zeros(4), np.zeros(3))
    with pytest.raises(BadInputError, match="matrix"):
        lie.se3_from_matrix(np.eye(3))
    with pytest.raises(BadInputError, match="expected quaternions"):
        lie.rotation_angle_between(np.zeros(5), np.zeros(5))
