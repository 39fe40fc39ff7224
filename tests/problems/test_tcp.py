"""Joint TCP from fixed cameras (jcalib.problems.tcp): recovery, covariance by Monte Carlo, degeneracies.

Two problem structures are compiled (one camera with the robot pose model; two cameras with the tool
axis), every other test reuses them or fails before the solve, so the file stays fast.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.cameras import Pinhole
from jcalib.init.tcp_analytic import tcp_from_camera_ray, viewing_ray_base
from jcalib.problems.tcp import calibrate_tcp

X_TRUE = np.array([0.015, -0.01, 0.16])  # tip in the flange, m
N_POSES = 12
SIGMA_T = 2e-5  # robot position noise per axis, m
SIGMA_R_DEG = 0.002  # robot orientation noise per axis
SIGMA_PX = 0.3


def _rotvec(w) -> np.ndarray:
    w = np.asarray(w, float)
    th = np.linalg.norm(w)
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * K @ K


def _camera() -> Pinhole:
    return Pinhole((1280, 1024), focal=(2400.0, 2410.0), principal_point=(641.0, 509.5))


def _T_base_cam(yaw_deg: float = 0.0) -> np.ndarray:
    """A camera looking horizontally along base +x (rotated by yaw about base z), 0.4 m from the tip."""
    T = np.eye(4)
    Rz = _rotvec([0.0, 0.0, np.deg2rad(yaw_deg)])
    T[:3, :3] = Rz @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]) @ _rotvec([0.02, -0.03, 0.01])
    T[:3, 3] = np.array([0.6, 0.0, 0.3]) - 0.4 * T[:3, 2]
    return T


P_TIP = np.array([0.6, 0.0, 0.3])  # where the tip is presented, base frame
R0 = np.diag([1.0, -1.0, -1.0]) @ _rotvec(np.deg2rad([4.0, -3.0, 25.0]))  # tool points down


def _poses(rng, n=N_POSES, angle=np.pi / 8, axes=None, shift_m=0.01):
    """Commanded flange poses: rotations about the nominal tip (axes in the base frame) plus shifts."""
    x_nom = X_TRUE + np.array([0.002, -0.0015, 0.001])
    out = []
    for k in range(n):
        if axes is None:
            phi = k * np.pi / 6.0
            a = np.array([np.cos(np.pi / 4) * (1.0 if k % 2 else -1.0), np.cos(phi) * 0.7, np.sin(phi) * 0.7])
        else:
            a = np.asarray(axes[k % len(axes)], float)
        R = _rotvec(a / np.linalg.norm(a) * angle * (1.0 if k % 3 else -1.0)) @ R0
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = P_TIP + rng.uniform(-shift_m, shift_m, 3) - R @ x_nom
        out.append(T)
    return np.stack(out)


def _project(cam, T_base_cam, p_base):
    pc = (p_base - T_base_cam[:3, 3]) @ T_base_cam[:3, :3]
    return np.array(cam.project(pc))


def _observe(cam, T_base_cam, T_true, rng=None, sigma_px=0.0):
    tips = np.einsum("nab,b->na", T_true[:, :3, :3], X_TRUE) + T_true[:, :3, 3]
    px = _project(cam, T_base_cam, tips)
    if rng is not None and sigma_px > 0:
        px = px + rng.normal(0.0, sigma_px, px.shape)
    return px


def _solve_a(cam, T_cam, T_meas, px, **kw):
    """Structure A: one camera, robot pose model on (one compiled solver for all its uses)."""
    return calibrate_tcp(cam, T_cam, T_meas, px, pose_noise_translation_m=SIGMA_T,
                         pose_noise_rotation_deg=SIGMA_R_DEG, sigma_px=SIGMA_PX, **kw)


# ------------------------------------------------------------------------------------ recovery


def test_noise_free_recovery_fixed_and_free_camera():
    rng = np.random.default_rng(1)
    cam, Tc = _camera(), _T_base_cam()
    T = _poses(rng)
    px = _observe(cam, Tc, T)
    assert np.all((px > 0) & (px < [1279, 1023]))
    # 1e-9 m: noiseless data, the LM reaches the exact solution to float64 round-off (~1e-15 m)
    res = _solve_a(cam, Tc, T, px)
    np.testing.assert_allclose(res.p_flange_tip, X_TRUE, atol=1e-9)
    assert res.p_flange_tip.dtype == np.float64
    assert res.rms_px < 1e-6
    # the camera pose started 3 deg / 30 mm off, estimated with the TCP
    Tc0 = Tc.copy()
    Tc0[:3, :3] = _rotvec([0.03, -0.04, 0.02]) @ Tc0[:3, :3]
    Tc0[:3, 3] += [0.03, -0.02, 0.01]
    res = _solve_a(cam, Tc0, T, px, free_camera_pose=True)
    np.testing.assert_allclose(res.p_flange_tip, X_TRUE, atol=1e-9)
    np.testing.assert_allclose(res.T_base_cam[0], Tc, atol=1e-8)  # 1e-8: pose entries, 10 nm / 1e-8 rad
    assert res.status == "converged"


def test_start_equals_camera_ray_lsq_on_servoed_data():
    """Tip held on one pixel (the thesis' servo): the linear start equals tcp_from_camera_ray."""
    rng = np.random.default_rng(2)
    cam, Tc = _camera(), _T_base_cam()
    T = _poses(rng)
    target = np.array([641.0, 509.5])
    # servo: translate every pose so that the tip lies on the ray of `target`, at its own depth
    d = viewing_ray_base(cam, target, Tc[:3, :3])
    tips = np.einsum("nab,b->na", T[:, :3, :3], X_TRUE) + T[:, :3, 3]
    on_ray = Tc[:3, 3] + np.outer((tips - Tc[:3, 3]) @ d, d)
    T[:, :3, 3] += on_ray - tips
    px = np.tile(target, (N_POSES, 1))
    ref = tcp_from_camera_ray(T, d)  # the analytic least-squares variant (4.17-4.18)
    res = _solve_a(cam, Tc, T, px, free_camera_pose=True)
    # 1e-9 m: both solve the same linear least squares exactly (noiseless data: both equal the truth)
    np.testing.assert_allclose(res.p_flange_tip_init, ref.p_flange_tip, atol=1e-9)
    np.testing.assert_allclose(res.p_flange_tip, X_TRUE, atol=1e-9)


def test_two_cameras_with_tool_axis():
    """Structure B: two cameras, imaged tool axis lines; tip and axis recovered exactly."""
    rng = np.random.default_rng(3)
    cams = [_camera(), Pinhole((1024, 1024), focal=(2000.0, 2000.0), principal_point=(511.5, 511.5))]
    Tcs = np.stack([_T_base_cam(0.0), _T_base_cam(70.0)])
    a_true = np.array([0.05, -0.08, 1.0])
    a_true /= np.linalg.norm(a_true)
    T = _poses(rng)
    tips = np.einsum("nab,b->na", T[:, :3, :3], X_TRUE) + T[:, :3, 3]
    px = np.stack([_observe(c, Tc, T) for c, Tc in zip(cams, Tcs)], axis=1)
    px[3, 1] = np.nan  # camera 1 misses the tip at pose 3
    # axis points: projections of points 5..40 mm up the tool from the tip (towards the flange)
    s = np.array([-0.005, -0.015, -0.04])
    axis_base = np.einsum("nab,b->na", T[:, :3, :3], a_true)
    lines = np.stack(
        [np.stack([_project(c, Tc, tips + si * axis_base) for si in s], axis=1) for c, Tc in zip(cams, Tcs)],
        axis=1,
    )  # (N, C, L, 2)
    lines[5, 0, 1] = np.nan
    res = calibrate_tcp(cams, Tcs, T, px, axis_lines=lines, camera_names=["left", "right"])
    np.testing.assert_allclose(res.p_flange_tip, X_TRUE, atol=1e-9)
    # the start axis points from the flange to the tip: a_true points away from the flange here
    sign = np.sign(res.axis_flange @ a_true)
    np.testing.assert_allclose(sign * res.axis_flange, a_true, atol=1e-9)
    np.testing.assert_allclose(res.T_flange_tcp[:3, 2], res.axis_flange, atol=1e-15)
    assert np.isnan(res.residuals_px[3, 1]).all() and np.isfinite(res.residuals_px[3, 0]).all()
    assert np.isnan(res.axis_residuals_px[5, 0, 1])
    assert np.nanmax(np.abs(res.axis_residuals_px)) < 1e-6
    assert res.camera_names == ["left", "right"]
    # the axis covariance has rank 2 (the unit vector's length is not a degree of freedom)
    assert abs(res.axis_flange @ res.axis_covariance @ res.axis_flange) < 1e-12 * np.trace(res.axis_covariance) + 1e-30


# ------------------------------------------------------------------------------------ covariance


def test_monte_carlo_covariance_matches_spread():
    """50 noisy trials: errors normalised by the reported (stated-noise) covariance follow chi2(3)."""
    rng = np.random.default_rng(4)
    cam, Tc = _camera(), _T_base_cam()
    T_cmd = _poses(np.random.default_rng(5))
    trials = 50
    nees, errs, covs = [], [], []
    for _ in range(trials):
        T_true = T_cmd.copy()
        for i in range(N_POSES):
            T_true[i, :3, :3] = T_cmd[i, :3, :3] @ _rotvec(rng.normal(0.0, np.deg2rad(SIGMA_R_DEG), 3))
            T_true[i, :3, 3] += T_cmd[i, :3, :3] @ rng.normal(0.0, SIGMA_T, 3)
        px = _observe(cam, Tc, T_true, rng, SIGMA_PX)
        res = _solve_a(cam, Tc, T_cmd, px, free_camera_pose=True, noise="stated")
        e = res.p_flange_tip - X_TRUE
        nees.append(e @ np.linalg.solve(res.tip_covariance, e))
        errs.append(e)
        covs.append(res.tip_covariance)
    total = float(np.sum(nees))
    dof = 3 * trials
    # loose two-sided chi2(150) bounds at 1e-3 (fixed seed; fails only for a wrong covariance)
    assert stats.chi2.ppf(1e-3, dof) < total < stats.chi2.ppf(1 - 1e-3, dof), total / trials
    # per axis: empirical variance vs mean reported variance (50 samples: s.e. of a variance ~20 %)
    ratio = np.var(np.stack(errs), axis=0) / np.mean(np.diagonal(np.stack(covs), axis1=1, axis2=2), axis=0)
    assert np.all((ratio > 0.45) & (ratio < 2.0)), ratio


# ------------------------------------------------------------------------------------ degenerate data


def test_rotations_about_one_axis_name_the_offset_along_it():
    rng = np.random.default_rng(6)
    cam, Tc = _camera(), _T_base_cam()
    axis_base = np.array([0.3, 0.2, 1.0])
    T = _poses(rng, axes=[axis_base])
    px = _observe(cam, Tc, T)
    with pytest.raises(NotObservableError) as err:
        calibrate_tcp(cam, Tc, T, px, free_camera_pose=True)
    msg = str(err.value)
    assert "T_flange_tcp offset along the rotation axis" in msg  # the unknown by its transform name
    assert any("rotation axis" in u for u in err.value.unknowns)
    # the named direction is the common rotation axis in the flange frame
    a_flange = R0.T @ (axis_base / np.linalg.norm(axis_base))
    named = np.array([float(v) for v in msg.split("rotation axis [")[1].split("]")[0].split(",")])
    assert abs(abs(named @ a_flange) - 1.0) < 1e-3  # printed to 4 decimals


def test_too_few_poses():
    rng = np.random.default_rng(7)
    cam, Tc = _camera(), _T_base_cam()
    T = _poses(rng, n=2)
    with pytest.raises(NotObservableError, match=r"detected at 2 pose\(s\); at least 3") as err:
        calibrate_tcp(cam, Tc, T, _observe(cam, Tc, T))
    assert "too few poses" in err.value.unknowns[0]
    # three poses, but the tip detected in only two of them
    T = _poses(rng, n=3)
    px = _observe(cam, Tc, T)
    px[1] = np.nan
    with pytest.raises(NotObservableError, match="detected at 2 pose"):
        calibrate_tcp(cam, Tc, T, px)


def test_tip_seen_along_one_ray_leaves_depth_free():
    """Known camera, flange only translated along the viewing ray: the depth of the tip is free."""
    cam, Tc = _camera(), _T_base_cam()
    d = Tc[:3, 2]
    T = np.stack([np.eye(4)] * 4)
    T[:, :3, :3] = R0
    T[:, :3, 3] = P_TIP - R0 @ X_TRUE + np.outer([0.0, 0.01, -0.02, 0.03], d)
    px = _observe(cam, Tc, T)
    with pytest.raises(NotObservableError, match="viewing ray") as err:
        calibrate_tcp(cam, Tc, T, px)
    assert "fewer than 2 distinct views" in err.value.unknowns[0]


def test_pure_translations_with_free_camera():
    cam, Tc = _camera(), _T_base_cam()
    T = np.stack([np.eye(4)] * 5)
    T[:, :3, :3] = R0
    T[:, :3, 3] = P_TIP - R0 @ X_TRUE + np.random.default_rng(8).uniform(-0.01, 0.01, (5, 3))
    with pytest.raises(NotObservableError, match="does not rotate"):
        calibrate_tcp(cam, Tc, T, _observe(cam, Tc, T), free_camera_pose=True)


def test_prior_covariance_inf_means_no_prior(monkeypatch):
    """``intrinsics_covariance``: the finite block becomes the prior's square-root information, an
    ``inf`` variance no prior on that coordinate, a zero variance holds it; a covariance that is not
    positive definite is refused by name. (Checked on what the preset hands the builder.)"""
    import jcalib.problems.tcp as tcp

    seen = {}

    def capture(cell, obs, options, *, priors, known):
        seen.update(cell=cell, priors=priors)
        raise RuntimeError("captured")

    monkeypatch.setattr(tcp, "calibrate_cell", capture)
    rng = np.random.default_rng(10)
    cam, Tc = _camera(), _T_base_cam()
    T = _poses(rng)
    px = _observe(cam, Tc, T)
    A = rng.normal(size=(3, 3))
    B = A @ A.T + 0.1 * np.eye(3)
    C = np.zeros((4, 4))  # fx, fy, cx, cy
    C[:3, :3] = B
    C[3, 3] = np.inf
    with pytest.raises(RuntimeError, match="captured"):
        calibrate_tcp(cam, Tc, T, px, free_intrinsics=True, intrinsics_covariance=[C])
    mean, S = seen["priors"]["cam0"]
    np.testing.assert_array_equal(mean, np.asarray(cam.params))
    # S^T S is the inverse of the finite block (1e-9: float64 inverse of a well-conditioned 3x3)
    np.testing.assert_allclose((S.T @ S)[:3, :3], np.linalg.inv(B), rtol=1e-9, atol=1e-9)
    assert not S[3:].any() and not S[:, 3:].any()
    assert seen["cell"].cameras["cam0"].fix == ()  # nothing held: cy is free, without a prior
    C[1, :] = C[:, 1] = 0.0  # a zero variance holds fy
    with pytest.raises(RuntimeError, match="captured"):
        calibrate_tcp(cam, Tc, T, px, free_intrinsics=True, intrinsics_covariance=[C])
    assert seen["cell"].cameras["cam0"].fix == ("fy",)
    with pytest.raises(BadInputError, match="positive-definite"):
        calibrate_tcp(cam, Tc, T, px, free_intrinsics=True, intrinsics_covariance=[-np.eye(4)])


def test_bad_input_is_named():
    rng = np.random.default_rng(9)
    cam, Tc = _camera(), _T_base_cam()
    T = _poses(rng)
    px = _observe(cam, Tc, T)
    with pytest.raises(BadInputError, match="tip_pixels"):
        calibrate_tcp(cam, Tc, T, px[:, :1])
    with pytest.raises(BadInputError, match="T_base_cam"):
        calibrate_tcp(cam, np.stack([Tc, Tc]), T, px)
    with pytest.raises(BadInputError, match="free_intrinsics"):
        calibrate_tcp(cam, Tc, T, px, free_intrinsics=("fx", "k9"))
    with pytest.raises(BadInputError, match="cameras"):
        calibrate_tcp("cam", Tc, T, px)
    behind = Tc.copy()
    behind[:3, :3] = behind[:3, :3] @ np.diag([-1.0, 1.0, -1.0])  # camera turned around
    with pytest.raises(BadInputError, match="behind camera"):
        calibrate_tcp(cam, behind, T, px)
