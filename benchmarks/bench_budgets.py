"""Compile and host-time budgets of ``jcalib calibrate``, cold and warm (issue 16), with farm-bench.

Prints one table: the whole process (start-up included) of

- the demo cell (``benchmarks/data/demo_cell``: the demo's own cell spec and observations: a flange
  camera, a fixed camera, a board, a torch; 22 stations),
- a camera-only calibration with 25 views (a synthetic 9x6 board, opencv5),

each with an empty JAX compilation cache (``JCALIB_CACHE_DIR=$(mktemp -d)`` per run: "cold") and with
a warm one ("warm"); and, in one warm Python process, a camera calibration whose view count is new
to the process (same shape bucket, and the next bucket).

Budgets (this 2-core machine, medians): demo cell <= 15 s cold, <= 3 s warm; camera-only <= 8 s cold,
<= 2.5 s warm; a new view count in a warm process <= 1 s.

``jcalib`` runs as a user runs it, with the XLA:CPU flag that ``import jcalib`` adds to ``XLA_FLAGS``
(``jcalib/__init__.py``); an ``XLA_FLAGS`` or ``JCALIB_XLA_DEFAULTS`` in this environment changes what is
measured, and the table's title names them.

Run: ``.venv/bin/python benchmarks/bench_budgets.py [--runs 5] [--cold-runs 3]`` (needs ``farm-bench``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data"
JCALIB = str(ROOT / ".venv" / "bin" / "jcalib")


def camera_inputs(num_views: int, seed: int = 7) -> tuple[dict, dict]:
    """A camera-only cell and observations of a 9x6 board in ``num_views`` views (0.2 px noise)."""
    from jcalib.geometry import Checkerboard, camera_from_opencv
    from jcalib.sim.scene import project_target, random_calibration_views

    rng = np.random.default_rng(seed)
    board = Checkerboard(cols=9, rows=6, square=0.03)
    model = camera_from_opencv(np.array([[1200.0, 0, 640.3], [0, 1198.0, 481.2], [0, 0, 1]]),
                               np.array([-0.21, 0.09, 0.0004, -0.0006, -0.02]), (1280, 960))
    stations = []
    for i, T in enumerate(random_calibration_views(model, board.points, num_views, rng=rng)):
        pix, _ = project_target(model, T, board.points)
        pix = pix + 0.2 * rng.standard_normal(pix.shape)
        stations.append({"id": f"v{i:03d}", "detections": [{"camera": "cam0", "target": "board",
                         "point_index": list(range(len(pix))), "pixels": pix.tolist()}]})
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5"}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": [1280, 960]}},
           "targets": {"board": {"points": np.asarray(board.points).tolist()}}, "stations": stations}
    return cell, obs


def farm_bench(command: str, runs: int, warmup: int, timeout: int) -> dict[str, float]:
    """farm-bench's min / median / max wall seconds of ``command`` (a shell line)."""
    out = subprocess.run(["farm-bench", "-n", str(runs), "--warmup", str(warmup), "--timeout", str(timeout), "--",
                          "sh", "-c", command], capture_output=True, text=True, check=True).stdout
    m = re.search(r"A wall s\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)", out)
    return {"min": float(m.group(1)), "median": float(m.group(2)), "max": float(m.group(3))}


def new_view_count(cache: str) -> list[tuple[str, float]]:
    """Seconds of calibrations with view counts new to one warm process."""
    code = f"""
import json, time, sys
sys.path.insert(0, {str(ROOT / 'benchmarks')!r})
from bench_budgets import camera_inputs
import jcalib
from jcalib.solve import enable_compilation_cache
enable_compilation_cache()
out = []
for n in (25, 27, 33):
    cell, obs = camera_inputs(n)
    t = time.perf_counter(); jcalib.calibrate(cell, obs); out.append((n, time.perf_counter() - t))
print(json.dumps(out))
"""
    env = dict(os.environ, JCALIB_CACHE_DIR=cache)
    res = subprocess.run([str(ROOT / ".venv" / "bin" / "python"), "-c", code], capture_output=True, text=True,
                         env=env, check=True)
    return [tuple(x) for x in json.loads(res.stdout.strip().splitlines()[-1])]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=5, help="warm runs per command")
    ap.add_argument("--cold-runs", type=int, default=3, help="cold runs per command")
    args = ap.parse_args()
    # before camera_inputs imports jcalib (which adds its flag to this process's XLA_FLAGS)
    env = "; ".join(f"{k}={os.environ[k]!r}" for k in ("XLA_FLAGS", "JCALIB_XLA_DEFAULTS") if k in os.environ)
    if shutil.which("farm-bench") is None:
        sys.exit("farm-bench is not installed: it times whole processes (start-up included)")
    work = Path(tempfile.mkdtemp(prefix="jcalib-budgets-"))
    cam_cell, cam_obs = camera_inputs(25)
    (work / "cam_cell.json").write_text(json.dumps(cam_cell))
    (work / "cam_obs.json").write_text(json.dumps(cam_obs))
    cases = {
        "demo cell (22 stations)": (DATA / "demo_cell" / "cell.yaml", DATA / "demo_cell" / "observations.json", 15, 3),
        "camera-only (25 views)": (work / "cam_cell.json", work / "cam_obs.json", 8, 2.5),
    }
    warm_cache = str(work / "warm-cache")
    rows = []
    for name, (cell, obs, cold_budget, warm_budget) in cases.items():
        cmd = f"{JCALIB} calibrate {cell} {obs} -o {work / 'result.json'} >/dev/null 2>&1"
        cold = farm_bench(f"JCALIB_CACHE_DIR=$(mktemp -d) {cmd}", args.cold_runs, 0, 3600)
        warm = farm_bench(f"JCALIB_CACHE_DIR={warm_cache} {cmd}", args.runs, 1, 3600)
        rows.append((name, "cold (empty cache)", cold, cold_budget))
        rows.append((name, "warm", warm, warm_budget))
    print(f"\njcalib calibrate, whole process (farm-bench wall s; {os.cpu_count()} CPUs; "
          f"{env or 'jcalib default XLA flags'})")
    print(f"{'case':26s} {'cache':20s} {'min':>7s} {'median':>7s} {'max':>7s} {'budget':>7s}  met")
    for name, kind, t, budget in rows:
        print(f"{name:26s} {kind:20s} {t['min']:7.2f} {t['median']:7.2f} {t['max']:7.2f} {budget:7.2f}  "
              f"{'yes' if t['median'] <= budget else 'NO'}")
    print("\nnew view counts in one warm process (camera-only; buckets: 25, 27 -> 28 views; 33 -> 36)")
    for n, s in new_view_count(warm_cache):
        print(f"  {n:3d} views: {s:6.2f} s{'' if n == 25 else ('  (budget 1 s: ' + ('met' if s <= 1 else 'NOT met') + ')')}")


if __name__ == "__main__":
    main()
