"""Whole-cell problem: exact recovery from noiseless data (flange + fixed camera, fixed board, a tool
seen by the fixed camera), routing from ``jcalib.calibrate`` to result.json, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

import jcalib
from jcalib.errors import BadInputError
from jcalib.io.cell import load_cell
from jcalib.io.observations import load_observations
from jcalib.io.result import load_result
from jcalib.problems import CalibrationOptions, calibrate_cell
from jcalib.sim.cells import synthetic_cell

SIZES = dict(num_board_stations=10, num_tool_stations=20)  # one problem shape: one compilation


@pytest.fixture(scope="module")
def noiseless():
    cell, obs, truth = synthetic_cell(0, sigma_px=0.0, tip_sigma_px=0.0, robot_m=1e-9, robot_deg=1e-7, **SIZES)
    cal = calibrate_cell(load_cell(cell), load_observations(obs), CalibrationOptions(noise="stated"))
    return cell, obs, truth, cal


def test_noiseless_recovery_against_ground_truth(noiseless):
    _, _, truth, cal = noiseless
    assert cal.status == "converged"
    for name in ("T_flange_cam0", "T_base_cam1", "T_base_board", "T_flange_needle"):
        # 1e-6 m / 1e-6 (rotation entries): parameter recovery from noiseless data
        np.testing.assert_allclose(cal.transforms[name], truth[name], atol=1e-6, err_msg=name)
        assert cal.transforms[name].dtype == np.float64
    # intrinsics: 1e-4 px (fx ~ 1400 px; relative 1e-7), distortion 1e-6
    np.testing.assert_allclose(np.asarray(cal.cameras["cam0"].params), truth["cam0"], atol=1e-4)
    assert cal.start_method["T_flange_needle"] == "tip_rays"
    assert cal.start_method["T_flange_cam0"].startswith("hand_eye")
    # the TCP's rotation is not observable from a tip: held, zero covariance, and said so
    assert np.all(cal.transform_covariance["T_flange_needle"][:3, :3] == 0.0)
    assert cal.calibrated["T_flange_needle"] == ["tx", "ty", "tz"]
    assert cal.tool_orientation == {"needle": "not calibrated"}


def test_calibrate_routes_mixed_cell_and_writes_result(tmp_path):
    cell, obs, truth = synthetic_cell(1, **SIZES)
    result = jcalib.calibrate(cell, obs, CalibrationOptions(sigma_px=0.2, tip_sigma_px=0.2))
    path = result.to_json(tmp_path / "result.json")
    back = load_result(path)
    assert set(back.transforms) == {"T_flange_cam0", "T_base_cam1", "T_base_board", "T_flange_needle"}
    # one problem for every cell: the statistics of each residual kind it has (no "problem" family key)
    assert {"rms_px", "sigma_px", "tip_rms_px", "robot", "variance_components"} <= set(back.stats)
    assert back.transforms["T_flange_needle"].extra["orientation"] == "not calibrated"
    # errors against the ground truth within 5 σ of the reported covariance (a loose sanity bound:
    # the Monte-Carlo χ² check of the covariance is in benchmarks/bench_cell.py)
    t_err = back.transforms["T_flange_needle"].matrix[:3, 3] - truth["T_flange_needle"][:3, 3]
    cov = result.covariance("T_flange_needle")[3:, 3:]
    assert float(t_err @ np.linalg.solve(cov, t_err)) < 25.0
    jc = back.extra["joint_covariance"]
    M = np.asarray(jc["matrix"])
    np.testing.assert_allclose(M, M.T, atol=1e-15)
    # the joint covariance's diagonal blocks are the per-unknown covariances (1e-9 relative: same numbers)
    o = int(np.sum(jc["dims"][: jc["names"].index("T_base_cam1")]))
    np.testing.assert_allclose(M[o:o + 6, o:o + 6], result.covariance("T_base_cam1"), rtol=1e-9, atol=1e-20)


def test_static_camera_without_intrinsics_is_refused():
    cell, obs, _ = synthetic_cell(2, **SIZES)
    cell = json.loads(json.dumps(cell))
    del cell["cameras"]["cam1"]["intrinsics"]
    cell["cameras"]["cam1"]["fix"] = []
    with pytest.raises(BadInputError, match="cam1"):
        calibrate_cell(load_cell(cell), load_observations(obs))


# ------------------------------------------------------------------------------------ contacts, outliers


def _rot(axis, angle):
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(axis, np.float64) / np.linalg.norm(axis) * angle).as_matrix()


def _contact_stations(rng, tip, point, n, *, tilt_deg=30.0, one_axis=False, prefix="c"):
    """Flange poses (true) whose tool tip ``tip`` (flange frame) sits on ``point`` (base frame)."""
    out = []
    for i in range(n):
        if one_axis:
            R = _rot((0, 0, 1), rng.uniform(-np.pi, np.pi)) @ _rot((1, 0, 0), np.pi)
        else:
            axis = np.r_[rng.standard_normal(2), 0.0]
            R = _rot((0, 0, 1), rng.uniform(-np.pi, np.pi)) @ _rot(axis, np.radians(rng.uniform(5, tilt_deg))) \
                @ _rot((1, 0, 0), np.pi)
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = point - R @ tip
        out.append((f"{prefix}{i:03d}", T))
    return out


def _perturb(T, rng, sigma_m, sigma_deg):
    d = np.eye(4)
    d[:3, :3] = _rot(rng.standard_normal(3), np.radians(sigma_deg) * np.sqrt(3) * abs(rng.standard_normal()))
    d[:3, 3] = sigma_m * rng.standard_normal(3)
    return T @ d


PIVOT_TIP = np.array([0.012, -0.004, 0.185])
DIVOT = np.array([0.62, 0.11, 0.05])


def _pivot_data(rng, n=25, noise=(1e-4, 0.01), **kw):
    cell = {"schema": "jcalib.cell/1", "cameras": {}, "targets": {}, "tools": {"needle": {"observed_by": []}},
            "points": {"divot": {}}, "robot": {"pose_noise": {"translation_m": noise[0], "rotation_deg": noise[1]}}}
    stations = [{"id": sid, "T_base_flange": _perturb(T, rng, *noise).tolist(), "detections": [],
                 "contacts": [{"tool": "needle", "point": "divot"}]}
                for sid, T in _contact_stations(rng, PIVOT_TIP, DIVOT, n, **kw)]
    obs = {"schema": "jcalib.observations/1", "cameras": {}, "targets": {}, "stations": stations}
    return cell, obs


def test_pivot_cell_recovers_tip_and_divot(tmp_path):
    rng = np.random.default_rng(4)
    cell, obs = _pivot_data(rng, noise=(1e-9, 1e-7))
    result = jcalib.calibrate(cell, obs, CalibrationOptions(noise="stated"))
    cal = result.details
    # noiseless contacts: exact to 1e-7 m (robot noise 1e-9 m / 1e-7 deg over a 0.19 m lever)
    np.testing.assert_allclose(cal.transforms["T_flange_needle"][:3, 3], PIVOT_TIP, atol=1e-7)
    np.testing.assert_allclose(cal.points["divot"], DIVOT, atol=1e-7)
    assert cal.start_method["T_flange_needle"] == "contacts"
    back = load_result(result.to_json(tmp_path / "result.json"))
    np.testing.assert_allclose(back.points["divot"].position, DIVOT, atol=1e-7)
    assert back.points["divot"].covariance.shape == (3, 3)


def test_pivot_cell_matches_the_pivot_problem():
    """Contacts without a robot pose model are plain least squares on ``R tip + t - p``: the
    whole-cell solve lands on refine_pivot's optimum (independent code, same model)."""
    from jcalib.problems.pivot import refine_pivot

    rng = np.random.default_rng(5)
    cell, obs = _pivot_data(rng)
    cell["robot"] = {}  # a robot without pose_noise: its poses are exact
    cal = calibrate_cell(load_cell(cell), load_observations(obs))
    assert not cal.pose_model
    T = np.stack([np.asarray(s["T_base_flange"]) for s in obs["stations"]])
    ref = refine_pivot(T)
    np.testing.assert_allclose(cal.transforms["T_flange_needle"][:3, 3], ref.p_flange_tip, atol=1e-9)
    np.testing.assert_allclose(cal.points["divot"], ref.p_base_pivot, atol=1e-9)
    # a-posteriori covariances agree too (same residuals, same redundancy)
    np.testing.assert_allclose(cal.point_covariance["divot"], ref.covariance[3:, 3:], rtol=1e-6)


