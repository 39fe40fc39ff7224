"""The simulated cell of ``jcalib demo`` and ``jcalib ui --simulate``: its cell spec, and the simulator process.

The simulator is ``jcalib simulate`` in a process of its own, like a real controller and real cameras
(Aravis' fake cameras and its client do not share one process reliably): :func:`start_simulator` starts
it, waits until every device listens and hands back their URLs. It must run where its camera addresses
exist: inside the private network namespace of :mod:`jcalib.acquisition.netns`.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from jcalib.errors import DeviceError

__all__ = ["DEMO_CELL", "DEMO_ADDRESSES", "SimulatorProcess", "start_simulator"]

#: The demo cell: an eye-in-hand camera, a fixed camera, a checkerboard on the table, a tool whose TCP
#: the fixed camera measures (its tip held in front of it, seen in silhouette), and the accuracy an integrator
#: needs of them (``goals:``, worst-direction σ, :mod:`jcalib.io.goals`), toward which ``jcalib demo`` plans
#: its stations (:func:`jcalib.app.demo_cell.plan_demo`).
DEMO_CELL = """schema: jcalib.cell/1
robot:
  model: kuka_kr10_r1100_sixx
  pose_noise: {translation_m: 0.000013, rotation_deg: 0.00115}  # the simulated robot's repeatability (ISO 9283: 0.04 mm)
cameras:
  cam_hand: {model: opencv4, mount: flange}
  cam_fixed:
    model: opencv5
    mount: base
    # a fixed camera that sees a fixed target cannot calibrate its own lens (every view is the same):
    # its intrinsics come from an earlier camera calibration; its pose in the cell is calibrated here
    intrinsics: {K: [[720.0, 0.0, 322.0], [0.0, 718.0, 241.0], [0.0, 0.0, 1.0]], dist: [-0.12, 0.05, 0.0, 0.0, 0.0]}
    fix: [fx, fy, cx, cy, k1, k2, p1, p2, k3]
targets:
  board: {type: checkerboard, cols: 9, rows: 6, square: 0.025, mount: base}  # 9x6: no 180° ambiguity
tools:
  torch: {observed_by: [cam_fixed]}
goals:  # worst-direction σ; the demo plans its stations to meet them
  - T_flange_cam_hand:translation_mm<=0.5  # hand-eye: where the flange camera measures, in the robot's frame
  - T_flange_cam_hand:rotation_deg<=0.05   # 0.05 deg = 0.35 mm at 0.4 m
  - T_base_cam_fixed:translation_mm<=0.5   # the fixed camera in the robot's base frame
  - T_base_cam_fixed:rotation_deg<=0.05
  - T_flange_torch:position_mm<=0.3        # TCP: where the torch tip is
  - T_flange_torch:rotation_deg<=0.5       # and where its axis points (a torch's angle matters to degrees)
  - cam_hand:projection_px<=1.0            # the flange camera's lens, anywhere in the image (corners included)
"""
#: Loopback address of each demo camera's fake GigE device (GigE Vision's control port is fixed).
DEMO_ADDRESSES = {"cam_hand": "127.0.0.1", "cam_fixed": "127.0.0.2"}


@dataclass
class SimulatorProcess:
    """A running ``jcalib simulate``.

    Attributes:
        process: the process.  robot_url: ``kuka://127.0.0.1:PORT`` (or ``abb://``, or ``ur://127.0.0.1``).
        camera_urls: camera id -> ``gige://ADDRESS``.  log_path: its stderr.
    """

    process: subprocess.Popen
    robot_url: str
    camera_urls: dict[str, str]
    log_path: Path

    def stop(self, timeout_s: float = 30.0) -> None:
        """Terminate the simulator and wait for it (killed after ``timeout_s``)."""
        self.process.terminate()
        try:
            self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


def start_simulator(cell: str | Path, *, addresses: dict[str, str], log_path: str | Path, protocol: str = "kuka",
                    robot: str | None = None, image_size: str | None = None, seed: int = 0, time_scale: float = 0.0,
                    noise: str = "realistic", fast_noise: bool = False, truth: str | Path | None = None,
                    kinematic_errors: int | None = None) -> SimulatorProcess:  # fmt: skip
    """Start ``jcalib simulate`` for ``cell`` and wait until its devices listen.

    Args:
        cell: the cell spec file.  addresses: camera id -> loopback address of its fake GigE camera.
        log_path: where the simulator's messages go.  protocol: "kuka", "abb" or "ur" (UR on its fixed ports).
        robot: robot preset (default: the cell's).  image_size: "WxH" of cameras without intrinsics.
        seed: noise seed.  time_scale: motion-time scale (0: instantaneous moves; 1: a real robot's speed).
        noise: "clean" or "realistic" images.  fast_noise: fast sensor noise for live views.
        truth: write the ground truth here.  kinematic_errors: seed of hidden kinematic errors (None: none).

    Raises:
        DeviceError: the simulator did not start (its log is quoted).
    """
    cmd = [sys.executable, "-c", "from jcalib.app.cli import main; main()", "simulate", "--cell", str(cell),
           "--robot-protocol", protocol, "--time-scale", str(time_scale), "--seed", str(int(seed)),
           "--noise", noise]  # fmt: skip
    if protocol != "ur":  # UR's ports are fixed (30004, 30002): free in the private namespace the cell runs in
        cmd += ["--robot-port", "0"]
    if robot:
        cmd += ["--robot", robot]
    if image_size:
        cmd += ["--image-size", image_size]
    if fast_noise:
        cmd += ["--fast-noise"]
    if truth is not None:
        cmd += ["--truth", str(truth)]
    if kinematic_errors is not None:
        cmd += ["--kinematic-errors", str(int(kinematic_errors))]
    for name, addr in addresses.items():
        cmd += ["--camera", f"{name}={addr}"]
    log_path = Path(log_path)
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, text=True)
    line = proc.stdout.readline() if proc.stdout else ""
    if not line.startswith("READY"):
        proc.kill()
        proc.wait()
        raise DeviceError(f"the simulated cell did not start: {log_path.read_text(errors='replace')[-2000:]}")
    words = line.split()
    robot_url = words[2]
    cams = {}
    for k, w in enumerate(words):
        if w == "--camera" and k + 1 < len(words):
            name, _, url = words[k + 1].partition("=")
            cams[name] = url
    return SimulatorProcess(proc, robot_url, cams, log_path)
