"""Candidate stations for goal-driven planning: flange poses the robot reaches that show something useful.

Every candidate is a flange pose of the cell's robot that inverse kinematics reaches within the joint
limits (:func:`jcalib.planning.stations.reachable`, seeded at home) and that

- **views** (a camera / grid target pair, one on the flange and the other on the base): looks at the
  target from its printed side within ``amplitude_deg`` of its normal (uniform over the spherical cap),
  at 0.55..1.3 ``D`` (``D``: the distance at which the target spans half the smaller image side), rolled
  by any angle about the optical axis, aimed with a normal jitter of 0.12 rad per axis (so the target
  lands anywhere in the image, its corners included), and passes
  :func:`jcalib.planning.stations.view_problem`: the whole target in the image with a margin, within
  60 deg of its normal (never edge-on), 0.5..2 ``D`` away;
- **tool tips** (a tool on the flange, a camera on the base that observes it): holds the tool tip at a
  point in the camera's view 0.35 m in front of it (spread over the middle 60 % of the image), the tool
  axis tilted up to ``amplitude_deg`` from the side-on direction
  (:func:`jcalib.planning.stations.side_on_direction`) and turned by any angle about itself, its tip
  in the image, the shaft at least 30 deg away from the optical axis (seen along its length, not end-on).

Nothing here knows what a station is worth: :mod:`jcalib.planning.predict` does, with the problem builder.
Lengths in metres, angles in radians unless a name says otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from jcalib.planning.layout import CellLayout, presentation_pose
from jcalib.planning.stations import (TOOL_VIEW_DISTANCE_M, camera_frames, random_views, side_on_direction,
                                     turn_onto, view_problem)
from jcalib.errors import BadInputError
from jcalib.geometry.se3 import exp_so3, invert, make_pose

__all__ = ["Candidates", "VIEW_DISTANCE", "VIEW_JITTER_RAD", "cell_pairs", "merge", "reach", "tool_candidates",
           "view_candidates"]

#: Candidate views are drawn at this range of multiples of the viewing distance ``D``.
VIEW_DISTANCE = (0.55, 1.3)
#: Normal jitter of a candidate view's aim, rad per axis.
VIEW_JITTER_RAD = 0.12
#: A tool candidate's tip is spread over this fraction of the image about its centre.
TIP_SPREAD = 0.6
#: A tool's shaft is at least this far from the camera's optical axis, deg.
MIN_SHAFT_ANGLE_DEG = 30.0
#: Inverse kinematics of candidates: random seeds besides home, iterations, tolerance (m and rad). A
#: candidate that these miss is only dropped (candidates are many); batches are padded to 64.
IK_SEEDS = 3
IK_ITERATIONS = 80
IK_TOLERANCE = 1e-6


def reach(layout: CellLayout, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(ok (M,), joints_rad (M, n))``: which flange poses the robot reaches within its joint limits (one
    batched :func:`jcalib.geometry.kinematics.inverse_kinematics` call from home and a few random seeds)."""
    from jcalib.geometry.kinematics import inverse_kinematics

    poses = np.asarray(poses, np.float64)
    m = len(poses)
    padded = np.concatenate([poses, np.broadcast_to(poses[:1], ((-m) % 64, 4, 4))])
    res = inverse_kinematics(layout.dh_robot(), padded, layout.home_rad, num_seeds=IK_SEEDS,
                             max_iterations=IK_ITERATIONS, position_tolerance_m=IK_TOLERANCE,
                             rotation_tolerance_rad=IK_TOLERANCE)
    return np.asarray(res.success)[:m], np.asarray(res.q)[:m]


@dataclass
class Candidates:
    """Candidate stations.

    Attributes:
        T_base_flange: ``(M, 4, 4)`` flange poses, m.  joints_rad: ``(M, n)`` joints reaching them.
        pair: ``(M,)`` what each one shows: ``(camera, target)`` or ``(camera, tool)``.
        dropped: why -> how many candidates were left out.
    """

    T_base_flange: np.ndarray
    joints_rad: np.ndarray
    pair: list[tuple[str, str]]
    dropped: dict[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.pair)

    def subset(self, index) -> Candidates:
        index = np.asarray(index, int)
        return Candidates(self.T_base_flange[index], self.joints_rad[index], [self.pair[i] for i in index], self.dropped)


def merge(parts: list[Candidates]) -> Candidates:
    """One candidate set from several (in order)."""
    parts = [p for p in parts if len(p)]
    dropped: dict[str, int] = {}
    for p in parts:
        for k, v in p.dropped.items():
            dropped[k] = dropped.get(k, 0) + v
    if not parts:
        return Candidates(np.zeros((0, 4, 4)), np.zeros((0, 6)), [], dropped)
    return Candidates(np.concatenate([p.T_base_flange for p in parts]), np.concatenate([p.joints_rad for p in parts]),
                      [x for p in parts for x in p.pair], dropped)


