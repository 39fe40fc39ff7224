"""The whole cell as one joint least-squares problem: any mix of flange and fixed cameras, fixed and
flange targets, tools seen by fixed cameras and/or touching cell points, one robot or several (each with its
base in a world frame), each with a pose-error model.

Unknowns (names as in the result file):

- ``intrinsics:<cam>``: every camera's intrinsic vector (order ``model.param_names``; ``fix`` in
  the cell holds entries, ``aspect`` ties ``fy`` to ``fx``);
- ``T_flange_<cam>`` (camera ``mount: flange``) or ``T_base_<cam>`` (``mount: base``);
- ``T_base_<target>`` or ``T_flange_<target>``;
- ``T_flange_<tool>``: the TCP of each tool; only its translation (the tip in the flange frame) is
  observable from tip pixels, its rotation stays at identity (fixed, zero covariance);
- ``point:<name>``: each cell point (``points:`` in the spec, e.g. a pivot divot or a work-object
  reference) in the base frame, m; held at ``position`` when the spec gives one;
- ``T_base_flange``: the true flange pose of every station, ``T_meas_i · Exp(δ_i)`` with the robot
  pose-noise prior of the cell (``robot.pose_noise``), eliminated by Schur complement; exact
  (fixed) without ``pose_noise``.

Factors: every target corner seen by every camera,

    project_c( inv(T_base_cam_i) · T_base_target_i · p )  −  u          (pixels, σ = ``sigma_px``)

with ``T_base_cam_i = T_base_flange_i · T_flange_cam`` for a flange camera (``T_base_cam`` for a
fixed one) and likewise for the target; and every tool-tip pixel (observations
``{"camera": c, "tool": t, "pixel": [u, v]}``, camera fixed on the base),

    project_c( inv(T_base_cam) · T_base_flange_i · p_flange_tip )  −  u   (pixels, σ = ``tip_sigma_px``);

and every contact (station ``"contacts": [{"tool": t, "point": p}]``: the tip touches the point),

    T_base_flange_i · p_flange_tip  −  p_base                              (m, σ = ``contact_sigma_m``),

which covers pivot calibration, the robot 4-point TCP method and touched work-object points.
Corners and tip pixels beyond ``outlier_threshold`` a-posteriori σ of their own kind are rejected
and the problem re-solved. With a-posteriori noise, each residual kind (corners, tips, contacts) gets
its own variance factor and the robot pose prior keeps its stated σ (:func:`_variance_components`):
one common σ̂² would let the numerous, precise corners set the noise of the tips.

Everything is solved jointly by the engine (:func:`jcalib.solve.solve`), with covariances.

Start (closed forms, order chosen from the spec): intrinsics (the cell's ``intrinsics``, a prior
result's, else Zhang on the camera's target views), then the poses: known poses from the cell or
the prior, poses that follow from a known one through a camera–target pair (static pairs: one
relative pose; moving pairs: averaged per station), and a closed-form hand-eye solve
(:func:`jcalib.init.handeye.solve_hand_eye`) for a moving pair whose two poses are both unknown;
then each TCP from its contacts (pivot / 4-point linear least squares, with the points it touches) or
else from the viewing rays of its tip detections (linear least squares), then the remaining points.

Several robots (``robots:`` in the cell, :mod:`jcalib.io.cell`): the cell's frame is ``world``
(fixed things ``T_world_<x>``, points in the world frame). Per robot ``r`` an SE(3) unknown
``T_world_<r>`` (its base) and per station the flange pose ``T_<r>_flange`` (station
``flange_poses``) with that robot's own pose-noise prior, so any chain works, e.g. a camera on r1
seeing a target on r2: ``T_world_cam = T_world_r1 · T_r1_flange_i · T_flange_cam`` and
``T_world_board = T_world_r2 · T_r2_flange_i · T_flange_board``; tool tips (world cameras) and contacts
likewise. The flange poses are Schur-eliminated per robot; where a camera on one robot sees a target
on another, one of the two robots' flange poses stays in the dense system (a factor may touch one
eliminated kind). The gauge: the world frame is the first robot's base (``T_world_<r1>`` held, at
identity or at its ``base``) unless a held world pose anchors it: a robot ``base`` or a ``mount:
world`` camera / target ``pose`` listed in ``fixed``; then every robot base not held is unknown.
A robot no observation involves is left out (a warning). The start goes on after the poses: a
robot base follows from a pair whose two poses are started (averaged), or, with the thing on the
robot still unknown, from a closed-form robot-world solve (AX = ZB, Shah,
:func:`jcalib.init.robot_world.solve_robot_world_hand_eye`) on a camera or target on its flange
that pairs with something whose world pose is started; hand-eye solves run per robot once its base
is started (motion degeneracy checks per robot). A base that nothing places is named
(:class:`NotObservableError`). One robot (``robot:`` or a one-entry ``robots:``) is exactly the
problem above.

Priors from a previous result (``prior=``): each named unknown gets a Gaussian prior with the old
value as mean and the old covariance (pseudo-inverse square root: coordinates with zero variance
get no prior). The old values are also the start.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import lie
from jcalib.geometry.cameras import AbstractCameraModel, camera_model_from_name
from jcalib.init.handeye import HAND_EYE_METHODS, average_poses, solve_hand_eye
from jcalib.init.pivot import DEFAULT_MIN_ROTATION_DEG, _check_rotations
from jcalib.init.robot_world import solve_robot_world_hand_eye
from jcalib.io.cell import CellSpec
from jcalib.io.observations import Observations
from jcalib.problems.camera import (
    MIN_POINTS_PER_VIEW,
    _CameraData,
    _initial_model,
    _intrinsics_fixed_mask,
    _reprojection_fn,
    _se3_matrix,
    _se3_params,
)
from jcalib.problems.tcp import _tip_fn
from jcalib.residuals.priors import gaussian_prior_residual
from jcalib.solve import (
    SE3,
    Euclidean,
    FactorGroup,
    Problem,
    SolveOptions,
    Variable,
    linear,
    solve,
)
from jcalib.solve.covariance import covariance as _covariance

__all__ = ["CellCalibration", "CellOptions", "calibrate_cell", "is_cell_problem", "synthetic_cell",
           "synthetic_two_robot_cell"]

#: Rounds of outlier rejection (each re-solves once; stops early when the rejected set stops changing).
MAX_OUTLIER_ROUNDS = 5


@dataclass(frozen=True)
class CellOptions:
    """Options of :func:`calibrate_cell`.

    Attributes:
        sigma_px: stated corner noise (pixels); weighs pixels against the robot-pose prior.
        tip_sigma_px: stated tool-tip detection noise (pixels).
        noise: covariance scale: ``"a_posteriori"`` (σ̂² from the residuals, default) or ``"stated"``.
        pose_model: per-station robot-pose corrections: ``None`` = on when the cell has
            ``robot.pose_noise``; ``False`` = off (poses exact).
        method: closed-form hand-eye start (a key of :data:`jcalib.init.handeye.HAND_EYE_METHODS`).
        max_iterations: LM iteration limit.
        contact_sigma_m: stated accuracy of a tool-tip contact with a cell point (per axis, m): how
            well the tip sits in the divot, on top of the robot pose noise.
        outlier_threshold: target corners and tip pixels whose residual exceeds this many
            a-posteriori σ are rejected after the solve and the problem re-solved (up to
            :data:`MAX_OUTLIER_ROUNDS` times); ``None`` keeps all.
    """

    sigma_px: float = 0.25
    tip_sigma_px: float = 0.25
    noise: str = "a_posteriori"
    pose_model: bool | None = None
    method: str = "park_martin"
    max_iterations: int = 100
    contact_sigma_m: float = 5e-5
    outlier_threshold: float | None = 5.0

    def __post_init__(self):
        for name in ("sigma_px", "tip_sigma_px"):
            if not getattr(self, name) > 0:
                raise BadInputError(f"{name}: got {getattr(self, name)!r}, expected a positive number of pixels")
        if not self.contact_sigma_m > 0:
            raise BadInputError(f"contact_sigma_m: got {self.contact_sigma_m!r}, expected a positive length in m")
        if self.outlier_threshold is not None and not self.outlier_threshold > 0:
            raise BadInputError(f"outlier_threshold: got {self.outlier_threshold!r}, expected a positive number "
                                "of σ or None")
        if self.noise not in ("a_posteriori", "stated"):
            raise BadInputError(f"noise: got {self.noise!r}, expected 'a_posteriori' or 'stated'")
        if self.pose_model not in (None, True, False):
            raise BadInputError(f"pose_model: got {self.pose_model!r}, expected None, True or False")
        if self.method not in HAND_EYE_METHODS:
            raise BadInputError(f"method: got {self.method!r}, expected one of {sorted(HAND_EYE_METHODS)}")

    @classmethod
    def from_options(cls, options) -> CellOptions:
        """Carry over ``sigma_px``, ``noise``, ``max_iterations`` (and ``pose_model``) from camera or
        hand-eye options (the CLI parses one set of options for every cell)."""
        if options is None:
            return cls()
        if isinstance(options, CellOptions):
            return options
        keep = {k: getattr(options, k) for k in ("sigma_px", "noise", "max_iterations", "pose_model",
                                                 "outlier_threshold") if hasattr(options, k)}
        if not keep:
            raise BadInputError(f"options: got {type(options).__name__}, expected CellOptions for a whole-cell problem")
        return cls(**keep)


@dataclass
class CellCalibration:
    """The outcome of :func:`calibrate_cell` (see :class:`jcalib.Result` for the file form).

    Attributes:
        cameras: camera id -> calibrated model.
        intrinsics_covariance: camera id -> ``(p, p)`` covariance of ``model.params`` (px², zero where fixed).
        transforms: name (``T_flange_cam0``, ``T_base_cam1``, ``T_base_board``, ``T_flange_needle``)
            -> ``(4, 4)``, m.
        transform_covariance: name -> ``(6, 6)`` right-perturbation covariance (rx..tz; rad², m²).
        start: name -> ``(4, 4)`` closed-form start of each transform (m).
        start_method: name -> how it was started (``"cell"``, ``"prior"``, ``"hand_eye:<method>"``,
            ``"from:<pair>"``, ``"tip_rays"``).
        station_ids: the stations used, in file order.
        T_base_flange_measured, T_base_flange: ``(N, 4, 4)`` measured / estimated flange poses, m (one-robot
            cells; ``(0, 4, 4)`` with several robots: see ``flange_poses``).
        rms_px: RMS of the target-corner residual coordinates (pixels). ``tip_rms_px``: of the tip pixels.
        sigma_px: a-posteriori corner noise (``sqrt(σ̂²)·sigma_px``).
        num_residuals, iterations, status, sigma2: solver facts.
        pose_model: whether robot pose corrections were estimated (for any robot).
        priors: names of the unknowns that carried a prior.
        joint_covariance: ``{"names": [...], "dims": [...], "matrix": (n, n)}``: the joint covariance
            of every unknown (camera ids for intrinsics, transform names; tangent coordinates in that
            order), with the cross terms that the per-unknown blocks leave out.
        points: cell point name -> ``(3,)`` position in the base frame (m), estimated from tool-tip
            contacts (or as given); ``point_covariance``: name -> ``(3, 3)`` m² (zero when given).
        contact_rms_m: RMS of the contact residual coordinates (m), nan without contacts.
        outliers: rejected measurements ``(camera/tool, station id, point index or -1 for a tip)``.
        variance_components: residual kind (``corner``, ``tip``, ``contact``) -> a-posteriori variance
            factor on its stated σ² that the covariances use (empty: one factor σ̂² for everything).
        frame: the frame of fixed things and points: ``"base"`` (one robot) or ``"world"``.
        flange_poses: several robots: robot -> ``{"station_ids": [...], "measured": (n, 4, 4),
            "estimated": (n, 4, 4)}`` (``T_<robot>_flange`` at the stations that use it, m); empty for one robot.
        solution: the :class:`jcalib.solve.Solution`.
    """

    cameras: dict[str, AbstractCameraModel]
    intrinsics_covariance: dict[str, np.ndarray]
    transforms: dict[str, np.ndarray]
    transform_covariance: dict[str, np.ndarray]
    start: dict[str, np.ndarray]
    start_method: dict[str, str]
    station_ids: list[str]
    T_base_flange_measured: np.ndarray
    T_base_flange: np.ndarray
    rms_px: float
    tip_rms_px: float
    sigma_px: float
    num_residuals: int
    iterations: int
    status: str
    sigma2: float
    pose_model: bool
    priors: list[str] = field(default_factory=list)
    joint_covariance: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    points: dict[str, np.ndarray] = field(default_factory=dict)
    point_covariance: dict[str, np.ndarray] = field(default_factory=dict)
    contact_rms_m: float = float("nan")
    outliers: list[tuple[str, str, int]] = field(default_factory=list)
    variance_components: dict[str, float] = field(default_factory=dict)
    frame: str = "base"
    flange_poses: dict[str, dict] = field(default_factory=dict)
    solution: object = field(default=None, repr=False)


def is_cell_problem(cell: CellSpec) -> bool:
    """Whether :func:`calibrate_cell` handles ``cell``: a robot cell (cameras/targets on the base or
    flange, tools, cell points touched by tools) without free-moving cameras or targets."""
    mounts = [c.mount for c in cell.cameras.values()] + [t.mount for t in cell.targets.values()]
    if "free" in mounts:
        return False
    return bool(cell.tools) or bool(cell.points) or any(m != "free" for m in mounts)


# ------------------------------------------------------------------------------------ residuals


@functools.cache
def _target_fn(model_cls: type, image_size: tuple[int, int], skew: bool, cam_slot: int, target_slot: int,
               with_base: bool):
    """``(intrinsics, X, Y, *robots, obs) -> (2,)`` px residual, ``obs = (p_target (3,), pixel (2,),
    aspect (2,))``. ``X``/``Y``: the camera's / target's pose on its holder (``T_<frame>_cam`` or
    ``T_flange_cam``). ``robots``: per robot involved (at most two) its flange pose
    ``T_base_flange`` (one-robot cell) or ``T_world_<r>, T_<r>_flange`` (``with_base``);
    ``cam_slot`` / ``target_slot`` say which robot holds the camera / target (-1: fixed). One
    function per configuration."""
    project = _reprojection_fn(model_cls, image_size, skew)
    width = 2 if with_base else 1

    def fn(intrinsics, X, Y, *rest):
        *robots, obs = rest

        def world(slot, T):
            if slot < 0:
                return T
            chain = robots[width * slot:width * (slot + 1)] + [T]
            return functools.reduce(lie.se3_compose, chain)

        return project(intrinsics, lie.se3_inverse(world(cam_slot, X)), world(target_slot, Y), obs)

    return fn


def _contact_fn(T_flange_tool, point, T_base_flange, obs):
    """Tool tip at the station's flange pose minus the touched cell point, base frame (m), (3,)."""
    return lie.se3_apply(T_base_flange, T_flange_tool[4:]) - point


