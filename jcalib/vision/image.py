"""Image loading and normalisation for detection, and the sharpness measure used to explain failures."""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass

import cv2
import numpy as np

from jcalib.errors import BadInputError, DetectionError

__all__ = ["GrayImage", "image_header_size", "load_image", "max_image_pixels", "to_gray", "image_stats"]


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


def max_image_pixels() -> int:
    """The pixel budget of one image (``JCALIB_MAX_IMAGE_MP`` megapixels, default 200)."""
    raw = os.environ.get("JCALIB_MAX_IMAGE_MP", "")
    try:
        mp = float(raw) if raw else 200.0
    except ValueError:
        raise BadInputError(f"JCALIB_MAX_IMAGE_MP: expected a number of megapixels, got {raw!r}") from None
    return int(mp * 1e6)


_PIL_LOCK = threading.Lock()


def image_header_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """``(width, height)`` from the file's header without decoding the pixels (Pillow), or None
    when Pillow does not know the format."""
    from PIL import Image

    with _PIL_LOCK:  # Pillow's own bomb limit is lifted while reading a header: the budget is ours
        old, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
        try:
            with Image.open(path) as im:
                return int(im.size[0]), int(im.size[1])
        except Exception:  # noqa: BLE001 - unknown format: OpenCV decides (within its own limit)
            return None
        finally:
            Image.MAX_IMAGE_PIXELS = old


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file unchanged (8- or 16-bit, grey or colour in OpenCV's BGR order).

    Raises:
        DetectionError: reason ``"unreadable"`` when the file is missing, not an image, or holds
            more pixels than :func:`max_image_pixels` (checked from the header, before decoding).
    """
    name = os.fspath(path)
    size = image_header_size(name) if os.path.isfile(name) else None
    budget = max_image_pixels()
    if size is not None and size[0] * size[1] > budget:
        raise DetectionError(
            f"{name}: the image is {size[0]}x{size[1]} px ({size[0] * size[1] / 1e6:.0f} Mpx), more than the "
            f"{budget / 1e6:.0f} Mpx jcalib decodes (set JCALIB_MAX_IMAGE_MP to raise the budget)", "unreadable")
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
