"""The splined lens model against the 4-coefficient fisheye on a lens the fisheye cannot describe, and
converting the splined result back to OpenCV models over image regions.

The lens: a stereographic projection with the fisheye scene's focal length and principal point
(``tests/problems/fisheye_scene.py``, 1024x768) plus a smooth, non-radial spline of about 1.3 px (the
truth of ``tests/problems/test_splined_calibration.py``). ``--views`` board views spread over the image
(ChArUco 9x7, partial views at the rim), Gaussian corner noise ``--sigma`` px, ``--trials`` noise draws.

For each model: the corner RMS, the projection error against the truth over the pixels the views cover
(after the rotation that best aligns the camera frames, which a lens model cannot see) as median and
95th percentile, and the wall time of a calibration (the first call compiles). Then the splined result
converted to ``fisheye`` and to ``opencv8`` (``k4..k6`` held) over the central half of the image and
over the whole covered region: the approximation error ``jcalib convert`` reports.

Run: ``.venv/bin/python benchmarks/bench_splined.py [--views 30] [--sigma 0.1] [--trials 3]``
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "problems"))
from fisheye_scene import BOARD, IMAGE_SIZE, board_views, observations, projection_error, splined_truth  # noqa: E402

import jcalib  # noqa: E402
from jcalib.problems.convert import convert_camera  # noqa: E402
from jcalib.sim.scene import project_target  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=30)
    parser.add_argument("--sigma", type=float, default=0.1)
    parser.add_argument("--trials", type=int, default=3)
    args = parser.parse_args()
    truth = splined_truth()
    poses = board_views(truth, BOARD, args.views, seed=3)
    rows = {m: [] for m in ("fisheye", "splined")}
    last = None
    for trial in range(args.trials):
        rng = np.random.default_rng(100 + trial)
        index, pixels = [], []
        for T in poses:
            pix, ok = project_target(truth, T, BOARD.points)
            index.append(np.flatnonzero(ok))
            pixels.append(pix[ok] + args.sigma * rng.standard_normal((int(ok.sum()), 2)))
        obs = observations(index, pixels)
        seen = np.concatenate(pixels)[::5]
        for model in rows:
            cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": model}},
                    "targets": {"board": BOARD.to_spec()}}
            t0 = time.perf_counter()
            result = jcalib.calibrate(cell, obs)
            seconds = time.perf_counter() - t0
            err = projection_error(result.details.cameras["cam0"], truth, seen)
            rows[model].append((result.details.rms_px, np.median(err), np.percentile(err, 95), seconds))
            if model == "splined":
                last = result, seen
    print(f"\n{args.views} views, {args.sigma} px noise, {args.trials} trials; lens: stereographic + 1.3 px "
          "non-radial spline (1024x768, f 331 px)")
    print("| model | corner RMS px | projection error vs truth, median px | 95 % px | time s (first / later) |")
    print("|---|---|---|---|---|")
    for model, r in rows.items():
        a = np.asarray(r)
        later = f"{np.median(a[1:, 3]):.1f}" if len(a) > 1 else "–"
        print(f"| {model} | {np.mean(a[:, 0]):.3f} | {np.mean(a[:, 1]):.3f} | {np.mean(a[:, 2]):.3f} | "
              f"{a[0, 3]:.1f} / {later} |")
    result, seen = last
    cam = result.details.cameras["cam0"]
    cov = result.details.intrinsics_covariance["cam0"]
    w, h = IMAGE_SIZE
    lo, hi = np.maximum(seen.min(axis=0), 0.0), np.minimum(seen.max(axis=0), [w - 1.0, h - 1.0])
    regions = {"central half": (w / 4, h / 4, 3 * w / 4, 3 * h / 4), "covered by the views": (*lo, *hi)}
    print("\nThe splined result converted (jcalib convert): approximation error over the region")
    print("| to | region | RMS px | max px | pixels compared / left out | time s |")
    print("|---|---|---|---|---|---|")
    for to, fix in (("fisheye", ()), ("opencv8", ("k4", "k5", "k6"))):
        for name, region in regions.items():
            t0 = time.perf_counter()
            try:
                c = convert_camera(cam, to, covariance=cov, region=region, fix=fix)
            except jcalib.JcalibError as err:
                print(f"| {to} | {name} | refused: {err} | | | |")
                continue
            print(f"| {to} | {name} | {c.rms_px:.3f} | {c.max_px:.3f} | {c.num_pixels} / {c.num_left_out} | "
                  f"{time.perf_counter() - t0:.1f} |")


if __name__ == "__main__":
    main()