def _world_contact_fn(T_flange_tool, point, T_world_robot, T_robot_flange, obs):
    """:func:`_contact_fn` for a tool on one of several robots: world frame (m), (3,)."""
    return lie.se3_apply(lie.se3_compose(T_world_robot, T_robot_flange), T_flange_tool[4:]) - point


@functools.cache
def _world_tip_fn(model_cls: type, image_size: tuple[int, int], skew: bool):
    """``(intrinsics, T_world_cam, T_flange_tcp, T_world_robot, T_robot_flange, pixel (2,)) -> (2,)`` px:
    :func:`jcalib.problems.tcp._tip_fn` for a tool on one of several robots."""
    tip = _tip_fn(model_cls, image_size, skew)

    def fn(intrinsics, T_world_cam, T_flange_tcp, T_world_robot, T_robot_flange, pixel):
        return tip(intrinsics, T_world_cam, T_flange_tcp, lie.se3_compose(T_world_robot, T_robot_flange), pixel)

    return fn


@functools.cache
def _residuals_jit(fn):
    return jax.jit(jax.vmap(fn))


# ------------------------------------------------------------------------------------ data


@dataclass
class _Pair:
    camera: str
    target: str
    views: list[int]  # station index per view
    points: list[np.ndarray]  # (n, 3) per view
    pixels: list[np.ndarray]  # (n, 2) per view
    point_index: list[np.ndarray]


@dataclass
class _Tips:
    camera: str
    tool: str
    stations: list[int]
    pixels: list[np.ndarray]  # (2,) each


@dataclass
class _Contacts:
    tool: str
    point: str
    stations: list[int]


class _Robots:
    """The robots of a cell and where things hang: the bookkeeping shared by gather, start and problem.

    One robot (``robot:`` or a one-entry ``robots:``): frame ``base``, one flange-pose variable
    ``T_base_flange``, no base variable. Several: frame ``world``, per robot ``r`` the variables
    ``T_world_<r>`` (its base) and ``T_<r>_flange`` (its flange pose at each station that needs it).
    A thing's *holder* is None (fixed in the cell's frame) or the robot whose flange carries it.
    """

    def __init__(self, cell: CellSpec):
        self.cell = cell
        self.multi = cell.multi_robot
        self.frame = cell.frame
        if self.multi:
            self.names = list(cell.robots)
            self.specs = dict(cell.robots)
        else:
            name = (cell.robot.name if cell.robot is not None and cell.robot.name else None) or "robot"
            self.names = [name]
            self.specs = {name: cell.robot}

    def holder(self, spec) -> str | None:
        """The robot carrying a camera / target (``mount: flange``) or a tool; None when fixed."""
        if getattr(spec, "mount", "flange") != "flange":
            return None
        return spec.robot if self.multi else self.names[0]

    def flange_var(self, r: str) -> str:
        return f"T_{r}_flange" if self.multi else "T_base_flange"

    def base_var(self, r: str) -> str | None:
        return f"T_world_{r}" if self.multi else None

    def label(self, r: str) -> str:
        return f"robot '{r}'" if self.multi or r != "robot" else "the robot"

    def has_noise(self, r: str) -> bool:
        s = self.specs[r]
        return s is not None and s.pose_noise_translation_m is not None

    def sqrt_info(self, r: str) -> np.ndarray:
        s = self.specs[r]
        rot = np.radians(np.asarray(s.pose_noise_rotation_deg, np.float64))
        trans = np.asarray(s.pose_noise_translation_m, np.float64)
        return np.diag(1.0 / np.concatenate([rot, trans]))

    def gauge(self) -> tuple[str | None, list[str]]:
        """``(robot whose base is the world frame or None, anchors)``. Anchors are held world poses:
        a robot ``base`` listed in ``fixed`` (``T_world_<r>`` or the robot's name), a ``mount: world``
        camera or target with a ``pose`` listed in ``fixed``. With an anchor every robot base not held
        is unknown; without, the first robot's base is the world frame (held at its ``base``, else identity)."""
        cell = self.cell
        if not self.multi:
            return self.names[0], []
        anchors = [f"T_world_{r}" for r, s in self.specs.items()
                   if s.base is not None and (r in cell.fixed or f"T_world_{r}" in cell.fixed)]
        for spec in list(cell.cameras.values()) + list(cell.targets.values()):
            if spec.mount == "world" and spec.pose is not None and (spec.name in cell.fixed
                                                                    or f"T_world_{spec.name}" in cell.fixed):
                anchors.append(f"T_world_{spec.name}")
        return (None if anchors else self.names[0]), anchors

    def held_base(self, r: str) -> bool:
        gauge, _ = self.gauge()
        s = self.specs[r]
        listed = r in self.cell.fixed or f"T_world_{r}" in self.cell.fixed
        return r == gauge or (s.base is not None and listed)


def _station_pose(rb: _Robots, station, r: str) -> np.ndarray | None:
    """The measured flange pose of robot ``r`` at ``station`` (None when the station has none)."""
    if rb.multi or station.flange_poses:
        return station.flange_poses.get(r)
    return station.T_base_flange


def _gather(cell: CellSpec, obs: Observations, rb: _Robots):
    """Pairs, tips and contacts of the used stations, and per robot its measured flange poses
    ``{robot: (N, 4, 4)}`` (identity where a station has none) with the stations that need them
    ``{robot: (N,) bool}``."""
    for c in cell.cameras.values():
        if c.name not in obs.cameras:
            raise BadInputError(f"{obs.source}: camera '{c.name}' of the cell has no image size in the observations")
    pairs: dict[tuple[str, str], _Pair] = {}
    tips: dict[tuple[str, str], _Tips] = {}
    contacts: dict[tuple[str, str], _Contacts] = {}
    ids, needs, stations = [], [], []
    fixed_mounts = ("base", "world")
    for station in obs.stations:
        used = False
        need: set[str] = set()
        k = len(ids)
        for c in station.contacts:
            if c.tool not in cell.tools:
                raise BadInputError(f"{obs.source}: station '{station.id}': contact of tool '{c.tool}', which is not "
                                    f"in the cell's tools ({', '.join(cell.tools) or 'none'})")
            if c.point not in cell.points:
                raise BadInputError(f"{obs.source}: station '{station.id}': contact with point '{c.point}', which is "
                                    f"not in the cell's points ({', '.join(cell.points) or 'none'})")
            contacts.setdefault((c.tool, c.point), _Contacts(c.tool, c.point, [])).stations.append(k)
            need.add(rb.holder(cell.tools[c.tool]))
            used = True
        for det in station.detections:
            if det.camera not in cell.cameras:
                continue
            if det.tool is not None:
                if det.tool not in cell.tools:
                    continue
                if cell.cameras[det.camera].mount not in fixed_mounts:
                    raise BadInputError(
                        f"{obs.source}: station '{station.id}': tool '{det.tool}' seen by camera '{det.camera}' "
                        f"(mount {cell.cameras[det.camera].mount}); tool tips are used from fixed cameras "
                        f"(mount: {rb.frame})"
                    )
                t = tips.setdefault((det.camera, det.tool), _Tips(det.camera, det.tool, [], []))
                t.stations.append(k)
                t.pixels.append(det.pixels.reshape(2))
                need.add(rb.holder(cell.tools[det.tool]))
                used = True
            elif det.target in cell.targets:
                n = det.point_index.size
                if n < MIN_POINTS_PER_VIEW:
                    raise BadInputError(
                        f"{obs.source}: station '{station.id}', camera '{det.camera}': only {n} points of target "
                        f"'{det.target}'; a view needs at least {MIN_POINTS_PER_VIEW}. Drop the view or re-detect it"
                    )
                if det.target not in obs.targets:
                    raise BadInputError(f"{obs.source}: the observations have no points for target '{det.target}'")
                p = pairs.setdefault((det.camera, det.target), _Pair(det.camera, det.target, [], [], [], []))
                p.views.append(k)
                p.points.append(obs.targets[det.target][det.point_index])
                p.pixels.append(det.pixels)
                p.point_index.append(det.point_index)
                need |= {rb.holder(cell.cameras[det.camera]), rb.holder(cell.targets[det.target])}
                used = True
        if not used:
            continue
        unknown = sorted(set(station.flange_poses) - set(rb.names))
        if unknown:
            raise BadInputError(
                f"{obs.source}: station '{station.id}': flange_poses names robot(s) {unknown}, which the cell does "
                f"not have (robots: {', '.join(rb.names)}); fix the robot names or the cell's robots"
            )
        if rb.multi:
            if station.T_base_flange is not None:
                raise BadInputError(
                    f"{obs.source}: station '{station.id}' gives T_base_flange, but the cell has several robots "
                    f"({', '.join(rb.names)}): give each robot's flange pose in flange_poses: {{robot: [[4x4]]}}"
                )
            need.discard(None)
            for r in sorted(need):
                if r not in station.flange_poses:
                    raise BadInputError(
                        f"{obs.source}: station '{station.id}': the detections or contacts involve robot '{r}' "
                        f"(a camera, target or tool on its flange), but the station has no flange pose of '{r}'; "
                        f"add flange_poses: {{{r}: [[4x4]]}} (T_{r}_flange, m) or drop those detections"
                    )
        else:  # one robot: every used station needs the flange pose, as always
            need = {rb.names[0]}
            if _station_pose(rb, station, rb.names[0]) is None:
                raise BadInputError(
                    f"{obs.source}: station '{station.id}' has no T_base_flange; a robot cell needs the flange pose "
                    "of every station"
                )
        ids.append(station.id)
        needs.append(need)
        stations.append(station)
    if not ids:
        raise BadInputError(f"{obs.source}: no detection of the cell's targets or tools, and no contact, in any station")
    poses, need_mask = {}, {}
    for r in rb.names:
        mask = np.array([r in n for n in needs])
        T = np.broadcast_to(np.eye(4), (len(ids), 4, 4)).copy()
        for k, station in enumerate(stations):
            if mask[k]:
                T[k] = np.asarray(_station_pose(rb, station, r), np.float64)
        poses[r], need_mask[r] = T, mask
    for (cam_name, target_name), p in pairs.items():
        if rb.holder(cell.cameras[cam_name]) == rb.holder(cell.targets[target_name]) and len(p.views) > 1:
            pairs[(cam_name, target_name)] = _static_view(p)
    return pairs, tips, contacts, ids, poses, need_mask


