"""The robot interface every driver implements (KUKA, ABB, simulated).

Poses are ``T_base_flange``: the flange (tool 0) in the robot base (base 0), a (4, 4) matrix in metres,
as everywhere in jcalib. Where the controller has tool / base (work object) selection,
:meth:`Robot.select_tool` / :meth:`Robot.select_base` switch it and poses then refer to that tool in that
base; capture always runs with tool 0 and base 0.

Stopping: :meth:`Robot.stop` may be called from any thread while :meth:`Robot.move` blocks in another; the
controller ramps the robot down on its path (a controlled stop, not an emergency stop) and the blocked
move raises :class:`MotionStoppedError`. A stop and a move that starts at the same moment must not miss
each other: a caller that decides to move reads :attr:`Robot.num_stops` first and moves inside
:meth:`Robot.stop_guard`, so a stop that came in between refuses the move instead of arriving at an idle
controller just before the motion starts (:func:`jcalib.acquisition.capture.capture` does that).
"""

from __future__ import annotations

import abc
import contextlib
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from jcalib.geometry.se3 import check_pose, pose_distance
from jcalib.errors import BadInputError, DeviceError


class MotionRefusedError(DeviceError):
    """The controller refused a motion target (unreachable, joint limits, path through a singularity).

    The connection is fine and the robot did not complete the move; a capture records the station as
    skipped and goes on.
    """


class MotionStoppedError(DeviceError):
    """A motion ended by a stop request (:meth:`Robot.stop`): the robot stands where it stopped, on its way.

    The connection is fine and the next :meth:`Robot.move` is accepted normally. A capture that sees it
    ends without recording the station in flight; the session can be resumed.
    """


@dataclass(frozen=True)
class RobotState:
    """One reading of the controller.

    Attributes:
        T_base_flange: (4, 4) pose of the active tool in the active base, m (the flange in the robot
            base for tool 0 / base 0).
        joints_deg: (num_joints,) joint angles in degrees, the controller's own convention.
    """

    T_base_flange: np.ndarray
    joints_deg: np.ndarray


