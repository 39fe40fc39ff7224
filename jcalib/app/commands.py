"""What the acquisition CLI commands call: open devices from URLs, run a capture, run a simulated cell.

Device URLs: ``kuka://HOST[:PORT]`` (KUKAVARPROXY, 7000), ``abb://HOST[:PORT]`` (jcalib RAPID server,
5515) for robots; ``gige://IPV4`` (opened by address, never by discovery) and ``replay://FOLDER`` for
cameras.

``jcalib plan`` calls :func:`run_plan`, ``jcalib simulate`` :func:`run_simulate`, ``jcalib capture``
:func:`run_capture`.
"""

from __future__ import annotations

import math
import shlex
import threading
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from jcalib.acquisition.cameras.base import Camera
from jcalib.acquisition.capture import CaptureControl, CaptureResult, EventListener, capture, stop_on_sigint
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


CAPTURE_KINDS = ("stations", "tcp")


def parse_settings(values: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``["cam0.ExposureTime=5000", "cam0.PixelFormat=Mono8"]`` -> ``{"cam0": {"ExposureTime": 5000, ...}}``.

    Values that read as integers or finite decimals become numbers, the rest stay strings.
    """
    out: dict[str, dict[str, Any]] = {}
    for v in values:
        key, sep, text = v.partition("=")
        cam, dot, feature = key.strip().partition(".")
        text = text.strip()
        if not sep or not dot or not cam or not feature or not text:
            raise BadInputError(f"--setting: expected CAMERA.FEATURE=VALUE such as cam0.ExposureTime=5000, got {v!r}")
        value: Any = text
        for conv in (int, float):
            try:
                value = conv(text)
                break
            except ValueError:
                continue
        if isinstance(value, float) and not math.isfinite(value):
            raise BadInputError(f"--setting {key}: expected a finite number or a word, got {text!r}")
        out.setdefault(cam, {})[feature] = value
    return out


def capture_settings(cell: Any, cli: Mapping[str, Mapping[str, Any]] | None) -> dict[str, dict[str, Any]]:
    """Camera settings of a capture: the cell spec's ``cameras.<id>.settings``, overridden per feature by ``cli``."""
    out = {cid: dict(c.settings) for cid, c in (cell.cameras.items() if cell is not None else []) if c.settings}
    for cid, features in (cli or {}).items():
        out.setdefault(cid, {}).update(features)
    return out


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
    settings: Mapping[str, Mapping[str, Any]] | None = None,
    kind: str = "stations",
    tolerance_px: float = 0.5,
    control: CaptureControl | None = None,
    listener: EventListener | None = None,
) -> CaptureResult:
    """``jcalib capture``: open the devices, run the plan into the session ``out``, close the devices.

    The first Ctrl-C (in the main thread) is the STOP button: the robot is stopped through its driver and
    the command ends with the resume hint (exit status 4); a second Ctrl-C interrupts at once.

    Args:
        settings: camera id -> {GenICam feature: value}; overrides the cell spec's
            ``cameras.<id>.settings`` feature by feature. Applied before the first station and
            recorded in session.json (:func:`jcalib.acquisition.capture.apply_camera_settings`).
        kind: "stations" (grab at every planned station) or "tcp": at every station, first bring the
            tool tip onto the image centre of the camera observing the tool with the visual servo
            (:func:`jcalib.acquisition.servo.servo_tool_tip`, tip detector
            :func:`jcalib.vision.tooltip.detect_tool_tip`), then grab; needs a ``jcalib plan --kind
            tcp`` plan and the cell spec.
        tolerance_px: ``kind="tcp"``: the servo stops when the tip is this close to the centre, px.
        control: the operator's pause / resume / abort / STOP
            (:class:`~jcalib.acquisition.capture.CaptureControl`; its ``stop()`` stops this command's robot).
        listener: per-step events (:data:`~jcalib.acquisition.capture.EventListener`).
    """
    import yaml

    if kind not in CAPTURE_KINDS:
        raise BadInputError(f"--kind: expected one of {', '.join(CAPTURE_KINDS)}, got {kind!r}")
    cell_dict = cell_spec = None
    if cell is not None:
        from jcalib.io.cell import parse_cell

        try:
            cell_dict = yaml.safe_load(Path(cell).read_text(encoding="utf-8"))
        except (OSError, yaml.YAMLError) as e:
            raise BadInputError(f"--cell: cannot read {cell}: {e}") from e
        cell_spec = parse_cell(cell_dict, source=str(cell))
    elif kind == "tcp":
        raise BadInputError("--kind tcp: give the cell spec (--cell) with the tool and the camera observing it")
    plan = load_plan(plan_path)
    all_settings = capture_settings(cell_spec, settings)
    argv = ["jcalib", "capture"] + (["--cell", str(cell)] if cell else []) + ["--robot", robot_url]
    for name, url in camera_urls.items():
        argv += ["--camera", f"{name}={url}"]
    argv += ["--plan", str(plan_path), "--out", str(out)]
    if packet_size:
        argv += ["--packet-size", str(packet_size)]
    for cid, features in (settings or {}).items():
        argv += [f"--setting={cid}.{k}={v}" for k, v in features.items()]
    if kind != "stations":
        argv += ["--kind", kind]
    hint = shlex.join(argv + ["--resume"])
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
        adjust = None
        if kind == "tcp":
            adjust = tcp_servo_adjust(robot, cams, cell, plan_path, tolerance_px=tolerance_px)
        control = control if control is not None else CaptureControl()
        with stop_on_sigint(control, robot):
            return capture(
                plan, robot, cams, out, resume=resume, cell=cell_dict, progress=progress,
                resume_hint=hint, camera_settings=all_settings, adjust=adjust, control=control, listener=listener,
            )  # fmt: skip
    except DeviceError as e:
        raise_capture_failure(e, out, hint)
    finally:
        close_devices(cams, robot)


