"""Captures with real or simulated devices: a station plan (``jcalib capture --plan``, the app's capture) and
the tool-tip servo of ``--kind tcp``. The command line opens the devices from URLs (:func:`run_capture`);
the app hands its open devices to :func:`capture_plan`. Both end the same way on a device failure: a
consistent session and the command that resumes it.
"""

from __future__ import annotations

import shlex
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.acquisition.cameras.base import Camera
from jcalib.acquisition.capture import CaptureControl, CaptureResult, EventListener, capture, stop_on_sigint
from jcalib.acquisition.robots.base import Robot
from jcalib.errors import BadInputError, DeviceError
from jcalib.io.plan import Plan, load_plan
from jcalib.workflow.devices import capture_settings, check_urls, close_devices, open_camera, open_robot

__all__ = ["CAPTURE_KINDS", "capture_plan", "raise_capture_failure", "read_cell", "run_capture", "tcp_servo_adjust"]

CAPTURE_KINDS = ("stations", "tcp")


def read_cell(cell: str | Path) -> tuple[dict, Any]:
    """The cell spec file as the plain mapping a session stores, and parsed (``--cell`` errors)."""
    import yaml

    from jcalib.io.cell import parse_cell

    try:
        cell_dict = yaml.safe_load(Path(cell).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
        raise BadInputError(f"--cell: cannot read {cell}: {e}") from e
    return cell_dict, parse_cell(cell_dict, source=str(cell))


def capture_plan(
    plan: Plan,
    robot: Robot,
    cameras: Mapping[str, Camera],
    out: str | Path,
    *,
    cell: str | Path | None = None,
    plan_path: str | Path | None = None,
    resume: bool = False,
    progress: bool = True,
    settings: Mapping[str, Mapping[str, Any]] | None = None,
    kind: str = "stations",
    tolerance_px: float = 0.5,
    control: CaptureControl | None = None,
    listener: EventListener | None = None,
    hint: str | None = None,
) -> CaptureResult:
    """Run ``plan`` with devices that are already open (what ``jcalib capture`` and the app's capture share).

    Args: as :func:`run_capture`; ``cell``: the cell spec file (stored in the session, settings and the
    servo read from it); ``plan_path``: the plan file (``kind="tcp"`` reads its planner key); ``hint``: the
    command that resumes the capture, quoted when it is interrupted.
    """
    if kind not in CAPTURE_KINDS:
        raise BadInputError(f"--kind: expected one of {', '.join(CAPTURE_KINDS)}, got {kind!r}")
    cell_dict = cell_spec = None
    if cell is not None:
        cell_dict, cell_spec = read_cell(cell)
    elif kind == "tcp":
        raise BadInputError("--kind tcp: give the cell spec (--cell) with the tool and the camera observing it")
    all_settings = capture_settings(cell_spec, settings)
    adjust = None
    if kind == "tcp":
        adjust = tcp_servo_adjust(robot, cameras, cell, plan_path, tolerance_px=tolerance_px)
    control = control if control is not None else CaptureControl()
    with stop_on_sigint(control, robot):
        return capture(
            plan, robot, cameras, out, resume=resume, cell=cell_dict, progress=progress,
            resume_hint=hint, camera_settings=all_settings, adjust=adjust, control=control, listener=listener,
        )  # fmt: skip


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
    if kind not in CAPTURE_KINDS:
        raise BadInputError(f"--kind: expected one of {', '.join(CAPTURE_KINDS)}, got {kind!r}")
    if cell is None and kind == "tcp":
        raise BadInputError("--kind tcp: give the cell spec (--cell) with the tool and the camera observing it")
    if cell is not None:
        read_cell(cell)
    plan = load_plan(plan_path)
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
    check_urls(robot_url, camera_urls)
    robot = None
    cams: dict[str, Camera] = {}
    try:
        robot = open_robot(robot_url)
        for name, url in camera_urls.items():
            extra = {"packet_size": packet_size} if url.startswith("gige://") and packet_size else {}
            cams[name] = open_camera(name, url, **extra)
        return capture_plan(plan, robot, cams, out, cell=cell, plan_path=plan_path, resume=resume, progress=progress,
                            settings=settings, kind=kind, tolerance_px=tolerance_px, control=control,
                            listener=listener, hint=hint)  # fmt: skip
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