def _static_view(p: _Pair) -> _Pair:
    """Repeated images of a static scene (camera and target on the same mount) as one view.

    They are not independent evidence about the geometry: the robot does not move one relative to
    the other, so only the sensor noise differs between the images (detection biases repeat). Each
    point seen in every image enters once, at its mean pixel; counting every image would shrink the
    reported σ of that camera's pose by the square root of the number of stations.
    """
    common = set(p.point_index[0].tolist())
    for idx in p.point_index[1:]:
        common &= set(idx.tolist())
    keep = np.array(sorted(common), dtype=p.point_index[0].dtype)
    if keep.size == 0:
        return _Pair(p.camera, p.target, p.views[:1], p.points[:1], p.pixels[:1], p.point_index[:1])
    rows = []
    for idx, pix in zip(p.point_index, p.pixels):
        where = {int(v): i for i, v in enumerate(idx.tolist())}
        rows.append(np.asarray(pix, np.float64)[[where[int(v)] for v in keep]])
    first = {int(v): i for i, v in enumerate(p.point_index[0].tolist())}
    points = np.asarray(p.points[0])[[first[int(v)] for v in keep]]
    return _Pair(p.camera, p.target, p.views[:1], [points], [np.mean(rows, axis=0)], [keep])


def _sqrt_info(cov: np.ndarray) -> np.ndarray:
    """Pseudo-inverse square root ``S`` (``SᵀS = Σ⁺``) of a covariance; zero rows where Σ has no variance."""
    cov = 0.5 * (np.asarray(cov, np.float64) + np.asarray(cov, np.float64).T)
    w, U = np.linalg.eigh(cov)
    keep = w > max(float(np.max(w)), 0.0) * 1e-12
    inv = np.where(keep, 1.0 / np.sqrt(np.where(keep, w, 1.0)), 0.0)
    return inv[:, None] * U.T


def _inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


# ------------------------------------------------------------------------------------ start


def _mount_name(mount: str, name: str) -> str:
    return f"T_{mount}_{name}"


def _start_intrinsics(cell: CellSpec, obs: Observations, pairs, prior, rb: _Robots) -> tuple[dict, dict]:
    """Start models and per-view target poses ``{(camera, target): (V, 4, 4)}``."""
    models, views = {}, {}
    for cam in cell.cameras.values():
        cam_pairs = [p for (c, _), p in pairs.items() if c == cam.name]
        K0, dist0 = cam.K, cam.dist
        if K0 is None and prior is not None and cam.name in prior.cameras:
            old = prior.cameras[cam.name]
            if old.model == cam.model:
                K0, dist0 = np.asarray(old.K), np.asarray(old.dist)
        moving = [p for p in cam_pairs if rb.holder(cell.targets[p.target]) != rb.holder(cam)]
        if K0 is None and not moving:
            raise BadInputError(
                f"{cell.source}: camera '{cam.name}' (mount {cam.mount}) sees no moving target, so its views do not "
                "determine its intrinsics on their own; give intrinsics: {K: [[3x3]], dist: [...]} in the cell "
                "(e.g. from a camera calibration) or pass a previous result as the prior"
            )
        use = cam_pairs if K0 is not None else moving
        cd = _CameraData(cam.name, cam.model, obs.cameras[cam.name], cam.skew, cam.fix, K0, dist0, [], [], [], [])
        where = []
        for p in use:
            for j, v in enumerate(p.views):
                cd.stations.append(len(where))
                cd.points.append(p.points[j])
                cd.pixels.append(p.pixels[j])
                cd.point_index.append(p.point_index[j])
                where.append((p.target, j))
        model, per_view = _initial_model(cd)
        models[cam.name] = model
        for p in use:
            views[(cam.name, p.target)] = np.stack(
                [per_view[i] for i, (t, j) in enumerate(where) if t == p.target]
            )
        for p in cam_pairs:  # static pairs of a camera started by Zhang: PnP with the start model
            if (cam.name, p.target) not in views:
                K, dist = (np.asarray(a, np.float64) for a in model.to_opencv())
                cd2 = _CameraData(cam.name, cam.model, obs.cameras[cam.name], cam.skew, cam.fix, K, dist,
                                  list(range(len(p.views))), p.points, p.pixels, p.point_index)
                _, pv = _initial_model(cd2)
                views[(cam.name, p.target)] = np.stack([pv[i] for i in range(len(p.views))])
    return models, views


def _contact_start(tool: str, tool_contacts: list, T_bf: np.ndarray, point_start: dict, source: str):
    """TCP translation (and the unknown points it touches) from contacts, by linear least squares.

    Each contact at station k says ``R_k · tip + t_k = p``: unknowns ``tip`` (flange frame) and
    every touched point not given in the cell (base frame); given points enter as constants. This is
    the pivot calibration (one point, many orientations) and the robot's 4-point TCP method, and it
    fills ``point_start`` with the points it solves. Returns ``(T_flange_tool, how)``.
    """
    unknown = sorted({c.point for c in tool_contacts if c.point not in point_start})
    name = f"T_flange_{tool}"
    if unknown:  # a pivot: the tip along an axis the flange never turns away from stays undetermined
        R = T_bf[np.asarray([k for c in tool_contacts if c.point in unknown for k in c.stations]), :3, :3]
        try:
            _check_rotations(R, DEFAULT_MIN_ROTATION_DEG, f"tool '{tool}' touching {unknown}")
        except NotObservableError as err:
            raise NotObservableError(f"{source}: {err} ({name} and the touched points)",
                                     [name] + [f"point:{p}" for p in unknown]) from None
    col = {p: 3 + 3 * i for i, p in enumerate(unknown)}
    rows, rhs = [], []
    for c in tool_contacts:
        for k in c.stations:
            A = np.zeros((3, 3 + 3 * len(unknown)))
            A[:, :3] = T_bf[k, :3, :3]
            b = -T_bf[k, :3, 3]
            if c.point in col:
                A[:, col[c.point]:col[c.point] + 3] = -np.eye(3)
            else:
                b = b + point_start[c.point]
            rows.append(A)
            rhs.append(b)
    A, b = np.concatenate(rows), np.concatenate(rhs)
    sv = np.linalg.svd(A, compute_uv=False)
    if A.shape[0] < A.shape[1] or sv[-1] < 1e-6 * sv[0]:
        raise NotObservableError(
            f"{source}: the contacts of tool '{tool}' do not determine its tip ({name}) and the touched points "
            f"{unknown}: the flange orientations at each point must differ by rotations about at least two axes "
            "(a pivot needs the tool tilted in different directions; the 4-point method four distinct orientations)",
            [name] + [f"point:{p}" for p in unknown])
    x = np.linalg.lstsq(A, b, rcond=None)[0]
    for p in unknown:
        point_start[p] = x[col[p]:col[p] + 3]
    T = np.eye(4)
    T[:3, 3] = x[:3]
    return T, "contacts"


