"""Pose conventions: round trips, scipy/OpenCV cross-checks, gimbal lock, bad input.

Reference: scipy.spatial.transform.Rotation (uppercase axes = intrinsic, lowercase = extrinsic,
quaternions xyzw) and cv2.Rodrigues. Tolerances: 1e-12 for float64 round trips (a few dozen
operations, rounding ~1e-16 each; mm-scale positions scale it by 1e3 -> 1e-9 mm).
"""

import warnings

import cv2
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from scipy.spatial.transform import Rotation

from jcalib.errors import BadInputError
from jcalib.geometry import conversions as C

PI = np.pi
SEQUENCES = [a + b + c for a in "XYZ" for b in "XYZ" for c in "XYZ" if a != b and b != c]

unit_quats = (
    st.tuples(*[st.floats(-1.0, 1.0, allow_subnormal=False)] * 4)
    .map(np.array)
    .filter(lambda q: np.linalg.norm(q) > 1e-3)
    .map(lambda q: q / np.linalg.norm(q))
)
rotations = st.one_of(
    unit_quats.map(lambda q: Rotation.from_quat(q).as_matrix()),
    # near identity and near 180 degrees
    st.builds(
        lambda q, a: Rotation.from_rotvec(a * q[1:] / max(np.linalg.norm(q[1:]), 1e-9)).as_matrix(),
        unit_quats.filter(lambda q: np.linalg.norm(q[1:]) > 1e-3),
        st.sampled_from([1e-12, 1e-9, 1e-6, PI - 1e-6, PI - 1e-9, PI]),
    ),
)
positions_mm = st.tuples(*[st.floats(-3000.0, 3000.0, allow_subnormal=False)] * 3).map(np.array)


def transform(rot, pos_m):
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = pos_m
    return m


def test_all_24_euler_conventions_match_scipy():
    mats = Rotation.random(200, random_state=7).as_matrix()
    for seq in SEQUENCES:
        for intrinsic in (True, False):
            sp = seq if intrinsic else seq.lower()
            ang = C.matrix_to_euler(mats, seq, intrinsic)
            np.testing.assert_allclose(ang, Rotation.from_matrix(mats).as_euler(sp), atol=1e-12)
            np.testing.assert_allclose(C.euler_to_matrix(ang, seq, intrinsic), mats, atol=1e-14)
            deg = np.degrees(ang)
            np.testing.assert_allclose(
                C.euler_to_matrix(deg, seq, intrinsic, degrees=True),
                Rotation.from_euler(sp, deg, degrees=True).as_matrix(), atol=1e-14,
            )


@pytest.mark.parametrize("seq", SEQUENCES)
@pytest.mark.parametrize("intrinsic", [True, False])
def test_gimbal_lock_sets_third_angle_to_zero(seq, intrinsic):
    proper = seq[0] == seq[2]
    for middle in ((0.0, PI) if proper else (PI / 2, -PI / 2)):
        for near in (0.0, 1e-13, 1e-9):  # exactly at, within and just outside the lock tolerance
            rot = C.euler_to_matrix([0.4, middle + near, -1.1], seq, intrinsic)
            ang = C.matrix_to_euler(rot, seq, intrinsic)
            np.testing.assert_allclose(C.euler_to_matrix(ang, seq, intrinsic), rot, atol=1e-12)
            if near == 0.0:
                assert ang[2] == 0.0
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # scipy warns about the lock
                    ref = Rotation.from_matrix(rot).as_euler(seq if intrinsic else seq.lower())
                np.testing.assert_allclose(ang, ref, atol=1e-9)


@given(rotations, positions_mm)
def test_kuka_roundtrip_and_convention(rot, pos_mm):
    T = transform(rot, pos_mm * 1e-3)
    xyzabc = C.matrix_to_kuka(T)
    np.testing.assert_allclose(C.kuka_to_matrix(xyzabc), T, atol=1e-12)
    np.testing.assert_allclose(xyzabc[:3], pos_mm, atol=1e-9)
    assert -90.0 <= xyzabc[4] <= 90.0
    # KUKA A, B, C = intrinsic Z, Y', X'' in degrees
    ref = Rotation.from_euler("ZYX", xyzabc[3:], degrees=True).as_matrix()
    np.testing.assert_allclose(ref, rot, atol=1e-12)


def test_kuka_known_values_and_gimbal_lock():
    # B = 90: tool x axis points down (Ry(90) maps x to -z)
    T = C.kuka_to_matrix([100.0, 200.0, 300.0, 0.0, 90.0, 0.0])
    np.testing.assert_allclose(T[:3, 0], [0.0, 0.0, -1.0], atol=1e-15)
    np.testing.assert_allclose(T[:3, 3], [0.1, 0.2, 0.3], atol=1e-15)
    # at B = 90 only A - C is defined: (10, 90, 30) comes back as (-20, 90, 0)
    got = C.matrix_to_kuka(C.kuka_to_matrix([1.0, 2.0, 3.0, 10.0, 90.0, 30.0]))
    np.testing.assert_allclose(got, [1.0, 2.0, 3.0, -20.0, 90.0, 0.0], atol=1e-9)
    got = C.matrix_to_kuka(C.kuka_to_matrix([1.0, 2.0, 3.0, 10.0, -90.0, 30.0]))
    np.testing.assert_allclose(got, [1.0, 2.0, 3.0, 40.0, -90.0, 0.0], atol=1e-9)


