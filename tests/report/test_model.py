"""The report's linear model is the solve's: its covariance, its information, the calibration restored from
a result file, and the predicted effect of a hypothetical station against a re-solve with that station."""

import numpy as np
import pytest

import jcalib
from jcalib.report.candidates import candidates, station_information, what_would_help
from jcalib.report.model import calibration_of, linear_model, model_from_file, options_of

CASES = ["camera_case", "handeye_case", "cell_case", "two_robot_case"]


def _model(case):
    _, _, result = case
    return linear_model(result.details, options_of(result.file))


def _reported(file, u_block: str, coords: list[str]) -> np.ndarray:
    """The result file's covariance of ``coords`` of one block (a camera, transform or point)."""
    if u_block in file.cameras:
        cam = file.cameras[u_block]
        pos = [cam.param_names.index(c) for c in coords]
        return np.asarray(cam.covariance)[np.ix_(pos, pos)]
    if u_block.startswith("point "):
        pos = ["xyz".index(c) for c in coords]
        return np.asarray(file.points[u_block[6:]].covariance)[np.ix_(pos, pos)]
    pos = [("rx", "ry", "rz", "tx", "ty", "tz").index(c) for c in coords]
    return np.asarray(file.transforms[u_block].covariance)[np.ix_(pos, pos)]


