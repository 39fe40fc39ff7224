"""A cell spec and its observations as a graph: things, what holds them, and what saw what.

Every camera, target and tool hangs on a *holder*:

- ``None``: fixed in the cell's frame (``mount: base`` with one robot, ``mount: world`` with
  several, and in a cell without robots every camera: the rig, whose frame is the reference camera);
- a robot name: on that robot's flange (``mount: flange``); its pose at station ``i`` is the robot's
  measured flange pose (with or without a pose-error model), times the robot's base with several
  robots;
- :data:`FREE`: the thing moves freely (``mount: free`` targets): one unknown pose per station.

Observations are grouped by what they connect: target corners per (camera, target) *pair*, tool tips
(and points on the imaged tool axis) per (camera, tool), contacts per (tool, cell point), 6-DOF pose
measurements per (camera, target), 3-D tool-tip positions per (point sensor, tool). :func:`gather`
validates them against the cell and keeps the stations that observe something.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import kinematic_models
from jcalib.problems.kinematics import Selection, forward_batch, repeatability_sqrt_info, select_parameters
from jcalib.problems.joint_check import check_joint_units, check_joints_against_poses
from jcalib.io.cell import CellSpec
from jcalib.io.observations import Observations

#: The holder of a freely moving thing (one unknown pose per station).
FREE = "~free"

#: Fewest target points per view: a homography has 8 degrees of freedom (4 points), and fewer
#: than 6 points leave a view pose with almost no redundancy.
MIN_POINTS_PER_VIEW = 6
#: ... but 4 points (planar PnP's minimum) make a view where nothing more can be had or asked: a
#: target of fewer than 6 points (a single AprilTag), or a camera whose intrinsics are given and held
#: (``fx, fy, cx, cy`` in ``fix``), whose views only have to place the target.
MIN_POINTS_PER_POSE = 4


def min_points_per_view(cam, num_target_points: int) -> int:
    """Fewest points a view of a target with ``num_target_points`` points by camera ``cam`` (a
    :class:`jcalib.io.cell.CameraSpec`) needs (:data:`MIN_POINTS_PER_VIEW`, :data:`MIN_POINTS_PER_POSE`)."""
    held = cam.K is not None and {"fx", "fy", "cx", "cy"} <= set(cam.fix)
    return MIN_POINTS_PER_POSE if num_target_points < MIN_POINTS_PER_VIEW or held else MIN_POINTS_PER_VIEW


@dataclass
class Pair:
    """Target corners that one camera saw of one target: one view per station."""

    camera: str
    target: str
    views: list[int] = field(default_factory=list)  # station index per view
    points: list[np.ndarray] = field(default_factory=list)  # (n, 3) per view, target frame, m
    pixels: list[np.ndarray] = field(default_factory=list)  # (n, 2) per view
    point_index: list[np.ndarray] = field(default_factory=list)
    images: int = 1  # images averaged into each view (> 1: a static scene, see _static_view)


@dataclass
class Tips:
    """Tool-tip pixels that one camera saw of one tool (and points on its imaged axis)."""

    camera: str
    tool: str
    stations: list[int] = field(default_factory=list)
    pixels: list[np.ndarray] = field(default_factory=list)  # (2,) each
    axis: list[np.ndarray] = field(default_factory=list)  # (L, 2) each (L may be 0)


@dataclass
class Contacts:
    """Stations where the tip of ``tool`` touches the cell point ``point``."""

    tool: str
    point: str
    stations: list[int] = field(default_factory=list)


@dataclass
class PoseMeasurements:
    """6-DOF poses of a target measured by a camera (or any sensor): ``T_cam_target`` per station."""

    camera: str
    target: str
    stations: list[int] = field(default_factory=list)
    T_cam_target: list[np.ndarray] = field(default_factory=list)


@dataclass
class Positions:
    """3-D positions of a tool's tip measured by a point sensor: ``p_sensor_tool`` per station."""

    sensor: str
    tool: str
    stations: list[int] = field(default_factory=list)
    p_sensor_tool: list[np.ndarray] = field(default_factory=list)


