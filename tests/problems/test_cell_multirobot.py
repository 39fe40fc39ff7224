"""Whole cell with several robots, each with its own base in the world frame: exact recovery (r1 carries a
flange camera; r2 carries a board and a tool seen by a world camera; a world board), covariance against
the errors over seeds, reduction to the one-robot problem, unobservable bases, bad input, the CLI."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from scipy.stats import chi2

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import conversions, lie
from jcalib.io.cell import load_cell
from jcalib.io.observations import load_observations
from jcalib.problems import CalibrationOptions, calibrate_cell
from jcalib.sim.cells import synthetic_cell, synthetic_two_robot_cell

SIZES = dict(num_board_stations=10, num_r2_stations=10, num_cross_stations=5, num_tool_stations=14)
UNKNOWNS = ("T_flange_cam0", "T_world_cam1", "T_world_board", "T_flange_board2", "T_flange_torch", "T_world_r2")


def _solve(cell, obs, **kw):
    return calibrate_cell(load_cell(cell), load_observations(obs), CalibrationOptions(**kw))


@pytest.fixture(scope="module")
def noiseless():
    cell, obs, truth = synthetic_two_robot_cell(0, sigma_px=0.0, tip_sigma_px=0.0, robot_m=1e-9, robot_deg=1e-7,
                                                **SIZES)
    return cell, obs, truth, _solve(cell, obs, noise="stated")


def test_two_robot_cell_noiseless_recovery(noiseless):
    _, _, truth, cal = noiseless
    assert cal.status == "converged"
    assert cal.frame == "world"
    assert set(cal.transforms) == set(UNKNOWNS) | {"T_world_r1"}
    for name in UNKNOWNS:
        # 1e-6 m / 1e-6 (rotation entries): parameter recovery from noiseless data
        np.testing.assert_allclose(cal.transforms[name], truth[name], atol=1e-6, err_msg=name)
    # the gauge: r1's base is the world frame, held (zero covariance)
    np.testing.assert_array_equal(cal.transforms["T_world_r1"], np.eye(4))
    assert np.all(cal.transform_covariance["T_world_r1"] == 0.0)
    assert np.all(np.diag(cal.transform_covariance["T_world_r2"]) > 0.0)
    for cam in ("cam0", "cam1"):  # 1e-4 px on fx ~ 1400-1800 px (relative 1e-7)
        np.testing.assert_allclose(np.asarray(cal.cameras[cam].params), truth[cam], atol=1e-4, err_msg=cam)
    # the start order: hand-eye on r1, then r2's base by robot-world (AX = ZB), the TCP from tip rays
    assert cal.start_method["T_flange_cam0"].startswith("hand_eye")
    assert cal.start_method["T_world_r2"] == cal.start_method["T_flange_board2"] == "robot_world:shah"
    assert cal.start_method["T_flange_torch"] == "tip_rays"
    assert set(cal.flange_poses) == {"r1", "r2"}


def _tangent_error(T_est, T_true):
    """``Log(T_est⁻¹ T_true)`` (rx..tz): the result's right-perturbation convention ``T_true = T · Exp(δ)``."""
    return np.asarray(lie.local(conversions.matrix_to_pose(T_est), conversions.matrix_to_pose(T_true)))


def test_two_robot_errors_follow_the_reported_covariance():
    """Over 4 seeds, the errors of the 6 transforms (33 free coordinates; the torch's rotation is held)
    normalised by the reported joint covariance: Σ χ² ~ χ²(132) when the covariance is right.
    Bound: the 0.1 % and 99.9 % quantiles (a false failure 1 run in 500 with correct covariances).
    Stated noise equal to the simulated noise: the covariance needs no a-posteriori scale."""
    total, dof = 0.0, 0
    for seed in range(4):
        cell, obs, truth = synthetic_two_robot_cell(seed + 10, **SIZES)
        cal = _solve(cell, obs, noise="stated", sigma_px=0.2, tip_sigma_px=0.2, prediction=False)  # stated model
        jc = cal.joint_covariance
        starts = np.cumsum([0] + list(jc["dims"]))
        idx, err = [], []
        for name in UNKNOWNS:
            k = jc["names"].index(name)
            e = _tangent_error(cal.transforms[name], truth[name])
            free = np.diag(jc["matrix"])[starts[k]:starts[k + 1]] > 0
            idx.append(starts[k] + np.flatnonzero(free))
            err.append(e[free])
        idx, err = np.concatenate(idx), np.concatenate(err)
        C = jc["matrix"][np.ix_(idx, idx)]
        total += float(err @ np.linalg.solve(C, err))
        dof += err.size
    assert dof == 4 * 33
    assert chi2.ppf(0.001, dof) < total < chi2.ppf(0.999, dof), (total, dof)


def _as_two_robots(cell, obs, rng):
    """The one-robot synthetic cell written as a two-robot cell whose second robot carries nothing
    (its flange pose is in some stations, unused)."""
    cell = copy.deepcopy(cell)
    obs = copy.deepcopy(obs)
    noise = cell.pop("robot")
    cell["robots"] = {"r1": noise, "r2": noise}
    cell["cameras"]["cam0"]["robot"] = "r1"
    cell["cameras"]["cam1"]["mount"] = "world"
    cell["targets"]["board"]["mount"] = "world"
    cell["tools"]["needle"]["robot"] = "r1"
    for i, s in enumerate(obs["stations"]):
        s["flange_poses"] = {"r1": s.pop("T_base_flange")}
        if i % 3 == 0:
            T = np.eye(4)
            T[:3, 3] = rng.uniform(-1, 1, 3)
            s["flange_poses"]["r2"] = T.tolist()
    return cell, obs


