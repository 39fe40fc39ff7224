"""Joint hand-eye vs OpenCV's closed forms: accuracy over many synthetic eye-in-hand trials.

Run: ``.venv/bin/python benchmarks/bench_handeye.py [--trials 100] [--stations 15]``

Setting (the generator of ``tests/problems/test_handeye_joint.py``, itself built on the scene of
``tests/init/test_handeye.py``): a 1600x1200 opencv5 camera (fx 1400 px, k1 -0.12) on the flange
looks at a 9x6 board (25 mm) from 0.35-0.7 m, tilted up to +-40 deg, roll +-30 deg; random
``T_flange_cam``. Corner pixels get N(0, 0.2 px) per axis; the recorded flange poses are the true
ones rotated by N(0, 0.01 deg) per axis and shifted by N(0, 0.1 mm) per axis.

Rows (errors of ``T_flange_cam``: rotation angle, deg; translation distance, mm; medians):
- known intrinsics (the setting of the issue target and of bench_handeye_closed_forms.py):
  OpenCV ``calibrateHandEye`` (5 methods) on ``cv2.solvePnP`` poses with the true intrinsics;
  jcalib joint with the intrinsics fixed to the truth, pixels only (poses exact) and with the
  robot-pose model (per-station corrections under the stated prior).
- estimated intrinsics: OpenCV closed forms on PnP poses from ``cv2.calibrateCamera`` intrinsics;
  jcalib joint with free intrinsics, pixels only and with the pose model.
Issue target: with the pose model, median translation error <= 0.5x and rotation <= 0.8x the best
closed form (best per column).
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import cv2
import numpy as np

from jcalib.geometry import lie
from jcalib.init.handeye import HAND_EYE_METHODS
from jcalib.io.cell import load_cell
from jcalib.io.observations import load_observations
from jcalib.problems.handeye import HandEyeOptions, calibrate_hand_eye

_path = Path(__file__).resolve().parents[1] / "tests" / "problems" / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers", _path)
T = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(T)
H = T.H

def _opencv_intrinsics(obs):
    obj = [H.BOARD[s["detections"][0]["point_index"]].astype(np.float32) for s in obs["stations"]]
    img = [np.asarray(s["detections"][0]["pixels"], np.float32) for s in obs["stations"]]
    _, K, dist, _, _ = cv2.calibrateCamera(obj, img, T.IMAGE_SIZE, None, None,
                                           criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    return K, dist.ravel()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--stations", type=int, default=15)
    parser.add_argument("--sigma-px", type=float, default=0.2)
    parser.add_argument("--robot-mm", type=float, default=0.1)
    parser.add_argument("--robot-deg", type=float, default=0.01)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-free-intrinsics", action="store_true", help="skip the estimated-intrinsics rows")
    args = parser.parse_args()

    K_true, dist_true = (np.asarray(a) for a in T.CAMERA.to_opencv())
    rows: dict[str, dict[str, list[float]]] = {}

    def record(group, name, T_est, T_true, dt=float("nan"), cov=None):
        d_rot, d_t = T._errors(T_est, T_true)
        r = rows.setdefault((group, name), {"rot": [], "t": [], "time": [], "nees": []})
        r["rot"].append(d_rot)
        r["t"].append(1e3 * d_t)
        r["time"].append(dt)
        if cov is not None:  # normalised squared error: T_true = T_est Exp(delta), chi2(6) if honest
            delta = np.asarray(lie.local(lie.se3_from_matrix(T_est), lie.se3_from_matrix(T_true)))
            r["nees"].append(float(delta @ np.linalg.solve(cov, delta)))

    robot = {}
    t_start = time.perf_counter()
    for trial in range(args.trials):
        cell, obs, truth = T.make_data(10_000 * args.seed + trial, "flange", n=args.stations, sigma_px=args.sigma_px,
                                       robot_m=1e-3 * args.robot_mm, robot_deg=args.robot_deg)
        X = truth["T_hand_eye"]
        c_obs = load_observations(obs)
        # known intrinsics
        T_ct = T.pnp_poses(obs, K_true, dist_true)
        for m, cv_name in HAND_EYE_METHODS.items():
            record("known intrinsics", f"OpenCV {cv_name}", H.opencv_hand_eye(truth["T_base_flange"], T_ct, m), X)
        c_fixed = load_cell(T.with_known_intrinsics(cell))
        for label, pose_model in (("jcalib joint, pixels only", False), ("jcalib joint + robot pose model", True)):
            t0 = time.perf_counter()
            cal = calibrate_hand_eye(c_fixed, c_obs, HandEyeOptions(sigma_px=args.sigma_px, pose_model=pose_model))
            record("known intrinsics", label, cal.T_hand_eye, X, time.perf_counter() - t0, cal.T_hand_eye_covariance)
            if pose_model:
                for k in ("a_posteriori_sigma_translation_m", "a_posteriori_sigma_rotation_deg"):
                    robot.setdefault(k, []).append(float(np.mean(cal.robot[k])))
        if args.no_free_intrinsics:
            continue
        K_cv, dist_cv = _opencv_intrinsics(obs)
        T_ct = T.pnp_poses(obs, K_cv, dist_cv)
        for m, cv_name in HAND_EYE_METHODS.items():
            record("estimated intrinsics", f"OpenCV {cv_name}", H.opencv_hand_eye(truth["T_base_flange"], T_ct, m), X)
        c_free = load_cell(cell)
        for label, pose_model in (("jcalib joint, pixels only", False), ("jcalib joint + robot pose model", True)):
            t0 = time.perf_counter()
            cal = calibrate_hand_eye(c_free, c_obs, HandEyeOptions(sigma_px=args.sigma_px, pose_model=pose_model))
            record("estimated intrinsics", label, cal.T_hand_eye, X, time.perf_counter() - t0,
                   cal.T_hand_eye_covariance)
    wall = time.perf_counter() - t_start

    print(f"\nEye-in-hand, {args.trials} trials, {args.stations} stations, {args.sigma_px} px, "
          f"robot {args.robot_mm} mm / {args.robot_deg} deg per axis (medians; solve time "
          f"median, so the first call's compile does not count)\n")
    print(f"{'intrinsics':22s} {'method':40s} {'rot deg':>9s} {'trans mm':>9s} {'time ms':>9s} {'NEES':>7s}")
    for group in ("known intrinsics", "estimated intrinsics"):
        keys = [k for k in rows if k[0] == group]
        if not keys:
            continue
        best_rot = min(np.median(rows[k]["rot"]) for k in keys if k[1].startswith("OpenCV"))
        best_t = min(np.median(rows[k]["t"]) for k in keys if k[1].startswith("OpenCV"))
        for k in keys:
            r = rows[k]
            tm = np.nanmedian(r["time"]) * 1e3 if np.any(np.isfinite(r["time"])) else float("nan")
            nees = f"{np.mean(r['nees']):7.2f}" if r["nees"] else f"{'':7s}"
            print(f"{group:22s} {k[1]:40s} {np.median(r['rot']):9.4f} {np.median(r['t']):9.4f} {tm:9.1f} {nees}")
        j = rows[(group, "jcalib joint + robot pose model")]
        print(f"{'':22s} {'ratio pose model / best closed form':40s} {np.median(j['rot']) / best_rot:9.2f} "
              f"{np.median(j['t']) / best_t:9.2f}   (target <= 0.8 rot, <= 0.5 trans)")
    print(f"\nestimated robot sigma (median over trials, mean over axes): "
          f"{1e3 * np.median(robot['a_posteriori_sigma_translation_m']):.4f} mm, "
          f"{np.median(robot['a_posteriori_sigma_rotation_deg']):.4f} deg "
          f"(true {args.robot_mm} mm, {args.robot_deg} deg)")
    print("NEES: mean of delta^T cov^-1 delta for T_flange_cam (reported a-posteriori covariance); 6 if honest.")
    print(f"wall time {wall:.1f} s")


if __name__ == "__main__":
    main()
