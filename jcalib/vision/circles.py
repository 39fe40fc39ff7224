"""Circle-grid centres with ``cv2.findCirclesGrid`` (symmetric and asymmetric grids)."""

from __future__ import annotations

import cv2
import numpy as np

from jcalib.vision.image import GrayImage

__all__ = ["find_circles", "count_blobs"]


def _blob_detector(gray: GrayImage) -> cv2.SimpleBlobDetector:
    p = cv2.SimpleBlobDetector_Params()
    p.blobColor = 0  # dark circles on white paper
    p.filterByArea = True
    p.minArea = 10.0
    p.maxArea = 0.05 * gray.u8.shape[0] * gray.u8.shape[1]  # the default 5000 px rejects close-up circles
    p.filterByCircularity = False
    p.filterByConvexity = True
    p.minConvexity = 0.8
    p.filterByInertia = True
    p.minInertiaRatio = 0.05
    return cv2.SimpleBlobDetector_create(p)


def find_circles(gray: GrayImage, target, *, retry: bool = True) -> tuple[np.ndarray | None, tuple[str, ...]]:
    """All circle centres in OpenCV's order ((cols*rows, 2) float64 px) or None, and the attempts run.

    Each attempt of :data:`jcalib.vision.attempts.CIRCLE_ATTEMPTS` (only the first unless ``retry``)
    runs ``findCirclesGrid`` (then with ``CALIB_CB_CLUSTERING``) on its prepared image.
    """
    from jcalib.vision.attempts import CIRCLE_ATTEMPTS, prepare, to_original

    flags = cv2.CALIB_CB_ASYMMETRIC_GRID if target.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    tried: list[str] = []
    for attempt in CIRCLE_ATTEMPTS if retry else CIRCLE_ATTEMPTS[:1]:
        tried.append(attempt.name)
        img = prepare(gray.u8, attempt)
        view = GrayImage(img, img.astype(np.float32), gray.name)
        ok, centres = cv2.findCirclesGrid(img, (target.cols, target.rows), flags=flags, blobDetector=_blob_detector(view))
        if not ok or centres is None:
            ok, centres = cv2.findCirclesGrid(
                img, (target.cols, target.rows), flags=flags | cv2.CALIB_CB_CLUSTERING, blobDetector=_blob_detector(view)
            )
        if ok and centres is not None:
            return to_original(centres.reshape(-1, 2).astype(np.float64), attempt), tuple(tried)
    return None, tuple(tried)


def count_blobs(gray: GrayImage) -> tuple[int, int]:
    """(number of dark blobs, how many of them touch the image border) — to explain a failure."""
    keypoints = _blob_detector(gray).detect(gray.u8)
    w, h = gray.size
    near = sum(1 for k in keypoints if min(k.pt[0], k.pt[1], w - 1 - k.pt[0], h - 1 - k.pt[1]) < 0.75 * k.size)
    return len(keypoints), near
