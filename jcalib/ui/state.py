"""The operator app's state: one cell, one session folder, the devices, the plan, the capture, the result.

Everything lives in the server and on disk, so a page that is reloaded (or a second browser) sees the same
thing: the cell file (``--cell``), the capture session (``--session``: images, ``stations.jsonl``,
``observations.json``, ``exclusions.json``) and the app's own files in ``SESSION/app/`` (the plan, the
latest and the previous result, the report). The app calls the functions the command line calls
(:mod:`jcalib.workflow`, :mod:`jcalib.pipeline`, :func:`jcalib.calibrate`, :mod:`jcalib.io.export`):
nothing is computed only here.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError, DeviceError
from jcalib.ui.jobs import EventBus, JobRunner
from jcalib.ui.security import ControlLease

__all__ = ["UIConfig", "AppState"]

#: How often the robot's state is read while no job uses the robot, s.
ROBOT_POLL_S = 1.0
#: Live views grab at most this many frames per second per camera (software trigger): a page draws about as
#: many, and grabs beyond it take the CPU that the detection overlays need.
LIVE_MAX_FPS = 15.0


@dataclass
class UIConfig:
    """How the app was started.

    Attributes:
        cell_path: the cell spec file the app reads and (when edited) writes.
        session_dir: the capture session folder (created by the first capture).
        robot_url: ``kuka://...`` / ``abb://...`` or None (no robot: capture is off).
        camera_urls: camera id -> ``gige://...`` / ``replay://...``.
        simulated: the devices are the simulated cell of ``--simulate``.
        title: shown in the pages' titles.
    """

    cell_path: Path
    session_dir: Path
    robot_url: str | None = None
    camera_urls: dict[str, str] = field(default_factory=dict)
    simulated: bool = False
    title: str = "jcalib ui"

    @property
    def app_dir(self) -> Path:
        """``SESSION/app``: the plan, results and report the app writes."""
        return self.session_dir / "app"

    @property
    def plan_path(self) -> Path:
        return self.app_dir / "plan.json"

    @property
    def result_path(self) -> Path:
        return self.app_dir / "result.json"

    @property
    def previous_path(self) -> Path:
        return self.app_dir / "result-previous.json"

    @property
    def report_path(self) -> Path:
        return self.app_dir / "report.html"

    @property
    def observations_path(self) -> Path:
        return self.session_dir / "observations.json"


class AppState:
    """The server side of the app (module docstring). Methods are called from request handlers (in worker
    threads) and from background jobs; the lock guards what both touch."""

    def __init__(self, config: UIConfig) -> None:
        self.config = config
        self.bus = EventBus()
        self.jobs = JobRunner(self.bus)
        self.lease = ControlLease()
        self.lock = threading.RLock()
        self.robot = None
        self.cameras: dict[str, Any] = {}
        self.detectors: dict[str, Any] = {}
        self.device_error: str | None = None
        self.capture_control = None
        self.capture_state: dict = {}
        self.adaptive_history: dict | None = None
        self.result = None
        self.previous = None
        self.solve_s: float | None = None
        self.detection_cache: dict = {}
        self.session_version = 0
        self._session_obs = None
        self.warnings: list[str] = []
        self.robot_state: dict = {"connected": False, "error": None}
        self._closing = threading.Event()
        self._threads: list[threading.Thread] = []
        self._cache: dict[str, Any] = {}  # image size and nominal layout (see image_size, layout)

    # --- devices -------------------------------------------------------------------------------------
    def open_devices(self) -> None:
        """Connect the robot and the cameras of the configuration (errors are kept and shown, not raised)."""
        from jcalib.acquisition.stream import LiveCamera
        from jcalib.workflow.devices import open_camera

        problems = []
        if self.config.robot_url:
            try:
                self.ensure_robot()
            except (BadInputError, DeviceError) as e:
                problems.append(f"robot {self.config.robot_url}: {e}")
        for name, url in self.config.camera_urls.items():
            try:
                self.cameras[name] = LiveCamera(open_camera(name, url), max_fps=LIVE_MAX_FPS)
            except (BadInputError, DeviceError) as e:
                problems.append(f"camera {name} ({url}): {e}")
        self.device_error = "; ".join(problems) or None
        self.reset_detectors()
        if self.config.robot_url:
            self.spawn(self._watch_robot, "robot-monitor")

    def spawn(self, target: Callable[..., Any], name: str, *args: Any) -> threading.Thread:
        """Run ``target(*args)`` in a background thread that the app waits for when it stops."""
        thread = threading.Thread(target=target, args=args, name=name, daemon=True)
        with self.lock:
            self._threads = [t for t in self._threads if t.is_alive()] + [thread]
        thread.start()
        return thread

    def join_background(self, timeout_s: float) -> list[str]:
        """After :meth:`begin_close`: wait up to ``timeout_s`` in all for the running job, the report being
        written and the device threads (a thread still inside XLA or OpenCV when the interpreter exits aborts
        the process); the names of what still runs."""
        deadline = time.monotonic() + timeout_s
        self.jobs.join(timeout_s)
        for det in list(self.detectors.values()):
            det.join(max(0.0, deadline - time.monotonic()))
        with self.lock:
            threads = list(self._threads)
        for t in threads:
            t.join(max(0.0, deadline - time.monotonic()))
        left = [t.name for t in threads if t.is_alive()]
        if self.jobs.busy:
            left.insert(0, f"the {self.jobs.current.title} job")
        return left

    def ensure_robot(self):
        """The connected robot, re-connecting when the last connection was lost (a controller drops a client
        whose requests time out); raises DeviceError when it cannot be reached."""
        from jcalib.workflow.devices import open_robot

        with self.lock:
            if self.robot is None:
                if not self.config.robot_url:
                    raise DeviceError("no robot is connected; start jcalib ui with --robot URL (or --simulate)")
                self.robot = open_robot(self.config.robot_url)
            return self.robot

    def _watch_robot(self) -> None:
        """Read the robot's state every second while no job uses it: the connection stays alive (controllers
        drop idle clients), the pages show where the robot is, and a lost connection is re-opened."""
        while not self._closing.wait(ROBOT_POLL_S):
            if self.jobs.busy:
                continue
            with self.lock:
                robot = self.robot
                try:
                    robot = self.ensure_robot()
                    st = robot.state()
                    self.robot_state = {"connected": True, "xyz_mm": (st.T_base_flange[:3, 3] * 1e3).round(3).tolist(),
                                        "joints_deg": np.round(st.joints_deg, 4).tolist(), "error": None,
                                        "time": time.time()}
                except (BadInputError, DeviceError) as e:
                    self.robot_state = {"connected": False, "error": str(e)}
                    if robot is not None:
                        robot.close()
                    self.robot = None

    def begin_close(self) -> None:
        """Close the devices in a background thread (:meth:`close_devices`; once): a device that vanished
        can hold its close for its protocol's timeouts, and :meth:`join_background` bounds the wait."""
        with self.lock:
            if self._closing.is_set():
                return
            self._closing.set()
        self.spawn(self.close_devices, "close-devices")

    def close_devices(self) -> None:
        """Stop the robot if a capture runs, then close everything (idempotent)."""
        from jcalib.workflow.devices import close_devices

        self._closing.set()
        control, robot = self.capture_control, self.robot
        if control is not None and self.jobs.busy and robot is not None:
            try:
                control.stop(robot)
            except DeviceError:
                pass
        for d in self.detectors.values():
            d.close()
        close_devices(self.cameras, robot)
        self.cameras, self.robot = {}, None

    def reset_detectors(self) -> None:
        """(Re)make the live detectors after the cell changed."""
        from jcalib.ui.live import LiveDetector

        try:
            spec = self.cell_spec()
            targets = {name: t.geometry() for name, t in spec.targets.items()}
        except BadInputError:
            targets = {}
        old = self.detectors
        self.detectors = {}
        for name, cam in self.cameras.items():
            det = LiveDetector(cam, targets, lambda name=name: self.intrinsics(name))
            prev = old.get(name)
            if prev is not None and prev._viewers:
                for _ in range(prev._viewers):
                    det.watch()
                    prev.unwatch()
            self.detectors[name] = det

    def intrinsics(self, camera: str) -> tuple[np.ndarray, np.ndarray] | None:
        """The best known ``(K, dist)`` of a camera: the latest result's, the cell's, else the nominal layout's."""
        result = self.result
        if result is not None and camera in result.file.cameras:
            c = result.file.cameras[camera]
            return np.asarray(c.K, dtype=np.float64), np.asarray(c.dist, dtype=np.float64)
        try:
            layout = self.layout()
        except BadInputError:
            return None
        c = layout.cameras.get(camera)
        return None if c is None else (np.asarray(c.K), np.asarray(c.dist))

    def camera_list(self) -> dict:
        """The cameras with their GenICam settings (value and unit where the device has them)."""
        out = []
        for name, cam in self.cameras.items():
            feats = {}
            for f, unit in (("ExposureTime", "µs"), ("Gain", ""), ("Focus", ""), ("Zoom", ""), ("Width", "px"),
                            ("Height", "px"), ("PixelFormat", "")):  # fmt: skip
                try:
                    if cam.has(f):
                        feats[f] = {"value": cam.get(f), "unit": unit}
                except DeviceError:
                    pass
            w = feats.get("Width", {}).get("value")
            h = feats.get("Height", {}).get("value")
            out.append({"name": name, "address": cam.address, "driver": type(cam.inner).__name__, "features": feats,
                        "width": w, "height": h, "error": cam.error, "fps": cam.fps})  # fmt: skip
        return {"cameras": out, "error": self.device_error}

    def set_camera_settings(self, camera: str, settings: dict) -> dict:
        """Apply GenICam settings with the refusals of ``jcalib capture --setting``."""
        from jcalib.acquisition.capture import apply_camera_settings

        if camera not in self.cameras:
            raise BadInputError(f"camera {camera!r} is not connected (connected: {', '.join(self.cameras) or 'none'})")
        if not isinstance(settings, dict):
            raise BadInputError("settings: expected {feature: value}")
        apply_camera_settings({camera: self.cameras[camera]}, {camera: settings})
        self._cache.pop("image_size", None)
        return next(c for c in self.camera_list()["cameras"] if c["name"] == camera)

    # --- cell ----------------------------------------------------------------------------------------
    def cell_text(self) -> str:
        path = self.config.cell_path
        return path.read_text(encoding="utf-8") if path.is_file() else ""

    def cell_spec(self, text: str | None = None):
        """The parsed cell (``text``, or the cell file), with the command line's validation and messages."""
        from jcalib.io.cell import parse_cell
        from jcalib.io.schema.reading import parse_yaml

        source = str(self.config.cell_path)
        text = self.cell_text() if text is None else text
        if len(text.encode("utf-8")) > (16 << 20):
            raise BadInputError(f"{source}: the cell spec is larger than 16 MiB")
        return parse_cell(parse_yaml(text, source), source)

    def _cell_stamp(self) -> tuple[int, int] | None:
        try:
            st = self.config.cell_path.stat()
        except OSError:
            return None
        return (st.st_mtime_ns, st.st_size)

    def image_size(self) -> tuple[int, int] | None:
        """The image size of the connected cameras the cell gives no intrinsics for (what plans and the nominal
        layout assume for them, as ``jcalib plan --image-size``), or None. Kept until the cell file or a
        camera's settings change (the live view asks for every frame)."""
        stamp = self._cell_stamp()
        cached = self._cache.get("image_size")
        if cached is not None and cached[0] == stamp:
            return cached[1]
        size = self._image_size()
        self._cache["image_size"] = (stamp, size)
        return size

    def _image_size(self) -> tuple[int, int] | None:
        try:
            spec = self.cell_spec()
        except BadInputError:
            return None
        for name, cam in self.cameras.items():
            entry = spec.cameras.get(name)
            if entry is not None and entry.K is None:
                try:
                    return int(cam.get("Width")), int(cam.get("Height"))
                except (DeviceError, TypeError, ValueError):
                    return None
        return None

    def layout(self):
        """The nominal layout of the cell (:func:`jcalib.planning.cell_layout`) for the connected cameras (kept
        while the cell file and the image size stay the same)."""
        from jcalib.planning import cell_layout

        key = (self._cell_stamp(), self.image_size())
        cached = self._cache.get("layout")
        if cached is not None and cached[0] == key:
            return cached[1]
        layout = cell_layout(self.config.cell_path, image_size=key[1])
        self._cache["layout"] = (key, layout)
        return layout

    @staticmethod
    def cell_summary(spec) -> dict:
        robots = list(getattr(spec, "robots", {}) or {})
        return {"cameras": list(spec.cameras), "targets": list(spec.targets), "tools": list(spec.tools),
                "robots": robots, "goals": [g.text for g in spec.goals]}  # fmt: skip

    def cell_document(self) -> dict:
        out: dict[str, Any] = {"path": str(self.config.cell_path), "text": self.cell_text()}
        try:
            spec = self.cell_spec()
            out["summary"] = self.cell_summary(spec)
            out["goals"] = [g.text for g in spec.goals]
        except BadInputError as e:
            out["error"] = str(e)
        return out

    def save_cell(self, text: str) -> dict:
        """Validate ``text`` as the command line would, then write the cell file atomically."""
        from jcalib.io.atomic import write_text_atomic

        if not isinstance(text, str):
            raise BadInputError("text: expected the cell spec as text (YAML)")
        spec = self.cell_spec(text)
        write_text_atomic(self.config.cell_path, text)
        with self.lock:
            self.detection_cache.clear()
            self._session_obs = None
        self.reset_detectors()
        return {"path": str(self.config.cell_path), "summary": self.cell_summary(spec)}

    def scene(self) -> dict:
        from jcalib.ui.scene3d import cell_scene

        layout = self.layout()
        planned = [s.T_base_flange for s in self.plan().stations] if self.config.plan_path.is_file() else []
        captured = [np.asarray(r["T_base_flange"]) for r in self.session_records()
                    if r.get("status") == "ok" and r.get("T_base_flange") is not None]  # fmt: skip
        result = self.result.file if self.result is not None else None
        scene = cell_scene(layout, result, planned, captured)
        scene["source"] = "(calibrated where the latest result has it, nominal elsewhere)" if result else "(nominal layout)"
        return scene

    # --- plan ----------------------------------------------------------------------------------------
    def plan(self):
        from jcalib.io.plan import load_plan

        return load_plan(self.config.plan_path)

    def start_plan(self, request: dict):
        """Plan stations as ``jcalib plan`` does (same options, same refusals), in the background."""
        from jcalib.workflow.plan import check_plan_options, run_plan

        kind = request.get("kind")
        opts = {k: request.get(k) for k in ("stations", "camera", "target", "tool", "goals", "max_stations")}
        seed = request.get("seed", 0)
        for key in ("stations", "max_stations", "seed"):
            value = opts.get(key) if key != "seed" else seed
            if value is not None and (not isinstance(value, int) or isinstance(value, bool)):
                raise BadInputError(f"{key}: expected a whole number, got {value!r}")
        if seed < 0:
            raise BadInputError(f"seed: expected a seed >= 0, got {seed}")
        if self.capture_started() and self.config.plan_path.is_file():
            raise BadInputError(
                f"the session {self.config.session_dir} was captured with the current plan; a new plan needs a new "
                "session folder (start jcalib ui with another --session)"
            )
        goals = opts["goals"] or None
        check_plan_options(str(kind), stations=opts["stations"], goal=goals, max_stations=opts["max_stations"],
                           tool=opts["tool"], camera=opts["camera"], target=opts["target"], candidates=None,
                           sigma_px=None)  # fmt: skip
        self.cell_spec()

        def work(job, report):
            report(None, f"planning {kind} stations")
            planned = run_plan(self.config.cell_path, str(kind), self.config.plan_path, num_stations=opts["stations"],
                               camera=opts["camera"], target=opts["target"], tool=opts["tool"], seed=int(seed),
                               goals=goals, max_stations=opts["max_stations"], image_size=self.image_size())  # fmt: skip
            return {"stations": len(planned.plan), "dropped": len(planned.dropped)}

        return self.jobs.start("plan", f"plan ({kind})", work)

    def plan_summary(self) -> dict:
        import json

        path = self.config.plan_path
        if not path.is_file():
            return {"message": "No plan yet: choose a kind and press Plan."}
        plan = self.plan()
        data = json.loads(path.read_text(encoding="utf-8"))
        planner = data.get("planner") or {}
        done = {r["id"]: r.get("status", "ok") for r in self.session_records()}
        rows = []
        after = (planner.get("after_each_station") or []) if planner.get("kind") == "optimal" else []
        goals = list(planner.get("goals") or []) if after else []
        for k, s in enumerate(plan.stations):
            t = s.T_base_flange[:3, 3] * 1e3
            row = {"id": s.id, "x": float(t[0]), "y": float(t[1]), "z": float(t[2]),
                   "status": done.get(s.id, "planned")}  # fmt: skip
            if k < len(after):
                row.update({g: after[k][g] for g in goals})
            rows.append(row)
        verdict = ""
        if planner.get("kind") == "optimal":
            verdict = "every goal is met (predicted)" if planner.get("met") else "the goals are NOT met (predicted)"
        return {"kind": planner.get("kind", "?"), "stations": rows, "goals": goals,
                "dropped": len(planner.get("dropped") or {}), "verdict": verdict}  # fmt: skip

    # --- session and capture -----------------------------------------------------------------------------
    def session_records(self) -> list[dict]:
        from jcalib.io.session import read_stations

        d = self.config.session_dir
        if not (d / "stations.jsonl").is_file():
            return []
        try:
            return read_stations(d)
        except BadInputError:
            return []

    def capture_started(self) -> bool:
        return (self.config.session_dir / "session.json").is_file()

    def start_capture(self, request: dict):
        """Capture the plan (``mode: "plan"``) or toward goals (``"goals"``) after the page's confirmation."""
        from jcalib.acquisition.capture import CaptureControl

        if request.get("confirm") is not True:
            raise BadInputError("capture: the robot moves only after an explicit confirmation (confirm: true)")
        try:
            self.ensure_robot()
        except (BadInputError, DeviceError) as e:
            raise DeviceError(f"the robot cannot be reached: {e}") from None
        if not self.cameras:
            raise DeviceError("no camera is connected; start jcalib ui with --camera NAME=URL (or --simulate)")
        mode = request.get("mode", "plan")
        if mode not in ("plan", "goals"):
            raise BadInputError(f"mode: expected 'plan' or 'goals', got {mode!r}")
        control = CaptureControl()
        self.capture_control = control
        self.capture_state = {"state": "running", "done": 0, "total": 0, "mode": mode}
        if mode == "plan":
            if not self.config.plan_path.is_file():
                raise BadInputError("capture: plan stations first")
            return self.jobs.start("capture", "capture", lambda job, report: self._capture_plan(control, report))
        from jcalib.io.goals import parse_goals

        goals = parse_goals(request.get("goals") or []) or self.cell_spec().goals
        if not goals:
            raise BadInputError("goals: name at least one goal (or give the cell goals:)")
        max_stations = request.get("max_stations", 20)
        if not isinstance(max_stations, int) or isinstance(max_stations, bool) or not 1 <= max_stations <= 500:
            raise BadInputError(f"max_stations: expected 1..500, got {max_stations!r}")
        return self.jobs.start("capture", "capture toward goals",
                               lambda job, report: self._capture_goals(control, goals, max_stations, report))

    def _listener(self, total: int, report):
        def listener(event: str, station: str, detail: str) -> None:
            st = self.capture_state
            if event in ("done", "skipped"):
                st["done"] = st.get("done", 0) + 1
                self.refresh_session(new_station=station)
            st["state"] = self.capture_control.state if self.capture_control is not None else "running"
            st["station"] = station
            report(st["done"] / total if total else None, f"{station}: {event}")
            self.bus.publish({"type": "capture", "event": event, "station": station, "detail": detail,
                              "done": st["done"], "total": total, "state": st["state"]})  # fmt: skip

        return listener

    def _capture_plan(self, control, report) -> dict:
        from jcalib.workflow.capture import capture_plan

        plan = self.plan()
        done_before = {r["id"] for r in self.session_records() if r.get("status") == "ok"}
        total = len(plan)
        self.capture_state.update(total=total, done=len(done_before & {s.id for s in plan.stations}))
        res = capture_plan(plan, self.robot, self.cameras, self.config.session_dir, cell=self.config.cell_path,
                           plan_path=self.config.plan_path, resume=self.capture_started(), progress=False,
                           control=control, listener=self._listener(total, report),
                           hint="press Capture the plan again (the session is continued)")  # fmt: skip
        self.capture_state["state"] = "aborted" if getattr(res, "aborted", False) else "done"
        self.refresh_session()
        return {"summary": f"{len(res.captured)} stations captured, {len(res.skipped)} skipped, "
                           f"{res.already_done} already there ({res.elapsed_s:.1f} s)"
                           + (" – aborted; resume to continue" if getattr(res, "aborted", False) else ""),
                "captured": res.captured, "skipped": res.skipped}  # fmt: skip

    def _capture_goals(self, control, goals, max_stations: int, report) -> dict:
        from jcalib.workflow.adaptive import adaptive_capture

        self.adaptive_history = {"goals": [{"text": g.text, "limit": g.limit} for g in goals], "steps": []}
        self.capture_state.update(total=max_stations)

        def progress(n, achieved, predicted, met) -> None:
            self.adaptive_history["steps"].append({"num_stations": n, "achieved": achieved, "predicted": predicted,
                                                   "met": met})  # fmt: skip
            self.bus.publish({"type": "adaptive", "history": self.adaptive_history})

        outcome = adaptive_capture(self.robot, self.cameras, cell=self.config.cell_path, goals=goals,
                                   max_stations=max_stations, out=self.config.session_dir, image_size=self.image_size(),
                                   resume=self.capture_started(), control=control, on_progress=progress,
                                   listener=self._listener(max_stations, report), echo=lambda line: report(None, line),
                                   hint="press Capture toward the goals again (the session is continued)")
        self.capture_state["state"] = "done"
        self.refresh_session()
        return {"summary": ("goals met: " if outcome.met else "goals NOT met: ") + outcome.message}

    def capture_command(self, what: str) -> str:
        control = self.capture_control
        if control is None or not self.jobs.busy or self.jobs.current.kind != "capture":
            raise BadInputError(f"{what}: no capture is running")
        getattr(control, what)()
        self.capture_state["state"] = control.state
        self.bus.publish({"type": "capture", "event": what, "station": self.capture_state.get("station"),
                          "done": self.capture_state.get("done", 0), "total": self.capture_state.get("total", 0),
                          "state": control.state})  # fmt: skip
        return {"pause": "pausing after the station in flight", "resume": "resumed",
                "abort": "aborting after the station in flight (the session can be resumed)"}[what]

    def stop(self) -> str:
        """STOP: halt the robot at once (any browser may); a running capture ends, resumable."""
        robot, control = self.robot, self.capture_control
        if robot is None:
            return "STOP: no robot is connected"
        t0 = time.monotonic()
        if control is not None and self.jobs.busy:
            control.stop(robot)
        else:
            robot.stop()
        msg = (f"STOP: the robot was told to stop ({1e3 * (time.monotonic() - t0):.0f} ms); the session in "
               f"{self.config.session_dir} can be resumed with Capture")
        self.bus.publish({"type": "stopped", "message": msg})
        return msg

    # --- detections of the session ----------------------------------------------------------------------
    def refresh_session(self, new_station: str | None = None) -> None:
        """Detect what is new in the session (cached per image) for thumbnails and coverage."""
        self._session_obs = None
        self.session_version += 1
        self.bus.publish({"type": "session", "version": self.session_version, "station": new_station})

    def session_observations(self):
        """``(observations, failures)`` of the session by the command line's detection (cached per image),
        exclusions honoured."""
        from jcalib.pipeline.session import detect_session

        with self.lock:
            if self._session_obs is None:
                if not self.capture_started() or not self.session_records():
                    return None, []
                self._session_obs = detect_session(self.config.session_dir, self.config.cell_path, progress=False,
                                                   cache=self.detection_cache)  # fmt: skip
            return self._session_obs

    def session_summary(self) -> dict:
        from jcalib.io.exclusions import load_exclusions
        from jcalib.ui.coverage import coverage

        records = self.session_records()
        obs, failures = self.session_observations()
        found: dict[tuple[str, str], int] = {}
        for st in obs.stations if obs is not None else []:
            for d in st.detections:
                found[(st.id, d.camera)] = found.get((st.id, d.camera), 0) + len(d.pixels)
        why = {(f.station, f.camera): f.reason for f in failures if f.camera is not None}
        excl = load_exclusions(self.config.session_dir)
        stations = []
        for r in records:
            views = {}
            for cam in r.get("images") or {}:
                n = found.get((r["id"], cam))
                summary = f"{n} points" if n else why.get((r["id"], cam), "nothing found")
                if excl.excludes(r["id"], cam):
                    summary = "excluded"
                views[cam] = {"summary": summary, "version": self.session_version}
            stations.append({"id": r["id"], "status": r.get("status", "ok"), "views": views})
        cov = []
        if obs is not None:
            spec = self.cell_spec()
            for cam in spec.cameras:
                size = obs.cameras.get(cam)
                if size is not None:
                    cov.append({"camera": cam, **coverage(obs, cam, size, lambda cam=cam: self.intrinsics(cam))})
        planned = len(self.plan()) if self.config.plan_path.is_file() else 0
        return {"stations": stations, "done": sum(1 for r in records if r.get("status") == "ok"),
                "planned": planned, "capture": self.capture_state or None, "coverage": cov,
                "version": self.session_version}  # fmt: skip

    def image_path(self, station: str, camera: str) -> Path:
        """The image of a station and camera, found through ``stations.jsonl`` and checked to lie in the session."""
        from jcalib.ui.security import inside

        for r in self.session_records():
            if r.get("id") == station:
                rel = (r.get("images") or {}).get(camera)
                if rel is None:
                    break
                path = self.config.session_dir / str(rel)
                if not inside(path, self.config.session_dir) or not path.is_file():
                    raise BadInputError(f"station {station}: image of {camera} is not a file in the session")
                return path
        raise BadInputError(f"no image of camera {camera!r} at station {station!r} in the session")

    def thumbnail(self, station: str, camera: str) -> bytes:
        from jcalib.ui.coverage import thumbnail_jpeg
        from jcalib.vision import load_image

        image = load_image(self.image_path(station, camera))
        obs, failures = self.session_observations()
        dets = {}
        for st in obs.stations if obs is not None else []:
            if st.id == station:
                dets = {d.target or d.tool: d.pixels for d in st.detections if d.camera == camera}
        fail = next((f.reason for f in failures if f.station == station and f.camera == camera), None)
        return thumbnail_jpeg(image, dets, failed=None if dets else fail)

    def coverage_png(self, camera: str) -> bytes:
        from jcalib.ui.coverage import coverage, heatmap_png

        obs, _ = self.session_observations()
        if obs is None or camera not in obs.cameras:
            raise BadInputError(f"camera {camera!r} has no detections in the session yet")
        return heatmap_png(coverage(obs, camera, obs.cameras[camera])["grid"])
