"""Image loading and normalisation for detection, and the sharpness measure used to explain failures."""

from __future__ import annotations

import os

import cv2
import numpy as np

from jcalib.errors import BadInputError, DetectionError
from jcalib.vision.image_header import FORMATS, ImageHeader, read_image_header

__all__ = ["GrayImage", "check_image_header", "detection_memory_bytes", "from_level", "image_header_size", "image_notes",
           "image_stats", "load_image", "max_image_bytes", "max_image_pixels", "mosaic", "read_image", "to_gray",
           "to_level"]


class GrayImage:
    """A grey image prepared for the detectors, with its pyramid.

    Attributes:
        u8: (H, W) uint8, what OpenCV's pattern finders take (16-bit input is scaled, not clipped).
        f32: (H, W) float32 on the same 0..255 scale, full precision (used for sub-pixel refinement);
            made from ``u8`` on first use when not given (8-bit input).
        name: the file path, or ``"<array>"``, used in messages.
    """

    __slots__ = ("u8", "name", "_f32", "_levels")

    def __init__(self, u8: np.ndarray, f32: np.ndarray | None = None, name: str = "<array>"):
        self.u8 = u8
        self.name = name
        self._f32 = f32
        self._levels = [u8]

    @property
    def f32(self) -> np.ndarray:
        if self._f32 is None:
            self._f32 = self.u8.astype(np.float32)
        return self._f32

    @property
    def size(self) -> tuple[int, int]:
        """(width, height), px."""
        return (int(self.u8.shape[1]), int(self.u8.shape[0]))

    def level(self, k: int) -> np.ndarray:
        """The uint8 image reduced ``2**k`` times (area average of 2x2 blocks per step; cached).

        Pixel ``(u, v)`` of level ``k`` covers full-resolution pixels whose centres map to it by
        :func:`to_level` (a trailing odd row or column is dropped)."""
        while len(self._levels) <= k:
            prev = self._levels[-1]
            h, w = prev.shape
            self._levels.append(cv2.resize(prev[: h - h % 2, : w - w % 2], (w // 2, h // 2), interpolation=cv2.INTER_AREA))
        return self._levels[k]

    def tiles(self, centres: np.ndarray, half: int) -> np.ndarray:
        """(N, 2 half + 1, 2 half + 1) float32 windows around integer pixel ``centres`` (N, 2) (x, y),
        the image's border pixels repeated outside it."""
        c = np.asarray(centres, np.int64).reshape(-1, 2)
        h, w = self.u8.shape
        d = np.arange(-half, half + 1)
        xs = np.clip(c[:, 0:1] + d[None], 0, w - 1)
        ys = np.clip(c[:, 1:2] + d[None], 0, h - 1)
        src = self._f32 if self._f32 is not None else self.u8
        return src[ys[:, :, None], xs[:, None, :]].astype(np.float32)

    def sample(self, points: np.ndarray) -> np.ndarray:
        """(N,) float64 grey values at float pixel positions (bilinear; clamped to the image)."""
        p = np.asarray(points, np.float64).reshape(-1, 2)
        h, w = self.u8.shape
        x = np.clip(p[:, 0], 0.0, w - 1.000001)
        y = np.clip(p[:, 1], 0.0, h - 1.000001)
        x0, y0 = np.floor(x).astype(np.intp), np.floor(y).astype(np.intp)
        fx, fy = x - x0, y - y0
        src = self._f32 if self._f32 is not None else self.u8
        a, b = src[y0, x0].astype(np.float64), src[y0, x0 + 1].astype(np.float64)
        c, d = src[y0 + 1, x0].astype(np.float64), src[y0 + 1, x0 + 1].astype(np.float64)
        return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy

    def f32_patch(self, x0: int, y0: int, x1: int, y1: int) -> tuple[np.ndarray, int, int]:
        """The float image over ``[x0, x1) x [y0, y1)`` clipped to the image, and its clipped origin."""
        h, w = self.u8.shape
        x0, y0 = max(0, int(x0)), max(0, int(y0))
        x1, y1 = min(w, int(x1)), min(h, int(y1))
        src = self._f32 if self._f32 is not None else self.u8
        return src[y0:y1, x0:x1].astype(np.float32, copy=self._f32 is None), x0, y0


def mosaic(tiles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Windows (N, T, T) laid side by side in one image (filters run once over all of them).

    Returns:
        ``(image, origins)``: the (rows * T, cols * T) float32 mosaic and (N, 2) the mosaic pixel
        (x, y) of each window's pixel (0, 0).
    """
    n, t, _ = tiles.shape
    cols = int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / cols))
    grid = np.zeros((rows * cols, t, t), np.float32)
    grid[:n] = tiles
    image = grid.reshape(rows, cols, t, t).transpose(0, 2, 1, 3).reshape(rows * t, cols * t)
    k = np.arange(n)
    return np.ascontiguousarray(image), np.stack([(k % cols) * t, (k // cols) * t], axis=1)


def to_level(points: np.ndarray, k: int) -> np.ndarray:
    """Full-resolution pixels -> pixels of pyramid level ``k`` (OpenCV pixel-centre convention)."""
    return (np.asarray(points, np.float64) + 0.5) / (2.0**k) - 0.5


def from_level(points: np.ndarray, k: int) -> np.ndarray:
    """Pixels of pyramid level ``k`` -> full-resolution pixels."""
    return (np.asarray(points, np.float64) + 0.5) * (2.0**k) - 0.5


def max_image_pixels() -> int:
    """The pixel budget of one image (``JCALIB_MAX_IMAGE_MP`` megapixels, default 200)."""
    return int(_budget("JCALIB_MAX_IMAGE_MP", 200.0, "megapixels") * 1e6)


def max_image_bytes() -> int:
    """The memory budget of one image's decoding and detection (``JCALIB_MAX_IMAGE_MB`` MiB, default 4096),
    per process: ``--jobs N`` may use N times as much."""
    return int(_budget("JCALIB_MAX_IMAGE_MB", 4096.0, "MiB") * 2**20)


def _budget(variable: str, default: float, unit: str) -> float:
    raw = os.environ.get(variable, "")
    try:
        value = float(raw) if raw else default
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise BadInputError(f"{variable}: expected a positive number of {unit}, got {raw!r}")
    return value


#: Bytes per pixel that detection needs beyond the grey images: the pyramid and the finders' working
#: copies (measured on blank and noise images with every target type, with margin:
#: benchmarks/bench_image_fuzz.py).
WORK_BYTES_PER_PX = 4
#: Copies of the decoded array OpenCV's decoder holds at its peak (measured with OpenCV 4.14: it decodes,
#: then copies; WebP and GIF decode to four channels first, OpenJPEG to 32-bit samples).
DECODE_COPIES = {"JPEG 2000": 6, "GIF": 4, "WebP": 3}


def detection_memory_bytes(header: ImageHeader) -> int:
    """Peak memory (bytes) of decoding an image and detecting in it, from its header.

    The largest of three stages: the decoder (:data:`DECODE_COPIES` of the decoded array, 2 by default),
    the grey conversion (the decoded array, the uint8 grey image and, for any input but 8-bit grey, its
    float32 copy, plus the 16-bit range stretch's copy) and the detection (the grey images and
    :data:`WORK_BYTES_PER_PX`)."""
    px = header.pixels
    gray = px * (1 if header.channels == 1 and header.bytes_per_sample == 1 else 5)
    stretch = 4 * px if header.bytes_per_sample == 2 else 0
    decode = DECODE_COPIES.get(header.format, 2) * header.decoded_bytes
    return max(decode, header.decoded_bytes + gray + stretch, gray + WORK_BYTES_PER_PX * px)


def image_header_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """``(width, height)`` from the file's header without decoding the pixels, or None when the file is
    not an image OpenCV reads or its header is damaged (:func:`jcalib.vision.image_header.read_image_header`)."""
    try:
        header = read_image_header(path)
    except DetectionError:
        return None
    return None if header is None else (header.width, header.height)


def check_image_header(path: str | os.PathLike) -> ImageHeader:
    """The image's header, within the pixel and memory budgets: what :func:`load_image` checks before decoding.

    Raises:
        DetectionError: reason ``"unreadable"``: missing, not a regular file, not an image format OpenCV
            reads, a damaged header, or over :func:`max_image_pixels` or :func:`max_image_bytes`.
    """
    name = os.fspath(path)
    if not os.path.isfile(name):
        what = "does not exist" if not os.path.lexists(name) else "is not a regular file"
        raise DetectionError(f"{name}: cannot read the image (the path {what})", "unreadable")
    header = read_image_header(name)
    if header is None:
        raise DetectionError(f"{name}: not an image format jcalib reads ({', '.join(FORMATS)})", "unreadable")
    budget = max_image_pixels()
    size = f"{header.width}x{header.height} px"
    if header.pixels > budget:
        raise DetectionError(
            f"{name}: the image is {size} ({header.pixels / 1e6:.0f} Mpx), more than the {budget / 1e6:.0f} Mpx "
            "jcalib decodes (set JCALIB_MAX_IMAGE_MP to raise the budget)", "unreadable")
    need, memory = detection_memory_bytes(header), max_image_bytes()
    if need > memory:
        depth = f"{header.channels} channel(s) of {8 * header.bytes_per_sample} bits"
        raise DetectionError(
            f"{name}: the {header.format} image ({size}, {depth}) needs about {need / 2**20:.0f} MiB to decode and "
            f"detect in, more than the {memory / 2**20:.0f} MiB budget of one image (set JCALIB_MAX_IMAGE_MB to "
            "raise it, or save the image in grey or 8 bits)", "unreadable")
    return header


def image_notes(header: ImageHeader) -> tuple[str, ...]:
    """What the file's header holds that the decoded pixels leave out: later pages or frames, an EXIF
    orientation (not applied: the pixels are used in the order the sensor stored them)."""
    notes = []
    if header.pages != 1:
        count = "several frames" if header.pages is None else f"{header.pages} pages or frames"
        notes.append(f"the {header.format} file holds {count}; only the first is read (save each view as its "
                     "own file)")
    if header.orientation != 1:
        notes.append(f"EXIF orientation {header.orientation} ({_ORIENTATIONS.get(header.orientation, 'unknown')}) "
                     "is not applied: the pixels are used as stored, in the sensor's frame (all images of a "
                     "camera must be stored alike)")
    return tuple(notes)


_ORIENTATIONS = {2: "mirrored", 3: "turned 180°", 4: "flipped", 5: "mirrored and turned 90°", 6: "turned 90°",
                 7: "mirrored and turned 270°", 8: "turned 270°"}


def read_image(path: str | os.PathLike) -> tuple[np.ndarray, ImageHeader]:
    """Read an image file unchanged, and its header (:func:`check_image_header` first, so the budgets hold
    before anything is decoded).

    Returns:
        ``(image, header)``: (H, W[, C]) uint8 / uint16 / float32 array, colour in OpenCV's BGR order.

    Raises:
        DetectionError: reason ``"unreadable"`` (:func:`check_image_header`), or OpenCV cannot decode it.
    """
    name = os.fspath(path)
    header = check_image_header(name)
    image = cv2.imread(name, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise DetectionError(f"{name}: cannot decode the {header.format} image (damaged or an unsupported "
                             "variant)", "unreadable")
    if (image.shape[1], image.shape[0]) != (header.width, header.height):
        raise DetectionError(f"{name}: the decoded image is {image.shape[1]}x{image.shape[0]} px but its header "
                             f"says {header.width}x{header.height} px (a damaged file)", "unreadable")
    return image, header


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file unchanged (8- or 16-bit, grey or colour in OpenCV's BGR order).

    Raises:
        DetectionError: reason ``"unreadable"`` when the file is missing, not an image, or needs more
            than :func:`max_image_pixels` or :func:`max_image_bytes` (checked from the header, before
            decoding: :func:`check_image_header`).
    """
    return read_image(path)[0]


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
    if a.dtype == np.uint8 and a.ndim == 2:  # the common case: no float copy until one is needed
        return GrayImage(u8=np.ascontiguousarray(a), name=name)
    bad_dtype = BadInputError(
        f"{name}: argument 'image' has dtype {a.dtype}, expected uint8, uint16 or finite float in [0, 1]")
    if a.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        raise bad_dtype
    # converted in bands of rows: the float copies of a colour image never exist whole
    h, w = a.shape[:2]
    rows = max(1, CONVERT_PIXELS // w)
    f = np.empty((h, w), np.float32)
    for y in range(0, h, rows):
        band = a[y:y + rows]
        if a.dtype == np.uint8:
            g = band.astype(np.float32)
        elif a.dtype == np.uint16:
            g = band.astype(np.float32) * np.float32(255.0 / 65535.0)
        elif np.all(np.isfinite(band)):
            g = np.clip(band, 0.0, 1.0).astype(np.float32) * np.float32(255.0)
        else:
            raise bad_dtype
        f[y:y + rows] = cv2.cvtColor(g, cv2.COLOR_BGR2GRAY if g.shape[2] == 3 else cv2.COLOR_BGRA2GRAY) if g.ndim == 3 else g
    if a.dtype == np.uint16:
        # A 12-bit camera in a 16-bit container uses a fraction of the range: stretch it robustly.
        lo, hi = np.percentile(f, [0.1, 99.9])
        if hi - lo > 1e-3:
            for y in range(0, h, rows):
                f[y:y + rows] = np.clip((f[y:y + rows] - lo) * np.float32(255.0 / (hi - lo)), 0.0, 255.0)
    u8 = np.empty((h, w), np.uint8)
    for y in range(0, h, rows):
        u8[y:y + rows] = np.clip(np.round(f[y:y + rows]), 0, 255)
    return GrayImage(u8=u8, f32=f, name=name)


#: Pixels :func:`to_gray` converts at a time (bands of rows): its float temporaries stay this small.
CONVERT_PIXELS = 1 << 20


#: Pixels :func:`image_stats` looks at: larger images are sampled in bands of rows.
STATS_PIXELS = 1_000_000
_BAND_ROWS = 24


def _stats_bands(gray: GrayImage) -> list[np.ndarray]:
    h, w = gray.u8.shape
    if h * w <= STATS_PIXELS or h <= 2 * _BAND_ROWS:
        return [gray.f32 if gray._f32 is not None else gray.u8]
    n = max(1, int(STATS_PIXELS // (w * _BAND_ROWS)))
    starts = np.linspace(0, h - _BAND_ROWS, n).astype(int)
    return [gray.f32_patch(0, y, w, y + _BAND_ROWS)[0] for y in starts]


def _histogram_percentiles(hist: np.ndarray, q: tuple[float, ...]) -> list[float]:
    """Percentiles (in bins, interpolated within a bin) of a 256-bin grey histogram."""
    c = np.cumsum(hist, dtype=np.float64)
    c /= c[-1]
    out = []
    for p in q:
        i = int(np.searchsorted(c, p / 100.0))
        below = c[i - 1] if i > 0 else 0.0
        out.append(i - 0.5 + min(max((p / 100.0 - below) / max(c[i] - below, 1e-12), 0.0), 1.0))
    return out


def image_stats(gray: GrayImage) -> tuple[float, float]:
    """Contrast and edge width of an image, to tell "nothing there" from "too blurred".

    Contrast is the spread between the 0.5 % and 99.5 % grey levels of the (slightly smoothed)
    image, on a 0..1 scale. Edge width is contrast divided by the steepest gradients (99.9th
    percentile of the gradient magnitude, per pixel): about 1 px for a focused step edge and
    ``sqrt(2 pi) * sigma`` ≈ 2.5 sigma px for a Gaussian blur of ``sigma`` px. The grey levels are
    counted in a 256-bin histogram (interpolated within a bin); an image over :data:`STATS_PIXELS` is
    sampled in bands of rows spread over its height.

    Returns:
        (contrast, edge_width_px); edge width is ``inf`` for a flat image.
    """
    grey_hist = np.zeros(256)
    grads = []
    for band in _stats_bands(gray):
        f = cv2.GaussianBlur(band.astype(np.float32, copy=False), (0, 0), 0.7)
        grey_hist += cv2.calcHist([cv2.convertScaleAbs(f)], [0], None, [256], [0, 256]).ravel()
        gx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3)
        grads.append(cv2.magnitude(gx, gy)[1:-1, 1:-1].ravel())
    lo, hi = _histogram_percentiles(grey_hist, (0.5, 99.5))
    contrast = float(hi - lo) / 255.0
    g = np.concatenate(grads) if len(grads) > 1 else grads[0]
    k = int(0.999 * (len(g) - 1))
    top = float(np.partition(g, k)[k]) / (8.0 * 255.0)
    # The 0.7 px pre-smoothing widens a focused edge slightly; the Sobel kernel averages 3 rows.
    width = contrast / top if top > 1e-6 else float("inf")
    return contrast, width