def tcp_servo_adjust(robot: Robot, cameras: Mapping[str, Camera], cell: str | Path, plan_path: str | Path, *,
                     tolerance_px: float = 0.5, max_iterations: int = 10):  # fmt: skip
    """The station step of ``jcalib capture --kind tcp``: the visual servo of the TCP thesis (algorithm 4.1).

    The plan's ``planner`` key names the tool and the base camera observing it (``jcalib plan --kind
    tcp``); the camera's orientation in the base comes from the cell spec's ``pose`` of that camera,
    else from the nominal layout the plan was made for (a rough orientation is enough: the servo
    measures its image Jacobian by two probing moves and keeps refining it). At every station the
    tip is brought to the image centre by flange translations; the station's record gets ``servo:
    {converged, iterations, error_px, pixel}``. A station where the tip is not found, or the servo does
    not converge, is skipped with the reason.

    Returns:
        A :data:`jcalib.acquisition.capture.StationAdjust`.
    """
    import json

    from jcalib.acquisition.capture import SkipStation
    from jcalib.planning.layout import cell_layout
    from jcalib.acquisition.robots.base import MotionRefusedError
    from jcalib.acquisition.servo import servo_tool_tip
    from jcalib.errors import DetectionError
    from jcalib.geometry.cameras.factory import camera_from_opencv
    from jcalib.vision.tooltip import detect_tool_tip

    try:
        planner = json.loads(Path(plan_path).read_text(encoding="utf-8")).get("planner") or {}
    except (OSError, ValueError, AttributeError):
        planner = {}
    if planner.get("kind") != "tcp" or not planner.get("tool"):
        raise BadInputError(
            f"--kind tcp: {plan_path} is not a tcp plan (make one with `jcalib plan --kind tcp`): its 'planner' "
            "key must name the tool"
        )
    layout = cell_layout(cell, robot=planner.get("robot"))
    tool = str(planner["tool"])
    if tool not in layout.cell.tools:
        raise BadInputError(f"--kind tcp: the plan is for tool {tool!r}, which the cell spec does not define")
    observers = [c for c in layout.cell.tools[tool].observed_by if layout.cameras[c].mount == "base"]
    cam_name = str(planner.get("camera") or (observers[0] if observers else ""))
    if cam_name not in cameras:
        raise BadInputError(
            f"--kind tcp: the servo needs the base camera observing tool {tool!r} ({cam_name or 'none in the cell'}); "
            f"add --camera {cam_name or 'NAME'}=gige://..."
        )
    nominal = layout.cameras[cam_name]
    model = camera_from_opencv(nominal.K, nominal.dist, nominal.image_size, fisheye=nominal.model == "fisheye")
    R_base_cam = np.asarray(nominal.pose, dtype=np.float64)[:3, :3]
    camera = cameras[cam_name]

    def detect(image: np.ndarray, name: str) -> np.ndarray:
        return detect_tool_tip(image, camera=model, name=name).pixel

    def adjust(station, state):
        try:
            res = servo_tool_tip(robot, camera, R_base_cam, detect, tolerance_px=tolerance_px,
                                 max_iterations=max_iterations)  # fmt: skip
        except DetectionError as e:
            raise SkipStation(f"servo: {e}") from None
        except (BadInputError, MotionRefusedError) as e:
            raise SkipStation(f"servo: {e}") from None
        info = {"converged": bool(res.converged), "iterations": int(res.iterations),
                "error_px": float(res.error_px), "pixel": [float(v) for v in res.pixel],
                "target_px": [float(v) for v in res.target_px]}  # fmt: skip
        if not res.converged:
            raise SkipStation(f"servo: tip {res.error_px:.2f} px from the centre after {res.iterations} moves")
        return robot.wait_settled(), {"servo": info}

    return adjust


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
    num_candidates: int | None = None,
    seed: int = 0,
    sigma_px: float | None = None,
    goals: list[str] | None = None,
    max_stations: int | None = None,
):
    """``jcalib plan``: plan stations for the cell (:func:`jcalib.planning.stations.plan_cell`,
    :func:`~jcalib.planning.stations.plan_kinematics` for ``kinematics``, or
    :func:`jcalib.planning.optimal.plan_optimal` for ``optimal``), write them.

    Returns:
        The :class:`~jcalib.planning.stations.PlannedStations` written to ``out`` (``jcalib.plan/1``
        JSON with an extra ``planner`` key: kind, robot, camera / target / tool, dropped candidates;
        ``kinematics``: also the prediction and the joint spans).
    """
    from jcalib.planning.layout import cell_layout
    from jcalib.planning.stations import plan_cell, plan_kinematics
    from jcalib.io.atomic import write_json_atomic

    if kind == "kinematics":  # the layout is built only where a camera view is planned (not for external axes)
        planned = plan_kinematics(cell, robot=robot, image_size=image_size, num_stations=num_stations, camera=camera,
                                  target=target, amplitude_deg=amplitude_deg, num_candidates=num_candidates,
                                  seed=seed, sigma_px=sigma_px)  # fmt: skip
        write_json_atomic(out, planned.to_json())
        return planned
    layout = cell_layout(cell, robot=robot, image_size=image_size)
    if kind == "optimal":
        from jcalib.io.goals import parse_goals
        from jcalib.planning.optimal import DEFAULT_CANDIDATES, DEFAULT_MAX_STATIONS, plan_optimal
        from jcalib.problems.options import CalibrationOptions

        wanted = parse_goals(goals) if goals else layout.cell.goals
        options = CalibrationOptions() if sigma_px is None else CalibrationOptions(sigma_px=check_sigma_px(sigma_px))
        planned = plan_optimal(layout, wanted, max_stations or DEFAULT_MAX_STATIONS, options=options,
                               num_candidates=num_candidates or DEFAULT_CANDIDATES, seed=seed,
                               amplitude_deg=amplitude_deg)  # fmt: skip
        write_json_atomic(out, planned.to_json(layout))
        return planned
    planned = plan_cell(layout, kind, num_stations=num_stations, camera=camera, target=target, tool=tool,
                        amplitude_deg=amplitude_deg)  # fmt: skip
    write_json_atomic(out, planned.to_json(layout))
    return planned


