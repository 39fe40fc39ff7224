"""Any cell can be studied: the simulator (:func:`jcalib.sim.observe.simulate_observations`) against
independent projections (OpenCV), and the builder recovering the truth of every kind of cell from
noise-free simulated data (camera rigs, eye-to-hand, pose pairs, pivots, TCP with tool axes, the whole
cell, two robots)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from jcalib.geometry.cameras import camera_model_from_name
from jcalib.geometry.targets import Checkerboard
from jcalib.geometry.se3 import exp_so3, invert, log_se3, make_pose, rot_x
from jcalib.io.cell import parse_cell
from jcalib.sim.observe import CellTruth, ObservationNoise, SimStation, simulate_observations
from jcalib.study import load_scenario, run_study, simulate_trial

PARAMS = np.array([1400.0, 1395.0, 801.5, 598.0, -0.12, 0.08, 0.0005, -0.0003, -0.02])
KNOWN = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]
BOARD = {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025}
#: Almost noise-free (exactly zero residuals leave the a-posteriori noise at 0, which the solver's rank
#: test reads as not observable).
TINY = {"pixel_sigma_px": 1e-6, "tip_sigma_px": 1e-6, "axis_sigma_px": 1e-6, "robot_translation_m": 0.0,
        "robot_rotation_deg": 0.0, "contact_sigma_m": 1e-9, "pose_rotation_deg": 1e-7, "pose_translation_m": 1e-9}
ZERO = {"pixel_sigma_px": 0.0, "tip_sigma_px": 0.0, "axis_sigma_px": 0.0, "robot_translation_m": 0.0,
        "robot_rotation_deg": 0.0, "contact_sigma_m": 0.0, "pose_rotation_deg": 0.0, "pose_translation_m": 0.0}


def _eye_in_hand():
    cell = parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "mount": "flange"},
                                                              "cam1": {"model": "pinhole", "mount": "base"}},
                       "targets": {"board": {**BOARD, "mount": "base"}},
                       "tools": {"pin": {"observed_by": ["cam1"]}}, "points": {"divot": {}}, "robot": {}})
    X = make_pose(exp_so3(np.array([0.1, -0.2, 0.3])), [0.05, -0.02, 0.08])
    B = make_pose(rot_x(np.pi), [0.6, 0.1, 0.0])
    C1 = make_pose(rot_x(np.pi), [0.45, 0.0, 0.9])  # looking straight down
    tool = make_pose(exp_so3(np.array([0.2, 0.1, 0.0])), [0.01, 0.02, 0.2])
    truth = CellTruth(
        cameras={"cam0": camera_model_from_name("opencv5", (1600, 1200), PARAMS),
                 "cam1": camera_model_from_name("pinhole", (1600, 1200), PARAMS[:4])},
        poses={"cam0": X, "cam1": C1, "board": B, "pin": tool},
        target_points={"board": np.asarray(Checkerboard(cols=9, rows=6, square=0.025).points)},
        frame="base", points={"divot": np.array([0.5, 0.0, 0.05])})
    return cell, truth


def _look_down(T_base_target, distance, tilt=(0.0, 0.0, 0.0)):
    """A camera pose ``distance`` above the board centre, looking at it (board printed side up)."""
    c = T_base_target @ np.array([0.1, 0.0625, 0.0, 1.0])
    return make_pose(rot_x(np.pi) @ exp_so3(np.asarray(tilt)), c[:3] + [0.0, 0.0, distance])


def test_noise_free_corners_are_opencv_projections():
    """Every corner pixel equals cv2.projectPoints of the true chain inv(T_base_flange · X) · T_base_board
    (1e-9 px: the same OpenCV model evaluated two ways); the recorded flange poses are the true ones."""
    cell, truth = _eye_in_hand()
    X, B = truth.poses["cam0"], truth.poses["board"]
    stations = [SimStation(f"s{i}", flange={"robot": _look_down(B, 0.45, (0.2 * i - 0.3, 0.1 * i, 0.3)) @ invert(X)})
                for i in range(4)]
    obs, kept = simulate_observations(cell, truth, stations, ObservationNoise(), np.random.default_rng(0))
    assert kept == [s.id for s in stations]
    K, dist = (np.asarray(a, np.float64) for a in truth.cameras["cam0"].to_opencv())
    P = np.asarray(truth.target_points["board"])
    for s, rec in zip(stations, obs["stations"]):
        np.testing.assert_array_equal(np.asarray(rec["T_base_flange"]), s.flange["robot"])
        (det,) = [d for d in rec["detections"] if d.get("camera") == "cam0"]
        T = invert(s.flange["robot"] @ X) @ B
        ref, _ = cv2.projectPoints(P[det["point_index"]], cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K, dist)
        assert len(det["point_index"]) >= 30
        np.testing.assert_allclose(np.asarray(det["pixels"]), ref.reshape(-1, 2), atol=1e-9)


def test_tool_tips_axes_contacts_and_pose_measurements():
    """Noise-free: a tip pixel is the projection of the tool frame's origin, axis points lie on the image
    of its z axis (a pinhole camera: exactly collinear), contacts are recorded as planned, a pose
    measurement is the true ``T_cam_target``."""
    cell, truth = _eye_in_hand()
    C1 = truth.poses["cam1"]
    tool = truth.poses["pin"]
    R_F = rot_x(np.pi) @ exp_so3(np.array([0.1, 0.2, 0.0]))
    tip = C1[:3, 3] + np.array([0.05, -0.03, -0.45])  # 0.45 m below the camera that looks down
    F = make_pose(R_F, tip - R_F @ tool[:3, 3])
    s = SimStation("s0", flange={"robot": F}, contacts=(("pin", "divot"),), pose_pairs=(("cam0", "board"),),
                   axis_points=3, axis_length_m=0.06)
    obs, _ = simulate_observations(cell, truth, [s], ObservationNoise(), np.random.default_rng(1))
    (rec,) = obs["stations"]
    (tip,) = [d for d in rec["detections"] if d.get("tool") == "pin"]
    T_ck = invert(C1) @ F @ tool
    K = np.asarray(truth.cameras["cam1"].to_opencv()[0])
    proj = K @ T_ck[:3, 3]
    np.testing.assert_allclose(tip["pixel"], proj[:2] / proj[2], atol=1e-9)
    axis = np.asarray(tip["axis"])
    assert axis.shape == (3, 2)
    e = axis - np.asarray(tip["pixel"])
    assert np.max(np.abs(e[:, 0] * e[0, 1] - e[:, 1] * e[0, 0])) < 1e-6 * np.max(np.abs(e)) ** 2
    assert rec["contacts"] == [{"tool": "pin", "point": "divot"}]
    (pose,) = rec["poses"]
    np.testing.assert_allclose(pose["T_cam_target"], invert(F @ truth.poses["cam0"]) @ truth.poses["board"],
                               atol=1e-12)
    assert not [d for d in rec["detections"] if d.get("camera") == "cam0"]  # measured as a pose, not corners


def test_robot_noise_has_the_stated_sigma():
    """Recorded flange poses are the true ones times Exp(δ), δ ~ N(0, diag(σ_rot², σ_t²)) in the flange
    frame: over 600 stations every coordinate's Σ(δ/σ)² is within 4 standard deviations of χ²(600)."""
    cell, truth = _eye_in_hand()
    rng = np.random.default_rng(5)
    F = [make_pose(exp_so3(rng.normal(size=3)), rng.normal(size=3)) for _ in range(600)]
    stations = [SimStation(f"s{i}", flange={"robot": T}, contacts=(("pin", "divot"),)) for i, T in enumerate(F)]
    sig_t, sig_r = np.array([1e-4, 2e-4, 3e-4]), np.array([0.01, 0.02, 0.03])
    obs, _ = simulate_observations(cell, truth, stations, ObservationNoise(robot={"robot": (sig_t, sig_r)}),
                                   np.random.default_rng(6))
    d = np.stack([log_se3(invert(T) @ np.asarray(r["T_base_flange"])) for T, r in zip(F, obs["stations"])])
    chi2 = np.sum((d / np.concatenate([np.radians(sig_r), sig_t])) ** 2, axis=0)
    assert np.all(np.abs(chi2 - 600) < 4 * math.sqrt(2 * 600)), chi2


