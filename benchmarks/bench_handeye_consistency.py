"""Is the reported hand-eye covariance right? Monte-Carlo NEES of the joint hand-eye estimate.

Run: ``.venv/bin/python benchmarks/bench_handeye_consistency.py [--trials 200] [--stations 15]``

Setting: a study (``jcalib.study``: cell spec, truth drawn per trial, ``jcalib.sim.observe``, solved by
``jcalib.calibrate_batch``): a 1600x1200 opencv5 camera, a 9x6 board (25 mm), 15 random stations,
0.2 px corner noise, robot noise 0.1 mm / 0.01 deg per axis; a new hand-eye transform, stations and
noise every trial (fixed seeds). For each trial the normalised squared error

    NEES = δᵀ Σ⁻¹ δ,   T_est = T_true · Exp(δ)   (right perturbation, (rx, ry, rz, tx, ty, tz))

of ``T_flange_cam`` (eye-in-hand) or ``T_base_cam`` (eye-to-hand) is computed with the reported
6x6 covariance Σ (a-posteriori scale, as users get it). If Σ is right, NEES ~ χ²(6): mean 6, the
mean of N trials inside the printed 95 % band ``χ²_{6N}(0.025, 0.975) / N``, 95 % of trials below
``χ²_6(0.95) = 12.59``. Per-axis ratio: reported σ (RMS over trials) / empirical RMS of δ; 1 if
right. The last row shows what an unmodelled robot error does (pose model off on the same data).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.stats import chi2

from jcalib.study import run_study

AXES = ("rx_deg", "ry_deg", "rz_deg", "tx_mm", "ty_mm", "tz_mm")
KNOWN = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]


def scenario(mount: str, intrinsics: str, pose_model, args) -> dict:
    """Eye-in-hand (camera on the flange, board fixed) or eye-to-hand (camera fixed, board on the flange)."""
    cam = {"model": "opencv5", "mount": "flange" if mount == "flange" else "base"}
    if intrinsics == "known":
        cam["fix"] = KNOWN  # held at the trial's truth
    robot_m = 1e-3 * args.robot_mm
    options = {"sigma_px": args.sigma_px, **({} if pose_model is None else {"pose_model": pose_model})}
    return {"cell": {"cameras": {"cam0": cam},
                     "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025,
                                           "mount": "base" if mount == "flange" else "flange"}},
                     "robot": {"pose_noise": {"translation_m": robot_m, "rotation_deg": args.robot_deg}}},
            "noise": {"pixel_sigma_px": args.sigma_px, "robot_translation_m": robot_m,
                      "robot_rotation_deg": args.robot_deg},
            "stations": {"strategy": "random", "count": args.stations},
            "estimators": [{"name": "joint", "options": options}]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--stations", type=int, default=15)
    parser.add_argument("--sigma-px", type=float, default=0.2)
    parser.add_argument("--robot-mm", type=float, default=0.1)
    parser.add_argument("--robot-deg", type=float, default=0.01)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    configs = [  # (label, mount, intrinsics, pose_model)
        ("eye-in-hand  T_flange_cam", "flange", "free", None),
        ("eye-in-hand  T_flange_cam", "flange", "known", None),
        ("eye-to-hand  T_base_cam", "base", "free", None),
        ("eye-to-hand  T_base_cam", "base", "known", None),
        ("eye-in-hand  T_flange_cam", "flange", "free", False),
    ]
    n = args.trials
    lo, hi = chi2.ppf([0.025, 0.975], 6 * n) / n
    q95 = chi2.ppf(0.95, 6)
    print(f"\nHand-eye covariance consistency: {n} trials, {args.stations} stations, {args.sigma_px} px, robot "
          f"{args.robot_mm} mm / {args.robot_deg} deg per axis; reported covariance with the a-posteriori scale")
    print(f"NEES ~ chi2(6) if honest: mean 6, 95 % band of the mean of {n} trials [{lo:.2f}, {hi:.2f}]; "
          f"fraction below chi2_6(0.95) = {q95:.2f} should be 0.95\n")
    head = f"{'unknown':27s} {'intrinsics':10s} {'pose model':10s} {'mean NEES':>9s} {'in band':>7s} {'<q95':>6s} "
    print(head + " ".join(f"{'σ ' + a[:2]:>7s}" for a in AXES) + "   (reported σ / empirical σ)  failed")
    t0 = time.perf_counter()
    for label, mount, intrinsics, pose_model in configs:
        name = "T_flange_cam0" if mount == "flange" else "T_base_cam0"
        rows = run_study(scenario(mount, intrinsics, pose_model, args), n, seed=args.seed, progress=False)
        ok_rows = [r for r in rows if r["status"] == "ok"]
        nees = np.array([r[f"nees_{name}"] for r in ok_rows])
        deltas = np.array([[r[f"err_{name}_{a}"] for a in AXES] for r in ok_rows])
        sds = np.array([[r[f"sigma_{name}_{a}"] for a in AXES] for r in ok_rows])
        ratio = np.sqrt(np.mean(sds**2, axis=0)) / np.sqrt(np.mean(deltas**2, axis=0))
        m = nees.mean()
        ok = "yes" if lo <= m <= hi else "NO"
        pm = "on" if pose_model is None else "off"
        print(f"{label:27s} {intrinsics:10s} {pm:10s} {m:9.2f} {ok:>7s} {np.mean(nees < q95):6.2f} "
              + " ".join(f"{r:7.2f}" for r in ratio) + f"   {len(rows) - len(ok_rows):>28d}")
    print(f"\nwall time {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
