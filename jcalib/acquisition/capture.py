"""Run a station plan: move, settle, check the pose, grab from every camera, check, write the session.

For each station not yet in the session: move the robot (joint or linear), wait until it has settled,
check that the pose it reports is the one commanded (another program moving the robot, or a tool or
base other than 0 active, stops the capture), optionally adjust the pose (the visual servo of a TCP
capture), grab one frame from every camera, run the optional quality check (re-grab up to ``regrabs``
times, then skip the station with the reason recorded), write the images atomically and append the
station line. A target the controller refuses (unreachable) is recorded as ``"skipped: unreachable:
..."`` and the capture goes on. A lost robot connection or a camera that gives no complete frame stops
the capture cleanly (:class:`CaptureInterrupted`) with a message saying how to resume; what was
finished is on disk.

Resuming (after any stop, ``kill -9`` included) skips the stations listed in the session whose images
are all there and readable, captures the others again (a listed station whose image went missing is
appended once more as a retake), and refuses a session whose ``stations.jsonl`` is gone rather than
capture every station again over its images. A capture holds its robot
(:class:`jcalib.acquisition.robots.lock.RobotLock`): a second capture of the same robot is refused.
Camera settings (GenICam feature names, e.g. ``{"cam0": {"ExposureTime": 5000}}``) are applied before
the first station and recorded in ``session.json``.

Operator control (:class:`CaptureControl`, from any thread): *pause* finishes the station in flight and
waits before the next one until *resume*; *abort* finishes the station in flight and ends the capture
(:attr:`CaptureResult.aborted`); *STOP* stops the robot at once through its driver (:meth:`Robot.stop
<jcalib.acquisition.robots.base.Robot.stop>`) and ends the capture without recording the station in flight
(:class:`CaptureInterrupted`). A stopped or aborted session is consistent and ``resume`` continues it.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from jcalib.acquisition.cameras.base import Camera, UnsupportedFeatureError
from jcalib.acquisition.control import CONTROL_STATES, CaptureControl, stop_on_sigint
from jcalib.acquisition.robots.base import MotionRefusedError, MotionStoppedError, Robot, RobotState
from jcalib.acquisition.robots.lock import RobotLock, needs_lock
from jcalib.errors import BadInputError, DeviceError
from jcalib.geometry.se3 import pose_distance
from jcalib.io.plan import Plan, Station
from jcalib.io.session import SessionWriter, utc_now

#: ``check(camera_id, image, station) -> None`` when the image is usable, else the reason it is not.
QualityCheck = Callable[[str, np.ndarray, Station], "str | None"]
#: ``listener(event, station_id, detail)``; events: "start", "moved", "grabbed", "done", "skipped", "stopped"
#: (detail: the reason), and with a :class:`CaptureControl` "paused", "resumed" (before the station named),
#: "aborted" (the capture ends before the station named).
EventListener = Callable[[str, str, str], None]
#: ``adjust(station, state) -> (state, record fields)``: runs after the move and the pose check, may move
#: the robot again (e.g. :func:`jcalib.acquisition.servo.servo_tool_tip`); the images are taken at the
#: returned state, and the fields (JSON values) are added to the station's record.
StationAdjust = Callable[[Station, RobotState], "tuple[RobotState, dict]"]
#: Features :func:`capture` records in session.json for every camera.
RECORDED_FEATURES = ("ExposureTime", "Gain", "PixelFormat", "Width", "Height", "OffsetX", "OffsetY", "PacketSize")


class CaptureInterrupted(DeviceError):
    """A device failed mid-capture; the session on disk is consistent and can be resumed.

    Attributes:
        session_dir: the session folder.
        station_id: the station that was in flight.
        num_done: stations listed in the session.
    """

    def __init__(self, message: str, session_dir: Path, station_id: str, num_done: int):
        super().__init__(message)
        self.session_dir, self.station_id, self.num_done = session_dir, station_id, num_done


__all__ = ["CONTROL_STATES", "RECORDED_FEATURES", "CaptureControl", "CaptureInterrupted", "CaptureResult",
           "EventListener", "QualityCheck", "SkipStation", "StationAdjust", "apply_camera_settings", "capture",
           "check_reached", "image_readable", "stop_on_sigint"]


class SkipStation(DeviceError):
    """Raised by a :data:`StationAdjust` to skip the station; the message is recorded as the reason."""


@dataclass
class CaptureResult:
    """Summary of a capture run.

    Attributes:
        session_dir: the session folder.
        num_planned: stations in the plan.
        captured: ids captured by this run (status ok).
        skipped: id -> reason, for stations skipped by this run.
        already_done: stations that were in the session before this run (resume).
        elapsed_s: wall time of this run, s.
        aborted: the capture ended early by :meth:`CaptureControl.abort` (the session is consistent;
            ``resume`` continues it).
    """

    session_dir: Path
    num_planned: int
    captured: list[str] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    already_done: int = 0
    elapsed_s: float = 0.0
    aborted: bool = False


def _device_settings(robot: Robot, cameras: Mapping[str, Camera], requested: Mapping[str, Mapping[str, Any]]) -> dict:
    cams = {}
    for cid, cam in cameras.items():
        settings = {}
        for f in dict.fromkeys([*RECORDED_FEATURES, *requested.get(cid, {})]):
            try:
                if cam.has(f):
                    settings[f] = cam.get(f)
            except DeviceError:
                pass
        cams[cid] = {"address": cam.address, "driver": type(cam).__name__, "settings": settings,
                     "settings_requested": dict(requested.get(cid, {}))}  # fmt: skip
    return {"robot": {"address": robot.address, "driver": type(robot).__name__}, "cameras": cams}


def apply_camera_settings(cameras: Mapping[str, Camera], settings: Mapping[str, Mapping[str, Any]] | None) -> dict:
    """Set GenICam features on the cameras, in the order given; returns ``{camera: {feature: value}}``.

    Args:
        cameras: camera id -> opened camera.
        settings: camera id -> {feature name: number or string} (SFNC names such as ``ExposureTime``
            (us), ``Gain``, ``Focus``, ``Zoom``, or the device's own names).

    Raises:
        BadInputError: a camera id that is not among ``cameras``, a value that is not a finite number
            or a string, a feature the camera does not have (named), or a value the camera refuses.
    """
    out: dict[str, dict[str, Any]] = {}
    for cid, features in (settings or {}).items():
        where = f"cameras.{cid}.settings"
        if cid not in cameras:
            raise BadInputError(f"{where}: no camera {cid!r} is being captured (cameras: {', '.join(cameras)})")
        if not isinstance(features, Mapping):
            raise BadInputError(f"{where}: expected a mapping of GenICam feature names to values, got {features!r}")
        cam = cameras[cid]
        for name, value in features.items():
            ok = isinstance(value, str) or (
                isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)
            )
            if not isinstance(name, str) or not name or not ok:
                raise BadInputError(f"{where}.{name}: expected a finite number or a string, got {value!r}")
            try:
                cam.set(name, value)
            except UnsupportedFeatureError as e:
                raise BadInputError(f"{where}.{name}: {e}") from None
            except (BadInputError, DeviceError) as e:
                raise BadInputError(f"{where}.{name}: camera {cid} refused {value!r}: {e}") from None
            out.setdefault(cid, {})[name] = value
    return out


def image_readable(path: Path) -> bool:
    """Whether ``path`` is an image file OpenCV can decode."""
    import cv2

    return path.is_file() and cv2.imread(str(path), cv2.IMREAD_UNCHANGED) is not None


def check_reached(station: Station, state: RobotState, tolerance_mm: float, tolerance_deg: float) -> str | None:
    """None when the pose the robot reports is the commanded one within the tolerances, else why not."""
    dt, dr = pose_distance(np.asarray(state.T_base_flange), np.asarray(station.T_base_flange))
    if dt * 1e3 <= tolerance_mm and np.degrees(dr) <= tolerance_deg:
        return None
    return (
        f"the robot reports a pose {dt * 1e3:.3f} mm / {np.degrees(dr):.4f} deg from the commanded one "
        f"(tolerance {tolerance_mm} mm / {tolerance_deg} deg): another program or capture is moving it, or a "
        "tool or base other than 0 is active"
    )


def capture(
    plan: Plan,
    robot: Robot,
    cameras: Mapping[str, Camera],
    session_dir: str | Path,
    *,
    resume: bool = False,
    cell: dict | None = None,
    quality_check: QualityCheck | None = None,
    regrabs: int = 2,
    grab_timeout_s: float = 2.0,
    settle_timeout_s: float = 10.0,
    progress: bool = True,
    listener: EventListener | None = None,
    resume_hint: str | None = None,
    camera_settings: Mapping[str, Mapping[str, Any]] | None = None,
    pose_tolerance_mm: float = 1.0,
    pose_tolerance_deg: float = 0.1,
    adjust: StationAdjust | None = None,
    lock_robot: bool = True,
    control: CaptureControl | None = None,
) -> CaptureResult:
    """Execute ``plan`` and write (or extend) the session in ``session_dir``.

    Args:
        plan: stations to visit, in order.
        robot: a connected robot (tool 0 / base 0 active: poses are the flange in the robot base).
        cameras: camera id -> opened camera.
        session_dir: session folder; created unless ``resume``.
        resume: continue the session in ``session_dir``: stations already listed are skipped; the
            plan must be the one the session was started with.
        cell: the cell spec mapping to store in session.json (new sessions).
        quality_check: optional per-image check; see :data:`QualityCheck`.
        regrabs: re-grabs allowed per station when the quality check rejects an image.
        grab_timeout_s: per-trigger timeout of every grab, s.
        settle_timeout_s: longest wait for the robot to settle after a move, s.
        progress: show a rich progress bar on stderr.
        listener: optional callback for every step (see :data:`EventListener`).
        resume_hint: the command line that resumes this capture, quoted in interruption messages.
        camera_settings: camera id -> {GenICam feature: value}, applied before the first station
            (see :func:`apply_camera_settings`); a resumed capture must give the session's settings.
        pose_tolerance_mm, pose_tolerance_deg: largest distance between the pose the robot reports
            after a move and the commanded one (mm, deg); beyond, the capture stops.
        adjust: optional step after the move (see :data:`StationAdjust`).
        lock_robot: hold the robot's capture lock (:class:`~jcalib.acquisition.robots.lock.RobotLock`).
        control: the operator's pause / resume / abort / STOP (:class:`CaptureControl`).

    Returns:
        A :class:`CaptureResult` (``aborted`` after :meth:`CaptureControl.abort`).

    Raises:
        BadInputError: no cameras, a session exists and ``resume`` is False, the plan or the camera
            settings differ from the session's, a session to resume without ``stations.jsonl``, or
            camera settings a camera refuses.
        DeviceError: another capture drives the robot.
        CaptureInterrupted: lost robot connection, camera failure, a reached pose that is not the
            commanded one, a stop (:meth:`CaptureControl.stop`, or ``robot.stop()`` from elsewhere)
            (session consistent; resume).
    """
    if not cameras:
        raise BadInputError("cameras: expected at least one camera")
    t_start = time.monotonic()
    session_dir = Path(session_dir)
    requested = apply_camera_settings(cameras, camera_settings)
    check_lens_settings(plan, cameras)
    robot_lock = RobotLock(robot.address, str(session_dir)) if lock_robot and needs_lock(robot.address) else None
    try:
        writer, retakes = _open_session(plan, robot, cameras, session_dir, resume, cell, requested)
    except BaseException:
        if robot_lock is not None:
            robot_lock.release()
        raise
    emit = listener or (lambda *a: None)
    result = CaptureResult(session_dir, len(plan), already_done=len(writer.stations) - len(retakes))
    todo = [s for s in plan.stations if s.id not in writer.stations or s.id in retakes]
    hint = resume_hint or "run the same capture again with resume=True (CLI: add --resume)"

    bar = None
    if progress:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        bar = Progress(
            TextColumn("[bold]capture[/]"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
            TextColumn("{task.description}"), transient=False,
        )  # fmt: skip
        bar.start()
        task = bar.add_task("", total=len(plan), completed=len(plan) - len(todo))

    def status(text: str) -> None:
        if bar is not None:
            bar.update(task, description=text)

    def interrupted(station: Station, what: str, err: Exception) -> CaptureInterrupted:
        n = len(writer.stations)
        emit("stopped", station.id, str(err))
        return CaptureInterrupted(
            f"capture stopped at station {station.id}: {what}: {err}\n"
            f"{n} of {len(plan)} stations are saved in {session_dir} (station {station.id} will be repeated). "
            f"Fix the cause, then resume: {hint}.",
            session_dir,
            station.id,
            n,
        )

    def operator_stop(station: Station) -> CaptureInterrupted:
        n = len(writer.stations)
        emit("stopped", station.id, "stopped by the operator")
        return CaptureInterrupted(
            f"capture stopped by the operator (STOP) at station {station.id}: the robot stands where it braked and "
            f"station {station.id} was not recorded.\n{n} of {len(plan)} stations are saved in {session_dir}; the "
            f"session can be resumed. Check the cell, then resume: {hint}.",
            session_dir,
            station.id,
            n,
        )

    def stopped() -> bool:
        return control is not None and control.stop_requested

    def run_station(station: Station) -> None:
        """Move, check, adjust, grab, write one station; a stop anywhere before the write ends the capture."""
        emit("start", station.id, "")
        status(f"{station.id}: moving ({station.move})")
        seen = robot.num_stops  # before the check: a stop after this read refuses the moves below
        if stopped():
            raise operator_stop(station)
        with robot.stop_guard(seen):
            try:
                state = robot.move(station.T_base_flange, kind=station.move, settle_timeout_s=settle_timeout_s)
                why = check_reached(station, state, pose_tolerance_mm, pose_tolerance_deg)
                if why:  # read once more: a robot still creeping in
                    state = robot.wait_settled(timeout_s=settle_timeout_s)
                    why = check_reached(station, state, pose_tolerance_mm, pose_tolerance_deg)
            except MotionRefusedError as e:
                reason = f"unreachable: {e}"
                finish(station, {"id": station.id, "T_base_flange": None, "joints_deg": None, "time": utc_now(),
                                 "images": {}, "status": f"skipped: {reason}"}, reason)  # fmt: skip
                return
            except DeviceError as e:
                if stopped():
                    raise operator_stop(station) from e
                what = "robot stopped by a stop request" if isinstance(e, MotionStoppedError) else "robot"
                raise interrupted(station, what, e) from e
            if stopped():
                raise operator_stop(station)
            if why:
                raise interrupted(station, "robot", DeviceError(why))
            emit("moved", station.id, "")
            extra: dict = {}
            if adjust is not None:
                try:
                    state, extra = adjust(station, state)
                except SkipStation as e:
                    finish(station, _record(station, state, {}, f"skipped: {e}"), str(e))
                    return
                except DeviceError as e:
                    if stopped():
                        raise operator_stop(station) from e
                    raise interrupted(station, "adjust", e) from e
        if station.lens:  # a motorised lens: set its settings, record what the camera reads back
            try:
                extra = {**extra, "lens": set_lens(cameras, station.lens)}
            except DeviceError as e:
                if stopped():
                    raise operator_stop(station) from e
                raise interrupted(station, "lens", e) from e
        images, reject = _grab_all(cameras, station, quality_check, regrabs, grab_timeout_s, status, interrupted)
        emit("grabbed", station.id, reject)
        if stopped():
            raise operator_stop(station)
        status(f"{station.id}: writing")
        paths = {} if reject else {cid: writer.write_image(cid, station.id, img) for cid, img in images.items()}
        finish(station, _record(station, state, paths, f"skipped: {reject}" if reject else "ok", extra), reject)

    def finish(station: Station, record: dict, reason: str) -> None:
        if station.id in retakes:
            record["retake"] = True
        writer.append_station(record)
        if reason:
            result.skipped[station.id] = reason
            emit("skipped", station.id, reason)
        else:
            result.captured.append(station.id)
            emit("done", station.id, "")
        if bar is not None:
            bar.advance(task)

    try:
        with control.active(robot) if control is not None else contextlib.nullcontext():
            for station in todo:
                if control is not None:
                    try:
                        verdict = control.checkpoint(station.id, emit, robot.state)
                    except DeviceError as e:
                        raise interrupted(station, "robot (while paused)", e) from e
                    if verdict == "abort":
                        result.aborted = True
                        emit("aborted", station.id, "")
                        status("aborted")
                        break
                run_station(station)
            else:
                status("done")
    finally:
        if bar is not None:
            bar.stop()
        writer.close()
        if robot_lock is not None:
            robot_lock.release()
    result.elapsed_s = time.monotonic() - t_start
    return result

def check_lens_settings(plan, cameras: Mapping[str, Camera]) -> None:
    """Every lens setting a plan's stations ask for names a camera of the capture and a feature it has."""
    for station in plan.stations:
        for cid, features in (station.lens or {}).items():
            if cid not in cameras:
                raise BadInputError(f"plan: station {station.id} sets the lens of camera {cid!r}, which is not in the "
                                    f"capture (cameras: {', '.join(cameras)})")
            missing = [f for f in features if not cameras[cid].has(f)]
            if missing:
                raise BadInputError(f"plan: station {station.id} sets {', '.join(missing)} on camera {cid!r}, which "
                                    "has no such feature (a camera without a motorised lens?)")


def set_lens(cameras: Mapping[str, Camera], lens: Mapping[str, Mapping[str, float]]) -> dict:
    """Set each camera's lens features and read them back: camera -> feature -> the value it reports."""
    out: dict[str, dict[str, float]] = {}
    for cid, features in lens.items():
        for name, value in features.items():
            cameras[cid].set(name, value)
            out.setdefault(cid, {})[name] = float(cameras[cid].get(name))
    return out


def _record(station: Station, state: RobotState, paths: dict, status: str, extra: dict | None = None) -> dict:
    """The stations.jsonl line of a station reached at ``state``."""
    return {
        "id": station.id,
        "T_base_flange": state.T_base_flange.tolist(),
        "joints_deg": [float(v) for v in state.joints_deg],
        "time": utc_now(),
        "images": paths,
        "status": status,
        "T_base_flange_commanded": station.T_base_flange.tolist(),
        **(extra or {}),
    }


def _grab_all(cameras, station, quality_check, regrabs, grab_timeout_s, status, interrupted) -> tuple[dict, str]:
    """One image per camera (re-grabbed while the quality check rejects it): ``(images, rejection reason)``."""
    images: dict[str, np.ndarray] = {}
    for cid, cam in cameras.items():
        reject = ""
        for attempt in range(regrabs + 1):
            status(f"{station.id}: grabbing {cid}" + (f" (re-grab {attempt})" if attempt else ""))
            try:
                frame = cam.grab(timeout_s=grab_timeout_s)
            except DeviceError as e:
                raise interrupted(station, f"camera {cid}", e) from e
            why = quality_check(cid, frame.image, station) if quality_check else None
            if not why:
                images[cid] = frame.image
                reject = ""
                break
            reject = f"quality {cid}: {why}"
        if reject:
            return images, reject
    return images, ""


def _open_session(
    plan: Plan, robot: Robot, cameras: Mapping[str, Camera], session_dir: Path, resume: bool, cell: dict | None,
    requested: dict,
) -> tuple[SessionWriter, set[str]]:  # fmt: skip
    """The session writer, and the listed stations to take again (an image missing or unreadable)."""
    if not resume:
        writer = SessionWriter.create(
            session_dir, cell=cell, devices=_device_settings(robot, cameras, requested),
            plan={"digest": plan.digest(), **plan.to_json()},
        )  # fmt: skip
        return writer, set()
    if (session_dir / "session.json").is_file() and not (session_dir / "stations.jsonl").is_file():
        images = list((session_dir / "images").glob("*/*.png"))
        raise BadInputError(
            f"session: {session_dir / 'stations.jsonl'} is missing: the record of which stations are finished "
            f"is lost, and resuming would capture every station again over the {len(images)} images in "
            f"{session_dir / 'images'}. Restore stations.jsonl from a backup, or capture into a new --out folder"
        )
    writer = SessionWriter.open(session_dir)
    try:
        saved = writer.meta.get("plan")
        if saved is not None and saved.get("digest") not in (None, plan.digest()):
            raise BadInputError(
                f"plan: the session in {session_dir} was captured with another plan "
                f"(digest {saved.get('digest', '?')[:12]}, this one {plan.digest()[:12]}); resume with the same plan file"
            )
        cams = (writer.meta.get("devices") or {}).get("cameras") or {}
        for cid in cameras:
            before = (cams.get(cid) or {}).get("settings_requested", {})
            if cid in cams and before != requested.get(cid, {}):
                raise BadInputError(
                    f"cameras.{cid}.settings: the session in {session_dir} was captured with {before}, this "
                    f"capture asks for {requested.get(cid, {})}; resume with the same settings"
                )
        retakes = {
            sid for sid, rec in writer.stations.items()
            if rec.get("status") == "ok"
            and not all(image_readable(session_dir / rel) for rel in (rec.get("images") or {}).values())
        }  # fmt: skip
    except BaseException:
        writer.close()
        raise
    return writer, retakes
