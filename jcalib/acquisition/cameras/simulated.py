"""In-process cameras without a network: a frame-source camera and a replay camera (images from a folder)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.acquisition.cameras.base import Camera, Frame, FrameRequest, FrameSource, to_pixels
from jcalib.errors import BadInputError, DeviceError


class SimulatedCamera(Camera):
    """A camera that renders ``frame_source`` directly (no GigE): for notebooks, benchmarks and tests.

    Args:
        frame_source: ``source(FrameRequest) -> image`` (full sensor or region).
        name: camera id.
        sensor_size: ``(width, height)`` in pixels.
        fail_grabs: this many next grabs raise DeviceError (fault injection; settable later).
    """

    def __init__(
        self, frame_source: FrameSource, *, name: str = "cam", sensor_size: tuple[int, int] = (640, 480),
        fail_grabs: int = 0,
    ) -> None:  # fmt: skip
        super().__init__()
        self.frame_source, self.name = frame_source, name
        self.address = f"sim://{name}"
        self.sensor_size = (int(sensor_size[0]), int(sensor_size[1]))
        w, h = self.sensor_size
        self._values: dict[str, Any] = {
            "Width": w, "Height": h, "OffsetX": 0, "OffsetY": 0, "PixelFormat": "Mono8",
            "ExposureTime": 10000.0, "Gain": 0.0,
        }  # fmt: skip
        self.fail_grabs = int(fail_grabs)

    def device_feature_names(self) -> list[str]:
        return sorted(self._values)

    def _get(self, device_name: str) -> Any:
        return self._values[device_name]

    def _set(self, device_name: str, value: Any) -> None:
        w, h = self.sensor_size
        limits = {"Width": (1, w), "Height": (1, h), "OffsetX": (0, w - 1), "OffsetY": (0, h - 1)}
        if device_name in limits:
            lo, hi = limits[device_name]
            if not lo <= int(value) <= hi:
                raise BadInputError(f"camera {self.name}: {device_name} must be in {lo}..{hi}, got {value!r}")
            value = int(value)
        if device_name == "PixelFormat" and value not in ("Mono8", "Mono16", "RGB8"):
            raise DeviceError(f"camera {self.name} refused PixelFormat = {value!r} (has Mono8, Mono16, RGB8)")
        self._values[device_name] = value

    def grab(self, timeout_s: float = 2.0) -> Frame:
        if self.fail_grabs > 0:
            self.fail_grabs -= 1
            self.stats.timeouts += 1
            raise DeviceError(f"camera {self.name} at {self.address}: no frame within {timeout_s} s (injected)")
        v = self._values
        x, y, w, h = v["OffsetX"], v["OffsetY"], v["Width"], v["Height"]
        if x + w > self.sensor_size[0] or y + h > self.sensor_size[1]:
            raise DeviceError(f"camera {self.name}: region {x},{y} {w}x{h} exceeds the sensor {self.sensor_size}")
        req = FrameRequest(w, h, x, y, v["PixelFormat"], float(v["ExposureTime"]), float(v["Gain"]), self.stats.frames)
        img = np.asarray(self.frame_source(req))
        if img.shape[:2] != (h, w):
            img = img[y : y + h, x : x + w]
        self.stats.frames += 1
        return Frame(to_pixels(img, v["PixelFormat"]), self.stats.frames, time.time_ns(), v["PixelFormat"])


class ReplayCamera(Camera):
    """Serves the images of a folder in name order, one per grab (a recorded session, a test set).

    Args:
        folder: directory of images (PNG, TIFF, JPEG... anything ``cv2.imread`` reads).
        pattern: glob of the files to use.
        name: camera id.
        loop: start again at the first image after the last (otherwise DeviceError).
    """

    def __init__(self, folder: str | Path, *, pattern: str = "*.png", name: str = "cam", loop: bool = False):
        super().__init__()
        self.folder = Path(folder)
        self.files = sorted(self.folder.glob(pattern))
        if not self.files:
            raise BadInputError(f"camera {name}: no images matching {pattern!r} in {self.folder}")
        self.name, self.address, self.loop = name, f"replay://{self.folder}", loop
        self._next = 0
        first = self._read(self.files[0])
        self._values = {
            "Width": first.shape[1],
            "Height": first.shape[0],
            "PixelFormat": "RGB8" if first.ndim == 3 else ("Mono16" if first.dtype == np.uint16 else "Mono8"),
        }

    def _read(self, path: Path) -> np.ndarray:
        import cv2

        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise DeviceError(f"camera {self.name}: cannot read image {path}")
        return img[:, :, ::-1].copy() if img.ndim == 3 else img  # BGR -> RGB

    def device_feature_names(self) -> list[str]:
        return sorted(self._values)

    def _get(self, device_name: str) -> Any:
        return self._values[device_name]

    def _set(self, device_name: str, value: Any) -> None:
        raise DeviceError(f"camera {self.name}: {device_name} is read-only on a replay camera")

    def grab(self, timeout_s: float = 2.0) -> Frame:
        if self._next >= len(self.files):
            if not self.loop:
                raise DeviceError(f"camera {self.name}: all {len(self.files)} images of {self.folder} replayed")
            self._next = 0
        path = self.files[self._next]
        self._next += 1
        img = self._read(path)
        self.stats.frames += 1
        return Frame(img, self._next, time.time_ns(), self._values["PixelFormat"])
