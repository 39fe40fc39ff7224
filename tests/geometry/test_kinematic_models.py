"""Parameterised kinematic models (dh, mdh, poe): FK against kinematics.py, Jacobians against finite
differences, parameter names and groups, controller units, cell-spec parsing and its errors, presets.

Tolerances: 1e-9 for float64 identities (same chain, other parameterisation: rounding is ~1e-15);
1e-6 relative for central differences (step 1e-6: truncation ~1e-12, rounding ~1e-10).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jcalib.errors import BadInputError
from jcalib.geometry import kinematic_models as km
from jcalib.geometry import kinematic_tables as kt
from jcalib.geometry import kinematics as K
from jcalib.geometry import robots

ARMS = sorted(robots.PRESETS)
CONVENTIONS = ("dh", "mdh", "poe")

MIXED_TABLE = {
    "convention": "dh",
    "joints": [
        {"name": "E1", "type": "prismatic", "a_m": 0.1, "alpha_deg": -90, "d_m": 0.3, "theta_deg": 10,
         "limits_mm": [0, 3000]},
        {"name": "A 1", "a_m": 0.2, "alpha_deg": 90, "d_m": 0.4, "theta_deg": 5, "sign": -1,
         "limits_deg": [-170, 170]},
        {"name": "A2", "a_m": 0.5, "alpha_deg": 0, "d_m": 0.0, "limits_deg": [-120, 120]},
        {"name": "E2", "type": "prismatic", "a_m": 0.0, "alpha_deg": 30, "d_m": 0.05,
         "limits_mm": [-100, 100]},
    ],
    "flange": [[1, 0, 0, 0.01], [0, 0, -1, 0.02], [0, 1, 0, 0.1], [0, 0, 0, 1]],
}


def _random_q(model, num, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(model.lower), np.asarray(model.upper)
    return lo + rng.uniform(size=(num, model.num_joints)) * (hi - lo)


def _assert_se3(T):
    R = T[..., :3, :3]
    np.testing.assert_allclose(np.swapaxes(R, -1, -2) @ R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_array_equal(T[..., 3, :], np.broadcast_to([0.0, 0.0, 0.0, 1.0], T.shape[:-2] + (4,)))


@pytest.mark.parametrize("arm", ARMS)
def test_fk_matches_dh_robot_in_every_convention(arm):
    robot = robots.PRESETS[arm]()
    q = _random_q(robot, 16)
    expected = np.asarray(K.forward_kinematics(robot, q))
    for convention in CONVENTIONS:
        model = km.from_dh_robot(robot, convention)
        assert model.convention == convention
        assert model.num_params == 6 * {"dh": 4, "mdh": 5, "poe": 6}[convention] + 12
        T = np.asarray(km.forward(model, model.nominal, q))
        assert T.dtype == np.float64 and T.shape == (16, 4, 4)
        np.testing.assert_allclose(T, expected, atol=1e-9, err_msg=convention)
        _assert_se3(T)


def test_names_are_sanitised_unique_and_grouped():
    abb = km.PRESETS["abb_irb4600_45_205"]()
    assert abb.joint_names == ("axis1", "axis2", "axis3", "axis4", "axis5", "axis6")
    assert set(km.PRESETS) == set(robots.PRESETS) | {"positioner_2axis", "linear_track", "rotary_table"}
    for name, make in km.PRESETS.items():
        model = make()
        assert len(set(model.param_names)) == model.num_params == model.nominal.shape[0], name
        assert model.param_names[-12:] == tuple(f"{f}.{c}" for f in ("base", "flange")
                                                 for c in ("rx", "ry", "rz", "tx", "ty", "tz"))
        groups = km.parameter_groups(model)
        parts = [p for g in ("joint_offsets", "link_lengths", "twists", "base", "flange") for p in groups[g]]
        assert sorted(parts) == sorted(model.param_names) == sorted(groups["all"]), name
        _assert_se3(np.asarray(km.forward(model, model.nominal, np.zeros(model.num_joints))))


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_jacobian_matches_finite_differences(convention):
    """d T_base_flange / d (params, q) on a chain mixing prismatic and revolute joints (one with sign
    -1) in each convention, and on the linear track (dh). Each model costs a ~1 s compilation."""
    rng = np.random.default_rng(1)
    h = 1e-6
    models = [km.convert(kt.from_spec(MIXED_TABLE, "r1"), convention)]
    for model in models + ([km.linear_track()] if convention == "dh" else []):
        P = model.num_params
        params = model.nominal + 1e-3 * rng.standard_normal(P)  # off the nominal
        x = jnp.concatenate([params, jnp.asarray(_random_q(model, 1, seed=2)[0])])
        f = lambda x, model=model, P=P: km.forward(model, x[:P], x[P:])
        # one compiled function gives the Jacobian and (as aux) the value for the differences
        jac_and_value = jax.jit(jax.jacfwd(lambda x, f=f: (f(x), f(x)), has_aux=True))
        jac = np.asarray(jac_and_value(x)[0])
        assert jac.shape == (4, 4, P + model.num_joints)
        fd = np.stack([(jac_and_value(x + h * e)[1] - jac_and_value(x - h * e)[1]) / (2 * h)
                       for e in np.eye(x.shape[0])], axis=-1)
        np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-6 * np.abs(jac).max(), err_msg=model.name)
        assert np.all(np.abs(jac).reshape(-1, x.shape[0]).max(axis=0) > 0), "a parameter has no effect"


def test_mixed_table_conversions_keep_the_fk():
    model = kt.from_spec(MIXED_TABLE, "r1")
    assert model.joint_types == ("prismatic", "revolute", "revolute", "prismatic")
    assert model.joint_names == ("E1", "A1", "A2", "E2")
    q = _random_q(model, 8)
    expected = np.asarray(km.forward(model, model.nominal, q))
    for convention in ("mdh", "poe"):
        other = km.convert(model, convention)
        np.testing.assert_allclose(np.asarray(km.forward(other, other.nominal, q)), expected, atol=1e-9)
    groups = km.parameter_groups(model)
    assert "E1.d" in groups["joint_offsets"] and "A1.theta" in groups["joint_offsets"]
    assert "E1.theta" in groups["twists"] and "A1.d" in groups["link_lengths"]
    poe_groups = km.parameter_groups(km.convert(model, "poe"))
    assert "E1.tz" in poe_groups["joint_offsets"] and "E1.rz" in poe_groups["twists"]
    assert "A1.tz" in poe_groups["link_lengths"]


def test_prismatic_motion_is_along_the_axis_in_metres():
    track = km.linear_track()
    T = np.asarray(km.forward(track, track.nominal, jnp.asarray([[0.0], [2.5]])))
    np.testing.assert_allclose(T[1] - T[0], np.pad([[2.5], [0.0], [0.0]], ((0, 1), (3, 0))), atol=1e-12)
    np.testing.assert_allclose(T[0], np.eye(4), atol=1e-12)


def test_poe_rz_perturbation_is_a_joint_offset():
    robot = robots.abb_irb4600_45_205()
    poe, dh = km.from_dh_robot(robot, "poe"), km.from_dh_robot(robot, "dh")
    q = _random_q(poe, 4)
    eps = 1e-3
    for joint in ("axis2", "axis5"):
        p_poe = poe.nominal.at[poe.param_names.index(f"{joint}.rz")].add(eps)
        p_dh = dh.nominal.at[dh.param_names.index(f"{joint}.theta")].add(eps)
        np.testing.assert_allclose(np.asarray(km.forward(poe, p_poe, q)),
                                   np.asarray(km.forward(dh, p_dh, q)), atol=1e-9)
        assert km.controller_offsets(poe, p_poe)[joint] == pytest.approx(math.degrees(eps), rel=1e-12)


def test_controller_units_round_trip():
    model = kt.from_spec(MIXED_TABLE, "r1")
    joints = np.array([[1500.0, 90.0, -45.0, 20.0], [0.0, 0.0, 180.0, -100.0]])
    q = km.joints_from_controller(model, joints)
    np.testing.assert_allclose(q[0], [1.5, math.pi / 2, -math.pi / 4, 0.02], rtol=1e-15)
    np.testing.assert_allclose(km.joints_to_controller(model, q), joints, rtol=1e-14)
    with pytest.raises(BadInputError, match=r"expected 4 joint values for r1 .*got 3"):
        km.joints_from_controller(model, [1.0, 2.0, 3.0])
    with pytest.raises(BadInputError, match=r"joints_deg\[1, 2\]: joint A2 of r1 is nan"):
        km.joints_from_controller(model, [[0.0] * 4, [0.0, 0.0, float("nan"), 0.0]])


def test_select_groups_and_names():
    model = km.PRESETS["kuka_kr10_r1100_sixx"]()
    mask = km.select(model, ["joint_offsets", "A2.a", "base"])
    chosen = {n for n, m in zip(model.param_names, mask) if m}
    assert chosen == {f"A{i}.theta" for i in range(1, 7)} | {"A2.a"} | {f"base.{c}" for c in
                                                                        ("rx", "ry", "rz", "tx", "ty", "tz")}
    assert mask.dtype == bool and km.select(model, ["all"]).all() and not km.select(model, []).any()
    with pytest.raises(BadInputError, match=r"cell.yaml: .*'A2.alfa'.*did you mean 'A2.alpha'.*joint_offsets"):
        km.select(model, ["A2.alpha", "A2.alfa"], source="cell.yaml")
    with pytest.raises(BadInputError, match=r"did you mean 'link_lengths'.*Valid groups"):
        km.select(model, ["link_length"])
    with pytest.raises(BadInputError, match=r"^cell: calibrate_kinematics: 3 is neither"):
        km.select(model, [3])


def test_controller_offsets_sign_convention():
    model = kt.from_spec(MIXED_TABLE, "r1")  # A1 has sign -1
    params = model.nominal.at[model.param_names.index("A1.theta")].add(0.01)
    params = params.at[model.param_names.index("E1.d")].add(0.002)
    offsets = km.controller_offsets(model, params)
    assert offsets["A1"] == pytest.approx(-0.5729578, abs=1e-6)
    assert offsets["E1"] == pytest.approx(2.0, abs=1e-12) and offsets["A2"] == 0.0
    # the calibrated arm at controller reading q is the nominal arm at q + offset
    q_ctrl = np.array([100.0, 30.0, -20.0, 10.0])
    shifted = q_ctrl + np.array([offsets[j] for j in model.joint_names])
    np.testing.assert_allclose(
        np.asarray(km.forward(model, params, km.joints_from_controller(model, q_ctrl))),
        np.asarray(km.forward(model, model.nominal, km.joints_from_controller(model, shifted))), atol=1e-12)


def test_positioner_table_height_and_rotation():
    pos = km.PRESETS["positioner_2axis"]()
    assert pos.joint_names == ("tilt", "rotate")
    np.testing.assert_allclose(np.degrees(np.asarray(pos.upper)), [135.0, 360.0])
    T0 = np.asarray(km.forward(pos, pos.nominal, jnp.zeros(2)))
    np.testing.assert_allclose(T0, [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.8], [0, 0, 0, 1]], atol=1e-12)
    for tilt in (0.0, 0.7):
        Ta, Tb = np.asarray(km.forward(pos, pos.nominal, jnp.asarray([[tilt, 0.0], [tilt, 1.2]])))
        rel = np.linalg.inv(Ta) @ Tb  # a pure rotation about the table normal (local z)
        c, s = math.cos(1.2), math.sin(1.2)
        np.testing.assert_allclose(rel, [[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], atol=1e-12)
    table = km.rotary_table()
    T = np.asarray(km.forward(table, table.nominal, jnp.asarray([0.5])))
    np.testing.assert_allclose(T[:3, :3], [[math.cos(0.5), -math.sin(0.5), 0], [math.sin(0.5), math.cos(0.5), 0],
                                          [0, 0, 1]], atol=1e-12)


def test_from_spec_preset_and_tables():
    kuka = robots.kuka_kr10_r1100_sixx()
    q = _random_q(kuka, 6)
    expected = np.asarray(K.forward_kinematics(kuka, q))
    base = np.eye(4)
    base[:3, 3] = [1.0, 2.0, 0.5]
    specs = {
        "name": "kuka_kr10_r1100_sixx",
        "preset": {"preset": "kuka_kr10_r1100_sixx"},
        "preset_mdh": {"preset": "kuka_kr10_r1100_sixx", "convention": "mdh"},
        "dh_table": kt.to_spec(km.from_dh_robot(kuka, "dh"), km.from_dh_robot(kuka).nominal),
        "mdh_table": kt.to_spec(km.from_dh_robot(kuka, "mdh"), km.from_dh_robot(kuka, "mdh").nominal),
    }
    for label, spec in specs.items():
        model = kt.from_spec(spec, "r1")
        np.testing.assert_allclose(np.asarray(km.forward(model, model.nominal, q)), expected, atol=1e-9,
                                   err_msg=label)
    assert kt.from_spec("kuka_kr10_r1100_sixx", "r1").name == "r1 (KUKA KR 10 R1100 sixx)"
    moved = kt.from_spec({"preset": "kuka_kr10_r1100_sixx", "base": base.tolist()}, "r1")
    np.testing.assert_allclose(np.asarray(km.forward(moved, moved.nominal, q)), base @ expected, atol=1e-9)
    mdh = kt.from_spec(specs["mdh_table"], "r1")
    assert mdh.convention == "mdh" and mdh.param_names[4] == "A1.beta"


def test_from_spec_poe_table_from_dh_axes():
    robot = robots.abb_irb4600_45_205()
    frames = np.asarray(K.link_frames(robot, np.zeros(6)))[:-1]  # joint i turns about z of DH frame i-1
    spec = {"convention": "poe", "home": np.asarray(K.forward_kinematics(robot, np.zeros(6))).tolist(),
            "joints": [{"name": f"J{i + 1}", "axis": frames[i, :3, 2].tolist(), "point_m": frames[i, :3, 3].tolist(),
                        "sign": float(robot.joint_sign[i]),
                        "limits_deg": np.degrees([robot.lower[i], robot.upper[i]]).tolist()} for i in range(6)]}
    model = kt.from_spec(spec, "r2")
    assert model.convention == "poe" and float(np.abs(model.nominal).max()) == 0.0
    q = _random_q(robot, 8)
    expected = np.asarray(K.forward_kinematics(robot, q))
    np.testing.assert_allclose(np.asarray(km.forward(model, model.nominal, q)), expected, atol=1e-9)
    # and the export of a perturbed poe model reads back with the same FK
    params = model.nominal + 1e-3 * np.random.default_rng(3).standard_normal(model.num_params)
    back = kt.from_spec(kt.to_spec(model, params), "r2")
    np.testing.assert_allclose(np.asarray(km.forward(back, back.nominal, q)),
                               np.asarray(km.forward(model, params, q)), atol=1e-9)
    rows = kt.table(model, params)
    assert [r["name"] for r in rows] == ["J1", "J2", "J3", "J4", "J5", "J6", "base", "flange"]
    assert set(rows[0]) >= {"rx_deg", "tz_m", "axis", "point_m", "limits_deg"}


def test_poe_table_matches_a_global_product_of_exponentials():
    """Anti-parallel axes, a prismatic joint with sign -1, names that need sanitising; the reference is
    the textbook global POE ``exp(S1 q1) exp(S2 q2) exp(S3 q3) home`` written with scipy."""
    home = np.array([[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1]], dtype=float)
    joints = [([0, 0, 1], [0, 0, 0], "revolute", 1), ([0, 0, -1], [0.5, 0, 0], "revolute", 1),
              ([0, 1, 0], [0.5, 0, 0], "prismatic", -1)]
    spec = {"convention": "poe", "home": home.tolist(), "joints": [
        {"name": name, "type": t, "axis": axis, "point_m": point, "sign": sign,
         ("limits_deg" if t == "revolute" else "limits_mm"): [-90, 90]}
        for name, (axis, point, t, sign) in zip(("1", "j 2.x", "s"), joints)]}
    model = kt.from_spec(spec, "r")
    assert model.joint_names == ("J1", "j2_x", "s")
    q = np.array([0.3, 0.5, 0.2])
    expected = home
    for (axis, point, t, sign), qi in zip(reversed(joints), reversed(q)):
        motion = np.eye(4)
        if t == "prismatic":
            motion[:3, 3] = np.asarray(axis) * sign * qi
        else:
            motion[:3, :3] = Rotation.from_rotvec(np.asarray(axis) * sign * qi).as_matrix()
            motion[:3, 3] = np.asarray(point) - motion[:3, :3] @ np.asarray(point)
        expected = motion @ expected
    np.testing.assert_allclose(np.asarray(km.forward(model, model.nominal, q)), expected, atol=1e-12)


def _table(**joint_changes):
    joint = {"name": "A1", "type": "revolute", "a_m": 0.1, "alpha_deg": 90.0, "d_m": 0.4, "limits_deg": [-90, 90]}
    joint.update(joint_changes)
    return {"convention": "dh", "joints": [{k: v for k, v in joint.items() if v is not None}]}


POE_JOINT = {"name": "T1", "type": "prismatic", "axis": [1.0, 0.0, 0.0], "point_m": [0, 0, 0], "limits_mm": [0, 10]}
BAD_SPECS = [
    ("kuka_kr10_r1100_six", r"unknown kinematics preset 'kuka_kr10_r1100_six'; did you mean 'kuka_kr10_r1100_sixx'"),
    ({"preset": "abb_irb4600", "base": np.eye(4).tolist()}, r"did you mean 'abb_irb4600_45_205'"),
    ({"preset": "linear_track", "bass": []}, r"unknown key 'bass'.*did you mean 'base'"),
    ({"preset": "linear_track", "convention": "dhm"}, r"convention: unknown 'dhm'.*did you mean"),
    ({"joints": []}, r"missing field 'convention'; write convention: dh, mdh or poe"),
    (_table(a_m=None), r"joint 1 \('A1'\): missing field 'a_m'; write a_m: <number>"),
    (_table(d_m="0.4"), r"joint 1 \('A1'\): d_m: expected a finite number"),
    (_table(alpha_deg=float("inf")), r"joint 1 \('A1'\): alpha_deg: expected a finite number"),
    (_table(limits_deg=[-90, 0, 90]), r"joint 1 \('A1'\): limits_deg: expected shape \(2,\)"),
    (_table(limits_deg=[90, -90]), r"joint 1 \('A1'\): limits_deg: lower 90 >= upper -90"),
    (_table(limits_deg=None), r"missing field 'limits_deg'; write limits_deg: \[lower, upper\] \(deg\)"),
    (_table(type="prismatic"), r"limits_deg: a prismatic joint's limits are in mm; write limits_mm"),
    (_table(type="rotary"), r"type: unknown 'rotary'.*Write revolute or prismatic"),
    (_table(sign=2), r"sign: expected \+1 or -1"),
    (_table(beta_deg=1.0), r"joint 1 \('A1'\): unknown key 'beta_deg'.*write convention: mdh"),
    (_table(name=None), r"joint 1: missing field 'name'"),
    ({**_table(), "flang": np.eye(4).tolist()}, r"unknown key 'flang' in the dh table; did you mean 'flange'"),
    ([1, 2], r"expected a preset name or a mapping"),
    ({"convention": "dh"}, r"expected 'preset' or 'joints'"),
    ({**_table(), "base": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, r"base: expected shape \(4, 4\)"),
    ({**_table(), "flange": (2 * np.eye(4)).tolist()}, r"flange: not a rigid transform"),
    ({"convention": "dh", "joints": [_table()["joints"][0]] * 2}, r"\['A1'\] repeat"),
    ({"convention": "poe", "joints": [POE_JOINT]}, r"missing field 'home'"),
    ({"convention": "poe", "home": np.eye(4).tolist(), "joints": [{**POE_JOINT, "axis": [2.0, 0, 0]}]},
     r"joint 1 \('T1'\): axis: expected a unit vector.*write axis: \[1.0, 0.0, 0.0\]"),
    ({"convention": "poe", "home": np.eye(4).tolist(), "joints": [{**POE_JOINT, "a_m": 0.1}]},
     r"joint 1 \('T1'\): unknown key 'a_m'"),
]


@pytest.mark.parametrize("spec, message", BAD_SPECS)
def test_from_spec_errors_name_source_robot_joint_and_field(spec, message):
    with pytest.raises(BadInputError, match=r"^cell.yaml: kinematics of robot 'r7'") as info:
        kt.from_spec(spec, "r7", source="cell.yaml")
    assert info.match(message), str(info.value)


def test_forward_checks_shapes():
    model = km.PRESETS["rotary_table"]()
    with pytest.raises(BadInputError, match=r"params: expected shape \(16,\)"):
        km.forward(model, np.zeros(3), np.zeros(1))
    with pytest.raises(BadInputError, match=r"q: expected joint values of shape \(\.\.\., 1\)"):
        km.forward(model, model.nominal, np.zeros((2, 3)))
    T = np.asarray(km.forward(model, model.nominal.at[2].add(0.1), jnp.zeros((3, 1))))  # rotate.a
    assert T.shape == (3, 4, 4)
    np.testing.assert_allclose(T[:, 0, 3], 0.1, atol=1e-15)
