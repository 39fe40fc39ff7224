"""Batched camera calibration (``jcalib.calibrate_batch``, vmapped solves): every member reaches
OpenCV's optimum on identical corners, its standard deviations agree with OpenCV's, sets of
different sizes share one padded shape, and a bad member is reported in its place."""

import numpy as np
import pytest

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.problems import CalibrationOptions, calibrate_cell
from jcalib.problems.batch import calibrate_batch
from jcalib.sim.scene import project_target, random_calibration_views
from jcalib.solve import core, solve_many

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
SIZE = (1280, 960)
CAM = camera_from_opencv(np.array([[1000.0, 0, 650.0], [0, 1000.0, 470.0], [0, 0, 1]]),
                         np.array([-0.25, 0.08, 5e-4, -3e-4, 0.0]), SIZE)
CELL = parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5"}},
                   "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}})


def make_obs(poses, rng, sigma_px, offsets=None):
    """Observations of ``poses`` with noise; ``offsets``: {(view, corner): px added} (outliers)."""
    stations, pixels = [], []
    for i, T in enumerate(poses):
        pix, vis = project_target(CAM, T, BOARD.points)
        assert vis.all()
        pix = pix + sigma_px * rng.standard_normal(pix.shape)
        for (v, c), d in (offsets or {}).items():
            if v == i:
                pix[c] += d
        pixels.append(pix)
        stations.append({"id": f"v{i:03d}", "detections": [{"camera": "cam0", "target": "board",
                         "point_index": list(range(len(BOARD.points))), "pixels": pix.tolist()}]})
    return parse_observations({
        "schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(SIZE)}},
        "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations,
    }), pixels


@pytest.fixture(scope="module")
def batch():
    rng = np.random.default_rng(21)
    sets = []
    for n in (10, 10, 12):  # 12 views pad to another bucket than 10: the batch re-pads to one shape
        poses = random_calibration_views(CAM, BOARD.points, n, rng=rng)
        sets.append(make_obs(poses, rng, sigma_px=0.3))
    fronto = []
    for i in range(6):
        T = np.eye(4)
        T[:3, 3] = [-0.12 + 0.01 * i, -0.08, 0.6 + 0.02 * i]
        fronto.append(T)
    bad, _ = make_obs(fronto, rng, sigma_px=0.1)
    obs = [o for o, _ in sets]
    results = calibrate_batch(CELL, [obs[0], bad, obs[1], obs[2]], CalibrationOptions(outlier_threshold=None),
                              raise_errors=False)
    return sets, results


def _opencv(pixels):
    import cv2

    obj = [BOARD.points.astype(np.float32)] * len(pixels)
    img = [p.astype(np.float32) for p in pixels]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    return cv2.calibrateCameraExtended(obj, img, SIZE, None, None, criteria=crit)


def test_every_member_reaches_opencvs_optimum(batch):
    sets, results = batch
    good = [results[0], results[2], results[3]]
    for (_, pixels), cal in zip(sets, good):
        rms, K, dist, _, _, std, _, _ = _opencv(pixels)
        K_ours, dist_ours = cal.cameras["cam0"].to_opencv()
        # Same optimum: OpenCV works in float32 corners -> agreement limited to ~1e-5 relative.
        np.testing.assert_allclose(K_ours, K, rtol=2e-5, atol=2e-3)
        np.testing.assert_allclose(dist_ours, dist.ravel(), atol=2e-5)
        assert abs(cal.rms_px - rms) < 1e-4
        assert cal.status == "converged"
        # OpenCV 4.14's std: sqrt(diag(JᵀJ)⁻¹ · Σr²/(m − n)), the same first-order covariance with
        # the same a-posteriori σ; only float32 corners and the stopping point differ (1 %).
        ours = np.sqrt(np.diag(cal.intrinsics_covariance["cam0"]))
        names = list(cal.cameras["cam0"].param_names)
        theirs = dict(zip(("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"), std.ravel()[:9]))
        for name in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"):
            np.testing.assert_allclose(ours[names.index(name)], theirs[name], rtol=0.01, err_msg=name)