def test_dropout_and_two_robots():
    """Each detection is lost with the dropout rate (all lost at 0.999...); stations of a two-robot cell
    record the flange pose of each robot they involve."""
    cell = parse_cell({"schema": "jcalib.cell/1", "robots": {"r1": {}, "r2": {}},
                       "cameras": {"cam0": {"model": "opencv5", "mount": "flange", "robot": "r1"}},
                       "targets": {"board": {**BOARD, "mount": "flange", "robot": "r2"}}})
    _, base_truth = _eye_in_hand()
    B2 = make_pose(np.eye(3), [1.5, 0.0, 0.0])
    truth = CellTruth(cameras={"cam0": base_truth.cameras["cam0"]},
                      poses={"cam0": base_truth.poses["cam0"], "board": make_pose(np.eye(3), [0.0, 0.0, 0.05])},
                      target_points=base_truth.target_points, frame="world", bases={"r1": np.eye(4), "r2": B2})
    T_wb = make_pose(rot_x(np.pi), [0.7, 0.0, 0.3])
    F2 = invert(B2) @ T_wb @ invert(truth.poses["board"])
    F1 = _look_down(T_wb, 0.45, (0.1, 0.0, 0.2)) @ invert(truth.poses["cam0"])
    s = SimStation("s0", flange={"r1": F1, "r2": F2})
    obs, _ = simulate_observations(cell, truth, [s], ObservationNoise(), np.random.default_rng(2))
    (rec,) = obs["stations"]
    assert set(rec["flange_poses"]) == {"r1", "r2"} and "T_base_flange" not in rec
    assert len(rec["detections"]) == 1
    obs, kept = simulate_observations(cell, truth, [s], ObservationNoise(dropout_rate=1 - 1e-12),
                                      np.random.default_rng(2))
    assert kept == [] and obs["stations"] == []


