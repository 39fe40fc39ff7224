"""The robot error model (``robot: {error_model: ...}``, :mod:`jcalib.problems.error_model`) and the
intrinsics-absorb check (:mod:`jcalib.problems.absorb`).

Cheap tests: the cell key, which models ``auto`` compares, the choice rule on given scores, and one small
eye-in-hand cell calibrated end to end. The multi-seed rates of the acceptance (auto picks the generating
model in ≥ 90 % of seeds, the absorb warning) are ``slow`` and in ``benchmarks/bench_accuracy_in_use.py``.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import jcalib
from jcalib.errors import BadInputError
from jcalib.io.cell import cell_to_dict, parse_cell
from jcalib.io.observations import parse_observations
from jcalib.problems import CalibrationOptions
from jcalib.problems import error_model as em

_path = Path(__file__).resolve().parent / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers_error_model", _path)
J = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(J)

ARM = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
       "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03, "mount": "base"}},
       "robot": {"kinematics": "kuka_kr10_r1100_sixx"}}


def _obs(joints: bool) -> object:
    st = {"id": "s0", "T_base_flange": np.eye(4).tolist(),
          "detections": [{"camera": "cam0", "target": "board", "point_index": [0, 1, 2, 3],
                          "pixels": [[1.0, 2.0], [3.0, 4.0], [5.0, 6.0], [7.0, 8.0]]}]}
    if joints:
        st["joints_deg"] = [0.0, -90.0, 90.0, 0.0, 0.0, 0.0]
    return parse_observations({"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": [640, 480]}},
                               "targets": {"board": {"points": np.zeros((54, 3)).tolist()}}, "stations": [st]})


def test_error_model_key_is_checked_and_round_trips():
    with pytest.raises(BadInputError, match="error_model"):
        parse_cell({**ARM, "robot": {"error_model": "magic"}})
    with pytest.raises(BadInputError, match="error_model.*nominal model"):
        parse_cell({**ARM, "robot": {"error_model": "kinematics"}})
    cell = parse_cell({**ARM, "robot": {"kinematics": "kuka_kr10_r1100_sixx", "error_model": "pose_noise"}})
    assert cell.robot.error_model == "pose_noise"
    assert cell_to_dict(cell)["robot"]["error_model"] == "pose_noise"
    assert "error_model" not in cell_to_dict(parse_cell(ARM))["robot"]  # auto, the default, is not written


def test_auto_compares_the_models_that_apply():
    runs, why = em.candidates(parse_cell(ARM), _obs(joints=True), CalibrationOptions())
    assert [m for m, _ in runs] == ["exact", "pose_noise", "kinematics"]
    exact, pose, kin = (c.robot for _, c in runs)
    assert exact.pose_noise_translation_m is None and not exact.calibrate_kinematics
    assert np.allclose(pose.pose_noise_translation_m, em.DEFAULT_POSE_NOISE[0])  # no stated level: the default
    assert kin.calibrate_kinematics == em.DEFAULT_KINEMATIC_GROUPS and not why
    # without recorded joints the kinematics cannot be calibrated: said why
    runs, why = em.candidates(parse_cell(ARM), _obs(joints=False), CalibrationOptions())
    assert [m for m, _ in runs] == ["exact", "pose_noise"] and "joints_deg" in why["kinematics"]
    # a stated level is the pose model's prior, never a reason to use it
    stated = {**ARM, "robot": {**ARM["robot"], "pose_noise": {"translation_m": 1e-4, "rotation_deg": 0.01}}}
    runs, _ = em.candidates(parse_cell(stated), _obs(joints=False), CalibrationOptions())
    assert [m for m, _ in runs] == ["exact", "pose_noise"]
    assert np.allclose(runs[1][1].robot.pose_noise_translation_m, 1e-4)


def test_a_forced_model_or_auto_off_calibrates_once():
    forced = parse_cell({**ARM, "robot": {**ARM["robot"], "error_model": "exact"}})
    runs, _ = em.candidates(forced, _obs(joints=True), CalibrationOptions())
    assert len(runs) == 1 and runs[0][1].robot.pose_noise_translation_m is None
    for options in (CalibrationOptions(prediction=False), CalibrationOptions(pose_model=False)):
        runs, _ = em.candidates(parse_cell(ARM), _obs(joints=True), options)
        assert len(runs) == 1 and runs[0][1].robot.error_model == "auto"  # as the cell states it
    with pytest.raises(BadInputError, match="joints_deg"):
        em.candidates(parse_cell({**ARM, "robot": {**ARM["robot"], "error_model": "kinematics"}}), _obs(joints=False),
                      CalibrationOptions())


def _fake(rms_px: float, sigma_px: float, n: int = 2000) -> SimpleNamespace:
    return SimpleNamespace(prediction={"rms_px": rms_px}, sigma_px=sigma_px, num_residuals=n, robot_error_model=None)


def test_choice_keeps_the_best_predictor_and_the_simplest_of_ties():
    # clearly better held-out prediction wins, whatever the fit
    chosen, info = em.choose({"exact": _fake(3.0, 0.3), "pose_noise": _fake(2.9, 0.2), "kinematics": _fake(0.4, 0.2)},
                             {}, {})
    assert chosen == "kinematics" and info["scores"]["exact"]["rms_px"] == 3.0
    # tied held-out prediction, same corner noise: the simplest
    tie = 1.0 + 0.5 * em.TIE
    chosen, _ = em.choose({"exact": _fake(1.0 * tie, 0.2), "pose_noise": _fake(1.0, 0.2)}, {}, {})
    assert chosen == "exact"
    # tied prediction, but the simpler model leaves the robot's error in its residuals: the pose model
    chosen, _ = em.choose({"exact": _fake(1.0 * tie, 1.0), "pose_noise": _fake(1.0, 0.2)}, {}, {})
    assert chosen == "pose_noise"
    # a station far off does not hide a model that predicts better at every station (sign test, not a mean)
    stations = [f"s{k}" for k in range(15)]
    worse = {"rms_px": 4.0, "per_station": {s: {"rms_px": 40.0 if s == "s0" else 3.0} for s in stations}}
    better = {"rms_px": 1.0, "per_station": {s: {"rms_px": 3.5 if s == "s1" else 0.3} for s in stations}}
    assert not em.indistinct(worse, better)
    # ... while two models that trade stations are tied
    mixed = {"rms_px": 1.2, "per_station": {s: {"rms_px": 0.2 if k % 2 else 0.4} for k, s in enumerate(stations)}}
    assert em.indistinct(mixed, better | {"per_station": {s: {"rms_px": 0.3} for s in stations}})
    # a failed model is reported, not chosen
    chosen, info = em.choose({"exact": _fake(1.0, 0.2)}, {"kinematics": "not observable"}, {"pose_noise": "x"})
    assert chosen == "exact" and info["failed"] == {"kinematics": "not observable"}


def test_auto_on_a_small_eye_in_hand_cell_with_random_pose_error():
    """Random flange-pose errors of 0.3 mm / 0.03° (stated as nothing): auto keeps the pose model, estimates its
    level near the truth, says the other's score, and the result file reproduces the chosen problem."""
    cell, obs, _ = J.make_data(21, mount="flange", n=10, sigma_px=0.3, robot_m=3e-4, robot_deg=0.03)
    cell = {k: v for k, v in cell.items() if k != "robot"} | {"robot": {}}
    res = jcalib.calibrate(cell, obs)
    info = res.file.stats["robot_error_model"]
    assert info["chosen"] == "pose_noise" and set(info["scores"]) == {"exact", "pose_noise"}
    assert res.file.stats["prediction"]["model"] == {"robot": "pose_noise"}
    level = info["pose_noise_level"]["robot"]
    # the level is estimated from the corrections (the default prior only weighs in): within a factor 2 of 0.3 mm
    assert 1.5e-4 < level["translation_m"] < 6e-4
    # the result file records the choice: the problem restored from it is the chosen one, at its optimum
    from jcalib.io.cell import load_cell
    from jcalib.problems.calibrate import restore

    back = restore(load_cell(cell), parse_observations(obs), res.file)
    assert back.pose_model
    std = np.sqrt(np.diag(res.file.transforms["T_flange_cam0"].covariance))
    moved = np.abs(back.transforms["T_flange_cam0"][:3, 3] - res.file.transforms["T_flange_cam0"].matrix[:3, 3])
    assert np.all(moved < 1e-3 * std[3:])


