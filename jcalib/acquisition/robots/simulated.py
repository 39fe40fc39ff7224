"""A simulated robot controller: reach and joint limits, motion time, repeatability, settling.

The protocol servers (:mod:`~jcalib.acquisition.robots.kuka_sim`, :mod:`~jcalib.acquisition.robots.abb_sim`)
wrap one :class:`SimulatedController`; a frame source renders images at :meth:`SimulatedController.true_T_base_flange`.
:class:`SimulatedRobot` drives a controller in-process through the :class:`~jcalib.acquisition.robots.base.Robot`
interface (no sockets), for benchmarks and notebooks.

Model of a motion: the target is checked like a controller does (inverse kinematics within the joint
limits; for a linear move, every point of the straight path), then the joints travel for
``max_j |dq_j| / v_j`` (joint move) or ``max(length / speed, angle / rot_speed)`` (linear move), scaled
by ``time_scale``. The joints reach the target's; after arrival they ring down (a decaying oscillation
of ``settle_amplitude_rad`` over ``settle_time_s``), so a client that grabs before the robot settled
sees a moving arm. :meth:`SimulatedController.halt` (a stop request) brakes the motion on its path: the
path parameter decelerates linearly to zero over ``stop_time_s`` (clipped at the target), so a stopped
linear move stands on its straight line; a halted robot does not ring down, and the waiting
:meth:`SimulatedController.move` raises :class:`~jcalib.acquisition.robots.base.MotionStoppedError` once
it stands. Reported poses come from the joints (the encoders), as a real controller's do;
the flange itself is off that pose by a random error of the size of the robot's repeatability, drawn
per move (backlash and elasticity the motor encoders do not see): the true pose, which a frame source
renders, is the reported one times that error.

Kinematic error (optional, ``true_forward``): a real arm's joint zeros, link lengths and twists differ
from the nominal model its controller uses. The controller still plans with its nominal model (inverse
kinematics, path checks) and reports the nominal forward kinematics at its encoder values, while the
flange really is at the *true* forward kinematics at the same joints (times the repeatability error):
the reported pose is off by up to millimetres, systematically, as on a real robot. Without it the true
kinematics is the nominal one. :func:`kinematics_forward` makes ``true_forward`` from a
:class:`jcalib.geometry.kinematic_models.Kinematics` and its true parameters.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from jcalib.acquisition.robots.base import MotionRefusedError, MotionStoppedError, Robot, RobotState
from jcalib.acquisition.robots.model import ControllerModel, default_model
from jcalib.geometry.se3 import (
    check_pose,
    exp_so3,
    interpolate_pose,
    invert,
    make_pose,
    pose_distance,
)
from jcalib.errors import BadInputError, DeviceError


class UnreachableError(MotionRefusedError):
    """The controller refused a target: outside reach, joint limit, or a linear path that leaves the workspace."""

    def __init__(self, message: str, reason: str, on_path: bool = False):
        super().__init__(message)
        self.reason = reason
        #: True when the target itself is reachable but the straight path to it is not.
        self.on_path = on_path


@dataclass
class _Trajectory:
    t0: float
    duration: float
    path: np.ndarray  # (k, n) joint waypoints, evenly spaced in time
    ring: bool = True  # rings down after arrival (not after a braking stop)


class SimulatedController:
    """Thread-safe simulated controller state shared by the protocol servers.

    Args:
        model: reach / joint limits / kinematics (:func:`~jcalib.acquisition.robots.model.default_model`).
        repeatability_m: 1-sigma position error of a reached pose per axis, in the flange frame, m
            (ISO 9283 repeatability of a 16 kg robot is about 0.04 mm, i.e. sigma ~0.013 mm); the
            reported pose does not contain it.
        repeatability_rad: 1-sigma orientation error per axis, in the flange frame, rad.
        linear_speed_m_s: TCP speed of linear moves, m/s.
        rotation_speed_rad_s: orientation speed of linear moves, rad/s.
        speed_fraction: fraction of the maximum joint speeds used by joint moves.
        settle_time_s: duration of the ring-down after arrival, s (before ``time_scale``).
        settle_amplitude_rad: initial joint oscillation amplitude, rad.
        stop_time_s: braking time of a stop from full path speed, s (before ``time_scale``); see
            :meth:`halt`.
        time_scale: multiplies every motion, settle and braking time (0 = instantaneous, for tests).
        tools: tool index -> ``T_flange_tool`` (4, 4) m; index 0 is the flange itself.
        bases: base index -> ``T_robroot_base`` (4, 4) m; index 0 is the robot base.
        seed: random seed of the repeatability noise.
        true_forward: the arm's true kinematics, joints ``(n,)`` (the controller's, rad; m for prismatic
            axes) -> true ``T_base_flange`` (4, 4), m (e.g. :func:`kinematics_forward`); None: the
            nominal ``model.forward`` (no kinematic error). Only :meth:`true_T_base_flange` uses it.
    """

    def __init__(
        self,
        model: ControllerModel | None = None,
        *,
        repeatability_m: float = 1.3e-5,
        repeatability_rad: float = 2e-5,
        linear_speed_m_s: float = 0.5,
        rotation_speed_rad_s: float = 1.5,
        speed_fraction: float = 0.5,
        settle_time_s: float = 0.15,
        settle_amplitude_rad: float = 2e-4,
        stop_time_s: float = 0.08,
        time_scale: float = 1.0,
        tools: dict[int, np.ndarray] | None = None,
        bases: dict[int, np.ndarray] | None = None,
        seed: int = 0,
        true_forward: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        self.model = model if model is not None else default_model()
        if true_forward is not None and not callable(true_forward):
            raise BadInputError(f"true_forward: expected a function joints -> T_base_flange, got {true_forward!r}")
        self.true_forward = true_forward
        self.repeatability_m = float(repeatability_m)
        self.repeatability_rad = float(repeatability_rad)
        self.linear_speed_m_s = float(linear_speed_m_s)
        self.rotation_speed_rad_s = float(rotation_speed_rad_s)
        self.speed_fraction = float(speed_fraction)
        self.settle_time_s = float(settle_time_s)
        self.settle_amplitude_rad = float(settle_amplitude_rad)
        if not 0.0 <= stop_time_s <= 10.0:
            raise BadInputError(f"stop_time_s: expected a braking time in [0, 10] s, got {stop_time_s!r}")
        self.stop_time_s = float(stop_time_s)
        self.time_scale = float(time_scale)
        self.tools = {0: np.eye(4), **{int(k): check_pose(v, f"tools[{k}]") for k, v in (tools or {}).items()}}
        self.bases = {0: np.eye(4), **{int(k): check_pose(v, f"bases[{k}]") for k, v in (bases or {}).items()}}
        self.tool = 0
        self.base = 0
        self._rng = np.random.default_rng(seed)
        self._lock = threading.RLock()
        self._changed = threading.Condition(self._lock)  # notified when a halt replaces the trajectory
        q = np.asarray(self.model.home_rad, dtype=np.float64)
        self._traj = _Trajectory(time.monotonic() - 1e9, 0.0, q[None, :])
        self._ring_dir = np.zeros_like(q)
        self._T_error = np.eye(4)  # reported flange -> true flange, drawn per move
        self.num_moves = 0
        self._halted = 0  # the num_moves of the last motion a halt ended

    # --- state ---------------------------------------------------------------------------------
    def _joints_at(self, t: float) -> tuple[np.ndarray, bool]:
        tr = self._traj
        s = (t - tr.t0) / tr.duration if tr.duration > 0 else 1.0
        if s < 1.0:
            k = tr.path.shape[0] - 1
            x = max(s, 0.0) * k
            i = min(int(x), k - 1)
            return tr.path[i] + (x - i) * (tr.path[i + 1] - tr.path[i]), True
        q = tr.path[-1]
        dt = t - tr.t0 - tr.duration
        settle = self.settle_time_s * self.time_scale
        if tr.ring and settle > 0 and dt < settle:
            decay = np.exp(-5.0 * dt / settle) * np.cos(2 * np.pi * 4.0 * dt / settle)
            return q + self.settle_amplitude_rad * decay * self._ring_dir, True
        return q, False

    def joints_rad(self) -> np.ndarray:
        """(n,) current joints, rad (moving or ringing down included)."""
        with self._lock:
            return self._joints_at(time.monotonic())[0].copy()

    def joint_velocities_rad_s(self, dt: float = 0.002) -> np.ndarray:
        """(n,) current joint speeds, rad/s: the change over the last ``dt`` seconds (what an encoder-based
        velocity reads; 0 when standing, ring-down included while it lasts)."""
        with self._lock:
            now = time.monotonic()
            return (self._joints_at(now)[0] - self._joints_at(now - dt)[0]) / dt

    @property
    def motion_time_s(self) -> float:
        """Duration of the current (or last) trajectory, s: the motion's, or the braking's after :meth:`halt`."""
        with self._lock:
            return self._traj.duration

    def is_moving(self) -> bool:
        """True while travelling or ringing down."""
        with self._lock:
            return self._joints_at(time.monotonic())[1]

    def true_T_base_flange(self) -> np.ndarray:
        """(4, 4) true flange pose in the robot base (m): what a frame source renders (the true
        kinematics at the current joints, the nominal one without ``true_forward``, times the
        repeatability error of the last move)."""
        with self._lock:
            q = self._joints_at(time.monotonic())[0]
            forward = self.true_forward if self.true_forward is not None else self.model.forward
            return np.asarray(forward(q), dtype=np.float64) @ self._T_error

    def T_base_tool(self) -> np.ndarray:
        """(4, 4) pose of the active tool in the active base, m (flange in robot base for 0/0)."""
        with self._lock:
            T = self.model.forward(self._joints_at(time.monotonic())[0])
            return invert(self.bases[self.base]) @ T @ self.tools[self.tool]

    def snapshot(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One consistent reading: joints ``(n,)`` rad, joint speeds ``(n,)`` rad/s, the active tool in the active
        base ``(4, 4)`` m, and the active tool in the flange ``(4, 4)`` m."""
        with self._lock:
            q = self.joints_rad()
            T_tool = self.tools[self.tool]
            T = invert(self.bases[self.base]) @ self.model.forward(q) @ T_tool
            return q, self.joint_velocities_rad_s(), T, T_tool.copy()

    def set_tool(self, index: int, T_flange_tool: np.ndarray) -> None:
        """Define tool ``index`` (>= 1) as ``T_flange_tool`` (4, 4, m) and make it active (a controller's ``set_tcp``)."""
        T = check_pose(T_flange_tool, f"tools[{index}]")
        if int(index) < 1:
            raise BadInputError(f"tool: index 0 is the flange itself and cannot be redefined, got {index}")
        with self._lock:
            self.tools[int(index)] = T
            self.tool = int(index)

    def select_tool(self, index: int) -> None:
        with self._lock:
            if index not in self.tools:
                raise BadInputError(f"tool: no tool {index} defined (have {sorted(self.tools)})")
            self.tool = index

    def select_base(self, index: int) -> None:
        with self._lock:
            if index not in self.bases:
                raise BadInputError(f"base: no base {index} defined (have {sorted(self.bases)})")
            self.base = index

    # --- motion --------------------------------------------------------------------------------
    def start_move(self, T_base_tool: np.ndarray, kind: str = "joint") -> float:
        """Check the target like a controller, then start the motion; returns its duration in s.

        Args:
            T_base_tool: (4, 4) target of the active tool in the active base, m.
            kind: "joint" (PTP / MoveJ) or "linear" (LIN / MoveL).

        Raises:
            UnreachableError: outside reach, joint limits, or (linear) a path point unreachable;
                the robot does not move.
        """
        T_base_tool = check_pose(T_base_tool, "target")
        if kind not in ("joint", "linear"):
            raise BadInputError(f"kind: expected 'joint' or 'linear', got {kind!r}")
        with self._lock:
            now = time.monotonic()
            q0, _ = self._joints_at(now)
            T_flange_target = self.bases[self.base] @ T_base_tool @ invert(self.tools[self.tool])
            T_error = make_pose(
                exp_so3(self._rng.normal(0.0, self.repeatability_rad, 3)),
                self._rng.normal(0.0, self.repeatability_m, 3),
            )
            ik = self.model.inverse(T_flange_target, q0)
            if not ik.ok:
                raise UnreachableError(f"target unreachable: {ik.reason}", ik.reason)
            if kind == "joint":
                q1 = ik.joints_rad
                path = np.stack([q0, q1])
                dq = np.abs(q1 - q0)
                duration = float(np.max(dq / (self.speed_fraction * self.model.joint_speed_rad_s)))
            else:
                T0 = self.model.forward(q0)
                dist, ang = pose_distance(T0, T_flange_target)
                n = int(np.clip(np.ceil(max(dist / 0.01, ang / 0.05)), 1, 200))
                path = [q0]
                for i in range(1, n + 1):
                    Ti = interpolate_pose(T0, T_flange_target, i / n)
                    ik = self.model.inverse(Ti, path[-1])
                    if not ik.ok:
                        raise UnreachableError(
                            f"linear path unreachable at {100.0 * i / n:.0f}% of the way: {ik.reason}",
                            ik.reason,
                            on_path=True,
                        )
                    if np.max(np.abs(ik.joints_rad - path[-1])) > 0.5:
                        raise UnreachableError(
                            f"linear path crosses a singularity at {100.0 * i / n:.0f}% of the way",
                            "singularity",
                            on_path=True,
                        )
                    path.append(ik.joints_rad)
                path = np.stack(path)
                duration = max(dist / self.linear_speed_m_s, ang / self.rotation_speed_rad_s)
            duration *= self.time_scale
            ring = self._rng.normal(size=path.shape[1])
            self._ring_dir = ring / np.linalg.norm(ring)
            self._traj = _Trajectory(now, duration, path)
            self._T_error = T_error
            self.num_moves += 1
            return duration

    def wait_motion(self, timeout_s: float = 60.0) -> None:
        """Block until the motion (not the ring-down) is over.

        Raises:
            MotionStoppedError: :meth:`halt` ended the motion (raised once the robot stands).
            DeviceError: the motion needs more than ``timeout_s``.
        """
        with self._changed:
            move = self.num_moves
            end = self._traj.t0 + self._traj.duration
            if end - time.monotonic() > timeout_s:
                raise DeviceError(f"simulated motion needs {end - time.monotonic():.1f} s, more than {timeout_s} s")
            while (remaining := self._traj.t0 + self._traj.duration - time.monotonic()) > 0:
                self._changed.wait(remaining)
            if self._halted == move and move > 0:
                raise MotionStoppedError("simulated controller: the motion was stopped (halt); the robot stands "
                                         "where it braked")

    def halt(self) -> bool:
        """Stop the motion in progress: brake on the path and stand (a controlled stop, no ring-down).

        The path parameter, moving at ``1 / duration`` per second, decelerates linearly to zero over
        ``stop_time_s * time_scale`` (the braking distance is half the distance that speed would cover;
        a target closer than that is where the robot stops). A waiting :meth:`move` / :meth:`wait_motion`
        raises :class:`MotionStoppedError` once the robot stands. Thread-safe.

        Returns:
            True when a motion was stopped; False when the robot was not travelling (idle or ringing
            down after arrival: nothing to stop).
        """
        with self._changed:
            now = time.monotonic()
            tr = self._traj
            s0 = (now - tr.t0) / tr.duration if tr.duration > 0 else 1.0
            if s0 >= 1.0:
                return False
            if not tr.ring:  # already braking
                return True
            s0 = max(s0, 0.0)
            brake = self.stop_time_s * self.time_scale
            rate = 1.0 / tr.duration  # path parameter per second
            # s(t) = s0 + rate t - rate t^2 / (2 brake) for t in [0, brake], or until it reaches the target (s = 1)
            if s0 + rate * brake / 2.0 <= 1.0:
                t_end = brake
            else:
                t_end = brake * (1.0 - np.sqrt(max(0.0, 1.0 - 2.0 * (1.0 - s0) / (rate * brake))))
            ts = np.linspace(0.0, t_end, 9) if t_end > 0 else np.zeros(2)
            s = np.minimum(s0 + rate * ts - (rate * ts**2 / (2.0 * brake) if brake > 0 else 0.0), 1.0)
            k = tr.path.shape[0] - 1
            x = s * k
            i = np.minimum(x.astype(int), k - 1)
            path = tr.path[i] + (x - i)[:, None] * (tr.path[i + 1] - tr.path[i])
            self._traj = _Trajectory(now, float(t_end), path, ring=False)
            self._halted = self.num_moves
            self._changed.notify_all()
            return True

    def move(self, T_base_tool: np.ndarray, kind: str = "joint") -> None:
        """Start a move and block until the robot arrives (fine point; the ring-down continues).

        Raises:
            UnreachableError: the target or the path is refused (the robot does not move).
            MotionStoppedError: :meth:`halt` stopped it on the way.
        """
        self.start_move(T_base_tool, kind)
        self.wait_motion()


