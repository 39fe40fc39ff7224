"""Split-half cross-validation (``jcalib.report.compare.split_half_comparison``) over simulated data sets.

Per trial: a fresh set of ``--views`` random board views of a strongly distorted opencv5 lens (1280x960,
σ = 0.3 px corner noise, fixed seeds), split into even / odd halves, each half calibrated with the same cell,
the two compared (24x18 grid, fitted rotation, per-point 2-dof χ²). Printed per lens model:

- the fraction of trials with the verdict "consistent" (right model: ≥ 95 % wanted, ~99 % expected; a wrong
  model: the fraction *not* flagged);
- the mean per-point χ² over the grid and the trials, against its prediction (≈ 2, ± its σ over the trials);
- the median RMS difference and RMS predicted σ over the grid (px), and the residual RMS of a half (px).

The models: ``opencv5`` (right), ``opencv5 k3=0`` (k3 held at 0, true −0.02: a small model error),
``k1 only`` (k2, p1, p2, k3 held at 0), ``no distortion`` (all held at 0: a pinhole on a barrel lens).

Run: ``.venv/bin/python benchmarks/bench_compare.py [--trials 100] [--views 20]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.report.compare import split_half_comparison
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
CAMERA = camera_from_opencv(np.array([[900.0, 0, 640.0], [0, 905.0, 481.0], [0, 0, 1]]),
                            np.array([-0.3, 0.12, 1e-3, -5e-4, -0.02]), (1280, 960))
SIGMA_PX = 0.3
MODELS = {
    "opencv5 (right model)": [],
    "opencv5, k3 = 0": ["k3"],
    "k1 only": ["k2", "p1", "p2", "k3"],
    "no distortion": ["k1", "k2", "p1", "p2", "k3"],
}


def observations(rng: np.random.Generator, num_views: int):
    stations = []
    for i, T in enumerate(random_calibration_views(CAMERA, BOARD.points, num_views, rng=rng)):
        pix, _ = project_target(CAMERA, T, BOARD.points)
        pix = pix + SIGMA_PX * rng.standard_normal(pix.shape)
        stations.append({"id": f"v{i:03d}", "detections": [{
            "camera": "cam0", "target": "board", "point_index": list(range(len(BOARD.points))),
            "pixels": pix.tolist()}]})
    return parse_observations({"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": [1280, 960]}},
                               "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations})


def cell(fix: list[str]):
    cam = {"model": "opencv5", **({"fix": fix} if fix else {})}
    return parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam0": cam},
                       "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100, help="simulated data sets per lens model")
    parser.add_argument("--views", type=int, default=20, help="views per data set (two halves)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rows = []
    for label, fix in MODELS.items():
        rng = np.random.default_rng(args.seed)  # the same data sets for every model
        spec = cell(fix)
        t0 = time.perf_counter()
        verdicts, means, expected, variances, rms, sig, res = [], [], [], [], [], [], []
        for _ in range(args.trials):
            cv = split_half_comparison(spec, observations(rng, args.views))
            c = cv.comparisons["cam0"]
            verdicts.append(c.verdict == "consistent")
            means.append(c.chi2_mean)
            expected.append(c.chi2_mean_expected)
            variances.append(c.chi2_mean_std ** 2)
            rms.append(c.rms_px)
            sig.append(c.sigma_rms_px)
            res.append(cv.results[0].file.stats["rms_px"])
        n = args.trials
        rows.append((label, f"{np.mean(verdicts):.0%}", f"{1 - np.mean(verdicts):.0%}", f"{np.mean(means):.2f}",
                     f"{np.mean(expected):.2f} ± {np.sqrt(np.sum(variances)) / n:.2f}", f"{np.median(rms):.3g}",
                     f"{np.median(sig):.3g}", f"{np.median(res):.3g}", f"{time.perf_counter() - t0:.0f}"))
    head = ("lens model", "consistent", "flagged", "mean χ²", "expected", "RMS diff px", "RMS σ px",
            "residual RMS px", "time s")
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    print(f"split-half cross-validation: {args.trials} data sets of {args.views} views (halves of "
          f"{args.views // 2}), opencv5 barrel lens 1280x960, σ {SIGMA_PX} px, grid 24x18")
    print("  ".join(h.ljust(w) for h, w in zip(head, widths)))
    for r in rows:
        print("  ".join(v.ljust(w) for v, w in zip(r, widths)))


if __name__ == "__main__":
    main()
