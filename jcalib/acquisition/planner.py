"""Station planners: flange poses for camera (view sets), hand-eye and TCP calibration.

Every planner works on the nominal :class:`~jcalib.acquisition.layout.CellLayout` (``jcalib plan``
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

Angles are spread evenly: group members alternate in sign with growing magnitude up to the amplitude.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jcalib.acquisition.layout import CellLayout, presentation_pose
from jcalib.io.plan import Plan, make_plan
from jcalib.geometry.se3 import exp_so3, invert, make_pose, rot_z
from jcalib.errors import BadInputError

KINDS = ("viewsets", "handeye", "tcp")
DEFAULT_STATIONS = {"viewsets": 14, "handeye": 19, "tcp": 13}
DEFAULT_AMPLITUDE_DEG = {"viewsets": 30.0, "handeye": 30.0, "tcp": 30.0}
#: ``tcp`` plans hold the tool tip this far in front of the base camera observing the tool, m (the
#: simulated cell's backlit tool zone is centred there too: :mod:`jcalib.app.simcell`).
TOOL_VIEW_DISTANCE_M = 0.35


@dataclass
class PlannedStations:
    """A plan and how it was made.

    Attributes:
        plan: the reachable stations, ids ``s000, s001, ...`` in order.
        kind: planner kind.  camera, target, tool: what it planned for (None when not used).
        dropped: candidate description -> why it was left out (unreachable, target not in view).
    """

    plan: Plan
    kind: str
    camera: str | None = None
    target: str | None = None
    tool: str | None = None
    dropped: dict[str, str] = field(default_factory=dict)

    def to_json(self, layout: CellLayout) -> dict:
        """The plan file (``jcalib.plan/1``) with the planner's settings as extra keys."""
        return {
            **self.plan.to_json(),
            "planner": {"kind": self.kind, "robot": layout.robot, "camera": self.camera, "target": self.target,
                        "tool": self.tool, "dropped": self.dropped},
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


def _turn_onto(v: np.ndarray, w: np.ndarray) -> np.ndarray:
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
) -> PlannedStations:
    """Plan stations of ``kind`` ("viewsets", "handeye" or "tcp") for the cell (see the module docstring).

    Args:
        layout: the nominal cell (:func:`jcalib.acquisition.layout.cell_layout`).
        kind: planner.
        num_stations: candidates to generate (default :data:`DEFAULT_STATIONS`); unreachable ones
            are dropped, so the plan may hold fewer.
        camera, target: the pair to plan for (default: the first camera with a target it can move
            relative to); tool: the tool for ``tcp`` (default: the cell's first tool).
        amplitude_deg: largest tilt / rotation, degrees.

    Raises:
        BadInputError: unknown kind or names, nothing to plan for, or fewer than half of the
            candidates (or under 3) reachable and in view: the nominal layout does not suit this robot.
    """
    if kind not in KINDS:
        raise BadInputError(f"--kind: expected one of {', '.join(KINDS)}, got {kind!r}")
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
        R0 = _turn_onto(R_h @ layout.tool_axis, w) @ R_h
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