@given(rotations, positions_mm)
def test_abb_roundtrip_and_convention(rot, pos_mm):
    T = transform(rot, pos_mm * 1e-3)
    trans, quat = C.matrix_to_abb(T)
    assert quat[0] >= 0.0
    np.testing.assert_allclose(trans, pos_mm, atol=1e-9)
    np.testing.assert_allclose(C.abb_to_matrix(trans, quat), T, atol=1e-12)
    # q1 = w: scipy's xyzw quaternion reordered
    ref = Rotation.from_quat(np.r_[quat[1:], quat[0]]).as_matrix()
    np.testing.assert_allclose(ref, rot, atol=1e-12)


def test_abb_accepts_rapid_rounded_quaternion():
    # RAPID prints 6 decimals: [0.707107, 0, 0.707107, 0] has norm 1 + 3e-7
    T = C.abb_to_matrix([1270.0, 0.0, 1570.0], [0.707107, 0.0, 0.707107, 0.0])
    np.testing.assert_allclose(T[:3, :3], Rotation.from_euler("y", 90, degrees=True).as_matrix(),
                               atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [1.27, 0.0, 1.57], atol=1e-15)


@given(rotations)
def test_quaternion_orders_and_matrix(rot):
    q = C.matrix_to_quat(rot)
    assert q[0] >= 0.0
    xyzw = C.quat_wxyz_to_xyzw(q)
    np.testing.assert_allclose(Rotation.from_quat(xyzw).as_matrix(), rot, atol=1e-12)
    np.testing.assert_array_equal(C.quat_xyzw_to_wxyz(xyzw), q)
    np.testing.assert_allclose(C.quat_to_matrix(q), rot, atol=1e-12)


@given(rotations, positions_mm)
def test_ros_and_pose_roundtrips(rot, pos_mm):
    T = transform(rot, pos_mm * 1e-3)
    p, q = C.matrix_to_ros(T)
    assert q[3] >= 0.0
    np.testing.assert_allclose(C.ros_to_matrix(p, q), T, atol=1e-12)
    pose = C.matrix_to_pose(T)
    np.testing.assert_allclose(C.pose_to_matrix(pose), T, atol=1e-12)


@given(rotations, positions_mm)
def test_rvec_tvec_roundtrip_vs_opencv(rot, pos_mm):
    T = transform(rot, pos_mm * 1e-3)
    rvec, tvec = C.matrix_to_rvec_tvec(T)
    assert np.linalg.norm(rvec) <= PI + 1e-15
    np.testing.assert_allclose(cv2.Rodrigues(rvec)[0], rot, atol=1e-12)
    np.testing.assert_allclose(C.rvec_tvec_to_matrix(rvec, tvec), T, atol=1e-12)
    np.testing.assert_allclose(C.rvec_to_matrix(rvec), cv2.Rodrigues(rvec)[0], atol=1e-14)
    np.testing.assert_allclose(C.matrix_to_rvec(rot), rvec, atol=0)


def test_batched_numpy_and_jax_paths_agree():
    rng = np.random.default_rng(3)
    mats = Rotation.random(12, random_state=3).as_matrix().reshape(3, 4, 3, 3)
    T = np.broadcast_to(np.eye(4), (3, 4, 4, 4)).copy()
    T[..., :3, :3] = mats
    T[..., :3, 3] = rng.normal(size=(3, 4, 3))
    out_np = C.matrix_to_kuka(T)
    assert isinstance(out_np, np.ndarray) and out_np.shape == (3, 4, 6)
    out_jax = C.matrix_to_kuka(jnp.asarray(T))
    assert isinstance(out_jax, jax.Array)
    np.testing.assert_allclose(out_jax, out_np, atol=1e-12)
    # traceable: jit and grad go through (no value checks on tracers)
    jitted = jax.jit(C.matrix_to_kuka)(jnp.asarray(T))
    np.testing.assert_allclose(jitted, out_np, atol=1e-12)
    g = jax.grad(lambda x: jnp.sum(C.kuka_to_matrix(x)))(jnp.asarray(out_np[0, 0]))
    assert np.all(np.isfinite(np.asarray(g)))


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: C.matrix_to_quat(np.eye(3) * 1.01), "rotation.*orthonormal"),
        (lambda: C.matrix_to_quat(np.diag([1.0, 1.0, -1.0])), "det"),
        (lambda: C.matrix_to_quat(np.eye(4)), r"rotation: expected shape \(\.\.\., 3, 3\)"),
        (lambda: C.quat_to_matrix([0.0, 0.0, 0.0, 0.0]), "zero quaternion"),
        (lambda: C.abb_to_matrix([0, 0, 0], [1.0, 0.0, 0.0, 0.5]), "quat: expected a unit"),
        (lambda: C.abb_to_matrix([0, 0, np.nan], [1.0, 0, 0, 0]), "trans_mm: expected finite"),
        (lambda: C.kuka_to_matrix([0, 0, 0, 0, 0]), "xyzabc"),
        (lambda: C.matrix_to_kuka(np.ones((4, 4))), "bottom row"),
        (lambda: C.matrix_to_euler(np.eye(3), "XXZ"), "axes"),
        (lambda: C.euler_to_matrix([0, 0, 0], "ABC"), "axes"),
        (lambda: C.rvec_tvec_to_matrix([0, 0, 0], "abc"), "tvec"),
    ],
)
def test_bad_input_raises_naming_the_argument(call, match):
    with pytest.raises(BadInputError, match=match):
        call()