class Graph:
    """The things of a cell, their holders, the used stations and the observation groups.

    Attributes:
        cell, obs: the inputs.
        frame: the cell's frame: ``"base"`` (one robot), ``"world"`` (several robots) or, in a cell
            without robots, the reference camera's id (the rig frame).
        multi: several robots (``robots:`` with two or more).
        robot_names: every robot of the cell (one unnamed robot is ``"robot"``).
        station_ids: the used stations, file order.
        flange: robot -> ``(N, 4, 4)`` measured flange poses per used station (identity where the
            station has none; the nominal kinematics at the joints where the station gives only joints);
            ``need``: robot -> ``(N,)`` bool, stations whose observations involve it; ``joints``: robot ->
            ``(N, n)`` joint values (rad, m) of the robots whose kinematics is calibrated; ``kinematics``:
            robot -> which of its kinematic parameters are estimated (the identifiable subset,
            :func:`jcalib.problems.kinematics.select_parameters`, which also refuses motion that cannot
            determine them); ``kinematic_noise``: robot -> ``(S (6, 6), source)`` the square-root
            information of one of its flange poses and where its σ came from.
        pairs, tips, contacts, poses, positions: the observation groups, keyed by the two names they connect.
    """

    def __init__(self, cell: CellSpec, obs: Observations, reference_camera: str | None = None):
        self.cell, self.obs = cell, obs
        self.multi = cell.multi_robot
        self.has_robot = cell.robot is not None or bool(cell.robots)
        if self.multi:
            self.robot_names = list(cell.robots)
            self.robot_specs = dict(cell.robots)
        elif self.has_robot:
            name = (cell.robot.name if cell.robot is not None and cell.robot.name else None) or "robot"
            self.robot_names = [name]
            self.robot_specs = {name: cell.robot}
        else:
            self.robot_names, self.robot_specs = [], {}
        self.reference_camera = None
        if not self.has_robot:
            self.reference_camera = self._reference(reference_camera)
            self.frame = self.reference_camera or "base"
        else:
            self.frame = cell.frame
        self.pairs: dict[tuple[str, str], Pair] = {}
        self.tips: dict[tuple[str, str], Tips] = {}
        self.contacts: dict[tuple[str, str], Contacts] = {}
        self.poses: dict[tuple[str, str], PoseMeasurements] = {}
        self.positions: dict[tuple[str, str], Positions] = {}
        self.station_ids: list[str] = []
        self.flange: dict[str, np.ndarray] = {}
        self.need: dict[str, np.ndarray] = {}
        self.joints: dict[str, np.ndarray] = {}
        self.kinematics: dict[str, Selection] = {}
        self.kinematic_noise: dict[str, tuple[np.ndarray, str]] = {}
        self._gather()

    # ------------------------------------------------------------------------- holders and names

    def _reference(self, name: str | None) -> str | None:
        cams = list(self.cell.cameras)
        if name is not None:
            if name not in self.cell.cameras:
                raise BadInputError(f"reference_camera: got {name!r}, expected one of the cell's cameras "
                                    f"({', '.join(cams) or 'none'})")
            return name
        return cams[0] if cams else None

    def holder(self, spec) -> str | None:
        """``None`` (fixed in the cell frame), a robot name (on its flange) or :data:`FREE`."""
        mount = getattr(spec, "mount", "flange")
        if mount == "flange":
            return spec.robot if self.multi else self.robot_names[0]
        if mount == "free" and not hasattr(spec, "observed_by"):
            if not self.has_robot and spec.name in self.cell.cameras:
                return None  # cameras of a cell without robots form the rig
            return FREE
        return None

    def mount_name(self, spec) -> str | None:
        """The name of a thing's pose on its holder (``T_<frame>_<x>``, ``T_flange_<x>``), or None for
        a free thing (its per-station poses are :meth:`free_name`)."""
        h = self.holder(spec)
        if h == FREE:
            return None
        if h is None:
            return f"T_{self.frame}_{spec.name}"
        return f"T_flange_{spec.name}"

    def free_name(self, name: str) -> str:
        """The per-station pose variable of a free thing: ``T_<frame>_<name>``."""
        return f"T_{self.frame}_{name}"

    def flange_name(self, robot: str) -> str:
        return f"T_{robot}_flange" if self.multi else "T_base_flange"

    def base_name(self, robot: str) -> str | None:
        return f"T_world_{robot}" if self.multi else None

    def label(self, robot: str) -> str:
        return f"robot '{robot}'" if self.multi or robot != "robot" else "the robot"

    def has_noise(self, robot: str) -> bool:
        s = self.robot_specs[robot]
        return s is not None and s.pose_noise_translation_m is not None

    def gauge(self) -> tuple[str | None, list[str]]:
        """``(robot whose base is the world frame, or None; the held world poses that fix it)``.

        Anchors are held world poses: a robot ``base`` listed in ``fixed`` (``T_world_<r>`` or the
        robot's name), a ``mount: world`` camera or target with a ``pose`` listed in ``fixed``. With an
        anchor every robot base not held is unknown; without, the first robot's base is the world
        frame (held at its ``base``, else identity)."""
        cell = self.cell
        if not self.multi:
            return (self.robot_names[0] if self.robot_names else None), []
        anchors = [f"T_world_{r}" for r, s in self.robot_specs.items()
                   if s.base is not None and (r in cell.fixed or f"T_world_{r}" in cell.fixed)]
        for spec in list(cell.cameras.values()) + list(cell.targets.values()):
            if spec.mount == "world" and spec.pose is not None and (spec.name in cell.fixed
                                                                    or f"T_world_{spec.name}" in cell.fixed):
                anchors.append(f"T_world_{spec.name}")
        return (None if anchors else self.robot_names[0]), anchors

    def held_base(self, robot: str) -> bool:
        gauge, _ = self.gauge()
        s = self.robot_specs[robot]
        listed = robot in self.cell.fixed or f"T_world_{robot}" in self.cell.fixed
        return robot == gauge or (s.base is not None and listed)

    def station_pose(self, station, robot: str) -> np.ndarray | None:
        """The measured flange pose of ``robot`` at ``station``: the one the station gives, else the
        robot's nominal kinematics at the station's joint values, else None."""
        T = station.flange_poses.get(robot) if self.multi or station.flange_poses else station.T_base_flange
        if T is None:
            q = self.station_joints(station, robot)
            kin = self.robot_specs[robot].kinematics if robot in self.robot_specs else None
            if q is not None and kin is not None:
                T = np.asarray(forward_batch(kin, kin.nominal, q[None]), np.float64)[0]
        return T

    def station_joints(self, station, robot: str) -> np.ndarray | None:
        """``(n,)`` joint values of ``robot`` at ``station`` in rad (m for prismatic axes), or None.

        Raises:
            BadInputError: the count does not match the robot's kinematics.
        """
        q = station.joints_deg
        if isinstance(q, dict):
            q = q.get(robot)
        elif q is not None and self.multi:
            raise BadInputError(f"{self.obs.source}: station '{station.id}': joints_deg is a list, but the cell has "
                                f"several robots ({', '.join(self.robot_names)}); give joints_deg: {{robot: [...]}}")
        kin = self.robot_specs[robot].kinematics if robot in self.robot_specs else None
        if q is None or kin is None:
            return None
        try:
            return np.asarray(kinematic_models.joints_from_controller(kin, q), np.float64)
        except BadInputError as e:
            raise BadInputError(f"{self.obs.source}: station '{station.id}': joints_deg: {e}") from None

    @property
    def kinematic_robots(self) -> list[str]:
        """The used robots whose kinematic parameters are unknowns (``calibrate_kinematics``)."""
        return [r for r in self.used_robots if r in self.kinematics]

    # ------------------------------------------------------------------------- gather

    def _gather(self) -> None:
        cell, obs = self.cell, self.obs
        src = obs.source
        for c in cell.cameras.values():
            if c.name not in obs.cameras and c.name not in cell.sensors:  # (a pose sensor has no image)
                raise BadInputError(f"{src}: camera '{c.name}' of the cell has no image size in the observations")
            if self.has_robot and c.mount == "free":
                raise BadInputError(
                    f"{cell.source}: camera '{c.name}' has mount: free in a robot cell; a camera is on the flange "
                    f"(mount: flange) or fixed in the cell (mount: {self.frame}); free-moving targets are mount: free")
        needs, stations = [], []
        for station in obs.stations:
            k = len(self.station_ids)
            need: set[str | None] = set()
            used = False
            for c in station.contacts:
                if c.tool not in cell.tools:
                    raise BadInputError(f"{src}: station '{station.id}': contact of tool '{c.tool}', which is not in "
                                        f"the cell's tools ({', '.join(cell.tools) or 'none'})")
                if c.point not in cell.points:
                    raise BadInputError(f"{src}: station '{station.id}': contact with point '{c.point}', which is not "
                                        f"in the cell's points ({', '.join(cell.points) or 'none'})")
                self.contacts.setdefault((c.tool, c.point), Contacts(c.tool, c.point)).stations.append(k)
                need.add(self.holder(cell.tools[c.tool]))
                used = True
            for det in station.detections:
                if det.camera not in cell.cameras:
                    continue
                cam = cell.cameras[det.camera]
                if det.tool is not None:
                    if det.tool not in cell.tools:
                        continue
                    tool = cell.tools[det.tool]
                    if self.holder(cam) == self.holder(tool):
                        raise BadInputError(
                            f"{src}: station '{station.id}': tool '{det.tool}' seen by camera '{det.camera}', which "
                            "is on the same flange: the tip does not move in that camera's image; tool tips are "
                            "used from cameras that do not move with the tool")
                    t = self.tips.setdefault((det.camera, det.tool), Tips(det.camera, det.tool))
                    t.stations.append(k)
                    t.pixels.append(det.pixels.reshape(2))
                    t.axis.append(np.asarray(getattr(det, "axis", None) if getattr(det, "axis", None) is not None
                                             else np.zeros((0, 2)), np.float64).reshape(-1, 2))
                    need |= {self.holder(cam), self.holder(tool)}
                    used = True
                elif det.target in cell.targets:
                    n = det.point_index.size
                    if det.target not in obs.targets:
                        raise BadInputError(f"{src}: the observations have no points for target '{det.target}'")
                    fewest = min_points_per_view(cam, len(obs.targets[det.target]))
                    if n < fewest:
                        held = "" if fewest < MIN_POINTS_PER_VIEW else (
                            f" ({MIN_POINTS_PER_POSE} with the camera's intrinsics given and held)")
                        raise BadInputError(
                            f"{src}: station '{station.id}', camera '{det.camera}': only {n} points of target "
                            f"'{det.target}'; a view needs at least {fewest}{held}. Drop the view or re-detect it")
                    p = self.pairs.setdefault((det.camera, det.target), Pair(det.camera, det.target))
                    if p.views and p.views[-1] == k:
                        continue  # one view per camera, target and station
                    p.views.append(k)
                    p.points.append(obs.targets[det.target][det.point_index])
                    p.pixels.append(det.pixels)
                    p.point_index.append(det.point_index)
                    need |= {self.holder(cam), self.holder(cell.targets[det.target])}
                    used = True
            for m in getattr(station, "poses", ()) or ():
                if m.camera not in cell.cameras or m.target not in cell.targets:
                    raise BadInputError(
                        f"{src}: station '{station.id}': a pose measurement of target '{m.target}' by '{m.camera}'; "
                        "both must be in the cell's cameras and targets")
                pm = self.poses.setdefault((m.camera, m.target), PoseMeasurements(m.camera, m.target))
                pm.stations.append(k)
                pm.T_cam_target.append(np.asarray(m.T_cam_target, np.float64))
                need |= {self.holder(cell.cameras[m.camera]), self.holder(cell.targets[m.target])}
                used = True
            for m in getattr(station, "positions", ()) or ():
                if m.sensor not in cell.sensors or m.tool not in cell.tools:
                    raise BadInputError(
                        f"{src}: station '{station.id}': a position of tool '{m.tool}' measured by '{m.sensor}'; the "
                        "sensor must be in the cell's sensors (kind: point) and the tool in its tools")
                ps = self.positions.setdefault((m.sensor, m.tool), Positions(m.sensor, m.tool))
                ps.stations.append(k)
                ps.p_sensor_tool.append(np.asarray(m.p_sensor_tool, np.float64).reshape(3))
                need |= {self.holder(cell.cameras[m.sensor]), self.holder(cell.tools[m.tool])}
                used = True
            if not used:
                continue
            self._check_station_poses(station, need)
            self.station_ids.append(station.id)
            needs.append(need)
            stations.append(station)
        if not self.station_ids:
            raise BadInputError(f"{src}: no detection of the cell's targets or tools, no contact and no pose "
                                "measurement in any station")
        n = len(self.station_ids)
        for r in self.robot_names:
            mask = np.array([r in nd for nd in needs]) if self.multi else np.ones(n, bool)
            T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
            for k, station in enumerate(stations):
                if mask[k]:
                    T[k] = np.asarray(self.station_pose(station, r), np.float64)
            self.flange[r], self.need[r] = T, mask
            self._check_recorded_joints(r, stations, mask)
            if self.robot_specs[r].calibrate_kinematics:
                q = [self.station_joints(station, r) if mask[k] else None for k, station in enumerate(stations)]
                missing = [self.station_ids[k] for k in range(n) if mask[k] and q[k] is None]
                if missing:
                    raise BadInputError(
                        f"{src}: station(s) {', '.join(repr(m) for m in missing[:5])} have no joints_deg of "
                        f"{self.label(r)}; calibrating its kinematics needs the joint values of every station "
                        "(sessions record them; add joints_deg or remove calibrate_kinematics)")
                nj = self.robot_specs[r].kinematics.num_joints
                self.joints[r] = np.stack([qk if qk is not None else np.zeros(nj) for qk in q])
                spec = self.robot_specs[r]
                S, how = repeatability_sqrt_info(spec)
                self.kinematics[r] = select_parameters(spec.kinematics, spec.calibrate_kinematics,
                                                       self.joints[r][mask], S, self.label(r))
                self.kinematic_noise[r] = (S, how)
        for key, p in list(self.pairs.items()):
            hc, ht = self.holder(cell.cameras[p.camera]), self.holder(cell.targets[p.target])
            if hc == ht and hc != FREE and len(p.views) > 1:
                self.pairs[key] = _static_view(p)

    def _check_recorded_joints(self, robot: str, stations: list, mask: np.ndarray) -> None:
        """Stations that record both joints and a flange pose of ``robot`` agree with its nominal kinematics
        (:mod:`jcalib.problems.joint_check`); a kinematic calibration's joints are not radians."""
        kin = self.robot_specs[robot].kinematics if robot in self.robot_specs else None
        if kin is None:
            return
        calibrated = bool(self.robot_specs[robot].calibrate_kinematics)
        ids, qs, Ts = [], [], []
        for k, station in enumerate(stations):
            given = station.flange_poses.get(robot) if self.multi or station.flange_poses else station.T_base_flange
            try:
                q = self.station_joints(station, robot) if mask[k] else None
            except BadInputError:
                if calibrated:  # the joints are used: their error stands
                    raise
                q = None  # joints the solve does not use (e.g. another axis count): not checked here
            if q is not None:
                ids.append(self.station_ids[k]), qs.append(q), Ts.append(given)
        have_pose = [i for i, T in enumerate(Ts) if T is not None]
        check_joints_against_poses(kin, self.label(robot), [ids[i] for i in have_pose],
                                   np.reshape([qs[i] for i in have_pose], (len(have_pose), kin.num_joints)),
                                   np.reshape([Ts[i] for i in have_pose], (len(have_pose), 4, 4)), self.obs.source)
        if calibrated and ids:
            check_joint_units(kin, self.label(robot), ids, np.stack(qs), self.obs.source)

    def _check_station_poses(self, station, need: set) -> None:
        src = self.obs.source
        unknown = sorted(set(station.flange_poses) - set(self.robot_names))
        if unknown:
            raise BadInputError(
                f"{src}: station '{station.id}': flange_poses names robot(s) {unknown}, which the cell does not "
                f"have (robots: {', '.join(self.robot_names) or 'none'}); fix the robot names or the cell's robots")
        if not self.has_robot:
            return
        if self.multi:
            if station.T_base_flange is not None:
                raise BadInputError(
                    f"{src}: station '{station.id}' gives T_base_flange, but the cell has several robots "
                    f"({', '.join(self.robot_names)}): give each robot's flange pose in flange_poses: {{robot: [[4x4]]}}")
            for r in sorted(x for x in need if x not in (None, FREE)):
                if self.station_pose(station, r) is None:
                    raise BadInputError(
                        f"{src}: station '{station.id}': the detections or contacts involve robot '{r}' (a camera, "
                        f"target or tool on its flange), but the station has no flange pose of '{r}'; add "
                        f"flange_poses: {{{r}: [[4x4]]}} (T_{r}_flange, m) or drop those detections")
        elif self.station_pose(station, self.robot_names[0]) is None:
            raise BadInputError(
                f"{src}: station '{station.id}' has no T_base_flange; a robot cell needs the flange pose of every "
                "station (or its joints_deg and the robot's kinematics: in the cell)")

    # ------------------------------------------------------------------------- queries

    @property
    def used_robots(self) -> list[str]:
        return [r for r in self.robot_names if self.need[r].any()]

    def moving(self, camera: str, target: str) -> bool:
        """Whether the target moves in the camera's image from station to station."""
        hc = self.holder(self.cell.cameras[camera])
        ht = self.holder(self.cell.targets[target])
        return hc != ht or hc == FREE

    def free_things(self) -> list[str]:
        """Targets with one unknown pose per station."""
        return [t.name for t in self.cell.targets.values() if self.holder(t) == FREE]

    def check_views(self, camera: str) -> None:
        """Raise when a camera of a cell without robots sees no target (nothing determines it)."""
        if not any(c == camera for (c, _) in self.pairs) and not any(c == camera for (c, _) in self.tips) \
                and not any(c == camera for (c, _) in self.poses):
            raise NotObservableError(f"camera '{camera}' sees the target in no station: nothing determines its "
                                     "intrinsics", [f"{camera} intrinsics"])


