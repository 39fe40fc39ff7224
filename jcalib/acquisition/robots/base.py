"""The robot interface every driver implements (KUKA, ABB, simulated).

Poses are ``T_base_flange``: the flange (tool 0) in the robot base (base 0), a (4, 4) matrix in metres,
as everywhere in jcalib. Where the controller has tool / base (work object) selection,
:meth:`Robot.select_tool` / :meth:`Robot.select_base` switch it and poses then refer to that tool in that
base; capture always runs with tool 0 and base 0.
"""

from __future__ import annotations

import abc
import time
from dataclasses import dataclass

import numpy as np

from jcalib.geometry.se3 import check_pose, pose_distance
from jcalib.errors import BadInputError, DeviceError


class MotionRefusedError(DeviceError):
    """The controller refused a motion target (unreachable, joint limits, path through a singularity).

    The connection is fine and the robot did not complete the move; a capture records the station as
    skipped and goes on.
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

    Subclasses implement :meth:`state`, :meth:`_move` (blocking until the controller reports the
    motion finished) and :meth:`close`; tool / base selection when the controller has it.
    Every failure to reach or command the controller raises :class:`jcalib.errors.DeviceError`.
    """

    address: str = "?"
    #: :meth:`wait_settled` tolerances: two consecutive readings closer than this count as still.
    settle_tol_m: float = 2e-6
    settle_tol_rad: float = 5e-6
    settle_poll_s: float = 0.02

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
        self._move(T, kind)
        return self.wait_settled(timeout_s=settle_timeout_s) if settle else self.state()

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
