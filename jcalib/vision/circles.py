"""Circle-grid centres with ``cv2.findCirclesGrid`` (symmetric and asymmetric grids)."""

from __future__ import annotations

import cv2
import numpy as np

from jcalib.vision.image import GrayImage, from_level

__all__ = ["CIRCLE_SIDE_PX", "count_blobs", "find_circles", "blob_lattice", "refine_centres"]


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


#: Fewest blobs on a lattice (:func:`blob_lattice`) for a grid search (measured at 640x480: 0 or 1 in
#: board-free cluttered scenes; 10 and more on most views of a 4x11 grid, also blurred, dim or glared).
MIN_BLOB_LATTICE = 2
#: Circles of an image whose longer side exceeds this are searched on the pyramid level below it (px), their
#: centres then measured at full resolution.
CIRCLE_SIDE_PX = 2000
#: Most dark blobs ``findCirclesGrid`` is given, beyond ``4 * circles`` of a large grid: its search grows
#: steeply with the blobs (measured on 800x600 Gaussian noise, OpenCV 4.14, an asymmetric 4x11 grid: 460
#: blobs 0.8 s, 770 blobs 1.3 s, 1075 blobs 44 s); an image with more is clutter or noise, not a grid.
MAX_GRID_BLOBS = 600


def find_circles(gray: GrayImage, target, *, retry: bool = True) -> tuple[np.ndarray | None, tuple[str, ...], int | None]:
    """All circle centres in OpenCV's order ((cols*rows, 2) float64 px) or None, the attempts run, and (when
    not found after a search) the number of dark blobs the default blob detector saw.

    Each attempt of :data:`jcalib.vision.attempts.CIRCLE_ATTEMPTS` (only the first unless ``retry``)
    runs ``findCirclesGrid`` (then with ``CALIB_CB_CLUSTERING``) on its prepared image. First a quick look on
    the next reduced level (:func:`blob_lattice`): with fewer than :data:`MIN_BLOB_LATTICE` blobs on a lattice
    there is no grid to find. When the defaults fail and the image shows
    fewer dark blobs than a quarter of the circles nothing is retried; with fewer blobs than circles the
    clustering variant is skipped (it cannot succeed). More than :data:`MAX_GRID_BLOBS` blobs (noise,
    clutter) are not searched (by the default: nothing is retried, and no blob count is returned).
    Images larger than :data:`CIRCLE_SIDE_PX` are searched on a reduced level and the centres measured
    again on the full-resolution image (:func:`refine_centres`).
    """
    from jcalib.vision.attempts import CIRCLE_ATTEMPTS, prepare, to_original

    flags = cv2.CALIB_CB_ASYMMETRIC_GRID if target.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    level = 0
    while max(gray.size) / 2**level > CIRCLE_SIDE_PX:
        level += 1
    base = gray.level(level)
    tried: list[str] = ["default"]
    if blob_lattice(gray.level(level + 1)) < MIN_BLOB_LATTICE:
        return None, tuple(tried), None  # no grid of dark circles here
    tried, seen = [], None
    for attempt in CIRCLE_ATTEMPTS if retry else CIRCLE_ATTEMPTS[:1]:
        tried.append(attempt.name)
        img = prepare(base, attempt)
        detector = _blob_detector(GrayImage(img, None, gray.name))
        blobs = len(detector.detect(img))
        if blobs > max(MAX_GRID_BLOBS, 4 * target.num_points):
            if attempt is CIRCLE_ATTEMPTS[0]:
                return None, tuple(tried), None  # noise or clutter: no grid search, no retries (minutes)
            continue
        ok, centres = cv2.findCirclesGrid(img, (target.cols, target.rows), flags=flags, blobDetector=detector)
        if not ok or centres is None:
            seen = blobs if seen is None else seen
            if attempt is CIRCLE_ATTEMPTS[0] and blobs < target.num_points / 4:
                break
            if blobs >= target.num_points:
                ok, centres = cv2.findCirclesGrid(img, (target.cols, target.rows), flags=flags | cv2.CALIB_CB_CLUSTERING,
                                                  blobDetector=detector)  # fmt: skip
        if ok and centres is not None:
            c = from_level(to_original(centres.reshape(-1, 2).astype(np.float64), attempt), level)
            return (refine_centres(gray, c, target) if level else c), tuple(tried), None
    return None, tuple(tried), seen


def refine_centres(gray: GrayImage, centres: np.ndarray, target) -> np.ndarray:
    """Circle centres measured on the full-resolution image: the centroid of the dark blob around each
    rough centre (a window of 0.8 spacings, thresholded half way between its darkest and brightest
    grey), as the blob detector measures them."""
    c = np.asarray(centres, np.float64)
    d = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    half = int(np.ceil(0.4 * float(np.median(d.min(axis=1)))))
    centre = np.round(c).astype(np.int64)
    tiles = gray.tiles(centre, half)
    out = c.copy()
    for k, tile in enumerate(tiles):
        lo, hi = float(tile.min()), float(tile.max())
        dark = (tile < 0.5 * (lo + hi)).astype(np.uint8)
        n, labels = cv2.connectedComponents(dark)
        lab = labels[half, half]
        if lab == 0 or hi - lo < 1.0:
            continue
        ys, xs = np.nonzero(labels == lab)
        out[k] = [centre[k, 0] - half + xs.mean(), centre[k, 1] - half + ys.mean()]
    return out


def blob_lattice(u8: np.ndarray) -> int:
    """Dark blobs of a (reduced) image that sit on a lattice (two pairs of opposite neighbours, as the
    circles of a grid do: :func:`jcalib.vision.locate.lattice_points`): the components of one adaptive
    threshold that fill 30-95 % of their box (a thin ellipse turned by 45° fills a third), a millisecond or two at 320x240."""
    from jcalib.vision.locate import lattice_points

    binary = cv2.adaptiveThreshold(cv2.GaussianBlur(u8, (0, 0), 0.8), 255, cv2.ADAPTIVE_THRESH_MEAN_C,
                                   cv2.THRESH_BINARY_INV, 31, 4)  # fmt: skip
    n, _, stats, centroids = cv2.connectedComponentsWithStats(binary, connectivity=8)
    w, h, area = stats[1:, cv2.CC_STAT_WIDTH], stats[1:, cv2.CC_STAT_HEIGHT], stats[1:, cv2.CC_STAT_AREA]
    fill = area / np.maximum(w * h, 1)
    blob = (area >= 4) & (area <= 0.05 * u8.size) & (fill > 0.3) & (fill < 0.95) & (np.minimum(w, h) >= 2)
    if np.sum(blob) < 5:
        return 0
    return int(np.sum(lattice_points(centroids[1:][blob].astype(np.float64))[0]))


def count_blobs(gray: GrayImage) -> tuple[int, int]:
    """(number of dark blobs, how many of them touch the image border) — to explain a failure."""
    keypoints = _blob_detector(gray).detect(gray.u8)
    w, h = gray.size
    near = sum(1 for k in keypoints if min(k.pt[0], k.pt[1], w - 1 - k.pt[0], h - 1 - k.pt[1]) < 0.75 * k.size)
    return len(keypoints), near
