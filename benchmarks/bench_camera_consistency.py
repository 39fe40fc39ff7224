"""Monte Carlo check that jcalib's reported intrinsic covariance matches the spread of its estimates.

Fixed board poses, fresh Gaussian corner noise of known σ per trial (fixed seeds). For each trial the
camera is calibrated twice (``jcalib.calibrate_cell``, a camera-only cell of the one builder): ``noise="stated"`` (covariance from the stated σ) and
``noise="a_posteriori"`` (default: σ estimated from the residuals). Printed per scenario:
- d² = eᵀ Σ⁻¹ e of the intrinsics against χ²(dof): mean, KS p-value, tail fractions;
- per parameter: reported σ (RMS over trials) / empirical σ (RMS error against the truth).

Run: ``.venv/bin/python benchmarks/bench_camera_consistency.py [--trials 250]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import stats

import jcalib
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
SCENARIOS = {
    "small: 640x480, 10 views, sigma 0.3 px": dict(
        K=[[800.0, 0, 330.0], [0, 805.0, 242.0], [0, 0, 1]], dist=[-0.3, 0.12, 1e-3, -5e-4, -0.02],
        size=(640, 480), views=10, sigma=0.3, seed=3),
    "large: 1280x960, 25 views, sigma 0.5 px": dict(
        K=[[1100.0, 0, 645.0], [0, 1098.0, 478.0], [0, 0, 1]], dist=[-0.25, 0.08, 5e-4, -3e-4, 0.01],
        size=(1280, 960), views=25, sigma=0.5, seed=11),
}


def run(spec: dict, trials: int) -> dict:
    cam = camera_from_opencv(np.array(spec["K"]), np.array(spec["dist"]), spec["size"])
    views = random_calibration_views(cam, BOARD.points, spec["views"], rng=spec["seed"])
    clean = [project_target(cam, T, BOARD.points)[0] for T in views]
    cell = parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv5"}},
                       "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}})
    rng = np.random.default_rng(1000 + spec["seed"])
    truth = np.asarray(cam.params)
    out = {"error": [], "stated": [], "a_posteriori": [], "sigma_hat": [], "status": [], "time": []}
    for _ in range(trials):
        obs = parse_observations({
            "schema": "jcalib.observations/1",
            "cameras": {"cam": {"image_size": list(spec["size"])}},
            "targets": {"board": {"points": BOARD.points.tolist()}},
            "stations": [{"id": f"v{i}", "detections": [{
                "camera": "cam", "target": "board", "point_index": list(range(len(BOARD.points))),
                "pixels": (p + spec["sigma"] * rng.standard_normal(p.shape)).tolist()}]}
                for i, p in enumerate(clean)],
        })
        for noise in ("stated", "a_posteriori"):
            t0 = time.perf_counter()
            cal = jcalib.calibrate_cell(cell, obs, jcalib.CalibrationOptions(noise=noise, sigma_px=spec["sigma"]))
            out["time"].append(time.perf_counter() - t0)
            out[noise].append(cal.intrinsics_covariance["cam"])
            out["status"].append(cal.status)
        out["error"].append(np.asarray(cal.cameras["cam"].params) - truth)
        out["sigma_hat"].append(cal.sigma_px)
    res = {k: np.array(v) for k, v in out.items()}
    res["names"] = cam.param_names
    return res


def report(title: str, spec: dict, r: dict) -> None:
    names, e = r["names"], r["error"]
    dof = len(names)
    n = len(e)
    print(f"\n## {title}  ({n} trials, true sigma {spec['sigma']} px)")
    print(f"solves: {np.mean(r['status'] == 'converged') * 100:.0f}% converged; median solve "
          f"{np.median(r['time'][2:]) * 1e3:.0f} ms; a-posteriori sigma: mean {r['sigma_hat'].mean():.4f} px")
    q = stats.chi2(dof).ppf([0.5, 0.9, 0.99])
    lo, hi = stats.chi2(n * dof).ppf([0.0005, 0.9995]) / n
    print(f"\nd2 = e^T S^-1 e over the {dof} intrinsics; chi2({dof}): mean {dof}, 99.9% band for the mean "
          f"of {n}: [{lo:.2f}, {hi:.2f}]; tail fractions expected 0.50 / 0.10 / 0.01")
    print("| covariance   | mean d2 | KS p   | >q50  | >q90  | >q99  |")
    print("|--------------|---------|--------|-------|-------|-------|")
    for noise in ("stated", "a_posteriori"):
        d2 = np.array([x @ np.linalg.solve(S, x) for x, S in zip(e, r[noise])])
        p = stats.kstest(d2, stats.chi2(dof).cdf).pvalue
        tails = [np.mean(d2 > qq) for qq in q]
        print(f"| {noise:<12} | {d2.mean():7.3f} | {p:6.3f} | {tails[0]:.3f} | {tails[1]:.3f} | {tails[2]:.3f} |")
    emp = np.sqrt(np.mean(e**2, axis=0))
    band = np.sqrt(stats.chi2(n).ppf([0.0005, 0.9995]) / n)
    print(f"\nreported / empirical sigma per parameter (1.0 is honest; sampling 99.9% band for the "
          f"ratio: [{1 / band[1]:.3f}, {1 / band[0]:.3f}])")
    print("| param | empirical sigma | reported (stated) | ratio | reported (a_post.) | ratio |")
    print("|-------|-----------------|-------------------|-------|--------------------|-------|")
    for k, name in enumerate(names):
        st = np.sqrt(np.mean(r["stated"][:, k, k]))
        ap = np.sqrt(np.mean(r["a_posteriori"][:, k, k]))
        print(f"| {name:<5} | {emp[k]:15.4g} | {st:17.4g} | {st / emp[k]:5.3f} | {ap:18.4g} | {ap / emp[k]:5.3f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=250)
    args = parser.parse_args()
    for title, spec in SCENARIOS.items():
        report(title, spec, run(spec, args.trials))


if __name__ == "__main__":
    main()
