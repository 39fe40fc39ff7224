"""What the acquisition CLI commands call: open devices from URLs, run a capture, run a simulated cell.

Device URLs: ``kuka://HOST[:PORT]`` (KUKAVARPROXY, 7000), ``abb://HOST[:PORT]`` (jcalib RAPID server,
5515) for robots; ``gige://IPV4`` (opened by address, never by discovery) and ``replay://FOLDER`` for
cameras.
"""

from __future__ import annotations

import shlex
import threading
from pathlib import Path
from typing import Any, Mapping

from jcalib.acquisition.cameras.base import Camera
from jcalib.acquisition.capture import CaptureResult, capture
from jcalib.acquisition.plan import load_plan
from jcalib.acquisition.robots.base import Robot
from jcalib.errors import BadInputError


def _split(url: str, what: str, schemes: tuple[str, ...]) -> tuple[str, str]:
    scheme, sep, rest = url.partition("://")
    if not sep or scheme not in schemes or not rest:
        raise BadInputError(
            f"{what}: expected {' or '.join(s + '://...' for s in schemes)}, got {url!r}"
        )
    return scheme, rest


def open_robot(url: str, **kw: Any) -> Robot:
    """Connect to the robot at ``kuka://HOST[:PORT]`` or ``abb://HOST[:PORT]``."""
    scheme, rest = _split(url, "--robot", ("kuka", "abb"))
    host, _, port = rest.partition(":")
    try:
        port_n = int(port) if port else (7000 if scheme == "kuka" else 5515)
    except ValueError:
        raise BadInputError(f"--robot: port must be a number, got {port!r} in {url!r}") from None
    if scheme == "kuka":
        from jcalib.acquisition.robots.kuka import KukaRobot

        return KukaRobot(host, port_n, **kw)
    from jcalib.acquisition.robots.abb import AbbRobot

    return AbbRobot(host, port_n, **kw)


def open_camera(name: str, url: str, **kw: Any) -> Camera:
    """Open camera ``name`` at ``gige://IPV4`` or ``replay://FOLDER``."""
    scheme, rest = _split(url, f"--camera {name}", ("gige", "replay"))
    if scheme == "gige":
        from jcalib.acquisition.cameras.aravis import GigECamera

        return GigECamera(rest, name=name, **kw)
    from jcalib.acquisition.cameras.simulated import ReplayCamera

    return ReplayCamera(rest, name=name)


def run_capture(
    *,
    robot_url: str,
    camera_urls: Mapping[str, str],
    plan_path: str | Path,
    out: str | Path,
    cell: str | Path | None = None,
    resume: bool = False,
    progress: bool = True,
    packet_size: int | None = None,
) -> CaptureResult:
    """``jcalib capture``: open the devices, run the plan into the session ``out``, close the devices."""
    import yaml

    cell_dict = None
    if cell is not None:
        try:
            cell_dict = yaml.safe_load(Path(cell).read_text(encoding="utf-8"))
        except (OSError, yaml.YAMLError) as e:
            raise BadInputError(f"--cell: cannot read {cell}: {e}") from e
    plan = load_plan(plan_path)
    argv = ["jcalib", "capture"] + (["--cell", str(cell)] if cell else []) + ["--robot", robot_url]
    for name, url in camera_urls.items():
        argv += ["--camera", f"{name}={url}"]
    argv += ["--plan", str(plan_path), "--out", str(out), "--resume"]
    robot = open_robot(robot_url)
    cams: dict[str, Camera] = {}
    try:
        for name, url in camera_urls.items():
            extra = {"packet_size": packet_size} if url.startswith("gige://") and packet_size else {}
            cams[name] = open_camera(name, url, **extra)
        return capture(
            plan, robot, cams, out, resume=resume, cell=cell_dict, progress=progress,
            resume_hint=shlex.join(argv),
        )  # fmt: skip
    finally:
        for c in cams.values():
            c.close()
        robot.close()


def run_simulated_cell(
    scene: Any,
    *,
    robot_protocol: str,
    robot_port: int,
    camera_addresses: Mapping[str, str],
    robot_model: Any = None,
    time_scale: float = 1.0,
    seed: int = 0,
    stop: threading.Event | None = None,
    ready: threading.Event | None = None,
) -> None:
    """``jcalib simulate``: a robot server plus one fake GigE camera per scene camera, until ``stop``.

    Args:
        scene: a :class:`jcalib.sim.scene.Scene` (cameras and targets on "base" / "flange").
        robot_protocol: "kuka" or "abb".
        robot_port: TCP port of the simulated controller on 127.0.0.1.
        camera_addresses: scene camera name -> loopback address of its fake GigE camera.
        robot_model: controller model (default: the generic six-axis arm).
        time_scale: motion-time scale of the simulated controller.
        seed: seed of the repeatability noise and of the sensor noise.
        stop: set it to shut everything down (default: run until KeyboardInterrupt).
        ready: set once every device is listening.
    """
    from contextlib import ExitStack

    from jcalib.acquisition.cameras.fake_gige import FakeGigECamera
    from jcalib.acquisition.robots.serve import make_server
    from jcalib.acquisition.robots.simulated import SimulatedController
    from jcalib.acquisition.simcell import scene_frame_source
    from jcalib.sim.render import camera_image_size

    unknown = set(camera_addresses) - set(scene.cameras)
    if unknown:
        raise BadInputError(f"--camera: {', '.join(sorted(unknown))} not in the cell (has {', '.join(scene.cameras)})")
    ctrl = SimulatedController(robot_model, time_scale=time_scale, seed=seed)
    stop = stop or threading.Event()
    with ExitStack() as stack:
        server = make_server(robot_protocol, "127.0.0.1", robot_port, ctrl).start()
        stack.callback(server.stop)
        for k, (name, address) in enumerate(camera_addresses.items()):
            source = scene_frame_source(scene, name, ctrl.true_T_base_flange, seed=seed + 1000 * k)
            size = camera_image_size(scene.cameras[name].model)
            fake = FakeGigECamera(source, address, sensor_size=size, serial=f"JCALIB-SIM-{name}")
            stack.enter_context(fake)
        if ready is not None:
            ready.set()
        try:
            while not stop.wait(0.2):
                pass
        except KeyboardInterrupt:
            pass
