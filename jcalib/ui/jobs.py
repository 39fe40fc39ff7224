"""Long work of the operator app (plan, capture, detect, calibrate) in a background thread, reported as events.

One job runs at a time (they all use the cell's devices or its files); a page starts one and follows it
through the event stream (:class:`EventBus`, one websocket per page). Every job's progress, outcome and
error text are events; the last state of each job stays readable (``/api/state``) so a page that is
reloaded mid-job shows it.
"""

from __future__ import annotations

import asyncio
import itertools
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from jcalib.errors import JcalibError

__all__ = ["EventBus", "Job", "JobRunner", "Busy"]


class Busy(JcalibError):
    """Another job is running."""

    exit_code = 2


class EventBus:
    """Fan-out of JSON events to the connected websockets; :meth:`publish` is safe from any thread."""

    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._queues: set[asyncio.Queue] = set()
        self._lock = threading.Lock()

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    def subscribe(self) -> asyncio.Queue:
        q: asyncio.Queue = asyncio.Queue(maxsize=1000)
        with self._lock:
            self._queues.add(q)
        return q

    def unsubscribe(self, q: asyncio.Queue) -> None:
        with self._lock:
            self._queues.discard(q)

    def publish(self, event: dict) -> None:
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        with self._lock:
            queues = list(self._queues)
        for q in queues:
            try:
                loop.call_soon_threadsafe(_put, q, event)
            except RuntimeError:  # the loop is shutting down
                return


def _put(q: asyncio.Queue, event: dict) -> None:
    if q.full():  # a stalled page loses old events, never blocks the app
        try:
            q.get_nowait()
        except asyncio.QueueEmpty:
            pass
    q.put_nowait(event)


@dataclass
class Job:
    """One background job.

    Attributes:
        id: running number.  kind: "plan", "capture", "calibrate", ...  title: shown to the user.
        status: "running", "done", "failed" or "stopped".  progress: 0..1 (None: unknown).
        message: the latest step.  error: the error text (failed / stopped).  result: JSON summary.
        started, ended: wall times (s since the epoch).
    """

    id: int
    kind: str
    title: str
    status: str = "running"
    progress: float | None = 0.0
    message: str = ""
    error: str = ""
    result: Any = None
    started: float = field(default_factory=time.time)
    ended: float | None = None

    def to_json(self) -> dict:
        return {"id": self.id, "kind": self.kind, "title": self.title, "status": self.status,
                "progress": self.progress, "message": self.message, "error": self.error, "result": self.result,
                "started": self.started, "ended": self.ended,
                "elapsed_s": (self.ended or time.time()) - self.started}  # fmt: skip


class JobRunner:
    """Runs one job at a time in a daemon thread and publishes ``{"type": "job", "job": {...}}`` events."""

    def __init__(self, bus: EventBus) -> None:
        self.bus = bus
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self.current: Job | None = None
        self.last: dict[str, Job] = {}
        self._thread: threading.Thread | None = None

    @property
    def busy(self) -> bool:
        with self._lock:
            return self.current is not None and self.current.status == "running"

    def start(self, kind: str, title: str, work: Callable[[Job, Callable[..., None]], Any]) -> Job:
        """Start ``work(job, report)`` in the background; ``report(progress=None, message=None)`` publishes.

        Raises:
            Busy: a job is running.
        """
        with self._lock:
            if self.current is not None and self.current.status == "running":
                raise Busy(f"{self.current.title} is still running; wait for it to finish (or stop it)")
            job = Job(next(self._ids), kind, title)
            self.current = job
            self.last[kind] = job
        self._emit(job)

        def report(progress: float | None = None, message: str | None = None, **extra: Any) -> None:
            if progress is not None:
                job.progress = float(progress)
            if message is not None:
                job.message = message
            self._emit(job, **extra)

        def run() -> None:
            try:
                job.result = work(job, report)
                job.status, job.progress = "done", 1.0
            except JcalibError as e:
                job.status, job.error = ("stopped" if "stopped by the operator" in str(e) else "failed"), str(e)
            except Exception as e:  # a bug: keep the app alive and say so
                job.status = "failed"
                job.error = f"internal error (a bug, please report it): {type(e).__name__}: {e}"
                traceback.print_exc()
            job.ended = time.time()
            self._emit(job)

        self._thread = threading.Thread(target=run, name=f"job-{kind}-{job.id}", daemon=True)
        self._thread.start()
        return job

    def join(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for the running job to end; whether none runs now."""
        thread = self._thread
        if thread is not None:
            thread.join(timeout_s)
        return thread is None or not thread.is_alive()

    def _emit(self, job: Job, **extra: Any) -> None:
        self.bus.publish({"type": "job", "job": job.to_json(), **extra})

    def to_json(self) -> dict:
        with self._lock:
            return {"current": self.current.to_json() if self.current else None,
                    "last": {k: j.to_json() for k, j in self.last.items()}}  # fmt: skip