def test_bad_member_is_reported_in_place(batch):
    _, results = batch
    assert isinstance(results[1], NotObservableError)
    assert "fx" in " ".join(results[1].unknowns)
    assert len(results) == 4


def test_raise_errors_raises_the_members_error(batch):
    sets, _ = batch
    rng = np.random.default_rng(0)
    T = np.eye(4)
    T[:3, 3] = [-0.12, -0.08, 0.6]
    bad, _ = make_obs([T] * 5, rng, sigma_px=0.1)
    with pytest.raises(NotObservableError):
        calibrate_batch(CELL, [sets[0][0], bad], raise_errors=True)


def test_members_equal_calibrate_cell_across_calls_and_refinements(monkeypatch):
    """Calls of 2 members (the last one filled with copies), a member with gross outliers (re-solved
    in the outlier rounds), starts built for the whole batch at once: every member's result is what
    ``calibrate_cell`` gives on its own data set."""
    rng = np.random.default_rng(5)
    obs = []
    for k in range(3):
        poses = random_calibration_views(CAM, BOARD.points, 9, rng=rng)
        # member 1: two corners 40 px off, rejected, then re-solved
        o, _ = make_obs(poses, rng, sigma_px=0.2, offsets={(2, 5): 40.0, (6, 11): -40.0} if k == 1 else None)
        obs.append(o)
    widths = []
    vmapped = core._core_vmap_jit
    from jcalib.problems import refine

    monkeypatch.setattr(core, "batch_width", lambda num: 2)
    monkeypatch.setattr(refine, "batch_width", lambda num: 2)  # the rounds keep the first call's width
    monkeypatch.setattr(core, "_core_vmap_jit", lambda p, *a: widths.append(p.variables[0].value.shape[0])
                        or vmapped(p, *a))
    batch = calibrate_batch(CELL, obs)
    monkeypatch.undo()
    assert widths[:2] == [2, 2]  # the first solve: members 0, 1, then member 2 with a copy
    assert len(batch[1].outliers) == 2
    for o, got in zip(obs, batch):
        want = calibrate_cell(CELL, o)
        assert got.outliers == want.outliers and got.reseeded_views == want.reseeded_views
        assert type(got.cameras["cam0"]) is type(want.cameras["cam0"])
        sigma = np.sqrt(np.diag(want.intrinsics_covariance["cam0"]))
        # same optimum up to the solver's tolerance under padding (< 1e-4 of a standard deviation)
        assert np.all(np.abs(np.asarray(got.cameras["cam0"].params) - np.asarray(want.cameras["cam0"].params))
                      < 1e-4 * sigma)
        # in units of σ_i σ_j (an entry near zero, e.g. a weak correlation of p1 and k3, has no relative scale)
        scale = np.outer(sigma, sigma)
        np.testing.assert_allclose(got.intrinsics_covariance["cam0"] / scale,
                                   want.intrinsics_covariance["cam0"] / scale, rtol=0, atol=1e-5)
        assert got.view_rms_px.keys() == want.view_rms_px.keys()
        np.testing.assert_allclose(list(got.view_rms_px.values()), list(want.view_rms_px.values()), rtol=1e-6)
        assert got.T_cam_target.keys() == want.T_cam_target.keys()
        for sid in want.T_cam_target:
            np.testing.assert_allclose(got.T_cam_target[sid]["cam0"], want.T_cam_target[sid]["cam0"], atol=1e-8)
        assert abs(got.rms_px - want.rms_px) < 1e-9 and got.num_residuals == want.num_residuals


def test_batch_width_must_be_a_positive_integer():
    """The width of a vmapped call (the old ``batch_size``) is the engine's: refused by name."""
    rng = np.random.default_rng(2)
    o, _ = make_obs(random_calibration_views(CAM, BOARD.points, 6, rng=rng), rng, sigma_px=0.2)
    problem = calibrate_cell(CELL, o).built.problem
    with pytest.raises(BadInputError, match="width"):
        solve_many([problem], width=0)
