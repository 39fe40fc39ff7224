"""The live page's work: detection overlays on a camera's newest frames, image quality, JPEG frames.

A :class:`LiveDetector` runs while somebody watches the camera: it takes the newest frame of a
:class:`~jcalib.acquisition.stream.LiveCamera`, detects the cell's targets in it with the vision layer
(:func:`jcalib.vision.track_target`: the previous frame's corners are the hint), and keeps one overlay:
the corners with their ids, the board outline, why nothing was found, the image's sharpness and exposure,
and — where the camera's intrinsics are known (the latest result, the cell's, or the nominal layout's) —
where the board is (PnP: distance, tilt), to help aim the camera. The overlay rate is measured.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any

import cv2
import numpy as np

from jcalib.errors import BadInputError, DetectionError

__all__ = ["LiveDetector", "encode_jpeg", "image_quality", "board_pose"]

#: Largest side of a live frame sent to the browser, px (larger frames are scaled down for display only).
MAX_DISPLAY_SIDE = 1600


def encode_jpeg(image: np.ndarray, quality: int = 80) -> tuple[bytes, float]:
    """A frame as JPEG bytes for the browser, and the display scale (1 unless scaled down).

    Args:
        image: (H, W) or (H, W, 3) uint8 / uint16 (RGB order for colour frames, as cameras deliver).
        quality: JPEG quality, 1..100.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = (img >> 8).astype(np.uint8) if img.dtype == np.uint16 else np.clip(img, 0, 255).astype(np.uint8)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    scale = 1.0
    side = max(img.shape[:2])
    if side > MAX_DISPLAY_SIDE:
        scale = MAX_DISPLAY_SIDE / side
        img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise BadInputError("live frame: JPEG encoding failed")
    return buf.tobytes(), scale


def image_quality(image: np.ndarray) -> dict[str, float]:
    """Sharpness and exposure of a frame: ``edge_width_px`` (about 1-3 px in focus), ``contrast`` (0..1),
    ``mean`` grey level (0..1), ``saturated_pct`` and ``dark_pct`` (pixels at the top / bottom of the range)."""
    from jcalib.vision.image import image_stats, to_gray

    gray = to_gray(image, "<live>")
    contrast, edge = image_stats(gray)
    img = np.asarray(image)
    top = 65535 if img.dtype == np.uint16 else 255
    g = gray.f32
    return {
        "edge_width_px": float(edge) if np.isfinite(edge) else None,
        "contrast": float(contrast),
        "mean": float(g.mean() / 255.0),
        "saturated_pct": float(100.0 * np.mean(img >= top)),
        "dark_pct": float(100.0 * np.mean(img <= 0)),
    }


def board_pose(points_target: np.ndarray, pixels: np.ndarray, K: np.ndarray, dist: np.ndarray) -> dict | None:
    """Where a planar board is in the camera: PnP of its detected points (OpenCV's IPPE for OpenCV lens
    coefficients, which runs in well under a millisecond; jcalib's planar PnP for other lens models).

    Returns:
        ``{"distance_m", "tilt_deg" (board normal to optical axis), "t_m" (3,), "rms_px"}``, or None with
        fewer than 4 points or a degenerate view.
    """
    if len(pixels) < 4:
        return None
    obj = np.asarray(points_target, dtype=np.float64).reshape(-1, 3)
    img = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    K = np.asarray(K, dtype=np.float64)
    dist = np.asarray(dist, dtype=np.float64).ravel()
    if dist.size in (0, 4, 5, 8, 12, 14) and np.allclose(obj[:, 2], 0.0):
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
        if not ok or not np.all(np.isfinite(tvec)):
            return None
        R = cv2.Rodrigues(rvec)[0]
        t = tvec.ravel()
        proj = cv2.projectPoints(obj, rvec, tvec, K, dist)[0].reshape(-1, 2)
        rms = float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1))))
    else:
        from jcalib.init.pnp import planar_pnp

        try:
            res = planar_pnp(obj, img, K, dist, refine=True)
        except BadInputError:
            return None
        R, t, rms = res.R[0], res.t[0], float(res.rms_px[0])
    normal = R[:, 2]
    tilt = float(np.degrees(np.arccos(min(1.0, abs(float(normal[2]))))))
    return {"distance_m": float(np.linalg.norm(t)), "tilt_deg": tilt, "t_m": [float(v) for v in t],
            "rms_px": rms}  # fmt: skip


