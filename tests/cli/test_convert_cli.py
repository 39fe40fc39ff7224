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


@pytest.fixture(scope="module")
def opencv_left_result(tmp_path_factory):
    """The bundled OpenCV sample camera (tests/data/real/opencv_left_right_chessboard, left), as calibrated in the
    golden case ``camera_opencv_left``: opencv5 with its covariance."""
    import json
    from pathlib import Path

    from jcalib.geometry.cameras import camera_model_from_name

    case = json.loads((Path(__file__).parents[1] / "golden" / "cases" / "camera_opencv_left.json").read_text())
    cam = case["outputs"]["cameras"]["left"]
    model = camera_model_from_name(cam["model"], case["observations"]["cameras"]["left"]["image_size"],
                                   np.asarray(cam["params"]))
    file = ResultFile(cameras={"left": CameraResult.from_model(model, covariance=np.asarray(cam["covariance"]))},
                      stats={"rms_px": 0.2, "num_residuals": 100, "sigma_px": 0.2})
    path = tmp_path_factory.mktemp("convert_real") / "opencv5.json"
    file.save(path)
    return path, file.cameras["left"]


#: Sample pixels of the splined round trip: the fewest (``num_pixels >= 2 x`` the splined model's 421
#: parameters) instead of the command's default 40 x 30. The splined fit's solve runs its autodiff
#: Jacobian over every parameter for every sample pixel, so its run time (most of this test's) is
#: proportional to the samples; the sampling density is not what the test is about.
SPLINED_ROUND_TRIP_GRID = (34, 25)


def test_any_model_to_splined_and_back_with_finite_sigma(opencv_left_result, tmp_path, run_cli, monkeypatch):
    """README: any model to any model. A real opencv5 camera converted to splined (the spline's prior decides
    what no ray reaches, so every σ is finite) and back to opencv5: the first camera again, to a fraction of its
    σ, with about its σ (the source's noise propagated through two fits)."""
    import functools

    import jcalib.app.convert
    from jcalib.problems.convert import convert_camera

    monkeypatch.setattr(jcalib.app.convert, "convert_camera",
                        functools.partial(convert_camera, grid=SPLINED_ROUND_TRIP_GRID))
    path, source = opencv_left_result
    splined = tmp_path / "splined.json"
    code, text = run_cli("convert", path, "--to", "splined", "-o", splined)
    assert code == 0, text
    cam = load_result(splined).cameras["left"]
    assert cam.model == "splined" and cam.extra["converted"]["rms_px"] < 0.1
    assert cam.extra["converted"]["num_pixels"] == np.prod(SPLINED_ROUND_TRIP_GRID)  # the sampling asked for
    std = np.sqrt(np.diag(cam.covariance))
    assert np.all(np.isfinite(std)) and std[0] > 0.0
    back = tmp_path / "back.json"
    code, text = run_cli("convert", splined, "--to", "opencv5", "-o", back)
    assert code == 0, text
    again = load_result(back).cameras["left"]
    sigma = np.sqrt(np.diag(source.covariance))
    assert np.all(np.abs(again.params - source.params) < 0.5 * sigma)
    np.testing.assert_allclose(np.sqrt(np.diag(again.covariance)), sigma, rtol=0.2)
