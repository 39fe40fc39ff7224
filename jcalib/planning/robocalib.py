"""RoboCalib station planning: hand-eye stations (algorithm 5, eqs 4.5–4.7) and camera view sets (eqs 4.1–4.4).

The RoboCalib thesis collects calibration data by moving the robot so that the camera keeps the
target in the middle of its image. Its text was not available to us (not in the reference corpora we
searched); this module implements the geometry as the issue describes it, and this docstring is our
reading. Everything is expressed through the camera pose relative to the target, ``T_target_cam``
(camera frame: OpenCV, z along the optical axis, x right, y down), and turned into flange poses at
the end. ``c`` is the *centre point* kept in the image (a point of the target, target frame, m;
default the target origin) and ``D`` the viewing distance (m).

Camera-calibration view sets (eqs 4.1–4.4), all looking at the printed side (the target's -z side,
camera z along target +z):

- (4.1) frontal view: ``T_target_cam = [I | c − D e_z]``: camera axes parallel to the target's,
  ``c`` on the optical axis at distance ``D``;
- (4.2, 4.3) four tilted views: the frontal view rotated about the line through ``c`` along the
  target's x axis by ``±α`` and along its y axis by ``±α``:
  ``T_target_cam = [R | c − D R e_z]`` with ``R = Rot(e_x, ±α)`` or ``Rot(e_y, ±α)``, so ``c`` stays
  on the optical axis at distance ``D`` (rotation about the target centre);
- world-origin view: ``[I | o − D e_z]`` with ``o = 0`` the target (world) origin at the image centre;
- (4.4) height poses: ``[Rot(e_z, ψ) | c − s D e_z]`` for heights ``s D`` (``s`` in ``heights``) and
  rolls ``ψ`` about the optical axis (``rolls_deg``): depth of field and focal length against
  distortion.

Hand-eye stations (algorithm 5, eqs 4.5–4.7): from a start view (the frontal view, or the camera
pose of a given start flange pose), for each camera axis ``a`` in Z, Y, X and each angle ``θ``:

- (4.5) rotate the camera about its own axis ``a`` at its centre: ``T_c ← T_c0 · [Rot(e_a, θ) | 0]``;
- (4.6) the centre point in the rotated camera: ``p = T_c⁻¹ c`` (it has left the optical axis
  unless ``a = Z``);
- (4.7) re-centre: translate the camera in its own frame so ``c`` is back on the optical axis at
  distance ``D``: ``T_c ← T_c · [I | p − D e_z]``.

Re-centring does not change the camera's orientation, so the camera motion from the start view to
each station is a rotation by exactly ``θ`` about the camera's own axis ``a``; large rotations about
three non-parallel axes make hand-eye rotation and translation observable. (The result equals a
rotation about the axis through ``c`` parallel to ``a``.)

Reachability: every station becomes ``T_base_flange`` (eye-in-hand:
``T_base_target · T_target_cam · T_flange_cam⁻¹``; eye-to-hand, where the robot carries the target in
front of a fixed camera: ``T_base_cam · T_target_cam⁻¹ · T_flange_target⁻¹``), solved by inverse
kinematics of the robot (:func:`jcalib.geometry.kinematics.inverse_kinematics`, joint limits
enforced) in one batched call. An unreachable rotation is retried at ``shrink`` fractions of its angle
(``adjusted``), then dropped (``rejected``, with the reason); a view set view that is not reachable is
dropped. With intrinsics, views whose target points leave the image (pinhole, no distortion) are
dropped too. Lengths in metres, angles in the names' unit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from jcalib.geometry.se3 import check_pose, invert
from jcalib.geometry.views import (
    frontal_view,
    height_view,
    origin_view,
    recentre,
    rotate_camera,
    tilted_view,
)
from jcalib.errors import BadInputError

__all__ = [
    "RoboCalibPlan",
    "RoboCalibStation",
    "handeye_stations",
    "viewset_stations",
]

# ------------------------------------------------------------------------------------ results


@dataclass(frozen=True)
class RoboCalibStation:
    """One planned station.

    Attributes:
        id: ``s000``, ``s001``, ... in plan order.
        kind: ``"start"``, ``"rotation"`` (hand-eye), ``"frontal"``, ``"tilt"``, ``"origin"``, ``"height"``.
        description: e.g. ``"camera about its Y by -30 deg"``.
        axis: ``"X"``, ``"Y"``, ``"Z"`` (camera axis for rotations, target axis for tilts) or None.
        angle_deg: planned rotation / tilt / roll (deg); 0 for the rest.
        used_angle_deg: the angle actually used (smaller when adjusted for reach).
        T_target_cam: (4, 4) the camera pose relative to the target, m.
        T_base_flange: (4, 4) the flange pose, m.
        joints_rad: (n,) inverse-kinematics solution within the joint limits, rad.
    """

    id: str
    kind: str
    description: str
    axis: str | None
    angle_deg: float
    used_angle_deg: float
    T_target_cam: np.ndarray
    T_base_flange: np.ndarray
    joints_rad: np.ndarray

    @property
    def adjusted(self) -> bool:
        return self.used_angle_deg != self.angle_deg


@dataclass(frozen=True)
class RoboCalibPlan:
    """Reachable stations of one planner run and what happened to the others.

    Attributes:
        kind: ``"handeye"`` or ``"viewsets"``.
        mode: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        robot: the robot's name.
        centre: (3,) the point kept in the image, target frame, m.  distance_m: viewing distance D.
        stations: the reachable stations in order.
        adjusted: description -> "angle reduced from A to B deg (reason)".
        rejected: description -> reason it was dropped.
    """

    kind: str
    mode: str
    robot: str
    centre: np.ndarray
    distance_m: float
    stations: tuple[RoboCalibStation, ...]
    adjusted: dict[str, str] = field(default_factory=dict)
    rejected: dict[str, str] = field(default_factory=dict)

    @property
    def T_base_flange(self) -> np.ndarray:
        """(N, 4, 4) flange poses of the stations, m."""
        return np.stack([s.T_base_flange for s in self.stations])

    @property
    def joints_rad(self) -> np.ndarray:
        """(N, n) joint solutions, rad."""
        return np.stack([s.joints_rad for s in self.stations])

    def to_plan(self):
        """A :class:`jcalib.io.plan.Plan` (``jcalib.plan/1``) of the stations, ids kept."""
        from jcalib.io.plan import make_plan

        return make_plan(list(self.T_base_flange), [s.id for s in self.stations])

    def __len__(self) -> int:
        return len(self.stations)


# ------------------------------------------------------------------------------------ reachability


@dataclass
class _Candidate:
    kind: str
    description: str
    axis: str | None
    angle_deg: float
    views: list[tuple[float, np.ndarray]]  # (angle_deg, T_target_cam) in order of preference


def _resolve_robot(robot):
    from jcalib.geometry.kinematics import DHRobot
    from jcalib.geometry.robots import robot_preset

    if isinstance(robot, str):
        return robot_preset(robot)
    if not isinstance(robot, DHRobot):
        raise BadInputError(f"robot: expected a preset name or a DHRobot, got {type(robot).__name__}")
    return robot


def _reach(robot, poses: list[np.ndarray], q_reference) -> tuple[np.ndarray, np.ndarray]:
    """Batched IK (padded to a multiple of 16 so plans of similar size share one compilation)."""
    from jcalib.geometry.kinematics import inverse_kinematics, outside_joint_limits

    n = len(poses)
    padded = np.stack(list(poses) + [poses[0]] * ((-n) % 16))
    res = inverse_kinematics(robot, padded, q_reference, position_tolerance_m=1e-6, rotation_tolerance_rad=1e-6)
    q = np.asarray(res.q)[:n]
    ok = np.asarray(res.success)[:n] & ~np.any(np.asarray(outside_joint_limits(robot, q)), axis=-1)
    return ok, q


def _in_image(T_target_cam: np.ndarray, K: np.ndarray, image_size, points: np.ndarray, margin_px: float = 2.0) -> bool:
    T = invert(T_target_cam)
    p = points @ T[:3, :3].T + T[:3, 3]
    if np.any(p[:, 2] <= 0.0):
        return False
    uv = (p[:, :2] / p[:, 2:3]) @ K[:2, :2].T + K[:2, 2]
    w, h = image_size
    return bool(np.all((uv >= margin_px) & (uv <= np.array([w - 1 - margin_px, h - 1 - margin_px]))))


def _check_mode_poses(mode, T_base_target, T_flange_cam, T_base_cam, T_flange_target):
    if mode == "eye_in_hand":
        if T_base_target is None or T_flange_cam is None:
            raise BadInputError("mode 'eye_in_hand': expected T_base_target and T_flange_cam (4x4, m), got None")
        A, Bm = check_pose(T_base_target, "T_base_target"), check_pose(T_flange_cam, "T_flange_cam")
        return lambda T_tc: A @ T_tc @ invert(Bm)
    if mode == "eye_to_hand":
        if T_base_cam is None or T_flange_target is None:
            raise BadInputError("mode 'eye_to_hand': expected T_base_cam and T_flange_target (4x4, m), got None")
        A, Bm = check_pose(T_base_cam, "T_base_cam"), check_pose(T_flange_target, "T_flange_target")
        return lambda T_tc: A @ invert(T_tc) @ invert(Bm)
    raise BadInputError(f"mode: expected 'eye_in_hand' or 'eye_to_hand', got {mode!r}")


def _plan(kind, mode, robot, centre, D, candidates: list[_Candidate], to_flange, q_reference, camera, target_points):
    robot = _resolve_robot(robot)
    K = None
    if camera is not None:
        K = np.asarray(camera[0], dtype=np.float64)
        size = tuple(int(v) for v in camera[1])
        if K.shape != (3, 3) or len(size) != 2:
            raise BadInputError(f"camera: expected (K (3, 3), (width, height)), got K shape {K.shape}, size {size}")
        pts = np.asarray(target_points if target_points is not None else centre[None], dtype=np.float64).reshape(-1, 3)
    chosen: list[tuple[_Candidate, float, np.ndarray, np.ndarray, np.ndarray]] = []
    adjusted: dict[str, str] = {}
    rejected: dict[str, str] = {}
    first_why: dict[str, str] = {}  # why the full angle failed, for the adjusted / rejected notes
    pending = [(c, 0) for c in candidates]
    while pending:
        poses = [to_flange(c.views[k][1]) for c, k in pending]
        ok, q = _reach(robot, poses, q_reference)
        retry = []
        for (c, k), good, qi, T_bf in zip(pending, ok, q, poses, strict=True):
            angle, T_tc = c.views[k]
            why = None
            if not good:
                why = f"outside the reach or joint limits of {robot.name}"
            elif K is not None and not _in_image(T_tc, K, size, pts):
                why = "target not entirely in the image"
            if why is None:
                chosen.append((c, angle, T_tc, T_bf, qi))
                if k > 0:
                    adjusted[c.description] = (
                        f"angle reduced from {c.angle_deg:+.1f} to {angle:+.1f} deg ({first_why[c.description]})"
                    )
                continue
            first_why.setdefault(c.description, why)
            if k + 1 < len(c.views):
                retry.append((c, k + 1))
            elif k == 0:
                rejected[c.description] = why
            else:
                rejected[c.description] = f"{first_why[c.description]}; at {angle:+.1f} deg: {why}"
        pending = retry
    order = {id(c): i for i, c in enumerate(candidates)}
    chosen.sort(key=lambda item: order[id(item[0])])
    stations = tuple(
        RoboCalibStation(f"s{i:03d}", c.kind, c.description, c.axis, c.angle_deg, angle, T_tc, T_bf, qi)
        for i, (c, angle, T_tc, T_bf, qi) in enumerate(chosen)
    )
    return RoboCalibPlan(kind, mode, robot.name, np.asarray(centre, dtype=np.float64), float(D), stations, adjusted, rejected)


def _check_common(distance_m, centre, shrink):
    D = float(distance_m)
    if not np.isfinite(D) or D <= 0.0:
        raise BadInputError(f"distance_m: expected a positive distance in metres, got {distance_m!r}")
    c = np.asarray(centre, dtype=np.float64).reshape(-1)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise BadInputError(f"centre: expected a finite point (3,) in the target frame, m, got {centre!r}")
    fr = tuple(float(s) for s in shrink)
    if not fr or fr[0] != 1.0 or any(not 0.0 < s <= 1.0 for s in fr):
        raise BadInputError(f"shrink: expected fractions in (0, 1] starting with 1.0, got {shrink!r}")
    return D, c, fr


# ------------------------------------------------------------------------------------ planners


def handeye_stations(
    robot,
    *,
    distance_m: float,
    mode: str = "eye_in_hand",
    T_base_target=None,
    T_flange_cam=None,
    T_base_cam=None,
    T_flange_target=None,
    centre=(0.0, 0.0, 0.0),
    angles_z_deg: Sequence[float] = (-90.0, -45.0, 45.0, 90.0),
    angles_y_deg: Sequence[float] = (-30.0, -15.0, 15.0, 30.0),
    angles_x_deg: Sequence[float] = (-30.0, -15.0, 15.0, 30.0),
    start_T_base_flange=None,
    shrink: Sequence[float] = (1.0, 0.75, 0.5),
    q_reference=None,
    camera: tuple | None = None,
    target_points=None,
) -> RoboCalibPlan:
    """Hand-eye stations of RoboCalib's algorithm 5: camera rotations about its Z, Y, X axes, re-centred.

    Args:
        robot: a preset name of :mod:`jcalib.geometry.robots` or a :class:`~jcalib.geometry.kinematics.DHRobot`.
        distance_m: viewing distance ``D`` of ``centre`` (m).
        mode: ``"eye_in_hand"`` (give ``T_base_target``, ``T_flange_cam``) or ``"eye_to_hand"``
            (give ``T_base_cam``, ``T_flange_target``): nominal poses (4, 4), m.
        centre: (3,) the target point kept in the image centre, target frame, m.
        angles_z_deg, angles_y_deg, angles_x_deg: rotations about the camera's Z (optical), Y and X
            axes from the start view, degrees (in this order: Z group, Y group, X group).
        start_T_base_flange: (4, 4) start flange pose (e.g. jogged by the operator); its view is
            re-centred first (eqs 4.6–4.7) and is station ``s000``. Default: the frontal view (4.1).
        shrink: fractions of an unreachable angle tried in turn (first 1.0).
        q_reference: (n,) joints (rad) the IK prefers (default: the middle of the limits).
        camera: optional ``(K (3, 3) px, (width, height))``: drop stations where ``target_points``
            (default: ``centre``) leave the image (pinhole, distortion ignored).
        target_points: (M, 3) target points (target frame, m) for that check.

    Returns:
        :class:`RoboCalibPlan` (kind ``"handeye"``); the start station first, then the reachable
        rotations in order.

    Raises:
        BadInputError: missing or malformed poses, unknown mode, bad distance / angles / shrink, or
            an unreachable start station.
    """
    D, c, fractions = _check_common(distance_m, centre, shrink)
    to_flange = _check_mode_poses(mode, T_base_target, T_flange_cam, T_base_cam, T_flange_target)
    if start_T_base_flange is None:
        T0 = frontal_view(c, D)
        start_desc = "start: frontal view"
    else:
        T_bf0 = check_pose(start_T_base_flange, "start_T_base_flange")
        # T_target_cam of the start flange pose, inverting the map of the mode
        if mode == "eye_in_hand":
            T_tc = invert(T_base_target) @ T_bf0 @ np.asarray(T_flange_cam, dtype=np.float64)
        else:
            T_tc = invert(invert(T_base_cam) @ T_bf0 @ np.asarray(T_flange_target, dtype=np.float64))
        T0 = recentre(T_tc, c, D)
        start_desc = "start: given pose, re-centred"
    cands = [_Candidate("start", start_desc, None, 0.0, [(0.0, T0)])]
    for axis, angles in (("Z", angles_z_deg), ("Y", angles_y_deg), ("X", angles_x_deg)):
        for a in angles:
            a = float(a)
            if not np.isfinite(a) or a == 0.0 or abs(a) > 180.0:
                raise BadInputError(f"angles_{axis.lower()}_deg: expected non-zero angles within +-180 deg, got {a!r}")
            views = [(f * a, recentre(rotate_camera(T0, axis, np.radians(f * a)), c, D)) for f in fractions]
            cands.append(_Candidate("rotation", f"camera about its {axis} by {a:+.0f} deg", axis, a, views))
    plan = _plan("handeye", mode, robot, c, D, cands, to_flange, q_reference, camera, target_points)
    if not plan.stations or plan.stations[0].kind != "start":
        raise BadInputError(
            f"the start station is unreachable for {plan.robot} ({plan.rejected.get(start_desc, '?')}): give another "
            "start_T_base_flange, distance_m or target / camera poses"
        )
    return plan


def viewset_stations(
    robot,
    *,
    distance_m: float,
    mode: str = "eye_in_hand",
    T_base_target=None,
    T_flange_cam=None,
    T_base_cam=None,
    T_flange_target=None,
    centre=(0.0, 0.0, 0.0),
    tilt_deg: float = 30.0,
    heights: Sequence[float] = (0.8, 1.25),
    rolls_deg: Sequence[float] = (0.0, 45.0),
    shrink: Sequence[float] = (1.0, 0.75, 0.5),
    q_reference=None,
    camera: tuple | None = None,
    target_points=None,
) -> RoboCalibPlan:
    """Camera-calibration view set made by robot motion (eqs 4.1–4.4).

    Views in order: frontal (4.1); tilted by ``±tilt_deg`` about the target's x and y axes through
    ``centre`` (4.2, 4.3); the world-origin view; height poses at ``h · D`` for ``h`` in ``heights``,
    each with every roll in ``rolls_deg`` about the optical axis (4.4). Tilts that cannot be reached
    are retried at the ``shrink`` fractions; other views are dropped when unreachable or (with
    ``camera``) when the target leaves the image.

    Args: as :func:`handeye_stations`; ``tilt_deg`` the tilt angle (deg), ``heights`` distance scale
        factors, ``rolls_deg`` rolls about the optical axis (deg).

    Returns:
        :class:`RoboCalibPlan` (kind ``"viewsets"``).
    """
    D, c, fractions = _check_common(distance_m, centre, shrink)
    to_flange = _check_mode_poses(mode, T_base_target, T_flange_cam, T_base_cam, T_flange_target)
    t = float(tilt_deg)
    if not 0.0 < t < 90.0:
        raise BadInputError(f"tilt_deg: expected 0 < tilt < 90 deg, got {tilt_deg!r}")
    if not heights or any(not 0.0 < float(h) <= 10.0 for h in heights):
        raise BadInputError(f"heights: expected scale factors in (0, 10], got {heights!r}")
    cands = [_Candidate("frontal", "frontal view", None, 0.0, [(0.0, frontal_view(c, D))])]
    for axis in ("X", "Y"):
        for s in (1.0, -1.0):
            a = s * t
            views = [(f * a, tilted_view(c, D, axis, np.radians(f * a))) for f in fractions]
            cands.append(_Candidate("tilt", f"tilted {a:+.0f} deg about target {axis.lower()}", axis, a, views))
    cands.append(_Candidate("origin", "world-origin view", None, 0.0, [(0.0, origin_view(D))]))
    for h in heights:
        for r in rolls_deg:
            cands.append(_Candidate("height", f"height {float(h):.2f} D, roll {float(r):+.0f} deg", "Z", float(r),
                                    [(float(r), height_view(c, D, float(h), np.radians(float(r))))]))  # fmt: skip
    return _plan("viewsets", mode, robot, c, D, cands, to_flange, q_reference, camera, target_points)