#: ``jcalib plan`` options and the kinds that use them (any other kind refuses them).
PLAN_OPTIONS = {
    "--stations": ("viewsets", "handeye", "tcp", "kinematics"),
    "--goal": ("optimal",),
    "--max-stations": ("optimal",),
    "--tool": ("tcp",),
    "--camera": ("viewsets", "handeye", "kinematics"),
    "--target": ("viewsets", "handeye", "kinematics"),
    "--candidates": ("kinematics", "optimal"),
    "--sigma-px": ("kinematics", "optimal"),
}


def check_plan_options(kind: str, **given) -> None:
    """Refuse a ``jcalib plan`` option that ``kind`` does not use (naming it and the kinds that do)."""
    from jcalib.planning.stations import KINDS

    if kind not in KINDS + ("optimal",):
        raise BadInputError(f"--kind: expected one of {', '.join(KINDS + ('optimal',))}, got {kind!r}")
    for name, value in given.items():
        opt = "--" + name.replace("_", "-")
        if value is not None and value != [] and kind not in PLAN_OPTIONS[opt]:
            hint = " (optimal plans take --max-stations)" if opt == "--stations" else ""
            raise BadInputError(f"{opt}: not used by --kind {kind}; it applies to --kind "
                                f"{' / '.join(PLAN_OPTIONS[opt])}{hint}")


def check_sigma_px(sigma_px: float) -> float:
    if not (np.isfinite(sigma_px) and 0.0 < sigma_px <= 10.0):
        raise BadInputError(f"--sigma-px: expected a corner noise in (0, 10] px, got {sigma_px}")
    return float(sigma_px)


