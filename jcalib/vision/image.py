"""Image loading and normalisation for detection, and the sharpness measure used to explain failures."""

from __future__ import annotations

import os
from dataclasses import dataclass

import cv2
import numpy as np

from jcalib.errors import BadInputError, DetectionError

__all__ = ["GrayImage", "load_image", "to_gray", "image_stats"]


@dataclass(frozen=True)
class GrayImage:
    """A grey image prepared for the detectors.

    Attributes:
        u8: (H, W) uint8, what OpenCV's pattern finders take (16-bit input is scaled, not clipped).
        f32: (H, W) float32 on the same 0..255 scale, full precision (used for sub-pixel refinement).
        name: the file path, or ``"<array>"``, used in messages.
    """

    u8: np.ndarray
    f32: np.ndarray
    name: str

    @property
    def size(self) -> tuple[int, int]:
        """(width, height), px."""
        return (int(self.u8.shape[1]), int(self.u8.shape[0]))


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file unchanged (8- or 16-bit, grey or colour in OpenCV's BGR order).

    Raises:
        DetectionError: reason ``"unreadable"`` when the file is missing or not an image.
    """
    name = os.fspath(path)
    image = cv2.imread(name, cv2.IMREAD_UNCHANGED) if os.path.isfile(name) else None
    if image is None:
        raise DetectionError(f"{name}: cannot read the image (missing file or not an image format OpenCV reads)", "unreadable")
    return image


def to_gray(image, name: str = "<array>") -> GrayImage:
    """Convert an 8-bit or 16-bit grey / BGR / BGRA image (or a float image in [0, 1]) for detection.

    Args:
        image: (H, W), (H, W, 1), (H, W, 3) or (H, W, 4) array; colour in OpenCV's BGR order.
        name: how messages refer to the image.

    Raises:
        BadInputError: wrong shape or dtype (the message names ``image``).
    """
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)) or min(a.shape[:2]) < 8:
        raise BadInputError(
            f"{name}: argument 'image' has shape {a.shape}, expected (H, W), (H, W, 3) or (H, W, 4) with H, W >= 8"
        )
    if a.dtype == np.uint8:
        f = a.astype(np.float32)
    elif a.dtype == np.uint16:
        f = a.astype(np.float32) * np.float32(255.0 / 65535.0)
    elif a.dtype in (np.float32, np.float64) and np.all(np.isfinite(a)):
        f = np.clip(a, 0.0, 1.0).astype(np.float32) * np.float32(255.0)
    else:
        raise BadInputError(
            f"{name}: argument 'image' has dtype {a.dtype}, expected uint8, uint16 or finite float in [0, 1]"
        )
    if f.ndim == 3:
        f = cv2.cvtColor(f, cv2.COLOR_BGR2GRAY if f.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if a.dtype == np.uint16:
        # A 12-bit camera in a 16-bit container uses a fraction of the range: stretch it robustly.
        lo, hi = np.percentile(f, [0.1, 99.9])
        if hi - lo > 1e-3:
            f = np.clip((f - lo) * np.float32(255.0 / (hi - lo)), 0.0, 255.0).astype(np.float32)
    u8 = np.clip(np.round(f), 0, 255).astype(np.uint8)
    return GrayImage(u8=u8, f32=np.ascontiguousarray(f, dtype=np.float32), name=name)


def image_stats(gray: GrayImage) -> tuple[float, float]:
    """Contrast and edge width of an image, to tell "nothing there" from "too blurred".

    Contrast is the spread between the 0.5 % and 99.5 % grey levels of the (slightly smoothed)
    image, on a 0..1 scale. Edge width is contrast divided by the steepest gradients (99.9th
    percentile of the gradient magnitude, per pixel): about 1 px for a focused step edge and
    ``sqrt(2 pi) * sigma`` ≈ 2.5 sigma px for a Gaussian blur of ``sigma`` px.

    Returns:
        (contrast, edge_width_px); edge width is ``inf`` for a flat image.
    """
    f = cv2.GaussianBlur(gray.f32, (0, 0), 0.7) / np.float32(255.0)
    lo, hi = np.percentile(f, [0.5, 99.5])
    contrast = float(hi - lo)
    gx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3) / np.float32(8.0)
    gy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3) / np.float32(8.0)
    g = float(np.percentile(np.hypot(gx, gy), 99.9))
    # The 0.7 px pre-smoothing widens a focused edge slightly; the Sobel kernel averages 3 rows.
    width = contrast / g if g > 1e-6 else float("inf")
    return contrast, width
