"""Closed-form hand-eye (AX = XB): against OpenCV, ground truth, degenerate motion and real data."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jcalib.errors import BadInputError, NotObservableError
from jcalib.init.handeye import (
    HAND_EYE_METHODS,
    TSAI_MAX_ANGLE_DEG,
    TSAI_MIN_ANGLE_DEG,
    relative_motions,
    solve_ax_xb,
    solve_hand_eye,
)
from jcalib.init.handeye_motion import analyse_motion

METHODS = list(HAND_EYE_METHODS)
REAL = Path(__file__).resolve().parents[1] / "data" / "real"

# A 9x6 checkerboard (25 mm), target frame at its centre, seen by a 1400 px pinhole camera.
BOARD = np.column_stack(
    [(np.stack(np.meshgrid(np.arange(9), np.arange(6)), -1).reshape(-1, 2) - [4.0, 2.5]) * 0.025, np.zeros(54)]
)
FOCAL_PX = 1400.0


# --------------------------------------------------------------------------------------------- helpers


def pose(R, t):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def inv(T):
    T = np.asarray(T)
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def errors(T_est, T_ref):
    """(rotation angle between the two, rad; translation distance, input unit)."""
    dR = Rotation.from_matrix(T_est[:3, :3].T @ T_ref[:3, :3]).magnitude()
    return float(dR), float(np.linalg.norm(T_est[:3, 3] - T_ref[:3, 3]))


def camera_views(rng, n, tilt_deg=40.0, roll_deg=30.0):
    """(n, 4, 4) T_target_cam: cameras 0.35-0.7 m from the board, looking near its centre."""
    views = []
    for _ in range(n):
        d = Rotation.from_euler("xy", rng.uniform(-tilt_deg, tilt_deg, 2), degrees=True).apply([0.0, 0.0, 1.0])
        look = np.array([*rng.uniform(-0.05, 0.05, 2), 0.0])
        centre = look + rng.uniform(0.35, 0.7) * d
        z = look - centre
        z /= np.linalg.norm(z)
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z]) @ Rotation.from_euler(
            "z", rng.uniform(-roll_deg, roll_deg), degrees=True
        ).as_matrix()
        views.append(pose(R, centre))
    return np.array(views)


def make_scene(rng, n=10, mount="flange", **view_kw):
    """Ground truth and station poses. Returns (T_true, T_other_true, T_base_flange, T_cam_target).

    mount "flange": T_true = T_flange_cam, T_other = T_base_target.
    mount "base":   T_true = T_base_cam,   T_other = T_flange_target.
    """
    X = pose(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.1, 0.1, 3))
    T_cam_target = inv(camera_views(rng, n, **view_kw))
    if mount == "flange":
        R_bt = Rotation.from_euler("z", rng.uniform(-180, 180), degrees=True).as_matrix()
        T_base_target = pose(R_bt, [0.6, 0.1, 0.0])
        T_base_flange = T_base_target @ inv(T_cam_target) @ inv(X)
        return X, T_base_target, T_base_flange, T_cam_target
    T_base_cam = pose(Rotation.random(random_state=rng).as_matrix(), [1.0, 0.2, 0.8])
    T_flange_target = X
    T_base_flange = T_base_cam @ T_cam_target @ inv(T_flange_target)
    return T_base_cam, T_flange_target, T_base_flange, T_cam_target


def perturb_robot(T, rng, sigma_m=1e-4, sigma_deg=0.01):
    """Robot pose noise: a rotation of N(0, sigma_deg^2) per axis and N(0, sigma_m^2) per axis translation."""
    out = T.copy()
    dR = Rotation.from_rotvec(np.radians(sigma_deg) * rng.normal(size=(len(T), 3))).as_matrix()
    out[:, :3, :3] = dR @ T[:, :3, :3]
    out[:, :3, 3] += sigma_m * rng.normal(size=(len(T), 3))
    return out


def perturb_camera(T_cam_target, rng, sigma_px=0.2):
    """Camera pose noise equivalent to sigma_px corner noise: sample the PnP pose covariance.

    Covariance = sigma_px^2 (J^T J)^-1, J = d(pixels)/d(delta) of the 54 board corners for a
    perturbation T' = [Exp(w), v] @ T_cam_target, delta = (w, v) in the camera frame.
    """
    out = T_cam_target.copy()
    for k, T in enumerate(T_cam_target):
        p = BOARD @ T[:3, :3].T + T[:3, 3]
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        du_dp = FOCAL_PX * np.stack(
            [np.stack([1 / z, 0 * z, -x / z**2], -1), np.stack([0 * z, 1 / z, -y / z**2], -1)], 1
        )
        px = np.zeros((len(p), 3, 3))
        px[:, 0, 1], px[:, 0, 2], px[:, 1, 2] = -z, y, -x
        px = px - np.swapaxes(px, 1, 2)  # [p]x
        J = np.einsum("kij,kjl->kil", du_dp, np.concatenate([-px, np.broadcast_to(np.eye(3), px.shape)], -1))
        J = J.reshape(-1, 6)
        delta = np.linalg.cholesky(sigma_px**2 * np.linalg.inv(J.T @ J)) @ rng.normal(size=6)
        out[k] = pose(Rotation.from_rotvec(delta[:3]).as_matrix(), delta[3:]) @ T
    return out


def opencv_hand_eye(T_base_flange, T_cam_target, method, mount="flange"):
    Hg = T_base_flange if mount == "flange" else inv(T_base_flange)
    R, t = cv2.calibrateHandEye(
        list(Hg[:, :3, :3]), list(Hg[:, :3, 3]), list(T_cam_target[:, :3, :3]), list(T_cam_target[:, :3, 3]),
        method=getattr(cv2, HAND_EYE_METHODS[method]),
    )
    return pose(R, t.ravel())


def load_camodocal():
    fs = cv2.FileStorage(str(REAL / "handeye_camodocal_example" / "TransformPairsInput.yml"), cv2.FILE_STORAGE_READ)
    n = int(fs.getNode("frameCount").real())
    T1 = np.array([fs.getNode(f"T1_{i}").mat() for i in range(n)])
    T2 = np.array([fs.getNode(f"T2_{i}").mat() for i in range(n)])
    fs.release()
    fs = cv2.FileStorage(str(REAL / "handeye_camodocal_example" / "CalibratedTransform.yml"), cv2.FILE_STORAGE_READ)
    ref = fs.getNode("ArmTipToMarkerTagTransform").mat()
    fs.release()
    return T1, T2, ref


# --------------------------------------------------------------------------------------------- vs OpenCV / truth


@given(st.integers(0, 2**32 - 1), st.sampled_from(["flange", "base"]))
def test_noise_free_every_method_matches_opencv_and_truth(seed, mount):
    rng = np.random.default_rng(seed)
    T_true, T_other_true, T_bf, T_ct = make_scene(rng, n=int(rng.integers(3, 12)), mount=mount)
    for method in METHODS:
        ref = opencv_hand_eye(T_bf, T_ct, method, mount)
        res = solve_hand_eye(T_bf, T_ct, method=method, mount=mount)
        assert res.T.dtype == np.float64 and res.T.shape == (4, 4)
        # noise-free float64 closed forms: identities hold to ~1e-13; 1e-9 leaves room for conditioning
        for T_a, T_b in [(res.T, ref), (res.T, T_true), (res.T_other, T_other_true)]:
            d_rot, d_t = errors(T_a, T_b)
            assert d_rot < 1e-9 and d_t < 1e-9, (method, mount, d_rot, d_t)


def test_noisy_every_method_matches_opencv():
    # same algorithm, so agreement does not depend on noise: deliberately large noise here
    for seed in range(4):
        rng = np.random.default_rng(seed)
        _, _, T_bf, T_ct = make_scene(rng, n=12)
        T_bf = perturb_robot(T_bf, rng, sigma_m=3e-3, sigma_deg=0.5)
        T_ct = perturb_camera(T_ct, rng, sigma_px=5.0)
        for method in METHODS:
            d_rot, d_t = errors(solve_hand_eye(T_bf, T_ct, method=method).T, opencv_hand_eye(T_bf, T_ct, method))
            assert d_rot < 1e-9 and d_t < 1e-9, (seed, method, d_rot, d_t)


def test_large_rotations_recover_truth():
    # fully random station orientations (relative rotations up to 180 deg): quaternion signs and the
    # Shepperd branches of the rotation-to-quaternion conversion must not matter
    rng = np.random.default_rng(7)
    X = pose(Rotation.random(random_state=rng).as_matrix(), [0.05, -0.02, 0.1])
    T_base_target = pose(np.eye(3), [0.5, 0.0, 0.2])
    T_bf = np.array(
        [pose(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.5, 0.5, 3)) for _ in range(8)]
    )
    T_ct = inv(T_bf @ X) @ T_base_target
    assert analyse_motion(T_bf).angles_deg.max() > 150.0
    for method in METHODS:
        for pairs in ("all", "consecutive"):
            d_rot, d_t = errors(solve_hand_eye(T_bf, T_ct, method=method, pairs=pairs).T, X)
            assert d_rot < 1e-9 and d_t < 1e-9, (method, pairs, d_rot, d_t)


def test_consecutive_pairs_recover_truth_and_use_fewer_motions():
    rng = np.random.default_rng(3)
    X, _, T_bf, T_ct = make_scene(rng, n=9)
    A, B, ij = relative_motions(T_bf, T_ct, pairs="consecutive")
    assert A.shape == B.shape == (8, 4, 4)
    np.testing.assert_array_equal(ij, np.column_stack([np.arange(8), np.arange(1, 9)]))
    assert relative_motions(T_bf, T_ct)[0].shape == (36, 4, 4)  # all pairs i < j
    # each relative motion satisfies A X = X B (independent identity on the ground truth)
    np.testing.assert_allclose(A @ X, X @ B, atol=1e-12)
    for method in METHODS:
        d_rot, d_t = errors(solve_ax_xb(A, B, method), X)
        assert d_rot < 1e-9 and d_t < 1e-9, method


def test_noisy_errors_small_and_comparable_across_methods():
    """15 stations, robot 0.1 mm / 0.01 deg, camera pose noise of 0.2 px corners (see perturb_camera)."""
    rng = np.random.default_rng(2024)
    rot = {m: [] for m in METHODS}
    tra = {m: [] for m in METHODS}
    for _ in range(30):
        X, _, T_bf, T_ct = make_scene(rng, n=15)
        T_bf = perturb_robot(T_bf, rng)
        T_ct = perturb_camera(T_ct, rng)
        for method in METHODS:
            d_rot, d_t = errors(solve_hand_eye(T_bf, T_ct, method=method, rotation_noise_deg=0.02).T, X)
            rot[method].append(np.degrees(d_rot))
            tra[method].append(d_t)
    med_rot = {m: float(np.median(v)) for m, v in rot.items()}
    med_t = {m: float(np.median(v)) for m, v in tra.items()}
    # measured: OpenCV's closed forms reach ~0.03 deg / 0.3-0.5 mm in this setting;
    # bounds at ~3x that, and no method more than 4x worse than the best (fixed seed)
    for m in METHODS:
        assert med_rot[m] < 0.1, (m, med_rot)
        assert med_t[m] < 2e-3, (m, med_t)
    assert max(med_rot.values()) < 4.0 * min(med_rot.values()), med_rot
    assert max(med_t.values()) < 4.0 * min(med_t.values()), med_t


def test_eye_to_hand_recovers_truth_and_is_the_inverted_problem():
    rng = np.random.default_rng(11)
    T_base_cam, T_flange_target, T_bf, T_ct = make_scene(rng, n=8, mount="base")
    for method in METHODS:
        res = solve_hand_eye(T_bf, T_ct, method=method, mount="base")
        assert res.name == "T_base_cam" and res.other_name == "T_flange_target"
        for T_a, T_b in [(res.T, T_base_cam), (res.T_other, T_flange_target)]:
            d_rot, d_t = errors(T_a, T_b)
            assert d_rot < 1e-9 and d_t < 1e-9
        # every station closes the loop: T_base_flange_i T_flange_target = T_base_cam T_cam_target_i
        np.testing.assert_allclose(T_bf @ res.T_other, res.T @ T_ct, atol=1e-9)
        assert res.diagnostics.other_translation_rms < 1e-9


def test_diagnostics_reflect_noise():
    rng = np.random.default_rng(5)
    _, _, T_bf, T_ct = make_scene(rng, n=12)
    clean = solve_hand_eye(T_bf, T_ct)
    assert clean.diagnostics.motion_translation_rms < 1e-12
    assert clean.diagnostics.other_rotation_rms_deg < 1e-10
    noisy = solve_hand_eye(perturb_robot(T_bf, rng, sigma_m=1e-3, sigma_deg=0.1), T_ct)
    assert noisy.diagnostics.other_translation_rms > 1e-4  # mm-level noise shows as mm-level spread
    assert noisy.diagnostics.motion_rotation_rms_deg > 0.01


# --------------------------------------------------------------------------------------------- motion analysis


def test_analyse_motion_matches_independent_relative_rotations():
    rng = np.random.default_rng(8)
    _, _, T_bf, _ = make_scene(rng, n=6)
    mot = analyse_motion(T_bf)
    k = 0
    for i in range(6):
        for j in range(i + 1, 6):
            rv = Rotation.from_matrix(T_bf[j, :3, :3].T @ T_bf[i, :3, :3]).as_rotvec()
            assert abs(mot.angles_deg[k] - np.degrees(np.linalg.norm(rv))) < 1e-9
            assert abs(abs(mot.axes[k] @ rv) / np.linalg.norm(rv) - 1.0) < 1e-12  # parallel (sign-free)
            rb = T_bf[j, :3, :3] @ rv
            assert abs(abs(mot.axes_base[k] @ rb) / np.linalg.norm(rb) - 1.0) < 1e-12
            k += 1
    assert mot.rank >= 2 and mot.num_stations == 6 and not mot.planar
    assert mot.axis_spread_deg > 15.0
    assert mot.warnings == ()


def _one_axis_stations(axis_flange, angles_deg, R0=np.eye(3)):
    """Flange poses that all rotate about one flange-frame axis, with translations of all kinds."""
    rng = np.random.default_rng(0)
    return np.array(
        [pose(R0 @ Rotation.from_rotvec(np.radians(a) * np.asarray(axis_flange)).as_matrix(), rng.uniform(-0.3, 0.3, 3))
         for a in angles_deg]
    )


X_DEFAULT = pose(Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix(), [0.03, -0.05, 0.1])


def _stations_for(T_bf, X=X_DEFAULT):
    T_base_target = pose(np.eye(3), [0.6, 0.0, 0.0])
    return T_bf, inv(T_bf @ X) @ T_base_target


def test_one_axis_rotation_names_axis_and_translation():
    R0 = Rotation.from_euler("xyz", [30, -50, 20], degrees=True).as_matrix()  # axis not the base z
    T_bf, T_ct = _stations_for(_one_axis_stations([1.0, 0.0, 0.0], [0, 20, -35, 50, 70, -10], R0))
    for method in METHODS:
        with pytest.raises(NotObservableError) as exc:
            solve_hand_eye(T_bf, T_ct, method=method)
        err = exc.value
        assert "parallel" in str(err) and "planar" not in str(err)
        where = "the common rotation axis (axis = [1, 0, 0] in the flange frame)"
        assert f"translation of T_flange_cam along {where}" in err.unknowns
        assert f"rotation of T_flange_cam about {where}" in err.unknowns
        assert err.exit_code == 3
    mot = analyse_motion(T_bf)
    assert mot.rank == 1 and mot.axis_spread_deg < 1e-6


def test_planar_scara_motion():
    # SCARA: flange z points down (R0 = Rx(180)), every rotation about the base z, translations in xy
    R0 = Rotation.from_euler("x", 180, degrees=True).as_matrix()
    rng = np.random.default_rng(1)
    T_bf = np.array(
        [pose(Rotation.from_euler("z", a, degrees=True).as_matrix() @ R0, [*rng.uniform(-0.3, 0.3, 2), 0.4])
         for a in [0, 40, -60, 90, 15, -120]]
    )
    T_bf, T_ct = _stations_for(T_bf)
    with pytest.raises(NotObservableError) as exc:
        solve_hand_eye(T_bf, T_ct)
    assert "planar motion (SCARA-like)" in str(exc.value)
    axis_z = "the common rotation axis (axis = [0, 0, 1]"
    assert f"translation of T_flange_cam along {axis_z} in the flange frame)" in exc.value.unknowns
    assert analyse_motion(T_bf).planar
    # eye-to-hand: the undetermined translation of T_base_cam is along the base z
    with pytest.raises(NotObservableError) as exc:
        solve_hand_eye(T_bf, T_ct, mount="base")
    assert f"translation of T_base_cam along {axis_z} in the base frame)" in exc.value.unknowns


def test_pure_translation():
    rng = np.random.default_rng(2)
    R = Rotation.from_euler("xyz", [170, 10, 30], degrees=True).as_matrix()
    T_bf, T_ct = _stations_for(np.array([pose(R, rng.uniform(-0.3, 0.3, 3)) for _ in range(6)]))
    with pytest.raises(NotObservableError) as exc:
        solve_hand_eye(T_bf, T_ct, method="tsai_lenz")
    assert "pure translations" in str(exc.value)
    assert exc.value.unknowns[0].startswith("rotation of T_flange_cam")
    assert exc.value.unknowns[1].startswith("translation of T_flange_cam")
    assert analyse_motion(T_bf).rank == 0


def test_rotations_too_small_for_the_stated_noise():
    # rotations of a few hundredths of a degree about two axes
    T_bf = np.concatenate(
        [_one_axis_stations([1.0, 0.0, 0.0], [0.0, 0.03]), _one_axis_stations([0.0, 1.0, 0.0], [-0.03, 0.02])]
    )
    T_bf, T_ct = _stations_for(T_bf)
    with pytest.raises(NotObservableError) as exc:
        solve_hand_eye(T_bf, T_ct, rotation_noise_deg=0.01)
    assert "too small relative to the stated noise" in str(exc.value)
    assert any(u.startswith("rotation of T_flange_cam") for u in exc.value.unknowns)
    # without noise the same (exact) data determine the transform; it warns about the small rotations
    res = solve_hand_eye(T_bf, T_ct, method="park_martin", rotation_noise_deg=0.0)
    assert any("largest relative rotation" in w for w in res.diagnostics.motion.warnings)


def test_nearly_one_axis_within_noise_is_one_axis():
    # a 0.005 deg wobble of the axis is below a 0.02 deg pose noise: still one axis
    T_bf = np.concatenate(
        [_one_axis_stations([0.0, 1.0, 0.0], [0, 30, -40]),
         _one_axis_stations(Rotation.from_euler("x", 0.005, degrees=True).apply([0.0, 1.0, 0.0]), [60, -70])]
    )
    assert analyse_motion(T_bf, rotation_noise_deg=0.0).rank >= 2  # numerically two axes
    with pytest.raises(NotObservableError) as exc:
        solve_hand_eye(*_stations_for(T_bf), rotation_noise_deg=0.02)
    assert any("along the common rotation axis (axis = [0, 1, 0]" in u for u in exc.value.unknowns)


def test_fewer_than_three_stations():
    rng = np.random.default_rng(4)
    _, _, T_bf, T_ct = make_scene(rng, n=3)
    with pytest.raises(NotObservableError) as exc:
        solve_hand_eye(T_bf[:2], T_ct[:2])
    assert "at least 3 stations" in str(exc.value) and "got 2" in str(exc.value)
    single = "translation of T_flange_cam along the rotation axis of the single motion"
    assert any(single in u for u in exc.value.unknowns)
    solve_hand_eye(T_bf, T_ct)  # three diverse stations are enough


def test_tsai_motion_window():
    # Tsai-Lenz (as OpenCV) ignores motions below ~17 deg: small but observable rotations make it refuse
    assert 17.0 < TSAI_MIN_ANGLE_DEG < 17.5 and 116.0 < TSAI_MAX_ANGLE_DEG < 117.0
    T_bf = np.concatenate(
        [_one_axis_stations([1.0, 0.0, 0.0], [0.0, 5.0]), _one_axis_stations([0.0, 1.0, 0.0], [-4.0, 6.0])]
    )
    T_bf, T_ct = _stations_for(T_bf)
    with pytest.raises(NotObservableError, match="Tsai-Lenz"):
        solve_hand_eye(T_bf, T_ct, method="tsai_lenz")
    for method in ("park_martin", "horaud", "daniilidis"):  # the others use every motion
        d_rot, d_t = errors(solve_hand_eye(T_bf, T_ct, method=method).T, X_DEFAULT)
        assert d_rot < 1e-9 and d_t < 1e-9, method


# --------------------------------------------------------------------------------------------- bad input


def test_bad_input_names_the_argument():
    rng = np.random.default_rng(6)
    _, _, T_bf, T_ct = make_scene(rng, n=5)
    with pytest.raises(BadInputError, match="T_cam_target"):
        solve_hand_eye(T_bf, T_ct[:4])
    with pytest.raises(BadInputError, match="T_base_flange.*shape"):
        solve_hand_eye(T_bf[:, :3], T_ct)
    with pytest.raises(BadInputError, match="method"):
        solve_hand_eye(T_bf, T_ct, method="tsai")
    with pytest.raises(BadInputError, match="mount"):
        solve_hand_eye(T_bf, T_ct, mount="wrist")
    bad = T_bf.copy()
    bad[2, :3, :3] *= 1.1
    with pytest.raises(BadInputError, match="T_base_flange: pose 2"):
        solve_hand_eye(bad, T_ct)
    bad = T_ct.copy()
    bad[1, 0, 3] = np.nan
    with pytest.raises(BadInputError, match="T_cam_target: pose 1"):
        solve_hand_eye(T_bf, bad)


# --------------------------------------------------------------------------------------------- real data


def test_real_camodocal_eye_to_hand():
    """Real robot + AR marker (jhu-lcsr/handeye_calib_camodocal): marker on the gripper, camera fixed.

    Noisy data: the per-station marker poses implied by the solution scatter by ~4 deg / ~7 mm RMS.
    """
    T_base_ee, T_cam_marker, ref = load_camodocal()
    assert len(T_base_ee) == 42
    for method in METHODS:
        res = solve_hand_eye(T_base_ee, T_cam_marker, method=method, mount="base", rotation_noise_deg=0.5)
        # the same numbers as OpenCV on real data too (T = T_base_cam)
        d_rot, d_t = errors(res.T, opencv_hand_eye(T_base_ee, T_cam_marker, method, mount="base"))
        assert d_rot < 1e-9 and d_t < 1e-9, method
        if method == "andreff":
            # linear in vec(R) with a free scale: 18 cm off here, for OpenCV as for us (see module docstring)
            continue
        # T_other = T_flange_target = the marker in the end-effector frame, the source project's unknown
        # (its answer comes from a non-linear refinement); the closed forms land 2-4 cm from it
        assert np.linalg.norm(res.T_other[:3, 3] - ref[:3, 3]) < 0.04, (method, res.T_other[:3, 3])
    # the same unknown as a direct AX = XB (README: A_i = T1_0^-1 T1_i, B_i = T2_0^-1 T2_i): X = T_ee_marker
    direct = solve_hand_eye(T_base_ee, inv(T_cam_marker), method="park_martin", rotation_noise_deg=0.5)
    assert np.linalg.norm(direct.T[:3, 3] - ref[:3, 3]) < 0.03