def _static_view(p: Pair) -> Pair:
    """Repeated images of a static scene (camera and target on the same holder) as one view.

    They are not independent evidence about the geometry: the robot does not move one relative to
    the other, so only the sensor noise differs between the images (detection biases repeat). Each
    point seen in every image enters once, at its mean pixel; counting every image would shrink the
    reported σ of that camera's pose by the square root of the number of stations. How much the mean
    is better than one image (sensor noise averages out, detection biases do not) is the data's to say:
    these corners are their own residual kind (``corner_mean``, :mod:`jcalib.problems.refine`).
    """
    common = set(p.point_index[0].tolist())
    for idx in p.point_index[1:]:
        common &= set(idx.tolist())
    keep = np.array(sorted(common), dtype=p.point_index[0].dtype)
    if keep.size == 0:
        return Pair(p.camera, p.target, p.views[:1], p.points[:1], p.pixels[:1], p.point_index[:1])
    rows = []
    for idx, pix in zip(p.point_index, p.pixels):
        where = {int(v): i for i, v in enumerate(idx.tolist())}
        rows.append(np.asarray(pix, np.float64)[[where[int(v)] for v in keep]])
    first = {int(v): i for i, v in enumerate(p.point_index[0].tolist())}
    points = np.asarray(p.points[0])[[first[int(v)] for v in keep]]
    return Pair(p.camera, p.target, p.views[:1], [points], [np.mean(rows, axis=0)], [keep], images=len(rows))