@pytest.mark.slow
def test_absorb_warning_fires_on_a_systematic_robot_error_and_not_on_an_exact_robot():
    """An exact-pose solve of an arm ~1 mm off its nominal kinematics names the intrinsics that absorbed it; the
    same arm with exact poses does not warn (5 seeds each; the benchmark runs more)."""
    from jcalib.geometry import kinematic_models
    from jcalib.problems.calibrate import calibrate_cell
    from jcalib.problems.kinematics import generic_joints, select_parameters
    from jcalib.sim.kinematic_cells import synthetic_arm_cell

    model = kinematic_models.PRESETS["kuka_kr10_r1100_sixx"]()
    mask = select_parameters(model, em.DEFAULT_KINEMATIC_GROUPS, generic_joints(model), np.eye(6) * 1e4, "r").free
    fired = {}
    for scale in (1.0, 0.0):
        fired[scale] = 0
        for seed in range(5):
            cell, obs, _ = synthetic_arm_cell(seed, 15, 1, error_mask=mask, error_scale=scale, scatter=scale > 0)
            cell["robot"] = {"kinematics": "kuka_kr10_r1100_sixx", "error_model": "exact"}
            cal = calibrate_cell(parse_cell(cell), parse_observations(obs), CalibrationOptions())
            fired[scale] += any("absorb robot pose error" in w for w in cal.warnings)
    assert fired[1.0] >= 4 and fired[0.0] == 0


def test_console_line_and_report_section_say_the_model_and_the_scores():
    from jcalib.report.error_model import error_model_line, error_model_section

    level = {"robot": {"factor": 0.7, "translation_m": 3.5e-4, "rotation_deg": 0.035, "prior_translation_m": 5e-4,
                       "prior_rotation_deg": 0.05}}
    stats = {"robot_error_model": {"chosen": "pose_noise", "criterion": "the lowest held-out prediction error",
                                   "scores": {"exact": {"rms_px": 2.5, "sigma_px": 1.4},
                                              "pose_noise": {"rms_px": 2.4, "sigma_px": 0.2}},
                                   "pose_noise_level": level, "not_applicable": {"kinematics": "no joints"}}}
    line = error_model_line(stats)
    assert line.startswith("robot error model: pose_noise") and "exact 2.500" in line and "0.35 mm" in line
    html = error_model_section(stats)
    assert "Robot error model" in html and ">2.4</td>" in html and "no joints" in html
    assert error_model_line({}) is None and error_model_section({}) == ""
