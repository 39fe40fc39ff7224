"""Detection on targets drawn by the texture generator and warped by known homographies."""

import os
import sys

import cv2
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))
from synth import project, random_homography, texture_resolution, warp_texture  # noqa: E402

from jcalib.errors import BadInputError, DetectionError
from jcalib.geometry.targets import Charuco, Checkerboard, CircleGrid
from jcalib.sim.textures import target_texture
from jcalib.vision import TargetDetection, detect_many, detect_target
from jcalib.vision.orientation import point_symmetries

SIZE = (640, 480)


def _view(target, seed, fill=0.6, tilt_deg=30.0, image_size=SIZE):
    rng = np.random.default_rng(seed)
    H = random_homography(rng, target, image_size=image_size, fill=fill, tilt_deg=tilt_deg)
    img = warp_texture(target_texture(target, texture_resolution(target, H)), H, image_size=image_size)
    return img, project(H, target.points)


def _errors(det, gt):
    return np.linalg.norm(det.pixels - gt[det.point_index], axis=1)


# Accuracy bounds: the measured means are 0.005-0.02 px (chessboard corners) and ~0.02-0.06 px
# (circle centres, which also carry the perspective bias of ellipse centroids); the bounds leave
# a factor ~2 of headroom and fail on any mislabelled point (errors of a whole square).
CASES = [
    (Checkerboard(9, 6, 0.03), 0.03, 0.3),
    (Charuco(7, 5, 0.04, 0.03), 0.06, 0.3),
    (Charuco(6, 8, 0.04, 0.03, legacy=True), 0.06, 0.3),
    (CircleGrid(4, 11, 0.02, asymmetric=True), 0.08, 0.3),
    (CircleGrid(7, 6, 0.03), 0.12, 0.3),
]


@pytest.mark.parametrize("target, mean_px, max_px", CASES, ids=lambda c: getattr(c, "type", ""))
def test_warped_ground_truth_is_recovered(target, mean_px, max_px):
    errs = []
    for seed in range(4):
        img, gt = _view(target, seed, fill=0.55)
        det = detect_target(img, target)
        assert det.num_points >= 0.9 * target.num_points
        if "orientation_ambiguous" in det.warnings:
            # Any labelling related by a symmetry of the board is equally valid: take the closest.
            best = min(point_symmetries(target.points[:, :2]), key=lambda p: _errors(det, gt[p]).mean())
            gt = gt[best]
        e = _errors(det, gt)
        assert e.max() < max_px
        errs.append(e)
    assert np.concatenate(errs).mean() < mean_px


def test_checkerboard_orientation_is_fixed_by_the_printed_squares():
    # 9x6 (cols + rows odd): point 0 stays at the black-square corner however the board is turned.
    b = Checkerboard(9, 6, 0.03)
    for seed in (10, 11, 12, 13):
        img, gt = _view(b, seed, fill=0.5, tilt_deg=20)
        det = detect_target(img, b)
        assert det.warnings == ()
        assert _errors(det, gt).max() < 0.2
    # 8x6 (symmetric): detection warns, and point 0 -> 7 (target +x) points to the image right.
    s = Checkerboard(8, 6, 0.03)
    img, gt = _view(s, 3, fill=0.5, tilt_deg=20)
    det = detect_target(img, s)
    assert "orientation_ambiguous" in det.warnings
    px = det.pixels[np.argsort(det.point_index)]
    assert px[7, 0] > px[0, 0]


def test_partial_charuco_view_keeps_ids():
    t = Charuco(7, 5, 0.04, 0.03)
    img, gt = _view(t, 0, fill=0.55)
    cut = img.copy()
    cut[:, 320:] = 235  # hide the right half
    det = detect_target(cut, t)
    assert 0.2 < det.fraction_found < 0.9
    assert np.all(gt[det.point_index, 0] < 320)
    assert _errors(det, gt).max() < 0.3


