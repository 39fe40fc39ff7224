"""LiveCamera: a live view and a capture share one device; every frame, the capture's included, is published."""

from __future__ import annotations

import threading
import time

import numpy as np

from jcalib.acquisition.cameras.simulated import SimulatedCamera
from jcalib.acquisition.stream import LiveCamera


def test_live_frames_and_capture_grabs_share_the_device():
    active = []
    lock = threading.Lock()
    served = []

    def source(req):
        with lock:
            active.append(1)
            assert len(active) == 1, "two grabs inside the device at once"
        time.sleep(0.004)
        with lock:
            active.pop()
            served.append(req.index)
        return np.full((req.height, req.width), len(served) % 255, np.uint8)

    cam = LiveCamera(SimulatedCamera(source, sensor_size=(64, 48), name="c0"))
    assert cam.name == "c0" and cam.latest() == (None, 0)
    cam.start_streaming()
    frame, seq = cam.wait_frame(0, timeout_s=5.0)
    assert frame is not None and seq >= 1
    grabbed = [cam.grab() for _ in range(5)]  # a capture grabs through the same lock while streaming
    assert all(f.image.shape == (48, 64) for f in grabbed)
    time.sleep(0.2)
    assert cam.fps > 5.0
    _, last = cam.latest()
    cam.stop_streaming()
    time.sleep(0.05)
    _, after = cam.latest()
    time.sleep(0.1)
    assert cam.latest()[1] == after  # nothing grabbed any more
    assert last >= seq + 5
    assert cam.get("Width") == 64 and cam.has("ExposureTime")
    cam.set("ExposureTime", 5000.0)
    assert cam.get("ExposureTime") == 5000.0
    cam.close()
    assert cam.wait_frame(after, timeout_s=0.1)[1] == after  # a closed camera does not block viewers


def test_a_failing_device_is_recorded_and_retried():
    inner = SimulatedCamera(lambda req: np.zeros((req.height, req.width), np.uint8), sensor_size=(32, 24),
                            fail_grabs=1)
    cam = LiveCamera(inner)
    cam.start_streaming()
    frame, seq = cam.wait_frame(0, timeout_s=5.0)
    assert frame is not None  # after the failure the stream went on
    cam.close()
