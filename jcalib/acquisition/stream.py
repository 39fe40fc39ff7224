"""Live frames from a camera that a capture shares: :class:`LiveCamera`.

A live view wants frames continuously; a capture wants one frame per station from the same device. A
:class:`LiveCamera` wraps an opened :class:`~jcalib.acquisition.cameras.base.Camera` and is one itself:

- :meth:`LiveCamera.grab` (what :func:`jcalib.acquisition.capture.capture` calls) grabs through the
  device under one lock, so a capture's frame is never interleaved with a live grab;
- while :meth:`LiveCamera.start_streaming` is on, a background thread grabs continuously (software
  trigger after software trigger, as fast as the device delivers, or at most ``max_fps``);
- every complete frame, the capture's included, is published: :meth:`LiveCamera.latest` and
  :meth:`LiveCamera.wait_frame` hand it to viewers with a running sequence number, and the measured
  frame rate is :attr:`LiveCamera.fps`.

Feature reads and writes go through the same lock. A grab error in the streaming thread is recorded
(:attr:`LiveCamera.error`) and retried after a pause; it never stops a capture, which raises its own.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any

from jcalib.acquisition.cameras.base import Camera, Frame
from jcalib.errors import DeviceError

__all__ = ["LiveCamera"]


class LiveCamera(Camera):
    """A camera shared by a live view and a capture (module docstring).

    Args:
        camera: the opened device (its ``name`` and ``address`` are taken over).
        max_fps: upper bound of the streaming rate (None: as fast as the device delivers).
        grab_timeout_s: per-grab timeout of the streaming thread, s.
    """

    def __init__(self, camera: Camera, *, max_fps: float | None = None, grab_timeout_s: float = 2.0) -> None:
        super().__init__()
        self.inner = camera
        self.name = camera.name
        self.address = camera.address
        self.stats = camera.stats
        self.max_fps = max_fps
        self.grab_timeout_s = float(grab_timeout_s)
        self._device = threading.Lock()  # one device access at a time
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._seq = 0
        self._times: deque[float] = deque(maxlen=30)
        self._thread: threading.Thread | None = None
        self._streaming = threading.Event()
        self._closed = False
        self.error: str | None = None

    # --- the Camera interface, serialised -------------------------------------------------------
    def device_feature_names(self) -> list[str]:
        with self._device:
            return self.inner.device_feature_names()

    def _get(self, device_name: str) -> Any:
        with self._device:
            return self.inner._get(device_name)

    def _set(self, device_name: str, value: Any) -> None:
        with self._device:
            self.inner._set(device_name, value)

    def resolve(self, feature: str) -> str:
        with self._device:
            return self.inner.resolve(feature)

    def has(self, feature: str) -> bool:
        with self._device:
            return self.inner.has(feature)

    def grab(self, timeout_s: float = 2.0) -> Frame:
        """Grab one frame through the device lock and publish it (what a capture calls)."""
        with self._device:
            frame = self.inner.grab(timeout_s=timeout_s)
        self._publish(frame)
        return frame

    def close(self) -> None:
        """Stop streaming and close the device (idempotent)."""
        self.stop_streaming()
        self._closed = True
        with self._device:
            self.inner.close()
        with self._cond:
            self._cond.notify_all()

    # --- live frames -----------------------------------------------------------------------------
    def _publish(self, frame: Frame) -> None:
        with self._cond:
            self._frame = frame
            self._seq += 1
            self._times.append(time.monotonic())
            self.error = None
            self._cond.notify_all()

    @property
    def fps(self) -> float:
        """Frames published per second over the last (up to) 30 frames; 0 when stalled for 2 s."""
        with self._cond:
            t = list(self._times)
        if len(t) < 2 or time.monotonic() - t[-1] > 2.0:
            return 0.0
        return (len(t) - 1) / max(t[-1] - t[0], 1e-9)

    @property
    def streaming(self) -> bool:
        return self._streaming.is_set()

    def latest(self) -> tuple[Frame | None, int]:
        """The newest frame and its sequence number (``(None, 0)`` before the first)."""
        with self._cond:
            return self._frame, self._seq

    def wait_frame(self, after_seq: int, timeout_s: float = 1.0) -> tuple[Frame | None, int]:
        """The newest frame once its sequence number exceeds ``after_seq`` (or the newest at the timeout)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._seq <= after_seq and not self._closed:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            return self._frame, self._seq

    def start_streaming(self) -> None:
        """Grab continuously in a background thread (idempotent)."""
        if self._closed:
            raise DeviceError(f"camera {self.name} at {self.address} is closed")
        self._streaming.set()
        if self._thread is None or not self._thread.is_alive():
            self._thread = threading.Thread(target=self._run, name=f"live-{self.name}", daemon=True)
            self._thread.start()

    def stop_streaming(self) -> None:
        """Stop the background grabs (a grab in flight finishes); idempotent."""
        self._streaming.clear()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=self.grab_timeout_s + 1.0)
        self._thread = None

    def _run(self) -> None:
        while self._streaming.is_set() and not self._closed:
            t0 = time.monotonic()
            try:
                self.grab(timeout_s=self.grab_timeout_s)
            except DeviceError as e:
                self.error = str(e)
                time.sleep(0.5)
                continue
            except Exception as e:  # a driver bug must not kill the live view silently
                self.error = f"{type(e).__name__}: {e}"
                time.sleep(0.5)
                continue
            if self.max_fps:
                time.sleep(max(0.0, 1.0 / self.max_fps - (time.monotonic() - t0)))
