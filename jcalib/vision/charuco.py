"""ChArUco corners: ArUco markers found (and re-tried) with ``cv2.aruco``, checked against the board, then
the chessboard corners interpolated by ``cv2.aruco.CharucoDetector`` and re-refined.

Markers are collected over the attempts of :mod:`jcalib.vision.attempts` until every marker the board
predicts inside the image is found (or the attempts run out); each attempt's markers are mapped back to
the original pixels and the whole set is checked marker by marker against the board layout
(:func:`jcalib.vision.validate.consistent_markers`): a marker whose id or rotation does not fit its
neighbours is dropped, whichever attempt found it. The corners are then interpolated from the kept
markers on the original image and each is checked against the homography of the markers around it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from jcalib.vision.attempts import CHARUCO_ATTEMPTS, Attempt, aruco_parameters, prepare, to_original
from jcalib.vision.chessboard import refine_corners, windows
from jcalib.vision.image import GrayImage, from_level
from jcalib.vision.validate import homography_steps, batched_homographies, consistent_markers

__all__ = ["CharucoFound", "find_charuco", "CORNER_TOLERANCE"]

#: Largest distance of a ChArUco corner from the prediction of the markers around it, in squares.
CORNER_TOLERANCE = 0.15
#: Detected corners (the corner itself included) whose local homography gives a corner's image scale.
LOCAL_NEIGHBOURS = 9


@dataclass(frozen=True)
class CharucoFound:
    """What :func:`find_charuco` found.

    Attributes:
        ids: (n,) int64 ChArUco corner ids, ascending.  pixels: (n, 2) float64 px.
        num_markers: markers kept (consistent with the board).
        attempts: names of the attempts run, in order.
        contributing: names of the attempts whose markers were kept.
        dropped_markers: markers found but inconsistent with the board layout.
        dropped_corners: corners interpolated but inconsistent with the markers around them.
    """

    ids: np.ndarray
    pixels: np.ndarray
    num_markers: int
    attempts: tuple[str, ...]
    contributing: tuple[str, ...]
    dropped_markers: int = 0
    dropped_corners: int = 0


@functools.lru_cache(maxsize=16)
def _board(target):
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, target.dictionary))
    board = cv2.aruco.CharucoBoard((target.squares_x, target.squares_y), target.square, target.marker, d)
    board.setLegacyPattern(target.legacy)
    marker_ids = np.asarray(board.getIds(), dtype=np.int64).reshape(-1)
    marker_xy = np.asarray(board.getObjPoints(), dtype=np.float64)[:, :, :2]  # (M, 4, 2), OpenCV board frame
    corner_xy = np.asarray(board.getChessboardCorners(), dtype=np.float64)[:, :2]
    return d, board, {int(i): k for k, i in enumerate(marker_ids)}, marker_xy, corner_xy


@functools.lru_cache(maxsize=16)
def _charuco_detector(target) -> cv2.aruco.CharucoDetector:
    d, board, *_ = _board(target)
    return cv2.aruco.CharucoDetector(board, cv2.aruco.CharucoParameters(), aruco_parameters(CHARUCO_ATTEMPTS[0]))


def _detect_markers(img: np.ndarray, target, attempt: Attempt) -> tuple[dict[int, np.ndarray], int]:
    """This board's markers found in ``img`` (corners in ``img``'s pixels before the attempt's scaling) and
    the number of marker-like candidates rejected."""
    d, board, index, *_ = _board(target)
    detector = cv2.aruco.ArucoDetector(d, aruco_parameters(attempt))
    corners, ids, rejected = detector.detectMarkers(img)
    if attempt.refine_markers and ids is not None and len(ids) > 0:
        corners, ids, rejected, _ = detector.refineDetectedMarkers(img, board, corners, ids, rejected)
    if ids is None:
        return {}, len(rejected)
    out = {}
    for c, i in zip(corners, np.asarray(ids).reshape(-1)):
        if int(i) in index and int(i) not in out:  # ids of other boards of the dictionary are not ours
            out[int(i)] = to_original(np.asarray(c, dtype=np.float64).reshape(4, 2), attempt)
    return out, len(rejected)


def _markers_to_full(gray: GrayImage, markers: dict[int, np.ndarray], level: int) -> dict[int, np.ndarray]:
    """Marker corners found on pyramid level ``level`` -> full resolution, each moved by ``cornerSubPix`` on
    a window of the full image (a marker's corner is the corner of its black border)."""
    if level == 0 or not markers:
        return markers
    keys = list(markers)
    c = from_level(np.concatenate([markers[i] for i in keys]), level)
    side = np.min(np.linalg.norm(np.stack([markers[i] for i in keys]) - np.roll(np.stack([markers[i] for i in keys]), 1, axis=1),
                                 axis=-1)) * 2**level  # fmt: skip
    half = int(np.clip(0.1 * side, 2, 8))
    image, local = windows(gray, c, half + 6)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-3)
    moved = cv2.cornerSubPix(image, local.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1), criteria)
    moved = moved.reshape(-1, 2).astype(np.float64) - local
    c = c + np.where(np.linalg.norm(moved, axis=1, keepdims=True) < 2.0**level, moved, 0.0)
    return {i: c[4 * k:4 * k + 4] for k, i in enumerate(keys)}


