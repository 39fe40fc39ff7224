"""The NumPy SE(3) module (jcalib.geometry.se3) against independent implementations.

References: scipy.spatial.transform.Rotation (rotation vectors, quaternions, axis-angle), np.cross,
and jcalib.geometry.lie (the JAX algebra, which shares none of se3's code but ``skew``). Every
function is checked batched over a leading axis against the same function one element at a time.
Tolerances: 1e-12 for float64 identities over a few operations (angles up to pi, translations up
to 2 m); near an angle of pi the rotation vector's axis is defined only up to sign.
"""

import hypothesis.strategies as st
import jax
import numpy as np
import pytest
from hypothesis import given
from scipy.spatial.transform import Rotation

from jcalib.errors import BadInputError
from jcalib.geometry import lie, se3

PI = np.pi
SPECIAL_ANGLES = [0.0, 1e-13, 1e-9, 1e-6, 1e-3, 0.5, 3.0, PI - 1e-3, PI - 1e-7]
angles = st.one_of(st.sampled_from(SPECIAL_ANGLES), st.floats(0.0, PI - 1e-7))
unit_vectors = (
    st.tuples(*[st.floats(-1.0, 1.0, allow_subnormal=False)] * 3)
    .map(np.array)
    .filter(lambda v: np.linalg.norm(v) > 1e-3)
    .map(lambda v: v / np.linalg.norm(v))
)
rvecs = st.builds(lambda ax, th: ax * th, unit_vectors, angles)
vectors = st.tuples(*[st.floats(-2.0, 2.0, allow_subnormal=False)] * 3).map(np.array)
batches = st.integers(1, 5)


def _batch(strategy):
    return st.lists(strategy, min_size=1, max_size=5).map(np.stack)


def _poses(rv, t):
    return se3.make_pose(Rotation.from_rotvec(rv).as_matrix(), t)


_lie_adjoint = jax.jit(lambda T: lie.se3_adjoint(lie.se3_from_matrix(T)))
_lie_log = jax.jit(lambda T: lie.se3_log(lie.se3_from_matrix(T)))
_lie_exp_mat = jax.jit(lambda d: lie.se3_to_matrix(lie.se3_exp(d)))
_lie_quat = jax.jit(lie.so3_from_matrix)


def _same_rvec(a, b, tol=1e-12):
    """Equal, or antipodal at an angle of pi (both the same rotation)."""
    return np.abs(a - b).max() <= tol or (abs(np.linalg.norm(a) - PI) < 1e-6 and np.abs(a + b).max() <= tol)


@given(_batch(vectors), _batch(vectors))
def test_skew_is_the_cross_product(a, b):
    n = min(len(a), len(b))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", se3.skew(a[:n]), b[:n]), np.cross(a[:n], b[:n]), atol=1e-14)
    np.testing.assert_array_equal(se3.skew(a), -np.swapaxes(se3.skew(a), -1, -2))


@given(_batch(rvecs))
def test_exp_so3_matches_scipy(w):
    R = se3.exp_so3(w)
    assert R.shape == (len(w), 3, 3)
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-14)
    for k in range(len(w)):  # batched == one at a time
        np.testing.assert_array_equal(se3.exp_so3(w[k]), R[k])


@given(_batch(rvecs))
def test_rotvec_inverts_exp_so3_and_matches_scipy(w):
    R = Rotation.from_rotvec(w).as_matrix()
    r = se3.rotvec(R)
    assert r.shape == (len(w), 3)
    ref = Rotation.from_matrix(R).as_rotvec()
    for k in range(len(w)):
        assert _same_rvec(r[k], w[k]), (r[k], w[k])
        assert _same_rvec(r[k], ref[k]), (r[k], ref[k])
        np.testing.assert_array_equal(se3.rotvec(R[k]), r[k])
    assert np.all(np.linalg.norm(r, axis=-1) <= PI + 1e-15)
    assert se3.log_so3 is se3.rotvec


@given(rvecs)
def test_rotvec_small_angles_keep_relative_precision(w):
    # a rotation of 1e-9 rad must come back to ~1e-16 rad, not to 1e-8 (arccos of the trace would)
    if np.linalg.norm(w) == 0.0:
        return
    w = w / np.linalg.norm(w) * 1e-9
    np.testing.assert_allclose(se3.rotvec(Rotation.from_rotvec(w).as_matrix()), w, rtol=1e-6, atol=1e-22)


