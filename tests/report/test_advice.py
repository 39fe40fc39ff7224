"""What the report tells the user: each piece against an independent reference (OpenCV, closed forms, the
solve's own propagation, an injected fault)."""

import re

import cv2
import equinox as eqx
import jax
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import jcalib
from jcalib.geometry import camera_from_opencv
from jcalib.io.result import CameraResult, TransformResult
from jcalib.problems import taskspace
from jcalib.report import advice, diagnostics, render_report
from jcalib.report.candidates import candidates, station_information
from jcalib.report.crossval import cross_validate
from jcalib.report.model import LinearModel, correlations, linear_model, options_of, transform_unknown
from jcalib.sim.scene import random_calibration_views


@given(st.lists(st.floats(-0.95, 0.95), min_size=3, max_size=3), st.lists(st.floats(0.1, 10), min_size=3, max_size=3))
def test_correlations_recover_a_constructed_matrix(rho_upper, sigmas):
    """C = D R D with a known correlation matrix R (made positive definite): correlations() gives R back."""
    R = np.eye(3)
    R[0, 1] = R[1, 0] = rho_upper[0]
    R[0, 2] = R[2, 0] = rho_upper[1]
    R[1, 2] = R[2, 1] = rho_upper[2]
    w, V = np.linalg.eigh(R)
    R = V @ np.diag(np.maximum(w, 0.05)) @ V.T
    R = R / np.sqrt(np.outer(np.diag(R), np.diag(R)))
    D = np.diag(sigmas)
    rho, pairs = correlations(D @ R @ D, ["a", "b", "c"], minimum=0.0)
    np.testing.assert_allclose(rho, R, atol=1e-9)  # float64 identity
    expected = sorted((abs(R[i, j]) for i, j in ((0, 1), (0, 2), (1, 2))), reverse=True)
    np.testing.assert_allclose([abs(p[2]) for p in pairs], expected, atol=1e-9)