#: Markers of an image whose longer side exceeds this are searched on the pyramid level below it (px).
MARKER_SIDE_PX = 2000
#: With no marker of the board found by the defaults, the retries run only when the detector rejected at
#: least this many marker-like candidates (measured at 640x480: 0-10 in board-free cluttered scenes,
#: 19-35 on boards blurred beyond reading, 3-5 on the low-contrast boards no attempt finds).
MIN_REJECTED_TO_RETRY = 12
#: ... or when the image's contrast (0..1) is below this: the default thresholds may miss every marker of a
#: faded or dim board (OpenCV's ChArUco photograph at 5 % contrast: no candidate at all).
LOW_CONTRAST = 0.25


def _apply(H, xy):
    p = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return p[:, :2] / p[:, 2:]


def _all_expected_found(found: dict[int, np.ndarray], target, image_size: tuple[int, int]) -> bool:
    """Whether every marker the found ones predict well inside the image is found."""
    _, _, index, marker_xy, _ = _board(target)
    if len(found) == len(index):
        return True
    if len(found) < 2:
        return False
    ks = [index[i] for i in found]
    H, _ = cv2.findHomography(marker_xy[ks].reshape(-1, 2), np.stack(list(found.values())).reshape(-1, 2), 0)
    if H is None:
        return False
    w, h = image_size
    for i, k in index.items():
        if i in found:
            continue
        p = _apply(H, marker_xy[k])
        if not np.all(np.isfinite(p)):
            continue
        side = float(np.linalg.norm(p[1] - p[0]))
        margin = 0.5 * side
        if np.all((p[:, 0] > margin) & (p[:, 0] < w - 1 - margin) & (p[:, 1] > margin) & (p[:, 1] < h - 1 - margin)):
            return False
    return True


