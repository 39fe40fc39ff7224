"""Pose-pair hand-eye (AX = YB per station, no pixels): OpenCV, ground truth, Monte Carlo, real data."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import lie
from jcalib.io.importers.opencv_pairs import read_calibrated_transform, read_transform_pairs
from jcalib.problems.handeye_pairs import calibrate_hand_eye_pairs

N_STATIONS = 12
SIGMA_ROT_DEG = 0.05
SIGMA_T_M = 0.0005


def pose(R, t):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def inv(T):
    return np.linalg.inv(T)


def random_pose(rng, scale_m):
    return pose(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-scale_m, scale_m, 3))


def camera_views(rng, n):
    """(n, 4, 4) T_target_cam: 0.35-0.7 m from the target, looking near its origin, tilted
    up to 40 deg, rolled up to 60 deg about the optical axis (rotations about 3 axes)."""
    views = []
    for _ in range(n):
        d = Rotation.from_euler("xy", rng.uniform(-40.0, 40.0, 2), degrees=True).apply([0.0, 0.0, -1.0])
        look = np.array([*rng.uniform(-0.05, 0.05, 2), 0.0])
        centre = look + rng.uniform(0.35, 0.7) * d
        z = look - centre
        z /= np.linalg.norm(z)
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z]) @ Rotation.from_euler(
            "z", rng.uniform(-60.0, 60.0), degrees=True
        ).as_matrix()
        views.append(pose(R, centre))
    return np.array(views)


def make_scene(rng, mode, n=N_STATIONS):
    """Ground truth (X, Y) and exact station poses (T_base_flange, T_cam_target)."""
    T_target_cam = camera_views(rng, n)
    T_cam_target = inv(T_target_cam)
    if mode == "eye_in_hand":
        X = random_pose(rng, 0.1)  # T_flange_cam
        Y = pose(Rotation.from_euler("x", 180.0, degrees=True).as_matrix(), [0.8, 0.1, 0.0])  # T_base_target
        T_base_flange = Y @ T_target_cam @ inv(X)
    else:
        X = pose(Rotation.from_euler("zx", [90.0, -120.0], degrees=True).as_matrix(), [1.2, 0.3, 0.9])  # T_base_cam
        Y = random_pose(rng, 0.1)  # T_flange_target
        T_base_flange = X @ T_cam_target @ inv(Y)
    return X, Y, T_base_flange, T_cam_target


def perturb(rng, T_cam_target, sigma_rot_deg, sigma_t_m):
    """Measured camera poses ``T_true · Exp(ε)``, ε ~ N(0, diag(σ_rot² I, σ_t² I)) in the target frame."""
    eps = np.concatenate(
        [rng.normal(0.0, np.radians(sigma_rot_deg), (len(T_cam_target), 3)),
         rng.normal(0.0, sigma_t_m, (len(T_cam_target), 3))], axis=1)  # fmt: skip
    noisy = lie.retract(lie.se3_from_matrix(T_cam_target), eps)
    return np.array(lie.se3_to_matrix(noisy))


def tangent_error(T_est, T_true):
    """Right-perturbation error ``Log(T_true⁻¹ T_est)`` (rad, m), the covariance's tangent."""
    return np.asarray(lie.local(lie.se3_from_matrix(T_true), lie.se3_from_matrix(T_est)))


def opencv_hand_eye(T_base_flange, T_cam_target, mode):
    Hg = T_base_flange if mode == "eye_in_hand" else inv(T_base_flange)
    R, t = cv2.calibrateHandEye(
        list(Hg[:, :3, :3]), list(Hg[:, :3, 3]), list(T_cam_target[:, :3, :3]), list(T_cam_target[:, :3, 3]),
        method=cv2.CALIB_HAND_EYE_PARK,
    )
    return pose(R, t.ravel())