def _start_poses(cell, rb: _Robots, pairs, views, poses, known: dict, method: str, rot_noise: float,
                 used_robots: list[str], tool_robots: frozenset = frozenset()):
    """Fill ``known`` (name -> (4, 4)) for every camera and target pose and every robot base, and say
    how each started.

    Repeats, until nothing changes: (1) a pose that follows from a started one through a camera–target
    pair (averaged over the pair's stations; a robot base the same way when both things of the pair are
    started); (2) a closed-form hand-eye solve (:func:`solve_hand_eye`) for a moving pair whose two
    poses are unknown while their robots' bases are started; (3) a closed-form robot-world solve
    (:func:`solve_robot_world_hand_eye`, AX = ZB, Shah) for a robot with an unknown base whose flange
    carries a camera or target that pairs with something whose world pose is started.
    """
    how = {name: "known" for name in known}

    def base_known(h) -> bool:
        return h is None or rb.base_var(h) is None or rb.base_var(h) in known

    def world(h, ks):
        """World (cell-frame) pose of holder ``h`` at stations ``ks``; None for a fixed thing."""
        if h is None:
            return None
        b = rb.base_var(h)
        return poses[h][ks] if b is None else known[b] @ poses[h][ks]

    def info(p):
        cs, ts = cell.cameras[p.camera], cell.targets[p.target]
        return _mount_name(cs.mount, p.camera), _mount_name(ts.mount, p.target), rb.holder(cs), rb.holder(ts)

    def pose_at(name, h, ks):
        """``(n, 4, 4)`` world pose of a started thing at stations ``ks``."""
        W = world(h, ks)
        return np.broadcast_to(known[name], (len(ks), 4, 4)) if W is None else W @ known[name]

    def offset(T_world, h, ks):
        """A thing's pose on its holder from its world poses at stations ``ks`` (averaged)."""
        W = world(h, ks)
        return average_poses(T_world if W is None else np.linalg.inv(W) @ T_world)

    def derive(p) -> bool:
        X, Y, hc, ht = info(p)
        T_ct = views[(p.camera, p.target)]
        ks = np.asarray(p.views)
        if hc == ht:  # static pair: the relative pose alone, whatever the holder's base
            if X in known and Y not in known:
                known[Y] = average_poses(known[X] @ T_ct)
                how[Y] = f"from:{X}+{p.camera}/{p.target}"
                return True
            if Y in known and X not in known:
                known[X] = average_poses(known[Y] @ np.linalg.inv(T_ct))
                how[X] = f"from:{Y}+{p.camera}/{p.target}"
                return True
            return False
        kc, kt = base_known(hc), base_known(ht)
        if X in known and kc and Y not in known and kt:
            known[Y] = offset(pose_at(X, hc, ks) @ T_ct, ht, ks)
            how[Y] = f"from:{X}+{p.camera}/{p.target}"
            return True
        if Y in known and kt and X not in known and kc:
            known[X] = offset(pose_at(Y, ht, ks) @ np.linalg.inv(T_ct), hc, ks)
            how[X] = f"from:{Y}+{p.camera}/{p.target}"
            return True
        if X in known and Y in known and kc != kt:  # a robot base through a started pair
            if not kt:
                T_wt = pose_at(X, hc, ks) @ T_ct  # world pose of the target = B · F_k · Y
                B = average_poses(T_wt @ np.linalg.inv(known[Y]) @ np.linalg.inv(poses[ht][ks]))
                name = rb.base_var(ht)
            else:
                T_wc = pose_at(Y, ht, ks) @ np.linalg.inv(T_ct)
                B = average_poses(T_wc @ np.linalg.inv(known[X]) @ np.linalg.inv(poses[hc][ks]))
                name = rb.base_var(hc)
            known[name] = B
            how[name] = f"from:{X}+{Y}+{p.camera}/{p.target}"
            return True
        return False

    plist = sorted(pairs.values(), key=lambda p: -len(p.views))
    while True:
        while any(derive(p) for p in plist):
            pass
        todo = [p for p in plist if info(p)[2] != info(p)[3] and info(p)[0] not in known and info(p)[1] not in known
                and base_known(info(p)[2]) and base_known(info(p)[3])]
        if todo:  # hand-eye: both poses unknown, the robots' bases started
            p = todo[0]
            X, Y, hc, ht = info(p)
            ks = np.asarray(p.views)
            if ht is None:  # camera on a flange, target fixed: T_world_flange, eye-in-hand
                H, mount = world(hc, ks), "flange"
            elif hc is None:  # camera fixed, target on a flange: eye-to-hand
                H, mount = world(ht, ks), "base"
            else:  # camera on one robot, target on another: the camera's flange in the target's flange
                H, mount = np.linalg.inv(world(ht, ks)) @ world(hc, ks), "flange"
            init = solve_hand_eye(H, views[(p.camera, p.target)], method=method, mount=mount,
                                  rotation_noise_deg=rot_noise)
            known[X], known[Y] = init.T, init.T_other
            how[X] = how[Y] = f"hand_eye:{method}"
            continue
        # robot-world: a thing Q on robot r (base unknown, Q's pose unknown) paired with a thing P whose
        # world pose is started: W_P,k · T_PQ,k = B · F_k · Q, i.e. T_Q_world,k = Q⁻¹ F_k⁻¹ B⁻¹ (eye-in-hand
        # AX = ZB with the world frame as the target fixed in r's base)
        rw = None
        for p in plist:
            X, Y, hc, ht = info(p)
            if hc == ht:
                continue
            for P, hP, Q, hQ, cam_is_P in ((X, hc, Y, ht, True), (Y, ht, X, hc, False)):
                if P in known and base_known(hP) and Q not in known and not base_known(hQ):
                    rw = (p, P, hP, Q, hQ, cam_is_P)
                    break
            if rw:
                break
        if rw is None:
            break
        p, P, hP, Q, hQ, cam_is_P = rw
        ks = np.asarray(p.views)
        T_ct = views[(p.camera, p.target)]
        W_Q = pose_at(P, hP, ks) @ (T_ct if cam_is_P else np.linalg.inv(T_ct))
        base = rb.base_var(hQ)
        try:
            init = solve_robot_world_hand_eye(poses[hQ][ks], np.linalg.inv(W_Q), method="shah", mount="flange",
                                              rotation_noise_deg=rot_noise)
        except NotObservableError as err:
            raise NotObservableError(f"{cell.source}: {rb.label(hQ)}'s base ({base}) and {Q} from the pair "
                                     f"{p.camera}/{p.target}: {err}", [base, Q]) from None
        known[Q], known[base] = init.T, _inv(init.T_other)
        how[Q] = how[base] = "robot_world:shah"
    missing = sorted({n for p in plist for n in info(p)[:2] if n not in known})
    bases = [r for r in used_robots if rb.base_var(r) is not None and rb.base_var(r) not in known]
    if bases:
        _unconnected_base(cell, rb, bases[0], pairs, missing, bases[0] in tool_robots)
    if missing:
        raise NotObservableError(
            f"{cell.source}: the poses {missing} are not determined: their cameras and targets are seen only "
            "together, without a robot motion between them or a known pose; give one of them a pose: [[4x4]] "
            "in the cell",
            missing,
        )
    return how


def _unconnected_base(cell, rb: _Robots, r: str, pairs, missing, has_tools: bool):
    """Raise the NotObservableError for robot ``r`` whose base the start could not place."""
    base = rb.base_var(r)
    gauge, anchors = rb.gauge()
    frame = (f"the world frame is robot '{gauge}''s base (nothing in the cell holds a world pose)" if gauge
             else f"the world frame is fixed by {', '.join(anchors)}")
    linked = [f"{c}/{t}" for (c, t) in pairs
              if r in (rb.holder(cell.cameras[c]), rb.holder(cell.targets[t]))
              and rb.holder(cell.cameras[c]) != rb.holder(cell.targets[t])]
    if not linked and has_tools:
        raise NotObservableError(
            f"{cell.source}: robot {r}'s base ({base}) cannot be started: {r} is linked to the world frame only "
            f"through tool tips or contacts ({frame}), which do not give a closed-form start for a base. Let a "
            f"camera see a target on {r} (or a camera on {r} see a target off it), or give robots.{r}.base", [base])
    if not linked:
        raise NotObservableError(
            f"{cell.source}: robot {r}'s base ({base}) is not connected to the world frame: no camera or target on "
            f"{r} is seen together with the world or another robot ({frame}). Let a camera fixed in the world or "
            f"on another robot see a target on {r} (or a camera on {r} see a target off it), or give robots.{r}.base "
            f"and list {base} in fixed", [base])
    raise NotObservableError(
        f"{cell.source}: robot {r}'s base ({base}) cannot be started: the pairs that link it ({', '.join(linked)}) "
        f"involve only things whose poses are not determined either ({', '.join(missing) or 'none'}; {frame}). "
        f"Give a known pose to one of them (pose: [[4x4]] listed in fixed) or robots.{r}.base", [base] + missing)


# ------------------------------------------------------------------------------------ solve


