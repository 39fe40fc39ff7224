"""Chessboard detection on OpenCV's real left/right sample images (Bouguet's stereo example 5)."""

import glob
import os

import cv2
import numpy as np
import pytest

from jcalib.geometry.targets import Checkerboard
from jcalib.vision import TargetDetection, detect_many

BOARD = Checkerboard(9, 6, 0.030)


@pytest.fixture(scope="module")
def detections(real_data):
    DATA = str(real_data / "opencv_left_right_chessboard" / "images")
    out = {}
    for side in ("left", "right"):
        files = sorted(glob.glob(os.path.join(DATA, f"{side}*.jpg")))
        assert len(files) == 13
        out[side] = detect_many(files, BOARD, progress=False)
    return out


@pytest.mark.parametrize("side", ["left", "right"])
def test_all_boards_found_and_consistent_with_a_camera(detections, side):
    dets = detections[side]
    assert all(isinstance(d, TargetDetection) for d in dets), [d for d in dets if not isinstance(d, TargetDetection)]
    for d in dets:
        assert d.fraction_found == 1.0 and d.warnings == ()  # 9 + 6 odd: orientation is unique
        np.testing.assert_array_equal(d.point_index, np.arange(54))
        assert d.pixels.dtype == np.float64 and d.image_size == (640, 480)
        # Locally the board is a plane seen through a smooth lens: a homography over each 3x3 patch of
        # corners fits to well under a pixel (a wrong order or a missed corner breaks this by pixels).
        P = d.pixels.reshape(6, 9, 2)
        X = BOARD.points[:, :2].reshape(6, 9, 2)
        for i in range(0, 4, 3):
            for j in range(0, 7, 3):
                src, dst = X[i : i + 3, j : j + 3].reshape(-1, 2), P[i : i + 3, j : j + 3].reshape(-1, 2)
                H, _ = cv2.findHomography(src, dst, 0)
                fit = cv2.perspectiveTransform(src[None], H)[0]
                # Real corner noise is ~0.2 px (the calibration RMS below): allow a few sigma.
                assert np.max(np.linalg.norm(fit - dst, axis=1)) < 0.75
    # Independent whole-set check: OpenCV's calibration on our corners. OpenCV's reference result on
    # these images (its own corners) has RMS 0.393 px and Bouguet's fc = (533.0, 533.2) for the left
    # camera; our sub-pixel corners must do at least as well.
    obj = [BOARD.points[d.point_index].astype(np.float32) for d in dets]
    img = [d.pixels.astype(np.float32) for d in dets]
    rms, K, *_ = cv2.calibrateCamera(obj, img, (640, 480), None, None)
    assert rms < 0.3
    if side == "left":
        assert abs(K[0, 0] - 533.0) < 5.0 and abs(K[1, 1] - 533.15) < 5.0


def test_left_right_ordering_is_consistent(detections):
    # The rig is nearly rectified (Bouguet: T = (-99.8, 1.1, 0.05) mm): the same corner has nearly the
    # same row in both images; a 180° relabelling would move rows by the board's height (>100 px).
    for left, right in zip(detections["left"], detections["right"]):
        dv = right.pixels[:, 1] - left.pixels[:, 1]
        dv_turned = right.pixels[::-1, 1] - left.pixels[:, 1]  # the other labelling of the right view
        # Lens distortion differs between the cameras: rows agree within ~16 px, not exactly.
        assert np.ptp(dv) < 25.0 and abs(np.median(dv)) < 30.0
        assert np.ptp(dv_turned) > 4.0 * np.ptp(dv)
        du = right.pixels[:, 0] - left.pixels[:, 0]
        assert np.all(du < 0.0)  # right camera sits to the right: points shift left