def optimal_plan_lines(planned) -> list[str]:
    """The predicted σ of each goal after each planned station (the greedy order), then the verdict."""
    d = planned.details
    goals = d["goals"]
    lines = ["predicted σ after each station (greedy order; goal in brackets):"]
    limits = {g: float(g.rsplit("<=", 1)[1]) for g in goals}
    for k, row in enumerate(d["after_each_station"], 1):
        parts = [f"{g.split('<=')[0]} {row[g]:.4g} [{limits[g]:g}]" for g in goals]
        lines.append(f"  {k:3d}: " + ", ".join(parts))
    final = ", ".join(f"{g.split('<=')[0]} {d['predicted'][g]:.4g}" for g in goals)
    lines.append(f"after exchanges and refinement ({d['refined']} stations refined): {final}")
    if d["met"]:
        lines.append(f"every goal is met (predicted) with {len(planned.plan)} stations")
    else:
        lines.append(f"WARNING: the goals are not met (predicted) with {len(planned.plan)} stations: raise "
                     "--max-stations, relax the goals, or lower the noise (better detection, a larger target)")
    return lines


def kinematic_plan_lines(planned) -> list[str]:
    """Console lines of a ``kinematics`` plan: each joint's span, the predicted worst σ per parameter
    group and what the prediction assumes."""
    d = planned.details
    pred = d["prediction"]
    spans = ", ".join(f"{j} {v['value']:.0f} {v['unit']}" for j, v in d["joint_span"].items())
    lines = [f"joints move over: {spans}",
             f"{len(d['free_parameters'])} parameters estimated, from {d['usable']} usable of {d['candidates']} "
             f"candidates; condition {pred['condition']:.3g}"]
    if d["held_parameters"]:
        lines.append(f"held at nominal (not separable): {', '.join(d['held_parameters'])}")
    for group, w in pred["worst"].items():
        lines.append(f"predicted worst σ {group}: {w['value']:.3g} ({w['name']})")
    lines.append(f"assuming {pred['assumes']}")
    return lines


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
    kinematic_errors: int | None = None,
    kinematic_error_scale: float = 1.0,
    fast_noise: bool = False,
) -> None:
    """``jcalib simulate``: serve the cell's nominal layout (robot + fake GigE cameras) until ``stop``.

    The robot is the layout's preset (:class:`~jcalib.acquisition.robots.model.DHRobotModel`) behind a
    KUKAVARPROXY or ABB line-protocol server on 127.0.0.1:``robot_port``; each camera named in
    ``camera_addresses`` is a fake GigE camera on its loopback address rendering the scene at the
    robot's true pose. Everything listens on loopback only.

    Args:
        cell: cell spec (path or mapping); see :func:`jcalib.planning.layout.cell_layout`.
        robot_protocol: "kuka" or "abb".
        robot_port: TCP port (0: any free one; the ready info says which).
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
        options = RenderOptions.preset(noise, fast_noise=bool(fast_noise))
    except BadInputError as e:
        raise BadInputError(f"--noise: {e}") from None
    layout = cell_layout(cell, robot=robot, image_size=image_size)
    unknown = set(camera_addresses) - set(layout.cameras)
    if unknown:
        raise BadInputError(f"--camera: {', '.join(sorted(unknown))} not in the cell (has {', '.join(layout.cameras)})")
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
        write_json_atomic(truth, layout_truth(layout, kinematics, seed=int(seed), time_scale=float(time_scale),
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
        true_forward=true_forward,
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
    true_forward: Callable[[np.ndarray], np.ndarray] | None = None,
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
        true_forward: the robot's true kinematics (joints rad -> ``T_base_flange``), which the cameras
            see while the controller reports ``robot_model``'s (None: no kinematic error).
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


def raise_capture_failure(e: DeviceError, out: str | Path, hint: str) -> None:
    """Re-raise a device error of a capture with what to do next: resume the consistent session in ``out``
    (``hint``: the command that resumes it), or run the command again when nothing was captured yet. An
    interruption or a session held by another process is re-raised as it is."""
    from jcalib.acquisition.capture import CaptureInterrupted

    if isinstance(e, CaptureInterrupted) or "being written by another process" in str(e):
        raise e
    if (Path(out) / "session.json").is_file():
        raise DeviceError(f"{e}\nThe session in {out} is consistent; fix the cause, then resume: {hint}") from e
    raise DeviceError(f"{e}\nNothing was captured yet; fix the cause and run the same command again.") from e


def close_devices(cameras: Mapping[str, Camera], robot: Robot | None) -> None:
    """Close a capture's cameras, then its robot (``None`` when it was never opened)."""
    for c in cameras.values():
        c.close()
    if robot is not None:
        robot.close()
