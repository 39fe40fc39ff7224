"""Robot kinematic calibration inside the joint problem: recovery, identifiability, degenerate motion,
bad input and the result file (docs/design.md: kinematics is a preset of the one builder)."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import yaml

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import kinematic_models
from jcalib.geometry.se3 import invert
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.io.result import ResultFile
from jcalib.problems import CalibrationOptions, calibrate_cell
from jcalib.problems.calibrate import result_file
from jcalib.problems.kinematics import generic_joints, select_parameters
from jcalib.sim.kinematic_cells import synthetic_arm_cell, synthetic_positioner_cell


def structural_mask(preset: str, groups=("joint_offsets", "link_lengths", "twists")) -> np.ndarray:
    """The parameters the builder keeps free for generic motion (errors are drawn only for those)."""
    model = kinematic_models.PRESETS[preset]()
    return select_parameters(model, groups, generic_joints(model), np.eye(6) * 1e4, "robot").free


def calibrate(cell, obs, **options):
    return calibrate_cell(parse_cell(cell), parse_observations(obs), CalibrationOptions(**options))


@pytest.fixture(scope="module")
def positioner_noiseless():
    mask = structural_mask("positioner_2axis")
    cell, obs, truth = synthetic_positioner_cell(3, num_stations=16, num_heldout=4, sigma_deg=0.0, sigma_m=0.0,
                                                 scatter=False, error_mask=mask, error_scale=20.0)
    return cell, obs, truth, mask, calibrate(cell, obs)


def test_positioner_kinematics_sensor_and_target_recovered_from_noiseless_poses(positioner_noiseless):
    """A 2-axis positioner seen by a fixed 6-DOF sensor: the identifiable DH parameters, the sensor's pose
    and the target's pose on the table come back to 1e-6 (m, rad) from noiseless measurements."""
    _, _, truth, mask, cal = positioner_noiseless
    k = cal.kinematics["robot"]
    assert np.array_equal(k["free"], mask)
    assert mask.sum() >= 2
    err = np.abs(k["params"] - truth["params"])
    assert err.max() < 1e-6, dict(zip(truth["names"], err))
    # the errors were real (20x the realistic σ): the nominal model is far off
    assert np.abs(truth["params"] - truth["nominal"])[mask].max() > 1e-3
    for name, T in (("T_base_tracker", truth["T_base_tracker"]), ("T_flange_part", truth["T_flange_part"])):
        D = invert(T) @ cal.transforms[name]
        assert np.linalg.norm(D[:3, 3]) < 1e-6
        assert np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)) < 1e-6


def test_held_parameters_are_named_with_what_absorbs_them(positioner_noiseless):
    _, _, truth, mask, cal = positioner_noiseless
    held = cal.kinematics["robot"]["held"]
    names = np.array(truth["names"])
    requested = set(kinematic_models.parameter_groups(kinematic_models.PRESETS["positioner_2axis"]())["joint_offsets"])
    # every requested parameter is either free or held with a reason
    for n in requested:
        assert (n in names[mask]) or ("not separable" in held[n])
    # the first joint's offset is a rotation of the base: what is fixed in the base absorbs it
    first = kinematic_models.PRESETS["positioner_2axis"]().joint_names[0]
    assert "base frame" in held[f"{first}.theta"]


def test_result_file_carries_the_kinematics_and_round_trips(positioner_noiseless):
    _, _, truth, mask, cal = positioner_noiseless
    file = result_file(cal, CalibrationOptions(), "0" * 16)
    back = ResultFile.from_dict(file.to_dict())
    k = back.kinematics["robot"]
    assert k.convention == "dh"
    assert list(k.names) == truth["names"]
    assert set(k.calibrated) == set(np.array(truth["names"])[mask])
    assert np.allclose(k.values, cal.kinematics["robot"]["params"], rtol=0, atol=1e-15)
    assert k.covariance.shape == (mask.sum(), mask.sum())
    assert set(k.extra["held"]) == set(cal.kinematics["robot"]["held"])
    assert set(k.extra["controller_offsets"]) == set(kinematic_models.PRESETS["positioner_2axis"]().joint_names)
    assert k.extra["heldout"]["calibrated"]["position_median_mm"] < 1e-3  # noiseless: exact to 1e-6 m
    assert k.extra["heldout"]["nominal"]["position_median_mm"] > 0.1