def kinematics_forward(model, params) -> Callable[[np.ndarray], np.ndarray]:
    """``true_forward`` of a :class:`SimulatedController` whose arm has the kinematics ``model`` at ``params``.

    Args:
        model: a :class:`jcalib.geometry.kinematic_models.Kinematics` whose joints are the controller's
            (same order, sign and zero: e.g. ``from_dh_robot`` of the controller's preset).
        params: ``(P,)`` the true parameters (m, rad), e.g. nominal plus
            :func:`jcalib.sim.kinematic_cells.kinematic_errors`.

    Returns:
        joints ``(n,)`` (rad, m) -> ``T_base_flange`` (4, 4), m (numpy; ``jit``-compiled on first call).
    """
    import jax
    import jax.numpy as jnp

    from jcalib.geometry import kinematic_models

    p = jnp.asarray(params, dtype=jnp.float64)
    if p.shape != (model.num_params,):
        raise BadInputError(
            f"params: expected shape ({model.num_params},) for the kinematics of {model.name}, got {p.shape}"
        )
    fk = jax.jit(lambda q: kinematic_models.forward(model, p, q))

    def forward(joints_rad: np.ndarray) -> np.ndarray:
        return np.asarray(fk(jnp.asarray(joints_rad, dtype=jnp.float64)))

    return forward


class SimulatedRobot(Robot):
    """A :class:`Robot` driving a :class:`SimulatedController` in-process (no network)."""

    def __init__(self, controller: SimulatedController | None = None, *, settle_poll_s: float = 0.01):
        super().__init__()
        self.controller = controller if controller is not None else SimulatedController()
        self.address = "sim://in-process"
        self.settle_poll_s = settle_poll_s

    def state(self) -> RobotState:
        c = self.controller
        with c._lock:  # one consistent snapshot
            q = c.joints_rad()
            T = invert(c.bases[c.base]) @ c.model.forward(q) @ c.tools[c.tool]
        return RobotState(T, np.degrees(q))

    def _move(self, T_base_flange: np.ndarray, kind: str) -> None:
        with self._starting("PTP" if kind == "joint" else "LIN"):
            self.controller.start_move(T_base_flange, kind)
        self.controller.wait_motion()

    def _stop(self) -> None:
        self.controller.halt()

    def select_tool(self, index: int) -> None:
        self.controller.select_tool(index)

    def select_base(self, index: int) -> None:
        self.controller.select_base(index)

    def close(self) -> None:
        pass
