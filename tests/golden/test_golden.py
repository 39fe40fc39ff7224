"""The single builder against the golden outputs of the six problem families it replaced.

``tests/golden/record.py`` recorded, at commit 428809f (before the rebuild), the estimates, σ and errors of
the camera, hand-eye, whole-cell, TCP, pivot and pose-pair families on fixed inputs (synthetic cells and
the real data sets), with the inputs. Here the same inputs go through today's one path. Estimates are
compared in units of the recorded σ, σ relative to the recorded σ.

Where the one path deliberately differs from a family, the case carries its tolerance and the reason
(measured differences in the comment):

- ``vce_resolved``: whole cells re-solve once more after the last variance-component update, so the
  covariance carries the reported factors (the family stopped one solve earlier): 2e-3 σ, 1.5e-3 rel.
- ``vce_pose_model``: hand-eye with the robot pose model re-weights the pixels by their variance
  component *and re-solves* (the family kept the stated σ_px for the estimate and rescaled only the
  covariance): 0.30 σ, 3e-3 rel.
- ``vce_tcp``: TCP from tips and axis points gives each kind its own variance component (the family
  scaled everything by one σ̂²): 0.17 σ, 6 % (two cameras with axes); 1.3e-3 σ (one camera).
- ``outlier_rule``: real camera data where the per-kind robust outlier rule (1.4826 MAD, re-deciding
  every corner each round) rejects more corners than the camera family's one round at 5 σ̂ (OpenCV
  left images 15 vs 6, mrcal's wide-angle set 187 vs 60). The same data without outlier rejection is
  compared at full precision (``*_no_outliers``).
- ``vce_pairs``: pose pairs estimate σ_rot, σ_trans by variance components to 1 % (the family iterated
  to 1e-6): 8e-5 rel.

Three later changes of the estimator move these cases further (measured, worst unknown):

- ``t_variance``: a kind's variance factor is ``χ² / (r − 2)``, the variance of Student's t with the
  ``r`` degrees of freedom its σ was estimated from (was ``χ² / r``): TCP tips from one camera (r ≈ 5)
  σ +6 %, pose pairs (r ≈ 115) σ +0.9 %, cells' tips up to +29 %.
- ``view_noise``: with variance components, each view of a camera gets its own noise factor (blurred,
  tilted views are noisier): hand-eye with the pose model 0.27 σ / 1.7 %, Huber 0.21 σ / 1 %, cells
  0.18 σ.
- ``corner_mean``: the mean corners of a static scene (camera and target on one holder, repeated
  images) are their own kind with their own variance factor (the family weighed the mean as one
  image, ~1/√n too weakly): the second robot's camera of ``cell_two_robots`` 0.67 σ / 20 %.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jcalib
from jcalib.problems.options import CalibrationOptions

CASES = Path(__file__).resolve().parent / "cases"
REAL = Path(__file__).resolve().parents[1] / "data" / "real"

#: case -> (estimate tolerance in σ, σ tolerance relative); see the module docstring for the reasons.
EXACT = (1e-5, 1e-5)
TOLERANCES = {
    "cell_synthetic": (0.3, 0.35),  # vce_resolved, view_noise, t_variance
    "cell_two_robots": (1.0, 0.3),  # vce_resolved, view_noise, corner_mean
    "handeye_eye_in_hand_pose_model": (0.5, 0.03),  # vce_pose_model, view_noise
    "handeye_huber": (0.5, 0.02),  # vce_pose_model, view_noise
    "camera_opencv_left": (3.0, 0.3),  # outlier_rule
    "camera_mrcal_figueroa": (25.0, 0.8),  # outlier_rule
    "tcp_two_cameras_axis": (0.3, 0.1),  # vce_tcp, t_variance
    "tcp_one_camera_free_pose": (1e-2, 0.1),  # vce_tcp, t_variance
    "pairs_camodocal": (1e-3, 0.015),  # vce_pairs, t_variance
}


def _case(name: str) -> dict:
    return json.loads((CASES / f"{name}.json").read_text())


def _names(kind: str) -> list[str]:
    return sorted(p.stem for p in CASES.glob("*.json") if json.loads(p.read_text())["kind"] == kind)


def _options(spec: dict | None, cell: dict | None = None) -> CalibrationOptions | None:
    """The case's options; robot cells pinned to the robot error model their cell states (``prediction`` off:
    no ``error_model: auto`` comparison, which re-estimates the pose model's level: these cases are about the
    estimator, not the model choice; ``handeye_eye_in_hand_pose_model`` under auto keeps the pose model at its
    a-posteriori level, σ 8 % from the stated level's)."""
    robot = cell is not None and ("robot" in cell or "robots" in cell)
    if spec is None and not robot:
        return None
    options = {k: v for k, v in (spec or {}).items() if k != "type"}
    if robot and options.get("pose_model") is None:
        options["prediction"] = False
    return CalibrationOptions(**options)


def _tangent(T_a, T_b) -> np.ndarray:
    d = np.linalg.inv(T_a) @ T_b
    return np.r_[Rotation.from_matrix(d[:3, :3]).as_rotvec(), d[:3, 3]]