def calibrate_cell(
    cell: CellSpec,
    obs: Observations,
    options: CellOptions | None = None,
    *,
    prior=None,
    prior_names=None,
    start=None,
) -> CellCalibration:
    """Calibrate a whole robot cell jointly (see the module docstring for the model).

    Args:
        cell: a ``jcalib.cell/1`` spec with cameras and targets on the ``base`` or ``flange`` and tools
            ``observed_by`` fixed cameras; ``robot.pose_noise`` switches the robot pose model on.
            ``fix`` (intrinsics), ``pose`` + ``fixed`` (known camera / target poses) are honoured.
        obs: observations with ``T_base_flange`` per station (m), or with several robots
            ``flange_poses`` (each robot the detections involve): target corners and tool-tip pixels
            (``{"camera", "tool", "pixel"}``).
        options: :class:`CellOptions`.
        prior: an old :class:`jcalib.io.result.ResultFile`: its values start the solve and its
            covariances become Gaussian priors on the unknowns in ``prior_names``.
        prior_names: names (camera ids, transform names) that get a prior; ``None`` = every unknown
            the prior result holds (with a covariance).
        start: an old result whose values only start the solve (no priors).

    Returns:
        :class:`CellCalibration`. Covariances are sampling noise (pixel noise and, with the pose model,
        the stated robot noise, first order, scaled by σ̂² by default) plus the priors, not model error.

    Raises:
        BadInputError: malformed input (missing poses, too few points, a camera whose intrinsics the
            data cannot start).
        NotObservableError: poses or a TCP the data cannot determine, or a rank-deficient problem,
            naming the unknowns.
    """
    options = options or CellOptions()
    if not is_cell_problem(cell):
        raise BadInputError(
            f"{cell.source}: the whole-cell problem takes cameras and targets on the base or flange and tools; "
            "free-moving cameras/targets and contact points are calibrated by the camera and pivot problems"
        )
    rb = _Robots(cell)
    pairs, tips, contacts, ids, poses, need = _gather(cell, obs, rb)
    used_robots = [r for r in rb.names if need[r].any()]
    pose_model = {}
    for r in used_robots:
        pose_model[r] = rb.has_noise(r) if options.pose_model is None else bool(options.pose_model)
        if pose_model[r] and not rb.has_noise(r):
            where = f"robots.{r}.pose_noise" if rb.multi else "robot.pose_noise"
            raise BadInputError(f"options.pose_model: got True, but {cell.source} has no {where}")
    use_pose_model = any(pose_model.values())
    noisy = [r for r in used_robots if rb.has_noise(r)]
    rot_noise = max([0.02] + [float(np.max(rb.specs[r].pose_noise_rotation_deg)) for r in noisy])
    seed = prior if prior is not None else start
    warnings = [f"{rb.label(r)} has no observations; its base ({rb.base_var(r)}) is not estimated"
                for r in rb.names if rb.multi and r not in used_robots]

    # --- start: intrinsics, then poses (hand-eye per robot, then robot bases), then TCPs
    models, views = _start_intrinsics(cell, obs, pairs, seed, rb)
    known: dict[str, np.ndarray] = {}
    for c in cell.cameras.values():
        if c.pose is not None:
            known[_mount_name(c.mount, c.name)] = np.asarray(c.pose, np.float64)
    for t in cell.targets.values():
        if t.pose is not None:
            known[_mount_name(t.mount, t.name)] = np.asarray(t.pose, np.float64)
    gauge, _ = rb.gauge()
    for r in rb.names:
        b = rb.base_var(r)
        if b is None:
            continue
        if rb.specs[r].base is not None:
            known[b] = np.asarray(rb.specs[r].base, np.float64)
        elif r == gauge:
            known[b] = np.eye(4)
        if (r in cell.fixed or b in cell.fixed) and rb.specs[r].base is None and r != gauge:
            raise BadInputError(f"{cell.source}: fixed lists '{r}' ({b}) but the cell gives it no base; add "
                                f"robots.{r}.base: [[4x4]] (m) or remove it from fixed")
    how_known = {n: "cell" for n in known}
    if gauge is not None and rb.base_var(gauge) is not None:
        how_known[rb.base_var(gauge)] = "gauge" if rb.specs[gauge].base is None else "gauge:cell"
    if seed is not None:
        for n, tr in seed.transforms.items():
            if n not in known:
                known[n] = np.asarray(tr.matrix, np.float64)
                how_known[n] = "prior"
    tool_robots = frozenset(rb.holder(cell.tools[t.tool]) for t in list(tips.values()) + list(contacts.values()))
    how = _start_poses(cell, rb, pairs, views, poses, known, options.method, rot_noise, used_robots, tool_robots)
    how.update(how_known)

    def world_flange(r):
        """``(N, 4, 4)`` started world (cell-frame) flange poses of robot ``r`` per station."""
        b = rb.base_var(r)
        return poses[r] if b is None else known[b] @ poses[r]

    point_start: dict[str, np.ndarray] = {n: np.asarray(pt.position, np.float64) for n, pt in cell.points.items()
                                          if pt.position is not None}
    for tool in cell.tools.values():
        name = f"T_flange_{tool.name}"
        tool_tips = [t for (c, tn), t in tips.items() if tn == tool.name]
        tool_contacts = [c for (tn, _), c in contacts.items() if tn == tool.name]
        if name in known:
            continue
        if tool_contacts:
            known[name], how[name] = _contact_start(tool.name, tool_contacts, world_flange(rb.holder(tool)),
                                                    point_start, obs.source)
            continue
        if not tool_tips:
            raise NotObservableError(f"{obs.source}: tool '{tool.name}' has no tip detections and no contacts; {name} "
                                     "is undetermined", [name])
        A_rows, x = [], None
        T_wf = world_flange(rb.holder(tool))
        for t in tool_tips:
            cam_name = _mount_name(rb.frame, t.camera)
            if cam_name not in known:
                raise NotObservableError(
                    f"{cell.source}: camera '{t.camera}' sees tool '{tool.name}' but its pose {cam_name} is not "
                    "determined by the targets; give it a pose or let it see a target", [cam_name])
            A_rows.append((models[t.camera], known[cam_name], T_wf[np.asarray(t.stations)], np.stack(t.pixels)))
        # all cameras together (one lstsq)
        As, bs = [], []
        for model, Tc, Tb, px in A_rows:
            d = np.asarray(model.unproject(jnp.asarray(px))) @ Tc[:3, :3].T
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
            As.append(np.einsum("nij,njk->nik", P, Tb[:, :3, :3]).reshape(-1, 3))
            bs.append(np.einsum("nij,nj->ni", P, Tc[:3, 3][None] - Tb[:, :3, 3]).reshape(-1))
        A, b = np.concatenate(As), np.concatenate(bs)
        sv = np.linalg.svd(A, compute_uv=False)
        if sv.size < 3 or sv[2] < 1e-3 * sv[0]:
            raise NotObservableError(
                f"{obs.source}: the tip of tool '{tool.name}' is seen along one viewing direction only (the flange "
                f"orientations barely change); the TCP offset along that ray ({name}) is not determined. Present "
                "the tool at several orientations", [name])
        x = np.linalg.lstsq(A, b, rcond=None)[0]
        T = np.eye(4)
        T[:3, 3] = x
        known[name] = T
        how[name] = "tip_rays"
    for point in cell.points:
        if point in point_start:
            continue
        touches = [c for (_, pn), c in contacts.items() if pn == point]
        if not touches:
            raise NotObservableError(f"{obs.source}: cell point '{point}' is touched in no station (no contacts); its "
                                     "position is undetermined. Touch it with a tool or give its position", [f"point:{point}"])
        tips_world = []
        for c in touches:
            T_wf = world_flange(rb.holder(cell.tools[c.tool]))
            tips_world += [T_wf[k, :3, :3] @ known[f"T_flange_{c.tool}"][:3, 3] + T_wf[k, :3, 3] for k in c.stations]
        point_start[point] = np.mean(tips_world, axis=0)

    # --- problem
    prior_for = {}
    if prior is not None:
        wanted = None if prior_names is None else set(prior_names)
        for n, tr in prior.transforms.items():
            if tr.covariance is not None and (wanted is None or n in wanted):
                prior_for[n] = (_se3_params(tr.matrix), _sqrt_info(tr.covariance))
        for n, cr in prior.cameras.items():
            if cr.covariance is not None and (wanted is None or n in wanted) and n in models \
                    and tuple(cr.param_names) == tuple(models[n].param_names):
                prior_for[n] = (np.asarray(cr.params, np.float64), _sqrt_info(cr.covariance))
    used_priors = []
    prior_factors = []

    def var(name, manifold, value, fixed=False, key=None, **kw):
        # Every unknown gets a prior factor group, weight 0 when there is no prior: problems with and
        # without priors then share one compiled solver (and a zero weight is not counted in σ̂²).
        key = key or name
        value = np.asarray(value, np.float64).reshape(1, -1)
        if key in prior_for:
            mean, S = prior_for[key]
            used_priors.append(key)
            w = 1.0
        else:
            mean, S, w = value[0], np.zeros((manifold.tangent_dim, manifold.tangent_dim)), 0.0
        prior_factors.append(FactorGroup(
            f"prior:{name}", gaussian_prior_residual(manifold), (name,), (np.zeros(1, np.int32),),
            (np.asarray(mean, np.float64)[None], np.asarray(S, np.float64)[None]), sqrt_weight=np.array([w])))
        return Variable(name, manifold, value, fixed=fixed, **kw)

    # per robot: its flange pose at each station that needs it (entry e_r[k] of station k)
    entry = {r: np.cumsum(need[r]) - 1 for r in used_robots}
    stations_of = {r: np.flatnonzero(need[r]) for r in used_robots}
    shared = _shared_flange_robots(cell, rb, pairs, {r: len(stations_of[r]) for r in used_robots})
    variables = []
    pose_sqrt_info = []  # (flange variable, S) of every robot with the pose model
    for r in used_robots:
        meas = np.stack([_se3_params(T) for T in poses[r][stations_of[r]]])
        label = "station {i} flange pose" if not rb.multi else f"station {{i}} {r} flange pose"
        elim = r not in shared
        if pose_model[r]:
            S = rb.sqrt_info(r)
            pose_sqrt_info.append((rb.flange_var(r), S))
            variables.append(Variable(rb.flange_var(r), SE3(), meas, prior_mean=meas, prior_sqrt_info=S,
                                      eliminate=elim, entry_label=label))
        else:
            variables.append(Variable(rb.flange_var(r), SE3(), meas, fixed=True, eliminate=elim,
                                      constant=not elim, entry_label=label))
    aspect = {}
    for cam in cell.cameras.values():
        model = models[cam.name]
        fixed = _intrinsics_fixed_mask(model, cam.fix)
        ratio = float(model.params[0] / model.params[1]) if cam.K is None else float(cam.K[0, 0] / cam.K[1, 1])
        flag = 1.0 if "aspect" in cam.fix else 0.0
        aspect[cam.name] = (flag, ratio)
        variables.append(var(f"intrinsics:{cam.name}", Euclidean(len(model.param_names)),
                             np.asarray(model.params, np.float64)[None, :], fixed=fixed[None, :], key=cam.name,
                             coord_names=list(model.param_names), entry_label=cam.name))
    transform_names = []
    for spec in list(cell.cameras.values()) + list(cell.targets.values()):
        name = _mount_name(spec.mount, spec.name)
        if name not in known:
            continue
        fixed = spec.name in cell.fixed or name in cell.fixed
        if fixed and spec.pose is None:
            raise BadInputError(f"{cell.source}: fixed lists '{spec.name}' ({name}) but the cell gives it no pose; "
                                "add pose: [[4x4]] (m) or remove it from fixed")
        transform_names.append(name)
        variables.append(var(name, SE3(), _se3_params(known[name]), fixed=fixed))
    for tool in cell.tools.values():
        name = f"T_flange_{tool.name}"
        transform_names.append(name)
        variables.append(var(name, SE3(), _se3_params(known[name]),
                             fixed=np.array([True, True, True, name in cell.fixed, name in cell.fixed,
                                             name in cell.fixed])))
    for r in used_robots:
        name = rb.base_var(r)
        if name is not None:
            transform_names.append(name)
            variables.append(var(name, SE3(), _se3_params(known[name]), fixed=rb.held_base(r)))

    for point, spec in cell.points.items():
        fixed = spec.position is not None or point in cell.fixed
        if point in cell.fixed and spec.position is None:
            raise BadInputError(f"{cell.source}: fixed lists point '{point}' but the cell gives it no position; add "
                                "position: [x, y, z] (m) or remove it from fixed")
        variables.append(Variable(f"point:{point}", Euclidean(3), point_start[point][None, :],
                                  fixed=np.full((1, 3), fixed), entry_label=f"point {point}"))

    def robot_args(holders, st):
        """Variable names and index arrays of the robots ``holders`` at stations ``st`` (per robot:
        ``T_world_<r>`` with several robots, then its flange pose)."""
        names, idx = [], []
        for r in holders:
            if rb.base_var(r) is not None:
                names.append(rb.base_var(r))
                idx.append(np.zeros_like(st))
            names.append(rb.flange_var(r))
            idx.append(entry[r][st].astype(np.int32))
        return tuple(names), tuple(idx)

    factors, evals = [], []
    for p in pairs.values():
        cam = cell.cameras[p.camera]
        tgt = cell.targets[p.target]
        hc, ht = rb.holder(cam), rb.holder(tgt)
        holders = [h for h in dict.fromkeys([hc, ht]) if h is not None]
        model = models[p.camera]
        fn = _target_fn(type(model), tuple(int(v) for v in model.image_size), bool(model.has_skew),
                        -1 if hc is None else holders.index(hc), -1 if ht is None else holders.index(ht), rb.multi)
        st = np.repeat(np.asarray(p.views, np.int32), [x.shape[0] for x in p.points])
        o = (np.concatenate(p.points), np.concatenate(p.pixels), np.broadcast_to(np.array(aspect[p.camera]),
                                                                                 (st.shape[0], 2)).copy())
        rnames, ridx = robot_args(holders, st)
        args = (f"intrinsics:{p.camera}", _mount_name(cam.mount, p.camera), _mount_name(tgt.mount, p.target)) + rnames
        z = np.zeros_like(st)
        indices = (z, z, z) + ridx
        factors.append(FactorGroup(f"reprojection:{p.camera}/{p.target}", fn, args, indices, o,
                                   sigma=options.sigma_px))
        evals.append(("corner", fn, args, st, o, (p.camera, np.concatenate(p.point_index)), indices))
    for t in tips.values():
        model = models[t.camera]
        size = tuple(int(v) for v in model.image_size)
        fn = _tip_fn(type(model), size, bool(model.has_skew)) if not rb.multi else \
            _world_tip_fn(type(model), size, bool(model.has_skew))
        st = np.asarray(t.stations, np.int32)
        o = np.stack(t.pixels)
        rnames, ridx = robot_args([rb.holder(cell.tools[t.tool])], st)
        args = (f"intrinsics:{t.camera}", _mount_name(rb.frame, t.camera), f"T_flange_{t.tool}") + rnames
        z = np.zeros_like(st)
        indices = (z, z, z) + ridx
        factors.append(FactorGroup(f"tooltip:{t.camera}/{t.tool}", fn, args, indices, o,
                                   sigma=options.tip_sigma_px))
        evals.append(("tip", fn, args, st, o, (f"{t.camera}/{t.tool}", np.full(st.shape, -1)), indices))
    for c in contacts.values():
        st = np.asarray(c.stations, np.int32)
        z = np.zeros_like(st)
        rnames, ridx = robot_args([rb.holder(cell.tools[c.tool])], st)
        args = (f"T_flange_{c.tool}", f"point:{c.point}") + rnames
        fn = _contact_fn if not rb.multi else _world_contact_fn
        o = np.zeros((st.shape[0], 1))
        indices = (z, z) + ridx
        factors.append(FactorGroup(f"contact:{c.tool}/{c.point}", fn, args, indices, o,
                                   sigma=options.contact_sigma_m))
        evals.append(("contact", fn, args, st, o, None, indices))

    def residuals(values):
        out = []
        for kind, fn, args, st, o, _, indices in evals:
            n = st.shape[0]
            ins = [jnp.asarray(values[a][np.asarray(i)]) for a, i in zip(args, indices)]
            out.append(np.asarray(_residuals_jit(fn)(*ins, jax.tree.map(jnp.asarray, o))).reshape(n, -1))
        return out

    def build(weights, scale=None):
        # scale: residual kind -> factor on its stated σ (variance components); None = as stated
        fs = [FactorGroup(f.name, f.fn, f.args, f.indices, f.observations,
                          sigma=f.sigma * (1.0 if scale is None else float(np.sqrt(scale.get(e[0], 1.0)))),
                          sqrt_weight=w)
              for f, e, w in zip(factors, evals, weights)]
        return Problem(variables, fs + prior_factors)

    # Solve; reject pixels (corners, tips) beyond the threshold and re-solve from the last solution.
    weights = [np.ones(e[3].shape[0]) for e in evals]
    solve_options = SolveOptions(max_iterations=options.max_iterations)
    sol = solve(build(weights), options=solve_options)
    res = residuals({k: np.asarray(v) for k, v in sol.values.items()})
    for _ in range(MAX_OUTLIER_ROUNDS if options.outlier_threshold is not None else 0):
        # each kind's own noise level: corners and tips come from different detectors (the demo's
        # corners are 10x more precise than its tips); a-posteriori: a robust scale (1.4826 MAD) of
        # that kind's inlier residual coordinates, so the outliers themselves do not inflate it.
        # Every round re-decides every measurement, so one pulled along by an outlier comes back.
        scale = {}
        for kind, stated in (("corner", options.sigma_px), ("tip", options.tip_sigma_px)):
            coords = [r[w > 0].reshape(-1) for (kd, *_), r, w in zip(evals, res, weights) if kd == kind]
            coords = np.concatenate(coords) if coords else np.zeros(0)
            scale[kind] = (1.4826 * float(np.median(np.abs(coords))) if coords.size >= 10
                           and options.noise == "a_posteriori" else stated)
        new = [w if kind == "contact" else
               np.where(np.linalg.norm(r, axis=1) > options.outlier_threshold * scale[kind], 0.0, 1.0)
               for (kind, *_), r, w in zip(evals, res, weights)]
        if all(np.array_equal(a, b) for a, b in zip(new, weights)):
            break
        weights = new
        sol = solve(build(weights), x0=sol.values, options=solve_options)
        res = residuals({k: np.asarray(v) for k, v in sol.values.items()})
    outliers: list[tuple[str, str, int]] = []
    for (kind, _, _, st, _, label, _), w in zip(evals, weights):
        if kind != "contact":
            who, index = label
            outliers += [(who, ids[int(st[j])], int(index[j])) for j in np.flatnonzero(w == 0)]
    if options.noise == "a_posteriori" and not sol.sigma2 == sol.sigma2:
        raise NotObservableError(
            f"The a-posteriori noise level needs more residuals ({sol.num_residuals}) than free unknowns "
            f"({sol.num_free}); use noise='stated'.", ["sigma2"])

    # --- covariance scale: one variance factor per residual kind (see _variance_components)
    cov_noise = options.noise
    components = {}
    if options.noise == "a_posteriori":
        sol, res, components = _variance_components(sol, build, residuals, evals, factors, weights,
                                                    pose_sqrt_info or None, solve_options)
        if components:
            cov_noise = "stated"
    cov_sol = sol
    corner_factor = components.get("corner", float(sol.sigma2))

    # --- outputs
    vals = {k: np.asarray(v) for k, v in sol.values.items()}
    sq = {"corner": [], "tip": [], "contact": []}
    for (kind, *_), r, w in zip(evals, res, weights):
        sq[kind].append(r[w > 0] ** 2)
    corner = np.concatenate(sq["corner"]) if sq["corner"] else np.zeros((0, 2))
    tip = np.concatenate(sq["tip"]) if sq["tip"] else np.zeros((0, 2))
    contact = np.concatenate(sq["contact"]) if sq["contact"] else np.zeros((0, 3))
    points = {n: vals[f"point:{n}"][0].copy() for n in cell.points}
    point_cov = {n: np.asarray(_covariance(cov_sol, f"point:{n}", noise=cov_noise)) for n in cell.points}
    cameras, intr_cov = {}, {}
    for cam in cell.cameras.values():
        prm = vals[f"intrinsics:{cam.name}"][0].copy()
        cov = np.asarray(_covariance(cov_sol, f"intrinsics:{cam.name}", noise=cov_noise))
        flag, ratio = aspect[cam.name]
        if flag:
            prm[1] = prm[0] / ratio
            cov[1, :] = cov[0, :] / ratio
            cov[:, 1] = cov[:, 0] / ratio
            cov[1, 1] = cov[0, 0] / ratio**2
        cameras[cam.name] = models[cam.name].with_params(jnp.asarray(prm))
        intr_cov[cam.name] = cov
    transforms = {n: _se3_matrix(vals[n][0]) for n in transform_names}
    tcov = {n: np.asarray(_covariance(cov_sol, n, noise=cov_noise)) for n in transform_names}
    joint = _joint_covariance(cov_sol, [(c, f"intrinsics:{c}") for c in cell.cameras] + [(n, n) for n in transform_names],
                              cov_noise)
    for cam in cell.cameras.values():  # the aspect tie, as in the per-camera block
        flag, ratio = aspect[cam.name]
        if flag:
            o = joint["names"].index(cam.name)
            o = int(np.sum(joint["dims"][:o]))
            M = joint["matrix"]
            M[o + 1, :] = M[o, :] / ratio
            M[:, o + 1] = M[:, o] / ratio
    flange = {}
    for r in used_robots:
        measured = poses[r][stations_of[r]]
        est = (np.stack([_se3_matrix(v) for v in vals[rb.flange_var(r)]]) if pose_model[r] else measured.copy())
        flange[r] = {"station_ids": [ids[k] for k in stations_of[r]], "measured": measured, "estimated": est}
    if rb.multi:
        T_bf, T_bf_est = np.zeros((0, 4, 4)), np.zeros((0, 4, 4))
    else:
        T_bf, T_bf_est = flange[rb.names[0]]["measured"], flange[rb.names[0]]["estimated"]
    return CellCalibration(
        cameras=cameras,
        intrinsics_covariance=intr_cov,
        transforms=transforms,
        transform_covariance=tcov,
        start={n: known[n] for n in transform_names},
        start_method={n: how.get(n, "known") for n in transform_names},
        station_ids=list(ids),
        T_base_flange_measured=T_bf,
        T_base_flange=T_bf_est,
        rms_px=float(np.sqrt(np.mean(corner))) if corner.size else float("nan"),
        tip_rms_px=float(np.sqrt(np.mean(tip))) if tip.size else float("nan"),
        contact_rms_m=float(np.sqrt(np.mean(contact))) if contact.size else float("nan"),
        points=points,
        point_covariance=point_cov,
        outliers=outliers,
        variance_components=components,
        sigma_px=float(np.sqrt(corner_factor)) * options.sigma_px,
        num_residuals=int(corner.size + tip.size + contact.size),
        iterations=int(sol.iterations),
        status=sol.status.name.lower(),
        sigma2=float(sol.sigma2),
        pose_model=bool(use_pose_model),
        priors=sorted(set(used_priors)),
        joint_covariance=joint,
        warnings=warnings,
        frame=rb.frame,
        flange_poses=flange if rb.multi else {},
        solution=sol,
    )


