"""Run a simulated robot controller as its own process.

``python -m jcalib.acquisition.robots.serve --protocol kuka|abb [--host 127.0.0.1] [--port 0]
[--time-scale 1.0] [--seed 0] [--robot PRESET]`` prints ``LISTENING <protocol> <host>:<port>`` on stdout once the port
is open, then serves until SIGTERM / SIGINT. :func:`start_subprocess` does that from Python.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import threading

from jcalib.errors import DeviceError


def make_server(protocol: str, host: str = "127.0.0.1", port: int = 0, controller=None, **kw):
    """A (not yet started) simulated server for ``protocol`` ("kuka" or "abb")."""
    if protocol == "kuka":
        from jcalib.acquisition.robots.kuka_sim import KukaSimServer

        return KukaSimServer(controller, host, port, **kw)
    if protocol == "abb":
        from jcalib.acquisition.robots.abb_sim import AbbSimServer

        return AbbSimServer(controller, host, port, **kw)
    from jcalib.errors import BadInputError

    raise BadInputError(f"protocol: expected 'kuka' or 'abb', got {protocol!r}")


def start_subprocess(
    protocol: str,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    time_scale: float = 1.0,
    seed: int = 0,
    robot: str | None = None,
) -> tuple[subprocess.Popen, int]:
    """Start a simulated controller in a child process; returns ``(process, port)``.

    Stop it with ``process.terminate(); process.wait()``.
    """
    cmd = [
        sys.executable, "-m", "jcalib.acquisition.robots.serve", "--protocol", protocol,
        "--host", host, "--port", str(port), "--time-scale", str(time_scale), "--seed", str(seed),
    ]  # fmt: skip
    if robot:
        cmd += ["--robot", robot]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline() if proc.stdout else ""
    if not line.startswith("LISTENING"):
        proc.kill()
        proc.wait()
        raise DeviceError(f"simulated {protocol} controller did not start (said {line!r})")
    return proc, int(line.rsplit(":", 1)[1])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", choices=["kuka", "abb"], required=True)
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=0)
    ap.add_argument("--time-scale", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--robot", default=None, help="preset of jcalib.geometry.robots (default: generic arm)")
    a = ap.parse_args(argv)
    from jcalib.acquisition.robots.model import preset_model
    from jcalib.acquisition.robots.simulated import SimulatedController

    model = preset_model(a.robot) if a.robot else None
    server = make_server(
        a.protocol, a.host, a.port, SimulatedController(model, time_scale=a.time_scale, seed=a.seed)
    ).start()
    done = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: done.set())
    print(f"LISTENING {a.protocol} {server.host}:{server.port}", flush=True)
    done.wait()
    server.stop()


if __name__ == "__main__":
    main()
