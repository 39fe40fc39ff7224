"""Acquisition throughput and robustness.

Run: ``.venv/bin/python benchmarks/bench_acquisition.py [--quick] [--kill-resume] [--flood]``.

- default: stations per minute of simulated captures, grab latency through the GigE fake (two tables);
- ``--kill-resume``: the long variant of ``tests/acquisition/test_kill_resume.py``: per protocol, 10
  captures through the CLI, each killed with SIGKILL at 2 random moments and resumed, then checked
  (every planned station exactly once, images readable and showing the board where the ground truth
  puts it);
- ``--flood``: ``jcalib simulate`` on 127.0.0.1 gets 10,000 random packets on each of its ports
  (``ss -lunpt``), then jcalib's clients must still move the robot and grab a frame.

Timings on shared CI machines move by tens of percent between runs: compare rows of one run.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from jcalib.acquisition import capture
from jcalib.io.plan import make_plan
from jcalib.acquisition.cameras import FakeGigECamera, GigECamera, SimulatedCamera, aravis_available
from jcalib.acquisition.robots import (
    AbbRobot,
    AbbSimServer,
    KukaRobot,
    KukaSimServer,
    SimulatedController,
    SimulatedRobot,
)


def _plan(T0: np.ndarray, n: int):
    rng = np.random.default_rng(0)
    poses = []
    for _ in range(n):
        T = T0.copy()
        T[:3, 3] += rng.uniform([-0.15, -0.15, -0.1], [0.15, 0.15, 0.1])
        poses.append(T)
    return make_plan(poses)


def bench_stations(n: int) -> list[tuple[str, float, float]]:
    """(setup, stations/min, mean s per station) of captures into a temporary session."""
    rows = []
    size = (1600, 1200)
    img = np.random.default_rng(1).integers(0, 256, size[::-1], dtype=np.uint8)
    for label, time_scale, proto in (
        ("in-process, motion time x1", 1.0, None),
        ("in-process, no motion time (overhead)", 0.0, None),
        ("KUKAVARPROXY sim, no motion time", 0.0, "kuka"),
        ("ABB line protocol sim, no motion time", 0.0, "abb"),
    ):
        ctrl = SimulatedController(time_scale=time_scale, seed=0)
        server = None
        if proto == "kuka":
            server = KukaSimServer(ctrl).start()
            robot = KukaRobot("127.0.0.1", server.port)
        elif proto == "abb":
            server = AbbSimServer(ctrl).start()
            robot = AbbRobot("127.0.0.1", server.port)
        else:
            robot = SimulatedRobot(ctrl)
        cams = {"cam0": SimulatedCamera(lambda r: img, name="cam0", sensor_size=size)}
        plan = _plan(robot.state().T_base_flange, n)
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            res = capture(plan, robot, cams, Path(d) / "s", progress=False)
            dt = time.perf_counter() - t0
        robot.close()
        if server is not None:
            server.stop()
        done = len(res.captured) + len(res.skipped)
        rows.append((label + f" ({size[0]}x{size[1]} PNG)", 60.0 * done / dt, dt / done))
    return rows


def bench_grab(n: int) -> list[tuple[str, float, float, float]]:
    """(setup, median ms, p90 ms, MB/s) of software-triggered grabs through the fake GigE camera."""
    rows = []
    for (w, h), packet in (((640, 480), 1400), ((1600, 1200), 1400), ((1600, 1200), 8000), ((2048, 1536), 8000)):
        img = np.random.default_rng(2).integers(0, 256, (h, w), dtype=np.uint8)
        with FakeGigECamera(lambda r: img, "127.0.0.1", sensor_size=(w, h)):
            cam = GigECamera("127.0.0.1", name="cam0", packet_size=packet)
            cam.grab()  # stream set-up
            lat = []
            for _ in range(n):
                t0 = time.perf_counter()
                f = cam.grab()
                lat.append(time.perf_counter() - t0)
            assert np.array_equal(f.image, img)
            cam.close()
        med = statistics.median(lat)
        p90 = sorted(lat)[int(0.9 * (len(lat) - 1))]
        rows.append((f"{w}x{h} Mono8, packet {packet} B", 1e3 * med, 1e3 * p90, w * h / med / 1e6))
    return rows


def bench_kill_resume(runs: int) -> list[tuple]:
    """Rows (protocol, runs, kills, moments, stations, failures, worst px, mean resume s, mean run s)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "acquisition"))
    from _kill_resume import kill_resume

    rows = []
    for protocol in ("kuka", "abb", "ur"):
        with tempfile.TemporaryDirectory() as d:
            rep = kill_resume(Path(d), protocol, runs=runs, kills_per_run=2, stations=10, seed=5,
                              min_delay_s=0.0, max_delay_s=6.0)  # fmt: skip
        bad = [p for r in rep["runs"] for p in r.get("problems", [])] + [
            f"exit {r['final_exit']}" for r in rep["runs"] if r["final_exit"] != 0]
        moments = [k["after_s"] for r in rep["runs"] for k in r["kills"]]
        listed = [k["stations_listed"] for r in rep["runs"] for k in r["kills"]]
        rows.append((protocol, len(rep["runs"]), rep["kills"], f"{min(moments):.2f}-{max(moments):.2f} s",
                     f"{min(listed)}-{max(listed)} of 10", len(bad), max(r.get("worst_px", 0.0) for r in rep["runs"]),
                     statistics.mean(r["final_resume_s"] for r in rep["runs"]),
                     statistics.mean(r["run_s"] for r in rep["runs"])))  # fmt: skip
    return rows