def test_arm_kinematics_recovered_and_held_out_poses_beat_the_nominal_model():
    """A 6-axis arm with hidden DH errors and a camera on its flange, 0.2 px: the recovered parameters lie
    within their σ (χ² over the free parameters), and on held-out joint values the calibrated model puts
    the flange camera far closer to its true pose (in the board frame, each model with the cell's
    estimates) than the nominal kinematics does. The comparison with today's per-station pose-noise
    model (its own hand-eye and board estimates) is benchmarks/bench_kinematics.py."""
    mask = structural_mask("kuka_kr10_r1100_sixx")
    cell, obs, truth = synthetic_arm_cell(5, num_stations=30, num_heldout=10, error_mask=mask)
    cal = calibrate(cell, obs)
    k = cal.kinematics["robot"]
    assert np.array_equal(k["free"], mask)
    free = k["free"]
    e = (k["params"] - truth["params"])[free]
    C = np.asarray(k["covariance"])[np.ix_(free, free)]
    chi2 = float(e @ np.linalg.solve(C, e))
    dof = int(free.sum())
    assert chi2 < dof + 5 * np.sqrt(2 * dof), (chi2, dof)  # χ²(dof): a 5σ bound, one trial
    assert np.sqrt(np.mean(((truth["params"] - truth["nominal"])[free]) ** 2 / np.diag(C))) > 10  # errors ≫ σ

    model = kinematic_models.PRESETS["kuka_kr10_r1100_sixx"]()
    q = truth["heldout"]["q"]
    true = invert(truth["T_base_board"]) @ truth["heldout"]["T_base_flange"] @ truth["T_flange_cam0"]

    def error_mm(params):
        T_bf = np.asarray(kinematic_models.forward(model, params, q))
        pred = invert(cal.transforms["T_base_board"]) @ T_bf @ cal.transforms["T_flange_cam0"]
        return 1e3 * np.linalg.norm(pred[:, :3, 3] - true[:, :3, 3], axis=1)

    calibrated, nominal = np.median(error_mm(k["params"])), np.median(error_mm(truth["nominal"]))
    assert calibrated < 0.2 * nominal, (calibrated, nominal)
    assert calibrated < 0.1  # mm: pixel noise and the robot's 0.02 mm repeatability
    # the result's own held-out check (no truth: folds of stations predicted from the others) sees it too
    held = k["heldout"]
    assert held["stations"] == 30 and held["folds"] == 5
    assert held["calibrated"]["position_median_mm"] < 0.5 * held["nominal"]["position_median_mm"]
    assert held["calibrated"]["rotation_median_deg"] < 0.5 * held["nominal"]["rotation_median_deg"]


def test_a_joint_that_never_moved_is_named_exit_3(tmp_path, run_cli):
    cell, obs, _ = synthetic_positioner_cell(4, num_stations=12, num_heldout=1, sigma_deg=0.0, sigma_m=0.0,
                                             scatter=False)
    still = copy.deepcopy(obs)
    model = kinematic_models.PRESETS["positioner_2axis"]()
    for st in still["stations"]:
        st["joints_deg"][1] = 30.0  # the table never turned
        st["T_base_flange"] = np.asarray(kinematic_models.forward(
            model, model.nominal, kinematic_models.joints_from_controller(model, st["joints_deg"]))).tolist()
    with pytest.raises(NotObservableError, match=f"{model.joint_names[1]}.*never moved") as err:
        calibrate(cell, still)
    assert err.value.unknowns
    # the command line: exit 3, the message on stderr, no traceback
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    (tmp_path / "obs.json").write_text(json.dumps(still))
    code, text = run_cli("calibrate", tmp_path / "cell.yaml", tmp_path / "obs.json", "-o", tmp_path / "r.json")
    assert code == 3
    assert "never moved" in text and "Traceback" not in text
    assert not (tmp_path / "r.json").exists()


def test_a_parameter_asked_for_by_name_that_no_motion_determines_is_refused():
    cell, obs, _ = synthetic_positioner_cell(4, num_stations=12, num_heldout=1)
    first = kinematic_models.PRESETS["positioner_2axis"]().joint_names[0]
    cell["robot"]["calibrate_kinematics"] = [f"{first}.theta"]
    with pytest.raises(NotObservableError, match=rf"{first}\.theta.*cannot be determined by any motion"):
        calibrate(cell, obs)


@pytest.mark.parametrize("edit, message", [
    (lambda c, o: c["robot"].pop("kinematics"), "needs the robot's nominal model"),
    (lambda c, o: c["robot"].update(calibrate_kinematics=["joint_ofsets"]), "joint_offsets"),
    (lambda c, o: o["stations"][2].pop("joints_deg"), "no joints_deg"),
    (lambda c, o: o["stations"][1].update(joints_deg=[1.0, 2.0, 3.0]), "station 's001'"),
    (lambda c, o: c["robot"].update(kinematics="kuka_kr10_r1100_six"), "kuka_kr10_r1100_sixx"),
])
def test_bad_kinematic_input_is_a_clear_error(edit, message):
    cell, obs, _ = synthetic_positioner_cell(4, num_stations=8, num_heldout=1)
    edit(cell, obs)
    with pytest.raises(BadInputError, match=message):
        calibrate(cell, obs)


def test_no_pose_model_is_refused_for_kinematic_calibration():
    cell, obs, _ = synthetic_positioner_cell(4, num_stations=8, num_heldout=1)
    with pytest.raises(BadInputError, match="no-pose-model"):
        calibrate(cell, obs, pose_model=False)