def _shared_flange_robots(cell, rb: _Robots, pairs, num_entries: dict[str, int]) -> set[str]:
    """Robots whose flange-pose variable stays in the dense (shared) system: a factor may touch one
    eliminated kind only, so of a camera on one robot seeing a target on another, one robot's flange
    poses are not eliminated. A greedy vertex cover of those robot pairs, fewest entries first."""
    edges = set()
    for c, t in pairs:
        hc, ht = rb.holder(cell.cameras[c]), rb.holder(cell.targets[t])
        if hc is not None and ht is not None and hc != ht:
            edges.add(tuple(sorted((hc, ht))))
    shared: set[str] = set()
    while edges:
        degree: dict[str, int] = {}
        for a, b in edges:
            degree[a] = degree.get(a, 0) + 1
            degree[b] = degree.get(b, 0) + 1
        r = max(degree, key=lambda n: (degree[n], -num_entries.get(n, 0)))
        shared.add(r)
        edges = {e for e in edges if r not in e}
    return shared


@eqx.filter_jit
def _information(problem: Problem, values: dict) -> linear.System:
    """Gauss–Newton information ``JᵀJ`` of ``problem``'s factors at ``values`` (no fixed-coordinate identity)."""
    layout = linear.make_layout(problem)
    free = linear.free_masks(problem)
    system = linear.empty_system(layout)
    for f in problem.factors:
        _, H_obs, g_obs, _, _, _ = linear.factor_linearization(problem, values, f, free)
        system = linear.scatter_factor(system, layout, f, H_obs, g_obs, linear._active_args(problem, f),
                                       f.chunk is not None)
    return system


def _hat_trace(sol, group: list) -> float:
    """``tr(H_g H⁻¹)`` for the factor groups ``group`` of the solved problem (same variables): the
    number of "parameters" their residuals use up. ``H⁻¹`` from the Schur-reduced inverse and the
    eliminated blocks (``Σ_ee = V⁻¹ + V⁻¹Wᵀ Σ_ss W V⁻¹``, ``Σ_es = −V⁻¹Wᵀ Σ_ss``); no dense inverse.
    The factor functions are cached per configuration, so one compilation serves every call."""
    from jcalib.solve.covariance import _inverse_blocks

    Hg = _information(Problem(sol.padded_problem.variables, group), sol.raw.values)
    sigma_ss, Vinvs = (np.asarray(a) if not isinstance(a, tuple) else tuple(np.asarray(b) for b in a)
                       for a in _inverse_blocks(sol))
    total = float(np.sum(np.asarray(Hg.H_ss) * sigma_ss))  # tr(A B) for symmetric A, B
    for slot, (Vg, Wg) in enumerate(zip(Hg.V, Hg.W)):
        W, Vinv = np.asarray(sol.raw.system.W[slot]), Vinvs[slot]
        Y = np.einsum("nde,nse->nds", Vinv, W)  # V⁻¹ Wᵀ
        sigma_ee = Vinv + np.einsum("nds,st,nxt->ndx", Y, sigma_ss, Y)
        sigma_es = -np.einsum("nds,st->ndt", Y, sigma_ss)
        total += float(np.einsum("nde,ned->", np.asarray(Vg), sigma_ee))
        total += 2.0 * float(np.einsum("nsd,nds->", np.asarray(Wg), sigma_es))
    return total


#: Iterations of the variance-component estimation (each re-solves from the previous solution).
VARIANCE_COMPONENT_ITERATIONS = 25
#: A residual kind estimates its own noise factor only with at least this redundancy (and a quarter
#: of its count); below, χ² has too few degrees of freedom (e.g. tool tips whose 2 coordinates per
#: station the station's 6-dof robot pose correction can absorb) and the kind keeps its stated σ.
MIN_REDUNDANCY = 5.0


