"""Are the demo's σ honest? Many runs of the demo cell, errors against the simulator's truth in units of σ.

Each run is the whole-cell demo of ``jcalib demo`` (:mod:`jcalib.app.demo_cell`): the same cell spec,
the same plan (toward the demo cell's goals: 14 board views + 8 tool stations), the same simulated KUKA robot (repeatability noise) and
cameras rendering the scene at the robot's true pose with the ``"realistic"`` image noise
(:meth:`jcalib.sim.render.RenderOptions.preset`), captured, detected and calibrated; only the seed
differs. It runs in process: a :class:`~jcalib.acquisition.robots.simulated.SimulatedRobot` and
:class:`~jcalib.acquisition.cameras.simulated.SimulatedCamera` instead of the loopback servers the demo
starts (same frames: :func:`jcalib.app.simcell.scene_frame_source`, seed ``seed + 1000 k`` for camera
``k``, as ``jcalib simulate`` uses). The calibration goes through the public API only,
``jcalib.calibrate(cell, observations)``, and is read back from ``result.json``, so the benchmark
measures whatever engine is installed.

Errors are taken as the demo's table takes them (:func:`jcalib.app.demo_cell.compare_with_truth`):
intrinsics minus truth; transforms as ``Log(R_trueᵀ R_est)`` (rad) and ``R_trueᵀ (t_est - t_true)`` (m),
the right perturbation in which the result states its covariance; the TCP by its translation only.

Printed:
- per scalar unknown: mean and RMS of z = error / σ over the runs, Σ z² against χ²(runs) with its
  central 95 % band, and the fraction of |z| > 1.96 (5 % expected);
- per block (a camera's free intrinsics with their covariance, each 6-DOF pose, the TCP position):
  d² = eᵀ Σ⁻¹ e per run, Σ d² against χ²(runs · dof), the fraction of runs above χ²(dof)'s 95 % point,
  and a KS test of the d² against χ²(dof);
- the a-posteriori corner σ of the runs (px).
With ~40 tests at 95 %, about two fall outside their band by chance; a whole camera or pose outside
by far means over- (Σ d² too large) or under-confident σ.

Run: ``.venv/bin/python benchmarks/bench_demo_consistency.py [--runs 50] [--work DIR] [--noise realistic]``
(about 20 s per run on one core after the first; ``--work`` keeps each run's files and a
``runs.jsonl`` that a second call with the same ``--work`` reuses).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import numpy as np
import yaml
from scipy import stats

import jcalib
from jcalib.acquisition.cameras.simulated import SimulatedCamera
from jcalib.acquisition.capture import capture
from jcalib.planning.layout import cell_layout
from jcalib.acquisition.robots.model import preset_model
from jcalib.acquisition.robots.simulated import SimulatedController, SimulatedRobot
from jcalib.app.demo_cell import DEMO_CELL, MAX_STATIONS, plan_demo
from jcalib.app.simcell import layout_truth, scene_frame_source, scene_from_layout
from jcalib.geometry.conversions import matrix_to_rvec
from jcalib.io.plan import load_plan
from jcalib.io.result import load_result
from jcalib.pipeline.session import detect_session_to_file
from jcalib.sim.render import RenderOptions

ROBOT = "kuka_kr10_r1100_sixx"
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def run_once(out: Path, seed: int, *, noise: str, stations: int, size: tuple[int, int]) -> dict:
    """One demo run in ``out``; returns its errors, covariances and statistics (JSON-ready)."""
    out.mkdir(parents=True, exist_ok=True)
    cell_path = out / "cell.yaml"
    cell_path.write_text(DEMO_CELL)
    plan_demo(cell_path, out / "plan.json", robot=ROBOT, max_stations=stations, image_size=size)
    layout = cell_layout(cell_path, robot=ROBOT, image_size=size)
    scene = scene_from_layout(layout)
    truth = layout_truth(layout, seed=seed)
    ctrl = SimulatedController(preset_model(layout.robot), time_scale=0.0, seed=seed)
    options = RenderOptions.preset(noise)
    cameras = {
        name: SimulatedCamera(scene_frame_source(scene, name, ctrl.true_T_base_flange, options=options,
                                                 seed=seed + 1000 * k), name=name, sensor_size=size)  # fmt: skip
        for k, name in enumerate(layout.cameras)
    }
    session = out / "session"
    if session.exists():  # a run interrupted earlier: start it again
        import shutil

        shutil.rmtree(session)
    capture(load_plan(out / "plan.json"), SimulatedRobot(ctrl), cameras, session,
            cell=yaml.safe_load(DEMO_CELL), progress=False)  # fmt: skip
    obs, failures = detect_session_to_file(session, cell_path, out / "observations.json")
    result = jcalib.calibrate(cell_path, out / "observations.json")
    result.to_json(out / "result.json")
    return {"seed": seed, **errors_against_truth(load_result(out / "result.json"), truth),
            "num_failures": len(failures)}  # fmt: skip


def errors_against_truth(result, truth: dict) -> dict:
    """``{"blocks": {name: {"names", "error", "covariance"}}, "stats": {...}}`` for every calibrated unknown."""
    blocks: dict[str, dict] = {}
    for name, cam in result.cameras.items():
        t = truth["cameras"].get(name)
        if t is None or cam.covariance is None:
            continue
        K, dist = np.asarray(t["K"]), np.asarray(t["dist"], dtype=np.float64)
        true = dict(zip(INTRINSIC_NAMES, [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *dist]))
        names = list(cam.param_names)
        keep = [i for i, p in enumerate(names) if p in true and cam.std.get(p, 0.0) > 0.0]
        if not keep:
            continue
        err = np.array([cam.params[i] - true[names[i]] for i in keep])
        cov = np.asarray(cam.covariance)[np.ix_(keep, keep)]
        blocks[f"{name} intrinsics"] = {"names": [f"{name} {names[i]}" for i in keep], "error": err.tolist(),
                                        "covariance": cov.tolist()}  # fmt: skip
    wanted = {}
    for name, c in truth["cameras"].items():
        wanted[f"T_{c['mount']}_{name}"] = np.asarray(c[f"T_{c['mount']}_{name}"])
    for name, tg in truth["targets"].items():
        wanted[f"T_{tg['mount']}_{name}"] = np.asarray(tg[f"T_{tg['mount']}_{name}"])
    tcps = {f"T_flange_{name}" for name in truth.get("tools", {})}
    for name, tool in truth.get("tools", {}).items():
        wanted[f"T_flange_{name}"] = np.asarray(tool[f"T_flange_{name}"])
    for key, T_true in wanted.items():
        entry = result.transforms.get(key)
        if entry is None or entry.covariance is None:
            continue
        T = np.asarray(entry.matrix)
        d_r = np.asarray(matrix_to_rvec(T_true[:3, :3].T @ T[:3, :3]), dtype=np.float64)
        d_t = T_true[:3, :3].T @ (T[:3, 3] - T_true[:3, 3])
        err = np.concatenate([d_r, d_t])  # (rx, ry, rz, tx, ty, tz): rad, m
        axes = [f"r{a} (rad)" for a in "xyz"] + [f"t{a} (m)" for a in "xyz"]
        idx = [3, 4, 5] if key in tcps else list(range(6))
        cov = np.asarray(entry.covariance)[np.ix_(idx, idx)]
        blocks[key] = {"names": [f"{key} {axes[i]}" for i in idx], "error": err[idx].tolist(),
                       "covariance": cov.tolist()}  # fmt: skip
    keys = ("sigma_px", "rms_px", "tip_rms_px", "num_outliers", "iterations", "status", "num_stations")
    return {"blocks": blocks, "stats": {k: result.stats.get(k) for k in keys}}


def chi2_band(dof: int, level: float = 0.95) -> tuple[float, float]:
    a = 0.5 * (1.0 - level)
    return float(stats.chi2.ppf(a, dof)), float(stats.chi2.ppf(1.0 - a, dof))


def print_tables(runs: list[dict]) -> int:
    """Print the per-unknown and per-block tables; returns the number of tests outside their band."""
    ok_runs = [r for r in runs if "blocks" in r]
    n = len(ok_runs)
    print(f"\n{n} runs calibrated, {len(runs) - n} failed")
    for r in runs:
        if "blocks" not in r:
            print(f"  seed {r['seed']}: {r['error']}")
    if n < 2:
        return 0
    block_names = sorted(set.intersection(*(set(r["blocks"]) for r in ok_runs)))
    outside = tests = 0
    lo, hi = chi2_band(n)
    print(f"\nper unknown: z = error / σ over {n} runs; Σ z² ~ χ²({n}), 95 % band [{lo:.1f}, {hi:.1f}]")
    header = f"{'unknown':44s} {'mean z':>7s} {'rms z':>6s} {'Σ z²':>7s} {'|z|>1.96':>8s}  in band"
    print(header)
    print("-" * len(header))
    for b in block_names:
        names = ok_runs[0]["blocks"][b]["names"]
        for i, name in enumerate(names):
            z = np.array([r["blocks"][b]["error"][i] / np.sqrt(r["blocks"][b]["covariance"][i][i]) for r in ok_runs])
            s = float(np.sum(z * z))
            inside = lo <= s <= hi
            outside += not inside
            tests += 1
            print(f"{name:44s} {np.mean(z):+7.2f} {np.sqrt(np.mean(z * z)):6.2f} {s:7.1f} "
                  f"{np.mean(np.abs(z) > 1.96):8.0%}  {'yes' if inside else 'NO'}")  # fmt: skip
    print(f"\nper block: d² = eᵀ Σ⁻¹ e (dof = block size); Σ d² ~ χ²({n}·dof), 95 % band")
    header = f"{'block':24s} {'dof':>3s} {'mean d²':>8s} {'Σ d²':>8s} {'95 % band':>17s} {'>q95':>5s} {'KS p':>6s}  in band"
    print(header)
    print("-" * len(header))
    for b in block_names:
        dof = len(ok_runs[0]["blocks"][b]["names"])
        d2 = []
        for r in ok_runs:
            e = np.asarray(r["blocks"][b]["error"])
            C = np.asarray(r["blocks"][b]["covariance"])
            d2.append(float(e @ np.linalg.solve(C, e)))
        d2 = np.array(d2)
        blo, bhi = chi2_band(n * dof)
        s = float(np.sum(d2))
        inside = blo <= s <= bhi
        outside += not inside
        tests += 1
        ks = stats.kstest(d2, stats.chi2(dof).cdf).pvalue
        q95 = float(stats.chi2.ppf(0.95, dof))
        print(f"{b:24s} {dof:3d} {np.mean(d2):8.2f} {s:8.1f} [{blo:7.1f}, {bhi:7.1f}] {np.mean(d2 > q95):5.0%} "
              f"{ks:6.3f}  {'yes' if inside else 'NO'}")  # fmt: skip
    sig = np.array([r["stats"]["sigma_px"] for r in ok_runs], dtype=np.float64)
    outl = np.array([r["stats"]["num_outliers"] or 0 for r in ok_runs])
    print(f"\na-posteriori corner σ: median {np.median(sig):.3f} px (min {sig.min():.3f}, max {sig.max():.3f}); "
          f"runs with solver-flagged outliers: {np.sum(outl > 0)} (median count {np.median(outl):.0f})")  # fmt: skip
    print(f"tests outside their 95 % band: {outside} of {tests} ({0.05 * tests:.1f} expected by chance; the tests "
          "of one block are correlated)")
    return outside


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--noise", default="realistic", help="RenderOptions preset: realistic or clean")
    ap.add_argument("--stations", type=int, default=MAX_STATIONS, help="the most stations the plan may take (the "
                    "demo's default)")
    ap.add_argument("--image-size", default="640x480")
    ap.add_argument("--work", type=Path, default=None, help="keep run folders here (default: a temporary folder)")
    args = ap.parse_args(argv)
    from jcalib.solve.cache import enable_compilation_cache

    enable_compilation_cache()
    w, h = (int(x) for x in args.image_size.lower().split("x"))
    work = args.work or Path(tempfile.mkdtemp(prefix="jcalib-demo-consistency-"))
    work.mkdir(parents=True, exist_ok=True)
    log = work / f"runs-{args.noise}-goals{args.stations}-{w}x{h}.jsonl"
    done = {}
    if log.exists():
        for line in log.read_text().splitlines():
            rec = json.loads(line)
            done[rec["seed"]] = rec
    print(f"demo consistency: {args.runs} runs, noise {args.noise!r}, at most {args.stations} stations toward the goals, "
          f"{w}x{h}; work folder {work}", flush=True)  # fmt: skip
    runs = []
    t_all = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.runs):
        if seed in done:
            runs.append(done[seed])
            continue
        t0 = time.perf_counter()
        try:
            rec = run_once(work / f"seed{seed:03d}", seed, noise=args.noise, stations=args.stations, size=(w, h))
        except Exception as e:  # noqa: BLE001  (a failed run is reported, not fatal)
            rec = {"seed": seed, "error": f"{type(e).__name__}: {e}"}
            traceback.print_exc(limit=2)
        rec["seconds"] = time.perf_counter() - t0
        with open(log, "a") as f:
            f.write(json.dumps(rec) + "\n")
        runs.append(rec)
        st = rec.get("stats", {})
        print(f"seed {seed:3d}: {rec['seconds']:5.1f} s  σ {st.get('sigma_px', float('nan')) or float('nan'):.3f} px  "
              f"outliers {st.get('num_outliers')}  {rec.get('error', '')}", flush=True)  # fmt: skip
    print(f"total {time.perf_counter() - t_all:.0f} s")
    print_tables(runs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
