"""ROS camera_info export: golden text, PyYAML parse-back, distortion model per camera model."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from jcalib.errors import BadInputError
from jcalib.io.export import ros_camera_info, write_ros_camera_info
from jcalib.io.result import CameraResult, ResultFile

GOLDEN = Path(__file__).parent / "golden"


def check_golden(name: str, text: str) -> None:
    """Compare with the golden file; JCALIB_UPDATE_GOLDEN=1 rewrites it (review the diff)."""
    path = GOLDEN / name
    if os.environ.get("JCALIB_UPDATE_GOLDEN"):
        path.write_text(text, encoding="utf-8")
    assert text == path.read_text(encoding="utf-8")


def _matrix(node: dict) -> np.ndarray:
    assert set(node) == {"rows", "cols", "data"}
    assert all(isinstance(v, float) for v in node["data"])  # YAML 1.1 floats, not strings
    return np.array(node["data"]).reshape(node["rows"], node["cols"])


def test_golden_and_fields(tmp_path):
    result = ResultFile.load(GOLDEN / "result.json")
    text = ros_camera_info(result, "cam0")
    check_golden("ros_cam0.yaml", text)
    path = write_ros_camera_info(GOLDEN / "result.json", tmp_path / "cam0.yaml", camera="cam0")
    info = yaml.safe_load(path.read_text())
    cam = result.cameras["cam0"]
    assert info["image_width"] == 1600 and info["image_height"] == 1200
    assert info["camera_name"] == "cam0"
    assert info["distortion_model"] == "plumb_bob"
    assert np.array_equal(_matrix(info["camera_matrix"]), cam.K)
    assert np.array_equal(_matrix(info["distortion_coefficients"]), cam.dist[None, :])
    assert np.array_equal(_matrix(info["rectification_matrix"]), np.eye(3))
    # monocular: P = [K | 0]
    assert np.array_equal(_matrix(info["projection_matrix"]), np.c_[cam.K, np.zeros(3)])


K = [[600.0, 0.0, 320.0], [0.0, 601.0, 240.0], [0.0, 0.0, 1.0]]
CASES = [
    ("pinhole", [], "plumb_bob", [0.0] * 5),
    ("opencv4", [0.1, -0.2, 1e-5, 2e-5], "plumb_bob", [0.1, -0.2, 1e-5, 2e-5, 0.0]),
    (
        "opencv8",
        [0.1, -0.2, 1e-5, 2e-5, 0.3, 0.01, 0.02, 0.03],
        "rational_polynomial",
        [0.1, -0.2, 1e-5, 2e-5, 0.3, 0.01, 0.02, 0.03],
    ),
    (
        "opencv12",
        [0.1, -0.2, 1e-5, 2e-5, 0.3, 0.01, 0.02, 0.03] + [0.0] * 4,
        "rational_polynomial",
        [0.1, -0.2, 1e-5, 2e-5, 0.3, 0.01, 0.02, 0.03],
    ),
    ("fisheye", [0.1, -0.02, 0.003, -0.0004], "equidistant", [0.1, -0.02, 0.003, -0.0004]),
]


@pytest.mark.parametrize("model, dist, ros_model, ros_dist", CASES)
def test_distortion_models(model, dist, ros_model, ros_dist):
    result = ResultFile(cameras={"c": CameraResult(model, (640, 480), K, dist)})
    info = yaml.safe_load(ros_camera_info(result, camera_name="left_camera"))
    assert info["camera_name"] == "left_camera"
    assert info["distortion_model"] == ros_model
    assert _matrix(info["distortion_coefficients"]).ravel().tolist() == ros_dist


def test_unrepresentable_and_bad_names():
    thin_prism = CameraResult("opencv12", (640, 480), K, [0.0] * 8 + [1e-4, 0.0, 0.0, 0.0])
    with pytest.raises(BadInputError, match="thin-prism"):
        ros_camera_info(ResultFile(cameras={"c": thin_prism}))
    ok = ResultFile(cameras={"c": CameraResult("opencv5", (640, 480), K, [0.0] * 5)})
    with pytest.raises(BadInputError, match="camera_name: expected an identifier"):
        ros_camera_info(ok, camera_name="left camera")
    with pytest.raises(BadInputError, match="2 cameras"):
        ros_camera_info(ResultFile(cameras={"a": ok.cameras["c"], "b": ok.cameras["c"]}))
