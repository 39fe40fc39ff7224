"""Start ``jcalib ui`` as a user does (a subprocess on loopback) and read the URL it prints."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

import pytest

URL = re.compile(r"jcalib ui: (http://\S+/\?token=(\S+))")


@dataclass
class UIServer:
    proc: subprocess.Popen
    url: str
    token: str
    lines: list[str] = field(default_factory=list)

    @property
    def base(self) -> str:
        parts = urlsplit(self.url)
        return f"{parts.scheme}://{parts.netloc}"

    @property
    def port(self) -> int:
        return int(urlsplit(self.url).port)

    def output(self) -> str:
        return "\n".join(self.lines)


def start_ui(args: list[str], cwd: Path, timeout_s: float = 240.0) -> UIServer:
    """``jcalib ui ARGS`` in ``cwd``; returns once it printed its URL (its output is collected)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-c", "from jcalib.app.cli import main; main()", "ui", *args]
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    lines: list[str] = []
    found: dict = {}
    ready = threading.Event()

    def read() -> None:
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))
            m = URL.search(line)
            if m and not found:
                found["url"], found["token"] = m.group(1), m.group(2)
                ready.set()
        ready.set()

    threading.Thread(target=read, daemon=True).start()
    deadline = time.monotonic() + timeout_s
    while not ready.wait(0.2):
        if time.monotonic() > deadline:
            proc.kill()
            raise AssertionError("jcalib ui printed no URL within the time limit:\n" + "\n".join(lines[-40:]))
    if not found:
        proc.wait(10)
        raise AssertionError(f"jcalib ui exited ({proc.returncode}) without a URL:\n" + "\n".join(lines[-40:]))
    return UIServer(proc, found["url"], found["token"], lines)


def stop_ui(server: UIServer, timeout_s: float = 60.0) -> int:
    """Terminate the app as a supervisor would (SIGTERM) and return its exit status."""
    if server.proc.poll() is None:
        server.proc.send_signal(signal.SIGTERM)
        try:
            server.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            server.proc.kill()
            server.proc.wait()
    return server.proc.returncode


def netns_available() -> str | None:
    """Why a private network namespace cannot be made here (None: it can)."""
    import shutil

    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return "needs util-linux unshare and iproute2 ip for a private network namespace"
    flags = "-n" if os.geteuid() == 0 else "-rn"
    probe = subprocess.run(["unshare", flags, "true"], capture_output=True, text=True)
    return None if probe.returncode == 0 else f"cannot create a network namespace: {probe.stderr.strip()}"


@pytest.fixture(scope="session")
def ui_tools():
    """``start_ui``, ``stop_ui``, ``netns_available`` for the test modules (importlib mode: no conftest import)."""
    import types

    return types.SimpleNamespace(start_ui=start_ui, stop_ui=stop_ui, netns_available=netns_available)


@pytest.fixture
def replay_images(tmp_path: Path) -> Path:
    """A replay camera folder: two rendered 640x480 views of the demo cell's 9x6 board."""
    import cv2
    import numpy as np

    from jcalib.geometry.cameras import camera_from_opencv
    from jcalib.geometry.targets import Checkerboard
    from jcalib.sim.render import RenderOptions, render_target_image
    from jcalib.sim.textures import target_texture

    folder = tmp_path / "replay"
    folder.mkdir()
    board = Checkerboard(cols=9, rows=6, square=0.025)
    tex = target_texture(board, 0.025 / 24)
    cam = camera_from_opencv(np.array([[700.0, 0, 319.5], [0, 700.0, 239.5], [0, 0, 1]]), np.zeros(5), (640, 480))
    for k, (x, tilt) in enumerate(((-0.1, 0.2), (-0.08, -0.25))):
        c, s = np.cos(tilt), np.sin(tilt)
        T = np.array([[c, 0, s, x], [0, 1, 0, -0.06], [-s, 0, c, 0.55], [0, 0, 0, 1.0]])
        img = render_target_image(cam, T, tex, RenderOptions(), rng=k)
        cv2.imwrite(str(folder / f"frame{k:02d}.png"), img)
    return folder
