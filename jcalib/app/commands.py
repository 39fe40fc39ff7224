"""What the acquisition CLI commands call: open devices from URLs, run a capture, run a simulated cell.

Device URLs: ``kuka://HOST[:PORT]`` (KUKAVARPROXY, 7000), ``abb://HOST[:PORT]`` (jcalib RAPID server,
5515) for robots; ``gige://IPV4`` (opened by address, never by discovery) and ``replay://FOLDER`` for
cameras.

``jcalib plan`` calls :func:`run_plan`, ``jcalib simulate`` :func:`run_simulate`, ``jcalib capture``
:func:`run_capture`.
"""

from __future__ import annotations

import shlex
import threading
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from jcalib.acquisition.cameras.base import Camera
from jcalib.acquisition.capture import CaptureResult, capture
from jcalib.io.plan import load_plan
from jcalib.acquisition.robots.base import Robot
from jcalib.errors import BadInputError, DeviceError


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
    hint = shlex.join(argv)
    if not camera_urls:
        raise BadInputError("--camera: expected at least one camera, e.g. --camera cam0=gige://192.168.10.20")
    for name, url in camera_urls.items():
        _split(url, f"--camera {name}", ("gige", "replay"))
    _split(robot_url, "--robot", ("kuka", "abb"))
    robot = None
    cams: dict[str, Camera] = {}
    try:
        robot = open_robot(robot_url)
        for name, url in camera_urls.items():
            extra = {"packet_size": packet_size} if url.startswith("gige://") and packet_size else {}
            cams[name] = open_camera(name, url, **extra)
        return capture(
            plan, robot, cams, out, resume=resume, cell=cell_dict, progress=progress,
            resume_hint=hint,
        )  # fmt: skip
    except DeviceError as e:
        from jcalib.acquisition.capture import CaptureInterrupted

        if isinstance(e, CaptureInterrupted) or "being written by another process" in str(e):
            raise
        if (Path(out) / "session.json").is_file():
            raise DeviceError(f"{e}\nThe session in {out} is consistent; fix the cause, then resume: {hint}") from e
        raise DeviceError(f"{e}\nNothing was captured yet; fix the cause and run the same command again.") from e
    finally:
        for c in cams.values():
            c.close()
        if robot is not None:
            robot.close()


def parse_named(values: Sequence[str], what: str = "--camera") -> dict[str, str]:
    """``["cam0=gige://10.0.0.5", ...]`` -> ``{"cam0": "gige://10.0.0.5", ...}`` (names unique)."""
    out: dict[str, str] = {}
    for v in values:
        name, sep, value = v.partition("=")
        name, value = name.strip(), value.strip()
        if not sep or not name or not value:
            raise BadInputError(f"{what}: expected NAME=VALUE such as cam0=gige://192.168.10.20, got {v!r}")
        if name in out:
            raise BadInputError(f"{what}: camera {name!r} is given twice")
        out[name] = value
    return out


def parse_image_size(text: str | None) -> tuple[int, int] | None:
    """``"640x480"`` -> ``(640, 480)``."""
    if text is None:
        return None
    w, sep, h = text.lower().partition("x")
    try:
        if not sep:
            raise ValueError
        return int(w), int(h)
    except ValueError:
        raise BadInputError(f"--image-size: expected WIDTHxHEIGHT such as 640x480, got {text!r}") from None


def run_plan(
    cell: str | Path,
    kind: str,
    out: str | Path,
    *,
    robot: str | None = None,
    num_stations: int | None = None,
    camera: str | None = None,
    target: str | None = None,
    tool: str | None = None,
    amplitude_deg: float | None = None,
    image_size: tuple[int, int] | None = None,
):
    """``jcalib plan``: plan stations for the cell (:func:`jcalib.acquisition.planner.plan_cell`), write them.

    Returns:
        The :class:`~jcalib.acquisition.planner.PlannedStations` written to ``out`` (``jcalib.plan/1``
        JSON with an extra ``planner`` key: kind, robot, camera / target / tool, dropped candidates).
    """
    from jcalib.acquisition.layout import cell_layout
    from jcalib.acquisition.planner import plan_cell
    from jcalib.io.atomic import write_json_atomic

    layout = cell_layout(cell, robot=robot, image_size=image_size)
    planned = plan_cell(layout, kind, num_stations=num_stations, camera=camera, target=target, tool=tool,
                        amplitude_deg=amplitude_deg)  # fmt: skip
    write_json_atomic(out, planned.to_json(layout))
    return planned