# ------------------------------------------------------------------------------------ studies of every kind


def _assert_recovered(rows, tolerance):
    """(Almost) noise-free: every error column of the estimators in ``tolerance`` below theirs."""
    assert rows
    for r in rows:
        if r["estimator"] not in tolerance:
            continue
        assert r["status"] == "ok", r["status"]
        errs = {k: v for k, v in r.items() if k.startswith("err_") and isinstance(v, float) and not math.isnan(v)}
        assert errs, r
        bad = {k: v for k, v in errs.items() if abs(v) > tolerance[r["estimator"]]}
        assert not bad, (r["estimator"], bad)


def test_pivot_study_through_the_builder():
    """A cell of contacts only (a tool touching a point, no camera): the builder and the closed form
    recover the tip and the point from noise-free contacts; with noise, the builder's σ describe its
    errors (NEES of tip and point χ²(3): mean within [1.5, 5] over 16 trials, ±2.4 σ of the mean). Both
    runs share one compiled solve (same shapes, batches of 8)."""
    sc = {"cell": {"cameras": {}, "tools": {"tip": {}}, "points": {"divot": {}}, "robot": {}},
          "stations": {"strategy": "pivot", "count": 6}, "estimators": ["joint", "pivot"]}
    _assert_recovered(run_study({**sc, "noise": TINY}, 8, seed=3, progress=False), {"joint": 1e-5, "pivot": 1e-5})
    rows = [r for r in run_study({**sc, "noise": {"contact_sigma_m": 2e-4}}, 16, seed=4, progress=False)
            if r["estimator"] == "joint"]
    assert all(r["status"] == "ok" for r in rows)
    for col in ("nees_T_flange_tip", "nees_divot"):
        assert 1.5 < np.mean([r[col] for r in rows]) < 5.0, (col, np.mean([r[col] for r in rows]))


ANY_CELL = {
    "camera rig": ({"cameras": {"cam0": {"model": "opencv5"}, "cam1": {"model": "opencv5"}},
                    "targets": {"board": {**BOARD, "mount": "free"}}},
                   {"strategy": "random", "count": 10, "fill": [0.3, 0.5]}, {}, ["joint", "opencv"]),
    "eye-to-hand": ({"cameras": {"cam0": {"model": "opencv5", "mount": "base"}},
                     "targets": {"board": {**BOARD, "mount": "flange"}}, "robot": {}},
                    {"strategy": "random", "count": 10}, {}, ["joint", "park_martin", "shah"]),
    "pose pairs": ({"cameras": {"tracker": {"model": "pinhole", "mount": "flange"}},
                    "targets": {"marker": {"type": "points", "mount": "base"}}, "robot": {}},
                   {"strategy": "robocalib_handeye", "measure": "poses", "distance_m": 4.0},
                   {"targets": {"marker": {"points": np.random.default_rng(0).normal(size=(8, 3)).tolist()}}},
                   ["joint", "park_martin"]),
    "tcp with tool axes": ({"cameras": {"cam1": {"model": "pinhole", "mount": "base", "fix": ["fx", "fy", "cx", "cy"]}},
                            "tools": {"needle": {"observed_by": ["cam1"]}}, "robot": {}, "fixed": ["cam1"]},
                           {"strategy": "tcp_spread", "count": 12, "axis_points": 4},
                           {"poses": {"needle": {"position": [0.01, -0.02, 0.18], "rotation_deg": 10}}}, ["joint"]),
    "whole cell": ({"cameras": {"cam0": {"model": "opencv5", "mount": "flange"},
                                "cam1": {"model": "opencv5", "mount": "base", "fix": KNOWN}},
                    "targets": {"board": {**BOARD, "mount": "base"}}, "tools": {"needle": {"observed_by": ["cam1"]}},
                    "robot": {}},
                   [{"strategy": "random", "camera": "cam0", "count": 12}, {"strategy": "tcp_spread", "count": 15}],
                   {}, ["joint", "park_martin"]),
    "two robots": ({"robots": {"r1": {}, "r2": {}},
                    "cameras": {"cam0": {"model": "opencv5", "mount": "flange", "robot": "r1"},
                                "cam1": {"model": "opencv5", "mount": "world", "fix": KNOWN}},
                    "targets": {"board": {**BOARD, "mount": "world"}, "board2": {**BOARD, "mount": "flange", "robot": "r2"}}},
                   [{"strategy": "random", "camera": "cam0", "target": "board", "count": 10},
                    {"strategy": "random", "camera": "cam1", "target": "board2", "count": 10},
                    {"strategy": "random", "camera": "cam0", "target": "board2", "count": 6}], {}, ["joint"]),
}


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(ANY_CELL))
def test_any_cell_noise_free_recovers_the_truth(kind):
    """Every kind of cell through the same scenario form, simulator and builder: (almost) noise-free data
    give the truth back: the builder to 1e-4 (mm, deg, px, unitless; the data carry 1e-6 px), the closed
    forms to 1e-3 (PnP and cv2.calibrateCamera stop at their own tolerances), cv2.calibrateCamera to
    1e-2 px. Slow: one compilation per kind."""
    cell, stations, truth, estimators = ANY_CELL[kind]
    rows = run_study({"cell": cell, "truth": truth, "noise": TINY, "stations": stations, "estimators": estimators},
                     1, seed=3, progress=False)
    _assert_recovered(rows, {e: 1e-4 if e == "joint" else 1e-2 if e == "opencv" else 1e-3 for e in estimators})