def opencv_robot_world(T_base_flange, T_cam_target, mode):
    """Y from cv2.calibrateRobotWorldHandEye (Shah): world = target, gripper = flange."""
    B = inv(T_base_flange) if mode == "eye_in_hand" else T_base_flange
    R_w, t_w, R_g, t_g = cv2.calibrateRobotWorldHandEye(
        list(T_cam_target[:, :3, :3]), list(T_cam_target[:, :3, 3]), list(B[:, :3, :3]), list(B[:, :3, 3]),
        method=cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH,
    )
    return inv(pose(R_g, t_g.ravel())), inv(pose(R_w, t_w.ravel()))  # (X, Y)


# --------------------------------------------------------------------------------------------- OpenCV


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_noise_free_agrees_with_opencv(mode):
    """Started far from the answer (5 deg, 3 cm off), the LM lands on OpenCV's closed forms to 1e-9."""
    rng = np.random.default_rng(1)
    X, Y, T_bf, T_ct = make_scene(rng, mode)
    off = lie.se3_exp(np.array([0.05, -0.04, 0.06, 0.03, -0.02, 0.01]))
    X0 = X @ np.asarray(lie.se3_to_matrix(off))
    Y0 = Y @ np.asarray(lie.se3_to_matrix(off))
    res = calibrate_hand_eye_pairs(T_bf, T_ct, mode=mode, init=(X0, Y0))
    X_cv = opencv_hand_eye(T_bf, T_ct, mode)
    X_rw, Y_rw = opencv_robot_world(T_bf, T_ct, mode)
    # float64 identities: both exact up to rounding of 12 stations' compositions
    assert np.abs(tangent_error(res.T_hand_eye, X_cv)).max() < 1e-9
    assert np.abs(tangent_error(res.T_hand_eye, X_rw)).max() < 1e-9
    assert np.abs(tangent_error(res.T_other, Y_rw)).max() < 1e-9
    assert np.abs(tangent_error(res.T_hand_eye, X)).max() < 1e-9
    assert res.T_hand_eye.dtype == np.float64 and res.T_hand_eye_covariance.shape == (6, 6)
    assert res.hand_eye_name == ("T_flange_cam" if mode == "eye_in_hand" else "T_base_cam")
    assert res.other_name == ("T_base_target" if mode == "eye_in_hand" else "T_flange_target")
    assert any("fit exactly" in w for w in res.warnings)


# --------------------------------------------------------------------------------------------- noise


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_noisy_estimate_within_a_few_sigma(mode):
    rng = np.random.default_rng(7)
    X, Y, T_bf, T_ct = make_scene(rng, mode)
    res = calibrate_hand_eye_pairs(T_bf, perturb(rng, T_ct, SIGMA_ROT_DEG, SIGMA_T_M), mode=mode)
    bound = chi2.ppf(0.999, 6)  # one trial: Mahalanobis distance of a 6-d Gaussian error
    for T_est, T_true, C in ((res.T_hand_eye, X, res.T_hand_eye_covariance), (res.T_other, Y, res.T_other_covariance)):
        e = tangent_error(T_est, T_true)
        assert e @ np.linalg.solve(C, e) < bound
    # 12 stations, ~30 degrees of freedom per variance component: the estimate is within ~40 %
    assert 0.6 < res.noise.rotation_deg / SIGMA_ROT_DEG < 1.4
    assert 0.6 < res.noise.translation_m / SIGMA_T_M < 1.4
    assert res.noise.source == "estimated" and res.noise.converged
    assert abs(res.noise.redundancy_rotation + res.noise.redundancy_translation - (6 * N_STATIONS - 12)) < 1e-6
    # each kind's factor is χ²_k / (r_k - 2) (Student's t variance): the residuals' χ² per redundancy
    # of the whole solve is then (r - 4) / r, r = 6 N - 12, at the converged components
    r = 6 * N_STATIONS - 12
    assert abs(res.sigma2 - (r - 4) / r) < 1e-4
    assert res.station_residuals.shape == (N_STATIONS, 6) and res.station_chi2.shape == (N_STATIONS,)


