"""``jcalib simulate``: a simulated cell (robot controller server + fake GigE cameras) on loopback.

The command and the other front ends start it as a process of its own
(:func:`jcalib.workflow.simulate.start_simulator`); devices are opened from URLs by
:mod:`jcalib.workflow.devices`.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from jcalib.errors import BadInputError


def run_simulate(
    cell: str | Path,
    *,
    robot_protocol: str,
    robot_port: int | None,
    camera_addresses: Mapping[str, str],
    truth: str | Path | None = None,
    robot: str | None = None,
    image_size: tuple[int, int] | None = None,
    time_scale: float = 1.0,
    seed: int = 0,
    noise: str = "clean",
    stop: threading.Event | None = None,
    on_ready: Callable[[dict], None] | None = None,
    kinematic_errors: int | None = None,
    kinematic_error_scale: float = 1.0,
    fast_noise: bool = False,
) -> None:
    """``jcalib simulate``: serve the cell's nominal layout (robot + fake GigE cameras) until ``stop``.

    The robot is the layout's preset (:class:`~jcalib.acquisition.robots.model.DHRobotModel`) behind a
    KUKAVARPROXY, ABB line-protocol or UR (RTDE + URScript) server on 127.0.0.1:``robot_port``; each camera named in
    ``camera_addresses`` is a fake GigE camera on its loopback address rendering the scene at the
    robot's true pose. Everything listens on loopback only.

    Args:
        cell: cell spec (path or mapping); see :func:`jcalib.planning.layout.cell_layout`.
        robot_protocol: "kuka", "abb" or "ur".
        robot_port: TCP port (0: any free one; the ready info says which). None: UR's fixed ports (RTDE 30004,
            secondary interface 30002) for "ur", required for the others; for "ur" 0 puts both on free ports.
        camera_addresses: camera id -> 127.x.y.z address.
        truth: write the ground truth (:func:`jcalib.app.simcell.layout_truth`) here.
        robot, image_size: passed to :func:`~jcalib.planning.layout.cell_layout`.
        time_scale: motion-time scale (0: instantaneous moves).
        seed: noise seed (robot repeatability, sensor noise).
        noise: image formation preset of the cameras (:meth:`jcalib.sim.render.RenderOptions.preset`):
            "clean" (bright, sharp: ~0.01 px corners) or "realistic" (dim, defocused: ~0.1 px corners).
        stop: set to shut down (default: until KeyboardInterrupt).
        on_ready: called with ``{"robot": URL, "cameras": {id: URL}}`` once every device listens.
        kinematic_errors: seed of hidden kinematic errors of the robot (None: its kinematics is the
            preset's): the controller plans and reports with the preset, the cameras see the true arm
            (:func:`jcalib.app.simcell.simulated_kinematics`); ``truth`` then holds the true parameters.
        kinematic_error_scale: factor on the errors' σ (1: a real arm's, ~0.05 deg and 0.5 mm).
        fast_noise: the cameras draw sensor noise by its normal approximation
            (:class:`jcalib.sim.render.RenderOptions` ``fast_noise``), for live views.
    """
    import ipaddress

    from jcalib.planning.layout import cell_layout
    from jcalib.acquisition.robots.model import preset_model
    from jcalib.app.simcell import layout_truth, scene_from_layout
    from jcalib.io.atomic import write_json_atomic
    from jcalib.sim.render import RenderOptions

    if robot_protocol not in ("kuka", "abb", "ur"):
        raise BadInputError(f"--robot-protocol: expected kuka, abb or ur, got {robot_protocol!r}")
    if robot_port is None and robot_protocol != "ur":
        raise BadInputError(f"--robot-port: give the TCP port of the {robot_protocol} simulator (0: any free one); "
                            "only ur has fixed ports")
    if robot_port is not None and not 0 <= int(robot_port) <= 65535:
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
        options = RenderOptions.preset(noise, fast_noise=bool(fast_noise))
    except BadInputError as e:
        raise BadInputError(f"--noise: {e}") from None
    layout = cell_layout(cell, robot=robot, image_size=image_size)
    unknown = set(camera_addresses) - set(layout.cameras)
    if unknown:
        raise BadInputError(f"--camera: {', '.join(sorted(unknown))} not in the cell (has {', '.join(layout.cameras)})")
    lenses = _zoom_lenses(cell, layout)
    scene = scene_from_layout(layout)
    model = preset_model(layout.robot)
    model.inverse(layout.T_base_flange_home, model.home_rad)  # compile the IK before clients connect
    kinematics = true_forward = None
    if kinematic_errors is not None:
        from jcalib.app.simcell import simulated_kinematics

        kinematics = simulated_kinematics(model, layout.robot, int(kinematic_errors), float(kinematic_error_scale))
        true_forward = kinematics.forward()
        true_forward(model.home_rad)  # compile before clients connect
    if truth is not None:
        known = layout_truth(layout, kinematics, seed=int(seed), time_scale=float(time_scale), protocol=robot_protocol)
        if lenses:  # the zoom lenses' functions, tabulated (the camera's pose in the layout is at Zoom = 0)
            known["lenses"] = {n: lens.functions(range(0, 1001, 25)) for n, lens in lenses.items()}
        write_json_atomic(truth, known)
    ready = threading.Event()
    info: dict = {}

    def announce() -> None:
        ready.wait()
        if on_ready is not None and info:
            on_ready(info)

    waiter = threading.Thread(target=announce, daemon=True)
    waiter.start()
    run_simulated_cell(
        scene, robot_protocol=robot_protocol, robot_port=None if robot_port is None else int(robot_port),
        camera_addresses=camera_addresses,
        robot_model=model, time_scale=time_scale, seed=seed, stop=stop, ready=ready, info=info, options=options,
        true_forward=true_forward, lenses=lenses,
    )  # fmt: skip


def run_simulated_cell(
    scene: Any,
    *,
    robot_protocol: str,
    robot_port: int | None,
    camera_addresses: Mapping[str, str],
    robot_model: Any = None,
    time_scale: float = 1.0,
    seed: int = 0,
    stop: threading.Event | None = None,
    ready: threading.Event | None = None,
    info: dict | None = None,
    options: Any = None,
    true_forward: Callable[[np.ndarray], np.ndarray] | None = None,
    lenses: Mapping[str, Any] | None = None,
) -> None:
    """A robot server plus one fake GigE camera per scene camera, until ``stop`` (behind ``jcalib simulate``).

    Args:
        scene: a :class:`jcalib.sim.scene.Scene` (cameras and targets on "base" / "flange").
        robot_protocol: "kuka", "abb" or "ur".
        robot_port: TCP port of the simulated controller on 127.0.0.1 (None: UR's fixed ports; see
            :func:`jcalib.acquisition.robots.serve.make_server`).
        camera_addresses: scene camera name -> loopback address of its fake GigE camera.
        robot_model: controller model (default: the generic six-axis arm).
        time_scale: motion-time scale of the simulated controller.
        seed: seed of the repeatability noise and of the sensor noise.
        stop: set it to shut everything down (default: run until KeyboardInterrupt).
        ready: set once every device is listening.
        info: filled before ``ready`` is set: ``{"robot": "kuka://127.0.0.1:PORT", "cameras": {id: "gige://ADDR"}}``
            (UR: ``ur://127.0.0.1``, or ``ur://127.0.0.1:RTDE:SCRIPT`` on free ports).
        options: the cameras' :class:`jcalib.sim.render.RenderOptions` (None: the defaults).
        true_forward: the robot's true kinematics (joints rad -> ``T_base_flange``), which the cameras
            see while the controller reports ``robot_model``'s (None: no kinematic error).
        lenses: camera -> :class:`jcalib.sim.zoom.ZoomLensModel` of the cameras with a motorised zoom lens
            (their fake has ``Zoom`` and ``Focus`` features and renders through the lens).
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
    ctrl = SimulatedController(robot_model, time_scale=time_scale, seed=seed, true_forward=true_forward)
    stop = stop or threading.Event()
    with ExitStack() as stack:
        server = make_server(robot_protocol, "127.0.0.1", robot_port, ctrl).start()
        stack.callback(server.stop)
        for k, (name, address) in enumerate(camera_addresses.items()):
            lens = (lenses or {}).get(name)
            source = scene_frame_source(scene, name, ctrl.true_T_base_flange, options=options, seed=seed + 1000 * k,
                                        lens=lens)
            size = camera_image_size(scene.cameras[name].model)
            # GigE Vision serials hold 15 bytes: index + name, cut
            fake = FakeGigECamera(source, address, sensor_size=size, serial=f"SIM{k}-{name}"[:15],
                                  lens_features=lens is not None)
            stack.enter_context(fake)
        if info is not None:
            info.update(robot=getattr(server, "url", f"{robot_protocol}://{server.host}:{server.port}"),
                        cameras={name: f"gige://{a}" for name, a in camera_addresses.items()})  # fmt: skip
        if ready is not None:
            ready.set()
        try:
            while not stop.wait(0.2):
                pass
        except KeyboardInterrupt:
            pass




def _zoom_lenses(cell: Any, layout: Any) -> dict:
    """Camera -> the simulated zoom lens (:class:`jcalib.sim.zoom.ZoomLensModel`, its sensor the layout
    camera's) of the cameras whose cell entry has ``lens:``."""
    from jcalib.io.cell import load_cell
    from jcalib.sim.zoom import ZoomLensModel

    spec = load_cell(cell)
    out = {}
    for name, cam in spec.cameras.items():
        if cam.lens is not None and name in layout.cameras:
            w, h = layout.cameras[name].image_size
            out[name] = ZoomLensModel(f_wide_px=0.8 * w, image_size=(int(w), int(h)))
    return out
