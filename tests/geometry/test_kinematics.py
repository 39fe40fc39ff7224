"""Robot kinematics: FK vs an independent joint-screw chain, published reach, Jacobian vs finite
differences, IK round trips, joint limits.

The reference chain is built from the ROS-Industrial URDFs of both arms (joint origin offsets and
rotation axes, evaluated with scipy rotations): a different parameterisation from our DH tables, so
agreement to 1e-12 m checks the DH derivation, signs and offsets. IK tolerances are the documented
1e-9 m / 1e-9 rad; FD tolerance 1e-7 (central differences, step 1e-6).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
from scipy.spatial.transform import Rotation

from jcalib.errors import BadInputError
from jcalib.geometry import kinematics as K
from jcalib.geometry import lie, robots


def _ry90():
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("y", 90, degrees=True).as_matrix()
    return m


# (joint origins in the parent link frame (m), joint axes, fixed flange transform)
URDF = {
    "abb": (
        [[0, 0, 0.495], [0.175, 0, 0], [0, 0, 0.9], [0, 0, 0.175], [0.96, 0, 0], [0.135, 0, 0]],
        [[0, 0, 1], [0, 1, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0]],
        _ry90(),  # tool0: z out of the flange
    ),
    "kuka": (
        [[0, 0, 0.4], [0.025, 0, 0], [0.56, 0, 0], [0, 0, 0.035], [0.515, 0, 0], [0.08, 0, 0]],
        [[0, 0, -1], [0, 1, 0], [0, 1, 0], [-1, 0, 0], [0, 1, 0], [-1, 0, 0]],
        np.eye(4),  # $FLANGE: x out of the flange
    ),
}
ROBOTS = {"abb": robots.abb_irb4600_45_205(), "kuka": robots.kuka_kr10_r1100_sixx()}


def screw_chain_fk(name, q):
    origins, axes, flange = URDF[name]
    T = np.eye(4)
    for o, a, qi in zip(origins, axes, q):
        step = np.eye(4)
        step[:3, 3] = o
        step[:3, :3] = Rotation.from_rotvec(np.array(a, float) * qi).as_matrix()
        T = T @ step
    return T @ flange


def random_q(robot, n, seed, margin=0.0):
    lo, hi = np.asarray(robot.lower) + margin, np.asarray(robot.upper) - margin
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, robot.num_joints))


_fk = jax.jit(K.forward_kinematics)
_jac = jax.jit(K.flange_jacobian)
_local_fk = jax.jit(lambda robot, p0, q: lie.local(p0, K.forward_kinematics_pose(robot, q)))
_BATCH = 12  # every IK call below uses 12 targets and 16 seeds: one compilation per robot


@pytest.mark.parametrize("name", ["abb", "kuka"])
def test_fk_matches_independent_screw_chain(name):
    robot = ROBOTS[name]
    q = random_q(robot, 50, seed=1)
    T = np.asarray(_fk(robot, q))
    assert T.shape == (50, 4, 4) and T.dtype == np.float64
    for i in range(50):
        np.testing.assert_allclose(T[i], screw_chain_fk(name, q[i]), atol=1e-12)
    # vmap over joint vectors agrees with leading-axis batching
    np.testing.assert_allclose(jax.vmap(lambda x: K.forward_kinematics(robot, x))(q), T, atol=1e-15)


def test_fk_known_poses():
    abb, kuka = ROBOTS["abb"], ROBOTS["kuka"]
    # ABB calibration position: tool0 at x = 175 + 960 + 135, z = 495 + 900 + 175 mm, z forward
    T = np.asarray(_fk(abb, np.zeros(6)))
    np.testing.assert_allclose(T[:3, 3], [1.270, 0.0, 1.570], atol=1e-15)
    np.testing.assert_allclose(T[:3, :3], Rotation.from_euler("y", 90, degrees=True).as_matrix(),
                               atol=1e-15)
    # ABB axis 2 at +90 deg: upper arm horizontal forward, forearm pointing down
    T = np.asarray(_fk(abb, np.radians([0, 90, 0, 0, 0, 0])))
    np.testing.assert_allclose(T[:3, 3], [0.175 + 0.9 + 0.175, 0.0, 0.495 - 0.96 - 0.135],
                               atol=1e-15)
    # KUKA zero: arm stretched forward, $FLANGE aligned with the base
    T = np.asarray(_fk(kuka, np.zeros(6)))
    np.testing.assert_allclose(T, np.array([[1, 0, 0, 1.18], [0, 1, 0, 0], [0, 0, 1, 0.435],
                                            [0, 0, 0, 1.0]]), atol=1e-15)
    # KUKA home {A2 -90, A3 90, A5 90}: upper arm vertical, flange pointing down (B = 90)
    T = np.asarray(_fk(kuka, np.radians([0, -90, 90, 0, 90, 0])))
    np.testing.assert_allclose(T[:3, 3], [0.025 + 0.515, 0.0, 0.4 + 0.56 + 0.035 - 0.08],
                               atol=1e-15)
    np.testing.assert_allclose(T[:3, 0], [0.0, 0.0, -1.0], atol=1e-15)
    # KUKA A1 +90: the arm turns clockwise seen from above (towards -y)
    T = np.asarray(_fk(kuka, np.radians([90, 0, 0, 0, 0, 0])))
    np.testing.assert_allclose(T[:3, 3], [0.0, -1.18, 0.435], atol=1e-15)


@pytest.mark.parametrize("name, reach_m", [("abb", 2.05), ("kuka", 1.101)])
def test_wrist_centre_reach_matches_datasheet(name, reach_m):
    robot = ROBOTS[name]
    frames = jax.jit(K.link_frames)

    def neg_reach(q23):
        q = np.array([0.0, q23[0], q23[1], 0.0, 0.0, 0.0])
        wrist = np.asarray(frames(robot, q))[4, :3, 3]  # DH frame 4 origin = wrist centre
        return -np.hypot(wrist[0], wrist[1])

    lo, hi = np.asarray(robot.lower)[1:3], np.asarray(robot.upper)[1:3]
    best = min(
        (scipy.optimize.minimize(neg_reach, x0, bounds=list(zip(lo, hi)), method="L-BFGS-B")
         for x0 in np.random.default_rng(0).uniform(lo, hi, size=(6, 2))),
        key=lambda r: r.fun,
    )
    # datasheets round to 1 mm (KUKA) / 10 mm (ABB: 2050.8 mm -> "2.05 m")
    assert abs(-best.fun - reach_m) < 1e-3


@pytest.mark.parametrize("name", ["abb", "kuka"])
def test_flange_jacobian_matches_finite_differences(name):
    robot = ROBOTS[name]
    q = random_q(robot, 3, seed=2)
    jac = np.asarray(_jac(robot, q))
    assert jac.shape == (3, 6, 6)
    h = 1e-6
    for k in range(3):
        p0 = K.forward_kinematics_pose(robot, q[k])
        for i in range(6):
            e = np.zeros(6)
            e[i] = h
            plus = _local_fk(robot, p0, q[k] + e)
            minus = _local_fk(robot, p0, q[k] - e)
            np.testing.assert_allclose(jac[k, :, i], (plus - minus) / (2 * h), atol=1e-7)
    # rotation rows at zero are the joint axes expressed in the flange frame
    T0 = screw_chain_fk(name, np.zeros(6))
    axes = np.array(URDF[name][1], float)
    np.testing.assert_allclose(np.asarray(_jac(robot, np.zeros(6)))[:3].T, axes @ T0[:3, :3],
                               atol=1e-12)


@pytest.mark.parametrize("name", ["abb", "kuka"])
def test_ik_roundtrip_random_in_limit_poses(name):
    robot = ROBOTS[name]
    q_true = random_q(robot, _BATCH, seed=3, margin=np.radians(2.0))
    targets = np.asarray(_fk(robot, q_true))
    # first call: start near the true joints (tracking); second: from the limits' middle
    near = K.inverse_kinematics(robot, targets, q_init=q_true + 0.05)
    cold = K.inverse_kinematics(robot, targets)
    for res in (near, cold):
        assert res.q.shape == (12, 6)
        assert np.all(np.asarray(res.success))
        assert np.all(np.asarray(res.position_error_m) <= 1e-9)
        assert np.all(np.asarray(res.rotation_error_rad) <= 1e-9)
        assert not np.any(np.asarray(K.outside_joint_limits(robot, res.q)))
        reached = np.asarray(_fk(robot, res.q))
        np.testing.assert_allclose(reached[:, :3, 3], targets[:, :3, 3], atol=1e-9)
        np.testing.assert_allclose(reached[:, :3, :3], targets[:, :3, :3], atol=1e-9)
    # staying close to q_init picks the branch it came from
    np.testing.assert_allclose(near.q, q_true, atol=1e-6)


def test_ik_unreachable_is_reported():
    robot = ROBOTS["kuka"]
    targets = np.array(_fk(robot, random_q(robot, _BATCH, seed=4)))
    targets[5, :3, 3] = [3.0, 0.0, 0.5]  # 3 m away: beyond the 1.1 m reach
    res = K.inverse_kinematics(robot, targets)
    ok = np.asarray(res.success)
    assert not ok[5] and ok.sum() == _BATCH - 1
    assert float(res.position_error_m[5]) > 1.5
    assert not np.any(np.asarray(K.outside_joint_limits(robot, res.q)))
    with pytest.raises(BadInputError, match=r"T_base_flange\[5\]: unreachable"):
        res.raise_if_unreachable(robot.name)
    assert np.all(ok[:5])


def test_ik_respects_joint_limits():
    # a pose reachable only with joint 1 at 90 deg, for an arm whose joint 1 stops at +-10 deg
    base = ROBOTS["kuka"]
    narrow = K.DHRobot(
        base.a, base.alpha, base.d, theta_offset=base.theta_offset, joint_sign=base.joint_sign,
        lower=np.r_[np.radians(-10.0), np.asarray(base.lower)[1:]],
        upper=np.r_[np.radians(10.0), np.asarray(base.upper)[1:]],
        T_link_flange=base.T_link_flange, name=base.name, joint_names=base.joint_names,
    )
    q = np.tile(np.radians([90.0, -60.0, 80.0, 0.0, 40.0, 0.0]), (_BATCH, 1))
    res = K.inverse_kinematics(narrow, np.asarray(_fk(base, q)))
    assert not np.any(np.asarray(res.success))
    assert np.all(np.asarray(res.q) >= np.asarray(narrow.lower))
    assert np.all(np.asarray(res.q) <= np.asarray(narrow.upper))


def test_joint_limit_checks_name_the_joint():
    robot = ROBOTS["kuka"]
    ok = np.radians([0.0, -90.0, 90.0, 0.0, 45.0, 0.0])
    K.check_joint_limits(robot, ok)
    K.check_joint_limits(robot, robot.upper)  # the limits themselves are allowed
    bad = np.stack([ok, ok])
    bad[1, 2] = np.radians(170.0)
    with pytest.raises(BadInputError, match=r"q\[1, 2\]: joint 3 \(A3\).*170\.0000 deg.*156"):
        K.check_joint_limits(robot, bad)
    out = np.asarray(jax.jit(K.outside_joint_limits)(robot, bad))
    np.testing.assert_array_equal(out, [[False] * 6, [False, False, True, False, False, False]])
    with pytest.raises(BadInputError, match="expected joint values of shape"):
        K.check_joint_limits(robot, np.zeros(5))


def test_robot_construction_validates_and_presets():
    with pytest.raises(BadInputError, match="lower/upper"):
        K.DHRobot([0.1, 0.2], [0, 0], [0, 0], lower=[0.0, 1.0], upper=[1.0, 0.5])
    with pytest.raises(BadInputError, match="joint_sign"):
        K.DHRobot([0.1], [0.0], [0.0], joint_sign=[2.0])
    with pytest.raises(BadInputError, match="alpha"):
        K.DHRobot([0.1, 0.2], [0.0], [0.0, 0.0])
    assert robots.robot_preset("kuka_kr10_r1100_sixx").name == "KUKA KR 10 R1100 sixx"
    with pytest.raises(BadInputError, match="unknown preset"):
        robots.robot_preset("fanuc")


def test_fk_differentiable_in_dh_parameters():
    # kinematic calibration needs d(FK)/d(DH): gradients flow through the robot pytree
    robot = ROBOTS["abb"]
    q = jnp.asarray(np.radians([10.0, 20.0, -30.0, 40.0, 50.0, 60.0]))
    g = jax.grad(lambda r: K.forward_kinematics(r, q)[0, 3])(robot)
    # against central finite differences in a1
    h = 1e-6
    a_plus = K.DHRobot(robot.a.at[0].add(h), robot.alpha, robot.d, theta_offset=robot.theta_offset,
                       lower=robot.lower, upper=robot.upper)
    a_minus = K.DHRobot(robot.a.at[0].add(-h), robot.alpha, robot.d,
                        theta_offset=robot.theta_offset, lower=robot.lower, upper=robot.upper)
    fd = (K.forward_kinematics(a_plus, q)[0, 3] - K.forward_kinematics(a_minus, q)[0, 3]) / (2 * h)
    assert abs(float(g.a[0]) - float(fd)) < 1e-7
