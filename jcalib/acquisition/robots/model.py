"""Controller models: what a simulated controller knows about its arm (reach, joint limits, joints).

A simulated robot server asks its :class:`ControllerModel` whether a flange pose is reachable and
which joints reach it, exactly the check a real controller does before a motion (KUKA ``INVERSE``,
ABB ``CalcJointT``). Any object with the methods of :class:`ControllerModel` plugs in:
:class:`SixAxisArm` is a self-contained analytic arm in numpy (elbow manipulator with a spherical
wrist, the layout of most industrial six-axis robots; the default, it starts instantly);
:class:`DHRobotModel` / :func:`preset_model` wrap the DH models and presets of
``jcalib.geometry.kinematics`` / ``jcalib.geometry.robots`` (real robot types, JAX).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from jcalib.geometry.se3 import make_pose, rot_x, rot_y, rot_z


@dataclass(frozen=True)
class IKResult:
    """Outcome of an inverse-kinematics query.

    Attributes:
        joints_rad: (n,) joint angles in rad, or None when the pose is unreachable.
        reason: empty when reachable, else a controller-style reason ("outside reach",
            "joint limit A5 (-130.0..130.0 deg)").
    """

    joints_rad: np.ndarray | None
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.joints_rad is not None


@runtime_checkable
class ControllerModel(Protocol):
    """What a simulated controller needs from a robot model (numpy, metres, radians).

    Attributes:
        num_joints: number of joints.
        home_rad: (num_joints,) joints at start-up.
        joint_limits_rad: (num_joints, 2) lower and upper limits.
        joint_speed_rad_s: (num_joints,) maximum joint speeds.
    """

    num_joints: int
    home_rad: np.ndarray
    joint_limits_rad: np.ndarray
    joint_speed_rad_s: np.ndarray

    def forward(self, joints_rad: np.ndarray) -> np.ndarray:
        """(num_joints,) rad -> ``T_base_flange`` (4, 4), m."""
        ...

    def inverse(self, T_base_flange: np.ndarray, seed_rad: np.ndarray) -> IKResult:
        """Joints reaching ``T_base_flange`` within the limits, closest to ``seed_rad``."""
        ...


def _wrap_candidates(q: float, lo: float, hi: float) -> list[float]:
    """All of q + 2 pi k inside [lo, hi] (joints with more than 360 deg of travel)."""
    out = []
    for k in (-2, -1, 0, 1, 2):
        v = q + 2.0 * np.pi * k
        if lo - 1e-9 <= v <= hi + 1e-9:
            out.append(float(np.clip(v, lo, hi)))
    return out


@dataclass(frozen=True)
class SixAxisArm:
    """Six-axis elbow manipulator with a spherical wrist and analytic inverse kinematics.

    ``T_base_flange = Rz(q1) Tr(a1, 0, d1) Ry(q2) Tr(0, 0, a2) Ry(q3) Tr(d4, 0, a3) Rx(q4) Ry(q5) Rx(q6)
    Tr(d6, 0, 0) Ry(90 deg)``: at zero joints the upper arm points up, the forearm forward along base x,
    and the flange z axis (the tool direction) along base x. Lengths in metres; the defaults are
    those of a 1.6 m reach, 16 kg class robot.
    """

    d1: float = 0.675
    a1: float = 0.26
    a2: float = 0.68
    a3: float = 0.035
    d4: float = 0.67
    d6: float = 0.158
    joint_limits_deg: tuple[tuple[float, float], ...] = (
        (-185.0, 185.0),
        (-140.0, 35.0),
        (-120.0, 158.0),
        (-350.0, 350.0),
        (-122.5, 122.5),
        (-350.0, 350.0),
    )
    joint_speed_deg_s: tuple[float, ...] = (156.0, 156.0, 156.0, 330.0, 330.0, 615.0)
    home_deg: tuple[float, ...] = (0.0, -30.0, 60.0, 0.0, 60.0, 0.0)
    num_joints: int = field(default=6, init=False)

    @property
    def home_rad(self) -> np.ndarray:
        return np.radians(np.array(self.home_deg))

    @property
    def joint_limits_rad(self) -> np.ndarray:
        return np.radians(np.array(self.joint_limits_deg))

    @property
    def joint_speed_rad_s(self) -> np.ndarray:
        return np.radians(np.array(self.joint_speed_deg_s))

    def _wrist_frame(self, q: np.ndarray) -> np.ndarray:
        R = rot_z(q[0]) @ rot_y(q[1] + q[2])
        shoulder = rot_z(q[0]) @ np.array([self.a1, 0.0, self.d1])
        elbow = shoulder + rot_z(q[0]) @ rot_y(q[1]) @ np.array([0.0, 0.0, self.a2])
        wrist = elbow + R @ np.array([self.d4, 0.0, self.a3])
        return make_pose(R, wrist)

    def forward(self, joints_rad: np.ndarray) -> np.ndarray:
        """(6,) rad -> ``T_base_flange`` (4, 4), m."""
        q = np.asarray(joints_rad, dtype=np.float64)
        W = self._wrist_frame(q)
        R6 = W[:3, :3] @ rot_x(q[3]) @ rot_y(q[4]) @ rot_x(q[5])
        return make_pose(R6 @ rot_y(np.pi / 2), W[:3, 3] + R6 @ np.array([self.d6, 0.0, 0.0]))

    def _arm_solutions(self, w: np.ndarray) -> list[tuple[float, float, float]]:
        """(q1, q2, q3) placing the wrist centre at ``w``; empty when out of reach."""
        out = []
        L = np.hypot(self.d4, self.a3)
        phi = np.arctan2(self.d4, self.a3)
        rho = np.hypot(w[0], w[1])
        base_angles = [np.arctan2(w[1], w[0])] if rho > 1e-9 else [0.0]
        for q1 in base_angles + [base_angles[0] + np.pi]:
            front = np.cos(q1) * w[0] + np.sin(q1) * w[1]  # signed distance along the arm plane
            r, h = front - self.a1, w[2] - self.d1
            c = (r * r + h * h - self.a2**2 - L**2) / (2 * self.a2 * L)
            if abs(c) > 1.0:
                continue
            for sgn in (1.0, -1.0):
                q3 = sgn * np.arccos(c) - phi
                vx = self.d4 * np.cos(q3) + self.a3 * np.sin(q3)
                vz = self.a2 - self.d4 * np.sin(q3) + self.a3 * np.cos(q3)
                q2 = np.arctan2(vz, vx) - np.arctan2(h, r)
                out.append((q1, q2, q3))
        return out

    def inverse(self, T_base_flange: np.ndarray, seed_rad: np.ndarray) -> IKResult:
        """All analytic solutions (base front/back, elbow up/down, wrist flip, +-360 deg turns),
        keep those within the joint limits, return the one closest to ``seed_rad``."""
        T = np.asarray(T_base_flange, dtype=np.float64)
        seed = np.asarray(seed_rad, dtype=np.float64)
        lim = self.joint_limits_rad
        w = T[:3, 3] - self.d6 * T[:3, 2]
        arms = self._arm_solutions(w)
        if not arms:
            return IKResult(None, "outside reach (wrist centre out of the arm's workspace)")
        best, best_cost, violated = None, np.inf, set()
        for q1, q2, q3 in arms:
            Rw = rot_z(q1) @ rot_y(q2 + q3)
            M = Rw.T @ T[:3, :3] @ rot_y(np.pi / 2).T  # = Rx(q4) Ry(q5) Rx(q6)
            sb = np.hypot(M[1, 0], M[2, 0])
            b = np.arctan2(sb, M[0, 0])
            if sb < 1e-9:  # wrist singular: keep q4 at its seed value
                wrists = [(seed[3], b)]
            else:
                a = np.arctan2(M[1, 0], -M[2, 0])
                wrists = [(a, b), (a + np.pi, -b)]
            for a, b_ in wrists:
                N = rot_y(b_).T @ rot_x(a).T @ M
                c = np.arctan2(N[2, 1], N[1, 1])
                raw = np.array([q1, q2, q3, a, b_, c])
                # choose the 2 pi turn of every joint closest to the seed, inside the limits
                q = np.empty(6)
                ok = True
                for j in range(6):
                    base = raw[j] + 2 * np.pi * np.round((seed[j] - raw[j]) / (2 * np.pi))
                    cands = _wrap_candidates(base, lim[j, 0], lim[j, 1])
                    if not cands:
                        violated.add(j)
                        ok = False
                        break
                    q[j] = min(cands, key=lambda v: abs(v - seed[j]))
                if not ok:
                    continue
                cost = float(np.max(np.abs(q - seed) / self.joint_speed_rad_s))
                if cost < best_cost:
                    best, best_cost = q, cost
        if best is None:
            j = min(violated) if violated else 0
            lo, hi = self.joint_limits_deg[j]
            return IKResult(None, f"joint limit A{j + 1} ({lo:.1f}..{hi:.1f} deg)")
        return IKResult(best)


def default_model() -> ControllerModel:
    """The controller model simulators use when none is given: :class:`SixAxisArm` (numpy, instant start).

    For the kinematics of a real robot type use :func:`preset_model` (``jcalib.geometry.robots``).
    """
    return SixAxisArm()


def preset_model(name: str, **kw) -> "DHRobotModel":
    """Controller model of a preset of :mod:`jcalib.geometry.robots` (e.g. ``"kuka_kr10_r1100_sixx"``)."""
    from jcalib.geometry.robots import robot_preset

    return DHRobotModel(robot_preset(name), **kw)


class DHRobotModel:
    """Adapts a :class:`jcalib.geometry.kinematics.DHRobot` (JAX) to :class:`ControllerModel`.

    Forward kinematics and the multi-seed inverse kinematics of :mod:`jcalib.geometry.kinematics` are
    ``jit``-compiled once per model (first move: a few seconds). Joint values are the controller's axis
    values in radians, so ``$AXIS_ACT`` / ``GETJ`` look like the real robot's.

    Args:
        robot: the arm.
        home_rad: joints at start-up (default :func:`jcalib.geometry.robots.home_joints`: zeros with axis 5
            at 30 deg, and for a KUKA A2 = -90 deg, A3 = +90 deg: the usual "home" postures).
        joint_speed_rad_s: maximum joint speeds (default 2.6 rad/s = 150 deg/s each).
    """

    def __init__(self, robot, *, home_rad=None, joint_speed_rad_s=None):
        import jax

        from jcalib.geometry import kinematics

        self.robot = robot
        self.num_joints = int(robot.num_joints)
        self.joint_limits_rad = np.stack([np.asarray(robot.lower), np.asarray(robot.upper)], axis=1)
        if home_rad is None:
            from jcalib.geometry.robots import home_joints

            home_rad = home_joints(robot)
        self.home_rad = np.asarray(home_rad, dtype=np.float64)
        self.joint_speed_rad_s = (
            np.full(self.num_joints, np.radians(150.0))
            if joint_speed_rad_s is None
            else np.asarray(joint_speed_rad_s, dtype=np.float64)
        )
        self._fk = jax.jit(lambda q: kinematics.forward_kinematics(robot, q))
        self._ik = jax.jit(lambda T, q0: kinematics.inverse_kinematics(robot, T, q0))

    def forward(self, joints_rad: np.ndarray) -> np.ndarray:
        return np.asarray(self._fk(np.asarray(joints_rad, dtype=np.float64)))

    def inverse(self, T_base_flange: np.ndarray, seed_rad: np.ndarray) -> IKResult:
        lo, hi = self.joint_limits_rad[:, 0], self.joint_limits_rad[:, 1]
        seed = np.clip(np.asarray(seed_rad, dtype=np.float64), lo, hi)
        r = self._ik(np.asarray(T_base_flange, dtype=np.float64), seed)
        if not bool(r.success):
            return IKResult(
                None,
                f"outside reach or joint limits of {self.robot.name} (closest pose "
                f"{float(r.position_error_m) * 1e3:.1f} mm, {np.degrees(float(r.rotation_error_rad)):.2f} deg away)",
            )
        return IKResult(np.asarray(r.q, dtype=np.float64))
