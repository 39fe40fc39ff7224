"""The operator's control of a running capture: pause, resume, abort, STOP (:class:`CaptureControl`).

:func:`jcalib.acquisition.capture.capture` takes one as ``control=`` (also importable from there). A user
interface calls its methods from its own threads; the capture checks it before every station and after
every step of one. :func:`stop_on_sigint` makes Ctrl-C the STOP button of a command-line capture.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator

from jcalib.acquisition.robots.base import Robot
from jcalib.errors import DeviceError

__all__ = ["CONTROL_STATES", "CaptureControl", "stop_on_sigint"]

#: :attr:`CaptureControl.state` values.
CONTROL_STATES = ("running", "paused", "aborting", "stopped", "done")


class CaptureControl:
    """The operator's buttons for a running :func:`~jcalib.acquisition.capture.capture`: pause, resume, abort,
    STOP. Thread-safe.

    Pass one as ``capture(..., control=...)`` and call its methods from any thread. :attr:`state` is one of
    :data:`CONTROL_STATES`: "running"; "paused" (the capture finishes the station in flight, then waits);
    "aborting" (it finishes the station in flight, then ends: ``CaptureResult.aborted``); "stopped"
    (:meth:`stop`); "done" once the capture has returned or raised, unless stopped. One control serves
    one capture run (an adaptive capture's one-station captures count as one run, see :meth:`active`).

    Attributes:
        keepalive_s: while paused, the capture reads the robot's state this often, s (a controller or
            simulator drops a connection that stays idle for long).
    """

    keepalive_s = 5.0

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._state = "running"
        self._aborted = False
        self._depth = 0
        self._robot: Robot | None = None

    @property
    def state(self) -> str:
        """One of :data:`CONTROL_STATES`."""
        with self._cond:
            return self._state

    @property
    def stop_requested(self) -> bool:
        """:meth:`stop` was called while the capture ran."""
        with self._cond:
            return self._state == "stopped"

    @property
    def abort_requested(self) -> bool:
        """:meth:`abort` was called (stays True after the capture ended)."""
        with self._cond:
            return self._aborted

    def _set(self, state: str, *, when: tuple[str, ...]) -> None:
        with self._cond:
            if self._state in when:
                self._state = state
                self._aborted = self._aborted or state == "aborting"
                self._cond.notify_all()

    def pause(self) -> None:
        """Finish the station in flight, then wait before the next one (no effect unless running)."""
        self._set("paused", when=("running",))

    def resume(self) -> None:
        """Continue after :meth:`pause` (no effect unless paused)."""
        self._set("running", when=("paused",))

    def abort(self) -> None:
        """Finish the station in flight, then end the capture (``CaptureResult.aborted``); resumable."""
        self._set("aborting", when=("running", "paused"))

    def stop(self, robot: Robot | None = None) -> None:
        """The STOP button: ``robot.stop()`` at once, from this thread, and end the capture now.

        The station in flight is not recorded and :func:`capture` raises :class:`CaptureInterrupted`
        ("stopped by the operator"); a stop between two moves prevents the next one. ``robot``: the robot to
        stop; default the robot of the run in progress (:meth:`active`), none before the run has started
        (the capture then ends before its first move). The robot is stopped even when the capture is done.

        Raises:
            DeviceError: the robot's driver could not deliver the stop (the capture still ends): stop the
                robot at the teach pendant.
        """
        self._set("stopped", when=("running", "paused", "aborting"))
        robot = robot if robot is not None else self._robot
        if robot is not None:
            robot.stop()

    @contextlib.contextmanager
    def active(self, robot: Robot | None = None) -> Iterator["CaptureControl"]:
        """Marks a capture run driving ``robot``: the outermost block's end sets the state to "done" (unless
        stopped), and :meth:`stop` stops ``robot`` meanwhile.

        :func:`capture` enters it; a caller that runs several captures as one (adaptive capture: one
        station per :func:`capture`) enters it around all of them. Entering a control that is "done"
        starts a new run ("running")."""
        with self._cond:
            if self._depth == 0 and self._state == "done":
                self._state, self._aborted = "running", False
            self._depth += 1
            self._robot = robot if robot is not None else self._robot
        try:
            yield self
        finally:
            with self._cond:
                self._depth -= 1
                if self._depth == 0:
                    self._robot = None
                    if self._state != "stopped":
                        self._state = "done"
                self._cond.notify_all()

    def checkpoint(self, station_id: str, emit: Callable[[str, str, str], None],
                   keepalive: Callable[[], object]) -> str:
        """Before a station: wait while paused; then "go", "abort" or "stop".

        Emits "paused" when it starts to wait and "resumed" when it goes on; calls ``keepalive`` (e.g.
        ``robot.state``) every :attr:`keepalive_s` while paused (its DeviceError propagates)."""
        with self._cond:
            paused = self._state == "paused"
        if paused:
            emit("paused", station_id, "")
            while True:
                with self._cond:
                    self._cond.wait_for(lambda: self._state != "paused", timeout=self.keepalive_s)
                    if self._state != "paused":
                        break
                keepalive()
            if self.state == "running":
                emit("resumed", station_id, "")
        with self._cond:
            return {"stopped": "stop", "aborting": "abort"}.get(self._state, "go")


@contextlib.contextmanager
def stop_on_sigint(control: CaptureControl, robot: Robot | None = None) -> Iterator[None]:
    """Within the block, the first Ctrl-C (SIGINT) is the STOP button (:meth:`CaptureControl.stop` from a
    helper thread: the main thread may hold the driver's locks); a second one interrupts as usual.

    A no-op outside the main thread (signal handlers can only be set there)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)

    def on_sigint(signum, frame):
        signal.signal(signal.SIGINT, previous if callable(previous) else signal.default_int_handler)
        threading.Thread(target=_stop_quietly, args=(control, robot), name="jcalib-stop", daemon=True).start()

    signal.signal(signal.SIGINT, on_sigint)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _stop_quietly(control: CaptureControl, robot: Robot | None) -> None:
    import sys

    print("jcalib: Ctrl-C: stopping the robot (press Ctrl-C again to quit at once)", file=sys.stderr, flush=True)
    try:
        control.stop(robot)
    except DeviceError as e:
        print(f"jcalib: the stop could not be delivered: {e}", file=sys.stderr, flush=True)
