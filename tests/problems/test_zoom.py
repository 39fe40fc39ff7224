"""Zoom lenses: the lens functions' basis and fit, the residual's linearisation, the joint calibration over
several zoom settings (recovery in units of σ at a held-out setting), the refusals, ``camera_at`` and
``export --at``. One small cell (5 settings x 4 stations) is solved once per session."""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.stats import chi2

import jcalib
import jcalib.geometry.conversions
import jcalib.geometry.lie
from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.cameras import OpenCV5, zoom
from jcalib.geometry.conversions import matrix_to_pose
from jcalib.geometry.lie import se3_log
from jcalib.problems.lens import file_at, parse_at
from jcalib.residuals.reprojection import zoom_reprojection
from jcalib.sim.zoom import heldout_projection_rms_px, mount_at, synthetic_zoom_cell

SETTINGS = (100, 250, 400, 550, 700)
HELD_OUT = 475.0


@pytest.fixture(scope="module")
def zoom_cell():
    # the lens stops within ~0.2 steps of each commanded setting; stations record what it reads back
    cell, obs, truth = synthetic_zoom_cell(3, settings=SETTINGS, num_stations=4, jitter=0.2)
    return cell, obs, truth, jcalib.calibrate(cell, obs)


@given(st.integers(1, 4), st.integers(0, 3), st.lists(st.floats(-0.2, 1.2), min_size=1, max_size=8))
def test_basis_is_a_partition_of_unity(degree, knots, u):
    B = zoom.basis(u, degree, knots)
    assert B.shape == (len(u), zoom.num_control_points(degree, knots))
    np.testing.assert_allclose(B.sum(axis=1), 1.0, atol=1e-12)  # float64 identity (also extrapolated)
    inside = (np.asarray(u) >= 0) & (np.asarray(u) <= 1)
    assert np.all(B[inside] >= -1e-15)


def test_read_back_jitter_groups_into_one_setting():
    from jcalib.problems.lens import setting_groups

    groups = setting_groups([99.8, 100.1, 100.2, 399.9, 400.3, 700.0])
    assert sorted(set(groups.values())) == pytest.approx([100.03333333333333, 400.1, 700.0])
    assert setting_groups([349.9, 350.1]) == {349.9: 350.0, 350.1: 350.0}


def test_fit_reproduces_functions_in_the_family():
    u = np.linspace(0.0, 1.0, 7)
    params = np.stack([np.exp(6.9 + 1.8 * u - 0.1 * u ** 2), np.exp(6.9 + 1.8 * u), 640 + 5 * u ** 3, 480 - 2 * u,
                       -0.2 + 0.3 * u], axis=1)
    shifts = 0.02 * u * (1.3 - 0.3 * u)
    ctrl = zoom.fit_control_points(u, params, shifts)
    p, d = zoom.lens_at(jnp.asarray(np.exp(ctrl[0, :5]) * [1, 1, 0, 0, 0] + ctrl[0, :5] * [0, 0, 1, 1, 1]),
                        jnp.asarray(ctrl[1:].ravel()), jnp.asarray(zoom.basis([0.37])[0]))
    t = 0.37
    np.testing.assert_allclose(np.asarray(p), [np.exp(6.9 + 1.8 * t - 0.1 * t * t), np.exp(6.9 + 1.8 * t),
                                               640 + 5 * t ** 3, 480 - 2 * t, -0.2 + 0.3 * t], rtol=1e-9)
    assert float(d) == pytest.approx(0.02 * t * (1.3 - 0.3 * t), abs=1e-12)


