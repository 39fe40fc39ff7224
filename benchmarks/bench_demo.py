"""``jcalib demo`` as a user runs it: time per phase, the goals against their limits, how far the estimates are
from the truth in σ, and how many warnings its report opens with (issue 30: "the showcase shows jcalib at its
best").

Runs ``jcalib demo --out DIR [DEMO ARGS]`` ``--runs`` times in a row (the compilation cache of
``JCALIB_CACHE_DIR``, or an empty one per run with ``--cold``) and prints one table, a row per run: the whole
command's wall time, each phase of the demo's own timing line (plan, capture, detect, calibrate,
report+export), the stations captured, max |error/σ| against the simulator's truth (the demo's table), the
goals of this checkout's demo cell (``jcalib.workflow.simulate.DEMO_CELL``) met by the result, with the
largest achieved σ / limit and the σ of the flange camera's hand-eye tz, the TCP rotation and the flange
camera's projection, and the warnings of ``report.html``. The load average before each run is printed with
it: the machine is shared, so times are only comparable between runs made under the same load.

``--pythonpath SRC`` runs the ``jcalib`` of another source tree (e.g. ``git archive <commit> | tar -x -C SRC``
of the commit before a change): its result is judged against this checkout's goals.

Run: ``.venv/bin/python benchmarks/bench_demo.py [--runs 2] [--cold] [--pythonpath SRC] [-- --stations 30 ...]``
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PHASES = ("plan", "capture", "detect", "calibrate", "report+export")


def _phases(text: str) -> dict[str, float]:
    m = re.search(r"timings: (.*?) wrote ", text)
    if m is None:
        return {}
    return {k.strip(): float(v) for k, v in re.findall(r"([a-z+() ]+?) ([0-9.]+) s", m.group(1))}


def _warnings(html: str) -> int:
    box = html[html.find('id="warnings"'):html.find("<h2>Summary</h2>")] if 'id="warnings"' in html else ""
    return len(re.findall(r"<li>", box))


def run_once(out: Path, args: list[str], *, pythonpath: str, cache: str) -> dict:
    import numpy as np
    import yaml

    from jcalib.io.goals import parse_goals
    from jcalib.io.result import load_result
    from jcalib.problems.goals import achieved_sigmas
    from jcalib.workflow.simulate import DEMO_CELL

    env = {**os.environ, "PYTHONPATH": pythonpath, "JCALIB_CACHE_DIR": cache}
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", "from jcalib.app.cli import main; main()", "demo", "--out", str(out),
                           *args], capture_output=True, text=True, env=env, check=False)  # fmt: skip
    wall = time.perf_counter() - t0
    text = " ".join(proc.stdout.split())
    row = {"load": load, "wall": wall, "rc": proc.returncode, **_phases(text)}
    if proc.returncode != 0:
        row["error"] = (proc.stderr or proc.stdout)[-300:]
        return row
    m = re.search(r"max \|error/σ\| = ([0-9.]+)", text)
    row["max_z"] = float(m.group(1)) if m else float("nan")
    result = load_result(out / "result.json")
    goals = parse_goals(yaml.safe_load(DEMO_CELL)["goals"])
    achieved = achieved_sigmas(goals, result)
    row["met"] = sum(achieved[g.text] <= g.limit for g in goals)
    row["goals"] = len(goals)
    row["worst"] = max(achieved[g.text] / g.limit for g in goals)
    pick = {"hand-eye σ (mm)": "T_flange_cam_hand:translation_mm", "TCP rot σ (deg)": "T_flange_torch:rotation_deg",
            "proj. σ (px)": "cam_hand:projection_px"}
    for label, prefix in pick.items():
        row[label] = next(achieved[g.text] for g in goals if g.text.startswith(prefix))
    cov = np.asarray(result.transforms["T_flange_cam_hand"].covariance)
    row["tz σ (mm)"] = float(np.sqrt(cov[5, 5]) * 1e3)
    row["stations"] = len(json.loads((out / "observations.json").read_text())["stations"])
    row["warnings"] = _warnings((out / "report.html").read_text())
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--cold", action="store_true", help="an empty compilation cache for every run")
    ap.add_argument("--pythonpath", default=str(ROOT), help="the source tree whose jcalib runs (default: this one)")
    ap.add_argument("demo_args", nargs="*", help="arguments for jcalib demo (after --)")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="jcalib-bench-demo-"))
    cache = os.environ.get("JCALIB_CACHE_DIR") or str(work / "cache")
    rows = []
    for k in range(args.runs):
        run_cache = str(work / f"cache{k}") if args.cold else cache
        rows.append(run_once(work / f"run{k}", args.demo_args, pythonpath=args.pythonpath, cache=run_cache))
    src = "this checkout" if args.pythonpath == str(ROOT) else args.pythonpath
    print(f"jcalib demo {' '.join(args.demo_args)} ({src}; {'cold' if args.cold else 'shared'} compilation cache; "
          f"{os.cpu_count()} CPUs)")
    cols = ["run", "load", "wall s", *[f"{p} s" for p in PHASES], "stations", "max |err/σ|", "goals met",
            "worst σ/limit", "tz σ (mm)", "hand-eye σ (mm)", "TCP rot σ (deg)", "proj. σ (px)", "warnings"]
    print(" | ".join(cols))
    for k, r in enumerate(rows):
        if r.get("rc"):
            print(f"{k} | {r['load']:.1f} | {r['wall']:.0f} | failed (exit {r['rc']}): {r.get('error', '')!r}")
            continue
        cells = [str(k), f"{r['load']:.1f}", f"{r['wall']:.0f}", *[f"{r.get(p, float('nan')):.1f}" for p in PHASES],
                 str(r["stations"]), f"{r['max_z']:.2f}", f"{r['met']}/{r['goals']}", f"{r['worst']:.2f}",
                 f"{r['tz σ (mm)']:.3g}", f"{r['hand-eye σ (mm)']:.3g}", f"{r['TCP rot σ (deg)']:.3g}",
                 f"{r['proj. σ (px)']:.3g}", str(r["warnings"])]
        print(" | ".join(cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
