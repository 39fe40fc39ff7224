"""Pose-pair hand-eye (AX = YB per station, no pixels): the camodocal real set and a Monte-Carlo study.

Run: ``.venv/bin/python benchmarks/bench_handeye_pairs.py [--trials 100] [--stations 12]``

1. Real data, ``tests/data/real/handeye_camodocal_example`` (jhu-lcsr/handeye_calib_camodocal,
   42 pairs, AR marker on the gripper, camera fixed: eye-to-hand). Prints X = ``T_base_cam`` and
   Y = ``T_flange_target`` (the marker in the end-effector frame, the source project's unknown) with
   their σ per axis, the estimated pose noise, flagged stations, and Y against the source's published
   answer (``CalibratedTransform.yml``; camodocal's dual-quaternion AX = XB + Ceres refinement on
   motions relative to station 0), also without the flagged station, and the closed forms' Y.
2. Synthetic eye-in-hand stations (the scene of ``tests/problems/test_handeye_pairs.py``): measured
   camera poses ``T_true · Exp(ε)``, ε ~ N(0, 0.05 deg / 0.5 mm per axis). Rows: OpenCV's closed
   forms (Park-Martin, Tsai, Daniilidis; Shah for AX = YB) and jcalib's pose-pair LM: median
   rotation / translation error of X, and for jcalib the NEES (mean, ideal 6) and per-axis ratio of
   the Monte-Carlo spread to the mean reported σ (ideal 1).
3. Time per solve (after compilation), median over the trials.
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import cv2
import numpy as np

from jcalib.geometry import lie
from jcalib.problems.handeye_pairs import calibrate_hand_eye_pairs

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / "tests" / "data" / "real" / "handeye_camodocal_example"
_spec = importlib.util.spec_from_file_location("_pairs_helpers", ROOT / "tests" / "problems" / "test_handeye_pairs.py")
T = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(T)

RAD2DEG = np.degrees(1.0)


def load_camodocal():
    from jcalib.io.importers.opencv_pairs import read_calibrated_transform, read_transform_pairs

    T1, T2 = read_transform_pairs(REAL / "TransformPairsInput.yml")
    return T1, T2, read_calibrated_transform(REAL / "CalibratedTransform.yml")


def fmt_pose(name, M, std):
    rv = np.asarray(lie.so3_to_rvec(lie.so3_from_matrix(M[:3, :3])))
    print(f"  {name}: t = ({', '.join(f'{v * 1e3:8.2f}' for v in M[:3, 3])}) mm   "
          f"rvec = ({', '.join(f'{v * RAD2DEG:8.3f}' for v in rv)}) deg")  # fmt: skip
    print(f"  {' ' * len(name)}  σ(rx, ry, rz) = ({', '.join(f'{v * RAD2DEG:.3f}' for v in std[:3])}) deg   "
          f"σ(tx, ty, tz) = ({', '.join(f'{v * 1e3:.3f}' for v in std[3:])}) mm")  # fmt: skip


def compare(res, ref, label):
    d = T.tangent_error(ref, res.T_other)  # Log(Y⁻¹ ref), in Y's tangent
    maha = float(d @ np.linalg.solve(res.T_other_covariance, d))
    dt = (ref[:3, 3] - res.T_other[:3, 3]) * 1e3
    print(f"  {label}: published - ours: Δt = ({', '.join(f'{v:+.2f}' for v in dt)}) mm (|Δt| {np.linalg.norm(dt):.2f} mm), "
          f"Δrot = {np.linalg.norm(d[:3]) * RAD2DEG:.2f} deg; Mahalanobis² {maha:.0f} (chi2(6) 99.9 %: 22.5)")  # fmt: skip


def loop_rms(T1, T2, Y):
    """RMS loop error (deg, mm) of Y with X = chordal mean of the T_base_cam implied per station."""
    Xs = T1 @ Y @ np.linalg.inv(T2)
    u, _, vt = np.linalg.svd(Xs[:, :3, :3].mean(axis=0))
    X = T.pose(u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt, Xs[:, :3, 3].mean(axis=0))
    E = np.linalg.inv(Y) @ np.linalg.inv(T1) @ X @ T2
    r = np.asarray(lie.se3_log(lie.se3_from_matrix(E)))
    return np.degrees(np.sqrt(np.mean(np.sum(r[:, :3] ** 2, 1)))), 1e3 * np.sqrt(np.mean(np.sum(r[:, 3:] ** 2, 1)))


def real_data():
    T1, T2, ref = load_camodocal()
    print(f"== camodocal example (eye-to-hand, {len(T1)} pose pairs) ==")
    t0 = time.perf_counter()
    res = calibrate_hand_eye_pairs(T1, T2, mode="eye_to_hand")
    t1 = time.perf_counter()
    res = calibrate_hand_eye_pairs(T1, T2, mode="eye_to_hand")
    t2 = time.perf_counter()
    print(f"  first call {t1 - t0:.2f} s (compilation), second {1e3 * (t2 - t1):.1f} ms; status {res.status}, "
          f"{res.iterations} LM iterations over {res.noise.iterations} noise re-solves")  # fmt: skip
    fmt_pose("X = T_base_cam     ", res.T_hand_eye, res.T_hand_eye_std)
    fmt_pose("Y = T_flange_target", res.T_other, res.T_other_std)
    fmt_pose("published Y        ", ref, np.zeros(6))
    n = res.noise
    print(f"  estimated pose noise (1σ per axis, loop error at the marker): {n.rotation_deg:.3f} deg, "
          f"{n.translation_m * 1e3:.3f} mm  (redundancy {n.redundancy_rotation:.1f} + {n.redundancy_translation:.1f})")  # fmt: skip
    print(f"  flagged stations: {res.outlier_stations} (chi2 {np.round(res.station_chi2[res.outlier_stations], 1).tolist()})")
    for w in res.warnings:
        print(f"  warning: {w}")
    compare(res, ref, "all 42  ")
    keep = np.setdiff1d(np.arange(len(T1)), res.outlier_stations)
    res2 = calibrate_hand_eye_pairs(T1[keep], T2[keep], mode="eye_to_hand")
    compare(res2, ref, f"without {res.outlier_stations}")
    fmt_pose(f"Y without {res.outlier_stations}", res2.T_other, res2.T_other_std)
    print(f"  noise without them: {res2.noise.rotation_deg:.3f} deg, {res2.noise.translation_m * 1e3:.3f} mm")
    r_ours, t_ours = loop_rms(T1, T2, res.T_other)
    r_ref, t_ref = loop_rms(T1, T2, ref)
    print(f"  RMS station loop error: ours {r_ours:.2f} deg / {t_ours:.2f} mm, published {r_ref:.2f} deg / {t_ref:.2f} mm")
    print("  closed-form Y (start values) vs published, |Δt| mm / Δrot deg:")
    for m in ("park_martin", "tsai_lenz", "horaud", "daniilidis", "shah", "li"):
        r = calibrate_hand_eye_pairs(T1, T2, mode="eye_to_hand", init_method=m)
        d = T.tangent_error(ref, r.init.T_other)
        same = np.abs(T.tangent_error(r.T_other, res.T_other)).max()
        print(f"    {m:12s} {np.linalg.norm(ref[:3, 3] - r.init.T_other[:3, 3]) * 1e3:7.2f} / {np.linalg.norm(d[:3]) * RAD2DEG:5.2f}"
              f"   (LM from it: same optimum to {same:.1e})")  # fmt: skip


def opencv_x(T_bf, T_ct, method):
    R, t = cv2.calibrateHandEye(list(T_bf[:, :3, :3]), list(T_bf[:, :3, 3]), list(T_ct[:, :3, :3]),
                                list(T_ct[:, :3, 3]), method=method)  # fmt: skip
    return T.pose(R, t.ravel())


def synthetic(trials: int, stations: int):
    rng = np.random.default_rng(12345)
    X, _, T_bf, T_ct = T.make_scene(rng, "eye_in_hand", n=stations)
    rows = {k: [] for k in ("cv2 park_martin", "cv2 tsai", "cv2 daniilidis", "cv2 shah (AX=YB)", "jcalib pose pairs")}
    nees, errs, stds, times, sig = [], [], [], [], []
    calibrate_hand_eye_pairs(T_bf, T.perturb(rng, T_ct, T.SIGMA_ROT_DEG, T.SIGMA_T_M))  # compile
    for _ in range(trials):
        noisy = T.perturb(rng, T_ct, T.SIGMA_ROT_DEG, T.SIGMA_T_M)
        for name, method in (("cv2 park_martin", cv2.CALIB_HAND_EYE_PARK), ("cv2 tsai", cv2.CALIB_HAND_EYE_TSAI),
                             ("cv2 daniilidis", cv2.CALIB_HAND_EYE_DANIILIDIS)):  # fmt: skip
            rows[name].append(T.tangent_error(opencv_x(T_bf, noisy, method), X))
        rows["cv2 shah (AX=YB)"].append(T.tangent_error(T.opencv_robot_world(T_bf, noisy, "eye_in_hand")[0], X))
        t0 = time.perf_counter()
        res = calibrate_hand_eye_pairs(T_bf, noisy)
        times.append(time.perf_counter() - t0)
        e = T.tangent_error(res.T_hand_eye, X)
        rows["jcalib pose pairs"].append(e)
        nees.append(e @ np.linalg.solve(res.T_hand_eye_covariance, e))
        errs.append(e)
        stds.append(res.T_hand_eye_std)
        sig.append([res.noise.rotation_deg, res.noise.translation_m])
    print(f"\n== synthetic eye-in-hand: {stations} stations, noise {T.SIGMA_ROT_DEG} deg / {T.SIGMA_T_M * 1e3} mm "
          f"per axis on T_cam_target, {trials} trials ==")  # fmt: skip
    print(f"  {'method':20s} {'median rot err (deg)':>21s} {'median trans err (mm)':>22s}")
    for name, e in rows.items():
        e = np.array(e)
        print(f"  {name:20s} {np.median(np.linalg.norm(e[:, :3], axis=1)) * RAD2DEG:21.4f} "
              f"{np.median(np.linalg.norm(e[:, 3:], axis=1)) * 1e3:22.4f}")  # fmt: skip
    ratio = np.std(np.array(errs), axis=0) / np.mean(np.array(stds), axis=0)
    s = np.mean(np.array(sig), axis=0)
    print(f"  jcalib NEES of T_flange_cam: mean {np.mean(nees):.2f} (ideal 6), median {np.median(nees):.2f} "
          f"(chi2(6) median 5.35); spread / reported σ per axis (rx ry rz tx ty tz): {np.round(ratio, 2).tolist()}")  # fmt: skip
    print(f"  mean estimated noise {s[0]:.4f} deg / {s[1] * 1e3:.4f} mm (true {T.SIGMA_ROT_DEG} / {T.SIGMA_T_M * 1e3})")
    print(f"  time per jcalib solve (incl. noise re-solves): median {1e3 * np.median(times):.1f} ms")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--stations", type=int, default=12)
    args = ap.parse_args()
    real_data()
    synthetic(args.trials, args.stations)


if __name__ == "__main__":
    main()
