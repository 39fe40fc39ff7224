"""`jcalib compare` and `jcalib cross-validate` as a user runs them: exit status 0 consistent, 1 differ, 2 bad
input (one plain message, never a traceback)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.io.result import CameraResult, ResultFile
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
K = np.array([[900.0, 0, 640.0], [0, 905.0, 481.0], [0, 0, 1]])
DIST = np.array([-0.3, 0.12, 1e-3, -5e-4, -0.02])
CAMERA = camera_from_opencv(K, DIST, (1280, 960))
#: σ of a 10-view calibration of CAMERA (fx, fy, cx, cy, k1, k2, p1, p2, k3), uncorrelated for the test.
STD = np.array([1.5, 1.5, 1.7, 1.5, 3e-3, 1e-2, 2e-4, 2e-4, 1e-2])
CELL = """schema: jcalib.cell/1
cameras:
  cam0: {model: opencv5%s}
targets:
  board: {type: checkerboard, cols: 9, rows: 6, square: 0.03}
"""


def _result(path, dist=DIST, model="opencv5", size=(1280, 960)):
    n = 4 + len(dist)
    cam = CameraResult(model, size, K, dist, covariance=np.diag(STD[:n] ** 2))
    ResultFile(cameras={"cam0": cam}).save(path)
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("compare")
    shifted = DIST + np.array([50 * STD[4], 0, 0, 0, 0])  # k1 moved by 50σ: a real difference
    return {"a": _result(d / "a.json"), "a2": _result(d / "a2.json"), "b": _result(d / "b.json", dist=shifted),
            "pinhole": _result(d / "p.json", dist=np.zeros(0), model="pinhole"),
            "small": _result(d / "s.json", size=(640, 480)), "dir": d}


def test_consistent_results_exit_0_and_write_json(files, tmp_path, run_cli):
    code, text = run_cli("compare", files["a"], files["a2"], "--grid", "12x9", "--json", tmp_path / "c.json")
    assert code == 0, text
    assert "consistent" in text and "cam0" in text
    doc = json.loads((tmp_path / "c.json").read_text())
    assert doc["schema"] == "jcalib.compare/1" and doc["cameras"]["cam0"]["verdict"] == "consistent"
    assert doc["cameras"]["cam0"]["num_points"] + doc["cameras"]["cam0"]["num_skipped"] == 12 * 9


def test_differing_results_exit_1(files, run_cli):
    code, text = run_cli("compare", files["a"], files["b"], "--camera", "cam0", "--grid", "12x9")
    assert code == 1, text
    assert "differ" in text and "corner" in text and "Traceback" not in text


@pytest.mark.parametrize("args, message", [
    (("{small}",), "image sizes differ"),
    (("{dir}/missing.json",), "missing.json"),
    (("{a2}", "--grid", "12by9"), "Invalid value for '--grid': expected WxH"),
    (("{a2}", "--camera", "cam9"), "no camera 'cam9'"),
    (("{a2}", "--distance", "-2"), "Invalid value for '--distance'"),
    (("{a2}", "--gird", "12x9"), "No such option"),
    (("{a2}", "--distance", "far"), "Invalid value"),
])
def test_bad_input_exit_2_without_traceback(files, args, message, run_cli):
    args = [a.format(**files) for a in args]
    code, text = run_cli("compare", files["a"], *args)
    assert code == 2, text
    assert message in text and "Traceback" not in text


def _observations(rng, num_views):
    stations = []
    for i, T in enumerate(random_calibration_views(CAMERA, BOARD.points, num_views, rng=rng)):
        pix, _ = project_target(CAMERA, T, BOARD.points)
        pix = pix + 0.3 * rng.standard_normal(pix.shape)
        stations.append({"id": f"s{i:02d}", "detections": [{
            "camera": "cam0", "target": "board", "point_index": list(range(54)), "pixels": pix.tolist()}]})
    return {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": [1280, 960]}},
            "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}


def test_cross_validate_exit_statuses(tmp_path, run_cli):
    rng = np.random.default_rng(21)
    (tmp_path / "cell.yaml").write_text(CELL % "")
    (tmp_path / "wrong.yaml").write_text(CELL % ", fix: [k1, k2, p1, p2, k3]")  # no distortion: wrong model
    (tmp_path / "obs.json").write_text(json.dumps(_observations(rng, 20)))
    (tmp_path / "few.json").write_text(json.dumps(_observations(rng, 7)))
    code, text = run_cli("cross-validate", tmp_path / "cell.yaml", tmp_path / "obs.json", "--json", tmp_path / "cv.json")
    assert code == 0, text
    assert "10 stations" in text and "consistent" in text
    doc = json.loads((tmp_path / "cv.json").read_text())
    assert doc["stations"]["a"][:2] == ["s00", "s02"] and doc["cameras"]["cam0"]["verdict"] == "consistent"
    code, text = run_cli("cross-validate", tmp_path / "wrong.yaml", tmp_path / "obs.json", "--split", "random")
    assert code == 1, text
    assert "differ" in text
    code, text = run_cli("cross-validate", tmp_path / "cell.yaml", tmp_path / "few.json")
    assert code == 2 and "7 views" in text and "Traceback" not in text, text
    code, text = run_cli("cross-validate", tmp_path / "cell.yaml", tmp_path / "obs.json", "--split", "thirds")
    assert code == 2 and "split" in text and "Traceback" not in text, text


def test_results_of_different_lens_models_are_compared(files, run_cli):
    """opencv5 against a pinhole of the same K: compared across lens models (the distortion is the difference)."""
    code, text = run_cli("compare", files["a"], files["pinhole"], "--grid", "12x9")
    assert code == 1, text
    flat = " ".join(text.split())  # the console wraps the message
    assert "opencv5 → pinhole" in flat and "cannot represent" in flat and "Traceback" not in text


def test_a_real_camera_against_its_exact_conversion_to_another_model(tmp_path, run_cli):
    """The bundled OpenCV sample camera (golden case camera_opencv_left: opencv5 with its covariance) and the
    same lens written as opencv8 (``jcalib convert`` with k4, k5, k6 held at 0: exact): compared across the
    two lens models, they agree to numerical precision."""
    from pathlib import Path

    from jcalib.geometry.cameras import camera_model_from_name

    case = json.loads((Path(__file__).parents[1] / "golden" / "cases" / "camera_opencv_left.json").read_text())
    cam = case["outputs"]["cameras"]["left"]
    model = camera_model_from_name(cam["model"], case["observations"]["cameras"]["left"]["image_size"],
                                   np.asarray(cam["params"]))
    ResultFile(cameras={"left": CameraResult.from_model(model, covariance=np.asarray(cam["covariance"]))}).save(
        tmp_path / "opencv5.json")
    code, text = run_cli("convert", tmp_path / "opencv5.json", "--to", "opencv8", "--fix", "k4,k5,k6",
                         "-o", tmp_path / "opencv8.json")
    assert code == 0, text
    code, text = run_cli("compare", tmp_path / "opencv5.json", tmp_path / "opencv8.json", "--grid", "12x9",
                         "--json", tmp_path / "c.json")
    assert code == 0, text
    doc = json.loads((tmp_path / "c.json").read_text())["cameras"]["left"]
    assert (doc["model"], doc["model_b"]) == ("opencv5", "opencv8") and doc["verdict"] == "consistent"
    assert doc["max_px"] < 1e-6 and doc["num_skipped"] == 0  # the same projection, two parameterisations