@pytest.mark.slow(reason="a Monte Carlo study (16 s): ./scripts/test -m slow, and benchmarks/bench_handeye_pairs.py")
def test_monte_carlo_nees_is_chi2_6():
    """50 trials of fresh noise: NEES of X and Y (a-posteriori covariance) against chi2(6)."""
    rng = np.random.default_rng(2024)
    mode = "eye_in_hand"
    X, Y, T_bf, T_ct = make_scene(rng, mode)
    trials = 50
    nees_X, nees_Y, err_X, std_X, sig = [], [], [], [], []
    nees_stated = []
    for _ in range(trials):
        noisy = perturb(rng, T_ct, SIGMA_ROT_DEG, SIGMA_T_M)
        res = calibrate_hand_eye_pairs(T_bf, noisy, mode=mode)
        eX = tangent_error(res.T_hand_eye, X)
        eY = tangent_error(res.T_other, Y)
        nees_X.append(eX @ np.linalg.solve(res.T_hand_eye_covariance, eX))
        nees_Y.append(eY @ np.linalg.solve(res.T_other_covariance, eY))
        err_X.append(eX)
        std_X.append(res.T_hand_eye_std)
        sig.append([res.noise.rotation_deg, res.noise.translation_m])
        if len(nees_stated) < 10:
            st = calibrate_hand_eye_pairs(T_bf, noisy, mode=mode, noise="stated",
                                          rotation_sigma_deg=SIGMA_ROT_DEG, translation_sigma_m=SIGMA_T_M)  # fmt: skip
            eS = tangent_error(st.T_hand_eye, X)
            nees_stated.append(eS @ np.linalg.solve(st.T_hand_eye_covariance, eS))
    # sum of 50 chi2(6) is chi2(300): two-sided 99.9 % bounds on the mean, widened by 10 % on the
    # upper side for the estimated noise (a t-like tail, ~30 dof per variance component)
    lo, hi = chi2.ppf(0.0005, 6 * trials) / trials, chi2.ppf(0.9995, 6 * trials) / trials
    assert lo < np.mean(nees_X) < 1.1 * hi, np.mean(nees_X)
    assert lo < np.mean(nees_Y) < 1.1 * hi, np.mean(nees_Y)
    lo10, hi10 = chi2.ppf(0.0005, 60) / 10, chi2.ppf(0.9995, 60) / 10
    assert lo10 < np.mean(nees_stated) < hi10, np.mean(nees_stated)
    # per axis: Monte-Carlo spread over mean reported sigma (loose: 50 samples, ~±20 % at 2 sigma)
    ratio = np.std(np.array(err_X), axis=0) / np.mean(np.array(std_X), axis=0)
    assert np.all((ratio > 0.65) & (ratio < 1.45)), ratio
    # the pose-noise estimate is unbiased to a few percent over 50 trials
    mean_sig = np.mean(np.array(sig), axis=0)
    assert abs(mean_sig[0] / SIGMA_ROT_DEG - 1.0) < 0.08, mean_sig
    assert abs(mean_sig[1] / SIGMA_T_M - 1.0) < 0.08, mean_sig


def test_stated_noise_that_is_wrong_is_reported():
    rng = np.random.default_rng(3)
    _, _, T_bf, T_ct = make_scene(rng, "eye_in_hand")
    noisy = perturb(rng, T_ct, SIGMA_ROT_DEG, SIGMA_T_M)
    res = calibrate_hand_eye_pairs(T_bf, noisy, noise="stated", rotation_sigma_deg=SIGMA_ROT_DEG / 10,
                                   translation_sigma_m=SIGMA_T_M / 10)  # fmt: skip
    assert res.noise.source == "stated" and res.noise.rotation_deg == SIGMA_ROT_DEG / 10
    assert any("contradict the stated noise" in w for w in res.warnings)
    # the variance components still see the true noise level
    assert 0.6 < res.estimated_noise.rotation_deg / SIGMA_ROT_DEG < 1.4