def _check(name: str, estimate: np.ndarray, golden: np.ndarray, sigma: np.ndarray, new_sigma: np.ndarray) -> None:
    tol_e, tol_s = TOLERANCES.get(name, EXACT)
    free = sigma > 0
    z = np.abs(estimate - golden)[free] / sigma[free]
    rel = np.abs(new_sigma[free] / sigma[free] - 1.0)
    assert z.max(initial=0.0) <= tol_e, f"{name}: estimate {z.max():.3g} σ from the golden one (tolerance {tol_e})"
    assert rel.max(initial=0.0) <= tol_s, f"{name}: σ {rel.max():.3g} relative from the golden one (tolerance {tol_s})"
    assert np.all(new_sigma[~free] == 0.0), f"{name}: held coordinates got a σ"


@pytest.mark.parametrize("name", _names("calibrate"))
def test_calibrate_matches_golden(name):
    case = _case(name)
    golden = case["outputs"]
    if "error" in golden:
        with pytest.raises(jcalib.JcalibError) as info:
            jcalib.calibrate(case["cell"], case["observations"], _options(case["options"], case["cell"]))
        assert type(info.value).__name__ == golden["error"]
        assert info.value.exit_code == golden["exit_code"]
        assert list(getattr(info.value, "unknowns", []) or []) == golden["unknowns"]
        return
    res = jcalib.calibrate(case["cell"], case["observations"], _options(case["options"], case["cell"]))
    file = res.file
    assert set(golden["cameras"]) == set(file.cameras)
    assert set(golden["transforms"]) <= set(file.transforms)
    for cam, g in golden["cameras"].items():
        new = file.cameras[cam]
        assert list(new.param_names) == g["param_names"]
        _check(name, np.asarray(new.params), np.asarray(g["params"]), np.sqrt(np.diag(g["covariance"])),
               np.sqrt(np.diag(new.covariance)))
    for t, g in golden["transforms"].items():
        new = file.transforms[t]
        _check(name, _tangent(np.asarray(g["matrix"]), new.matrix), np.zeros(6), np.sqrt(np.diag(g["covariance"])),
               np.sqrt(np.diag(new.covariance)))
    for p, g in golden["points"].items():
        new = file.points[p]
        _check(name, new.position, np.asarray(g["position"]), np.sqrt(np.diag(g["covariance"])),
               np.sqrt(np.diag(new.covariance)))
    assert file.stats["status"] == golden["stats"]["status"]
    if name not in TOLERANCES:
        assert file.stats["num_outliers"] == golden["stats"]["num_outliers"]


def test_tcp_matches_golden():
    from jcalib.geometry.cameras import Pinhole
    from jcalib.problems.tcp import calibrate_tcp

    for name in ("tcp_two_cameras_axis", "tcp_one_camera_free_pose"):
        i, g = _case(name)["inputs"], _case(name)["outputs"]
        cams = [Pinhole(tuple(c["image_size"]), focal=tuple(c["params"][:2]), principal_point=tuple(c["params"][2:4]))
                for c in i["cameras"]]
        res = calibrate_tcp(cams, np.asarray(i["T_base_cam"]), np.asarray(i["T_base_flange"]),
                            np.asarray(i["tip_pixels"]),
                            axis_lines=None if i["axis_lines"] is None else np.asarray(i["axis_lines"]),
                            free_camera_pose=i.get("free_camera_pose", False),
                            pose_noise_translation_m=i["pose_noise_translation_m"],
                            pose_noise_rotation_deg=i["pose_noise_rotation_deg"], sigma_px=i["sigma_px"])
        _check(name, res.p_flange_tip, np.asarray(g["p_flange_tip"]), np.sqrt(np.diag(g["tip_covariance"])),
               np.sqrt(np.diag(res.tip_covariance)))
        if g.get("axis_flange") is not None:
            axis_sigma = np.sqrt(np.trace(np.asarray(g["axis_covariance"])))
            assert np.linalg.norm(res.axis_flange - np.asarray(g["axis_flange"])) <= TOLERANCES[name][0] * axis_sigma


@pytest.mark.parametrize("serial", [False, True])
def test_pivot_matches_golden(serial):
    from jcalib.problems.pivot import refine_pivot

    name = f"pivot_ucl_serial_{serial}".lower()
    g = _case(name)["outputs"]
    T = np.stack([np.loadtxt(p).reshape(4, 4) for p in sorted((REAL / "pivot_ucl_ndi" / "matrices").glob("*.txt"))])
    T[:, :3, 3] *= 1e-3
    res = refine_pivot(T, serial_correlation=serial)
    sigma = np.sqrt(np.diag(g["covariance"]))
    _check(name, np.r_[res.p_flange_tip, res.p_base_pivot], np.r_[g["p_flange_tip"], g["p_base_pivot"]], sigma,
           np.sqrt(np.diag(res.covariance)))


def test_pose_pairs_match_golden():
    from jcalib.io.importers.opencv_pairs import read_transform_pairs
    from jcalib.problems.handeye_pairs import calibrate_hand_eye_pairs

    g = _case("pairs_camodocal")["outputs"]
    T1, T2 = read_transform_pairs(REAL / "handeye_camodocal_example" / "TransformPairsInput.yml")
    res = calibrate_hand_eye_pairs(T1, T2, mode="eye_to_hand")
    for key, T, C in (("X", res.T_hand_eye, res.T_hand_eye_covariance), ("Y", res.T_other, res.T_other_covariance)):
        _check("pairs_camodocal", _tangent(np.asarray(g[key]), T), np.zeros(6),
               np.sqrt(np.diag(g[f"{key}_covariance"])), np.sqrt(np.diag(C)))
    np.testing.assert_allclose([res.noise.rotation_deg, res.noise.translation_m], g["noise"], rtol=1e-2)