def bench_flood() -> list[tuple]:
    """Rows (protocol, port, packets, seconds, simulator alive, clients served after) of the flood."""
    import json
    import subprocess

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "acquisition"))
    import _interop_worker as w

    rows = []
    with tempfile.TemporaryDirectory() as d:
        out = Path(d)
        (out / "cell.yaml").write_text(w.CELL)
        for protocol in ("kuka", "abb"):
            proc, robot_url = w.start(out, protocol)
            try:
                sockets = w.listening(proc.pid)
                for sock in sockets:
                    t0 = time.perf_counter()
                    sent = w.flood([sock], 7)
                    dt = time.perf_counter() - t0
                    alive = proc.poll() is None
                    ok = alive and w.our_clients_work(robot_url)["image_shape"] == [240, 320]
                    rows.append((protocol, f"{sock[0]} {sock[1]}:{sock[2]}", sum(sent.values()), dt, alive, ok))
            finally:
                proc.terminate()
                proc.wait(30)
    del json, subprocess
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer stations and grabs (and kill-resume runs)")
    ap.add_argument("--kill-resume", action="store_true", help="SIGKILL-and-resume captures (minutes)")
    ap.add_argument("--flood", action="store_true", help="10,000 random packets per simulator port")
    a = ap.parse_args()
    from rich.console import Console
    from rich.table import Table

    con = Console()
    if a.kill_resume or a.flood:
        if a.kill_resume:
            t = Table(title="Capture killed with SIGKILL at 2 random moments per run, resumed (CLI, simulate on 127.0.0.1)")
            for col in ("protocol", "runs", "kills", "kill moments", "stations listed at kills", "failed checks",
                        "worst corner vs truth px", "final resume s", "run s"):  # fmt: skip
                t.add_column(col)
            for row in bench_kill_resume(3 if a.quick else 10):
                t.add_row(*(f"{v:.2f}" if isinstance(v, float) else str(v) for v in row))
            con.print(t)
        if a.flood:
            t = Table(title="10,000 random packets per port of jcalib simulate (127.0.0.1), then a move and a grab")
            for col in ("protocol", "socket", "packets", "s", "simulator alive", "clients served after"):
                t.add_column(col)
            for row in bench_flood():
                t.add_row(*(f"{v:.2f}" if isinstance(v, float) else str(v) for v in row))
            con.print(t)
        return
    t = Table(title="Simulated capture: stations per minute (1 camera, move + settle + grab + PNG + fsync)")
    for col in ("setup", "stations/min", "s/station"):
        t.add_column(col)
    for label, spm, sps in bench_stations(8 if a.quick else 30):
        t.add_row(label, f"{spm:.0f}", f"{sps:.3f}")
    con.print(t)
    if not aravis_available():
        con.print("[yellow]Aravis not available: grab latency skipped[/]")
        sys.exit(0)
    t = Table(title="Grab latency through Aravis' GigE fake camera on loopback (software trigger -> frame)")
    for col in ("setup", "median ms", "p90 ms", "Mpx/s"):
        t.add_column(col)
    for label, med, p90, mps in bench_grab(10 if a.quick else 40):
        t.add_row(label, f"{med:.1f}", f"{p90:.1f}", f"{mps:.1f}")
    con.print(t)


if __name__ == "__main__":
    main()