def test_outlier_station_is_flagged():
    rng = np.random.default_rng(5)
    _, _, T_bf, T_ct = make_scene(rng, "eye_in_hand")
    noisy = perturb(rng, T_ct, SIGMA_ROT_DEG, SIGMA_T_M)
    noisy[4, :3, 3] += [0.02, 0.0, 0.0]  # 2 cm detection error at station 4
    res = calibrate_hand_eye_pairs(T_bf, noisy)
    assert 4 in res.outlier_stations
    assert any("stations [4]" in w for w in res.warnings)


def _traced(monkeypatch):
    """Count the traces of the one compiled solve (its Python body runs once per trace, not per call)."""
    from jcalib.solve import core

    traces = []
    original = core.lm_solve
    monkeypatch.setattr(core, "lm_solve", lambda *a, **k: traces.append(1) or original(*a, **k))
    return traces


def test_new_data_of_the_same_mode_reuses_the_compiled_solver(monkeypatch):
    """Same station count, other data: the solve is not traced again (one compilation)."""
    rng = np.random.default_rng(21)
    _, _, T_bf, T_ct = make_scene(rng, "eye_in_hand")
    calibrate_hand_eye_pairs(T_bf, perturb(rng, T_ct, SIGMA_ROT_DEG, SIGMA_T_M))  # compiled here or before
    traces = _traced(monkeypatch)
    _, _, T_bf, T_ct = make_scene(rng, "eye_in_hand")
    calibrate_hand_eye_pairs(T_bf, perturb(rng, T_ct, SIGMA_ROT_DEG, SIGMA_T_M))
    assert traces == []


def test_each_mode_compiles_once(monkeypatch):
    """Eye-in-hand and eye-to-hand are two residual functions (the flange pose enters the chain inverted
    or not; the pose-pair family shared one by inverting the constant poses on the host): after one call
    of each, new data of either mode traces nothing."""
    rng = np.random.default_rng(22)
    for mode in ("eye_in_hand", "eye_to_hand"):  # compiled here or before
        _, _, T_bf, T_ct = make_scene(rng, mode)
        calibrate_hand_eye_pairs(T_bf, perturb(rng, T_ct, SIGMA_ROT_DEG, SIGMA_T_M), mode=mode)
    traces = _traced(monkeypatch)
    for mode in ("eye_to_hand", "eye_in_hand"):
        _, _, T_bf, T_ct = make_scene(rng, mode)
        calibrate_hand_eye_pairs(T_bf, perturb(rng, T_ct, SIGMA_ROT_DEG, SIGMA_T_M), mode=mode)
    assert traces == []


# --------------------------------------------------------------------------------------------- degenerate


def test_one_axis_rotation_is_not_observable():
    rng = np.random.default_rng(11)
    X = random_pose(rng, 0.1)
    Y = pose(np.eye(3), [0.8, 0.0, 0.0])
    T_bf = np.array([pose(Rotation.from_euler("z", a, degrees=True).as_matrix(), [0.5, 0.1 * a / 90, 0.6])
                     for a in (-60, -20, 10, 40, 80)])  # fmt: skip
    T_ct = inv(X) @ inv(T_bf) @ Y
    with pytest.raises(NotObservableError) as err:
        calibrate_hand_eye_pairs(T_bf, T_ct)
    assert any("common rotation axis" in u for u in err.value.unknowns)


def test_pure_translation_and_too_few_stations():
    T_bf = np.array([pose(np.eye(3), [0.5 + 0.1 * k, 0.0, 0.6]) for k in range(5)])
    T_ct = np.array([pose(np.eye(3), [0.0, 0.0, 0.5 - 0.1 * k]) for k in range(5)])
    with pytest.raises(NotObservableError):
        calibrate_hand_eye_pairs(T_bf, T_ct)
    with pytest.raises(NotObservableError):
        calibrate_hand_eye_pairs(T_bf[:2], T_ct[:2])