def test_tools_without_a_robot_are_tracked_tools():
    """A tracked pointer (an optical tracker's marker body, no robot): the cell without ``robot:`` is the
    cell with ``robot: {}`` (the tracked body is the flange, its measured poses exact): the same numbers."""
    cell, obs = _pivot_data(np.random.default_rng(5))
    cell["robot"] = {}
    with_robot = calibrate_cell(load_cell(cell), load_observations(obs))
    del cell["robot"]
    tracked = calibrate_cell(load_cell(cell), load_observations(obs))
    assert not tracked.pose_model
    np.testing.assert_array_equal(tracked.transforms["T_flange_needle"], with_robot.transforms["T_flange_needle"])
    np.testing.assert_array_equal(tracked.points["divot"], with_robot.points["divot"])
    np.testing.assert_array_equal(tracked.point_covariance["divot"], with_robot.point_covariance["divot"])


def test_contacts_about_one_axis_are_not_observable():
    from jcalib.errors import NotObservableError

    cell, obs = _pivot_data(np.random.default_rng(6), one_axis=True)
    with pytest.raises(NotObservableError, match="T_flange_needle") as err:
        calibrate_cell(load_cell(cell), load_observations(obs))
    assert "T_flange_needle" in err.value.unknowns


def test_contact_with_unknown_point_or_tool_is_refused():
    cell, obs = _pivot_data(np.random.default_rng(7), n=6)
    obs["stations"][2]["contacts"] = [{"tool": "needle", "point": "hole"}]
    with pytest.raises(BadInputError, match="point 'hole'"):
        calibrate_cell(load_cell(cell), load_observations(obs))
    obs["stations"][2]["contacts"] = [{"tool": "torch", "point": "divot"}]
    with pytest.raises(BadInputError, match="tool 'torch'"):
        calibrate_cell(load_cell(cell), load_observations(obs))


