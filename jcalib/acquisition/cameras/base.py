"""The camera interface every driver implements (GigE Vision, simulated, replay).

Features use GenICam SFNC names; a driver maps them to what its device has (e.g. the Aravis fake and
many older GigE cameras have ``ExposureTimeAbs`` / ``GainRaw`` instead of ``ExposureTime`` / ``Gain``).
A feature the device lacks raises :class:`UnsupportedFeatureError` naming it and what the device has.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from jcalib.errors import DeviceError

#: Standard names -> device names tried in order. Units: ExposureTime in microseconds (SFNC).
FEATURE_ALIASES: dict[str, tuple[str, ...]] = {
    "ExposureTime": ("ExposureTime", "ExposureTimeAbs", "ExposureTimeRaw"),
    "Gain": ("Gain", "GainAbs", "GainRaw"),
    "PixelFormat": ("PixelFormat",),
    "Width": ("Width",),
    "Height": ("Height",),
    "OffsetX": ("OffsetX",),
    "OffsetY": ("OffsetY",),
    "PacketSize": ("GevSCPSPacketSize",),
    "Zoom": ("Zoom", "ZoomPosition", "LensZoom"),
    "Focus": ("Focus", "FocusPosition", "FocusPos", "LensFocus"),
    "Iris": ("Iris", "IrisPosition", "LensIris"),
}


class UnsupportedFeatureError(DeviceError):
    """The camera has no such feature (e.g. zoom on a fixed-lens camera)."""


@dataclass(frozen=True)
class FrameRequest:
    """What a frame source is asked to render (also the fake camera's current settings).

    Attributes:
        width, height: image size in pixels (the region of interest).
        offset_x, offset_y: top-left pixel of the region on the sensor.
        pixel_format: GenICam pixel format name ("Mono8", "Mono16", "RGB8", ...).
        exposure_us: exposure time, microseconds.
        gain: device gain value (device units).
        index: running number of frames served by this camera.
        lens: lens feature -> current value (``Zoom``, ``Focus`` in motor steps) of a camera with a
            motorised lens; empty otherwise.
    """

    width: int
    height: int
    offset_x: int = 0
    offset_y: int = 0
    pixel_format: str = "Mono8"
    exposure_us: float = 10000.0
    gain: float = 0.0
    index: int = 0
    lens: Mapping[str, float] = field(default_factory=dict)


#: A frame source renders the scene as seen now: ``source(request) -> image``. The image is either the
#: full sensor (the camera crops the region) or exactly ``(height, width)``; uint8 / uint16, or float in
#: [0, 1]; (H, W) gray or (H, W, 3) RGB.
FrameSource = Callable[[FrameRequest], np.ndarray]


@dataclass(frozen=True)
class Frame:
    """One complete image.

    Attributes:
        image: (H, W) or (H, W, 3) uint8 / uint16 pixels, row 0 at the top (OpenCV layout).
        frame_id: the device's frame counter.
        timestamp_ns: host time the frame arrived, ns since the epoch.
        pixel_format: GenICam pixel format name.
    """

    image: np.ndarray
    frame_id: int
    timestamp_ns: int
    pixel_format: str


@dataclass
class GrabStats:
    """Counters of a camera's grabs: complete frames, incomplete ones discarded, timeouts, retries."""

    frames: int = 0
    incomplete: int = 0
    timeouts: int = 0
    retries: int = 0
    missing_packets: int = 0
    history: list[str] = field(default_factory=list)


class Camera(abc.ABC):
    """A camera opened by address. Subclasses implement the device access.

    ``grab()`` triggers (software trigger) and returns the next complete frame, discarding and counting
    incomplete ones (missing packets) and retrying up to ``max_retries`` times; it never returns a
    partial image.
    """

    name: str = "cam"
    address: str = "?"
    max_retries: int = 3

    def __init__(self) -> None:
        self.stats = GrabStats()

    @abc.abstractmethod
    def device_feature_names(self) -> list[str]:
        """Names of the device features that exist (device names, not aliases)."""

    @abc.abstractmethod
    def _get(self, device_name: str) -> Any: ...

    @abc.abstractmethod
    def _set(self, device_name: str, value: Any) -> None: ...

    def resolve(self, feature: str) -> str:
        """Device name of a standard (or device) feature name.

        Raises:
            UnsupportedFeatureError: the device has none of the names for it.
        """
        names = self.device_feature_names()
        for cand in FEATURE_ALIASES.get(feature, (feature,)):
            if cand in names:
                return cand
        tried = ", ".join(FEATURE_ALIASES.get(feature, (feature,)))
        raise UnsupportedFeatureError(
            f"camera {self.name} at {self.address} does not support {feature!r} (device names tried: {tried}); "
            f"supported: {', '.join(sorted(k for k in FEATURE_ALIASES if self.has(k)))}"
        )

    def has(self, feature: str) -> bool:
        """True when the device has the feature (standard or device name)."""
        names = self.device_feature_names()
        return any(c in names for c in FEATURE_ALIASES.get(feature, (feature,)))

    def get(self, feature: str) -> Any:
        """Current value of a feature (int, float or str)."""
        return self._get(self.resolve(feature))

    def set(self, feature: str, value: Any) -> None:
        """Set a feature. Raises UnsupportedFeatureError, or DeviceError when the device refuses the value."""
        self._set(self.resolve(feature), value)

    def set_roi(self, offset_x: int, offset_y: int, width: int, height: int) -> None:
        """Region of interest in sensor pixels."""
        self.set("OffsetX", 0)
        self.set("OffsetY", 0)
        self.set("Width", int(width))
        self.set("Height", int(height))
        self.set("OffsetX", int(offset_x))
        self.set("OffsetY", int(offset_y))

    @abc.abstractmethod
    def grab(self, timeout_s: float = 2.0) -> Frame:
        """Software-trigger and return the next complete frame (see class docstring)."""

    def close(self) -> None:
        """Release the device (idempotent)."""

    def __enter__(self) -> "Camera":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def to_pixels(image: np.ndarray, pixel_format: str) -> np.ndarray:
    """Convert a frame source's image to the layout of ``pixel_format`` (uint8 / uint16 array)."""
    img = np.asarray(image)
    if img.dtype.kind == "f":
        hi = 65535.0 if pixel_format == "Mono16" else 255.0
        img = np.clip(np.round(img * hi), 0, hi).astype(np.uint16 if hi > 255 else np.uint8)
    if pixel_format == "RGB8":
        if img.ndim == 2:
            img = np.repeat(img[:, :, None], 3, axis=2)
        return img.astype(np.uint8) if img.dtype != np.uint8 else img
    if img.ndim == 3:  # colour source, gray camera: ITU-R BT.601 luma
        img = (img.astype(np.float64) @ np.array([0.299, 0.587, 0.114])).round().astype(img.dtype)
    if pixel_format == "Mono16":
        return img.astype(np.uint16) * 257 if img.dtype == np.uint8 else img.astype(np.uint16)
    return (img >> 8).astype(np.uint8) if img.dtype == np.uint16 else img.astype(np.uint8)