def test_rotations_too_small_for_the_estimated_noise():
    """Rotations of ~0.3 deg pass the default check, but not against the ~1 deg noise in the data."""
    rng = np.random.default_rng(9)
    X, Y, _, _ = make_scene(rng, "eye_in_hand")
    views = [pose(Rotation.from_rotvec(rng.normal(0.0, np.radians(0.3), 3)).as_matrix(), [0.0, 0.0, -0.5])
             for _ in range(N_STATIONS)]  # fmt: skip
    T_bf = Y @ np.array(views) @ inv(X)
    noisy = perturb(rng, inv(np.array(views)), 1.0, 0.001)
    with pytest.raises(NotObservableError):
        calibrate_hand_eye_pairs(T_bf, noisy)


def test_bad_input():
    rng = np.random.default_rng(0)
    _, _, T_bf, T_ct = make_scene(rng, "eye_in_hand", n=5)
    with pytest.raises(BadInputError, match="mode"):
        calibrate_hand_eye_pairs(T_bf, T_ct, mode="hand_in_eye")
    with pytest.raises(BadInputError, match="rotation_sigma_deg"):
        calibrate_hand_eye_pairs(T_bf, T_ct, noise="stated")
    with pytest.raises(BadInputError, match="T_cam_target"):
        calibrate_hand_eye_pairs(T_bf, T_ct[:4])
    with pytest.raises(BadInputError, match="init_method"):
        calibrate_hand_eye_pairs(T_bf, T_ct, init_method="magic")
    with pytest.raises(BadInputError, match="translation_sigma_m"):
        calibrate_hand_eye_pairs(T_bf, T_ct, translation_sigma_m=-1.0)


# --------------------------------------------------------------------------------------------- real data


def test_real_camodocal_end_to_end(real_data):
    """jhu-lcsr/handeye_calib_camodocal: AR marker on the gripper, camera fixed (eye-to-hand), 42 pairs."""
    folder = real_data / "handeye_camodocal_example"
    T1, T2 = read_transform_pairs(folder / "TransformPairsInput.yml")
    ref = read_calibrated_transform(folder / "CalibratedTransform.yml")
    res = calibrate_hand_eye_pairs(T1, T2, mode="eye_to_hand")
    assert res.num_stations == 42 and res.status == "CONVERGED"
    # degrees and millimetres of noise (README: "the data is noisy")
    assert 0.5 < res.noise.rotation_deg < 10.0 and 0.0005 < res.noise.translation_m < 0.02
    # large but finite uncertainty of the marker in the end-effector frame (Y)
    std = res.T_other_std
    assert np.all(np.isfinite(std)) and np.all(std[3:] < 0.01) and np.all(std[:3] < np.radians(2.0))
    # the published answer (a different estimator: AX = XB relative to station 0) is within 3 cm
    assert np.linalg.norm(res.T_other[:3, 3] - ref[:3, 3]) < 0.03
    # the estimate explains the station loops better than the published answer does (for each Y,
    # X = chordal mean of the per-station T_base_cam it implies)
    def loop_rms_m(Y):
        Xs = T1 @ Y @ inv(T2)
        u, _, vt = np.linalg.svd(Xs[:, :3, :3].mean(axis=0))
        X = pose(u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt, Xs[:, :3, 3].mean(axis=0))
        E = inv(Y) @ inv(T1) @ X @ T2
        return float(np.sqrt(np.mean(np.sum(E[:, :3, 3] ** 2, axis=1))))

    assert loop_rms_m(res.T_other) < loop_rms_m(ref)
    assert 36 in res.outlier_stations  # one grossly inconsistent pair (chi2 ~ 160)
