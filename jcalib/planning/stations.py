"""Station planners: flange poses for camera (view sets), hand-eye, TCP and kinematic calibration.

Every planner works on the nominal :class:`~jcalib.planning.layout.CellLayout` (``jcalib plan``
and ``jcalib simulate`` use the same one) and keeps only stations the robot reaches within its joint
limits (:func:`jcalib.geometry.kinematics.inverse_kinematics` on the preset, one batched call) and, for
camera views, where the whole target is in the image (nominal intrinsics). Relative poses are built
in the target frame around the target centre ``c``; the *frontal* view puts the camera at distance
``D`` (the target then spans half the smaller image side) on the printed side, axes parallel to the
target's, looking at ``c``.

- ``viewsets`` (intrinsics; the RoboCalib thesis' view sets): the frontal view, a view straight over
  the target origin (point 0 at the image centre: the board fills one quadrant), four views tilted by
  ``amplitude`` (default 30 deg) about the target x and y axes through ``c`` (both signs), then
  *height* views: frontal at 0.8 D and 1.25 D, rolled about the optical axis by 0, +-30, +-60 deg.
- ``handeye``: the frontal view, then the camera rotated about its own Z (optical) axis by up to
  +-90 deg, about its Y and X axes by up to ``amplitude`` (default 30 deg), each re-centred on the
  target (the rotation axis passes through ``c``), in three groups Z, Y, X: large rotations about
  non-parallel axes make the hand-eye rotation and translation observable.
- ``tcp``: the tool tip (nominal TCP) held at one point while the tool turns about two horizontal
  base axes (x, then y) by up to ``amplitude`` (default 30 deg) from its start orientation. With a
  base camera observing the tool, the point is 0.35 m (:data:`TOOL_VIEW_DISTANCE_M`) in front of the
  first such camera and the tool starts *side-on* to it, pointing as far down as it can while
  perpendicular to the optical axis (:func:`side_on_direction`: a silhouette with the tip's cone
  edges in view, not the tool seen end-on); otherwise the point is 0.1 m above the work point and the
  tool starts pointing straight down.

- ``kinematics`` (:func:`plan_kinematics`): joint configurations that determine the robot's kinematic
  parameters (the cell's ``kinematics:`` and ``calibrate_kinematics:``). Candidates: for an arm (six or
  more joints) with a camera / target pair, camera poses looking at the target centre from within
  ``amplitude`` (default 45 deg) of its normal, at 0.6..1.25 ``D``, rolled freely about the optical
  axis and aimed with a small jitter, each solved by inverse kinematics on the nominal model from a
  random joint vector (so configurations differ in every joint, elbow and wrist branches included);
  for an external axis (or an arm without such a pair): joint values spread uniformly over the limits.
  A candidate is kept when it is within the joint limits (less 1 deg / 5 mm), away from singularities,
  and, where the view is known, shows the whole target, not edge-on (within 60 deg of its normal), at
  a usable distance (0.5..2 ``D``), with the arm's elbow and wrist on the target's printed side (not
  through the table the target lies on). From these, :func:`jcalib.planning.kinematic_design.d_optimal`
  picks the stations that maximise the log determinant of the information of the identifiable
  parameters, with the two unknown poses on either side of the robot eliminated (their Schur
  complement in the information of all: Ds-optimal); the plan records each station's
  joints (``joints_deg``) and the predicted σ per parameter. It refuses (``BadInputError``) a cell
  without kinematics to calibrate, and a plan in which a joint moves less than 5 deg (10 mm) or some
  identifiable parameter stays undetermined, naming the joints and parameters. Obstacles and
  self-collisions are not checked (beyond the target's plane).

Angles are spread evenly: group members alternate in sign with growing magnitude up to the amplitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jcalib.planning.layout import TOOL_VIEW_DISTANCE_M, CellLayout, cell_layout, load_cell_dict, presentation_pose
from jcalib.io.plan import Plan, make_plan
from jcalib.geometry.se3 import exp_so3, invert, make_pose, rot_z
from jcalib.errors import BadInputError

KINDS = ("viewsets", "handeye", "tcp", "kinematics")
DEFAULT_STATIONS = {"viewsets": 14, "handeye": 19, "tcp": 13, "kinematics": 30}
DEFAULT_AMPLITUDE_DEG = {"viewsets": 30.0, "handeye": 30.0, "tcp": 30.0, "kinematics": 45.0}
#: ``kinematics``: candidate configurations per planned station (``--candidates`` overrides).
CANDIDATES_PER_STATION = 20
#: ``kinematics``: corner noise assumed for the predicted σ, px per coordinate.
DEFAULT_SIGMA_PX = 0.2
#: ``kinematics``: a view is usable when the target centre is 0.5..2 ``D`` away (the target spans about
#: the whole to a quarter of the smaller image side) and seen within this angle of its normal.
USABLE_DISTANCE = (0.5, 2.0)
MAX_VIEW_ANGLE_DEG = 60.0
#: ``kinematics``: candidate views are drawn at 0.6..1.25 ``D``.
VIEW_DISTANCE = (0.6, 1.25)
#: ``kinematics``: every joint moves at least this much over a plan (deg revolute, mm prismatic), or no plan.
MIN_JOINT_SPAN = (5.0, 10.0)
#: ``kinematics``: inverse kinematics of the candidate views: random seeds besides the candidate's own random
#: start, and iterations (a batch costs candidates x seeds x iterations; a missed candidate is just dropped).
IK_SEEDS = 2
IK_ITERATIONS = 100
#: ``kinematics``: smallest singular value of an arm's joint Jacobian kept (rad/rad, m/rad): below it the
#: arm is near a singularity (wrist stretched, axes 4 and 6 aligned), where joints flip unpredictably.
MIN_JOINT_JACOBIAN_SV = 0.05


@dataclass
class PlannedStations:
    """A plan and how it was made.

    Attributes:
        plan: the reachable stations, ids ``s000, s001, ...`` in order.
        kind: planner kind.  camera, target, tool: what it planned for (None when not used).
        dropped: candidate description -> why it was left out (unreachable, target not in view);
            ``kinematics``: why -> how many of the candidates.
        robot: the robot planned for (default: the layout's preset).
        details: further planner keys (``kinematics``: the prediction, joint spans, assumptions).
    """

    plan: Plan
    kind: str
    camera: str | None = None
    target: str | None = None
    tool: str | None = None
    dropped: dict[str, str] = field(default_factory=dict)
    robot: str | None = None
    details: dict = field(default_factory=dict)

    def to_json(self, layout: CellLayout | None = None) -> dict:
        """The plan file (``jcalib.plan/1``) with the planner's settings as extra keys."""
        robot = self.robot if self.robot is not None else (layout.robot if layout is not None else None)
        return {
            **self.plan.to_json(),
            "planner": {"kind": self.kind, "robot": robot, "camera": self.camera, "target": self.target,
                        "tool": self.tool, "dropped": self.dropped, **self.details},
        }  # fmt: skip


def _spread(m: int, amplitude: float) -> list[float]:
    """``m`` non-zero angles alternating in sign, magnitudes growing evenly up to ``amplitude``."""
    half = max(1, (m + 1) // 2)
    return [(1.0 if k % 2 == 0 else -1.0) * amplitude * (k // 2 + 1) / half for k in range(m)]


def _about(axis: np.ndarray, angle: float, point: np.ndarray) -> np.ndarray:
    """(4, 4) rotation by ``angle`` rad about the line through ``point`` along ``axis``."""
    R = exp_so3(np.asarray(axis, dtype=np.float64) * angle)
    return make_pose(R, point - R @ point)


def side_on_direction(T_base_cam: np.ndarray) -> np.ndarray:
    """(3,) unit base-frame direction for a tool seen side-on by a base camera, pointing as far down as it can.

    The base ``-z`` axis with its component along the camera's optical axis removed (a straight tool
    along it has the longest silhouette and shows its tip's cone edges); the camera's image-down
    axis (``+y``) when the camera looks within 10 deg of vertically.

    Args:
        T_base_cam: (4, 4) camera pose in the base, m.
    """
    o = T_base_cam[:3, 2]
    down = np.array([0.0, 0.0, -1.0])
    w = down - np.dot(down, o) * o
    n = float(np.linalg.norm(w))
    return w / n if n > np.sin(np.radians(10.0)) else T_base_cam[:3, 1] / np.linalg.norm(T_base_cam[:3, 1])


def turn_onto(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(3, 3) smallest rotation taking unit vector ``v`` onto unit vector ``w`` (half a turn when opposite)."""
    axis = np.cross(v, w)
    s, c = float(np.linalg.norm(axis)), float(np.dot(v, w))
    if s > 1e-12:
        return exp_so3(axis / s * np.arctan2(s, c))
    if c > 0:
        return np.eye(3)
    perp = np.cross(v, np.eye(3)[int(np.argmin(np.abs(v)))])
    return exp_so3(perp / np.linalg.norm(perp) * np.pi)


def _pick_pair(layout: CellLayout, camera: str | None, target: str | None) -> tuple[str, str]:
    cams = [camera] if camera else list(layout.cameras)
    for c in cams:
        if c not in layout.cameras:
            raise BadInputError(f"--camera: no camera {c!r} in the cell (has {', '.join(layout.cameras)})")
        want = "base" if layout.cameras[c].mount == "flange" else "flange"
        tgts = [target] if target else [t for t in layout.targets if layout.targets[t].mount == want]
        for t in tgts:
            if t not in layout.targets:
                raise BadInputError(f"--target: no target {t!r} in the cell (has {', '.join(layout.targets)})")
            if layout.targets[t].mount == want:
                return c, t
    raise BadInputError(
        "the cell has no camera / target pair the robot can move relative to each other (one on the "
        "flange, the other on the base); name them with --camera / --target"
    )


def _view_candidates(kind: str, n: int, c: np.ndarray, D: float, amplitude: float) -> list[tuple[str, np.ndarray]]:
    """(description, ``T_target_cam``) candidates, in order, at least ``n`` of them."""
    ex, ey, ez = np.eye(3)
    frontal = make_pose(np.eye(3), c - D * ez)
    out = [("frontal", frontal)]
    if kind == "viewsets":
        out.append(("over the target origin", make_pose(np.eye(3), -D * ez)))
        for axis, name in ((ex, "x"), (ey, "y")):
            for s in (1.0, -1.0):
                out.append((f"tilted {s * np.degrees(amplitude):+.0f} deg about target {name}", _about(axis, s * amplitude, c) @ frontal))
        rolls = [0.0] + _spread(max(0, n), np.radians(60.0))
        k = 0
        while len(out) < max(n, 7):
            scale = (0.8, 1.25)[k % 2]
            roll = rolls[(k // 2) % len(rolls)]
            T = make_pose(rot_z(roll), c - scale * D * ez)
            out.append((f"height {scale:.2f} D, roll {np.degrees(roll):+.0f} deg", T))
            k += 1
    else:
        m = max(0, n - 1)
        groups = [m - 2 * (m // 3), m // 3, m // 3]  # Z gets the rest
        for (axis, name, amp), count in zip(((ez, "Z", np.radians(90.0)), (ey, "Y", amplitude), (ex, "X", amplitude)), groups, strict=True):
            for ang in _spread(count, amp):
                out.append((f"camera about its {name} by {np.degrees(ang):+.0f} deg", _about(axis, ang, c) @ frontal))
    return out


def _in_view(layout: CellLayout, camera: str, target: str, T_cam_target: np.ndarray, margin_px: float = 2.0) -> bool:
    import cv2

    cam, tgt = layout.cameras[camera], layout.targets[target]
    P = np.asarray(tgt.geometry.points, dtype=np.float64)
    p_cam = P @ T_cam_target[:3, :3].T + T_cam_target[:3, 3]
    if np.any(p_cam[:, 2] <= 0.0):
        return False
    rvec, _ = cv2.Rodrigues(T_cam_target[:3, :3])
    if cam.model == "fisheye":
        px, _ = cv2.fisheye.projectPoints(P[None], rvec, T_cam_target[:3, 3], cam.K, cam.dist)
    else:
        px, _ = cv2.projectPoints(P, rvec, T_cam_target[:3, 3], cam.K, cam.dist)
    px = px.reshape(-1, 2)
    w, h = cam.image_size
    return bool(np.all((px >= margin_px) & (px <= np.array([w - 1 - margin_px, h - 1 - margin_px]))))


def reachable(layout: CellLayout, poses: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Which flange poses the robot reaches within its joint limits, and their joints.

    One batched :func:`jcalib.geometry.kinematics.inverse_kinematics` call seeded at home; the batch
    is padded to a multiple of 16 so plans of similar size share one compilation.

    Returns:
        ok: (n,) bool.  joints_rad: (n, 6) joints (meaningful where ``ok``).
    """
    from jcalib.geometry.kinematics import inverse_kinematics

    n = len(poses)
    padded = list(poses) + [poses[0]] * ((-n) % 16)
    res = inverse_kinematics(layout.dh_robot(), np.stack(padded), layout.home_rad,
                             position_tolerance_m=1e-6, rotation_tolerance_rad=1e-6)  # fmt: skip
    return np.asarray(res.success)[:n], np.asarray(res.q)[:n]


def plan_cell(
    layout: CellLayout,
    kind: str,
    *,
    num_stations: int | None = None,
    camera: str | None = None,
    target: str | None = None,
    tool: str | None = None,
    amplitude_deg: float | None = None,
    num_candidates: int | None = None,
    seed: int = 0,
    sigma_px: float | None = None,
) -> PlannedStations:
    """Plan stations of ``kind`` ("viewsets", "handeye", "tcp" or "kinematics") for the cell (see the
    module docstring; ``kinematics``: :func:`plan_kinematics`, which takes the other arguments).

    Args:
        layout: the nominal cell (:func:`jcalib.planning.layout.cell_layout`).
        kind: planner.
        num_stations: candidates to generate (default :data:`DEFAULT_STATIONS`); unreachable ones
            are dropped, so the plan may hold fewer.
        camera, target: the pair to plan for (default: the first camera with a target it can move
            relative to); tool: the tool for ``tcp`` (default: the cell's first tool).
        amplitude_deg: largest tilt / rotation, degrees.
        num_candidates, seed, sigma_px: ``kinematics`` only (:func:`plan_kinematics`).

    Raises:
        BadInputError: unknown kind or names, nothing to plan for, or fewer than half of the
            candidates (or under 3) reachable and in view: the nominal layout does not suit this robot.
    """
    if kind not in KINDS:
        raise BadInputError(f"--kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    if kind == "kinematics":
        return plan_kinematics(layout.cell_dict, layout=layout, num_stations=num_stations, camera=camera,
                               target=target, amplitude_deg=amplitude_deg, num_candidates=num_candidates,
                               seed=seed, sigma_px=sigma_px)
    n = int(num_stations if num_stations is not None else DEFAULT_STATIONS[kind])
    if not 3 <= n <= 500:
        raise BadInputError(f"--stations: expected 3..500 stations, got {n}")
    amp_deg = float(amplitude_deg if amplitude_deg is not None else DEFAULT_AMPLITUDE_DEG[kind])
    if not 1.0 <= amp_deg <= 80.0:
        raise BadInputError(f"--amplitude-deg: expected 1..80 deg, got {amp_deg}")
    amp = np.radians(amp_deg)

    cands: list[tuple[str, np.ndarray]] = []
    view_check = None
    cam_name = tgt_name = tool_name = None
    if kind in ("viewsets", "handeye"):
        cam_name, tgt_name = _pick_pair(layout, camera, target)
        tgt = layout.targets[tgt_name]
        D = layout.viewing_distance(cam_name, tgt_name)
        view_check = []
        for desc, T_target_cam in _view_candidates(kind, n, tgt.centre, D, amp)[:n]:
            view_check.append(invert(T_target_cam))
            cands.append((desc, presentation_pose(layout, cam_name, tgt_name, view_check[-1])))
    else:
        if not layout.tools:
            raise BadInputError("--kind tcp: the cell has no tool (add one under 'tools:')")
        tool_name = tool or next(iter(layout.tools))
        if tool_name not in layout.tools:
            raise BadInputError(f"--tool: no tool {tool_name!r} in the cell (has {', '.join(layout.tools)})")
        T_flange_tool = layout.tools[tool_name]
        observers = [c for c in layout.cell.tools[tool_name].observed_by if layout.cameras[c].mount == "base"]
        if observers:
            T_base_cam = layout.cameras[observers[0]].pose
            p_tip = T_base_cam[:3, 3] + TOOL_VIEW_DISTANCE_M * T_base_cam[:3, 2]
            w = side_on_direction(T_base_cam)
            start = "tool pointing down, across the view of " + observers[0]
        else:
            p_tip = layout.work_point + np.array([0.0, 0.0, 0.1])
            w, start = np.array([0.0, 0.0, -1.0]), "tool pointing down"
        R_h = layout.T_base_flange_home[:3, :3]
        # the flange orientation that turns the tool axis onto w, placed so that the tip is at p_tip (the
        # TCP frame's own rotation does not matter: only where the tip is and where the shaft points)
        R0 = turn_onto(R_h @ layout.tool_axis, w) @ R_h
        T_flange0 = make_pose(R0, p_tip - R0 @ T_flange_tool[:3, 3])
        cands.append((start, T_flange0))
        m = n - 1
        for ax, name, count in ((np.eye(3)[0], "x", m - m // 2), (np.eye(3)[1], "y", m // 2)):
            for ang in _spread(count, amp):
                cands.append((f"tool about base {name} by {np.degrees(ang):+.0f} deg", _about(ax, ang, p_tip) @ T_flange0))

    ok, _ = reachable(layout, [T for _, T in cands])
    dropped: dict[str, str] = {}
    keep = []
    for i, ((desc, T), good) in enumerate(zip(cands, ok, strict=True)):
        if not good:
            dropped[desc] = f"outside reach or joint limits of {layout.dh_robot().name}"
        elif view_check is not None and not _in_view(layout, cam_name, tgt_name, view_check[i]):
            dropped[desc] = f"target {tgt_name} not entirely in the image of {cam_name}"
        else:
            keep.append(T)
    if len(keep) < max(3, (len(cands) + 1) // 2):
        raise BadInputError(
            f"plan {kind}: only {len(keep)} of {len(cands)} candidate stations are reachable and in view "
            f"for {layout.robot} ({'; '.join(f'{k}: {v}' for k, v in list(dropped.items())[:4])}). Give the "
            "target / camera / tool poses in the cell spec (pose: [[4x4]], m), another robot preset, or a "
            "smaller --amplitude-deg"
        )
    return PlannedStations(make_plan(keep), kind, cam_name, tgt_name, tool_name, dropped)


# ----------------------------------------------------------------------------------------------
# Kinematic calibration
# ----------------------------------------------------------------------------------------------


def _kinematics_robot(spec, source: str):
    """The cell's one robot entry, which must name its kinematics and what to calibrate."""
    if spec.robot is None:
        what = (f"has several robots ({', '.join(spec.robots)}); plan one robot's kinematics at a time "
                "(a cell with only that robot)") if spec.robots else "has no robot"
        raise BadInputError(f"plan --kind kinematics: {source} {what}")
    rs = spec.robot
    if rs.kinematics is None:
        raise BadInputError(
            f"plan --kind kinematics: {source}: the robot has no 'kinematics:' (its nominal model), so there "
            "is no kinematic calibration to plan for; add kinematics: <preset> (kuka_kr10_r1100_sixx, "
            "abb_irb4600_45_205, positioner_2axis, linear_track, rotary_table) or a dh / mdh / poe table, "
            "and calibrate_kinematics: [joint_offsets, link_lengths, twists]"
        )
    if not rs.calibrate_kinematics:
        raise BadInputError(
            f"plan --kind kinematics: {source}: the robot's kinematics is taken as exact (no "
            "calibrate_kinematics:); name what to calibrate, e.g. calibrate_kinematics: [joint_offsets, "
            "link_lengths, twists]"
        )
    return rs


def _arm_preset(rs) -> str | None:
    """The arm preset of :mod:`jcalib.geometry.robots` that a robot's ``kinematics:`` names, if any."""
    from jcalib.geometry.robots import PRESETS

    entry = rs.kinematics_spec
    name = entry.get("preset") if isinstance(entry, dict) else entry
    return name if isinstance(name, str) and name in PRESETS else None


def _view_pair(spec, camera: str | None, target: str | None) -> tuple[str, str] | None:
    """A camera and a grid target the robot moves relative to each other (one on the flange, the other on
    the base), or None; named ones must exist and form such a pair."""
    for c in [camera] if camera else list(spec.cameras):
        if c not in spec.cameras:
            raise BadInputError(f"--camera: no camera {c!r} in the cell (has {', '.join(spec.cameras)})")
        want = "base" if spec.cameras[c].mount == "flange" else "flange"
        for t in [target] if target else list(spec.targets):
            if t not in spec.targets:
                raise BadInputError(f"--target: no target {t!r} in the cell (has {', '.join(spec.targets)})")
            if spec.targets[t].mount == want and spec.cameras[c].mount in ("flange", "base") \
                    and spec.targets[t].type != "points":
                return c, t
    if camera or target:
        raise BadInputError("--camera / --target: they must be a camera and a grid target of which one is on "
                            "the flange and the other on the base")
    return None


def random_views(rng: np.random.Generator, count: int, c: np.ndarray, D: float, amp: float, jitter: float = 0.05,
                 distance: tuple[float, float] = VIEW_DISTANCE) -> np.ndarray:
    """``(count, 4, 4)`` random ``T_target_cam``: looking at the target centre ``c`` from its printed side
    within ``amp`` rad of its normal (uniform over the spherical cap), at ``distance`` (default
    :data:`VIEW_DISTANCE`) x ``D``, rolled by any angle about the optical axis and aimed with a jitter of
    ``jitter`` rad (normal, per axis: larger ones put the target off the image centre)."""
    out = np.empty((count, 4, 4))
    cos_tilt = rng.uniform(np.cos(amp), 1.0, count)
    azimuth = rng.uniform(-np.pi, np.pi, count)
    dist = rng.uniform(*distance, count) * D
    roll = rng.uniform(-np.pi, np.pi, count)
    jitter = rng.normal(scale=jitter, size=(count, 2))
    for k in range(count):
        frontal = make_pose(np.eye(3), c - dist[k] * np.array([0.0, 0.0, 1.0]))
        axis = np.array([np.cos(azimuth[k]), np.sin(azimuth[k]), 0.0])
        T = _about(axis, float(np.arccos(cos_tilt[k])), c) @ frontal
        R = T[:3, :3] @ rot_z(roll[k]) @ exp_so3(np.array([jitter[k, 0], jitter[k, 1], 0.0]))
        out[k] = make_pose(R, T[:3, 3])
    return out


def view_problem(layout: CellLayout, camera: str, target: str, T_cam_target: np.ndarray, D: float) -> str | None:
    """Why a view is not usable for calibration (None when it is): edge-on, too near or far, target cut."""
    tgt = layout.targets[target]
    c = T_cam_target[:3, :3] @ tgt.centre + T_cam_target[:3, 3]
    dist = float(np.linalg.norm(c))
    if float(np.dot(T_cam_target[:3, 2], c / dist)) < np.cos(np.radians(MAX_VIEW_ANGLE_DEG)):
        return f"target {target} seen more than {MAX_VIEW_ANGLE_DEG:g} deg from its normal (edge-on or from behind)"
    if not USABLE_DISTANCE[0] * D <= dist <= USABLE_DISTANCE[1] * D:
        return f"target {target} nearer than {USABLE_DISTANCE[0]:g} or further than {USABLE_DISTANCE[1]:g} x {D:.3f} m"
    margin_px = max(2.0, 0.01 * min(layout.cameras[camera].image_size))
    if not _in_view(layout, camera, target, T_cam_target, margin_px=margin_px):
        return f"target {target} not entirely in the image of {camera}"
    return None


def camera_frames(layout: CellLayout, camera: str, target: str, T_base_flange: np.ndarray):
    """``(T_cam_target, T_cam_flange)`` ``(M, 4, 4)`` at flange poses ``T_base_flange (M, 4, 4)``."""
    cam, tgt = layout.cameras[camera], layout.targets[target]
    if cam.mount == "flange":
        T_cam_flange = np.broadcast_to(invert(cam.pose), T_base_flange.shape)
        return T_cam_flange @ invert(T_base_flange) @ tgt.pose, T_cam_flange
    T_cam_flange = invert(cam.pose) @ T_base_flange
    return T_cam_flange @ tgt.pose, T_cam_flange


def visit_order(q: np.ndarray, start: np.ndarray) -> list[int]:
    """Visit order of joint vectors ``q (M, n)``: nearest neighbour from ``start`` (short moves)."""
    left, order, at = list(range(len(q))), [], start
    while left:
        k = left[int(np.argmin([np.max(np.abs(q[i] - at)) for i in left]))]
        order.append(k)
        left.remove(k)
        at = q[k]
    return order


@dataclass
class KinematicCandidates:
    """Usable candidate configurations for a kinematic calibration plan, with their design rows.

    Attributes:
        model: the robot's nominal :class:`~jcalib.geometry.kinematic_models.Kinematics`.
        q: ``(M, n)`` joints (rad, m).  T_base_flange: ``(M, 4, 4)`` nominal flange poses, m.
        design: the whitened Jacobian rows (:class:`~jcalib.planning.kinematic_design.DesignRows`).
        total: candidates generated.  dropped: why -> how many of them were left out.
        held: requested parameters not separable from others (kept at their nominal value).
        camera, target: the view pair (None: no view planned).  layout: the nominal layout, if built.
        assumes: what the prediction assumes.  sigma_px: its corner noise (None without a view).
    """

    model: Any
    q: np.ndarray
    T_base_flange: np.ndarray
    design: Any
    total: int
    dropped: dict[str, int]
    held: dict[str, str]
    camera: str | None
    target: str | None
    layout: CellLayout | None
    assumes: str
    sigma_px: float | None


def kinematic_candidates(
    cell,
    *,
    layout: CellLayout | None = None,
    robot: str | None = None,
    image_size: tuple[int, int] | None = None,
    camera: str | None = None,
    target: str | None = None,
    amplitude_deg: float | None = None,
    num_candidates: int = 600,
    seed: int = 0,
    sigma_px: float | None = None,
) -> KinematicCandidates:
    """Generate and check candidate configurations for :func:`plan_kinematics` (module docstring).

    Raises:
        BadInputError: no kinematics to calibrate, bad options, nothing identifiable.
    """
    import jax

    from jcalib.planning import kinematic_design as kd
    from jcalib.geometry.kinematics import inverse_kinematics
    from jcalib.io.cell import parse_cell

    data, source = (layout.cell_dict, layout.cell.source) if layout is not None else load_cell_dict(cell)
    spec = layout.cell if layout is not None else parse_cell(data, source)
    rs = _kinematics_robot(spec, source)
    model = rs.kinematics
    amp_deg = float(amplitude_deg if amplitude_deg is not None else DEFAULT_AMPLITUDE_DEG["kinematics"])
    if not 1.0 <= amp_deg <= MAX_VIEW_ANGLE_DEG:
        raise BadInputError(f"--amplitude-deg: expected 1..{MAX_VIEW_ANGLE_DEG:g} deg from the target normal, "
                            f"got {amp_deg}")
    m = int(num_candidates)
    if not 8 <= m <= 20000:
        raise BadInputError(f"--candidates: expected 8..20000 candidate configurations, got {m}")
    sigma = float(sigma_px if sigma_px is not None else DEFAULT_SIGMA_PX)
    if not (np.isfinite(sigma) and 0.0 < sigma <= 10.0):
        raise BadInputError(f"--sigma-px: expected a corner noise in (0, 10] px, got {sigma_px}")

    rep_cov, rep_how = kd.repeatability_covariance(rs)
    free, held = kd.identifiable(model, rs.calibrate_kinematics, rep_cov)
    if not free.any():
        raise BadInputError(f"plan --kind kinematics: none of {list(rs.calibrate_kinematics)} of {model.name} can be "
                            "separated from the poses on either side of the robot; nothing to plan for")
    arm = model.num_joints >= 6
    pair = _view_pair(spec, camera, target)
    if pair is not None and not arm and (spec.cameras[pair[0]].pose is None or spec.targets[pair[1]].pose is None):
        pair = None  # the nominal layout places things for an arm: an external axis' view needs given poses
    if pair is not None and layout is None:
        layout = cell_layout(data, robot=robot or (None if rs.model else _arm_preset(rs)), image_size=image_size)
    rng = np.random.default_rng(seed)
    counts: dict[str, int] = {}

    def drop(keep: np.ndarray, why: str) -> np.ndarray:
        if (~keep).any():
            counts[why] = counts.get(why, 0) + int((~keep).sum())
        return keep

    if arm and pair is not None:
        cam, tgt = pair
        D = layout.viewing_distance(cam, tgt)
        views = random_views(rng, m, layout.targets[tgt].centre, D, np.radians(amp_deg))
        flange = np.stack([presentation_pose(layout, cam, tgt, invert(T)) for T in views])
        dh = kd.ik_robot(model, rs.kinematics_spec)
        q0 = kd.joint_space_candidates(model, m, rng)
        pad = (-m) % 64
        ik = inverse_kinematics(dh, np.concatenate([flange, flange[:pad]]), np.concatenate([q0, q0[:pad]]),
                                num_seeds=IK_SEEDS, key=jax.random.PRNGKey(seed), max_iterations=IK_ITERATIONS,
                                position_tolerance_m=1e-7, rotation_tolerance_rad=1e-7)  # fmt: skip
        q = np.array(ik.q)[:m]
        keep = drop(np.array(ik.success)[:m], f"outside reach or joint limits of {model.name}")
    else:
        q = kd.joint_space_candidates(model, m, rng)
        keep = np.ones(m, bool)
    margin = kd.joint_margin(model)
    lo, hi = np.asarray(model.lower), np.asarray(model.upper)
    keep &= drop(~keep | np.all((q >= lo + margin - 1e-12) & (q <= hi - margin + 1e-12), axis=1),
                 "within 1 deg (5 mm) of a joint limit")
    q = q[keep]
    T, Jp, Jq, origins = kd.flange_jacobians(model, q)
    keep = np.ones(len(q), bool)
    if arm:
        # the joint Jacobian in rad and m (one metre of translation weighs as one radian)
        keep &= drop(np.linalg.svd(Jq, compute_uv=False)[:, -1] >= MIN_JOINT_JACOBIAN_SV,
                     f"near a singularity (joint Jacobian singular value under {MIN_JOINT_JACOBIAN_SV:g})")
    cov = np.broadcast_to(rep_cov, (len(q), 6, 6)).copy()
    if pair is not None:
        cam, tgt = pair
        D = layout.viewing_distance(cam, tgt)
        T_ct, T_cf = camera_frames(layout, cam, tgt, T)
        why = [(view_problem(layout, cam, tgt, T_ct[i], D) if keep[i] else None) for i in range(len(q))]
        for w in sorted({w for w in why if w}):
            keep &= drop(np.array([x != w for x in why]), w)
        if layout.targets[tgt].mount == "base":
            # the elbow, the wrist and the flange stay on the printed side of the target (its table or wall)
            Tt = layout.targets[tgt].pose
            pts = np.concatenate([origins[:, 2:], T[:, None, :3, 3]], axis=1)
            depth = (pts - Tt[:3, 3]) @ Tt[:3, 2]  # along the target z: into the board, behind its face
            keep &= drop(~keep | np.all(depth < 0.0, axis=1), f"the arm would reach behind target {tgt}'s plane")
        points = np.asarray(layout.targets[tgt].geometry.points, np.float64)
        info = kd.view_information(T_ct[keep], T_cf[keep], points, layout.cameras[cam].K, sigma)
        cov[keep] += np.linalg.inv(info)
        assumes = (f"{sigma:g} px corner noise per coordinate on {tgt} seen by {cam} (nominal intrinsics, known, "
                   f"distortion ignored), the robot's {rep_how}, unknown poses on either side of the robot")
    else:
        assumes = (f"exact flange-pose measurements (no camera view planned) and the robot's {rep_how}, unknown "
                   "poses on either side of the robot")
    q, T, Jp, cov = q[keep], T[keep], Jp[keep], cov[keep]
    return KinematicCandidates(model, q, T, kd.design_rows(model, T, Jp, free, cov), m, counts, held,
                               pair[0] if pair else None, pair[1] if pair else None, layout, assumes,
                               sigma if pair is not None else None)


def plan_kinematics(
    cell,
    *,
    layout: CellLayout | None = None,
    robot: str | None = None,
    image_size: tuple[int, int] | None = None,
    num_stations: int | None = None,
    camera: str | None = None,
    target: str | None = None,
    amplitude_deg: float | None = None,
    num_candidates: int | None = None,
    seed: int = 0,
    sigma_px: float | None = None,
) -> PlannedStations:
    """Plan stations that determine the kinematic parameters the cell calibrates (module docstring).

    Args:
        cell: path of ``cell.yaml`` or the loaded mapping; its one robot must have ``kinematics:`` and
            ``calibrate_kinematics:``.
        layout: the nominal layout (default: :func:`~jcalib.planning.layout.cell_layout` of the cell,
            built where a camera view is planned), with ``robot`` (a preset of
            :mod:`jcalib.geometry.robots`; default the cell's ``robot.model``, else the arm preset the
            kinematics names) and ``image_size`` as there.
        num_stations: stations to plan (default 30); camera, target: the view pair (default: the first
            camera and grid target that the robot moves relative to each other).
        amplitude_deg: largest angle of a view from the target normal (default 45).
        num_candidates: candidate configurations (default :data:`CANDIDATES_PER_STATION` per station).
        seed: the candidates' random seed.  sigma_px: corner noise of the prediction (default 0.2 px).

    Returns:
        The plan (stations with ``joints_deg``, in a short-move order) and, under ``details``, the
        prediction (σ per parameter in deg / mm, the worst per group, condition number, log det), the
        parameters held as not separable, each joint's span and the assumptions.

    Raises:
        BadInputError: no kinematics to calibrate, bad options, too few usable candidates, or no plan
            that determines every identifiable parameter (naming them and the joints that did not move).
    """
    from jcalib.planning import kinematic_design as kd
    from jcalib.geometry import kinematic_models

    n = int(num_stations if num_stations is not None else DEFAULT_STATIONS["kinematics"])
    if not 3 <= n <= 500:
        raise BadInputError(f"--stations: expected 3..500 stations, got {n}")
    m = int(num_candidates if num_candidates is not None else CANDIDATES_PER_STATION * n)
    if m < 2 * n:
        raise BadInputError(f"--candidates: expected at least twice the stations ({2 * n}), got {m}")
    c = kinematic_candidates(cell, layout=layout, robot=robot, image_size=image_size, camera=camera, target=target,
                             amplitude_deg=amplitude_deg, num_candidates=m, seed=seed, sigma_px=sigma_px)
    model, q, T = c.model, c.q, c.T_base_flange
    if len(q) < n:
        raise BadInputError(
            f"plan kinematics: only {len(q)} of {c.total} candidate configurations of {model.name} are usable for "
            f"{n} stations ({'; '.join(f'{w}: {k}' for w, k in c.dropped.items())}). Give more --candidates, fewer "
            "--stations, the camera / target poses in the cell spec (pose: [[4x4]], m), or a larger --amplitude-deg"
        )
    revolute = np.array([t == "revolute" for t in model.joint_types])
    least = np.where(revolute, np.radians(MIN_JOINT_SPAN[0]), MIN_JOINT_SPAN[1] * 1e-3)

    def barely_moving(span: np.ndarray) -> str:
        return ", ".join(f"{j} ({math.degrees(s) if r else s * 1e3:.3g} {'deg' if r else 'mm'})"
                         for j, s, r, lim in zip(model.joint_names, span, revolute, least) if s < lim)

    if barely_moving(np.ptp(q, axis=0)):
        raise BadInputError(
            f"plan kinematics: joint(s) {barely_moving(np.ptp(q, axis=0))} of {model.name} move less than "
            f"{MIN_JOINT_SPAN[0]:g} deg / {MIN_JOINT_SPAN[1]:g} mm over all {len(q)} usable configurations (within "
            "the joint limits, reach and view): a joint that does not move cannot be told apart from its "
            "neighbours. Widen its limits, change the camera / target placement, or leave it out of "
            "calibrate_kinematics"
        )
    chosen = kd.d_optimal(c.design.normalised, n, nuisance=kd.GAUGE_COLUMNS)  # the poses: unknown, not of interest
    pred = kd.prediction(model, c.design, chosen)
    lo, hi = np.asarray(model.lower), np.asarray(model.upper)
    span = np.ptp(q[chosen], axis=0)
    if not pred["full_rank"] or barely_moving(span):
        raise BadInputError(
            f"plan kinematics: no {n} of the {len(q)} usable configurations of {model.name} determine "
            f"{', '.join(kd.null_parameters(c.design, chosen)) or 'all free parameters'}"
            + (f" (joint(s) {barely_moving(span)} hardly move)" if barely_moving(span) else "")
            + ": plan more --stations or --candidates, change the camera / target placement, or remove them "
              "from calibrate_kinematics"
        )
    arm = c.layout is not None and c.layout.home_rad.shape == (model.num_joints,)
    order = chosen[visit_order(q[chosen], c.layout.home_rad if arm else 0.5 * (lo + hi))]
    joints = kinematic_models.joints_to_controller(model, q[order])
    plan = make_plan(list(T[order]), joints_deg=[[float(v) for v in j] for j in joints])
    details = {
        "candidates": c.total,
        "usable": len(q),
        "seed": int(seed),
        "free_parameters": c.design.names,
        "held_parameters": c.held,
        "joint_span": {j: {"value": float(math.degrees(s) if r else s * 1e3), "unit": "deg" if r else "mm"}
                       for j, s, r in zip(model.joint_names, span, revolute)},
        "prediction": {**pred, "assumes": c.assumes, "sigma_px": c.sigma_px},
        "view_checked": c.camera is not None,
    }
    dropped = {why: f"{k} of {c.total} candidates" for why, k in c.dropped.items()}
    return PlannedStations(plan, "kinematics", c.camera, c.target, None, dropped, robot=model.name, details=details)