def test_known_values_reach_the_estimators():
    """What the cell holds fixed without a value (all intrinsics in ``fix``, a camera in ``fixed``) is
    written into each trial's cell spec from that trial's truth; ``given`` does it for anything."""
    sc = load_scenario({"cell": {"cameras": {"cam1": {"model": "opencv5", "mount": "base", "fix": KNOWN}},
                                 "tools": {"needle": {"observed_by": ["cam1"]}}, "points": {"p": {}},
                                 "robot": {}, "fixed": ["cam1"]},
                        "truth": {"poses": {"cam1": {"rotation_deg": 30.0, "translation_m": 0.05}}},
                        "given": ["p"], "stations": {"strategy": "tcp_spread", "count": 5}})
    a, b = simulate_trial(sc, 0, 0), simulate_trial(sc, 0, 1)
    for t in (a, b):
        np.testing.assert_array_equal(t.cell.cameras["cam1"].pose, t.truth.poses["cam1"])
        np.testing.assert_allclose(t.cell.cameras["cam1"].K, np.asarray(t.truth.cameras["cam1"].to_opencv()[0]))
        np.testing.assert_array_equal(t.cell.points["p"].position, t.truth.points["p"])
    assert not np.array_equal(a.truth.poses["cam1"], b.truth.poses["cam1"])  # drawn per trial


def test_explicit_stations_are_the_true_poses():
    """``strategy: explicit`` simulates exactly the given flange poses (true poses; robot noise on the
    recorded ones): the pivot closed form recovers tip and point from noise-free contacts (1e-9 mm)."""
    rng = np.random.default_rng(0)
    tip, point = np.array([0.01, -0.02, 0.175]), np.array([0.5, 0.0, 0.1])
    records = []
    for _ in range(6):
        R = rot_x(np.pi) @ exp_so3(0.4 * rng.normal(size=3))
        records.append({"T_base_flange": make_pose(R, point - R @ tip).tolist(),
                        "contacts": [{"tool": "tip", "point": "divot"}]})
    sc = {"cell": {"cameras": {}, "tools": {"tip": {}}, "points": {"divot": {}}, "robot": {}},
          "truth": {"poses": {"tip": make_pose(np.eye(3), tip).tolist()}, "points": {"divot": point.tolist()}},
          "stations": {"strategy": "explicit", "stations": records}, "noise": ZERO, "estimators": ["pivot"]}
    t = simulate_trial(load_scenario(sc), 0, 0)
    for s, rec in zip(t.observations.stations, records):
        np.testing.assert_array_equal(s.T_base_flange, np.asarray(rec["T_base_flange"]))
    (row,) = run_study(sc, 1, progress=False)
    assert row["status"] == "ok" and row["err_T_flange_tip_trans_mm"] < 1e-9 and row["err_divot_norm_mm"] < 1e-9


@pytest.mark.parametrize("kind", list(ANY_CELL))
def test_scenarios_round_trip_as_plain_data(kind):
    """A scenario's plain data (what a Dask worker receives) loads back to the same scenario and the same
    simulated trial."""
    cell, stations, truth, estimators = ANY_CELL[kind]
    sc = load_scenario({"cell": cell, "truth": truth, "stations": stations, "estimators": estimators})
    back = load_scenario(sc.to_dict())
    assert back.to_dict() == sc.to_dict()
    assert simulate_trial(back, 5, 2).observations.to_dict() == simulate_trial(sc, 5, 2).observations.to_dict()