def test_contacts_join_the_camera_cell():
    """A needle seen by the fixed camera that also touches a divot: the contacts sharpen its TCP."""
    cell, obs, truth = synthetic_cell(2, **SIZES)
    tip = truth["T_flange_needle"][:3, 3]
    rng = np.random.default_rng(8)
    cell["points"] = {"divot": {}}
    for sid, T in _contact_stations(rng, tip, DIVOT, 12):
        obs["stations"].append({"id": sid, "T_base_flange": _perturb(T, rng, 1e-4, 0.01).tolist(), "detections": [],
                                "contacts": [{"tool": "needle", "point": "divot"}]})
    opts = CalibrationOptions(sigma_px=0.2, tip_sigma_px=0.2, contact_sigma_m=5e-5)
    with_contacts = calibrate_cell(load_cell(cell), load_observations(obs), opts)
    cell_nc, obs_nc, _ = synthetic_cell(2, **SIZES)
    without = calibrate_cell(load_cell(cell_nc), load_observations(obs_nc), opts)
    var_with = np.diag(with_contacts.transform_covariance["T_flange_needle"])[3:]
    var_without = np.diag(without.transform_covariance["T_flange_needle"])[3:]
    assert np.all(var_with < var_without)
    err = with_contacts.transforms["T_flange_needle"][:3, 3] - tip
    cov = with_contacts.transform_covariance["T_flange_needle"][3:, 3:]
    assert float(err @ np.linalg.solve(cov, err)) < 25.0  # loose 5σ sanity bound (χ² check: bench_cell)
    assert np.linalg.norm(with_contacts.points["divot"] - DIVOT) < 1e-3