class Robot(abc.ABC):
    """A robot controller reached over the network (or simulated).

    Subclasses call ``super().__init__()``, implement :meth:`state`, :meth:`_move` (blocking until the
    controller reports the motion finished; the command is sent inside :meth:`_starting`), :meth:`_stop`
    and :meth:`close`; tool / base selection when the controller has it.
    Every failure to reach or command the controller raises :class:`jcalib.errors.DeviceError`.
    """

    address: str = "?"
    #: :meth:`wait_settled` tolerances: two consecutive readings closer than this count as still.
    settle_tol_m: float = 2e-6
    settle_tol_rad: float = 5e-6
    settle_poll_s: float = 0.02
    #: False when the program on the controller predates jcalib's stop (:meth:`stop` then refuses): a user
    #: interface should say so before it starts a motion.
    can_stop: bool = True

    def __init__(self) -> None:
        #: How many times :meth:`stop` was called on this driver.
        self.num_stops = 0
        self._stop_lock = threading.Lock()
        self._guard: int | None = None
        self._seen = 0

    @abc.abstractmethod
    def state(self) -> RobotState:
        """Read the current pose and joints from the controller."""

    @abc.abstractmethod
    def _move(self, T_base_flange: np.ndarray, kind: str) -> None:
        """Command the motion and block until the controller reports it finished."""

    def move(
        self, T_base_flange: np.ndarray, *, kind: str = "joint", settle: bool = True, settle_timeout_s: float = 10.0
    ) -> RobotState:
        """Move the flange to ``T_base_flange`` and return the state reached.

        Args:
            T_base_flange: (4, 4) target pose of the flange (active tool) in the base (active base), m.
            kind: "joint" (PTP / MoveJ: joints interpolated) or "linear" (LIN / MoveL: straight line).
            settle: also wait until consecutive readings agree (:meth:`wait_settled`).
            settle_timeout_s: how long to wait for the robot to settle, s.

        Raises:
            BadInputError: the pose is not a rigid transform, or ``kind`` is unknown.
            DeviceError: unreachable target (the robot did not move), lost connection, motion timeout.
        """
        T = check_pose(T_base_flange, "T_base_flange")
        if kind not in ("joint", "linear"):
            raise BadInputError(f"kind: expected 'joint' or 'linear', got {kind!r}")
        with self._stop_lock:
            self._seen = self.num_stops if self._guard is None else self._guard
        self._move(T, kind)
        return self.wait_settled(timeout_s=settle_timeout_s) if settle else self.state()

    def stop(self) -> None:
        """Stop any motion now: the controller ramps the robot down on its path and holds it there.

        Callable from any thread, also while :meth:`move` blocks in another one; that move then raises
        :class:`MotionStoppedError`. Returns once the controller has the request (the robot may still be
        braking; the simulators stand still within about 0.1 s at ``time_scale=1``). Idempotent; a no-op
        when the robot stands. The next :meth:`move` is accepted normally.

        Raises:
            DeviceError: the request could not be delivered (lost connection, a controller program without
                stop support): stop the robot at the teach pendant.
        """
        with self._stop_lock:
            self.num_stops += 1
        self._stop()

    @contextlib.contextmanager
    def stop_guard(self, num_stops_seen: int) -> Iterator[None]:
        """Within the block, every :meth:`move` is refused once :meth:`stop` has been called after the caller
        read ``num_stops_seen`` from :attr:`num_stops`: it raises :class:`MotionStoppedError` and the robot
        does not move. Closes the gap between "no stop requested, so move" and the motion starting."""
        self._guard = int(num_stops_seen)
        try:
            yield
        finally:
            self._guard = None

    @contextlib.contextmanager
    def _starting(self, what: str) -> Iterator[None]:
        """Held by :meth:`_move` while it sends the motion command: refuses the move when a stop came since
        :meth:`move` began (or since the :meth:`stop_guard` read), and makes a concurrent :meth:`stop` wait
        until the command is out, so that its request reaches the controller after the command."""
        with self._stop_lock:
            if self.num_stops != self._seen:
                raise MotionStoppedError(f"robot at {self.address}: {what} not started: a stop was requested")
            yield

    @abc.abstractmethod
    def _stop(self) -> None:
        """Ask the controller to stop the motion in progress (no-op when idle); see :meth:`stop`."""

    def wait_settled(self, *, timeout_s: float = 10.0) -> RobotState:
        """Poll the controller until two consecutive readings agree within the settle tolerances.

        Raises:
            DeviceError: the robot is still moving after ``timeout_s``.
        """
        deadline = time.monotonic() + timeout_s
        prev = self.state()
        while True:
            time.sleep(self.settle_poll_s)
            cur = self.state()
            dt, dr = pose_distance(prev.T_base_flange, cur.T_base_flange)
            if dt <= self.settle_tol_m and dr <= self.settle_tol_rad:
                return cur
            if time.monotonic() > deadline:
                raise DeviceError(
                    f"robot at {self.address} did not settle within {timeout_s} s "
                    f"(last change {dt * 1e3:.4f} mm, {np.degrees(dr):.5f} deg between readings)"
                )
            prev = cur

    def select_tool(self, index: int) -> None:
        """Make tool ``index`` active (0 = flange). Default: the controller has no tool selection."""
        raise DeviceError(f"robot at {self.address}: tool selection is not supported by this controller")

    def select_base(self, index: int) -> None:
        """Make base ``index`` active (0 = robot base). Default: not supported."""
        raise DeviceError(f"robot at {self.address}: base selection is not supported by this controller")

    @abc.abstractmethod
    def close(self) -> None:
        """Release the connection (idempotent)."""

    def __enter__(self) -> "Robot":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def recv_exact(sock: socket.socket, n: int) -> bytes:
    """Read exactly ``n`` bytes of a controller protocol (KUKAVARPROXY, RTDE); ConnectionError when the
    peer closes first."""
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("connection closed by peer")
        buf += chunk
    return bytes(buf)
