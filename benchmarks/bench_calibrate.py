"""Camera calibration speed: the public ``jcalib.calibrate`` against ``cv2.calibrateCamera`` and mrcal on identical corners.

Synthetic 9x6 board (30 mm), opencv5 lens, 0.2 px corner noise, N views (``random_calibration_views``).
Prints tables (medians of ``--repeats`` runs; timings on a shared 2-core box move ±30–50 %):

1. per N: ``jcalib.calibrate(cell, observations)`` first call (compilation or the persistent cache) and
   steady state (the whole public call: checks, graph, closed-form start, the compiled solve with its
   covariance, outlier round, result file), OpenCV ``calibrateCamera`` and ``calibrateCameraExtended``
   (standard deviations) with the same convergence (``COUNT+EPS, 200, 1e-15``: OpenCV's default 30
   iterations stop early at 400 views), mrcal's own OPENCV5 fit (``seed_stereographic``, then
   ``mrcal.optimize`` on the intrinsics core, then with the distortions, as mrcal-calibrate-cameras does;
   run by ``/usr/bin/python3`` in a subprocess on the same corners, timed inside it; skipped with a note
   when mrcal is absent: ``apt-get install python3-mrcal``), and the ratios. jcalib runs twice: interleaved
   with the OpenCV calls (the ratios to OpenCV), and back to back as mrcal's loop runs (the ratio to mrcal):
   a call that follows other work, or even a sleep, takes ~2-3 ms longer at 25 views (caches and XLA's
   thread pool gone cold), so each comparison runs both sides alike;
2. Monte Carlo: ``--mc`` calibrations at N=25 via ``jcalib.calibrate_batch`` (every refinement round
   vmapped over the data sets, :func:`jcalib.solve.batch_width` per call: 8 on the CPU, all on a GPU)
   split into its host preparation (graph, closed-form start, problem), the batched rounds and the result
   assembly, vs sequential ``jcalib.calibrate_cell`` vs the same number of sequential
   ``cv2.calibrateCamera`` calls, on whatever machine runs it;
3. ``jcalib calibrate`` CLI wall time in a fresh process, cold and warm persistent compilation cache.

    .venv/bin/python benchmarks/bench_calibrate.py [--views 25 100 400] [--repeats 5] [--mc 1000]
        [--mc-no-sequential] [--skip-cli] [--skip-mrcal]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # multithreaded BLAS makes small lstsq 100x slower here

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import jax  # noqa: E402
import numpy as np  # noqa: E402

import jcalib  # noqa: E402
from jcalib.geometry import Checkerboard, camera_from_opencv  # noqa: E402
from jcalib.io.cell import parse_cell  # noqa: E402
from jcalib.io.observations import parse_observations  # noqa: E402
from jcalib.sim.scene import project_target, random_calibration_views  # noqa: E402

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
K_TRUE = np.array([[1000.0, 0, 640.0], [0, 1000.0, 480.0], [0, 0, 1]])
DIST_TRUE = np.array([-0.2, 0.05, 1e-3, -5e-4, 0.0])
SIZE = (1280, 960)
CELL = {"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv5"}},
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}
CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-15)
CRITERIA_TEXT = "COUNT+EPS, 200 iterations, eps 1e-15"
SYSTEM_PYTHON = "/usr/bin/python3"

#: mrcal's OPENCV5 fit, run by the system Python (mrcal is a Debian package, not in the venv): reads the
#: corners from an .npz, prints JSON with the time of each fit (seed + two optimize passes) after a warm-up.
MRCAL_FIT = r'''
import json, sys, time
import numpy as np
import mrcal

d = np.load(sys.argv[1])
pixels, size, spacing = d["pixels"], [int(v) for v in d["size"]], float(d["spacing"])
rows, cols, repeats = int(d["rows"]), int(d["cols"]), int(sys.argv[2])

def fit():
    n = len(pixels)
    obs = np.ones((n, rows, cols, 3))
    obs[..., :2] = pixels.reshape(n, rows, cols, 2)
    ifc = np.stack([np.arange(n), np.zeros(n, int)], 1).astype(np.int32)
    intr, extr, frames = mrcal.seed_stereographic(imagersizes=np.array([size]), focal_estimate=float(d["focal"]),
                                                  indices_frame_camera=ifc, observations=obs, object_spacing=spacing)
    intrinsics = np.hstack([intr[:, :4], np.zeros((1, 5))])
    icc = np.stack([ifc[:, 0], ifc[:, 1], ifc[:, 1] - 1], 1).astype(np.int32)
    common = dict(points=None, observations_board=obs, indices_frame_camintrinsics_camextrinsics=icc,
                  observations_point=None, indices_point_camintrinsics_camextrinsics=None,
                  lensmodel="LENSMODEL_OPENCV5", imagersizes=np.array([size], np.int32),
                  calibration_object_spacing=spacing, do_optimize_extrinsics=False, do_optimize_frames=True,
                  do_optimize_calobject_warp=False, do_apply_outlier_rejection=False, verbose=False)
    mrcal.optimize(intrinsics, extr, frames, do_optimize_intrinsics_core=True,
                   do_optimize_intrinsics_distortions=False, **common)
    stats = mrcal.optimize(intrinsics, extr, frames, do_optimize_intrinsics_core=True,
                           do_optimize_intrinsics_distortions=True, **common)
    return intrinsics[0], stats

times = []
for _ in range(repeats + 1):
    t = time.perf_counter()
    intr, stats = fit()
    times.append(time.perf_counter() - t)
print(json.dumps({"times": times[1:], "intrinsics": intr.tolist(),
                  "rms": float(stats["rms_reproj_error__pixels"])}))
'''


def make_views(num_views: int, seed: int):
    cam = camera_from_opencv(K_TRUE, DIST_TRUE, SIZE)
    return cam, random_calibration_views(cam, BOARD.points, num_views, rng=seed)


def make_data(cam, poses, seed: int, sigma_px: float = 0.2, outliers: int = 0):
    """Observations (jcalib), float32 corner lists (OpenCV) and the corners (N, 54, 2) of the same noise;
    with ``outliers``, that many views (every fifth) have one corner moved ~10 px (a gross outlier)."""
    rng = np.random.default_rng(seed)
    stations, pixels = [], []
    for i, T in enumerate(poses):
        pix, _ = project_target(cam, T, BOARD.points)
        pix = pix + sigma_px * rng.standard_normal(pix.shape)
        if i % 5 == 0 and i // 5 < outliers:
            pix[(7 * i) % len(pix)] += (7.0, -7.0)
        pixels.append(pix)
        stations.append({"id": f"s{i:03d}", "detections": [{"camera": "cam", "target": "board",
                         "point_index": list(range(len(BOARD.points))), "pixels": pix.tolist()}]})
    data = {"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": list(SIZE)}},
            "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}
    obj = [BOARD.points.astype(np.float32)] * len(poses)
    img = [p.astype(np.float32) for p in pixels]
    return data, obj, img, np.stack(pixels)


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def mrcal_available() -> bool:
    if not os.path.exists(SYSTEM_PYTHON):
        return False
    return subprocess.run([SYSTEM_PYTHON, "-c", "import mrcal"], capture_output=True).returncode == 0


def run_mrcal(pixels: np.ndarray, repeats: int) -> dict | None:
    """mrcal's fit of the corners (N, 54, 2) in a subprocess: ``{"times", "intrinsics", "rms"}``."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "corners.npz")
        np.savez(path, pixels=pixels, size=np.array(SIZE), spacing=BOARD.square, cols=BOARD.cols, rows=BOARD.rows,
                 focal=K_TRUE[0, 0])
        script = os.path.join(tmp, "fit.py")
        with open(script, "w") as f:
            f.write(MRCAL_FIT)
        env = {k: v for k, v in os.environ.items() if not k.startswith(("VIRTUAL_ENV", "PYTHON"))}
        proc = subprocess.run([SYSTEM_PYTHON, script, path, str(repeats)], capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        print(f"mrcal failed: {proc.stderr[-500:]}")
        return None
    return json.loads(proc.stdout.strip().splitlines()[-1])


def bench_views(views, repeats, use_mrcal, outliers=(25,)):
    """Rows per N (and per N in ``outliers`` with 5 gross outliers): ``jcalib.calibrate`` with the dicts a
    user passes (the cell spec and the observations document, parsed and checked inside the call)."""
    cell = CELL
    rows = []
    for n, bad in [(n, 0) for n in views] + [(n, 5) for n in outliers]:
        cam, poses = make_views(n, seed=n)
        data, obj, img, pixels = make_data(cam, poses, seed=n, outliers=bad)
        obs = data
        t_first, res = timed(lambda: jcalib.calibrate(cell, obs))
        ours, cv, cvx = [], [], []
        for _ in range(repeats):  # interleaved A/B
            ours.append(timed(lambda: jcalib.calibrate(cell, obs))[0])
            cv.append(timed(lambda: cv2.calibrateCamera(obj, img, SIZE, None, None, criteria=CRITERIA))[0])
            cvx.append(timed(lambda: cv2.calibrateCameraExtended(obj, img, SIZE, None, None, criteria=CRITERIA))[0])
        rms_cv, K_cv = cv2.calibrateCamera(obj, img, SIZE, None, None, criteria=CRITERIA)[:2]
        # back to back, as mrcal's own loop runs (a call right after another finds caches and the XLA
        # thread pool warm: ~2-3 ms less at 25 views than one after 20 ms of other work, even sleep)
        b2b = [timed(lambda: jcalib.calibrate(cell, obs))[0] for _ in range(repeats)]
        mr = run_mrcal(pixels, repeats) if use_mrcal else None
        o, c, cx = statistics.median(ours), statistics.median(cv), statistics.median(cvx)
        ob = statistics.median(b2b)
        m = statistics.median(mr["times"]) if mr else float("nan")
        cal = res.details
        fx = float(cal.cameras["cam"].params[0])
        label = f"{n}" if not bad else f"{n}+{bad}o"
        rows.append((label, t_first, o, ob, c, cx, m, cal.iterations, cal.rms_px, rms_cv, fx, K_cv[0, 0],
                     mr["intrinsics"][0] if mr else float("nan"), len(cal.outliers)))
    print(f"\nSteady state (medians of {repeats}); OpenCV criteria: {CRITERIA_TEXT}")
    print("jcalib = the public jcalib.calibrate (checks, start, solve + covariance, outlier round, result file); "
          "mrcal = seed_stereographic + 2 optimize passes (OPENCV5), /usr/bin/python3" + ("" if use_mrcal else
                                                                                        " (not run: mrcal absent)"))
    print("jcalib ms: interleaved with the two OpenCV calls (/cv, /cv ext); b2b ms: back to back, as mrcal's loop "
          "times itself (/mrcal)")
    print("N+5o: 5 views with one corner moved ~10 px; out: measurements jcalib rejected")
    print(f"{'N':>6} {'first s':>8} {'jcalib ms':>10} {'b2b ms':>7} {'cv ms':>8} {'cv ext ms':>10} {'mrcal ms':>9} "
          f"{'/cv':>6} {'/cv ext':>8} {'/mrcal':>7} {'iters':>6} {'rms jcalib':>11} {'rms cv':>9} "
          f"{'fx jcalib':>10} {'fx cv':>9} {'fx mrcal':>9} {'out':>4}")
    for n, tf, o, ob, c, cx, m, it, rms, rcv, fx, fxc, fxm, nout in rows:
        print(f"{n:>6} {tf:>8.2f} {o * 1e3:>10.1f} {ob * 1e3:>7.1f} {c * 1e3:>8.1f} {cx * 1e3:>10.1f} {m * 1e3:>9.1f} "
              f"{o / c:>6.2f} {o / cx:>8.2f} {ob / m:>7.2f} {it:>6} {rms:>11.5f} {rcv:>9.5f} {fx:>10.3f} {fxc:>9.3f} "
              f"{fxm:>9.3f} {nout:>4}")


def _device_line() -> str:
    dev = jax.devices()[0]
    return (f"JAX {jax.__version__} on {jax.default_backend()} ({getattr(dev, 'device_kind', dev.platform)}), "
            f"{os.cpu_count()} CPU cores")


def bench_monte_carlo(num, num_views=25, sequential=True):
    """``num`` calibrations of one view set with fresh noise: ``calibrate_batch`` (and its three parts),
    sequential ``calibrate_cell``, sequential OpenCV."""
    from jcalib.problems.assemble import assemble
    from jcalib.problems.calibrate import prepare
    from jcalib.problems.options import CalibrationOptions
    from jcalib.problems.refine import Member, refine_many
    from jcalib.solve import batch_width

    cell = parse_cell(CELL)
    cam, poses = make_views(num_views, seed=1)
    sets = [make_data(cam, poses, seed=1000 + i) for i in range(num)]
    obs = [parse_observations(d) for d, _, _, _ in sets]
    options = CalibrationOptions()
    t_compile, _ = timed(lambda: jcalib.calibrate_batch(cell, obs))  # first call: compiles the vmapped solve
    t_ours, cals = timed(lambda: jcalib.calibrate_batch(cell, obs))
    t_prep, members = timed(lambda: [Member(*prepare(cell, o, options)) for o in obs])
    t_rounds, refined = timed(lambda: refine_many(members, options, batched=True))
    t_asm, _ = timed(lambda: [assemble(m.g, m.start, m.built, r) for m, r in zip(members, refined)])
    if sequential:
        jcalib.calibrate_cell(cell, obs[0])  # compile the single solve
    t_seq = timed(lambda: [jcalib.calibrate_cell(cell, o) for o in obs])[0] if sequential else float("nan")
    t_cv, _ = timed(lambda: [cv2.calibrateCamera(o, i, SIZE, None, None, criteria=CRITERIA) for _, o, i, _ in sets])
    print(f"\nMonte Carlo: {num} calibrations, N={num_views} views, same poses, fresh 0.2 px noise; {_device_line()}")
    print(f"calibrate_batch = host preparation + batched rounds ({batch_width(num)} data sets per vmapped call) "
          "+ result assembly")
    print(f"{'what':<52} {'total s':>8} {'per calib ms':>13} {'OpenCV/this':>12}")
    print(f"{'jcalib.calibrate_batch (first call: compile)':<52} {t_compile:>8.2f} {t_compile / num * 1e3:>13.3f} "
          f"{t_cv / t_compile:>11.2f}x")
    print(f"{'jcalib.calibrate_batch':<52} {t_ours:>8.2f} {t_ours / num * 1e3:>13.3f} {t_cv / t_ours:>11.2f}x")
    for label, t in (("  host preparation (graph, Zhang/PnP start, problem)", t_prep),
                     ("  batched rounds (vmapped solves, outliers)", t_rounds), ("  result assembly", t_asm)):
        print(f"{label:<52} {t:>8.2f} {t / num * 1e3:>13.3f} {'':>12}")
    if sequential:
        print(f"{'jcalib.calibrate_cell, sequential':<52} {t_seq:>8.2f} {t_seq / num * 1e3:>13.3f} "
              f"{t_cv / t_seq:>11.2f}x")
    print(f"{'OpenCV calibrateCamera, sequential':<52} {t_cv:>8.2f} {t_cv / num * 1e3:>13.3f} {1.0:>11.2f}x")
    ok = [c for c in cals if not isinstance(c, Exception)]
    fx = np.array([c.cameras["cam"].params[0] for c in ok])
    std = np.array([np.sqrt(c.intrinsics_covariance["cam"][0, 0]) for c in ok])
    print(f"{len(ok)} of {num} calibrated; fx spread {fx.std():.3f} px, median stated std {np.median(std):.3f} px, "
          f"mean fx {fx.mean():.4f} px (true {K_TRUE[0, 0]:.1f})")


def bench_cli(num_views=25):
    cam, poses = make_views(num_views, seed=7)
    data, _, _, _ = make_data(cam, poses, seed=7)
    with tempfile.TemporaryDirectory() as tmp:
        with open(os.path.join(tmp, "cell.json"), "w") as f:
            json.dump(CELL, f)
        with open(os.path.join(tmp, "obs.json"), "w") as f:
            json.dump(data, f)
        env = dict(os.environ, JCALIB_CACHE_DIR=os.path.join(tmp, "jax-cache"))
        cmd = [sys.executable, "-c", "from jcalib.app.cli import main; main()", "calibrate", "cell.json", "obs.json",
               "-o", "result.json"]
        times = []
        for _ in range(3):  # cold cache, then warm twice
            t, proc = timed(lambda: subprocess.run(cmd, cwd=tmp, env=env, capture_output=True, text=True))
            if proc.returncode != 0:
                print(proc.stderr)
            times.append(t)
    print(f"\njcalib calibrate CLI, N={num_views}, fresh process each (import + init + compile/cache + solve + write)")
    print(f"{'cold cache s':>13} {'warm cache s':>13} {'warm (again) s':>15}")
    print(f"{times[0]:>13.2f} {times[1]:>13.2f} {times[2]:>15.2f}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, nargs="*", default=[25, 100, 400])
    ap.add_argument("--outlier-views", type=int, nargs="*", default=[25],
                    help="N of the rows with 5 gross outliers (one corner moved ~10 px in 5 views)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--mc", type=int, default=1000)
    ap.add_argument("--mc-no-sequential", action="store_true",
                    help="skip the sequential jcalib run of the Monte Carlo (slow on a GPU: one launch per solve)")
    ap.add_argument("--skip-cli", action="store_true")
    ap.add_argument("--skip-mrcal", action="store_true")
    args = ap.parse_args()
    use_mrcal = not args.skip_mrcal and mrcal_available()
    print(f"OpenCV {cv2.__version__}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, "
          f"cv2 threads {cv2.getNumThreads()}; {_device_line()}")
    if not use_mrcal and not args.skip_mrcal:
        print(f"note: mrcal not found for {SYSTEM_PYTHON} (Debian: apt-get install python3-mrcal); "
              "its column is left empty")
    if args.views:
        bench_views(args.views, args.repeats, use_mrcal, args.outlier_views)
    if args.mc:
        bench_monte_carlo(args.mc, sequential=not args.mc_no_sequential)
    if not args.skip_cli:
        bench_cli()


if __name__ == "__main__":
    main()
