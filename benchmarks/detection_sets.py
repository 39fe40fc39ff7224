"""Rendered image sets of ``bench_detection.py``: target types x image sizes x conditions, with ground truth.

Each set is a list of :class:`Case` (a grey image, the true pixels of every target point, NaN where
outside the image, and the target). Images are rendered by :mod:`jcalib.sim` (board present, partly out
of view, blur, low contrast, glare, steep tilt) or drawn (board absent: clutter of shapes, lines, text,
a torch-like bar and, in every third image, a small chessboard of another size), with fixed seeds, and
cached as PNG + JSON under a folder so that "before" and "after" runs see the same pixels.

The 6016x4016 size is the sensor of the bundled mrcal set (``tests/data/real/mrcal_figueroa``), whose
images are not bundled (only its corner CSV): its views are rendered at that size instead (one sample
per pixel: 24 Mpx renders take minutes otherwise; the squares are hundreds of pixels wide).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

SIZES = {"640x480": (640, 480), "1280x960": (1280, 960), "1600x1200": (1600, 1200), "6016x4016": (6016, 4016)}
CONDITIONS = ("present", "absent", "partly out", "blur", "low contrast", "glare", "steep tilt")


@dataclass(frozen=True)
class Case:
    image: np.ndarray
    truth: np.ndarray  # (N, 2) true pixels of every target point, NaN where not in the image
    name: str


def targets():
    from jcalib.geometry.targets import Charuco, Checkerboard, CircleGrid

    return {
        "chessboard 9x6": Checkerboard(9, 6, 0.03),
        "charuco 7x5": Charuco(7, 5, 0.04, 0.03, "DICT_5X5_100"),
        "circles 4x11 asym": CircleGrid(4, 11, 0.02, asymmetric=True),
    }


def camera(size):
    from jcalib.geometry import camera_from_opencv

    w, h = size
    f = 1.25 * w
    K = np.array([[f, 0.0, (w - 1) / 2 + 0.003 * w], [0.0, f * 0.998, (h - 1) / 2 + 0.002 * h], [0.0, 0.0, 1.0]])
    return camera_from_opencv(K, np.array([-0.2, 0.08, 0.0, 0.0, 0.0]), size)


def _render_options(condition: str, size, rng):
    from jcalib.sim.render import RenderOptions

    scale = size[0] / 640.0
    if condition == "blur":
        return RenderOptions(blur_sigma_px=3.0 * scale, supersample=1 if scale > 3 else 3)
    if condition == "low contrast":
        return RenderOptions.preset("realistic", white_electrons=400.0, gain_dn_per_e=255 / 560, ink_reflectance=0.55,
                                    paper_reflectance=0.8, blur_sigma_px=1.4 * min(scale, 2.0),
                                    supersample=1 if scale > 3 else 3)  # fmt: skip
    if condition == "glare":
        spot = (float(rng.uniform(0.35, 0.65)), float(rng.uniform(0.35, 0.65)), 0.12, 1.5)
        return RenderOptions(glare=(spot,), supersample=1 if scale > 3 else 3)
    return RenderOptions(supersample=1 if scale > 3 else 3)


def _steep(cam, points, rng, lo=55.0, hi=75.0):
    from jcalib.sim.scene import random_calibration_views

    for _ in range(200):
        T = random_calibration_views(cam, points, 1, rng, max_tilt_deg=hi, fill=(0.45, 0.9), margin_px=5.0)[0]
        centre = T[:3, :3] @ points.mean(axis=0) + T[:3, 3]
        tilt = math.degrees(math.acos(min(1.0, abs(float(T[:3, 2] @ centre)) / np.linalg.norm(centre))))
        if tilt >= lo:
            return T
    raise RuntimeError("no steep view")


def _partly_out(cam, points, size, rng):
    """A view with 25-50 % of the points outside the image (board shifted across an image edge)."""
    from jcalib.sim.scene import project_target, random_calibration_views

    w, h = size
    for _ in range(100):
        T = random_calibration_views(cam, points, 1, rng, fill=(0.45, 0.7), max_roll_deg=25.0)[0].copy()
        d = rng.integers(4)
        axis, sign = (0, 1.0) if d == 0 else (0, -1.0) if d == 1 else (1, 1.0) if d == 2 else (1, -1.0)
        goal = rng.uniform(0.25, 0.5)
        z = float(T[2, 3])
        for step in np.linspace(0.0, 1.2, 121):
            S = T.copy()
            S[axis, 3] += sign * step * z * (w if axis == 0 else h) / (1.25 * w)
            pix, vis = project_target(cam, S, points)
            out = 1.0 - float(np.mean(vis))
            if out >= goal:
                if out <= 0.55:
                    return S
                break
    raise RuntimeError("no partial view")


def _clutter(size, rng) -> np.ndarray:
    """A board-free scene: shapes, lines, text, a torch-like bar, noise; every third one holds a small
    chessboard of another size (4x3 inner corners)."""
    w, h = size
    s = w / 640.0
    img = np.zeros((h, w), np.float32)
    gx, gy = rng.uniform(-40, 40, 2)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img += np.float32(rng.uniform(60, 160)) + np.float32(gx) * xx / w + np.float32(gy) * yy / h
    for _ in range(int(rng.integers(8, 20))):
        colour = float(rng.uniform(0, 255))
        kind = rng.integers(4)
        c = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
        if kind == 0:
            pts = (np.array(c) + rng.normal(0, 60 * s, (int(rng.integers(3, 7)), 2))).astype(np.int32)
            cv2.fillPoly(img, [pts], colour)
        elif kind == 1:
            cv2.ellipse(img, c, (int(rng.uniform(5, 60) * s), int(rng.uniform(5, 60) * s)), float(rng.uniform(0, 180)),
                        0, 360, colour, -1)  # fmt: skip
        elif kind == 2:
            p2 = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
            cv2.line(img, c, p2, colour, max(1, int(rng.uniform(1, 8) * s)))
        else:
            cv2.putText(img, "".join(chr(int(rng.integers(65, 90))) for _ in range(6)), c, cv2.FONT_HERSHEY_SIMPLEX,
                        float(rng.uniform(0.5, 2.0) * s), colour, max(1, int(2 * s)))  # fmt: skip
    x0 = int(rng.uniform(0.3, 0.7) * w)  # a torch: a dark bar from the top edge
    cv2.rectangle(img, (x0, 0), (x0 + int(20 * s), int(rng.uniform(0.2, 0.5) * h)), 20.0, -1)
    if rng.integers(3) == 0:
        sq = int(rng.uniform(8, 20) * s)
        ox, oy = int(rng.uniform(0.1, 0.6) * w), int(rng.uniform(0.1, 0.6) * h)
        for i in range(4):
            for j in range(5):
                colour = 30.0 if (i + j) % 2 == 0 else 220.0
                cv2.rectangle(img, (ox + j * sq, oy + i * sq), (ox + (j + 1) * sq, oy + (i + 1) * sq), colour, -1)
    img = cv2.GaussianBlur(img, (0, 0), 0.8 * max(1.0, s / 2))
    img += rng.normal(0.0, 3.0, img.shape).astype(np.float32)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def render_set(target, size_name: str, condition: str, count: int, seed: int) -> list[Case]:
    from jcalib.sim.render import render_target_image
    from jcalib.sim.scene import project_target, random_calibration_views
    from jcalib.sim.textures import target_texture

    size = SIZES[size_name]
    rng = np.random.default_rng(seed)
    cam = camera(size)
    points = target.points
    nan = np.full((len(points), 2), np.nan)
    out = []
    if condition == "absent":
        return [Case(_clutter(size, rng), nan.copy(), f"absent{i}") for i in range(count)]
    spacing = getattr(target, "square", None) or target.spacing
    # texture finer than a pixel of the largest view: ~1.5 texels per image pixel at fill 0.9
    extent = max(target.extent_m[2] - target.extent_m[0], target.extent_m[3] - target.extent_m[1])
    mpp = min(spacing / 24, extent / (2.0 * 0.9 * min(size)))
    texture = target_texture(target, mpp)
    for i in range(count):
        if condition == "steep tilt":
            T = _steep(cam, points, rng)
        elif condition == "partly out":
            T = _partly_out(cam, points, size, rng)
        else:
            T = random_calibration_views(cam, points, 1, rng, fill=(0.3, 0.85), max_roll_deg=30.0)[0]
        options = _render_options(condition, size, rng)
        img = render_target_image(cam, T, texture, options, rng=int(rng.integers(1 << 31)))
        pix, vis = project_target(cam, T, points)
        truth = np.where(vis[:, None], pix, np.nan)
        out.append(Case(img, truth, f"{condition}{i}"))
    return out


def load_or_render(folder: Path, target_name: str, target, size_name: str, condition: str, count: int,
                   seed: int) -> list[Case]:
    """The set from ``folder`` (rendered and saved there on first use)."""
    key = f"{target_name}_{size_name}_{condition}_{count}_{seed}".replace(" ", "-")
    d = Path(folder) / key
    meta = d / "truth.json"
    if meta.is_file():
        info = json.loads(meta.read_text())
        return [Case(cv2.imread(str(d / f"{n}.png"), cv2.IMREAD_UNCHANGED), np.array(t, np.float64), n)
                for n, t in info.items()]  # fmt: skip
    cases = render_set(target, size_name, condition, count, seed)
    d.mkdir(parents=True, exist_ok=True)
    for c in cases:
        cv2.imwrite(str(d / f"{c.name}.png"), c.image)
    meta.write_text(json.dumps({c.name: np.where(np.isnan(c.truth), None, c.truth).tolist() for c in cases}))
    return load_or_render(folder, target_name, target, size_name, condition, count, seed)
