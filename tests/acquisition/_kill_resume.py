"""Capture killed with SIGKILL at random moments and resumed, through the ``jcalib`` CLI (test + benchmark).

:func:`kill_resume` starts ``jcalib simulate`` (one fake GigE camera on 127.0.0.1, a KUKA, ABB or UR
controller with motion time; UR on free ports, ``--robot-port 0``), then for each run: starts ``jcalib capture``, kills it with SIGKILL at
a random moment (start-up, control-channel wait, motion, grab, write: anything), resumes it with
``--resume``, kills again..., and finally resumes it to the end. It then checks the session: every
planned station exactly once in ``stations.jsonl``, status ok, each image readable, of the camera's
size, and showing the board where the ground truth says it is at the recorded pose (so an image
belongs to its station). Everything talks to 127.0.0.1 only.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
JCALIB = [sys.executable, "-c", "from jcalib.app.cli import main; main()"]
CELL = """schema: jcalib.cell/1
cameras:
  cam0: {model: opencv5, mount: flange}
targets:
  board: {type: checkerboard, cols: 8, rows: 5, square: 0.02, mount: base}
"""
ROBOTS = {"kuka": "kuka_kr10_r1100_sixx", "abb": "abb_irb4600_45_205", "ur": "ur5e"}
IMAGE_SIZE = (320, 240)


def _env(tmp: Path) -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT), "JCALIB_CACHE_DIR": os.environ.get("JCALIB_CACHE_DIR", str(tmp / "jax")),
            "JAX_PLATFORMS": "cpu"}  # fmt: skip


def _project(truth: dict, T_base_flange: np.ndarray) -> np.ndarray:
    """Ground-truth pixels of the board corners with OpenCV (independent of jcalib's renderer)."""
    import cv2

    c, b = truth["cameras"]["cam0"], truth["targets"]["board"]
    T = np.linalg.inv(T_base_flange @ np.array(c["T_flange_cam0"])) @ np.array(b["T_base_board"])
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    px, _ = cv2.projectPoints(np.array(b["points"]), rvec, T[:3, 3], np.array(c["K"]), np.array(c["dist"]))
    return px.reshape(-1, 2)


def check_session(session: Path, plan: dict, truth: dict) -> dict:
    """Problems of a finished session (empty lists when it is right) and its worst corner error, px."""
    import cv2

    lines = [json.loads(x) for x in (session / "stations.jsonl").read_text().splitlines()]
    ids = [r["id"] for r in lines]
    planned = [s["id"] for s in plan["stations"]]
    problems = []
    if sorted(ids) != sorted(planned) or len(set(ids)) != len(ids):
        problems.append(f"stations {ids} != planned {planned} (each exactly once)")
    worst, worst_id = 0.0, None
    for r in lines:
        if r["status"] != "ok":
            problems.append(f"{r['id']}: {r['status']}")
            continue
        img = cv2.imread(str(session / r["images"]["cam0"]), cv2.IMREAD_UNCHANGED)
        if img is None or img.shape != IMAGE_SIZE[::-1]:
            problems.append(f"{r['id']}: image unreadable or of the wrong size")
            continue
        # OpenCV's SB finder: its classic finder now and then returns a border square's
        # outer corner for an inner one, 14 px off on one of these 320x240 views
        found, corners = cv2.findChessboardCornersSB(img, (8, 5))
        if not found:
            problems.append(f"{r['id']}: board not found in its image")
            continue
        corners = cv2.cornerSubPix(img, corners, (5, 5), (-1, -1), (3, 30, 1e-3)).reshape(-1, 2)
        truth_px = _project(truth, np.array(r["T_base_flange"]))
        # every detected inner corner must sit on a projected one (the board's corner order may flip)
        d = np.linalg.norm(corners[:, None, :] - truth_px[None, :, :], axis=2).min(axis=1)
        if float(d.max()) > worst:
            worst, worst_id = float(d.max()), r["id"]
    if worst > 1.0:
        problems.append(f"the image of {worst_id} (line {ids.index(worst_id) + 1} of {len(ids)}) does not show the "
                        f"board where its recorded pose puts it ({worst:.2f} px)")
    return {"problems": problems, "worst_px": worst, "num_lines": len(lines)}


def kill_resume(tmp: Path, protocol: str, *, runs: int, kills_per_run: int, stations: int, seed: int,
                min_delay_s: float = 0.0, max_delay_s: float = 3.0, time_scale: float = 0.3) -> dict:  # fmt: skip
    """Run the experiment (module docstring); returns a report with per-run results and timings."""
    tmp.mkdir(parents=True, exist_ok=True)
    (tmp / "cell.yaml").write_text(CELL)
    env = _env(tmp)
    rng = np.random.default_rng(seed)
    size = f"{IMAGE_SIZE[0]}x{IMAGE_SIZE[1]}"
    plan_cmd = [*JCALIB, "plan", "--cell", str(tmp / "cell.yaml"), "--kind", "viewsets", "--stations", str(stations),
                "--robot", ROBOTS[protocol], "--image-size", size, "-o", str(tmp / "plan.json")]  # fmt: skip
    subprocess.run(plan_cmd, env=env, check=True, capture_output=True, timeout=300)
    plan = json.loads((tmp / "plan.json").read_text())
    sim = subprocess.Popen(
        [*JCALIB, "simulate", "--cell", str(tmp / "cell.yaml"), "--robot-protocol", protocol, "--robot-port", "0",
         "--camera", "cam0=127.0.0.1", "--time-scale", str(time_scale), "--robot", ROBOTS[protocol],
         "--image-size", size, "--truth", str(tmp / "truth.json"), "--seed", str(seed)],
        env=env, stdout=subprocess.PIPE, stderr=open(tmp / "simulate.err", "w"), text=True,
    )  # fmt: skip
    report: dict = {"protocol": protocol, "runs": [], "kills": 0}
    try:
        line = sim.stdout.readline() if sim.stdout else ""
        if not line.startswith("READY"):
            raise RuntimeError(f"simulate did not start: {line!r} {(tmp / 'simulate.err').read_text()[-2000:]}")
        robot_url = line.split()[2]
        truth = json.loads((tmp / "truth.json").read_text())
        r, cap = -1, max_delay_s
        # a capture that finishes before its kill completes its run with fewer kills: such runs are kept,
        # further runs are added (at most as many again) until runs x kills_per_run kills happened, and
        # the kill moments are drawn below the shortest completed capture seen
        while r + 1 < runs or (report["kills"] < runs * kills_per_run and r + 1 < 2 * runs):
            r += 1
            session = tmp / f"session{r}"
            cmd = [*JCALIB, "capture", "--cell", str(tmp / "cell.yaml"), "--robot", robot_url, "--camera",
                   "cam0=gige://127.0.0.1", "--plan", str(tmp / "plan.json"), "--out", str(session),
                   "--packet-size", "1400"]  # fmt: skip
            kills, moments, attempts, t_run = [], [], 0, time.monotonic()
            while len(kills) < kills_per_run and attempts < 4 * kills_per_run:
                attempts += 1
                resume = (session / "session.json").exists()
                proc = subprocess.Popen(cmd + (["--resume"] if resume else []), env=env,
                                        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)  # fmt: skip
                delay = float(rng.uniform(min(min_delay_s, cap), cap))
                t_started = time.monotonic()
                try:
                    proc.wait(delay)
                except subprocess.TimeoutExpired:
                    os.kill(proc.pid, signal.SIGKILL)
                    proc.wait()
                    done = (session / "stations.jsonl").read_text().count("\n") if (session / "stations.jsonl").exists() else 0
                    kills.append({"after_s": round(delay, 3), "stations_listed": done})
                    moments.append(delay)
                    continue
                err = proc.stderr.read().decode() if proc.stderr else ""
                if proc.returncode != 0:
                    raise RuntimeError(f"capture exited {proc.returncode} before its kill: {err[-2000:]}")
                cap = max(0.5, min(cap, 0.9 * (time.monotonic() - t_started)))
                break  # finished before the kill: the run is complete
            t0 = time.monotonic()
            final = subprocess.run(cmd + (["--resume"] if (session / "session.json").exists() else []), env=env,
                                   capture_output=True, text=True, timeout=300)  # fmt: skip
            resume_s = time.monotonic() - t0
            result = {"run": r, "kills": kills, "final_exit": final.returncode, "final_resume_s": resume_s,
                      "run_s": time.monotonic() - t_run, "stderr": final.stderr[-1500:]}  # fmt: skip
            if final.returncode == 0:
                result.update(check_session(session, plan, truth))
            else:
                result["problems"] = [f"final resume exited {final.returncode}: {final.stderr[-800:]}"]
            report["runs"].append(result)
            report["kills"] += len(kills)
    finally:
        sim.send_signal(signal.SIGTERM)
        try:
            sim.wait(30)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim.wait()
    report["simulator_exit"] = sim.returncode
    return report


if __name__ == "__main__":  # python _kill_resume.py OUT PROTOCOL RUNS KILLS STATIONS SEED
    out, proto, runs, kills, n, seed = sys.argv[1:7]
    rep = kill_resume(Path(out), proto, runs=int(runs), kills_per_run=int(kills), stations=int(n), seed=int(seed))
    print(json.dumps(rep))