@given(_batch(unit_vectors.map(lambda v: v * 3.7)), _batch(st.floats(-2 * PI, 2 * PI)))
def test_rotation_axis_angle_matches_scipy(axis, angle):
    n = min(len(axis), len(angle))
    axis, angle = axis[:n], angle[:n]
    R = se3.rotation(axis, angle)
    unit = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    np.testing.assert_allclose(R, Rotation.from_rotvec(unit * angle[:, None]).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(se3.rotation(axis[0], angle[0]), R[0], atol=0.0)


def test_rotation_refuses_a_zero_axis():
    with pytest.raises(BadInputError, match="axis"):
        se3.rotation(np.zeros(3), 0.3)


@given(_batch(rvecs))
def test_quaternions_match_scipy_and_lie(w):
    R = Rotation.from_rotvec(w).as_matrix()
    q = se3.quat_from_matrix(R)
    assert q.shape == (len(w), 4) and np.all(q[:, 0] >= 0.0)
    ref = Rotation.from_matrix(R).as_quat()[:, [3, 0, 1, 2]]
    ref = np.where(ref[:, :1] < 0.0, -ref, ref)
    for k in range(len(w)):
        if abs(q[k, 0]) > 1e-9:  # at pi (w = 0) the sign is a convention
            np.testing.assert_allclose(q[k], ref[k], atol=1e-14)
            np.testing.assert_allclose(q[k], np.asarray(_lie_quat(R[k])), atol=1e-14)
        np.testing.assert_array_equal(se3.quat_from_matrix(R[k]), q[k])
    np.testing.assert_allclose(se3.matrix_from_quat(q), R, atol=1e-14)
    np.testing.assert_allclose(se3.matrix_from_quat(-3.0 * q), R, atol=1e-14)  # any scale, either sign


def test_matrix_from_quat_refuses_zero():
    with pytest.raises(BadInputError, match="quaternion"):
        se3.matrix_from_quat(np.array([[1.0, 0, 0, 0], [0.0, 0, 0, 0]]))


@given(_batch(rvecs), _batch(vectors))
def test_make_pose_and_invert(w, t):
    n = min(len(w), len(t))
    T = _poses(w[:n], t[:n])
    assert T.shape == (n, 4, 4)
    np.testing.assert_array_equal(T[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)))
    Ti = se3.invert(T)
    np.testing.assert_allclose(Ti @ T, np.broadcast_to(np.eye(4), T.shape), atol=1e-14)
    np.testing.assert_allclose(T @ Ti, np.broadcast_to(np.eye(4), T.shape), atol=1e-14)
    np.testing.assert_allclose(Ti, np.linalg.inv(T), atol=1e-14)
    np.testing.assert_array_equal(se3.invert(T[0]), Ti[0])
    # one rotation with many translations broadcasts
    assert se3.make_pose(np.eye(3), t).shape == (len(t), 4, 4)


@given(rvecs, vectors, rvecs, vectors)
def test_adjoint_matches_lie_and_moves_perturbations(w, t, dw, dv):
    T = _poses(w, t)
    Ad = se3.adjoint(T)
    np.testing.assert_allclose(Ad, np.asarray(_lie_adjoint(T)), atol=1e-14)
    d = 1e-3 * np.concatenate([dw, dv])
    np.testing.assert_allclose(
        T @ np.asarray(_lie_exp_mat(d)), np.asarray(_lie_exp_mat(Ad @ d)) @ T, atol=1e-13
    )  # T Exp(d) = Exp(Ad d) T
    np.testing.assert_allclose(se3.adjoint(np.stack([T, T]))[1], Ad, atol=0.0)


@given(_batch(rvecs), _batch(vectors))
def test_log_se3_matches_lie(w, t):
    n = min(len(w), len(t))
    T = _poses(w[:n], t[:n])
    d = se3.log_se3(T)
    assert d.shape == (n, 6)
    for k in range(n):
        ref = np.asarray(_lie_log(T[k]))
        assert _same_rvec(d[k, :3], ref[:3], 1e-11), (d[k], ref)
        if np.linalg.norm(w[k]) < PI - 1e-4:  # the translation part flips with the axis at pi
            np.testing.assert_allclose(d[k], ref, atol=1e-11)
            np.testing.assert_allclose(np.asarray(_lie_exp_mat(d[k])), T[k], atol=1e-12)


@given(unit_vectors)
def test_rotation_z_to_takes_z_to_the_axis(a):
    R = se3.rotation_z_to(a)
    np.testing.assert_allclose(R @ [0.0, 0.0, 1.0], a, atol=1e-14)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
    assert np.linalg.det(R) > 0.0


@given(_batch(rvecs), _batch(vectors))
def test_as_pose_matrices_reads_matrices_and_wxyz_xyz(w, t):
    n = min(len(w), len(t))
    T = _poses(w[:n], t[:n])
    np.testing.assert_array_equal(se3.as_pose_matrices(T, "T"), T)
    np.testing.assert_array_equal(se3.as_pose_matrices(T[0], "T"), T[:1])  # one pose is N = 1
    seven = np.concatenate([se3.quat_from_matrix(T[:, :3, :3]), T[:, :3, 3]], axis=-1)
    np.testing.assert_allclose(se3.as_pose_matrices(seven, "T"), T, atol=1e-14)
    np.testing.assert_allclose(se3.as_pose_matrices(seven, "T"), np.asarray(jax.vmap(lie.se3_to_matrix)(seven)), atol=1e-14)


@pytest.mark.parametrize(
    "poses, match",
    [
        (np.zeros((2, 3, 3)), r"T_x: expected shape \(N, 4, 4\)"),
        (np.stack([np.eye(4), np.full((4, 4), np.nan)]), "T_x: pose 1 has NaN"),
        (np.stack([np.eye(4), np.diag([1.0, 1.0, -1.0, 1.0])]), "T_x: pose 1 has a rotation block"),
        (np.stack([np.eye(4), np.eye(4) + np.diag([0.0, 0.0, 0.0, 1e-3])]), r"T_x: pose 1 has bottom row"),
        (np.array([[2.0, 0, 0, 0, 1, 2, 3]]), "T_x: pose 0 has a quaternion of norm 2"),
        ("not poses", "T_x: expected"),
    ],
)
def test_pose_checks_name_the_argument_and_the_pose(poses, match):
    with pytest.raises(BadInputError, match=match):
        se3.as_pose_matrices(poses, "T_x")
