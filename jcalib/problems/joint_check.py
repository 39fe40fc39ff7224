"""Recorded joints against recorded flange poses, before the solve: a unit or convention error in the
kinematic data (joints in radians where degrees are expected, prismatic axes in metres where millimetres
are, a tool's pose recorded as the flange's) is named as such, with the station, instead of being absorbed
by the unknowns (a camera's distortion, a 10 m "kinematic error").

A real arm's flange lies within millimetres of its nominal kinematics at the controller's joint values
(:data:`POSITION_TOLERANCE_M`, :data:`ROTATION_TOLERANCE_DEG` are loose by two orders of magnitude), so a
station beyond them holds data of another unit, frame or robot.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import invert
from jcalib.problems.kinematics import forward_batch

__all__ = ["POSITION_TOLERANCE_M", "ROTATION_TOLERANCE_DEG", "check_joint_units", "check_joints_against_poses"]

#: A recorded flange position further than this (m) from the nominal forward kinematics is not kinematic error.
POSITION_TOLERANCE_M = 0.05
#: The same for the flange orientation (deg).
ROTATION_TOLERANCE_DEG = 5.0


def _distances(kin, q: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per station, the position (m) and rotation (deg) difference between ``T`` and the FK at ``q``, and
    ``FK⁻¹ T`` (4, 4)."""
    with np.errstate(over="ignore", invalid="ignore"):
        F = np.asarray(forward_batch(kin, kin.nominal, q), np.float64)
        D = invert(F) @ T
        pos = np.linalg.norm(T[:, :3, 3] - F[:, :3, 3], axis=1)
        cos = np.clip((np.trace(D[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    pos = np.where(np.isfinite(pos), pos, np.inf)
    rot = np.where(np.isfinite(cos), np.degrees(np.arccos(cos)), np.inf)
    return pos, rot, D


def _fits(pos: np.ndarray, rot: np.ndarray) -> bool:
    return bool(np.all((pos <= POSITION_TOLERANCE_M) & (rot <= ROTATION_TOLERANCE_DEG)))


def _diagnosis(kin, q: np.ndarray, T: np.ndarray, D: np.ndarray) -> str:
    """What the misfit looks like: one of the unit errors that would explain every station, else the causes."""
    revolute = np.array([t == "revolute" for t in kin.joint_types])
    guesses = []
    if revolute.any():
        guesses.append((np.where(revolute, np.degrees(q), q), ("joints in radians where degrees are expected? "
                        "(joints_deg holds degrees, as the controller shows them)")))
    if (~revolute).any():
        guesses.append((np.where(revolute, q, q * 1e3), ("prismatic axes in metres where millimetres are "
                        "expected? (joints_deg holds prismatic axes in mm)")))
    for q_guess, text in guesses:
        if _fits(*_distances(kin, q_guess, T)[:2]):
            return text
    offset = D[:, :3, 3]
    if len(D) >= 2 and np.max(np.std(offset, axis=0)) < 1e-3 and np.max(np.abs(D[:, :3, :3] - D[0, :3, :3])) < 1e-3:
        return (f"every recorded pose is the same offset from the flange ({np.round(offset.mean(axis=0), 4).tolist()} "
                "m in the flange frame): a tool's (TCP) pose recorded instead of the flange's? (record the flange, "
                "tool0, with no tool active)")
    return ("check the units (joints_deg in degrees and prismatic axes in mm; flange poses in metres), that the "
            "poses are the flange's in the robot's base frame, and that the cell's kinematics: is this robot's")


def check_joints_against_poses(kin, label: str, station_ids: Sequence[str], q: np.ndarray, T: np.ndarray,
                               source: str) -> None:
    """Refuse stations whose recorded flange pose is far from the nominal kinematics at their joints.

    Args:
        kin: the robot's :class:`~jcalib.geometry.kinematic_models.Kinematics` (its nominal parameters).
        label: the robot, as messages name it.
        station_ids: the ``N`` stations that record both.
        q: ``(N, n)`` their joint values, rad (m for prismatic axes).
        T: ``(N, 4, 4)`` their recorded ``T_base_flange``, m.
        source: the observations' source, for the message.

    Raises:
        BadInputError: naming the worst station, its distance from the forward kinematics and the likely
            unit or convention error, and how many stations are off.
    """
    if len(station_ids) == 0:
        return
    q, T = np.asarray(q, np.float64), np.asarray(T, np.float64)
    pos, rot, D = _distances(kin, q, T)
    bad = (pos > POSITION_TOLERANCE_M) | (rot > ROTATION_TOLERANCE_DEG)
    if not bad.any():
        return
    k = int(np.argmax(np.where(bad, pos / POSITION_TOLERANCE_M + rot / ROTATION_TOLERANCE_DEG, -1.0)))
    idx = np.flatnonzero(bad)
    raise BadInputError(
        f"{source}: station '{station_ids[k]}': the flange pose recorded is {pos[k]:.3g} m and {rot[k]:.3g} deg "
        f"from the forward kinematics of its joints ({label}, nominal kinematics); "
        f"{_diagnosis(kin, q[idx], T[idx], D[idx])} ({idx.size} of {len(station_ids)} stations are beyond "
        f"{POSITION_TOLERANCE_M:g} m or {ROTATION_TOLERANCE_DEG:g} deg; a real arm is within millimetres)")


def check_joint_units(kin, label: str, station_ids: Sequence[str], q: np.ndarray, source: str) -> None:
    """Refuse joint values that look like radians where degrees are expected, for a kinematic calibration.

    Every revolute joint of every station within ±2π "degrees" (while the joint limits allow more) is a
    robot that did not move, or joints written in radians.

    Raises:
        BadInputError: naming the robot and the largest value recorded.
    """
    q = np.asarray(q, np.float64)
    revolute = np.array([t == "revolute" for t in kin.joint_types])
    if len(station_ids) < 3 or not revolute.any():
        return
    recorded_deg = np.degrees(np.abs(q[:, revolute]))
    span = np.degrees(np.asarray(kin.upper) - np.asarray(kin.lower))[revolute]
    if np.max(recorded_deg) <= 2.0 * np.pi and np.max(recorded_deg) > 0.0 and np.max(span) > 4.0 * np.pi:
        raise BadInputError(
            f"{source}: the joints_deg of {label} lie within ±{np.max(recorded_deg):.3g} at every one of "
            f"{len(station_ids)} stations (e.g. station '{station_ids[0]}'): joints in radians where degrees are "
            "expected? Write the joint values in degrees as the controller shows them (a kinematic calibration "
            "needs every joint to move through tens of degrees)")