@pytest.mark.parametrize("convention", [
    pytest.param("mdh", marks=pytest.mark.slow(reason="compiles a third kinematic structure; the builder's convention-"
                                              "independence is checked by the poe case, mdh's FK by tests/geometry")),
    "poe"])
def test_other_conventions_fit_the_same_robot_exactly(convention):
    """The positioner's true (DH) kinematics calibrated in MDH or POE form: each parameterisation keeps its
    own identifiable subset, and all predict the part's pose in the sensor frame at new joint values
    exactly (noiseless data), where the nominal model is off."""
    cell, obs, truth = synthetic_positioner_cell(8, num_stations=16, num_heldout=6, sigma_deg=0.0, sigma_m=0.0,
                                                 scatter=False, error_mask=structural_mask("positioner_2axis"),
                                                 error_scale=20.0)
    cell["robot"]["kinematics"] = {"preset": "positioner_2axis", "convention": convention}
    cell["robot"]["calibrate_kinematics"] = ["all"]
    cal = calibrate(cell, obs)
    k = cal.kinematics["robot"]
    model = k["model"]
    assert model.convention == convention and k["free"].sum() >= 2
    assert "base.rx" in k["held"] and "flange.tz" in k["held"]
    q = truth["heldout"]["q"]
    true = invert(truth["T_base_tracker"]) @ truth["heldout"]["T_base_flange"] @ truth["T_flange_part"]
    pred = invert(cal.transforms["T_base_tracker"]) @ np.asarray(kinematic_models.forward(model, k["params"], q)) \
        @ cal.transforms["T_flange_part"]
    nominal = invert(cal.transforms["T_base_tracker"]) @ np.asarray(kinematic_models.forward(model, model.nominal, q)) \
        @ cal.transforms["T_flange_part"]
    assert np.abs(pred[:, :3, 3] - true[:, :3, 3]).max() < 1e-6
    assert np.abs(nominal[:, :3, 3] - true[:, :3, 3]).max() > 1e-4


def test_barely_excited_parameters_lean_on_the_prior_and_are_named():
    """A positioner whose tilt axis moves only ±0.2°: its geometry is barely seen, so the estimate stays near
    the nominal model (the prior), within its σ of the truth, and the result names the weak parameters."""
    cell, obs, truth = synthetic_positioner_cell(9, num_stations=16, num_heldout=1, tilt_range_deg=0.2)
    cal = calibrate(cell, obs)
    k = cal.kinematics["robot"]
    assert k["weak"], k["free"]
    assert any("barely determine" in w and all(n in w for n in k["weak"]) for w in cal.warnings)
    free = k["free"]
    z = (k["params"] - truth["params"])[free] / np.sqrt(np.diag(k["covariance"]))[free]
    assert np.all(np.abs(z) < 5), z


def test_the_robot_model_preset_is_the_nominal_kinematics_when_the_cell_has_no_kinematics():
    """``robot: {model: kuka_kr10_r1100_sixx, calibrate_kinematics: [...]}`` needs no second ``kinematics:``
    (docs/design.md): the preset is the nominal model, and writing the cell back does not add one."""
    from jcalib.io.cell import cell_to_dict

    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025, "mount": "base"}}}
    spec = parse_cell({**cell, "robot": {"model": "kuka_kr10_r1100_sixx", "calibrate_kinematics": ["joint_offsets"]}})
    model = kinematic_models.PRESETS["kuka_kr10_r1100_sixx"]()
    assert spec.robot.kinematics_from_model
    assert spec.robot.kinematics.param_names == model.param_names
    assert np.array_equal(spec.robot.kinematics.nominal, model.nominal)
    assert cell_to_dict(spec)["robot"] == {"model": "kuka_kr10_r1100_sixx", "calibrate_kinematics": ["joint_offsets"]}
    with pytest.raises(BadInputError, match="model 'my_arm' is not a kinematics preset"):
        parse_cell({**cell, "robot": {"model": "my_arm", "calibrate_kinematics": ["joint_offsets"]}})


def test_a_model_preset_calibrates_as_the_same_kinematics_preset_and_says_so(positioner_noiseless):
    """The noiseless positioner cell with ``model: positioner_2axis`` instead of ``kinematics:``: the same
    numbers (same problem, same compiled solve), and the result notes where the nominal model came from."""
    cell, obs, _, _, cal = positioner_noiseless
    by_model = copy.deepcopy(cell)
    by_model["robot"]["model"] = by_model["robot"].pop("kinematics")
    mine = calibrate(by_model, obs)
    assert np.array_equal(mine.kinematics["robot"]["params"], cal.kinematics["robot"]["params"])
    for name, T in cal.transforms.items():
        assert np.array_equal(mine.transforms[name], T)
    notes = result_file(mine, CalibrationOptions(), "0" * 16).stats["notes"]
    assert notes == [("nominal kinematics: the robot's model preset positioner_2axis (the cell has no kinematics:; "
                      "write kinematics: <preset or table> to use another)")]
    assert "notes" not in result_file(cal, CalibrationOptions(), "0" * 16).stats