@pytest.mark.parametrize("case", CASES)
def test_covariance_is_the_solves(case, request):
    """Every block of the model's covariance equals what the solve reported in the result file (per variable,
    through the assembler: another code path of the Solution, with the tool frames' convention applied),
    the cross terms equal the file's joint covariance, and the information inverts to the covariance."""
    _, _, result = request.getfixturevalue(case)
    model = _model(request.getfixturevalue(case))
    C = model.covariance()
    blocks = dict.fromkeys(u.block for u in model.unknowns)
    assert len(blocks) >= 1 and model.calibration is result.details
    for b in blocks:
        idx = [i for i, u in enumerate(model.unknowns) if u.block == b]
        ref = _reported(result.file, b, [model.unknowns[i].coord for i in idx])
        # the same float64 numbers of one solve, read two ways: equal to rounding
        np.testing.assert_allclose(C[np.ix_(idx, idx)], ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    joint = model_from_file(result.file)
    keys = [u.key for u in model.unknowns]
    common = [k for k in (u.key for u in joint.unknowns) if k in keys]
    a = [keys.index(k) for k in common]
    b = [[u.key for u in joint.unknowns].index(k) for k in common]
    ref = joint.covariance()[np.ix_(b, b)]
    np.testing.assert_allclose(C[np.ix_(a, a)], ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    # information (Schur complement of the solve's system, marginalised on the host) against the covariance
    # (the solve's compiled inverse): one matrix, inverted two ways; σ-scaled to compare mixed units
    d = np.sqrt(np.diag(C))
    err = (np.linalg.inv(model.information) - C) / np.outer(d, d)
    assert np.max(np.abs(err)) < 1e-7, np.max(np.abs(err))


@pytest.mark.parametrize("case", ["camera_case", "cell_case", "two_robot_case"])
def test_restored_from_the_file_is_the_same_solve(case, request, tmp_path):
    """From result.json + observations + cell (the ``jcalib report`` path): the problem rebuilt by the one
    builder and re-solved from the file's values gives the in-memory model to the solver's tolerance."""
    cell, obs, result = request.getfixturevalue(case)
    path = result.to_json(tmp_path / "result.json")
    cal = calibration_of(path, obs, cell)
    assert cal is not result.details and cal.solution is not None
    model, ref = linear_model(cal, options_of(result.file)), _model(request.getfixturevalue(case))
    assert [u.key for u in model.unknowns] == [u.key for u in ref.unknowns]
    # the estimate moves by the convergence tolerance only (the file is at the optimum)
    np.testing.assert_allclose(model.sigma(), ref.sigma(), rtol=1e-6)
    d = np.sqrt(np.diag(ref.covariance()))
    assert np.max(np.abs((model.covariance() - ref.covariance()) / np.outer(d, d))) < 1e-6
    assert calibration_of(path) is None  # without observations and cell there is no solve


PREDICTED = {
    "camera_case": ["cam0/board tilt_y"],
    "handeye_case": ["cam0/board rot_x"],
    "cell_case": ["cam0/board rot_y", "cam1/needle tip_x"],
}


@pytest.mark.parametrize("case", list(PREDICTED))
def test_predicted_stations_match_a_re_solve(case, request, cases):
    """Adding the candidate stations (observations exactly on the estimate's predictions) and calibrating
    again gives the covariance the prediction said. Stated noise: no variance factor moves; the new
    stations add zero residual, so the optimum stays and only the information grows (additively: two
    stations predicted as the sum of their information)."""
    cell, obs, result = request.getfixturevalue(case)
    options = dict(result.file.provenance.options)
    given = {k: options[k] for k in ("noise", "sigma_px", "tip_sigma_px") if k in options and (
        k != "tip_sigma_px" or "tools" in cell)}
    # the robot error model as the cell states it (no error_model: auto, which re-estimates the pose model's
    # level from the data each time: the added stations would move it): the prediction is about information
    if "robot" in cell or "robots" in cell:
        given["prediction"] = False
    result = jcalib.calibrate(cell, obs, given)
    model = _model((cell, obs, result))
    by_key = {c.key: c for c in candidates(model)}
    added = np.zeros_like(model.information)
    for key in PREDICTED[case]:
        added = added + station_information(model, by_key[key])
        obs = cases.with_station(obs, by_key[key].station)
    after = jcalib.calibrate(cell, obs, given)
    resolved = linear_model(after.details)
    assert [u.key for u in resolved.unknowns] == [u.key for u in model.unknowns]
    predicted = model.sigma(added)
    np.testing.assert_allclose(predicted, resolved.sigma(), rtol=1e-4)
    assert np.all(predicted <= model.sigma() * (1 + 1e-9))  # information only adds
    assert np.min(predicted / model.sigma()) < 0.95  # and it does add


def test_candidates_for_every_pair_of_a_two_robot_cell(two_robot_case):
    """Two robots, a fixed camera, a flange camera, a board on each side and a torch: candidates for every
    moving pair (robot r1 moves cam0 over the world board, r2 presents board2 to cam1, both robots for
    cam0/board2) and for the torch tip; each adds positive semi-definite information, and the torch's own
    stations are what helps its TCP most."""
    model = _model(two_robot_case)
    cands = candidates(model)
    pairs = {c.pair for c in cands}
    assert {("cam0", "board"), ("cam1", "board2"), ("cam0", "board2"), ("cam1", "torch")} <= pairs
    for c in cands:
        A = station_information(model, c)
        w = np.linalg.eigvalsh(A)
        assert w.min() > -1e-9 * w.max(), (c.key, w.min(), w.max())
        assert np.all(model.sigma(A) <= model.sigma() * (1 + 1e-9))
    label = "T_flange_torch translation y"
    best = what_would_help(model, [label])[0]
    assert "torch" in best.kind and best.gain(label) > 1.02, best


def test_held_aspect_ratio_ties_fy_to_fx(camera_case, cases):
    """``fix: [aspect]``: fy is no unknown of the model, and the camera's covariance the report propagates
    (projection maps, predicted stations) ties fy to fx exactly as the result file does."""
    cell, obs, _ = camera_case
    cell = {**cell, "cameras": {"cam0": {"model": "opencv5", "fix": ["aspect"]}}}
    result = jcalib.calibrate(cell, obs, cases.STATED)
    model = linear_model(result.details, options_of(result.file))
    assert "cam0 fy" not in model.labels and "cam0 fx" in model.labels
    ref = result.file.cameras["cam0"].covariance
    np.testing.assert_allclose(model.camera_covariance("cam0"), ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    from_file = model_from_file(result.file)  # the file's joint covariance: fy dropped as tied, not inverted
    assert "cam0 fy" not in from_file.labels
    np.testing.assert_allclose(from_file.sigma(), model.sigma(), rtol=1e-9)


def test_restored_scara_keeps_the_prior_on_the_unobservable_translation(tmp_path, cases):
    """One-axis (SCARA) motion with ``fix_unobservable``: the result file records the prior along the axis
    and the restored problem holds it again (else it would not be observable); a re-optimised result,
    whose priors the file does not hold, is refused."""
    from jcalib.errors import BadInputError
    from jcalib.io.result import ResultFile

    cell, obs = cases.scara_handeye()
    options = {**cases.STATED, "fix_unobservable": True, "unobservable_prior_m": 0.08}
    result = jcalib.calibrate(cell, obs, options)
    assert result.file.stats["unobservable_fixed"]["transform"] == "T_flange_cam0"
    path = result.to_json(tmp_path / "result.json")
    model = linear_model(calibration_of(path, obs, cell), options_of(result.file))
    np.testing.assert_allclose(model.sigma(), linear_model(result.details).sigma(), rtol=1e-6)
    f = result.file
    refit = ResultFile(cameras=f.cameras, transforms=f.transforms, stats={**f.stats, "priors": ["T_flange_cam0"]},
                       provenance=f.provenance)
    with pytest.raises(BadInputError, match="re-optimised"):
        calibration_of(refit, obs, cell)