def test_unused_second_robot_reduces_to_the_one_robot_problem():
    """The one-robot code path (frame base, T_base_flange) is the reference: the same estimates to
    1e-8 (both converge to the same optimum; the solver stops at relative steps far below that).
    Stated noise: the a-posteriori variance components stop at 1 % changes, and weights that agree to
    that level move the optimum by ~1e-6 σ, which is not what this test is about."""
    cell, obs, _ = synthetic_cell(5, num_board_stations=10, num_tool_stations=20)
    one = _solve(cell, obs, sigma_px=0.2, tip_sigma_px=0.2, noise="stated")
    cell2, obs2 = _as_two_robots(cell, obs, np.random.default_rng(0))
    two = _solve(cell2, obs2, sigma_px=0.2, tip_sigma_px=0.2, noise="stated")
    assert any("r2" in w for w in two.warnings)
    rename = {"T_base_cam1": "T_world_cam1", "T_base_board": "T_world_board"}
    assert set(two.transforms) == {rename.get(n, n) for n in one.transforms} | {"T_world_r1"}
    for n, T in one.transforms.items():
        np.testing.assert_allclose(two.transforms[rename.get(n, n)], T, atol=1e-8, err_msg=n)
        np.testing.assert_allclose(two.transform_covariance[rename.get(n, n)], one.transform_covariance[n],
                                   rtol=1e-6, atol=1e-20, err_msg=n)
    p1, p2 = np.asarray(one.cameras["cam0"].params), np.asarray(two.cameras["cam0"].params)
    np.testing.assert_allclose(p2[:4], p1[:4], rtol=1e-8)  # fx, fy, cx, cy (px)
    # distortion (unitless, σ ~1e-3): 1e-6 = the solver's stopping point on these flat directions
    np.testing.assert_allclose(p2[4:], p1[4:], atol=1e-6)
    assert two.rms_px == pytest.approx(one.rms_px, rel=1e-8)
    np.testing.assert_allclose(two.flange_poses["r1"]["estimated"], one.flange_poses["robot"]["estimated"], atol=1e-8)


def test_robot_without_a_link_to_the_world_is_named():
    cell, obs, _ = synthetic_two_robot_cell(1, **SIZES)
    # r2's board is seen only by a camera on r2 itself: nothing relates r2's base to the world
    cell["cameras"]["cam2"] = dict(cell["cameras"]["cam1"], mount="flange", robot="r2",
                                   fix=["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"])
    obs["cameras"]["cam2"] = obs["cameras"]["cam1"]
    keep = []
    for s in obs["stations"]:
        if "r1" in s["flange_poses"] and "r2" in s["flange_poses"] or any("tool" in d for d in s["detections"]):
            continue
        for d in s["detections"]:
            if d.get("target") == "board2":
                d["camera"] = "cam2"
        keep.append(s)
    obs["stations"] = keep
    cell["tools"] = {}
    with pytest.raises(NotObservableError, match="robot r2's base .* is not connected to the world frame") as err:
        _solve(cell, obs)
    assert "T_world_r2" in err.value.unknowns


def test_robot_seen_only_through_tool_tips_is_named():
    cell, obs, _ = synthetic_two_robot_cell(1, **SIZES)
    obs["stations"] = [s for s in obs["stations"] if not any(d.get("target") == "board2" for d in s["detections"])]
    with pytest.raises(NotObservableError, match="only through tool tips") as err:
        _solve(cell, obs)
    assert err.value.unknowns == ["T_world_r2"]


@pytest.mark.parametrize("case", ["missing_pose", "unknown_robot", "T_base_flange"])
def test_station_poses_are_checked_against_the_robots(case):
    cell, obs, _ = synthetic_two_robot_cell(1, **SIZES)
    s = next(s for s in obs["stations"] if "r1" in s["flange_poses"] and "r2" in s["flange_poses"])
    if case == "missing_pose":
        del s["flange_poses"]["r2"]
        needle = rf"station '{s['id']}'.*robot 'r2'.*add flange_poses"
    elif case == "unknown_robot":
        s["flange_poses"]["r7"] = s["flange_poses"]["r2"]
        needle = rf"station '{s['id']}'.*'r7'"
    else:
        s["T_base_flange"] = s.pop("flange_poses")["r1"]
        needle = rf"station '{s['id']}' gives T_base_flange.*flange_poses"
    with pytest.raises(BadInputError, match=needle):
        _solve(cell, obs)


def test_cli_calibrate_writes_the_robot_base(tmp_path, noiseless):
    from typer.testing import CliRunner

    from jcalib.app.cli import app

    cell, obs, truth, _ = noiseless
    (tmp_path / "cell.yaml").write_text(json.dumps(cell))  # JSON is YAML
    (tmp_path / "obs.json").write_text(json.dumps(obs))
    out = tmp_path / "result.json"
    # noiseless data: stated noise (an a-posteriori σ̂ of ~0 would make the covariance meaningless)
    res = CliRunner().invoke(app, ["calibrate", str(tmp_path / "cell.yaml"), str(tmp_path / "obs.json"), "-o", str(out),
                                   "--noise", "stated"])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    # noiseless data: 1e-6 m / rotation entries, as the recovery test
    np.testing.assert_allclose(np.asarray(data["transforms"]["T_world_r2"]["matrix"]), truth["T_world_r2"], atol=1e-6)
    assert np.asarray(data["transforms"]["T_world_r2"]["covariance"]).shape == (6, 6)
