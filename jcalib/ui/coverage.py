"""What the captured views cover: a heat map of corners over each camera's image, the spread of board tilts
and distances, and station thumbnails with their detections drawn.

All of it is read from the session's observations (:func:`jcalib.pipeline.session.detect_session`), so
the capture page shows what the calibration will use.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import cv2
import numpy as np

from jcalib.ui.live import board_pose

__all__ = ["coverage", "heatmap_png", "thumbnail_jpeg", "GRID"]

#: Heat-map cells across (columns, rows) of an image.
GRID = (16, 12)


def coverage(observations: Any, camera: str, image_size: tuple[int, int],
             intrinsics: Callable[[], Any] | None = None) -> dict:
    """Where one camera's corners landed over the captured stations.

    Args:
        observations: :class:`jcalib.io.observations.Observations` of the session.
        camera: camera id.  image_size: (width, height), px.
        intrinsics: ``() -> (K, dist) or None`` for the board poses (tilt, distance).

    Returns:
        ``{"grid": [[count]] (rows x columns of :data:`GRID`), "covered_pct", "views", "points",
        "tilts_deg": [...], "distances_m": [...], "image_size"}``; ``covered_pct`` is the share of heat-map
        cells with at least one corner.
    """
    w, h = image_size
    cols, rows = GRID
    counts = np.zeros((rows, cols), dtype=np.int64)
    tilts, dists, views, points = [], [], 0, 0
    cam = intrinsics() if intrinsics is not None else None
    for st in observations.stations:
        for d in st.detections:
            if d.camera != camera or d.target is None:
                continue
            px = np.asarray(d.pixels, dtype=np.float64)
            views += 1
            points += len(px)
            c = np.clip(((px[:, 0] + 0.5) / w * cols).astype(int), 0, cols - 1)
            r = np.clip(((px[:, 1] + 0.5) / h * rows).astype(int), 0, rows - 1)
            np.add.at(counts, (r, c), 1)
            if cam is not None:
                pts = np.asarray(observations.targets[d.target], dtype=np.float64)[np.asarray(d.point_index)]
                pose = board_pose(pts, px, cam[0], cam[1])
                if pose is not None:
                    tilts.append(round(pose["tilt_deg"], 2))
                    dists.append(round(pose["distance_m"], 4))
    return {"grid": counts.tolist(), "covered_pct": float(100.0 * np.mean(counts > 0)), "views": views,
            "points": points, "tilts_deg": tilts, "distances_m": dists, "image_size": [int(w), int(h)]}  # fmt: skip


def heatmap_png(grid: list[list[int]], width: int = 320) -> bytes:
    """The heat map as a PNG ``width`` pixels wide (dark blue: no corner; cells scaled by the largest count)."""
    counts = np.asarray(grid, dtype=np.float64)
    rows, cols = counts.shape
    norm = np.sqrt(counts / counts.max()) if counts.max() > 0 else counts
    img = (norm * 255).astype(np.uint8)
    height = int(round(width * rows / cols))
    big = cv2.resize(img, (width, height), interpolation=cv2.INTER_NEAREST)
    color = cv2.applyColorMap(big, cv2.COLORMAP_VIRIDIS)
    color[big == 0] = (60, 20, 20)
    for k in range(1, cols):
        x = int(round(k * width / cols))
        color[:, x] = (color[:, x] * 0.6).astype(np.uint8)
    for k in range(1, rows):
        y = int(round(k * height / rows))
        color[y, :] = (color[y, :] * 0.6).astype(np.uint8)
    ok, buf = cv2.imencode(".png", color)
    return buf.tobytes()


def thumbnail_jpeg(image: np.ndarray, detections: Mapping[str, np.ndarray] | None = None, *, width: int = 240,
                   failed: str | None = None) -> bytes:
    """A small JPEG of a station image with its detected points drawn (green) or the failure written (red).

    Args:
        image: the station image (gray or colour, 8 or 16 bit).
        detections: target or tool id -> (n, 2) pixels found.
        width: thumbnail width, px.
        failed: a short reason shown when nothing was found.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = (img >> 8).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    s = width / img.shape[1]
    small = cv2.resize(img, (width, max(1, int(round(img.shape[0] * s)))), interpolation=cv2.INTER_AREA)
    for px in (detections or {}).values():
        for u, v in np.asarray(px, dtype=np.float64).reshape(-1, 2):
            cv2.circle(small, (int(round((u + 0.5) * s - 0.5)), int(round((v + 0.5) * s - 0.5))), 2, (60, 220, 60), -1)
    if failed:
        cv2.putText(small, failed[:28], (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (40, 40, 230), 1, cv2.LINE_AA)
    ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, 80])
    return buf.tobytes()