def run_simulate(
    cell: str | Path,
    *,
    robot_protocol: str,
    robot_port: int,
    camera_addresses: Mapping[str, str],
    truth: str | Path | None = None,
    robot: str | None = None,
    image_size: tuple[int, int] | None = None,
    time_scale: float = 1.0,
    seed: int = 0,
    noise: str = "clean",
    stop: threading.Event | None = None,
    on_ready: Callable[[dict], None] | None = None,
) -> None:
    """``jcalib simulate``: serve the cell's nominal layout (robot + fake GigE cameras) until ``stop``.

    The robot is the layout's preset (:class:`~jcalib.acquisition.robots.model.DHRobotModel`) behind a
    KUKAVARPROXY or ABB line-protocol server on 127.0.0.1:``robot_port``; each camera named in
    ``camera_addresses`` is a fake GigE camera on its loopback address rendering the scene at the
    robot's true pose. Everything listens on loopback only.

    Args:
        cell: cell spec (path or mapping); see :func:`jcalib.acquisition.layout.cell_layout`.
        robot_protocol: "kuka" or "abb".
        robot_port: TCP port (0: any free one; the ready info says which).
        camera_addresses: camera id -> 127.x.y.z address.
        truth: write the ground truth (:func:`jcalib.app.simcell.layout_truth`) here.
        robot, image_size: passed to :func:`~jcalib.acquisition.layout.cell_layout`.
        time_scale: motion-time scale (0: instantaneous moves).
        seed: noise seed (robot repeatability, sensor noise).
        noise: image formation preset of the cameras (:meth:`jcalib.sim.render.RenderOptions.preset`):
            "clean" (bright, sharp: ~0.01 px corners) or "realistic" (dim, defocused: ~0.1 px corners).
        stop: set to shut down (default: until KeyboardInterrupt).
        on_ready: called with ``{"robot": URL, "cameras": {id: URL}}`` once every device listens.
    """
    import ipaddress

    from jcalib.acquisition.layout import cell_layout
    from jcalib.acquisition.robots.model import preset_model
    from jcalib.app.simcell import layout_truth, scene_from_layout
    from jcalib.io.atomic import write_json_atomic
    from jcalib.sim.render import RenderOptions

    if robot_protocol not in ("kuka", "abb"):
        raise BadInputError(f"--robot-protocol: expected kuka or abb, got {robot_protocol!r}")
    if not 0 <= int(robot_port) <= 65535:
        raise BadInputError(f"--robot-port: expected 0..65535, got {robot_port}")
    if not camera_addresses:
        raise BadInputError("--camera: expected at least one camera, e.g. --camera cam0=127.0.0.1")
    for name, addr in camera_addresses.items():
        try:
            loop = ipaddress.IPv4Address(addr).is_loopback
        except ValueError:
            loop = False
        if not loop:
            raise BadInputError(
                f"--camera {name}: the simulator serves on loopback IPv4 addresses (127.x.y.z) only, got {addr!r}"
            )
    try:
        options = RenderOptions.preset(noise)
    except BadInputError as e:
        raise BadInputError(f"--noise: {e}") from None
    layout = cell_layout(cell, robot=robot, image_size=image_size)
    unknown = set(camera_addresses) - set(layout.cameras)
    if unknown:
        raise BadInputError(f"--camera: {', '.join(sorted(unknown))} not in the cell (has {', '.join(layout.cameras)})")
    scene = scene_from_layout(layout)
    model = preset_model(layout.robot)
    model.inverse(layout.T_base_flange_home, model.home_rad)  # compile the IK before clients connect
    if truth is not None:
        write_json_atomic(truth, layout_truth(layout, seed=int(seed), time_scale=float(time_scale),
                                              protocol=robot_protocol))  # fmt: skip
    ready = threading.Event()
    info: dict = {}

    def announce() -> None:
        ready.wait()
        if on_ready is not None and info:
            on_ready(info)

    waiter = threading.Thread(target=announce, daemon=True)
    waiter.start()
    run_simulated_cell(
        scene, robot_protocol=robot_protocol, robot_port=int(robot_port), camera_addresses=camera_addresses,
        robot_model=model, time_scale=time_scale, seed=seed, stop=stop, ready=ready, info=info, options=options,
    )  # fmt: skip


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
    info: dict | None = None,
    options: Any = None,
) -> None:
    """A robot server plus one fake GigE camera per scene camera, until ``stop`` (behind ``jcalib simulate``).

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
        info: filled before ``ready`` is set: ``{"robot": "kuka://127.0.0.1:PORT", "cameras": {id: "gige://ADDR"}}``.
        options: the cameras' :class:`jcalib.sim.render.RenderOptions` (None: the defaults).
    """
    from contextlib import ExitStack

    from jcalib.acquisition.cameras.fake_gige import FakeGigECamera
    from jcalib.acquisition.robots.serve import make_server
    from jcalib.acquisition.robots.simulated import SimulatedController
    from jcalib.app.simcell import scene_frame_source
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
            source = scene_frame_source(scene, name, ctrl.true_T_base_flange, options=options, seed=seed + 1000 * k)
            size = camera_image_size(scene.cameras[name].model)
            # GigE Vision serials hold 15 bytes: index + name, cut
            fake = FakeGigECamera(source, address, sensor_size=size, serial=f"SIM{k}-{name}"[:15])
            stack.enter_context(fake)
        if info is not None:
            info.update(robot=f"{robot_protocol}://{server.host}:{server.port}",
                        cameras={name: f"gige://{a}" for name, a in camera_addresses.items()})  # fmt: skip
        if ready is not None:
            ready.set()
        try:
            while not stop.wait(0.2):
                pass
        except KeyboardInterrupt:
            pass
