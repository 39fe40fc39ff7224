"""AprilGrid and single-AprilTag detection: time, tags and corners found, wrong labels, corner accuracy.

Rendered views (``jcalib.sim``: perspective, lens distortion k1 = -0.15, defocus, sensor noise) of a
Kalibr AprilGrid (6x6 tag36h11, tags 30 mm, spacing 0.3) and of a single tag36h11 tag (50 mm), at
640x480 and 1280x960 (the camera matrix scales with the image). Per condition:

- time per image of ``jcalib.vision.detect_target`` (median, 95th percentile; one OpenCV thread);
- tags and corners found out of those of the tags wholly in view (all 4 corners >= 3 px inside);
- wrong labels: returned corners farther from their true projection than half the distance to the
  nearest other point of the target in the image (a wrong id, corner or order: the corner of another
  point); "> 1 px": right labels more than 1 px off (inaccurate corners, which a calibration's outlier
  rounds must handle);
- corner error against the truth (median, RMS, px) of jcalib's corners, and of OpenCV's ArUco corners
  for the same tags (``cv2.aruco.ArucoDetector`` with the tags' border width and
  ``CORNER_REFINE_SUBPIX``, the usual recipe), with the tags OpenCV's detector finds on its own.

Run: ``.venv/bin/python benchmarks/bench_apriltag.py [--views 8] [--sizes 640x480,1280x960]``; output
saved as ``benchmarks/data/bench_apriltag.txt``.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import cv2
import numpy as np

import jcalib  # noqa: F401  (float64)
from jcalib.errors import DetectionError
from jcalib.geometry import camera_from_opencv
from jcalib.geometry.apriltags import APRILTAG_FAMILIES, AprilGrid, AprilTag
from jcalib.geometry.se3 import make_pose, rotation
from jcalib.sim.render import RenderOptions, render_target_image
from jcalib.sim.scene import project_target, random_calibration_views
from jcalib.sim.textures import target_texture
from jcalib.vision import detect_target
from jcalib.vision.apriltag import OPENCV_TO_POINT

GRID = AprilGrid(6, 6, 0.03, 0.3)
TAG = AprilTag(id=7, size=0.05)
GROSS_PX = 1.0
IN_VIEW_PX = 3.0


def camera(size):
    w, h = size
    s = w / 640.0
    K = np.array([[760.0 * s, 0.0, (w - 1) / 2 + 2.0 * s], [0.0, 758.0 * s, (h - 1) / 2 - 1.5 * s], [0.0, 0.0, 1.0]])
    return camera_from_opencv(K, np.array([-0.15, 0.06, 0.0, 0.0, 0.0]), size)


def conditions():
    """name -> (render options, view kind)."""
    return {
        "clean": (RenderOptions(), "normal"),
        "blur σ 2 px": (RenderOptions(blur_sigma_px=2.0), "normal"),
        "realistic noise (120 e-)": (RenderOptions.preset("realistic"), "normal"),
        "steep tilt 50-70°": (RenderOptions(), "steep"),
        "partly out of view": (RenderOptions(), "partial"),
        "small tags": (RenderOptions(), "small"),
    }


def views(cam, points, kind: str, n: int, rng) -> list[np.ndarray]:
    w, h = cam.image_size
    if kind == "small":
        return random_calibration_views(cam, points, n, rng=rng, fill=(0.3, 0.4), max_roll_deg=180)
    if kind == "steep":
        out = []
        while len(out) < n:
            for T in random_calibration_views(cam, points, 4 * n, rng=rng, fill=(0.5, 0.9), max_tilt_deg=70,
                                              max_roll_deg=180):
                if np.degrees(np.arccos(abs(T[2, 2]))) >= 50 and len(out) < n:
                    out.append(T)
        return out
    poses = random_calibration_views(cam, points, n, rng=rng, fill=(0.6, 1.0), max_tilt_deg=45, max_roll_deg=180)
    if kind == "partial":  # the board's centre moved to 92 % of the width or 8 % of the height
        K = np.asarray(cam.to_opencv()[0])
        centre = points.mean(axis=0)
        for k, T in enumerate(poses):
            p = T[:3, :3] @ centre + T[:3, 3]
            if k % 2 == 0:
                T[0, 3] += (0.92 * w - K[0, 2]) / K[0, 0] * p[2] - p[0]
            else:
                T[1, 3] += (0.08 * h - K[1, 2]) / K[1, 1] * p[2] - p[1]
    return poses


def single_tag_views(cam, kind: str, n: int, rng) -> list[np.ndarray]:
    out = []
    for _ in range(n):
        dist = rng.uniform(0.3, 0.5) * (1.8 if kind == "small" else 1.0)
        tilt = rng.uniform(50, 65) if kind == "steep" else rng.uniform(5, 40)
        axis = np.append(rng.normal(size=2), 0.0)
        R = rotation(axis / np.linalg.norm(axis), np.radians(tilt)) @ rotation(np.array([0, 0, 1.0]), rng.uniform(-np.pi, np.pi))
        off = [rng.uniform(-0.05, 0.05), rng.uniform(-0.04, 0.04)]
        if kind == "partial":
            off[0] = 0.45 * dist * cam.image_size[0] / float(np.asarray(cam.to_opencv()[0])[0, 0])
        out.append(make_pose(R, [off[0], off[1], dist]))
    return out


def opencv_corners(img, target, family):
    """OpenCV's own ArUco corners: id -> (4, 2) in jcalib's point order."""
    params = cv2.aruco.DetectorParameters()
    params.markerBorderBits = target.border_bits
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, APRILTAG_FAMILIES[family][0]))
    corners, ids, _ = cv2.aruco.ArucoDetector(d, params).detectMarkers(img)
    out = {}
    for c, i in zip(corners or (), (ids if ids is not None else np.zeros((0, 1))).reshape(-1)):
        pts = np.empty((4, 2))
        pts[OPENCV_TO_POINT] = np.asarray(c, np.float64).reshape(4, 2)
        out[int(i)] = pts
    return out


def run(target, cam, poses, options, texture, seed):
    times, err, raw_err, wrong, gross = [], [], [], 0, 0
    tags_in = tags_found = corners_in = corners_found = raw_tags = 0
    w, h = cam.image_size
    grid = isinstance(target, AprilGrid)
    for k, T in enumerate(poses):
        img = render_target_image(cam, T, texture, options, rng=seed + k)
        truth, vis = project_target(cam, T, target.points)
        inside = vis & (truth[:, 0] >= IN_VIEW_PX) & (truth[:, 0] <= w - 1 - IN_VIEW_PX) & (truth[:, 1] >= IN_VIEW_PX) \
            & (truth[:, 1] <= h - 1 - IN_VIEW_PX)
        whole = inside.reshape(-1, 4).all(axis=1)
        want = np.flatnonzero(np.repeat(whole, 4))
        tags_in += int(whole.sum())
        corners_in += len(want)
        t0 = time.perf_counter()
        try:
            det = detect_target(img, target, min_points=4)
            idx, px = det.point_index, det.pixels
        except DetectionError:
            idx, px = np.zeros(0, np.int64), np.zeros((0, 2))
        times.append(time.perf_counter() - t0)
        e = np.linalg.norm(px - truth[idx], axis=1)
        d = np.linalg.norm(truth[:, None] - truth[None], axis=-1)
        np.fill_diagonal(d, np.inf)
        mislabelled = e > 0.5 * d.min(axis=1)[idx]
        wrong += int(mislabelled.sum())
        gross += int(np.sum(~mislabelled & (e > GROSS_PX)))
        ok = np.isin(idx, want)
        corners_found += int(ok.sum())
        tags_found += len(np.unique(idx // 4)) if grid else int(len(idx) == 4)
        err.append(e[~mislabelled])
        for tid, c in opencv_corners(img, target, target.family).items():
            t = tid if grid else (0 if tid == target.id else None)
            if t is None or t >= len(whole):
                continue
            raw_tags += 1
            raw_err.append(np.linalg.norm(c - truth[4 * t:4 * t + 4], axis=1))
    e = np.concatenate(err) if err else np.zeros(0)
    r = np.concatenate(raw_err) if raw_err else np.zeros(0)
    ms = 1000 * np.array(times)

    def stats(v):
        return (f"{np.median(v):6.3f} {np.sqrt(np.mean(v ** 2)):6.3f}" if len(v) else "     -      -")

    return (f"{np.median(ms):6.1f} {np.percentile(ms, 95):6.1f} | {tags_found:4d}/{tags_in:<4d} "
            f"{corners_found:5d}/{corners_in:<5d} {wrong:5d} {gross:5d} | {stats(e)} | {raw_tags:4d} {stats(r)}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--sizes", default="640x480,1280x960")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    head = (f"{'condition':26s} {'ms med':>6s} {'p95':>6s} | {'tags':>9s} {'corners':>11s} {'wrong':>5s} {'> 1px':>5s} | "
            f"{'med px':>6s} {'rms px':>6s} | {'cv':>4s} {'med px':>6s} {'rms px':>6s}")
    print(f"load average: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f}; one OpenCV thread; {args.views} views "
          "per row; corners found / corners of the tags wholly in view; cv: OpenCV's ArUco alone (tags, corner error)")
    for name, target, tex_res in (("AprilGrid 6x6 tag36h11 (30 mm, spacing 0.3)", GRID, GRID.tag_size / 60),
                                  ("AprilTag tag36h11 id 7 (50 mm), 4 corners", TAG, TAG.size / 120)):
        texture = target_texture(target, tex_res)
        for size in sizes:
            cam = camera(size)
            print(f"\n{name}, {size[0]}x{size[1]}\n{head}")
            for cond, (options, kind) in conditions().items():
                rng = np.random.default_rng(7)
                if isinstance(target, AprilGrid):
                    poses = views(cam, target.points, kind, args.views, rng)
                else:
                    poses = single_tag_views(cam, kind, args.views, rng)
                print(f"{cond:26s} {run(target, cam, poses, options, texture, 100)}", flush=True)


if __name__ == "__main__":
    main()
