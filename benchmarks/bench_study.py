"""Strategy-study throughput: trials per second of the hand-eye study on each backend.

Run: ``.venv/bin/python benchmarks/bench_study.py [--trials 32] [--stations 15] [--batch-size 8] [--camera]``

The study (``jcalib.study``): eye-in-hand, 1600x1200 opencv5 camera with known intrinsics, 9x6 board,
``--stations`` random stations, 0.2 px corners, robot 0.1 mm / 0.01 deg; estimators: the five closed
forms (jcalib's, on cv2.solvePnP poses), the joint solve pixels-only and with the robot pose model.
One trial = simulate + all seven estimators.

Rows (compilation excluded everywhere: each process solves one warm-up study first, timed apart):
- sequential loop: ``run_study(batch_size=1)`` in this process, one trial at a time;
- local batched: ``run_study(batch_size=B)`` in this process: each joint estimator solves the batch
  with one ``calibrate_hand_eye_batch`` call (host preparation per trial, then the B main solves in
  one vmapped jitted call and the B covariance systems of the pose model in another);
- Dask: ``run_study(backend="dask")`` on a ``LocalCluster(2 workers, 1 thread each, 127.0.0.1)``,
  one task per batch (workers warmed up first with one batch of B each; their warm-up time is printed);
- OpenCV closed forms alone: ``cv2.calibrateHandEye`` with its five methods on precomputed PnP poses
  (the scale of a closed-form-only study).
With ``--camera`` also the camera study (12 random views, jcalib joint + OpenCV): sequential vs
vmapped batches of ``calibrate_cameras_batch``.

Then where a joint hand-eye solve spends its time (``joint_pose_model`` on the same trials, ms per
trial): the host preparation alone (gather, Zhang/PnP starts, closed form, problem), the per-trial
``calibrate_hand_eye`` loop and ``calibrate_hand_eye_batch`` in sub-batches of B.

Timings on shared CPUs move by ±30-50 % between runs: compare rows of one run.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def _handeye_scenario(stations: int) -> dict:
    return {
        "cell": "handeye",
        "noise": {"pixel_sigma_px": 0.2, "robot_translation_m": 1e-4, "robot_rotation_deg": 0.01, "dropout_rate": 0.0},
        "stations": {"strategy": "random", "count": stations},
        "estimators": ["tsai_lenz", "park_martin", "horaud", "andreff", "daniilidis", "joint", "joint_pose_model"],
    }


def _camera_scenario() -> dict:
    return {"cell": "camera", "noise": {"pixel_sigma_px": 0.2}, "stations": {"strategy": "random", "count": 12},
            "estimators": ["joint", "opencv"]}


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def _opencv_closed_forms(scenario, trials: int, seed: int) -> float:
    """Seconds for cv2.calibrateHandEye (5 methods) on ``trials`` precomputed trials."""
    import cv2

    from jcalib.study import load_scenario, simulate_trial
    from jcalib.study.simulate import camera_model

    sc = load_scenario(scenario)
    K, dist = (np.asarray(a) for a in camera_model(sc).to_opencv())
    data = []
    for k in range(trials):
        d = simulate_trial(sc, seed, k)
        Rs, ts = [], []
        for idx, pix in zip(d.point_index, d.pixels):
            _, r, t = cv2.solvePnP(d.points[idx], pix, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
            Rs.append(cv2.Rodrigues(r)[0])
            ts.append(t)
        data.append((list(d.T_base_flange[:, :3, :3]), list(d.T_base_flange[:, :3, 3]), Rs, ts))
    methods = [cv2.CALIB_HAND_EYE_TSAI, cv2.CALIB_HAND_EYE_PARK, cv2.CALIB_HAND_EYE_HORAUD,
               cv2.CALIB_HAND_EYE_ANDREFF, cv2.CALIB_HAND_EYE_DANIILIDIS]
    t0 = time.perf_counter()
    for Rg, tg, Rc, tc in data:
        for m in methods:
            cv2.calibrateHandEye(Rg, tg, Rc, tc, method=m)
    return time.perf_counter() - t0


def _breakdown(scenario, trials: int, seed: int, B: int) -> list[tuple[str, float]]:
    """ms per trial of the joint solve with the pose model: host preparation, loop, batched."""
    from jcalib.io.cell import load_cell
    from jcalib.io.observations import load_observations
    from jcalib.problems import handeye
    from jcalib.study import load_scenario, simulate_trial
    from jcalib.study.estimators import _handeye_cell, _handeye_obs

    sc = load_scenario(scenario)
    cell = load_cell(_handeye_cell(sc, True))
    obs = [load_observations(_handeye_obs(sc, simulate_trial(sc, seed, k))) for k in range(trials)]
    opt = handeye.HandEyeOptions(sigma_px=sc.noise.pixel_sigma_px, pose_model=True)
    handeye.calibrate_hand_eye_batch(cell, obs[:B], opt)  # warm (compiled by the study already)
    for o in obs:  # warm: the single-solve path compiles per padded shape
        handeye.calibrate_hand_eye(cell, o, opt)
    out = []
    dt, _ = _timed(lambda: [handeye._prepare(cell, o, opt) for o in obs])
    out.append(("host preparation only (gather, starts, closed form)", dt))
    dt, _ = _timed(lambda: [handeye.calibrate_hand_eye(cell, o, opt) for o in obs])
    out.append(("calibrate_hand_eye, loop", dt))
    dt, _ = _timed(lambda: [handeye.calibrate_hand_eye_batch(cell, obs[s:s + B], opt) for s in range(0, trials, B)])
    out.append((f"calibrate_hand_eye_batch, batches of {B}", dt))
    return [(name, 1e3 * t / trials) for name, t in out]


def _medians(table) -> dict:
    rows = table.to_dict("records") if hasattr(table, "to_dict") else table
    out = {}
    for e in dict.fromkeys(r["estimator"] for r in rows):
        rr = [r for r in rows if r["estimator"] == e and r["status"] == "ok"]
        out[e] = (np.median([r["err_rot_deg"] for r in rr]), np.median([r["err_trans_mm"] for r in rr]),
                  np.median([r["runtime_s"] for r in rr]) * 1e3)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=32)
    parser.add_argument("--stations", type=int, default=15)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-dask", action="store_true")
    parser.add_argument("--camera", action="store_true", help="also the camera study (vmapped batches)")
    args = parser.parse_args()

    import jcalib  # noqa: F401
    from jcalib.study import run_study

    sc = _handeye_scenario(args.stations)
    n, B = args.trials, args.batch_size
    rows = []
    # warm-up: compile the solves for a batch of 1 (the sequential row) and of B (the batched rows)
    warm, _ = _timed(lambda: (run_study(sc, 1, seed=10_000 + args.seed, batch_size=1, progress=False),
                              run_study(sc, B, seed=10_001 + args.seed, batch_size=B, progress=False)))
    dt, seq = _timed(lambda: run_study(sc, n, seed=args.seed, batch_size=1, progress=False))
    rows.append(("hand-eye", "sequential loop (this process)", n, dt))
    dt, _ = _timed(lambda: run_study(sc, n, seed=args.seed, batch_size=B, progress=False))
    rows.append(("hand-eye", f"local batched (batch {B})", n, dt))
    dask_warm = None
    if not args.no_dask:
        from dask.distributed import Client, LocalCluster

        with LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None) as cluster, \
                Client(cluster) as client:
            dask_warm, _ = _timed(lambda: run_study(sc, 2 * B, seed=20_000 + args.seed, backend="dask",
                                                    batch_size=B, client=client, progress=False))
            dt, _ = _timed(lambda: run_study(sc, n, seed=args.seed, backend="dask", batch_size=B, client=client,
                                             progress=False))
            rows.append(("hand-eye", f"Dask LocalCluster, 2 workers (batch {B})", n, dt))
    dt = _opencv_closed_forms(sc, n, args.seed)
    rows.append(("hand-eye", "OpenCV calibrateHandEye x5 methods only", n, dt))
    if args.camera:
        cs = _camera_scenario()
        _timed(lambda: (run_study(cs, 1, seed=1, batch_size=1, progress=False),
                                      run_study(cs, B, seed=2, batch_size=B, progress=False)))
        dt, _ = _timed(lambda: run_study(cs, n, seed=args.seed, batch_size=1, progress=False))
        rows.append(("camera", "sequential loop (calibrate_cameras_batch of 1)", n, dt))
        dt, _ = _timed(lambda: run_study(cs, n, seed=args.seed, batch_size=B, progress=False))
        rows.append(("camera", f"vmapped batches of {B}", n, dt))

    print(f"\nStudy throughput: {n} trials, {args.stations} stations, 7 estimators per hand-eye trial "
          f"(compile excluded: warm-up {warm:.1f} s here"
          + (f", {dask_warm:.1f} s for the Dask workers" if dask_warm is not None else "") + ")\n")
    print(f"{'study':9s} {'backend':48s} {'trials':>6s} {'wall s':>8s} {'trials/s':>9s}")
    for study, name, k, dt in rows:
        print(f"{study:9s} {name:48s} {k:6d} {dt:8.2f} {k / dt:9.2f}")
    print(f"\nJoint hand-eye with the pose model, ms per trial ({n} trials):")
    for name, ms in _breakdown(sc, n, args.seed, B):
        print(f"  {name:55s} {ms:8.2f}")
    print("\nHand-eye medians (sequential run): estimator, rotation deg, translation mm, runtime ms")
    for e, (r, t, ms) in _medians(seq).items():
        print(f"  {e:18s} {r:8.4f} {t:8.4f} {ms:8.2f}")


if __name__ == "__main__":
    main()
