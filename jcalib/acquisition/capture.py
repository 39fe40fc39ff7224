"""Run a station plan: move, settle, grab from every camera, check, write the session.

For each station not yet in the session: move the robot (joint or linear), wait until it has settled,
grab one frame from every camera, run the optional quality check (re-grab up to ``regrabs`` times,
then skip the station with the reason recorded), write the images atomically and append the station
line. A target the controller refuses (unreachable) is recorded as ``"skipped: unreachable: ..."`` and
the capture goes on. A lost robot connection or a camera that gives no complete frame stops the capture
cleanly (:class:`CaptureInterrupted`) with a message saying how to resume; what was finished is on disk.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from jcalib.acquisition.cameras.base import Camera
from jcalib.io.plan import Plan, Station
from jcalib.acquisition.robots.base import MotionRefusedError, Robot
from jcalib.io.session import SessionWriter, utc_now
from jcalib.errors import BadInputError, DeviceError

#: ``check(camera_id, image, station) -> None`` when the image is usable, else the reason it is not.
QualityCheck = Callable[[str, np.ndarray, Station], "str | None"]
#: ``listener(event, station_id, detail)``; events: "start", "moved", "grabbed", "done", "skipped", "stopped".
EventListener = Callable[[str, str, str], None]


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
    """

    session_dir: Path
    num_planned: int
    captured: list[str] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    already_done: int = 0
    elapsed_s: float = 0.0


def _device_settings(robot: Robot, cameras: Mapping[str, Camera]) -> dict:
    cams = {}
    for cid, cam in cameras.items():
        settings = {}
        for f in ("ExposureTime", "Gain", "PixelFormat", "Width", "Height", "OffsetX", "OffsetY", "PacketSize"):
            try:
                if cam.has(f):
                    settings[f] = cam.get(f)
            except DeviceError:
                pass
        cams[cid] = {"address": cam.address, "driver": type(cam).__name__, "settings": settings}
    return {"robot": {"address": robot.address, "driver": type(robot).__name__}, "cameras": cams}


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

    Returns:
        A :class:`CaptureResult`.

    Raises:
        BadInputError: no cameras, a session exists and ``resume`` is False, or the plan differs
            from the session's.
        CaptureInterrupted: lost robot connection or camera failure (session consistent; resume).
    """
    if not cameras:
        raise BadInputError("cameras: expected at least one camera")
    t_start = time.monotonic()
    session_dir = Path(session_dir)
    if resume:
        writer = SessionWriter.open(session_dir)
        saved = writer.meta.get("plan")
        if saved is not None and saved.get("digest") not in (None, plan.digest()):
            writer.close()
            raise BadInputError(
                f"plan: the session in {session_dir} was captured with another plan "
                f"(digest {saved.get('digest', '?')[:12]}, this one {plan.digest()[:12]}); resume with the same plan file"
            )
    else:
        writer = SessionWriter.create(
            session_dir,
            cell=cell,
            devices=_device_settings(robot, cameras),
            plan={"digest": plan.digest(), **plan.to_json()},
        )
    emit = listener or (lambda *a: None)
    result = CaptureResult(session_dir, len(plan), already_done=len(writer.stations))
    todo = [s for s in plan.stations if s.id not in writer.stations]
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

    try:
        for station in todo:
            emit("start", station.id, "")
            status(f"{station.id}: moving ({station.move})")
            try:
                state = robot.move(station.T_base_flange, kind=station.move, settle_timeout_s=settle_timeout_s)
            except MotionRefusedError as e:
                reason = f"unreachable: {e}"
                writer.append_station(
                    {"id": station.id, "T_base_flange": None, "joints_deg": None, "time": utc_now(),
                     "images": {}, "status": f"skipped: {reason}"}
                )  # fmt: skip
                result.skipped[station.id] = reason
                emit("skipped", station.id, reason)
                if bar is not None:
                    bar.advance(task)
                continue
            except DeviceError as e:
                raise interrupted(station, "robot", e) from e
            emit("moved", station.id, "")

            images: dict[str, np.ndarray] = {}
            reject = ""
            for cid, cam in cameras.items():
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
                    break
            emit("grabbed", station.id, reject)
            status(f"{station.id}: writing")
            paths = {} if reject else {cid: writer.write_image(cid, station.id, img) for cid, img in images.items()}
            record = {
                "id": station.id,
                "T_base_flange": state.T_base_flange.tolist(),
                "joints_deg": [float(v) for v in state.joints_deg],
                "time": utc_now(),
                "images": paths,
                "status": f"skipped: {reject}" if reject else "ok",
                "T_base_flange_commanded": station.T_base_flange.tolist(),
            }
            writer.append_station(record)
            if reject:
                result.skipped[station.id] = reject
                emit("skipped", station.id, reject)
            else:
                result.captured.append(station.id)
                emit("done", station.id, "")
            if bar is not None:
                bar.advance(task)
        status("done")
    finally:
        if bar is not None:
            bar.stop()
        writer.close()
    result.elapsed_s = time.monotonic() - t_start
    return result
