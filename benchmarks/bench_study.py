"""Strategy-study throughput: trials per second of the hand-eye study on each backend.

Run: ``.venv/bin/python benchmarks/bench_study.py [--trials 32] [--stations 15] [--batch-size 8] [--camera]``

The study (``jcalib.study``, first scenario form ``cell: handeye``, read as a cell spec): eye-in-hand,
1600x1200 opencv5 camera with known intrinsics, 9x6 board, ``--stations`` random stations, 0.2 px
corners, robot 0.1 mm / 0.01 deg; estimators: the five closed forms (jcalib's, on cv2.solvePnP poses),
the builder pixels-only and with the robot pose model (``jcalib.calibrate_batch``). One trial =
simulate (``jcalib.sim.observe``) + all seven estimators.

Rows (compilation excluded everywhere: each process solves one warm-up study first, timed apart):
- sequential loop: ``run_study(batch_size=1)`` in this process, one trial at a time;
- local batched: ``run_study(batch_size=B)`` in this process: each builder estimator solves the batch
  with one ``calibrate_batch`` call (host preparation per trial, then every refinement round of the B
  data sets in vmapped jitted calls);
- Dask: ``run_study(backend="dask")`` on a ``LocalCluster(2 workers, 1 thread each, 127.0.0.1)``,
  one task per batch (workers warmed up first with one batch of B each; their warm-up time is printed);
- OpenCV closed forms alone: ``cv2.calibrateHandEye`` with its five methods on precomputed PnP poses
  (the scale of a closed-form-only study).
With ``--camera`` also the camera study (12 random views, jcalib joint + OpenCV): sequential vs
vmapped batches of ``calibrate_batch``.

Then where a joint hand-eye solve spends its time (``joint_pose_model`` on the same trials, ms per
trial): the host preparation alone (graph, closed-form starts, problem), the per-trial
``calibrate_cell`` loop and ``calibrate_batch`` in sub-batches of B.

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
    """Seconds for cv2.calibrateHandEye (5 methods) on ``trials`` precomputed trials (PnP poses)."""
    import cv2

    from jcalib.study import load_scenario, simulate_trial
    from jcalib.study.closed_forms import hand_eye_data

    sc = load_scenario(scenario)
    data = []
    for k in range(trials):
        _, _, T_bf, T_ct = hand_eye_data(sc, simulate_trial(sc, seed, k))
        data.append((list(T_bf[:, :3, :3]), list(T_bf[:, :3, 3]), list(T_ct[:, :3, :3]), list(T_ct[:, :3, 3])))
    methods = [cv2.CALIB_HAND_EYE_TSAI, cv2.CALIB_HAND_EYE_PARK, cv2.CALIB_HAND_EYE_HORAUD,
               cv2.CALIB_HAND_EYE_ANDREFF, cv2.CALIB_HAND_EYE_DANIILIDIS]
    t0 = time.perf_counter()
    for Rg, tg, Rc, tc in data:
        for m in methods:
            cv2.calibrateHandEye(Rg, tg, Rc, tc, method=m)
    return time.perf_counter() - t0


def _breakdown(scenario, trials: int, seed: int, B: int) -> list[tuple[str, float]]:
    """ms per trial of the joint solve with the pose model: host preparation, loop, batched."""
    import jcalib
    from jcalib.problems.calibrate import prepare
    from jcalib.study import load_scenario, simulate_trial
    from jcalib.study.estimators import builder_options

    sc = load_scenario(scenario)
    est = next(e for e in sc.estimators if e.name == "joint_pose_model")
    opt = jcalib.CalibrationOptions(**builder_options(sc, est))
    data = [simulate_trial(sc, seed, k) for k in range(trials)]
    cells, obs = [d.cell for d in data], [d.observations for d in data]
    jcalib.calibrate_batch(cells[:B], obs[:B], opt)  # warm (compiled by the study already)
    for c, o in zip(cells, obs):  # warm: the single-solve path compiles per padded shape
        jcalib.calibrate_cell(c, o, opt)
    out = []
    dt, _ = _timed(lambda: [prepare(c, o, opt) for c, o in zip(cells, obs)])
    out.append(("host preparation only (graph, starts, problem)", dt))
    dt, _ = _timed(lambda: [jcalib.calibrate_cell(c, o, opt) for c, o in zip(cells, obs)])
    out.append(("calibrate_cell, loop", dt))
    dt, _ = _timed(lambda: [jcalib.calibrate_batch(cells[s:s + B], obs[s:s + B], opt) for s in range(0, trials, B)])
    out.append((f"calibrate_batch, batches of {B}", dt))
    return [(name, 1e3 * t / trials) for name, t in out]


def _medians(table) -> dict:
    rows = table.to_dict("records") if hasattr(table, "to_dict") else table
    out = {}
    for e in dict.fromkeys(r["estimator"] for r in rows):
        rr = [r for r in rows if r["estimator"] == e and r["status"] == "ok"]
        out[e] = (np.median([r["err_T_flange_cam0_rot_deg"] for r in rr]),
                  np.median([r["err_T_flange_cam0_trans_mm"] for r in rr]),
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
        rows.append(("camera", "sequential loop (calibrate_batch of 1)", n, dt))
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