def test_outlying_corners_and_tips_are_rejected():
    cell, obs, truth = synthetic_cell(3, **SIZES)
    clean = calibrate_cell(load_cell(cell), load_observations(obs), CalibrationOptions(sigma_px=0.2, tip_sigma_px=0.2))
    bad = []
    for k, (s, j) in enumerate([(1, 3), (4, 10), (7, 40)]):
        det = next(d for d in obs["stations"][s]["detections"] if d.get("camera") == "cam0")
        det["pixels"][j][0] += 25.0 + 5 * k
        bad.append(("cam0", obs["stations"][s]["id"], int(det["point_index"][j])))
    tip_station = next(s for s in obs["stations"] if any("tool" in d for d in s["detections"]))
    next(d for d in tip_station["detections"] if "tool" in d)["pixel"][1] += 30.0
    cal = calibrate_cell(load_cell(cell), load_observations(obs), CalibrationOptions(sigma_px=0.2, tip_sigma_px=0.2))
    assert set(bad) <= set(cal.outliers)
    assert ("cam1/needle", tip_station["id"], -1) in cal.outliers
    assert len(cal.outliers) == 4
    for name in ("T_flange_cam0", "T_base_cam1", "T_flange_needle"):  # back at the clean answer (< 0.5 σ)
        d = cal.transforms[name][:3, 3] - clean.transforms[name][:3, 3]
        cov = clean.transform_covariance[name][3:, 3:]
        assert float(d @ np.linalg.pinv(cov) @ d) < 0.25, name


def test_each_residual_kind_gets_its_own_noise_factor():
    """Corners at 0.05 px and tips at 0.5 px, both stated as 0.25 px: the variance components
    recover (0.05/0.25)² and (0.5/0.25)² (Helmert; tips: ~37 redundant coordinates, ±25 % at 1σ),
    and the TCP covariance follows the tips' own noise rather than the corners'."""
    cell, obs, truth = synthetic_cell(9, sigma_px=0.05, tip_sigma_px=0.5, **SIZES)
    cal = calibrate_cell(load_cell(cell), load_observations(obs), CalibrationOptions(sigma_px=0.25, tip_sigma_px=0.25,
                                                                                prediction=False))  # stated pose model
    comp = cal.variance_components
    assert 0.9 * 0.04 < comp["corner"] < 1.1 * 0.04
    assert 0.45 * 4.0 < comp["tip"] < 1.8 * 4.0
    assert cal.sigma_px == pytest.approx(0.25 * np.sqrt(comp["corner"]))
    # one common factor (the corners', they are the many) puts the tips at the corners' 0.05 px: the
    # TCP σ would come out too small (measured 1.5-1.7x here; the robot pose prior, which both keep as
    # stated, carries the rest of the TCP's uncertainty)
    one = calibrate_cell(load_cell(cell), load_observations(obs), CalibrationOptions(sigma_px=0.05, tip_sigma_px=0.05,
                                                                                noise="stated", prediction=False))
    ratio = np.sqrt(np.diag(cal.transform_covariance["T_flange_needle"])[3:]
                    / np.diag(one.transform_covariance["T_flange_needle"])[3:])
    assert np.all(ratio > 1.25)


def test_hat_traces_add_up_to_the_number_of_unknowns():
    """tr(H_g H⁻¹) summed over every factor group (priors included) is tr(I) = the free unknowns:
    an identity that checks the Schur-block assembly of the redundancies (the solve's traces, which
    the variance components use)."""
    cell, obs, _ = synthetic_cell(4, **SIZES)
    cal = calibrate_cell(load_cell(cell), load_observations(obs), CalibrationOptions(sigma_px=0.2, tip_sigma_px=0.2))
    sol = cal.solution
    assert cal.variance_components  # several kinds: the final solve carries the traces
    parts = list(sol.hat.values())
    assert {"prior:T_base_flange"} <= set(sol.hat) and len(parts) == len(sol.problem.factors)
    assert sum(parts) == pytest.approx(sol.num_free, rel=1e-9)
    assert all(p >= -1e-9 for p in parts)
    # each group uses up at most what it measures (its redundancy count − hat is not negative)
    assert all(sol.hat[n] <= sol.count[n] + 1e-9 for n in sol.hat)
