"""``jcalib convert``: a fisheye result converted to opencv5 over a region, and its refusals (exit 2)."""

from __future__ import annotations


import numpy as np
import pytest

from jcalib.geometry import camera_from_opencv
from jcalib.io.result import CameraResult, ResultFile, TransformResult, load_result

KF = np.array([[420.0, 0, 640.0], [0, 421.0, 480.0], [0, 0, 1]])
DF = np.array([0.02, -0.01, 0.003, -0.0005])


@pytest.fixture(scope="module")
def fisheye_result(tmp_path_factory):
    model = camera_from_opencv(KF, DF, (1280, 960), fisheye=True)
    cov = np.diag([0.04, 0.04, 0.02, 0.02, 1e-6, 1e-6, 1e-7, 1e-8])
    file = ResultFile(cameras={"cam0": CameraResult.from_model(model, covariance=cov)},
                      transforms={"T_flange_cam0": TransformResult(np.eye(4), np.eye(6) * 1e-8)},
                      stats={"rms_px": 0.2, "num_residuals": 100, "sigma_px": 0.2},
                      extra={"joint_covariance": {"names": ["cam0"], "dims": [8], "matrix": cov.tolist()}})
    path = tmp_path_factory.mktemp("convert") / "fisheye.json"
    file.save(path)
    return path


def test_convert_writes_the_converted_camera_and_reports_the_error(fisheye_result, tmp_path, run_cli):
    out = tmp_path / "opencv5.json"
    code, text = run_cli("convert", fisheye_result, "--to", "opencv5", "--region", "440,330,840,630", "-o", out)
    assert code == 0, text
    assert "RMS" in text and "fisheye → opencv5" in text
    file = load_result(out)
    cam = file.cameras["cam0"]
    assert cam.model == "opencv5" and cam.dist.shape == (5,)
    conv = cam.extra["converted"]
    assert conv["from_model"] == "fisheye" and conv["region_px"] == [440.0, 330.0, 840.0, 630.0]
    assert 0.0 < conv["rms_px"] <= conv["max_px"] < 5.0
    assert cam.covariance is not None and cam.covariance.shape == (9, 9) and cam.std["fx"] > 0.0
    assert "joint_covariance" not in file.extra  # it was over the fisheye's coefficients
    np.testing.assert_array_equal(file.transforms["T_flange_cam0"].matrix, np.eye(4))


@pytest.mark.parametrize("args, expected", [
    (("--to", "opencv9"), "unknown camera model"),
    (("--to", "opencv5", "--region", "1,2,3"), "x0,y0,x1,y1"),
    (("--to", "opencv5", "--camera", "cam7"), "cam7"),
    (("--to", "opencv8", "--fix", "k9"), "k9"),
    (("--too", "opencv5"), "--too"),
])
def test_refusals_exit_2_with_a_message(fisheye_result, tmp_path, args, expected, run_cli):
    code, text = run_cli("convert", fisheye_result, *args, "-o", tmp_path / "x.json")
    assert code == 2, text
    assert expected in text and "Traceback" not in text
    assert not (tmp_path / "x.json").exists()