def test_bit_depths_and_colour_give_the_same_corners():
    t = Checkerboard(9, 6, 0.03)
    img, gt = _view(t, 1, fill=0.55)
    ref = detect_target(img, t)
    img16 = img.astype(np.uint16) * 257
    bgr = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    for other in (img16, bgr, cv2.cvtColor(img16, cv2.COLOR_GRAY2BGRA)):
        det = detect_target(other, t)
        np.testing.assert_array_equal(det.point_index, ref.point_index)
        # 16-bit input is contrast-stretched and colour goes through cvtColor: tiny differences.
        assert np.max(np.abs(det.pixels - ref.pixels)) < 0.02


@pytest.mark.parametrize("target", [Checkerboard(9, 6, 0.03), CircleGrid(4, 11, 0.02, asymmetric=True), Charuco(7, 5, 0.04, 0.03)],
                         ids=["checkerboard", "circles", "charuco"])
def test_failure_reasons(target):
    blank = np.full((480, 640), 200, np.uint8)
    with pytest.raises(DetectionError, match="blank.png") as e:
        detect_target(blank, target, name="blank.png")
    assert e.value.reason == "not_found"

    img, gt = _view(target, 2, fill=0.6, tilt_deg=10)
    # Shift the board so that about a third of it leaves the image.
    x_cut = float(np.percentile(gt[:, 0], 65))
    shifted = np.full_like(img, img[0, 0])
    shift = int(640 - x_cut)
    shifted[:, shift:] = img[:, : 640 - shift]
    if isinstance(target, Charuco):
        # ChArUco accepts partial views; it fails only when too few corners remain.
        shifted = np.full_like(img, img[0, 0])
        shift = int(640 - np.percentile(gt[:, 0], 12))
        shifted[:, shift:] = img[:, : 640 - shift]
    with pytest.raises(DetectionError) as e:
        detect_target(shifted, target, name="cut.png")
    assert e.value.reason == "partially_visible", str(e.value)

    # findChessboardCornersSB still finds a chessboard at sigma 12 px (with a "blurred" warning).
    sigma = 20.0 if isinstance(target, Checkerboard) else 12.0
    blurred = cv2.GaussianBlur(img, (0, 0), sigma)
    with pytest.raises(DetectionError) as e:
        detect_target(blurred, target, name="blurred.png")
    assert e.value.reason == "too_blurred", str(e.value)


def test_blurred_but_found_board_warns():
    t = Checkerboard(9, 6, 0.03)
    img, gt = _view(t, 2, fill=0.6, tilt_deg=10)
    det = detect_target(cv2.GaussianBlur(img, (0, 0), 6.0), t)
    assert "blurred" in det.warnings and det.edge_width_px > 8.0
    assert _errors(det, gt).mean() < 0.5  # sigma 6 px blur: corners lose accuracy (measured 0.16 px)


def test_detect_many_never_crashes(tmp_path):
    t = Checkerboard(9, 6, 0.03)
    img, _ = _view(t, 0, fill=0.5)
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), img)
    corrupt = tmp_path / "corrupt.png"
    corrupt.write_bytes(b"\x89PNG not really")
    images = [str(good), str(tmp_path / "missing.png"), str(corrupt), np.zeros((480, 640), np.uint8),
              np.zeros((3, 3), np.uint8), np.full((480, 640), np.nan), img]
    out = detect_many(images, t, progress=True)
    assert len(out) == len(images)
    assert isinstance(out[0], TargetDetection) and isinstance(out[-1], TargetDetection)
    assert [getattr(r, "reason", None) for r in out[1:-1]] == ["unreadable", "unreadable", "not_found", "unreadable", "unreadable"]
    assert "missing.png" in str(out[1])
    np.testing.assert_allclose(out[0].pixels, out[-1].pixels, atol=1e-9)  # PNG is lossless


def test_bad_arguments_raise():
    with pytest.raises(BadInputError, match="'target'"):
        detect_target(np.zeros((480, 640), np.uint8), {"type": "checkerboard"})
    with pytest.raises(BadInputError, match="'min_points'"):
        detect_many([np.zeros((480, 640), np.uint8)], Charuco(5, 5, 0.04, 0.03), progress=False, min_points=2)
    with pytest.raises(DetectionError) as e:
        detect_target(os.path.join("/nonexistent", "x.png"), Checkerboard(9, 6, 0.03))
    assert e.value.reason == "unreadable"
