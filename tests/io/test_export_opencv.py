"""OpenCV YAML export: golden text, exact parse-back with cv2.FileStorage, stereo R/T meaning."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from jcalib.errors import BadInputError
from jcalib.io.export import opencv_yaml, write_opencv_yaml
from jcalib.io.result import CameraResult, ResultFile, TransformResult

GOLDEN = Path(__file__).parent / "golden"


def check_golden(name: str, text: str) -> None:
    """Compare with the golden file; JCALIB_UPDATE_GOLDEN=1 rewrites it (review the diff)."""
    path = GOLDEN / name
    if os.environ.get("JCALIB_UPDATE_GOLDEN"):
        path.write_text(text, encoding="utf-8")
    assert text == path.read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def result() -> ResultFile:
    return ResultFile.load(GOLDEN / "result.json")


def _read(path: Path) -> cv2.FileStorage:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.isOpened()
    return fs


def test_mono_golden_and_exact_parse_back(result, tmp_path):
    text = opencv_yaml(result, "cam0")
    check_golden("opencv_cam0.yaml", text)
    path = write_opencv_yaml(GOLDEN / "result.json", tmp_path / "cam0.yaml", "cam0")
    assert path.read_text() == text
    fs = _read(path)
    cam = result.cameras["cam0"]
    assert np.array_equal(
        fs.getNode("camera_matrix").mat(), cam.K
    )  # exact: shortest repr round trip
    assert np.array_equal(fs.getNode("distortion_coefficients").mat(), cam.dist[None, :])
    assert fs.getNode("image_width").isInt() and int(fs.getNode("image_width").real()) == 1600
    assert int(fs.getNode("image_height").real()) == 1200
    assert fs.getNode("camera_name").string() == "cam0"
    assert fs.getNode("camera_model").string() == "opencv5"
    fs.release()


def test_stereo_golden_and_R_T_map_cam1_points_into_cam2(result, tmp_path):
    text = opencv_yaml(result)  # two cameras with a common parent (base): a stereo pair
    check_golden("opencv_stereo.yaml", text)
    (tmp_path / "stereo.yaml").write_text(text)
    fs = _read(tmp_path / "stereo.yaml")
    R, T = fs.getNode("R").mat(), fs.getNode("T").mat()
    assert T.shape == (3, 1)
    for suffix, name in (("_1", "cam0"), ("_2", "cam1")):
        assert fs.getNode("camera_name" + suffix).string() == name
        assert np.array_equal(fs.getNode("camera_matrix" + suffix).mat(), result.cameras[name].K)
        assert np.array_equal(
            fs.getNode("distortion_coefficients" + suffix).mat()[0], result.cameras[name].dist
        )
    fs.release()
    # Independent reference: p_cam1 = T_base_cam1^-1 T_base_cam0 p_cam0 (numpy inverse).
    T_base_cam0 = result.transforms["T_base_cam0"].matrix
    T_base_cam1 = result.transforms["T_base_cam1"].matrix
    p_cam0 = np.array([[0.1, -0.2, 1.5], [0.0, 0.0, 0.8], [-0.3, 0.25, 2.0]])
    p_cam1 = (np.linalg.inv(T_base_cam1) @ T_base_cam0 @ np.c_[p_cam0, np.ones(3)].T)[:3].T
    # 1e-12 m: float64 rounding of products of O(1) matrices (R, T are exact copies of ours)
    np.testing.assert_allclose((R @ p_cam0.T + T).T, p_cam1, atol=1e-12)
    # and OpenCV projects a cam0 point into cam1 with (R, T) as the extrinsics
    img, _ = cv2.projectPoints(
        p_cam0, cv2.Rodrigues(R)[0], T, result.cameras["cam1"].K, result.cameras["cam1"].dist
    )
    ref, _ = cv2.projectPoints(
        p_cam1, np.zeros(3), np.zeros(3), result.cameras["cam1"].K, result.cameras["cam1"].dist
    )
    np.testing.assert_allclose(img, ref, atol=1e-9)  # px; Rodrigues round trip ~1e-15 rad


def test_explicit_pair_order_swaps_the_transform(result):
    forward, backward = (opencv_yaml(result, pair) for pair in (("cam0", "cam1"), ("cam1", "cam0")))
    assert forward == opencv_yaml(result)
    assert 'camera_name_1: "cam1"' in backward


def test_pinhole_writes_five_zeros_and_fisheye_its_four_D(tmp_path):
    K = [[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]]
    result = ResultFile(
        cameras={
            "pin": CameraResult("pinhole", (640, 480), K, []),
            "fish": CameraResult("fisheye", (640, 480), K, [0.1, -0.02, 0.003, -0.0004]),
        }
    )
    for name, expected in (
        ("pin", np.zeros((1, 5))),
        ("fish", np.array([[0.1, -0.02, 0.003, -0.0004]])),
    ):
        (tmp_path / f"{name}.yaml").write_text(opencv_yaml(result, name))
        fs = _read(tmp_path / f"{name}.yaml")
        assert np.array_equal(fs.getNode("distortion_coefficients").mat(), expected)
        fs.release()


def test_bad_requests(result):
    three = ResultFile(
        cameras={**result.cameras, "cam2": result.cameras["cam0"]},
        transforms={"T_base_cam0": result.transforms["T_base_cam0"]},
    )
    with pytest.raises(BadInputError, match="3 cameras"):
        opencv_yaml(three)
    with pytest.raises(BadInputError, match="cannot form T_cam2_cam0"):
        opencv_yaml(three, ["cam0", "cam2"])
    with pytest.raises(BadInputError, match="no camera 'cam9'"):
        opencv_yaml(result, "cam9")
    with pytest.raises(BadInputError, match="two different ids"):
        opencv_yaml(result, ["cam0", "cam0"])
    with pytest.raises(BadInputError, match="0 cameras"):
        opencv_yaml(ResultFile(transforms={"T_a_b": TransformResult(np.eye(4))}))
