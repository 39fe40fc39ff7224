"""Pivot calibration on real tracker data: linear solve vs the engine's joint refinement, and how
honest the reported uncertainty is.

Data: ``tests/data/real/pivot_ucl_ndi`` (1151 poses of a tracked pointer pivoting in a divot, NDI
optical tracker, mm; file names are time stamps in ns). Prints the tip and pivot from plain numpy
least squares, :func:`jcalib.init.pivot.pivot_calibration` (closed form), :func:`refine_pivot` (engine)
and the sphere fit; the residual RMS; the a-posteriori sigma and the reported standard deviations
(independent, isotropic residuals); then two checks of that noise model on these data: the lag-1
autocorrelation of the residuals (consecutive poses share their error) and a moving-block bootstrap
of the tip (blocks of consecutive poses resampled, which keeps that correlation), whose spread is
the more realistic uncertainty, and the serial-correlation (Newey-West) covariance of
:func:`refine_pivot`. Last, solve times.

    .venv/bin/python benchmarks/bench_pivot.py [--data DIR] [--block 50] [--boot 200]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path,
                    default=Path(__file__).resolve().parents[1] / "tests" / "data" / "real" / "pivot_ucl_ndi")
    ap.add_argument("--block", type=int, default=200, help="bootstrap block length (consecutive poses)")
    ap.add_argument("--boot", type=int, default=200, help="bootstrap resamples")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    import jcalib  # noqa: F401  (float64)
    from jcalib.init.pivot import pivot_calibration, pivot_sphere_fit
    from jcalib.problems.pivot import refine_pivot

    files = sorted((args.data / "matrices").glob("*.txt"))
    T = np.stack([np.loadtxt(f) for f in files])
    stamps = np.array([int(f.stem) for f in files], dtype=np.int64)
    n = T.shape[0]
    dt_ms = np.median(np.diff(stamps)) / 1e6
    print(f"{n} poses from {args.data} (median {dt_ms:.1f} ms apart, {(stamps[-1] - stamps[0]) / 1e9:.1f} s)")

    # plain numpy least squares, the reference
    A = np.zeros((3 * n, 6))
    A[:, :3] = T[:, :3, :3].reshape(3 * n, 3)
    A[:, 3:] = -np.tile(np.eye(3), (n, 1))
    b = -T[:, :3, 3].reshape(-1)
    ref = np.linalg.lstsq(A, b, rcond=None)[0]

    lin = pivot_calibration(T)
    res = refine_pivot(T)
    sph = pivot_sphere_fit(T)

    def row(name, tip, piv):
        print(f"{name:28s}" + "".join(f"{v:11.4f}" for v in tip) + "   " + "".join(f"{v:11.4f}" for v in piv))

    print()
    print(f"{'':28s}{'tip x':>11s}{'tip y':>11s}{'tip z':>11s}   {'pivot x':>11s}{'pivot y':>11s}{'pivot z':>11s}  (mm)")
    row("numpy lstsq (reference)", ref[:3], ref[3:])
    row("closed form (init.pivot)", lin.p_flange_tip, lin.p_base_pivot)
    row("refine_pivot (engine)", res.p_flange_tip, res.p_base_pivot)
    row("sphere fit", sph.p_flange_tip, sph.p_base_pivot)
    d_tip = np.max(np.abs(res.p_flange_tip - ref[:3]))
    d_piv = np.max(np.abs(res.p_base_pivot - ref[3:]))
    print(f"engine vs numpy: max |d tip| = {d_tip:.2e} mm, max |d pivot| = {d_piv:.2e} mm "
          f"(acceptance < 0.01 mm: {'met' if max(d_tip, d_piv) < 0.01 else 'NOT met'}); "
          f"{res.iterations} LM iterations, status {res.status}")
    print()
    print(f"residual RMS per coordinate {res.rms:.3f} mm, RMS 3-D tip distance {res.rms_distance:.3f} mm, "
          f"max {np.max(np.linalg.norm(res.residuals, axis=1)):.3f} mm")
    print(f"a-posteriori sigma per coordinate {res.sigma:.3f} mm (3N - 6 = {3 * n - 6} dof)")
    print("reported std (independent residuals):  tip " + " ".join(f"{v:.3f}" for v in res.tip_std)
          + " mm, pivot " + " ".join(f"{v:.3f}" for v in res.pivot_std) + " mm")

    # --- is the noise model right? consecutive poses
    r = res.residuals
    rc = r - r.mean(axis=0)
    rho1 = np.sum(rc[1:] * rc[:-1], axis=0) / np.sum(rc * rc, axis=0)
    print("lag-1 autocorrelation of the residuals (x, y, z): " + " ".join(f"{v:.3f}" for v in rho1))
    rng = np.random.default_rng(args.seed)
    nb = int(np.ceil(n / args.block))
    tips = []
    for _ in range(args.boot):
        starts = rng.integers(0, n - args.block + 1, nb)
        idx = np.concatenate([np.arange(s, s + args.block) for s in starts])[:n]
        tips.append(pivot_calibration(T[idx]).p_flange_tip)
    boot_std = np.std(np.stack(tips), axis=0, ddof=1)
    print(f"moving-block bootstrap ({args.boot} x blocks of {args.block} poses): tip std "
          + " ".join(f"{v:.3f}" for v in boot_std) + " mm  = "
          + " ".join(f"{v:.1f}" for v in boot_std / res.tip_std) + " x the reported std")
    n_eff = n * float(np.mean((res.tip_std / boot_std) ** 2))
    print(f"  -> effective number of independent poses ~ {n_eff:.0f} of {n}")
    ser = refine_pivot(T, serial_correlation=True)
    print("refine_pivot(serial_correlation=True), Newey-West (prewhitened, bandwidth "
          f"{ser.serial_bandwidth}): tip std " + " ".join(f"{v:.3f}" for v in ser.tip_std)
          + " mm, pivot std " + " ".join(f"{v:.3f}" for v in ser.pivot_std) + " mm")

    # --- timing (after compilation), medians
    def med(fn, k=7):
        ts = []
        for _ in range(k):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        return 1e3 * float(np.median(ts))

    print()
    print(f"time: numpy lstsq {med(lambda: np.linalg.lstsq(A, b, rcond=None)):.2f} ms, closed form "
          f"{med(lambda: pivot_calibration(T)):.2f} ms, refine_pivot {med(lambda: refine_pivot(T)):.1f} ms "
          "(engine solve + covariance, compiled)")


if __name__ == "__main__":
    main()
