"""Run a simulated robot controller as its own process.

``python -m jcalib.acquisition.robots.serve --protocol kuka|abb|ur [--host 127.0.0.1] [--port 0]
[--time-scale 1.0] [--seed 0] [--robot PRESET]`` prints ``LISTENING <protocol> <host>:<port> <url>`` on stdout once
the port is open (for ``ur`` the port is the RTDE port and the URL names the secondary interface's too), then
serves until SIGTERM / SIGINT. :func:`start_subprocess` does that from Python.

UR's ports are fixed (RTDE 30004, secondary interface 30002): ``--protocol ur`` without ``--port`` takes them;
``--port 0`` puts both on free ports (tests outside a private network namespace).
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import threading

from jcalib.errors import DeviceError


#: The robot protocols the simulators speak.
PROTOCOLS = ("kuka", "abb", "ur")


def make_server(protocol: str, host: str = "127.0.0.1", port: int | None = 0, controller=None, **kw):
    """A (not yet started) simulated server for ``protocol`` ("kuka", "abb" or "ur").

    ``port`` 0 is any free port; None is the protocol's fixed port where it has one (UR: RTDE 30004 and the
    secondary interface 30002), else any free port. A UR server on a given port other than 30004 puts its
    secondary interface on a free port (see its ``url``).
    """
    if protocol == "ur":
        from jcalib.acquisition.robots.rtde import RTDE_PORT
        from jcalib.acquisition.robots.ur_sim import UrSimServer

        return UrSimServer(controller, host, RTDE_PORT if port is None else port, **kw)
    port = 0 if port is None else port
    if protocol == "kuka":
        from jcalib.acquisition.robots.kuka_sim import KukaSimServer

        return KukaSimServer(controller, host, port, **kw)
    if protocol == "abb":
        from jcalib.acquisition.robots.abb_sim import AbbSimServer

        return AbbSimServer(controller, host, port, **kw)
    from jcalib.errors import BadInputError

    raise BadInputError(f"protocol: expected 'kuka', 'abb' or 'ur', got {protocol!r}")


def start_subprocess(
    protocol: str,
    *,
    host: str = "127.0.0.1",
    port: int | None = 0,
    time_scale: float = 1.0,
    seed: int = 0,
    robot: str | None = None,
) -> tuple[subprocess.Popen, int]:
    """Start a simulated controller in a child process; returns ``(process, port)`` (UR: the RTDE port; the
    secondary interface's is the last number of the URL on its ``LISTENING`` line, which
    :func:`listening_url` reads).

    Stop it with ``process.terminate(); process.wait()``.
    """
    cmd = [
        sys.executable, "-m", "jcalib.acquisition.robots.serve", "--protocol", protocol,
        "--host", host, "--time-scale", str(time_scale), "--seed", str(seed),
    ]  # fmt: skip
    if port is not None:
        cmd += ["--port", str(port)]
    if robot:
        cmd += ["--robot", robot]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline() if proc.stdout else ""
    if not line.startswith("LISTENING"):
        proc.kill()
        proc.wait()
        raise DeviceError(f"simulated {protocol} controller did not start (said {line!r})")
    proc.listening = line  # type: ignore[attr-defined]
    return proc, int(line.split()[2].rsplit(":", 1)[1])


def listening_url(proc: subprocess.Popen) -> str:
    """The robot URL a simulator started by :func:`start_subprocess` announced (e.g. ``kuka://127.0.0.1:7001``)."""
    return str(getattr(proc, "listening")).split()[3]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", choices=list(PROTOCOLS), required=True)
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=None, help="0: any free port (default; UR: its fixed ports)")
    ap.add_argument("--time-scale", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--robot", default=None, help="preset of jcalib.geometry.robots (default: generic arm)")
    a = ap.parse_args(argv)
    from jcalib.acquisition.robots.model import preset_model
    from jcalib.acquisition.robots.simulated import SimulatedController

    model = preset_model(a.robot) if a.robot else None
    port = a.port if a.port is not None or a.protocol == "ur" else 0
    server = make_server(
        a.protocol, a.host, port, SimulatedController(model, time_scale=a.time_scale, seed=a.seed)
    ).start()
    done = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: done.set())
    url = getattr(server, "url", f"{a.protocol}://{server.host}:{server.port}")
    print(f"LISTENING {a.protocol} {server.host}:{server.port} {url}", flush=True)
    done.wait()
    server.stop()


if __name__ == "__main__":
    main()