def _variance_components(sol, build, residuals, evals, factors, weights, pose_sqrt_info, solve_options):
    """A-posteriori variance factors per residual kind, and the solution weighted by them.

    Corner pixels, tool-tip pixels and contacts come from different sensors and detectors: one
    σ̂² of all residuals lets the most numerous kind (corners) set the noise of the others (the demo's
    corners are 0.011 px, its tips ~0.1 px). With the robot pose model, the prior on the flange poses
    keeps its stated σ too (as in the hand-eye problem). Each kind ``g`` gets its own factor
    ``f_g = χ²_g / r_g`` (Helmert's estimator), ``r_g = m_g − tr(H_g H⁻¹)`` its redundancy at the
    current weights (:func:`_hat_trace`); the robot prior's redundancy is
    ``Σ_k 6 − tr(S Σ_k Sᵀ)``; the most numerous kind takes the rest, so the redundancies add up to
    ``m − n``. The weights are updated and the problem re-solved until every update is within 1 % of
    1 (the estimate is biased while the weights are wrong: a too-trusted kind pushes its errors into
    the robot poses). A kind with too little redundancy to estimate its noise (:data:`MIN_REDUNDANCY`)
    keeps its stated σ.

    Returns:
        ``(solution, residuals, {kind: factor on its stated σ²})``; the factors are ``{}`` (and the
        solution unchanged) when one common factor serves (a single kind, no pose model).
    """
    kinds = sorted({e[0] for e in evals})
    if len(kinds) < 2 and pose_sqrt_info is None:
        return sol, residuals({k: np.asarray(v) for k, v in sol.values.items()}), {}
    count = dict.fromkeys(kinds, 0)
    for (kind, *_), w in zip(evals, weights):
        count[kind] += int(np.sum(w > 0)) * (2 if kind != "contact" else 3)
    main = max(kinds, key=lambda k: count[k])
    scale = dict.fromkeys(kinds, 1.0)
    use = {}
    for _ in range(VARIANCE_COMPONENT_ITERATIONS):
        if use:
            sol = solve(build(weights, scale).with_values(sol.values), options=solve_options)
        res = residuals({k: np.asarray(v) for k, v in sol.values.items()})
        chi2 = dict.fromkeys(kinds, 0.0)
        for (kind, *_), f, r, w in zip(evals, factors, res, weights):
            chi2[kind] += float(np.sum((r[w > 0] / f.sigma) ** 2)) / scale[kind]
        redundancy = {}
        for k in kinds:
            if k != main:
                group = [FactorGroup(f.name, f.fn, f.args, f.indices, f.observations,
                                     sigma=f.sigma * float(np.sqrt(scale[k])), sqrt_weight=w)
                         for e, f, w in zip(evals, factors, weights) if e[0] == k]
                redundancy[k] = count[k] - _hat_trace(sol, group)
        prior = 0.0
        for name, S in pose_sqrt_info or ():  # every robot with the pose model
            S = np.asarray(S)
            n = sol.problem.variable(name).num
            cov = np.asarray(sol.covariance(name, noise="stated")).reshape(n, 6, n, 6)
            prior += float(sum(6.0 - np.trace(S @ cov[k, :, k, :] @ S.T) for k in range(n)))
        redundancy[main] = (sol.num_residuals - sol.num_free) - prior - sum(redundancy.values())
        use = {k: chi2[k] / redundancy[k] for k in kinds
               if redundancy[k] >= max(MIN_REDUNDANCY, 0.25 * count[k]) and chi2[k] > 0.0}
        if not use:
            break
        for k in use:
            scale[k] *= use[k]
        if all(abs(v - 1.0) < 0.01 for v in use.values()):
            break
    else:
        sol = solve(build(weights, scale).with_values(sol.values), options=solve_options)
        res = residuals({k: np.asarray(v) for k, v in sol.values.items()})
    # the factors the final solve's weights carry (a kind left at its stated σ is not listed)
    return sol, res, {k: v for k, v in scale.items() if v != 1.0}


def _joint_covariance(sol, names: list[tuple[str, str]], noise: str) -> dict:
    """Joint covariance of shared (non-eliminated) variables from the Schur-reduced inverse."""
    from jcalib.solve.covariance import _inverse_blocks, _scale

    scale = _scale(sol, noise)
    sigma_ss, _ = _inverse_blocks(sol)
    sigma_ss = np.asarray(sigma_ss)
    layout = sol.layout
    idx, dims = [], []
    for _, v in names:
        k = layout.kind(v)
        d = layout.dims[k]
        free = ~np.asarray(sol.padded_problem.variable(v).fixed[0])
        rows = layout.offsets[k] + np.arange(d)
        idx.append(np.where(free, rows, -1))
        dims.append(d)
    idx = np.concatenate(idx)
    ok = idx >= 0
    M = np.zeros((idx.size, idx.size))
    M[np.ix_(ok, ok)] = scale * sigma_ss[np.ix_(idx[ok], idx[ok])]
    return {"names": [n for n, _ in names], "dims": dims, "matrix": M}


# ------------------------------------------------------------------------------------ synthetic cell

#: The synthetic demo cell's cameras: opencv5 ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)`` at 1600x1200.
SYNTH_IMAGE_SIZE = (1600, 1200)
SYNTH_FLANGE_PARAMS = np.array([1400.0, 1398.0, 801.5, 598.0, -0.12, 0.08, 0.0005, -0.0003, -0.02])
SYNTH_FIXED_PARAMS = np.array([1800.0, 1801.0, 795.0, 603.0, -0.08, 0.05, 0.0, 0.0, 0.0])


def _rot(axis, angle):
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _look_at(eye, target, up=(0.0, 0.0, 1.0)):
    """``T_base_cam`` of a camera at ``eye`` whose optical axis (+z) points at ``target``."""
    z = np.asarray(target, np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, (1.0, 0.0, 0.0))
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = eye
    return T


def _perturb(T, rng, sigma_m, sigma_deg):
    if sigma_m <= 0 and sigma_deg <= 0:
        return T.copy()
    d = np.concatenate([np.radians(sigma_deg) * rng.normal(size=3), sigma_m * rng.normal(size=3)])
    return T @ _se3_matrix(np.asarray(lie.se3_exp(jnp.asarray(d))))


def _synth_project(model, T_cam_x, P):
    """Pixels ``(n, 2)`` of points ``P (n, 3)`` in frame x seen by ``model`` at ``T_cam_x``, and whether each
    is in front of the camera and 5 px inside the synthetic image."""
    p = P @ T_cam_x[:3, :3].T + T_cam_x[:3, 3]
    u = np.asarray(model.project(jnp.asarray(p)))
    w, h = SYNTH_IMAGE_SIZE
    ok = (p[:, 2] > 0.05) & (u[:, 0] > 5) & (u[:, 0] < w - 6) & (u[:, 1] > 5) & (u[:, 1] < h - 6)
    return u, ok


def synthetic_cell(
    seed: int = 0,
    *,
    num_board_stations: int = 15,
    num_tool_stations: int = 30,
    sigma_px: float = 0.2,
    tip_sigma_px: float = 0.2,
    robot_m: float = 1e-4,
    robot_deg: float = 0.01,
    truth: dict | None = None,
) -> tuple[dict, dict, dict]:
    """A synthetic demo cell: flange camera ``cam0``, fixed camera ``cam1`` (intrinsics known from a lab
    calibration and held fixed), a 9x6 checkerboard ``board`` fixed on the table, a tool ``needle`` whose
    tip ``cam1`` sees. Pixels come from the true flange poses plus Gaussian noise; the file holds flange
    poses perturbed by the robot noise (right perturbation, σ per axis), as the cell states.

    Args:
        seed: random seed (stations and noise).
        num_board_stations: stations where ``cam0`` (and ``cam1``) see the board.
        num_tool_stations: stations presenting the tool tip to ``cam1``.
        sigma_px, tip_sigma_px: corner / tip pixel noise σ.
        robot_m, robot_deg: robot pose noise σ per axis (m, degrees).
        truth: override true transforms (``T_flange_cam0``, ``T_base_cam1``, ``T_base_board``,
            ``T_flange_needle``, (4, 4) m) and intrinsics (``cam0``, ``cam1`` param vectors), e.g. to
            simulate a bumped camera or a moved TCP with the same geometry.

    Returns:
        ``(cell dict, observations dict, truth dict)``.
    """
    from jcalib.geometry.targets import Checkerboard

    rng = np.random.default_rng(seed)
    geo = np.random.default_rng(12345)  # the cell's layout is the same for every seed
    board = Checkerboard(cols=9, rows=6, square=0.03)
    pts = np.asarray(board.points, np.float64)
    centre_t = pts.mean(axis=0)
    T_base_board = np.eye(4)
    T_base_board[:3, :3] = _rot((1, 0, 0), np.pi)  # printed face (-z) up
    T_base_board[:3, 3] = [0.7, -0.1, 0.0]
    centre = T_base_board[:3, :3] @ centre_t + T_base_board[:3, 3]
    T_flange_cam0 = np.eye(4)
    T_flange_cam0[:3, :3] = _rot((0.2, 0.1, 1.0), 0.3)
    T_flange_cam0[:3, 3] = [0.06, -0.03, 0.08]
    T_base_cam1 = _look_at(np.array([1.2, 0.5, 0.6]), centre + np.array([0.05, 0.1, 0.1]))
    T_flange_tool = np.eye(4)
    T_flange_tool[:3, 3] = [0.01, -0.02, 0.18]
    true = {"T_flange_cam0": T_flange_cam0, "T_base_cam1": T_base_cam1, "T_base_board": T_base_board,
            "T_flange_needle": T_flange_tool, "cam0": SYNTH_FLANGE_PARAMS.copy(), "cam1": SYNTH_FIXED_PARAMS.copy()}
    true.update({k: np.asarray(v, np.float64) for k, v in (truth or {}).items()})
    cams = {c: camera_model_from_name("opencv5", SYNTH_IMAGE_SIZE, true[c]) for c in ("cam0", "cam1")}

    def project(cam, T_cam_x, P):
        return _synth_project(cams[cam], T_cam_x, P)

    stations = []
    T_bf_true = []
    # board stations: cam0 looks at the board from 0.35-0.6 m, tilted up to ~35 deg
    k = 0
    while len(T_bf_true) < num_board_stations:
        k += 1
        dirn = np.array([geo.uniform(-0.5, 0.5), geo.uniform(-0.5, 0.5), 1.0])
        eye = centre + geo.uniform(0.35, 0.6) * dirn / np.linalg.norm(dirn)
        T_base_c = _look_at(eye, centre + geo.normal(scale=0.03, size=3), up=(1.0, 0.0, 0.0))
        T_base_c[:3, :3] = T_base_c[:3, :3] @ _rot((0, 0, 1), geo.uniform(-0.6, 0.6))
        T_bf = T_base_c @ _inv(true["T_flange_cam0"])
        u, ok = project("cam0", _inv(T_bf @ true["T_flange_cam0"]) @ true["T_base_board"], pts)
        if ok.sum() == len(pts):
            T_bf_true.append(T_bf)
    # tool stations: the tip in front of cam1, the tool tilted up to ~40 deg
    look = true["T_base_cam1"]
    while len(T_bf_true) < num_board_stations + num_tool_stations:
        p_cam = np.array([geo.uniform(-0.08, 0.08), geo.uniform(-0.06, 0.06), geo.uniform(0.5, 0.7)])
        p_base = look[:3, :3] @ p_cam + look[:3, 3]
        R = _rot((1, 0, 0), np.pi) @ _rot(geo.normal(size=3), geo.uniform(0.1, 0.7))
        T_bf = np.eye(4)
        T_bf[:3, :3] = R
        T_bf[:3, 3] = p_base - R @ true["T_flange_needle"][:3, 3]
        T_bf_true.append(T_bf)
    for i, T_bf in enumerate(T_bf_true):
        dets = []
        if i < num_board_stations:
            for cam, T_cam_board in (
                ("cam0", _inv(T_bf @ true["T_flange_cam0"]) @ true["T_base_board"]),
                ("cam1", _inv(true["T_base_cam1"]) @ true["T_base_board"]),
            ):
                u, ok = project(cam, T_cam_board, pts)
                idx = np.flatnonzero(ok)
                if idx.size >= MIN_POINTS_PER_VIEW:
                    px = u[idx] + sigma_px * rng.normal(size=(idx.size, 2))
                    dets.append({"camera": cam, "target": "board", "point_index": idx.tolist(), "pixels": px.tolist()})
        else:
            tip = T_bf[:3, :3] @ true["T_flange_needle"][:3, 3] + T_bf[:3, 3]
            u, ok = project("cam1", _inv(true["T_base_cam1"]), tip[None])
            if ok[0]:
                dets.append({"camera": "cam1", "tool": "needle",
                             "pixel": (u[0] + tip_sigma_px * rng.normal(size=2)).tolist()})
        T_meas = _perturb(T_bf, rng, robot_m, robot_deg)
        stations.append({"id": f"s{i:03d}", "T_base_flange": T_meas.tolist(), "detections": dets})
    K1, d1 = cams["cam1"].to_opencv()
    cell = {
        "schema": "jcalib.cell/1",
        "cameras": {
            "cam0": {"model": "opencv5", "mount": "flange"},
            "cam1": {"model": "opencv5", "mount": "base",
                     "fix": ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"],
                     "intrinsics": {"K": np.asarray(K1).tolist(), "dist": np.asarray(d1).tolist()}},
        },
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03, "mount": "base"}},
        "tools": {"needle": {"observed_by": ["cam1"]}},
        "robot": {"pose_noise": {"translation_m": robot_m, "rotation_deg": robot_deg}},
    }
    obs = {"schema": "jcalib.observations/1",
           "cameras": {c: {"image_size": list(SYNTH_IMAGE_SIZE)} for c in ("cam0", "cam1")},
           "targets": {"board": {"points": pts.tolist()}}, "stations": stations}
    return cell, obs, true


