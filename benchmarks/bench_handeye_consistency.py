"""Is the reported hand-eye covariance right? Monte-Carlo NEES of the joint hand-eye estimate.

Run: ``.venv/bin/python benchmarks/bench_handeye_consistency.py [--trials 200] [--stations 15]``

Setting: the synthetic scene of ``tests/problems/test_handeye_joint.py`` (1600x1200 opencv5 camera,
9x6 board, 15 random stations), 0.2 px corner noise, robot noise 0.1 mm / 0.01 deg per axis; a new
scene and new noise every trial (fixed seeds). For each trial the normalised squared error

    NEES = δᵀ Σ⁻¹ δ,   T_true = T_est · Exp(δ)   (right perturbation, (rx, ry, rz, tx, ty, tz))

of ``T_flange_cam`` (eye-in-hand) or ``T_base_cam`` (eye-to-hand) is computed with the reported
6x6 covariance Σ (a-posteriori scale, as users get it). If Σ is right, NEES ~ χ²(6): mean 6, the
mean of N trials inside the printed 95 % band ``χ²_{6N}(0.025, 0.975) / N``, 95 % of trials below
``χ²_6(0.95) = 12.59``. Per-axis ratio: reported σ (RMS over trials) / empirical RMS of δ; 1 if
right. The last row shows what an unmodelled robot error does (pose model off on the same data).
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from jcalib.geometry import lie
from jcalib.io.cell import load_cell
from jcalib.io.observations import load_observations
from jcalib.problems.handeye import HandEyeOptions, calibrate_hand_eye

_path = Path(__file__).resolve().parents[1] / "tests" / "problems" / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers", _path)
T = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(T)

AXES = ("rx", "ry", "rz", "tx", "ty", "tz")


def nees_of(T_est: np.ndarray, T_true: np.ndarray, cov: np.ndarray) -> tuple[float, np.ndarray]:
    """(NEES, δ (6,)) with ``T_true = T_est · Exp(δ)``."""
    delta = np.asarray(lie.local(lie.se3_from_matrix(T_est), lie.se3_from_matrix(T_true)))
    return float(delta @ np.linalg.solve(cov, delta)), delta


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
    print(head + " ".join(f"{'σ ' + a:>7s}" for a in AXES) + "   (reported σ / empirical σ)")
    t0 = time.perf_counter()
    for label, mount, intrinsics, pose_model in configs:
        nees, deltas, sds = [], [], []
        for trial in range(n):
            cell, obs, truth = T.make_data(10_000 * args.seed + trial, mount, n=args.stations, sigma_px=args.sigma_px,
                                           robot_m=1e-3 * args.robot_mm, robot_deg=args.robot_deg)
            if intrinsics == "known":
                cell = T.with_known_intrinsics(cell)
            cal = calibrate_hand_eye(load_cell(cell), load_observations(obs),
                                     HandEyeOptions(sigma_px=args.sigma_px, pose_model=pose_model))
            e, d = nees_of(cal.T_hand_eye, truth["T_hand_eye"], cal.T_hand_eye_covariance)
            nees.append(e)
            deltas.append(d)
            sds.append(np.diag(cal.T_hand_eye_covariance))
        nees, deltas, sds = np.array(nees), np.array(deltas), np.array(sds)
        ratio = np.sqrt(sds.mean(axis=0)) / np.sqrt(np.mean(deltas**2, axis=0))
        m = nees.mean()
        ok = "yes" if lo <= m <= hi else "NO"
        pm = "on" if pose_model is None else "off"
        print(f"{label:27s} {intrinsics:10s} {pm:10s} {m:9.2f} {ok:>7s} {np.mean(nees < q95):6.2f} "
              + " ".join(f"{r:7.2f}" for r in ratio))
    print(f"\nwall time {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
