"""Synthetic views of target textures for the vision tests: a homography warp, supersampled."""

from __future__ import annotations

import cv2
import numpy as np


def random_homography(rng: np.random.Generator, target, image_size=(640, 480), fill=0.6, tilt_deg=35.0):
    """A plausible pinhole view of the target: (3, 3) homography target-metres (x, y) -> pixels."""
    w, h = image_size
    x_min, y_min, x_max, y_max = target.extent_m
    size = max(x_max - x_min, y_max - y_min)
    f = 1.2 * w
    dist = f * size / (fill * min(w, h))
    ax, ay = np.deg2rad(rng.uniform(-tilt_deg, tilt_deg, size=2))
    az = rng.uniform(-np.pi, np.pi)
    rvec = np.array([ax, ay, 0.0])
    R_tilt, _ = cv2.Rodrigues(rvec)
    Rz, _ = cv2.Rodrigues(np.array([0.0, 0.0, az]))
    R = R_tilt @ Rz
    centre = np.array([0.5 * (x_min + x_max), 0.5 * (y_min + y_max), 0.0])
    t = np.array([rng.uniform(-0.05, 0.05) * size, rng.uniform(-0.05, 0.05) * size, dist]) - R @ centre
    K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
    H = K @ np.column_stack([R[:, 0], R[:, 1], t])
    return H / H[2, 2]


def warp_texture(texture, H: np.ndarray, image_size=(640, 480), supersample: int = 4, dark=0.08, bright=0.92):
    """Image (uint8, grey) of a texture seen through homography H (target metres -> pixels).

    The texture is warped bilinearly onto a ``supersample``-times finer grid and box-averaged down,
    which integrates each camera pixel's footprint (pixel centres at integer coordinates).
    """
    w, h = image_size
    s = supersample
    m = texture.metres_per_pixel
    A = np.array([[1 / m, 0.0, -texture.origin_m[0] / m], [0.0, 1 / m, -texture.origin_m[1] / m], [0, 0, 1.0]])
    S = np.array([[s, 0.0, (s - 1) / 2], [0.0, s, (s - 1) / 2], [0.0, 0.0, 1.0]])
    M = S @ H @ np.linalg.inv(A)
    tex = texture.image.astype(np.float32)
    hi = cv2.warpPerspective(tex, M, (w * s, h * s), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=1.0)
    lo = cv2.resize(hi, (w, h), interpolation=cv2.INTER_AREA).astype(np.float64)
    return np.clip(np.round(255.0 * (dark + (bright - dark) * lo)), 0, 255).astype(np.uint8)


def project(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of target points (N, 3) (z ignored) through homography H."""
    p = np.column_stack([points[:, 0], points[:, 1], np.ones(len(points))]) @ H.T
    return p[:, :2] / p[:, 2:]


def texture_resolution(target, H: np.ndarray, supersample: int = 4) -> float:
    """A texture resolution (m/px) finer than one supersampled image pixel everywhere on the target."""
    x_min, y_min, x_max, y_max = target.extent_m
    g = np.array([[x, y, 0.0] for x in np.linspace(x_min, x_max, 9) for y in np.linspace(y_min, y_max, 9)])
    d = 1e-4
    p0 = project(H, g)
    px = np.linalg.norm(project(H, g + [d, 0, 0]) - p0, axis=1) / d
    py = np.linalg.norm(project(H, g + [0, d, 0]) - p0, axis=1) / d
    return 0.7 / (supersample * max(px.max(), py.max()))