def test_weak_directions_and_transform_sigma_closed_form():
    """A hand-made 2-unknown model: translation z (σ 3 mm) correlated 0.8 with rotation x (σ 0.1°)."""
    s_t, s_r, rho = 3e-3, np.radians(0.1), 0.8
    C = np.array([[s_r**2, rho * s_r * s_t], [rho * s_r * s_t, s_t**2]])
    unknowns = (transform_unknown("T_flange_cam0", "rx"), transform_unknown("T_flange_cam0", "tz"))
    m = LinearModel("hand-made", "hand-eye", unknowns, np.linalg.inv(C), C)
    np.testing.assert_allclose(m.sigma(), [0.1, 3.0], rtol=1e-9)
    # scaled by tolerances 0.05 deg / 0.5 mm: [[4, 0.8*2*6], [.., 36]]
    S = np.array([[4.0, 0.8 * 2 * 6], [0.8 * 2 * 6, 36.0]])
    lam, vec = np.linalg.eigh(S)
    weak = advice.weak_directions(m, 2)
    np.testing.assert_allclose([w.ratio for w in weak], np.sqrt(lam[::-1]), rtol=1e-9)
    assert weak[0].components[0][0] == "T_flange_cam0 translation z"
    assert abs(weak[0].components[0][1]) == pytest.approx(abs(vec[1, 1]), rel=1e-9)
    full = np.zeros((6, 6))
    full[np.ix_([0, 5], [0, 5])] = C
    ts = taskspace.transform_sigma(TransformResult(np.eye(4), full))
    np.testing.assert_allclose(ts["rotation_deg"], [0.1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(ts["translation_mm"], [0, 0, 3.0], rtol=1e-9)


def test_radial_structure_detects_unmodelled_distortion(cases):
    """Residuals of a too-simple model (an unmodelled r^5 term) are flagged; pure noise is not."""
    rng = np.random.default_rng(3)
    pix = rng.uniform([0, 0], cases.SIZE, size=(2000, 2))
    centre = np.array([640.0, 480.0])
    d = pix - centre
    r = np.linalg.norm(d, axis=-1)
    noise = 0.2 * rng.standard_normal(pix.shape)
    trend = (0.6 * (r / r.max()) ** 4 - 0.3 * (r / r.max()) ** 2)[:, None] * d / r[:, None]
    hit = diagnostics.radial_structure(pix, noise + trend, centre, 0.2)
    assert hit.flagged and hit.p_value < 1e-10 and 0.2 < hit.amplitude_px < 0.5
    false = [diagnostics.radial_structure(pix, 0.2 * rng.standard_normal(pix.shape), centre, 0.2).flagged
             for _ in range(20)]
    assert not any(false)  # p < 1e-4 per trial: 20 clean trials all pass (chance of a false flag 2e-3)


def test_projection_difference_against_opencv(cases):
    """Halves differing by a principal-point shift: without the rotation fit the difference equals
    OpenCV's undistort (A) + project (B) of each pixel; a small shift is nearly a rotation, so the
    fitted difference is far smaller."""
    a = CameraResult.from_model(cases.CAMERA)
    K_b = cases.K_TRUE.copy()
    K_b[0, 2] += 2.0
    b = CameraResult.from_model(camera_from_opencv(K_b, cases.DIST_TRUE, cases.SIZE))
    u, v, diff = taskspace.projection_difference(a, b, grid=(9, 7), fit_rotation=False)
    pix = np.stack([u.ravel(), v.ravel()], -1)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    xy = cv2.undistortPointsIter(pix[:, None, :], a.K, a.dist, None, None, crit)[:, 0, :]
    ref, _ = cv2.projectPoints(np.c_[xy, np.ones(len(xy))], np.zeros(3), np.zeros(3), b.K, b.dist)
    np.testing.assert_allclose(diff.ravel(), np.linalg.norm(ref[:, 0] - pix, axis=-1), atol=1e-6)
    fitted = taskspace.projection_difference(a, b, grid=(9, 7))[2]
    assert np.nanmax(fitted) < 0.25 * np.nanmax(diff)


def test_projection_sigma_matches_opencv_jacobian(camera_case):
    """σ map against an independent J C Jᵀ: OpenCV's analytic projectPoints Jacobian w.r.t.
    (fx, fy, cx, cy, k1, k2, p1, p2, k3) at rays found by OpenCV's undistortPoints."""
    cam = camera_case[2].file.cameras["cam0"]
    u, v, sigma = taskspace.projection_sigma_map(cam, grid=(9, 7))
    pix = np.stack([u.ravel(), v.ravel()], axis=-1)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    xy = cv2.undistortPointsIter(pix[:, None, :], cam.K, cam.dist, None, None, crit)[:, 0, :]
    p = np.concatenate([xy, np.ones((len(xy), 1))], axis=-1)
    proj, jac = cv2.projectPoints(p[:, None, :], np.zeros(3), np.zeros(3), cam.K, cam.dist)
    np.testing.assert_allclose(proj[:, 0, :], pix, atol=1e-6)  # the rays are right
    J = jac[:, 6:].reshape(len(p), 2, 9)
    cov = np.einsum("nip,pq,njq->nij", J, cam.covariance, J)
    ref = np.sqrt(np.linalg.eigvalsh(cov)[:, -1])
    # same linearisation, float64 both: agreement far below any displayed digit
    np.testing.assert_allclose(sigma.ravel(), ref, rtol=1e-6)
    # at the principal point only cx, cy move the projection: σ = sqrt(λ_max(C[cx, cy]))
    pp = taskspace.projection_sigma_at(cam, np.array([[cam.K[0, 2], cam.K[1, 2]]]), cam.covariance)
    np.testing.assert_allclose(pp, np.sqrt(np.linalg.eigvalsh(cam.covariance[2:4, 2:4])[-1]), rtol=1e-9)


class _Projection(eqx.Module):
    """``values -> (n, 2)`` pixels of fixed rays with the solve's intrinsics (for Solution.propagate)."""

    rays: jax.Array
    model_cls: type = eqx.field(static=True)
    size: tuple = eqx.field(static=True)

    def __call__(self, values):
        return self.model_cls.from_params(self.size, values["intrinsics:cam0"][0]).project(self.rays)


def test_projection_sigma_is_the_solves_propagation(camera_case):
    """The task-space σ at grid pixels equals the solve's own propagation (Solution.propagate: the Jacobian
    of the projection w.r.t. every unknown through the solve's block inverse)."""
    cal = camera_case[2].details
    model = linear_model(cal, options_of(camera_case[2].file))
    cam = cal.cameras["cam0"]
    pix = np.array([[0.0, 0.0], [640.0, 480.0], [1279.0, 700.0], [300.0, 900.0]])
    rays, _ = taskspace.unproject(cam, pix)
    fn = _Projection(np.asarray(rays), type(cam), tuple(cam.image_size))
    Sigma = cal.solution.propagate(fn, noise=cal.covariance_noise).reshape(4, 2, 4, 2)
    blocks = Sigma[np.arange(4), :, np.arange(4), :]
    ref = np.sqrt(np.linalg.eigvalsh(blocks)[:, -1])
    mine = taskspace.projection_sigma_at(cam, pix, model.camera_covariance("cam0"))
    np.testing.assert_allclose(mine, ref, rtol=1e-7)


def test_residual_diagnostics_are_the_solves_and_name_an_injected_outlier(camera_case, cases):
    """A corner pushed 5 px off: the solve rejects it and the diagnostics name it; the per-view RMS equals
    OpenCV's reprojection with the solve's view poses."""
    cell, obs, _ = camera_case
    bad = {**obs, "stations": [dict(s) for s in obs["stations"]]}
    det = dict(bad["stations"][3]["detections"][0])
    pix = np.array(det["pixels"])
    pix[17] += [4.0, -3.0]  # 5 px off
    det["pixels"] = pix.tolist()
    bad["stations"][3]["detections"] = [det]
    result = jcalib.calibrate(cell, bad, cases.STATED)
    d = diagnostics.residual_diagnostics(result.details)["cam0"]
    assert [(s, i) for s, i, _ in d.outliers] == [("s03", 17)]
    cam = result.file.cameras["cam0"]
    T = result.details.T_cam_target["s03"]["cam0"]
    proj, _ = cv2.projectPoints(cases.BOARD.points, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], cam.K, cam.dist)
    r = np.delete(pix - proj[:, 0], 17, axis=0)  # the rejected corner is not in the view's RMS
    np.testing.assert_allclose(d.view_rms_px["s03"], np.sqrt(np.mean(np.sum(r**2, axis=-1))), rtol=1e-7)
    assert abs(d.outliers[0][2] - 5.0) < 0.5 and not d.radial.flagged  # the right lens model: no radial trend
    warnings = advice.analysis_warnings(result.file, None, {"cam0": d})
    assert any("1 corner(s) rejected" in w.message and "station s03 corner 17" in w.message for w in warnings)


def test_cross_validation_halves(cases):
    """Two halves (even / odd stations) of a camera calibration: the difference is of the size the halves'
    σ predict (not orders of magnitude off; the best-fit rotation absorbs part of the difference that the
    expected value, from the halves' σ, still has)."""
    rng = np.random.default_rng(11)
    obs = cases.camera_observations(random_calibration_views(cases.CAMERA, cases.BOARD.points, 8, rng=rng), rng)
    cv = cross_validate(cases.CAMERA_CELL, obs, cases.STATED, grid=(9, 7))
    assert cv.stations == ([f"s{i:02d}" for i in (0, 2, 4, 6)], [f"s{i:02d}" for i in (1, 3, 5, 7)])
    _u, _v, diff, expected = cv.maps["cam0"]
    assert diff.shape == expected.shape == (7, 9)
    ratio = np.nanmedian(diff) / np.nanmedian(expected)
    assert 0.1 < ratio < 3.0, ratio
    assert cv.comparisons["cam0"].verdict == "consistent", cv.comparisons["cam0"].message  # the right lens model


def test_fronto_parallel_views_first_warning_names_focal_and_tilt(cases):
    """All views within 4° of fronto-parallel (a nominal K in the cell starts the solve): the first
    warning names the focal length and a tilted view, and that station's predicted σ is smaller."""
    rng = np.random.default_rng(11)
    obs = cases.camera_observations(random_calibration_views(cases.CAMERA, cases.BOARD.points, 8, rng=rng,
                                                             max_tilt_deg=4.0), rng)
    cell = {**cases.CAMERA_CELL, "cameras": {"cam0": {"model": "opencv5", "intrinsics": {
        "K": (cases.K_TRUE * [[1.03, 1, 1], [1, 1.03, 1], [1, 1, 1]]).tolist(), "dist": [0, 0, 0, 0, 0]}}}}
    result = jcalib.calibrate(cell, obs)
    model = linear_model(result.details, options_of(result.file))
    warnings = advice.analysis_warnings(result.file, model, diagnostics.residual_diagnostics(result.details))
    first = warnings[0]
    assert first.unknown in ("cam0 fx", "cam0 fy") and first.fix in ("cam0/board tilt_x", "cam0/board tilt_y"), first
    assert first.message.startswith(first.unknown) and "tilted 40° about the camera" in first.message
    i = model.labels.index(first.unknown)
    cand = {c.key: c for c in candidates(model)}[first.fix]
    assert model.sigma(station_information(model, cand))[i] < 0.2 * model.sigma()[i]


def test_weak_handeye_first_warning_names_translation_and_a_tilting_station(handeye_case):
    """Stations rotating about the optical axis only: the hand-eye translation along it is the weakest
    unknown, the first warning says so and names a station rotated about camera X or Y, which helps
    far more than one more rotation about Z; the page shows the same warning first."""
    _, obs, result = handeye_case
    model = linear_model(result.details, options_of(result.file))
    warnings = advice.analysis_warnings(result.file, model, diagnostics.residual_diagnostics(result.details))
    first = warnings[0]
    assert first.unknown == "T_flange_cam0 translation z", [w.message for w in warnings[:3]]
    assert first.fix in ("cam0/board rot_x", "cam0/board rot_y")
    assert first.message.startswith("T_flange_cam0 translation z is weakly determined")
    assert "about the camera X axis" in first.message or "about the camera Y axis" in first.message
    i = model.index("T_flange_cam0", "tz")
    by_key = {c.key: c for c in candidates(model)}
    after = {k: model.sigma(station_information(model, by_key[f"cam0/board {k}"]))[i] for k in ("rot_x", "rot_y", "rot_z")}
    assert max(after["rot_x"], after["rot_y"]) < 0.5 * after["rot_z"], after
    html = render_report(result, obs)
    assert html.index("<ol><li>T_flange_cam0 translation z is weakly determined") > 0


def test_stated_once_says_a_shared_hint_once_and_a_lone_one_in_its_line():
    """Two warnings share a hint, one has its own: the shared hint leaves their lines and comes back once
    (with how many warnings it covers); the lone one ends its warning's line."""
    ws = [advice.Warning(3.0, "a is weak", hint="do X"), advice.Warning(2.0, "b is weak.", hint="do X"),
          advice.Warning(1.5, "c: 2 outliers", hint="check the detections"), advice.Warning(1.0, "d")]
    lines, hints = advice.stated_once(ws)
    assert lines == ["a is weak", "b is weak.", "c: 2 outliers: check the detections.", "d"]
    assert hints == ["Do X (said once for the 2 warnings above that it applies to)."]


def test_weak_cell_report_states_the_repeated_hint_once(handeye_case):
    """The weak hand-eye cell: from its result file alone, several weak unknowns, the hint on what to give the
    report said once; with the solve (in-memory result), each weak unknown names its own station instead."""
    _, obs, result = handeye_case
    alone = render_report(result.file, cross_validation=False)
    box = alone[alone.index('id="warnings"'):alone.index("<h2>Summary</h2>")]
    assert box.count("is weakly determined") >= 2
    hint = advice.NO_SOLVE_HINT[1:60]  # the hint after the list starts with a capital
    assert box.count(hint) == 1 and box.index(hint) > box.index("</ol>")
    full = render_report(result, obs, cross_validation=False)
    box = full[full.index('id="warnings"'):full.index("<h2>Summary</h2>")]
    weak = [li for li in re.findall(r"<li>(.*?)</li>", box) if "is weakly determined" in li]
    assert weak and all(". Add " in li for li in weak) and hint not in full


def test_goals_are_the_tolerances_of_what_they_name():
    """A transform σ of 0.3 deg / 3 mm per axis: over the default tolerances; a goal of 1 deg on its rotation
    silences the rotation warnings (the translation ones stay), a goal of 0.01 mm names itself as the limit."""
    from jcalib.io.goals import parse_goals
    from jcalib.io.result import ResultFile

    cov = np.diag([np.radians(0.3) ** 2] * 3 + [3e-3**2] * 3)
    file = ResultFile(cameras={}, transforms={"T_flange_cam0": TransformResult(np.eye(4), cov)}, stats={})

    def weak(goals):
        tol = advice.goal_tolerances(parse_goals(goals)) if goals else None
        return [w for w in advice.analysis_warnings(file, None, None, tol) if w.unknown]

    assert len(weak([])) == 6 and all("(tolerance " in w.message for w in weak([]))
    assert {w.unknown for w in weak(["T_flange_cam0:rotation_deg<=1"])} == {
        f"T_flange_cam0 translation {a}" for a in "xyz"}
    tight = weak(["T_flange_cam0:rotation_deg<=1", "T_flange_cam0:translation_mm<=0.01"])
    assert len(tight) == 3 and all("(goal 0.01 mm)" in w.message for w in tight)
    assert advice.goal_tolerances(parse_goals(["divot:position_mm<=0.2", "cam0:projection_px<=0.3"])) == {
        "point divot.translation_mm": 0.2, "cam0.projection_px": 0.3}


def test_added_station_with_a_conventional_direction_closed_form():
    """A tool's rotation (rx, ry free, rz held by convention in the solve's frame) seen in another frame Q: the
    information is singular along Q's third axis. One more station's information A = Q diag(p, q, r) Qᵀ gives
    Q diag(1 / (1/a + p), 1 / (1/b + q), 0) Qᵀ, with r = 0 (as a board view adds nothing to a tool) or not (the
    held direction stays held): not the garbage of inverting a singular information."""
    a, b, p, q = 4e-6, 9e-6, 2e5, 5e4
    from jcalib.geometry.se3 import exp_so3

    Q = exp_so3(np.array([0.3, -0.5, 0.8]))
    unknowns = tuple(transform_unknown("T_flange_torch", c) for c in ("rx", "ry", "rz"))
    m = LinearModel("hand-made", "cell", unknowns, Q @ np.diag([1 / a, 1 / b, 0.0]) @ Q.T,
                    Q @ np.diag([a, b, 0.0]) @ Q.T)
    want = Q @ np.diag([1 / (1 / a + p), 1 / (1 / b + q), 0.0]) @ Q.T
    for r in (0.0, 3e5):
        got = m.covariance(Q @ np.diag([p, q, r]) @ Q.T)
        np.testing.assert_allclose(got, want, atol=1e-9 * a)  # float64 identity, relative to the largest variance
    assert np.all(np.isfinite(m.sigma(np.zeros((3, 3))))) and np.allclose(m.sigma(np.zeros((3, 3))), m.sigma())
