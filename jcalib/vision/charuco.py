"""ChArUco corners with ``cv2.aruco.CharucoDetector`` (partial views, corner ids), re-refined."""

from __future__ import annotations

import functools

import cv2
import numpy as np

from jcalib.vision.chessboard import refine_corners
from jcalib.vision.image import GrayImage

__all__ = ["find_charuco"]


@functools.lru_cache(maxsize=16)
def _detector(target) -> cv2.aruco.CharucoDetector:
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, target.dictionary))
    board = cv2.aruco.CharucoBoard((target.squares_x, target.squares_y), target.square, target.marker, d)
    board.setLegacyPattern(target.legacy)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.CharucoDetector(board, cv2.aruco.CharucoParameters(), params)


def find_charuco(gray: GrayImage, target) -> tuple[np.ndarray, np.ndarray, int]:
    """ChArUco corners seen in an image.

    Returns:
        (ids (n,) int64, pixels (n, 2) float64 px, number of ArUco markers found). ``n`` may be 0.
    """
    corners, ids, _marker_corners, marker_ids = _detector(target).detectBoard(gray.u8)
    num_markers = 0 if marker_ids is None else len(marker_ids)
    if ids is None or corners is None or len(ids) == 0:
        return np.zeros((0,), np.int64), np.zeros((0, 2)), num_markers
    ids = ids.reshape(-1).astype(np.int64)
    pixels = corners.reshape(-1, 2).astype(np.float64)
    if len(ids) >= 4:
        # Window: stay inside the white gap between the corner and the neighbouring markers.
        xy = target.points[ids, :2]
        H, _ = cv2.findHomography(xy, pixels, 0)
        if H is not None:
            gap_m = 0.5 * (target.square - target.marker)
            d = 1e-3 * target.square
            p0 = _apply(H, xy)
            scale = np.minimum(
                np.linalg.norm(_apply(H, xy + [d, 0.0]) - p0, axis=1),
                np.linalg.norm(_apply(H, xy + [0.0, d]) - p0, axis=1),
            ) / d
            gap_px = float(np.min(scale)) * gap_m
            # refine_corners' half window is 0.35 * spacing and its smoothing reaches ~window/2 further:
            # both must stay inside the white gap, or marker edges bias the corner. Where the gap is
            # too narrow (small board in the image), OpenCV's own refinement is kept (measured better).
            half = 0.6 * gap_px
            if half >= 3.0:
                spacing = min(half / 0.35, float(np.min(scale)) * target.square)
                refined = refine_corners(gray, pixels, spacing_px=spacing)
                ok = np.linalg.norm(refined - pixels, axis=1) < 2.0
                pixels = np.where(ok[:, None], refined, pixels)
    order = np.argsort(ids)
    return ids[order], pixels[order], num_markers


def _apply(H, xy):
    p = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    return p[:, :2] / p[:, 2:]