def synthetic_two_robot_cell(
    seed: int = 0,
    *,
    num_board_stations: int = 12,
    num_r2_stations: int = 12,
    num_cross_stations: int = 6,
    num_tool_stations: int = 16,
    sigma_px: float = 0.2,
    tip_sigma_px: float = 0.2,
    robot_m: float = 1e-4,
    robot_deg: float = 0.01,
) -> tuple[dict, dict, dict]:
    """A synthetic two-robot cell (world frame = robot ``r1``'s base): ``r1`` carries the flange camera
    ``cam0``; ``r2`` (base ``T_world_r2`` unknown) carries a 7x5 checkerboard ``board2`` and a tool
    ``torch``; the world holds a 9x6 ``board`` (on the table) and a camera ``cam1`` (intrinsics given as
    the start, estimated) that sees ``board``, ``board2`` and the torch's tip. Stations: ``cam0`` looks at
    ``board`` (r1 only), ``r2`` presents ``board2`` to ``cam1`` (r2 only), ``cam0`` looks at ``board2``
    held by ``r2`` (both robots), ``r2`` presents the tip to ``cam1``. Pixels from the true poses plus
    Gaussian noise; the file holds each robot's flange poses perturbed by the robot noise (right
    perturbation, σ per axis, both robots alike).

    Returns:
        ``(cell dict, observations dict, truth dict)``; truth holds ``T_world_r1`` (identity),
        ``T_world_r2``, ``T_flange_cam0``, ``T_world_cam1``, ``T_world_board``, ``T_flange_board2``,
        ``T_flange_torch`` ((4, 4), m) and the ``cam0`` / ``cam1`` parameter vectors.
    """
    from jcalib.geometry.targets import Checkerboard

    rng = np.random.default_rng(seed)
    geo = np.random.default_rng(54321)  # the layout is the same for every seed
    boards = {"board": Checkerboard(cols=9, rows=6, square=0.03), "board2": Checkerboard(cols=7, rows=5, square=0.03)}
    pts = {n: np.asarray(b.points, np.float64) for n, b in boards.items()}
    T_world_board = np.eye(4)
    T_world_board[:3, :3] = _rot((1, 0, 0), np.pi)
    T_world_board[:3, 3] = [0.7, -0.1, 0.0]
    centre = T_world_board[:3, :3] @ pts["board"].mean(axis=0) + T_world_board[:3, 3]
    T_world_r2 = np.eye(4)
    T_world_r2[:3, :3] = _rot((0.05, -0.03, 1.0), 2.4)
    T_world_r2[:3, 3] = [1.7, 0.9, 0.05]
    T_flange_cam0 = np.eye(4)
    T_flange_cam0[:3, :3] = _rot((0.2, 0.1, 1.0), 0.3)
    T_flange_cam0[:3, 3] = [0.06, -0.03, 0.08]
    T_flange_board2 = np.eye(4)
    T_flange_board2[:3, :3] = _rot((0.1, -0.2, 1.0), 0.5)
    T_flange_board2[:3, 3] = [-0.09, -0.06, 0.04]
    T_flange_torch = np.eye(4)
    T_flange_torch[:3, 3] = [0.015, 0.01, 0.21]
    T_world_cam1 = _look_at(np.array([1.2, 0.5, 0.6]), centre + np.array([0.05, 0.1, 0.1]))
    true = {"T_world_r1": np.eye(4), "T_world_r2": T_world_r2, "T_flange_cam0": T_flange_cam0,
            "T_world_cam1": T_world_cam1, "T_world_board": T_world_board, "T_flange_board2": T_flange_board2,
            "T_flange_torch": T_flange_torch, "cam0": SYNTH_FLANGE_PARAMS.copy(), "cam1": SYNTH_FIXED_PARAMS.copy()}
    cams = {c: camera_model_from_name("opencv5", SYNTH_IMAGE_SIZE, true[c]) for c in ("cam0", "cam1")}

    def project(cam, T_cam_x, P):
        return _synth_project(cams[cam], T_cam_x, P)

    def look(eye, at):  # a camera pose at eye looking at `at`, rolled at random
        T = _look_at(eye, at + geo.normal(scale=0.03, size=3), up=(1.0, 0.0, 0.0))
        T[:3, :3] = T[:3, :3] @ _rot((0, 0, 1), geo.uniform(-0.6, 0.6))
        return T

    def facing(T_world_cam, dist):  # a board2 pose in front of a camera, tilted, printed face to it
        c = np.array([geo.uniform(-0.06, 0.06), geo.uniform(-0.05, 0.05), dist])
        T = T_world_cam.copy()
        T[:3, :3] = T_world_cam[:3, :3] @ _rot(geo.normal(size=3), geo.uniform(0.1, 0.6))
        T[:3, 3] = T_world_cam[:3, :3] @ c + T_world_cam[:3, 3] - T[:3, :3] @ pts["board2"].mean(axis=0)
        return T

    stations = []  # (F1 or None, F2 or None) true flange poses in each robot's base
    while len(stations) < num_board_stations:
        dirn = np.array([geo.uniform(-0.5, 0.5), geo.uniform(-0.5, 0.5), 1.0])
        T_wc = look(centre + geo.uniform(0.35, 0.6) * dirn / np.linalg.norm(dirn), centre)
        if project("cam0", _inv(T_wc) @ T_world_board, pts["board"])[1].all():
            stations.append((T_wc @ _inv(T_flange_cam0), None))
    while len(stations) < num_board_stations + num_r2_stations:
        T_wb = facing(T_world_cam1, geo.uniform(0.45, 0.7))
        if project("cam1", _inv(T_world_cam1) @ T_wb, pts["board2"])[1].all():
            stations.append((None, _inv(T_world_r2) @ T_wb @ _inv(T_flange_board2)))
    hold = np.array([1.0, 0.45, 0.35])
    while len(stations) < num_board_stations + num_r2_stations + num_cross_stations:
        dirn = np.array([geo.uniform(-0.6, 0.2), geo.uniform(-0.6, 0.0), geo.uniform(0.2, 0.6)])
        T_wc = look(hold + geo.uniform(0.4, 0.55) * dirn / np.linalg.norm(dirn), hold)
        T_wb = facing(T_wc, np.linalg.norm(T_wc[:3, 3] - hold))
        if project("cam0", _inv(T_wc) @ T_wb, pts["board2"])[1].all():
            stations.append((T_wc @ _inv(T_flange_cam0), _inv(T_world_r2) @ T_wb @ _inv(T_flange_board2)))
    while len(stations) < num_board_stations + num_r2_stations + num_cross_stations + num_tool_stations:
        p_cam = np.array([geo.uniform(-0.08, 0.08), geo.uniform(-0.06, 0.06), geo.uniform(0.5, 0.7)])
        p_world = T_world_cam1[:3, :3] @ p_cam + T_world_cam1[:3, 3]
        T_wf = np.eye(4)
        T_wf[:3, :3] = _rot((1, 0, 0), np.pi) @ _rot(geo.normal(size=3), geo.uniform(0.1, 0.7))
        T_wf[:3, 3] = p_world - T_wf[:3, :3] @ T_flange_torch[:3, 3]
        stations.append((None, _inv(T_world_r2) @ T_wf))

    out = []
    for i, (F1, F2) in enumerate(stations):
        W1 = F1
        W2 = None if F2 is None else T_world_r2 @ F2
        dets = []
        views = []
        if W1 is not None and W2 is not None:
            views.append(("cam0", W1 @ T_flange_cam0, "board2", W2 @ T_flange_board2))
        elif W1 is not None:
            views += [("cam0", W1 @ T_flange_cam0, "board", T_world_board), ("cam1", T_world_cam1, "board", T_world_board)]
        elif i < num_board_stations + num_r2_stations:
            views.append(("cam1", T_world_cam1, "board2", W2 @ T_flange_board2))
        for cam, T_wc, tgt, T_wt in views:
            u, ok = project(cam, _inv(T_wc) @ T_wt, pts[tgt])
            idx = np.flatnonzero(ok)
            if idx.size >= MIN_POINTS_PER_VIEW:
                px = u[idx] + sigma_px * rng.normal(size=(idx.size, 2))
                dets.append({"camera": cam, "target": tgt, "point_index": idx.tolist(), "pixels": px.tolist()})
        if F1 is None and i >= num_board_stations + num_r2_stations:
            tip = W2[:3, :3] @ T_flange_torch[:3, 3] + W2[:3, 3]
            u, ok = project("cam1", _inv(T_world_cam1), tip[None])
            if ok[0]:
                dets.append({"camera": "cam1", "tool": "torch", "pixel": (u[0] + tip_sigma_px * rng.normal(size=2)).tolist()})
        flange = {r: _perturb(F, rng, robot_m, robot_deg).tolist() for r, F in (("r1", F1), ("r2", F2)) if F is not None}
        out.append({"id": f"s{i:03d}", "flange_poses": flange, "detections": dets})
    K1, d1 = cams["cam1"].to_opencv()
    noise = {"pose_noise": {"translation_m": robot_m, "rotation_deg": robot_deg}}
    cell = {
        "schema": "jcalib.cell/1",
        "robots": {"r1": dict(noise), "r2": dict(noise)},
        "cameras": {
            "cam0": {"model": "opencv5", "mount": "flange", "robot": "r1"},
            "cam1": {"model": "opencv5", "mount": "world",
                     "intrinsics": {"K": np.asarray(K1).tolist(), "dist": np.asarray(d1).tolist()}},
        },
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03, "mount": "world"},
                    "board2": {"type": "checkerboard", "cols": 7, "rows": 5, "square": 0.03, "mount": "flange",
                               "robot": "r2"}},
        "tools": {"torch": {"observed_by": ["cam1"], "robot": "r2"}},
    }
    obs = {"schema": "jcalib.observations/1",
           "cameras": {c: {"image_size": list(SYNTH_IMAGE_SIZE)} for c in ("cam0", "cam1")},
           "targets": {n: {"points": p.tolist()} for n, p in pts.items()}, "stations": out}
    return cell, obs, true
