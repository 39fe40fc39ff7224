"""Time from ``Robot.stop()`` to standstill and to the blocked ``move()`` raising, per driver (issue 30).

Run: ``.venv/bin/python benchmarks/bench_stop.py [--stops 20] [--seed 0]``.

Each driver talks to its simulator over its real protocol on 127.0.0.1 (KUKAVARPROXY, the ABB line
protocol with its stop port, UR's RTDE + a stopj / stopl program on the secondary interface; the in-process
simulated robot without a socket), motion times realistic
(``time_scale=1``). A move to a random station (joint and linear alternately, 0.3-0.9 s long) starts in a
thread; at a random 20-70 % of its motion time the main thread calls ``robot.stop()`` (on a loaded machine
that call may come after the arrival: such stops are counted, not timed). Measured from just before it:

- **stop call**: until ``stop()`` returns (the controller has the request);
- **standstill**: until the simulated controller's joints stop changing (sampled every 1 ms in-process:
  the first sample after which every later one is identical);
- **move raises**: until the blocked ``move()`` raises ``MotionStoppedError`` in its thread.

The simulated controller brakes over ``stop_time_s`` = 0.08 s from full path speed (less near the end of
a move); the rest is the protocol: the KUKA driver's write of ``JC_STOP`` and its 20 ms ``JC_FLAG`` poll,
the ABB driver's connection to the stop port, the UR driver's next RTDE package (125 Hz) showing the arm
standing. Target: standstill <= 0.2 s. Timings move with the load
of the machine (the script prints the load average).
"""

from __future__ import annotations

import argparse
import os
import statistics
import threading
import time

import numpy as np

from jcalib.acquisition.robots import (
    AbbRobot,
    AbbSimServer,
    KukaRobot,
    KukaSimServer,
    MotionStoppedError,
    SimulatedController,
    SimulatedRobot,
    UrRobot,
    UrSimServer,
)

DRIVERS = (
    ("in-process SimulatedRobot", "sim", 0.0),
    ("KUKA, KUKAVARPROXY sim", "kuka", 0.0),
    ("KUKA, sim answering in 5 ms (a real KRC: 2-10 ms)", "kuka", 0.005),
    ("ABB, line protocol sim + stop port", "abb", 0.0),
    ("UR, RTDE + URScript sim (stopj / stopl)", "ur", 0.0),
)


def _connect(protocol: str, ctrl: SimulatedController, reply_delay_s: float):
    if protocol == "kuka":
        srv = KukaSimServer(ctrl, reply_delay_s=reply_delay_s).start()
        return srv, KukaRobot("127.0.0.1", srv.port)
    if protocol == "abb":
        srv = AbbSimServer(ctrl).start()
        return srv, AbbRobot("127.0.0.1", srv.port)
    if protocol == "ur":
        srv = UrSimServer(ctrl, port=0).start()
        return srv, UrRobot("127.0.0.1", rtde_port=srv.port, script_port=srv.script_port)
    return None, SimulatedRobot(ctrl)


def _sampler(ctrl: SimulatedController, until: threading.Event, samples: list) -> None:
    while not until.is_set():
        samples.append((time.perf_counter(), ctrl.joints_rad()))
        time.sleep(0.001)


def one_stop(robot, ctrl: SimulatedController, T: np.ndarray, kind: str, fraction: float) -> dict:
    """Start a move to ``T``, stop it at ``fraction`` of its motion time; the three times in s."""
    result: dict = {}

    def mover():
        try:
            robot.move(T, kind=kind, settle=False)
            result["error"] = None
        except MotionStoppedError as e:
            result["error"] = e
        result["t_raise"] = time.perf_counter()

    moves = ctrl.num_moves
    th = threading.Thread(target=mover)
    th.start()
    while ctrl.num_moves == moves:
        time.sleep(0.0005)
    time.sleep(fraction * ctrl.motion_time_s)
    done, samples = threading.Event(), []
    sampler = threading.Thread(target=_sampler, args=(ctrl, done, samples))
    sampler.start()
    time.sleep(0.003)  # a few samples of the moving robot first
    t0 = time.perf_counter()
    robot.stop()
    t_call = time.perf_counter()
    th.join(30)
    time.sleep(0.05)
    done.set()
    sampler.join()
    if result.get("error") is None:  # the stop came after the arrival (a loaded machine slept too long)
        return {}
    last = samples[-1][1]
    still = next(i for i in range(len(samples)) if all(np.array_equal(q, last) for _, q in samples[i:]))
    return {"call": t_call - t0, "standstill": max(0.0, samples[still][0] - t0), "raise": result["t_raise"] - t0}


def bench_driver(protocol: str, reply_delay_s: float, stops: int, seed: int, late: list[int]) -> list[dict]:
    """``stops`` stopped moves; ``late[0]`` counts stops that came after the arrival (not timed)."""
    rng = np.random.default_rng(seed)
    ctrl = SimulatedController(time_scale=1.0, seed=seed)
    srv, robot = _connect(protocol, ctrl, reply_delay_s)
    home = robot.state().T_base_flange
    rows = []
    try:
        while len(rows) < stops:
            T = home.copy()
            T[:3, 3] += rng.uniform([-0.3, -0.4, -0.25], [0.3, 0.4, 0.15])
            kind = "joint" if len(rows) % 2 == 0 else "linear"
            duration = _duration(ctrl, T, kind)
            if duration is None or not 0.3 <= duration <= 0.9:
                continue
            row = one_stop(robot, ctrl, T, kind, float(rng.uniform(0.2, 0.7)))
            if row:
                rows.append(row)
            else:
                late[0] += 1
            ctrl.time_scale = 0.0  # back home at once
            robot.move(home, settle=False)
            ctrl.time_scale = 1.0
    finally:
        robot.close()
        if srv is not None:
            srv.stop()
    return rows


def _duration(ctrl: SimulatedController, T: np.ndarray, kind: str) -> float | None:
    """Motion time of a move from home to ``T`` (None: unreachable), on a scratch copy of the controller."""
    from jcalib.acquisition.robots import UnreachableError

    scratch = SimulatedController(ctrl.model, time_scale=1.0)
    try:
        return scratch.start_move(T, kind)
    except UnreachableError:
        return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stops", type=int, default=20, help="stops per driver")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    from rich.console import Console
    from rich.table import Table

    load = os.getloadavg()
    t = Table(title=f"Robot.stop() at time_scale=1, {a.stops} stops per driver, 127.0.0.1 "
                    f"(load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}); ms, median / max")  # fmt: skip
    for col in ("driver", "stop call", "standstill", "move() raises", "standstill <= 200 ms", "stops after arrival"):
        t.add_column(col)
    for label, protocol, delay in DRIVERS:
        late = [0]
        rows = bench_driver(protocol, delay, a.stops, a.seed, late)
        cells = []
        for key in ("call", "standstill", "raise"):
            v = [1e3 * r[key] for r in rows]
            cells.append(f"{statistics.median(v):.1f} / {max(v):.1f}")
        ok = sum(r["standstill"] <= 0.2 for r in rows)
        t.add_row(label, *cells, f"{ok} of {len(rows)}", str(late[0]))
    Console(width=160).print(t)


if __name__ == "__main__":
    main()