def test_zoom_residual_jacobian_matches_autodiff():
    chain = ((0, True), (1, True), (2, False))  # T_flange_cam⁻¹ · T_base_flange⁻¹ · T_base_board · p
    fn, jac = zoom_reprojection(OpenCV5, (1280, 960), False, chain)
    rng = np.random.default_rng(0)
    intr = jnp.asarray([1000.0, 1001.0, 640.0, 480.0, -0.2, 0.05, 1e-4, -1e-4, 0.0])
    lens = jnp.asarray(rng.normal(scale=0.05, size=30))
    poses = [jnp.asarray(np.concatenate([q / np.linalg.norm(q), t])) for q, t in
             ((np.array([1.0, 0.05, -0.02, 0.1]), [0.05, -0.03, 0.09]),
              (np.array([0.0, 1.0, 0.1, 0.05]), [0.6, 0.0, 0.4]),
              (np.array([0.0, 1.0, 0.0, 0.0]), [0.6, -0.05, 0.0]))]
    obs = (jnp.asarray([0.05, 0.03, 0.0]), jnp.asarray([600.0, 500.0]), jnp.asarray([0.0, 1.0]),
           jnp.asarray(zoom.basis([0.4])[0]))
    fn, jac = jax.jit(fn), jax.jit(jac)
    r, blocks = jac(intr, *poses, lens, obs)
    np.testing.assert_allclose(np.asarray(r), np.asarray(fn(intr, *poses, lens, obs)), atol=1e-9)

    def moved(args):  # the engine's right perturbation of each pose: A · Exp(δ)
        from jcalib.geometry import lie

        k, d = args
        out = list(poses)
        out[k] = lie.se3_compose(poses[k], lie.se3_exp(d))
        return fn(intr, *out, lens, obs)

    auto_intr = jax.jit(jax.jacfwd(lambda i: fn(i, *poses, lens, obs)))(intr)
    auto_lens = jax.jit(jax.jacfwd(lambda ll: fn(intr, *poses, ll, obs)))(lens)
    np.testing.assert_allclose(np.asarray(blocks[0]), np.asarray(auto_intr), rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(np.asarray(blocks[-1]), np.asarray(auto_lens), rtol=1e-7, atol=1e-7)
    for k in (0,):  # the camera's pose (the chain's blocks are chain_jacobian's, tested with the chain)
        auto = jax.jit(jax.jacfwd(lambda d, k=k: moved((k, d))))(jnp.zeros(6))
        np.testing.assert_allclose(np.asarray(blocks[1 + k]), np.asarray(auto), rtol=1e-6, atol=1e-6)


def test_zoom_cell_recovers_the_lens_and_hand_eye_in_sigma(zoom_cell):
    _, _, truth, result = zoom_cell
    lens = truth["lens"]
    assert set(result.file.extra["lenses"]) == {"cam0"}
    lo, hi = result.file.extra["lenses"]["cam0"]["range"]
    assert abs(lo - SETTINGS[0]) < 1 and abs(hi - SETTINGS[-1]) < 1  # the recorded (read-back) extremes
    for value in (lo, HELD_OUT, hi):
        cam, T = result.camera_at("cam0", Zoom=value)
        err = cam.params - lens.params(value)
        free = np.diag(cam.covariance) > 0
        d2 = err[free] @ np.linalg.solve(np.asarray(cam.covariance)[np.ix_(free, free)], err[free])
        assert d2 < chi2.ppf(0.999, free.sum()), (value, err, d2)
        T_true = mount_at(truth["T_flange_cam0_wide"], lens, value)
        delta = np.asarray(se3_log(jnp.asarray(matrix_to_pose(np.linalg.inv(T.matrix) @ T_true))))
        d2 = delta @ np.linalg.solve(T.covariance, delta)
        assert d2 < chi2.ppf(0.999, 6), (value, delta, d2)
        assert heldout_projection_rms_px(lens, value, cam.params) < 1.0


def test_one_setting_only_is_refused_by_name():
    cell, obs, _ = synthetic_zoom_cell(0, settings=(300,), num_stations=4)
    with pytest.raises(NotObservableError) as err:
        jcalib.calibrate(cell, obs)
    assert "lens:cam0" in err.value.unknowns and "Zoom" in str(err.value)


def test_station_without_its_setting_is_named():
    cell, obs, _ = synthetic_zoom_cell(0, settings=(100, 300, 500, 700), num_stations=3)
    obs = copy.deepcopy(obs)
    del obs["stations"][2]["lens"]
    with pytest.raises(BadInputError, match=obs["stations"][2]["id"]):
        jcalib.calibrate(cell, obs)


def test_export_at_a_setting_and_the_range_refusal(zoom_cell, tmp_path):
    result = zoom_cell[3]
    assert parse_at("cam0.Zoom=350") == ("cam0", "Zoom", 350.0)
    with pytest.raises(BadInputError, match="outside the calibrated range"):
        file_at(result.file, "cam0.Zoom=900")
    at = file_at(result.file, "cam0.Zoom=900", extrapolate=True)
    assert at.cameras["cam0"].K[0, 0] > result.file.cameras["cam0"].K[0, 0]
    with pytest.raises(BadInputError, match="CAMERA.SETTING=VALUE"):
        parse_at("cam0=350")
    with pytest.raises(BadInputError, match="depends on Zoom"):
        file_at(result.file, "cam0.Focus=350")
    from jcalib.io.export import export_result

    inside = file_at(result.file, f"cam0.Zoom={HELD_OUT}")
    path = export_result(inside, "opencv", tmp_path / "cam0.yaml", cameras="cam0")
    text = path.read_text()
    fx = inside.cameras["cam0"].K[0, 0]
    assert f"{fx:.3f}"[:6] in text
    # the file at the setting is the result's own camera function there, read back from disk
    result.to_json(tmp_path / "r.json")
    again = file_at(jcalib.io.result.load_result(tmp_path / "r.json"), f"cam0.Zoom={HELD_OUT}")
    np.testing.assert_allclose(again.cameras["cam0"].params, inside.cameras["cam0"].params, rtol=1e-12)
    assert "cam0 at lens setting Zoom=475" in text and "fx=" in text


def test_camera_at_propagates_the_covariance_like_sampling():
    """``LensFunction.at``'s first-order covariances (intrinsics, and the camera frame at the setting, whose
    shift adds to its pose's) against the spread of the same quantities over samples of the unknowns."""
    from jcalib.geometry.se3 import invert, log_se3

    rng = np.random.default_rng(1)
    P, nb = 9, 4
    intr = np.array([1000.0, 1001.0, 640.0, 480.0, -0.2, 0.05, 1e-4, -1e-4, 0.0])
    lens = np.concatenate([np.r_[zoom.to_transformed(jnp.asarray(intr)), 0.0] + k * np.r_[0.6, 0.6, 2, -2, 0.1, -0.02,
                                                                                         0, 0, 0, 0.007]
                           for k in range(1, nb)])
    A = rng.normal(size=(P + lens.size + 6, P + lens.size + 6)) * 1e-4
    cov = A @ A.T
    mount = np.eye(4)
    mount[:3, 3] = [0.05, -0.03, 0.09]
    lf = zoom.LensFunction("Zoom", (100.0, 800.0), 3, 0, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"), intr, lens,
                           cov, mount)
    at = lf.at(430.0)
    b = jnp.asarray(zoom.basis(lf.normalise([430.0]))[0])
    samples = rng.multivariate_normal(np.zeros(cov.shape[0]), cov, size=4000)
    p, d = jax.vmap(lambda x: zoom.lens_at(jnp.asarray(intr) + x[:P], jnp.asarray(lens) + x[P:P + lens.size], b))(
        jnp.asarray(samples))
    shift = np.broadcast_to(np.eye(4), (len(samples), 4, 4)).copy()
    shift[:, 2, 3] = np.asarray(d)
    E = np.asarray(jcalib.geometry.conversions.pose_to_matrix(jcalib.geometry.lie.se3_exp(jnp.asarray(samples[:, -6:]))))
    params, deltas = np.asarray(p), log_se3(invert(at["mount"]) @ mount @ E @ shift)
    for got, want in ((np.cov(np.array(params).T), at["params_covariance"]),
                      (np.cov(np.array(deltas).T), at["mount_covariance"])):
        sd = np.sqrt(np.diag(want))
        # correlation-scale agreement: 4000 samples give ~0.02-0.03 sampling error on each entry / (σ_i σ_j)
        assert np.max(np.abs(got - want) / np.outer(sd, sd)) < 0.12


def test_report_plots_the_lens_functions(zoom_cell):
    from jcalib.report import sections

    html = sections.lenses(zoom_cell[3].file, {"cam0": {"settings": {475.0: {"rms_px": 0.3}}}})
    assert "Zoom lenses" in html and 'alt="lens functions of cam0"' in html


@pytest.mark.slow
def test_heldout_settings_are_predicted_near_the_fit(zoom_cell):
    """The stations at one inner setting left out and predicted from the lens functions: their RMS stays
    near the noise (σ 0.2 px per coordinate, ~0.28 px per point); a wrong shift or interpolation would not."""
    from jcalib.problems.lens_heldout import heldout_settings

    cell, obs, _, _ = zoom_cell
    check = heldout_settings(cell, obs, [400.0])
    assert set(check["settings"]) == {400.0} and check["settings"][400.0]["num_points"] > 100
    assert check["rms_px"] < 2.0 * check["fit_rms_px"]
    from jcalib.problems.lens_heldout import with_heldout
    from jcalib.report import sections

    marked = with_heldout(zoom_cell[3].file, check)
    assert marked.extra["lenses"]["cam0"]["heldout"]["settings"]["400"]["rms_px"] == check["rms_px"]
    assert 'alt="lens functions of cam0"' in sections.lenses(marked)
    with pytest.raises(BadInputError, match="not inside"):
        heldout_settings(cell, obs, [100.0])