def cell_pairs(layout: CellLayout) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    """``(views, tips)``: every camera / grid target pair the robot moves relative to each other, and every
    (base camera, flange tool) pair where the camera observes the tool."""
    views = []
    for c, cam in layout.cameras.items():
        for t, tgt in layout.targets.items():
            if {cam.mount, tgt.mount} == {"flange", "base"} and layout.cell.targets[t].type != "points":
                views.append((c, t))
    tips = [(c, tool) for tool in layout.tools for c in layout.cell.tools[tool].observed_by
            if layout.cameras[c].mount == "base"]
    return views, tips


def _keep_reachable(layout: CellLayout, poses: np.ndarray, pairs: list, dropped: dict[str, int]) -> Candidates:
    if not len(poses):
        return Candidates(np.zeros((0, 4, 4)), np.zeros((0, 6)), [], dropped)
    ok, q = reach(layout, poses)
    if (~ok).any():
        why = f"outside reach or joint limits of {layout.robot}"
        dropped[why] = dropped.get(why, 0) + int((~ok).sum())
    idx = np.flatnonzero(ok)
    return Candidates(poses[idx], q[idx], [pairs[i] for i in idx], dropped)


def view_candidates(layout: CellLayout, camera: str, target: str, count: int, rng: np.random.Generator,
                    amplitude_deg: float = 45.0) -> Candidates:
    """Up to ``count`` candidate views of ``target`` by ``camera`` (module docstring)."""
    D = layout.viewing_distance(camera, target)
    views = random_views(rng, count, layout.targets[target].centre, D, math.radians(amplitude_deg),
                         jitter=VIEW_JITTER_RAD, distance=VIEW_DISTANCE)
    flange = np.stack([presentation_pose(layout, camera, target, invert(T)) for T in views])
    T_ct, _ = camera_frames(layout, camera, target, flange)
    dropped: dict[str, int] = {}
    keep = []
    for i in range(count):
        why = view_problem(layout, camera, target, T_ct[i], D)
        if why is None:
            keep.append(i)
        else:
            dropped[why] = dropped.get(why, 0) + 1
    return _keep_reachable(layout, flange[keep], [(camera, target)] * len(keep), dropped)


def tool_candidates(layout: CellLayout, camera: str, tool: str, count: int, rng: np.random.Generator,
                    amplitude_deg: float = 40.0) -> Candidates:
    """Up to ``count`` candidate stations showing ``tool``'s tip to the base camera ``camera``."""
    cam = layout.cameras[camera]
    T_base_cam, K = cam.pose, cam.K
    w, h = cam.image_size
    T_flange_tool = layout.tools[tool]
    R_h = layout.T_base_flange_home[:3, :3]
    side = side_on_direction(T_base_cam)
    dropped: dict[str, int] = {}
    poses = []
    for _ in range(count):
        pix = np.array([(w - 1) / 2, (h - 1) / 2]) + rng.uniform(-0.5, 0.5, 2) * TIP_SPREAD * np.array([w, h])
        ray = np.linalg.solve(K, np.array([pix[0], pix[1], 1.0]))
        p_cam = ray / ray[2] * TOOL_VIEW_DISTANCE_M * rng.uniform(0.85, 1.15)
        p_tip = T_base_cam[:3, :3] @ p_cam + T_base_cam[:3, 3]
        tilt_axis = np.cross(side, rng.normal(size=3))
        tilt_axis /= np.linalg.norm(tilt_axis)
        shaft = exp_so3(tilt_axis * math.radians(amplitude_deg) * math.sqrt(rng.uniform())) @ side
        if abs(float(shaft @ T_base_cam[:3, 2])) > math.cos(math.radians(MIN_SHAFT_ANGLE_DEG)):
            why = f"tool shaft within {MIN_SHAFT_ANGLE_DEG:g} deg of the optical axis of {camera} (seen end-on)"
            dropped[why] = dropped.get(why, 0) + 1
            continue
        R = exp_so3(shaft * rng.uniform(-math.pi, math.pi)) @ turn_onto(R_h @ layout.tool_axis, shaft) @ R_h
        poses.append(make_pose(R, p_tip - R @ T_flange_tool[:3, 3]))
    if not poses:
        return Candidates(np.zeros((0, 4, 4)), np.zeros((0, 6)), [], dropped)
    return _keep_reachable(layout, np.stack(poses), [(camera, tool)] * len(poses), dropped)


def check_count(count: int) -> int:
    if not 10 <= int(count) <= 20000:
        raise BadInputError(f"--candidates: expected 10..20000 candidate stations, got {count}")
    return int(count)
