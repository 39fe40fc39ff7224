"""Tool-tip detection: tip error vs noise and blur, and detection time per image.

Renders a 3 mm / 20-degree tool (sharp tip) on a backlight at random poses (tip inside the image,
0.2-0.4 m away at the reference size, axis tilted up to +-45 degrees out of the image plane) through
a pinhole camera, detects the tip and compares with the projected TCP. Prints a table of the tip
error (mean, p95, px) and axis error (mean, degrees) per noise level and blur, then the detection
time per image at the timing size.

    .venv/bin/python benchmarks/bench_tooltip.py [--size 2048] [--poses 10] [--timing-size 2048]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=2048, help="image width = height for the error table, px")
    ap.add_argument("--poses", type=int, default=10, help="random poses per table row")
    ap.add_argument("--timing-size", type=int, default=2048, help="image width = height for the timing, px")
    ap.add_argument("--timing-runs", type=int, default=10)
    args = ap.parse_args()

    import cv2

    import jcalib  # noqa: F401  (float64)
    from jcalib.errors import DetectionError
    from jcalib.geometry.cameras import camera_from_opencv
    from jcalib.sim.render import RenderOptions
    from jcalib.sim.tool import SymmetricTool, render_tool_image
    from jcalib.vision.tooltip import detect_tool_tip

    tool = SymmetricTool(shaft_radius_m=0.003, cone_half_angle_deg=20.0, length_m=1.0)

    def setup(size: int):
        f = 1.9 * size  # ~30 degree field of view
        K = np.array([[f, 0.0, (size - 1) / 2 + 3.3], [0.0, f, (size - 1) / 2 - 2.1], [0.0, 0.0, 1.0]])
        return K, camera_from_opencv(K, None, (size, size))

    def pose(rng, K, size):
        m = 0.06 * size
        u, v = rng.uniform(m, size - 1 - m, size=2)
        depth = rng.uniform(0.2, 0.4) * size / 640.0  # same apparent tool size as at 640 px
        p = np.linalg.solve(K, [u, v, 1.0]) * depth
        th, tilt = rng.uniform(-np.pi, np.pi), np.deg2rad(rng.uniform(-45, 45))
        z = np.array([np.cos(tilt) * np.cos(th), np.cos(tilt) * np.sin(th), np.sin(tilt)])
        x = np.cross([0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0], z)
        x /= np.linalg.norm(x)
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
        T[:3, 3] = p
        return T

    K, cam = setup(args.size)
    # (label, options): exposure sets the backlight's signal (shot noise), read noise 3 e-
    rows = []
    for label, white in (("high SNR (backlight ~25000 e-, 16-bit)", None), ("default (~6300 e-)", 7000.0),
                         ("low light (~900 e-)", 1000.0), ("very low (~270 e-)", 300.0)):
        for blur in (0.7, 1.5, 2.5):
            if white is None:
                opts = RenderOptions(blur_sigma_px=blur, white_electrons=28000.0, full_well_e=30000.0, bit_depth=16)
            else:
                opts = RenderOptions(blur_sigma_px=blur, white_electrons=white)
            rows.append((label, blur, opts))

    print(f"tip error at {args.size}x{args.size}, {args.poses} poses per row (same poses in every row)")
    print(f"{'noise':40s} {'blur px':>7s} {'mean px':>8s} {'p95 px':>8s} {'max px':>8s} {'axis deg':>9s} {'fails':>5s}")
    for label, blur, opts in rows:
        rng = np.random.default_rng(0)
        errs, angs, fails = [], [], 0
        for _ in range(args.poses):
            T = pose(rng, K, args.size)
            out = render_tool_image(cam, T, tool, opts, rng)
            try:
                det = detect_tool_tip(out.image)
            except DetectionError:
                fails += 1
                continue
            errs.append(float(np.linalg.norm(det.pixel - out.tip_px)))
            angs.append(math.degrees(math.acos(float(np.clip(det.axis_direction @ out.axis_direction, -1, 1)))))
        e = np.array(errs) if errs else np.array([np.nan])
        a = np.array(angs) if angs else np.array([np.nan])
        print(f"{label:40s} {blur:7.1f} {e.mean():8.3f} {np.percentile(e, 95):8.3f} {e.max():8.3f} "
              f"{a.mean():9.4f} {fails:5d}")

    # timing
    K, cam = setup(args.timing_size)
    rng = np.random.default_rng(1)
    images = [render_tool_image(cam, pose(rng, K, args.timing_size), tool, RenderOptions(), rng).image
              for _ in range(3)]
    detect_tool_tip(images[0])  # warm-up
    times = []
    for i in range(args.timing_runs):
        t0 = time.perf_counter()
        detect_tool_tip(images[i % len(images)])
        times.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    render_tool_image(cam, pose(rng, K, args.timing_size), tool, RenderOptions(), rng)
    t_render = time.perf_counter() - t0
    print()
    print(f"{'image':>11s} {'detect median ms':>17s} {'min ms':>8s} {'render s':>9s}   ({cv2.getNumThreads()} OpenCV threads)")
    print(f"{args.timing_size:>5d}x{args.timing_size:<5d} {1e3 * np.median(times):17.1f} {1e3 * min(times):8.1f} "
          f"{t_render:9.2f}")


if __name__ == "__main__":
    main()