class LiveDetector:
    """Detection overlays of one camera's live frames (module docstring).

    Args:
        camera: the :class:`~jcalib.acquisition.stream.LiveCamera`.
        targets: target id -> geometry (``jcalib.geometry.targets``) to look for.
        intrinsics: ``() -> (K, dist) or None``: the camera's current best intrinsics, for the board pose.
    """

    def __init__(self, camera: Any, targets: Mapping[str, Any], intrinsics: Callable[[], Any]) -> None:
        self.camera = camera
        self.targets = dict(targets)
        self.intrinsics = intrinsics
        self._viewers = 0
        self._lock = threading.Lock()
        self._active = threading.Event()
        self._thread: threading.Thread | None = None
        self._previous: dict[str, Any] = {}
        self._times: deque[float] = deque(maxlen=20)
        self.overlay: dict = {"seq": 0, "targets": [], "rate_hz": 0.0}

    def watch(self) -> None:
        """A viewer arrived: stream and detect while anybody watches."""
        with self._lock:
            self._viewers += 1
            self._active.set()
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._run, name=f"detect-{self.camera.name}", daemon=True)
                self._thread.start()
        self.camera.start_streaming()

    def unwatch(self) -> None:
        """A viewer left."""
        with self._lock:
            self._viewers = max(0, self._viewers - 1)
            if self._viewers == 0:
                self._active.clear()
        if self._viewers == 0:
            self.camera.stop_streaming()

    def close(self) -> None:
        """Every viewer left (the app stops)."""
        with self._lock:
            self._viewers = 0
            self._active.clear()
        self.camera.stop_streaming()

    def join(self, timeout_s: float) -> None:
        """Wait (up to ``timeout_s``) for the detection thread after the last viewer left."""
        thread = self._thread
        if thread is not None and not self._active.is_set():
            thread.join(timeout_s)

    @property
    def rate_hz(self) -> float:
        t = list(self._times)
        if len(t) < 2 or time.monotonic() - t[-1] > 2.0:
            return 0.0
        return (len(t) - 1) / max(t[-1] - t[0], 1e-9)

    def _run(self) -> None:
        seq = 0
        while self._active.is_set():
            frame, new = self.camera.wait_frame(seq, timeout_s=0.5)
            if frame is None or new == seq:
                continue
            seq = new
            try:
                overlay = self.analyse(frame.image, seq)
            except Exception as e:  # the overlay says it; the live view goes on
                overlay = {"seq": seq, "targets": [], "error": f"{type(e).__name__}: {e}"}
            self._times.append(time.monotonic())
            overlay["rate_hz"] = self.rate_hz
            overlay["time"] = time.time()
            self.overlay = overlay

    def analyse(self, image: np.ndarray, seq: int = 0) -> dict:
        """The overlay of one frame (also usable without the thread)."""
        from jcalib.vision import track_target

        h, w = np.asarray(image).shape[:2]
        quality = image_quality(image)
        found = []
        cam = self.intrinsics()
        for name, geometry in self.targets.items():
            entry: dict[str, Any] = {"target": name, "found": False}
            try:
                det = track_target(image, geometry, self._previous.get(name), name=f"{self.camera.name} live")
            except DetectionError as e:
                self._previous.pop(name, None)
                entry.update(reason=e.reason, message=str(e).split(": ", 1)[-1])
                found.append(entry)
                continue
            self._previous[name] = det
            px = np.asarray(det.pixels, dtype=np.float64)
            idx = np.asarray(det.point_index, dtype=np.int64)
            hull = cv2.convexHull(px.astype(np.float32)).reshape(-1, 2) if len(px) >= 3 else px
            entry.update(found=True, corners=[[round(float(u), 2), round(float(v), 2), int(i)]
                                              for (u, v), i in zip(px, idx)],
                         outline=hull.round(2).tolist(), num_points=int(len(idx)),
                         num_board_points=int(len(geometry.points)), warnings=list(det.warnings),
                         tracked=bool(det.tracked))  # fmt: skip
            if cam is not None:
                pts = np.asarray(geometry.points, dtype=np.float64)[idx]
                entry["pose"] = board_pose(pts, px, cam[0], cam[1])
            found.append(entry)
        return {"seq": seq, "width": int(w), "height": int(h), "quality": quality, "targets": found}
