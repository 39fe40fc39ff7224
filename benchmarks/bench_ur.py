"""A UR5e in the demo cell against the KUKA KR 10 of ``jcalib demo``: hand-eye and kinematic calibration accuracy.

For each robot (``kuka_kr10_r1100_sixx`` over KUKAVARPROXY, ``ur5e`` over RTDE + URScript: the drivers ``jcalib
capture`` uses, against the in-process protocol simulators on free loopback ports, motion instantaneous) and each
seed, the whole demo cell of :mod:`jcalib.app.demo_cell` (an eye-in-hand camera, a fixed camera, a board, a torch):

- **hand-eye**: the stations ``jcalib demo`` plans for the robot toward the cell's goals (board views and tool
  stations), captured with the realistic image noise (``jcalib demo``), detected and calibrated jointly; errors against the simulator's truth of ``T_flange_cam_hand``
  (translation mm, rotation deg), ``T_base_cam_fixed``, ``T_base_board`` and the TCP ``T_flange_torch`` (mm), and
  the largest |error / σ| over all unknowns;
- **kinematic**: the same with hidden kinematic errors of the arm (``jcalib demo --kinematic-errors``: seeded,
  ~0.05 deg and 0.5 mm on the identifiable joint offsets, link lengths and twists) and 20 more stations planned for
  the kinematics; ``calibrate_kinematics: [joint_offsets, link_lengths, twists]``. Errors of the calibrated
  kinematic parameters against the truth (RMS over lengths in mm and over angles in deg), the largest |error / σ|
  among them, and the hand-eye error, also for the same observations calibrated with the nominal kinematics.

Printed: per mode and quantity the median over seeds per robot and the UR5e / KUKA ratio. Both arms see the same
cell (the layout follows each arm's home posture), so the ratio is what the arm and its protocol change.

Run: ``.venv/bin/python benchmarks/bench_ur.py [--seeds 3] [--work DIR]`` (a few minutes per run on one quiet core;
``--work`` keeps every run's files and a ``runs.jsonl`` that a second call with the same ``--work`` reuses).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import numpy as np
import yaml

import jcalib
from jcalib.acquisition.cameras.simulated import SimulatedCamera
from jcalib.acquisition.capture import capture
from jcalib.acquisition.robots import KukaRobot, KukaSimServer, SimulatedController, UrRobot, UrSimServer
from jcalib.acquisition.robots.model import preset_model
from jcalib.app.demo_cell import (DEMO_CELL, KINEMATIC_STATIONS, MAX_STATIONS, compare_kinematics, compare_with_truth,
                                  kinematic_cell, plan_demo)  # fmt: skip
from jcalib.app.simcell import layout_truth, scene_frame_source, scene_from_layout, simulated_kinematics
from jcalib.io.plan import load_plan
from jcalib.pipeline.session import detect_session_to_file
from jcalib.planning.layout import cell_layout
from jcalib.sim.render import RenderOptions, camera_image_size
from jcalib.solve.cache import enable_compilation_cache

ROBOTS = {"kuka": "kuka_kr10_r1100_sixx", "ur": "ur5e"}
SIZE = (640, 480)


def _driver(protocol: str, ctrl: SimulatedController):
    if protocol == "kuka":
        srv = KukaSimServer(ctrl).start()
        return srv, KukaRobot("127.0.0.1", srv.port)
    srv = UrSimServer(ctrl, port=0).start()
    return srv, UrRobot("127.0.0.1", rtde_port=srv.port, script_port=srv.script_port)


def _pose_errors(rows: dict, key: str) -> tuple[float, float]:
    t = [rows[f"{key} t{a} (mm, frame b)"][1] for a in "xyz" if f"{key} t{a} (mm, frame b)" in rows]
    r = [rows[f"{key} r{a} (deg)"][1] for a in "xyz" if f"{key} r{a} (deg)" in rows]
    return float(np.linalg.norm(t)) if t else float("nan"), float(np.linalg.norm(r)) if r else float("nan")


def run_once(work: Path, protocol: str, mode: str, seed: int, model) -> dict:
    """One capture + calibration; returns the errors (JSON-ready)."""
    robot = ROBOTS[protocol]
    out = work / f"{protocol}-{mode}-{seed}"
    out.mkdir(parents=True, exist_ok=True)
    cell_path = out / "cell.yaml"
    cell_path.write_text(DEMO_CELL)
    calib_cell = cell_path
    if mode == "kinematic":
        calib_cell = out / "cell_kinematics.yaml"
        calib_cell.write_text(kinematic_cell(robot))
    plan = work / f"plan-{protocol}-{mode}.json"
    if not plan.exists():
        plan_demo(calib_cell, plan, robot=robot, max_stations=MAX_STATIONS, image_size=SIZE,
                  kinematic_stations=KINEMATIC_STATIONS if mode == "kinematic" else 0)  # fmt: skip
    layout = cell_layout(cell_path, robot=robot, image_size=SIZE)
    scene = scene_from_layout(layout)
    kin = simulated_kinematics(model, robot, seed) if mode == "kinematic" else None
    truth = layout_truth(layout, kin, seed=seed)
    ctrl = SimulatedController(model, time_scale=0.0, seed=seed, true_forward=kin.forward() if kin else None)
    options = RenderOptions.preset("realistic")
    cameras = {name: SimulatedCamera(scene_frame_source(scene, name, ctrl.true_T_base_flange, options=options,
                                                        seed=seed + 1000 * k),
                                     name=name, sensor_size=camera_image_size(scene.cameras[name].model))
               for k, name in enumerate(layout.cameras)}  # fmt: skip
    srv, driver = _driver(protocol, ctrl)
    t0 = time.perf_counter()
    try:
        capture(load_plan(plan), driver, cameras, out / "session", cell=yaml.safe_load(DEMO_CELL), progress=False)
    finally:
        driver.close()
        srv.stop()
    t_capture = time.perf_counter() - t0
    detect_session_to_file(out / "session", cell_path, out / "observations.json")
    result = jcalib.calibrate(calib_cell, out / "observations.json").file
    rows = compare_with_truth(result, truth)
    z = [abs(e - t) / s for t, e, s in rows.values() if s > 0]
    res = {"protocol": protocol, "mode": mode, "seed": seed, "capture_s": t_capture,
           "rms_px": float(result.stats.get("rms_px", float("nan"))), "max_z": float(max(z)),
           "num_stations": int(result.stats.get("num_stations") or 0)}  # fmt: skip
    for key, label in (("T_flange_cam_hand", "hand-eye"), ("T_base_cam_fixed", "fixed camera"),
                       ("T_base_board", "board"), ("T_flange_torch", "TCP")):  # fmt: skip
        res[f"{label} mm"], res[f"{label} deg"] = _pose_errors(rows, key)
    if mode == "kinematic":
        krows = compare_kinematics(result, truth)
        lengths = [e - t for k, (t, e, s) in krows.items() if k.endswith("(mm)")]
        angles = [e - t for k, (t, e, s) in krows.items() if k.endswith("(deg)")]
        res["kinematics mm rms"] = float(np.sqrt(np.mean(np.square(lengths)))) if lengths else float("nan")
        res["kinematics deg rms"] = float(np.sqrt(np.mean(np.square(angles)))) if angles else float("nan")
        res["kinematics max z"] = float(max(abs(e - t) / s for t, e, s in krows.values() if s > 0))
        res["kinematic parameters"] = len(krows)
        res["true error mm rms"] = float(np.sqrt(np.mean([t * t for k, (t, e, s) in krows.items() if k.endswith("(mm)")])))
        nominal = jcalib.calibrate(cell_path, out / "observations.json").file
        res["hand-eye mm (nominal kinematics)"], res["hand-eye deg (nominal kinematics)"] = _pose_errors(
            compare_with_truth(nominal, truth), "T_flange_cam_hand")
    return res


def print_table(runs: list[dict]) -> None:
    for mode in ("hand-eye", "kinematic"):
        rs = [r for r in runs if r["mode"] == mode]
        if not rs:
            continue
        keys = [k for k in rs[0] if k not in ("protocol", "mode", "seed") and isinstance(rs[0][k], (int, float))]
        seeds = {p: sorted(r["seed"] for r in rs if r["protocol"] == p) for p in ROBOTS}
        print(f"\n{mode} calibration of the demo cell: median over seeds (kuka: {len(seeds['kuka'])} runs, "
              f"ur: {len(seeds['ur'])} runs)")
        header = f"{'quantity':36s} {'KUKA KR 10':>12s} {'UR5e':>12s} {'UR5e/KUKA':>10s}"
        print(header)
        print("-" * len(header))
        for k in keys:
            med = {p: float(np.median([r[k] for r in rs if r["protocol"] == p])) if seeds[p] else float("nan")
                   for p in ROBOTS}  # fmt: skip
            ratio = med["ur"] / med["kuka"] if med["kuka"] else float("nan")
            print(f"{k:36s} {med['kuka']:12.4g} {med['ur']:12.4g} {ratio:10.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--modes", default="hand-eye,kinematic")
    ap.add_argument("--work", type=Path, default=None)
    a = ap.parse_args()
    enable_compilation_cache()
    work = a.work or Path(tempfile.mkdtemp(prefix="bench_ur-"))
    work.mkdir(parents=True, exist_ok=True)
    log = work / "runs.jsonl"
    done = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    have = {(r["protocol"], r["mode"], r["seed"]) for r in done}
    print(f"load average before: {os.getloadavg()[0]:.1f}; work: {work}", flush=True)
    for protocol, robot in ROBOTS.items():
        model = preset_model(robot)
        for mode in a.modes.split(","):
            for seed in range(a.seeds):
                if (protocol, mode, seed) in have:
                    continue
                t0 = time.perf_counter()
                r = run_once(work, protocol, mode, seed, model)
                r["wall_s"] = time.perf_counter() - t0
                done.append(r)
                with open(log, "a") as f:
                    f.write(json.dumps(r) + "\n")
                print(f"{protocol} {mode} seed {seed}: hand-eye {r['hand-eye mm']:.3f} mm, max |z| {r['max_z']:.2f} "
                      f"({r['wall_s']:.0f} s)", flush=True)
    print_table(done)
    print(f"\nload average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
