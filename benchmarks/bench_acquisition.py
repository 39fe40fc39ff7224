"""Acquisition throughput: stations per minute of simulated captures, grab latency through the GigE fake.

Run: ``.venv/bin/python benchmarks/bench_acquisition.py [--quick]``. Prints two tables. Timings on
shared CI machines move by tens of percent between runs: compare rows of one run.
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer stations and grabs")
    a = ap.parse_args()
    from rich.console import Console
    from rich.table import Table

    con = Console()
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