def _check_corners(target, found: dict[int, np.ndarray], ids: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(n,) bool: each corner agrees with the homography of the (up to 4) kept markers nearest to it."""
    _, _, index, marker_xy, corner_xy = _board(target)
    if len(ids) == 0:
        return np.zeros(0, dtype=bool)
    ks = np.array([index[i] for i in found])
    mpx = np.stack(list(found.values()))
    centres = marker_xy[ks].mean(axis=1)
    xy = corner_xy[ids]
    near = np.argsort(np.linalg.norm(xy[:, None, :] - centres[None, :, :], axis=-1), axis=1, kind="stable")[:, :4]
    H = batched_homographies(marker_xy[ks[near]].reshape(len(ids), -1, 2), mpx[near].reshape(len(ids), -1, 2))
    pred, square_px = homography_steps(H, xy, target.square)
    with np.errstate(invalid="ignore"):
        return np.linalg.norm(pred - pixels, axis=1) <= CORNER_TOLERANCE * square_px


def find_charuco(gray: GrayImage, target, *, retry: bool = True, contrast: float = 1.0) -> CharucoFound:
    """ChArUco corners seen in an image, checked against the board (module docstring).

    Args:
        gray: the image.
        target: a :class:`jcalib.geometry.targets.Charuco`.
        retry: run the further attempts of :data:`jcalib.vision.attempts.CHARUCO_ATTEMPTS` while
            markers the board predicts inside the image are missing (False: the default attempt only);
            with no marker found, only when the detector rejected at least :data:`MIN_REJECTED_TO_RETRY`
            marker-like candidates or the image's ``contrast`` is below :data:`LOW_CONTRAST`.
        contrast: the image's grey-level spread, 0..1 (:func:`jcalib.vision.image.image_stats`).

    Returns:
        :class:`CharucoFound`; ``ids`` may be empty.
    """
    _, _, index, marker_xy, _ = _board(target)
    found: dict[int, np.ndarray] = {}
    tried: list[str] = []
    contributing: list[str] = []
    dropped: set[int] = set()  # ids of markers found somewhere inconsistent with the board
    level = 0
    while max(gray.size) / 2**level > MARKER_SIDE_PX:
        level += 1
    for attempt in CHARUCO_ATTEMPTS if retry else CHARUCO_ATTEMPTS[:1]:
        tried.append(attempt.name)
        markers, rejected = _detect_markers(prepare(gray.level(level), attempt), target, attempt)
        if attempt is CHARUCO_ATTEMPTS[0] and not markers and rejected < MIN_REJECTED_TO_RETRY and contrast > LOW_CONTRAST:
            break  # no marker and nothing marker-like in a well-exposed image: no board here
        new = {i: c for i, c in _markers_to_full(gray, markers, level).items() if i not in found}
        if new:
            union = {**found, **new}
            keys = list(union)
            ok = consistent_markers(marker_xy[[index[i] for i in keys]], np.stack([union[i] for i in keys]))
            kept = {i: union[i] for i, good in zip(keys, ok) if good}
            dropped |= {i for i in keys if i not in kept}
            if any(i in kept for i in new):
                contributing.append(attempt.name)
            found = kept
        if _all_expected_found(found, target, gray.size):
            break
    dropped_markers = len(dropped - set(found))
    empty = CharucoFound(np.zeros((0,), np.int64), np.zeros((0, 2)), len(found), tuple(tried), tuple(contributing),
                         dropped_markers)  # fmt: skip
    if len(found) < 2:
        return empty
    mids = np.array(list(found), dtype=np.int32).reshape(-1, 1)
    mcorners = tuple(np.asarray(c, dtype=np.float32).reshape(1, 4, 2) for c in found.values())
    corners, ids, _, _ = _charuco_detector(target).detectBoard(gray.u8, markerCorners=mcorners, markerIds=mids)
    if ids is None or corners is None or len(ids) == 0:
        return empty
    ids = ids.reshape(-1).astype(np.int64)
    pixels = _refine(gray, target, ids, corners.reshape(-1, 2).astype(np.float64))
    ok = _check_corners(target, found, ids, pixels)
    order = np.argsort(ids[ok])
    return CharucoFound(ids[ok][order], pixels[ok][order], len(found), tuple(tried), tuple(contributing),
                        dropped_markers, int(np.sum(~ok)))  # fmt: skip


def _local_scales(xy: np.ndarray, pixels: np.ndarray, neighbours: int = LOCAL_NEIGHBOURS) -> np.ndarray:
    """(n,) image length per board length (px/m) at each corner, the smaller of the two board axes:
    from a homography fitted to the corner and its nearest detected neighbours on the board; NaN where
    they are fewer than 5 or collinear.

    Local on purpose: through a wide-angle or fisheye lens one homography of the whole board misstates
    the scale near the rim (by 15 % and more on rendered 180° fisheye views), and a white gap taken too
    wide lets the refinement window reach the marker edges (corners moved by 1-1.5 px, measured).
    """
    n = len(xy)
    if n < 5:
        return np.full(n, np.nan)
    near = np.argsort(np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=-1), axis=1, kind="stable")[:, :neighbours]
    src = xy[near]
    sv = np.linalg.svd(src - src.mean(axis=1, keepdims=True), compute_uv=False)
    H = batched_homographies(src, pixels[near])
    w = np.einsum("bj,bj->b", H[:, 2, :2], xy) + H[:, 2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        p = (np.einsum("bij,bj->bi", H[:, :2, :2], xy) + H[:, :2, 2]) / w[:, None]
        J = (H[:, :2, :2] - p[:, :, None] * H[:, 2:3, :2]) / w[:, None, None]  # d(pixel)/d(board xy)
        out = np.min(np.linalg.norm(J, axis=1), axis=1)
    ok = (sv[:, 1] > 1e-6 * sv[:, 0]) & (np.abs(w) >= 1e-12) & np.isfinite(out)
    return np.where(ok, out, np.nan)


def _refine(gray: GrayImage, target, ids: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """jcalib's sub-pixel step on OpenCV's interpolated corners, where the white gap allows it."""
    if len(ids) < 4:
        return pixels
    # Window: stay inside the white gap between the corner and the neighbouring markers, measured where
    # it is narrowest in the image (local scales: see _local_scales).
    xy = target.points[ids, :2]
    scale = _local_scales(xy, pixels)
    if not np.any(np.isfinite(scale)):
        return pixels
    min_scale = float(np.nanmin(scale))
    gap_m = 0.5 * (target.square - target.marker)
    gap_px = min_scale * gap_m
    # refine_corners' half window is 0.35 * spacing and its smoothing reaches ~window/2 further:
    # both must stay inside the white gap, or marker edges bias the corner. Where the gap is
    # too narrow (small board in the image), OpenCV's own refinement is kept (measured better).
    half = 0.6 * gap_px
    if half >= 3.0:
        spacing = min(half / 0.35, min_scale * target.square)
        refined = refine_corners(gray, pixels, spacing_px=spacing)
        ok = np.linalg.norm(refined - pixels, axis=1) < 2.0
        pixels = np.where(ok[:, None], refined, pixels)
    return pixels
