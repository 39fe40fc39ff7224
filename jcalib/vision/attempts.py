"""Detection attempts: how the image is prepared and the finder tuned when the default finds too little.

Each attempt is one way of looking at the image again, aimed at one cause of a missed board:

- ``default``: the finders as they come (OpenCV's parameters; jcalib's sub-pixel refinement);
- ``refine_markers`` (ChArUco): OpenCV's board-guided recovery of rejected marker candidates
  (``refineDetectedMarkers``): markers whose border or bits were marginal, next to found ones;
- ``adaptive_windows``: adaptive-threshold windows from 3 to 53 px (defaults 3-23) and a lower
  threshold offset, smaller markers and rougher outlines accepted: large, small or low-contrast markers;
- ``clahe``: contrast-limited adaptive histogram equalisation (``cv2.createCLAHE``, 8x8 tiles): glare,
  shadows, vignetting, low contrast;
- ``upscale_2x``: the image enlarged twice (bicubic): markers or squares of a few pixels;
- ``downscale_2x``: the image reduced by half (area average): defocus and noise shrink with it,
  so a blurred board looks sharp to the finder;
- ``smooth``: a Gaussian of σ = 1.5 px: sensor noise that breaks the finders' thresholds.

Where the attempts look: chessboards, on the region the X-junction locator found, reduced to the level
where its squares are a few pixels wide (:mod:`jcalib.vision.chessboard`: ``default`` is there the fast
pass and that region, the others run only when the image plausibly holds a board that is not cut by the
image border); ChArUco markers and circle grids, on the image (reduced when it is larger than 2000 px),
the retries only when a marker, a marker-like candidate or a lattice of blobs says a board is there.

Whatever an attempt finds is mapped back to the original pixels and refined there, so the accuracy of
a point does not depend on the attempt that found it; and it is checked against the board model
(:mod:`jcalib.vision.validate`, and the chessboard checks) before it is kept, by every attempt alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["Attempt", "CHARUCO_ATTEMPTS", "CIRCLE_ATTEMPTS", "GRID_ATTEMPTS", "prepare", "to_original"]


@dataclass(frozen=True)
class Attempt:
    """One way of looking at an image (see the module docstring).

    Attributes:
        name: how detections and messages refer to it.
        scale: resize factor applied before the finder (2 = enlarge, 0.5 = reduce).
        clahe: equalise the contrast locally first.
        smooth_sigma_px: Gaussian pre-smoothing, px (0 = none).
        wide_thresholds: ArUco: wider adaptive-threshold windows and looser candidate filters.
        refine_markers: ArUco: recover rejected candidates where the board predicts a marker.
    """

    name: str
    scale: float = 1.0
    clahe: bool = False
    smooth_sigma_px: float = 0.0
    wide_thresholds: bool = False
    refine_markers: bool = False


DEFAULT = Attempt("default")
CHARUCO_ATTEMPTS = (
    DEFAULT,
    Attempt("refine_markers", refine_markers=True),
    Attempt("adaptive_windows", wide_thresholds=True, refine_markers=True),
    Attempt("clahe", clahe=True, wide_thresholds=True, refine_markers=True),
    Attempt("upscale_2x", scale=2.0, wide_thresholds=True, refine_markers=True),
    Attempt("downscale_2x", scale=0.5, refine_markers=True),
    Attempt("smooth", smooth_sigma_px=1.5, wide_thresholds=True, refine_markers=True),
)
GRID_ATTEMPTS = (
    DEFAULT,
    Attempt("clahe", clahe=True),
    Attempt("downscale_2x", scale=0.5),
    Attempt("smooth", smooth_sigma_px=1.5),
    Attempt("upscale_2x", scale=2.0),
    Attempt("clahe+downscale_2x", clahe=True, scale=0.5),
)
#: Circle grids have no sub-pixel step on the original image: their centres are the blob centroids of
#: the prepared image, which CLAHE and reduction bias (measured: 0.8 px mean error on a blurred grid
#: found after CLAHE). Only preparations that keep a centroid where it is are tried.
CIRCLE_ATTEMPTS = (
    DEFAULT,
    Attempt("smooth", smooth_sigma_px=1.5),
    Attempt("upscale_2x", scale=2.0),
)


def prepare(u8: np.ndarray, attempt: Attempt) -> np.ndarray:
    """The (H', W') uint8 image an attempt's finder sees."""
    img = u8
    if attempt.smooth_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), attempt.smooth_sigma_px)
    if attempt.clahe:
        img = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(8, 8)).apply(img)
    if attempt.scale != 1.0:
        interp = cv2.INTER_CUBIC if attempt.scale > 1.0 else cv2.INTER_AREA
        img = cv2.resize(img, None, fx=attempt.scale, fy=attempt.scale, interpolation=interp)
    return np.ascontiguousarray(img)


def to_original(points: np.ndarray, attempt: Attempt) -> np.ndarray:
    """Points found in :func:`prepare`'s image -> pixels of the original (OpenCV pixel-centre convention)."""
    p = np.asarray(points, dtype=np.float64)
    if attempt.scale == 1.0:
        return p
    return (p + 0.5) / attempt.scale - 0.5


def aruco_parameters(attempt: Attempt) -> cv2.aruco.DetectorParameters:
    """OpenCV's ArUco detector parameters for an attempt (sub-pixel marker corners always)."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    if attempt.wide_thresholds:
        params.adaptiveThreshWinSizeMin = 3
        params.adaptiveThreshWinSizeMax = 53
        params.adaptiveThreshWinSizeStep = 10
        params.adaptiveThreshConstant = 5.0
        params.minMarkerPerimeterRate = 0.01
        params.polygonalApproxAccuracyRate = 0.05
    return params
