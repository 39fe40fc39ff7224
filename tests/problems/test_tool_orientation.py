"""Tool orientation in the joint problem: the tilt of a symmetric tool's axis from imaged tool axes.

A tool's TCP ``T_flange_<tool>`` has its z axis along the tool (flange towards tip). Tip pixels
determine the tip; points on the imaged tool axis determine the axis direction (two tilt angles);
the rotation about the axis is not observable for a symmetric tool and is held at the convention
``rotation_z_to(axis)``. Monte Carlo: the tilt and tip errors normalised by the reported covariance
follow χ² (one camera with the axis, and two cameras).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

import jcalib
from jcalib.geometry.cameras import camera_from_opencv
from jcalib.geometry.se3 import rotation_z_to

TIP = np.array([0.012, -0.018, 0.17])  # tool tip in the flange frame, m
AXIS = np.array([0.05, -0.08, 1.0]) / np.linalg.norm([0.05, -0.08, 1.0])  # tool axis, flange -> tip
SIGMA_TIP, SIGMA_AXIS = 0.3, 0.5  # px
K = np.array([[2400.0, 0.0, 641.0], [0.0, 2410.0, 509.5], [0.0, 0.0, 1.0]])
DIST = np.array([-0.1, 0.05, 0.0, 0.0, 0.0])
CAMERA = camera_from_opencv(K, DIST, (1280, 1024))
P_TIP = np.array([0.6, 0.0, 0.3])  # where the tip is presented, base frame


def _T_base_cam(yaw_deg: float) -> np.ndarray:
    """A camera 0.4 m from the presentation point, looking at it horizontally, turned by yaw about base z."""
    Rz = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    R = Rz @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = P_TIP - 0.4 * R[:, 2]
    return T


def _stations(rng, n=14) -> list[np.ndarray]:
    """Flange poses presenting the tip at ``P_TIP``: the tool pointing down, tilted about varied axes."""
    R0 = np.diag([1.0, -1.0, -1.0])
    out = []
    for k in range(n):
        phi = k * np.pi / 7
        axis = np.array([np.cos(phi), np.sin(phi), 0.3 * (-1) ** k])
        R = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(25.0)).as_matrix() @ R0
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = P_TIP + rng.uniform(-0.01, 0.01, 3) - R @ TIP
        out.append(T)
    return out


def _project(T_base_cam, p_base):
    p_cam = (p_base - T_base_cam[:3, 3]) @ T_base_cam[:3, :3]
    return np.asarray(CAMERA.project(p_cam))


def _data(seed: int, yaws=(0.0,)):
    rng = np.random.default_rng(seed)
    cams = {f"cam{i}": _T_base_cam(y) for i, y in enumerate(yaws)}
    cell = {"schema": "jcalib.cell/1", "robot": {},
            "cameras": {c: {"model": "opencv5", "mount": "base", "pose": T.tolist(),
                            "intrinsics": {"K": K.tolist(), "dist": DIST.tolist()},
                            "fix": ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]} for c, T in cams.items()},
            "targets": {}, "tools": {"torch": {"observed_by": list(cams)}}, "fixed": list(cams)}
    stations = []
    for k, T in enumerate(_stations(rng)):
        tip = T[:3, :3] @ TIP + T[:3, 3]
        into = -T[:3, :3] @ AXIS  # from the tip into the tool
        dets = []
        for c, Tc in cams.items():
            px = _project(Tc, tip[None])[0] + SIGMA_TIP * rng.standard_normal(2)
            pt = _project(Tc, (tip + 0.03 * into)[None])[0] + SIGMA_AXIS * rng.standard_normal(2)
            dets.append({"camera": c, "tool": "torch", "pixel": px.tolist(), "axis": [pt.tolist()]})
        stations.append({"id": f"s{k:02d}", "T_base_flange": T.tolist(), "detections": dets})
    obs = {"schema": "jcalib.observations/1", "cameras": {c: {"image_size": [1280, 1024]} for c in cams},
           "targets": {}, "stations": stations}
    return cell, obs


OPTIONS = jcalib.CalibrationOptions(tip_sigma_px=SIGMA_TIP, axis_sigma_px=SIGMA_AXIS, noise="stated",
                                    outlier_threshold=None)


def _errors(cal) -> np.ndarray:
    """``(5,)`` error of (tilt rx, ry, tip tx, ty, tz) in the tangent of the estimate, whitened."""
    T = cal.transforms["T_flange_torch"]
    C = cal.transform_covariance["T_flange_torch"]
    R_true = rotation_z_to(AXIS)
    d_rot = Rotation.from_matrix(T[:3, :3].T @ R_true).as_rotvec()  # true = est · Exp(d)
    d_t = T[:3, :3].T @ (TIP - T[:3, 3])
    d = np.r_[d_rot[:2], d_t]
    idx = [0, 1, 3, 4, 5]
    return d, C[np.ix_(idx, idx)]


def test_noise_free_axis_is_recovered_and_reported():
    cell, obs = _data(0)
    for st in obs["stations"]:  # exact pixels: project again without noise
        T = np.asarray(st["T_base_flange"])
        tip = T[:3, :3] @ TIP + T[:3, 3]
        st["detections"][0]["pixel"] = _project(_T_base_cam(0.0), tip[None])[0].tolist()
        st["detections"][0]["axis"] = [_project(_T_base_cam(0.0), (tip - 0.03 * T[:3, :3] @ AXIS)[None])[0].tolist()]
    res = jcalib.calibrate(cell, obs, OPTIONS)
    T = res.details.transforms["T_flange_torch"]
    np.testing.assert_allclose(T[:3, 3], TIP, atol=1e-7)
    np.testing.assert_allclose(T[:3, 2], AXIS, atol=1e-7)
    np.testing.assert_allclose(T[:3, :3], rotation_z_to(AXIS), atol=1e-7)  # the convention about the axis
    entry = res.file.transforms["T_flange_torch"]
    assert entry.extra["orientation"] == "calibrated"
    assert entry.extra["calibrated"] == ["rx", "ry", "tx", "ty", "tz"]
    C = entry.covariance
    assert C[2, 2] == 0.0 and np.all(np.diag(C)[[0, 1, 3, 4, 5]] > 0.0)  # rotation about the axis: held


@pytest.mark.parametrize("yaws", [(0.0,), pytest.param((0.0, 70.0), marks=pytest.mark.slow(
    reason="the same Monte Carlo with a second camera (25 s): ./scripts/test -m slow"))], ids=["one camera", "two cameras"])
def test_monte_carlo_tilt_and_tip_errors_follow_chi2(yaws):
    """40 noisy data sets: Σ (whitened tilt + tip error)² ~ χ²(5·40); two-sided 99 % band."""
    trials = 40
    data = [_data(100 + i, yaws) for i in range(trials)]
    cals = jcalib.calibrate_batch([c for c, _ in data], [o for _, o in data], OPTIONS, raise_errors=True)
    total = 0.0
    for cal in cals:
        d, C = _errors(cal)
        total += float(d @ np.linalg.solve(C, d))
    dof = 5 * trials
    lo, hi = stats.chi2.ppf([0.005, 0.995], dof)
    assert lo <= total <= hi, f"χ² = {total:.1f}, expected within [{lo:.1f}, {hi:.1f}] for {dof} dof"


def test_without_axis_the_orientation_is_not_calibrated_and_rapid_refuses(tmp_path):
    from jcalib.errors import BadInputError
    from jcalib.io.export import export_result

    cell, obs = _data(1)
    for st in obs["stations"]:
        for det in st["detections"]:
            det.pop("axis")
    res = jcalib.calibrate(cell, obs, OPTIONS.replace(axis_sigma_px=0.5))
    entry = res.file.transforms["T_flange_torch"]
    assert entry.extra["orientation"] == "not calibrated"
    assert entry.extra["calibrated"] == ["tx", "ty", "tz"]
    np.testing.assert_array_equal(entry.covariance[:3, :3], 0.0)
    path = res.to_json(tmp_path / "result.json")
    for fmt in ("rapid", "krl"):
        with pytest.raises(BadInputError, match="orientation was not calibrated"):
            export_result(path, fmt, tmp_path / f"x.{fmt}")
        out = export_result(path, fmt, tmp_path / f"x.{fmt}", orientations={"torch": np.eye(3)})
        assert "supplied at export" in out.read_text()


def test_given_axis_in_the_cell_is_exported_as_given(tmp_path):
    from jcalib.io.export import export_result

    cell, obs = _data(2)
    for st in obs["stations"]:
        for det in st["detections"]:
            det.pop("axis")
    cell["tools"]["torch"]["axis"] = AXIS.tolist()
    res = jcalib.calibrate(cell, obs, OPTIONS)
    entry = res.file.transforms["T_flange_torch"]
    assert entry.extra["orientation"] == "given"
    np.testing.assert_allclose(entry.matrix[:3, :3], rotation_z_to(AXIS), atol=1e-12)
    text = export_result(res.to_json(tmp_path / "r.json"), "rapid", tmp_path / "x.mod").read_text()
    assert "as stated in the cell spec" in text
