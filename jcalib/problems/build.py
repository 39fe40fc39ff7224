"""The one builder: a cell graph and its start -> the engine's :class:`jcalib.solve.Problem`.

Unknowns (names as in the result file):

- ``intrinsics:<cam>``: every camera's intrinsic vector (order ``model.param_names``; ``fix`` holds
  entries, ``aspect`` ties ``fy`` to ``fx``);
- every camera's and target's pose on its holder: ``T_<frame>_<x>`` (fixed in the cell, the rig
  frame of a cell without robots) or ``T_flange_<x>`` (on a flange); held when listed in ``fixed``;
- ``T_flange_<tool>``: each tool's TCP; its translation always, the tilt of its z axis when imaged
  tool axes determine it (the rotation about the axis itself is held);
- ``T_world_<robot>``: each robot's base (several robots; the gauge robot's is held);
- ``point:<name>``: each cell point (held when the spec gives its position);
- ``lens:<cam>``: a zoom lens's function coefficients (:mod:`jcalib.problems.lens`), for cameras with ``lens:``;
- ``kinematics:<robot>``: a robot's kinematic parameters (``calibrate_kinematics``; an identifiable
  subset free, :mod:`jcalib.problems.kinematics`), whose flange poses are then per-station unknowns
  tied to the kinematics at the station's joints (factor ``kinematic:<robot>``) instead of the pose prior;
- per station: each robot's flange pose (``T_base_flange`` / ``T_<robot>_flange``) under the robot's
  pose-noise prior, or constant (exact) without the pose model; each free target's pose
  (``T_<frame>_<target>``). Per-station kinds are eliminated by Schur complement; where one factor
  would touch two of them, a vertex cover keeps the fewest in the dense system.

Factor groups (one per pair of things, one residual function per configuration): target corners
(pose-chain reprojection, pixels), tool tips (the tool frame's origin through the chain, pixels),
tool-axis points (distance from the projected axis, pixels), contacts (tip minus point, m), pose
measurements (rotation and translation halves), tool tips measured by point sensors (m), priors. Corners are laid out in runs of one view
(``FactorGroup.chunk``), padded with zero-weight copies: the normal equations are summed per view
with one matrix product.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import conversions
from jcalib.geometry.targets import warp_bow
from jcalib.problems.graph import FREE, Graph
from jcalib.problems.start import Start
from jcalib.residuals.losses import CauchyLoss, HuberLoss, TrivialLoss
from jcalib.residuals.pose import axis_translation_prior, contact, kinematic, pose_measurement, position_measurement
from jcalib.residuals.reprojection import reprojection, tool_axis, warped_reprojection, zoom_reprojection
from jcalib.solve import SE3, Euclidean, FactorGroup, Problem, Variable, replace

#: Residual kinds and their unit.
KINDS = {"corner": "px", "corner_mean": "px", "tip": "px", "axis": "px", "contact": "m",
         "pose_rotation": "rad", "pose_translation": "m", "position": "m"}

#: Kinds of target corners: one image each, or the mean of a static scene's repeated images.
CORNER_KINDS = ("corner", "corner_mean")

#: Length along the tool axis (m) of the segment whose projection is the imaged axis line.
AXIS_LENGTH_M = 0.05


def se3_params(T) -> np.ndarray:
    """(..., 4, 4) -> (..., 7) ``wxyz_xyz``."""
    return np.asarray(conversions.matrix_to_pose(np.asarray(T, np.float64)))


def start_params(T) -> np.ndarray:
    """(4, 4) -> (7,) of a start value computed by a closed form, its rotation projected onto the nearest
    rotation first (a closed form on near-degenerate motion can return one a little off orthonormal)."""
    T = np.array(T, np.float64)
    U, _, Vt = np.linalg.svd(T[:3, :3])
    T[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return se3_params(T)


def se3_matrix(p) -> np.ndarray:
    """(..., 7) ``wxyz_xyz`` -> (..., 4, 4)."""
    return np.asarray(conversions.pose_to_matrix(np.asarray(p, np.float64)))


@dataclass
class Group:
    """Bookkeeping of one measurement factor group (host side).

    Attributes:
        name, kind (a key of :data:`KINDS`), key: the two names it connects.
        stations: ``(n,)`` station index of each real observation; ``index``: ``(n,)`` target point
            index (corners) or -1; ``pad``: ``(n,)`` position of each observation in the group's arrays.
        size: the group's number of observations ``K`` (with the fill of short views).
        robust: the group's observations can be rejected as outliers.
    """

    name: str
    kind: str
    key: tuple[str, str]
    stations: np.ndarray
    index: np.ndarray
    pad: np.ndarray
    size: int
    robust: bool


@dataclass
class Built:
    """The problem of a cell and how to read it back.

    Attributes:
        problem: the engine problem (unit weights, stated σ).
        groups: the measurement factor groups.
        sigma: kind -> stated σ.
        flange_entry: robot -> ``(N,)`` entry of each station in its flange-pose variable (-1: none).
        free_entry: free target -> station index -> entry of its pose variable.
        transforms: reported transform names, in order; ``pose_model``: robot -> on/off.
        calibrated: transform name -> tangent coordinates estimated (``rx``..``tz``).
        priors: names that carried a prior from a previous result.
        pose_sqrt_info: robot -> ``(6, 6)`` square-root information of one flange-pose correction.
        warps: targets whose warp (``warp:<target>``, :func:`jcalib.residuals.reprojection.warped_reprojection`)
            is estimated.
        kinematics: robot -> :class:`jcalib.problems.kinematics.Selection` of the robots whose kinematic
            parameters (``kinematics:<robot>``) are estimated; ``kinematic_noise``: robot -> where the
            repeatability σ of its flange poses came from.
    """

    problem: Problem
    groups: list[Group]
    sigma: dict[str, float]
    flange_entry: dict[str, np.ndarray]
    free_entry: dict[str, dict[int, int]]
    transforms: list[str]
    pose_model: dict[str, bool]
    calibrated: dict[str, list[str]]
    priors: list[str] = field(default_factory=list)
    pose_sqrt_info: dict[str, np.ndarray] = field(default_factory=dict)
    warps: list[str] = field(default_factory=list)
    kinematics: dict = field(default_factory=dict)
    kinematic_noise: dict[str, str] = field(default_factory=dict)

    def with_weights(self, weights: dict[str, np.ndarray], scale: dict[str, float] | None = None,
                     views: dict[str, np.ndarray] | None = None) -> Problem:
        """The problem with per-observation weights (0 = rejected), per-kind variance factors and
        per-view variance factors (``views``: group -> ``(n,)`` factor of each observation's view)."""
        by_name = {gr.name: gr for gr in self.groups}
        factors = []
        for f in self.problem.factors:
            gr = by_name.get(f.name)
            if gr is not None:
                w = np.zeros(gr.size)
                w[gr.pad] = weights[gr.name]
                if views and gr.name in views:
                    w[gr.pad] /= np.sqrt(views[gr.name])
                sigma = self.sigma[gr.kind] * (1.0 if scale is None else float(np.sqrt(scale.get(gr.kind, 1.0))))
                f = replace(f, sqrt_weight=w, sigma=np.asarray(sigma, np.float64))
            factors.append(f)
        return replace(self.problem, factors=tuple(factors))

    def unit_weights(self) -> dict[str, np.ndarray]:
        return {gr.name: np.ones(gr.stations.shape[0]) for gr in self.groups}

    def view_factors(self, station_ids: list[str], factors: dict[str, float]) -> dict[str, np.ndarray]:
        """Group -> ``(n,)`` per-observation factors from ``{"<camera>/<station id>": factor}`` (1 if absent)."""
        out = {}
        for gr in self.groups:
            if gr.kind == "corner":
                out[gr.name] = np.array([factors.get(f"{gr.key[0]}/{station_ids[int(k)]}", 1.0)
                                         for k in gr.stations])
        return out


def _lookup(entry: dict[int, int], stations: np.ndarray) -> np.ndarray:
    """``entry[k]`` of every station index ``k`` (a table lookup: there is one per corner)."""
    if not len(entry):
        if np.size(stations):
            raise KeyError(int(np.ravel(stations)[0]))
        return np.zeros(np.shape(stations), np.int32)
    keys = np.fromiter(entry.keys(), np.int64, len(entry))
    table = np.full(int(keys.max()) + 1, -1, np.int32)
    table[keys] = np.fromiter(entry.values(), np.int64, len(entry))
    st = np.asarray(stations, np.int64)
    out = np.where((st >= 0) & (st < table.size), table[np.clip(st, 0, table.size - 1)], -1)
    if np.any(out < 0):
        raise KeyError(int(st[out < 0].ravel()[0]))
    return out.astype(np.int32)


def loss_of(options):
    if options.loss == "huber":
        return HuberLoss(options.loss_scale)
    if options.loss == "cauchy":
        return CauchyLoss(options.loss_scale)
    return TrivialLoss()


#: σ of each value of a splined lens model's spline (stereographic units, about 0.1·f pixels) in the
#: prior that regularises it towards an ideal stereographic lens. The data determine every spline value
#: near observed corners far more precisely (pixel noise / f); the prior decides only what they do not:
#: control points no corner reaches, and the directions in which the spline, the core (fx, fy, cx, cy)
#: and the camera frame's rotation can stand in for one another (it picks the smallest spline).
SPLINE_PRIOR_SIGMA = 0.1


#: σ of the prior that keeps calibrated kinematic parameters near their nominal values (m, rad): a robot's
#: real geometry is within a few millimetres and tenths of a degree of its data sheet, far wider than what
#: usable stations determine (hundredths), so the prior decides only directions the motion barely excites
#: and keeps the solve out of far-away minima there (the result warns about such parameters).
KINEMATIC_PRIOR_SIGMA = {"m": 5e-3, "rad": float(np.radians(1.0))}


def kinematic_prior_sigma(model) -> np.ndarray:
    """``(P,)`` prior σ of each kinematic parameter (:data:`KINEMATIC_PRIOR_SIGMA`, by its unit)."""
    angle = ("theta", "alpha", "beta", "rx", "ry", "rz")
    return np.array([KINEMATIC_PRIOR_SIGMA["rad" if n.rsplit(".", 1)[-1] in angle else "m"]
                     for n in model.param_names])


def sqrt_info(cov: np.ndarray) -> np.ndarray:
    """Pseudo-inverse square root ``S`` (``SᵀS = Σ⁺``) of a covariance; zero rows where Σ has no variance."""
    cov = 0.5 * (np.asarray(cov, np.float64) + np.asarray(cov, np.float64).T)
    w, U = np.linalg.eigh(cov)
    keep = w > max(float(np.max(w)), 0.0) * 1e-12
    inv = np.where(keep, 1.0 / np.sqrt(np.where(keep, w, 1.0)), 0.0)
    return inv[:, None] * U.T


class _Builder:
    def __init__(self, g: Graph, start: Start, options, pose_model: dict[str, bool], priors: dict):
        self.g, self.s, self.o = g, start, options
        self.pose_model = pose_model
        self.prior_for = priors  # name -> (mean params, sqrt_info)
        self.used_priors: list[str] = []
        self.variables: dict[str, Variable] = {}
        self.per_station: dict[str, tuple[str, object]] = {}  # variable -> ("flange", robot) | ("free", target)
        self.flange_entry: dict[str, np.ndarray] = {}
        self.free_entry: dict[str, dict[int, int]] = {}
        self.factors: list[FactorGroup] = []
        self.groups: list[Group] = []
        self.chains: list[tuple[str, ...]] = []  # per factor: the per-station variables it touches
        self.calibrated: dict[str, list[str]] = {}
        self.transforms: list[str] = []
        self.pose_sqrt_info: dict[str, np.ndarray] = {}
        self.warps: list[str] = []
        self.kinematic: dict[str, object] = {r: None for r in g.kinematic_robots}  # robot -> Selection
        self.kinematic_noise: dict[str, str] = {}

    # ------------------------------------------------------------------------- variables

    def fixed_names(self, spec, name: str) -> bool:
        return spec.name in self.g.cell.fixed or name in self.g.cell.fixed

    def add(self, name: str, manifold, value, fixed=False, key=None, **kw) -> None:
        key = key or name
        if key in self.prior_for:
            mean, S = self.prior_for[key]
            self.used_priors.append(key)
            kw.update(prior_mean=np.asarray(mean, np.float64), prior_sqrt_info=np.asarray(S, np.float64))
        self.variables[name] = Variable(name, manifold, value, fixed=fixed, **kw)

    def station_variables(self) -> None:
        g, s = self.g, self.s
        for r in g.used_robots:
            name = g.flange_name(r)
            stations = np.flatnonzero(g.need[r])
            self.flange_entry[r] = np.where(g.need[r], np.cumsum(g.need[r]) - 1, -1)
            meas = se3_params(g.flange[r][stations])
            label = "station {i} flange pose" if not g.multi else f"station {{i}} {r} flange pose"
            self.per_station[name] = ("flange", r)
            if r in self.kinematic:
                self.kinematic_variables(r, name, stations, meas, label)
            elif self.pose_model[r]:
                spec = g.robot_specs[r]
                trans = np.asarray(spec.pose_noise_translation_m, np.float64)
                rot = spec.pose_noise_rotation_deg
                rot_exact = rot is None
                rot = np.zeros(3) if rot_exact else np.radians(np.asarray(rot, np.float64))
                S = np.diag(np.concatenate([np.where(rot > 0, 1.0 / np.where(rot > 0, rot, 1.0), 0.0), 1.0 / trans]))
                fixed = np.array([rot_exact] * 3 + [False] * 3)
                self.pose_sqrt_info[r] = S
                self.variables[name] = Variable(name, SE3(), meas, fixed=fixed, prior_mean=meas, prior_sqrt_info=S,
                                                eliminate=True, entry_label=label)
            else:
                self.variables[name] = Variable(name, SE3(), meas, constant=True, entry_label=label)
        for t in g.free_things():
            poses = s.free[t]
            ks = sorted(poses)
            name = g.free_name(t)
            self.free_entry[t] = {k: i for i, k in enumerate(ks)}
            self.per_station[name] = ("free", t)
            self.variables[name] = Variable(name, SE3(), se3_params(np.stack([poses[k] for k in ks])), eliminate=True,
                                            entry_label=f"station {{i}} {t} pose")

    def kinematic_variables(self, r: str, name: str, stations: np.ndarray, meas: np.ndarray, label: str) -> None:
        """A robot whose kinematics is calibrated: its parameters ``kinematics:<robot>`` (the identifiable
        subset free), each station's flange pose unknown (started at the measured one) and tied to the
        kinematics at the station's joints by the robot's repeatability (:func:`kinematic`)."""
        g = self.g
        model = g.robot_specs[r].kinematics
        S, how = g.kinematic_noise[r]
        q = g.joints[r][stations]
        sel = g.kinematics[r]
        self.kinematic[r] = sel
        self.kinematic_noise[r] = how
        self.pose_sqrt_info[r] = S
        self.variables[name] = Variable(name, SE3(), meas, eliminate=True, entry_label=label)
        kname = f"kinematics:{r}"
        nominal = np.asarray(model.nominal, np.float64)
        self.add(kname, Euclidean(model.num_params), nominal[None, :], fixed=~sel.free[None, :], key=kname,
                 coord_names=list(model.param_names), entry_label=f"{g.label(r)} kinematics", prior_mean=nominal,
                 prior_sqrt_info=np.diag(np.where(sel.free, 1.0 / kinematic_prior_sigma(model), 0.0)))
        n = stations.size
        fn, jac = kinematic(model)
        self.factors.append(FactorGroup(
            f"kinematic:{r}", fn, (kname, name), (np.zeros(n, np.int32), np.arange(n, dtype=np.int32)),
            (q, np.broadcast_to(S, (n, 6, 6)).copy()), jacobian=jac))
        self.chains.append((name,))

    def shared_variables(self) -> None:
        g, s, cell = self.g, self.s, self.g.cell
        for cam in cell.cameras.values():
            if cam.name not in s.models:
                continue  # a pose sensor: no intrinsics
            model = s.models[cam.name]
            params = np.asarray(model.params, np.float64)
            kw = {}
            if model.name == "splined":  # the spline's regularisation (see SPLINE_PRIOR_SIGMA)
                spline = np.arange(params.size) > list(model.param_names).index("fov_x_deg")
                kw = dict(prior_mean=np.where(spline, 0.0, params),
                          prior_sqrt_info=np.diag(np.where(spline, 1.0 / SPLINE_PRIOR_SIGMA, 0.0)))
            self.add(f"intrinsics:{cam.name}", Euclidean(len(model.param_names)), params[None, :],
                     fixed=s.fixed_masks[cam.name][None, :], key=cam.name, coord_names=list(model.param_names),
                     entry_label=cam.name, **kw)
            ls = s.lenses.get(cam.name)
            if ls is not None:  # a zoom lens: its functions' further control points (jcalib.problems.lens)
                cols = ["log_fx", "log_fy"] + list(model.param_names)[2:] + ["shift_m"]
                rows = ls.lens.size // len(cols)
                self.add(f"lens:{cam.name}", Euclidean(ls.lens.size), ls.lens[None, :], fixed=ls.fixed[None, :],
                         key=f"lens:{cam.name}", coord_names=[f"{c}@{i + 1}" for i in range(rows) for c in cols],
                         entry_label=f"{cam.name} lens")
        for spec in list(cell.cameras.values()) + list(cell.targets.values()):
            name = g.mount_name(spec)
            if name is None or name in self.variables:
                continue
            if g.reference_camera is not None and spec.name == g.reference_camera and spec.name in cell.cameras:
                self.variables[name] = Variable(name, SE3(), se3_params(np.eye(4)), constant=True)
                continue
            fixed = self.fixed_names(spec, name)
            if fixed and spec.pose is None:
                raise BadInputError(f"{cell.source}: fixed lists '{spec.name}' ({name}) but the cell gives it no pose; "
                                    "add pose: [[4x4]] (m) or remove it from fixed")
            if name not in s.known:  # nothing observes it and the cell gives no pose
                what = "sensor" if spec.name in cell.sensors else "camera" if spec.name in cell.cameras else "target"
                raise NotObservableError(f"{cell.source}: {what} '{spec.name}' ({name}) is in the cell but no station "
                                         "observes it, so nothing determines its pose; remove it from the cell or add "
                                         "stations that show it", [name])
            self.transforms.append(name)
            self.calibrated[name] = [] if fixed else ["rx", "ry", "rz", "tx", "ty", "tz"]
            self.add(name, SE3(), start_params(s.known[name]), fixed=fixed)
        for tool in cell.tools.values():
            name = f"T_flange_{tool.name}"
            held = name in cell.fixed or tool.name in cell.fixed
            tilt = bool(s.tool_axes.get(tool.name)) and not held
            fixed = np.array([not tilt, not tilt, True, held, held, held])
            self.transforms.append(name)
            self.calibrated[name] = [c for c, f in zip(("rx", "ry", "rz", "tx", "ty", "tz"), fixed) if not f]
            self.add(name, SE3(), start_params(s.known[name]), fixed=fixed)
        for r in g.used_robots:
            name = g.base_name(r)
            if name is not None:
                self.transforms.append(name)
                held = g.held_base(r)
                self.calibrated[name] = [] if held else ["rx", "ry", "rz", "tx", "ty", "tz"]
                self.add(name, SE3(), start_params(s.known[name]), fixed=held)
        for t in sorted({t for _, t in g.pairs}):
            if cell.targets[t].warp:
                self.warps.append(t)
                self.add(f"warp:{t}", Euclidean(2), np.zeros((1, 2)), key=f"warp:{t}", coord_names=["c0", "c1"],
                         entry_label=f"{t} warp")
        for point, spec in cell.points.items():
            fixed = spec.position is not None or point in cell.fixed
            if point in cell.fixed and spec.position is None:
                raise BadInputError(f"{cell.source}: fixed lists point '{point}' but the cell gives it no position; add "
                                    "position: [x, y, z] (m) or remove it from fixed")
            self.add(f"point:{point}", Euclidean(3), s.points[point][None, :], fixed=np.full((1, 3), fixed),
                     key=f"point:{point}", entry_label=f"point {point}")

    # ------------------------------------------------------------------------- chains

    def side(self, spec, thing: str, inverted: bool) -> list[tuple[str, bool]]:
        """The chain of a thing's cell-frame pose (output side first), inverted for a camera."""
        g = self.g
        h = g.holder(spec)
        if h == FREE:
            out = [g.free_name(thing)]
        else:
            out = [] if h is None else [x for x in (g.base_name(h), g.flange_name(h)) if x is not None]
            m = g.mount_name(spec)
            if m is not None:
                out.append(m)
        if inverted:
            return [(n, True) for n in reversed(out)]
        return [(n, False) for n in out]

    def chain(self, cam_spec, cam: str, other_spec, other: str):
        """``(argument names, chain)`` of ``p_cam = W_cam⁻¹ · W_other · p`` (holders in common cancel)."""
        left = self.side(cam_spec, cam, True)
        right = self.side(other_spec, other, False)
        while left and right and left[-1][0] == right[0][0]:
            left, right = left[:-1], right[1:]  # one robot holds both (base and flange cancel): a static pair
        return self._args(left + right)

    def _args(self, items):
        args, chain = [], []
        for n, inv in items:
            if n not in args:
                args.append(n)
            chain.append((args.index(n), inv))
        return tuple(args), tuple(chain)

    def indices(self, args, stations: np.ndarray) -> tuple[np.ndarray, ...]:
        out = []
        for a in args:
            kind = self.per_station.get(a)
            if kind is None:
                out.append(np.zeros(stations.shape, np.int32))
            elif kind[0] == "flange":
                out.append(self.flange_entry[kind[1]][stations].astype(np.int32))
            else:
                out.append(_lookup(self.free_entry[kind[1]], stations))
        return tuple(out)

    def aspect(self, cam: str, n: int) -> np.ndarray:
        return np.broadcast_to(np.asarray(self.s.aspects[cam], np.float64), (n, 2)).copy()

    def camera_config(self, cam: str):
        model = self.s.models[cam]
        return type(model), tuple(int(v) for v in model.image_size), bool(model.has_skew)

    def factor(self, group: Group, f: FactorGroup, args) -> None:
        self.factors.append(f)
        self.groups.append(group)
        self.chains.append(tuple(a for a in args if a in self.per_station
                                 and not self.variables[a].constant))

    # ------------------------------------------------------------------------- factor groups

    def corners(self) -> None:
        g, cell, loss = self.g, self.g.cell, loss_of(self.o)
        for (c, t), p in g.pairs.items():
            args, chain = self.chain(cell.cameras[c], c, cell.targets[t], t)
            counts = np.array([x.shape[0] for x in p.points])
            chunk = int(-(-counts.max() // 8) * 8)
            first = np.concatenate([[0], np.cumsum(counts)[:-1]])
            pad = np.repeat(np.arange(len(counts)) * chunk, counts) + np.arange(counts.sum()) - np.repeat(first, counts)
            fill = np.repeat(first, chunk)  # each run starts as copies of its view's first corner
            pts, pix = np.concatenate(p.points), np.concatenate(p.pixels)
            points, pixels = pts[fill], pix[fill]
            points[pad], pixels[pad] = pts, pix
            runs = np.repeat(np.asarray(p.views, np.int32), chunk)
            name = f"corners:{c}/{t}"
            arguments = (f"intrinsics:{c}",) + args
            indices = (np.zeros_like(runs),) + self.indices(args, runs)
            obs = (points, pixels, self.aspect(c, runs.size))
            ls = self.s.lenses.get(c)
            if ls is not None and t in self.warps:
                raise BadInputError(f"{cell.source}: target '{t}' (warp: true) seen by camera '{c}' with a zoom lens: "
                                    "the two together are not supported yet; drop one")
            if ls is not None:
                fn, jac = zoom_reprojection(*self.camera_config(c), chain)
                arguments, indices = arguments + (f"lens:{c}",), indices + (np.zeros_like(runs),)
                obs = obs + (ls.basis[runs],)
            elif t in self.warps:
                fn, jac = warped_reprojection(*self.camera_config(c), chain)
                arguments, indices = arguments + (f"warp:{t}",), indices + (np.zeros_like(runs),)
                obs = obs + (warp_bow(points, np.asarray(g.obs.targets[t], np.float64)),)
            else:
                fn, jac = reprojection(*self.camera_config(c), chain)
            f = FactorGroup(name, fn, arguments, indices, obs, sigma=self.o.sigma_px, loss=loss, chunk=chunk,
                            jacobian=jac, sqrt_weight=_ones_at(runs.size, pad))
            stations = np.repeat(np.asarray(p.views), counts)
            kind = "corner" if p.images == 1 else "corner_mean"
            self.factor(Group(name, kind, (c, t), stations, np.concatenate(p.point_index), pad, runs.size, True),
                        f, args)

    def tips_and_axes(self) -> None:
        g, cell, loss = self.g, self.g.cell, loss_of(self.o)
        for (c, tool), tp in g.tips.items():
            args, chain = self.chain(cell.cameras[c], c, cell.tools[tool], tool)
            st = np.asarray(tp.stations, np.int32)
            n = st.size
            fn, jac = reprojection(*self.camera_config(c), chain)
            name = f"tips:{c}/{tool}"
            f = FactorGroup(name, fn, (f"intrinsics:{c}",) + args, (np.zeros_like(st),) + self.indices(args, st),
                            (np.zeros((n, 3)), np.stack(tp.pixels), self.aspect(c, n)), sigma=self.o.tip_sigma_px,
                            loss=loss, jacobian=jac)
            self.factor(Group(name, "tip", (c, tool), st, np.full(n, -1), np.arange(n), n, True), f, args)
            if not self.s.tool_axes.get(tool):
                continue
            counts = np.array([len(a) for a in tp.axis])
            if counts.sum() == 0:
                continue
            st_axis = np.repeat(st, counts)
            m = st_axis.size
            fn, jac = tool_axis(*self.camera_config(c), chain)
            name = f"axis:{c}/{tool}"
            f = FactorGroup(name, fn, (f"intrinsics:{c}",) + args, (np.zeros_like(st_axis),) + self.indices(args, st_axis),
                            (np.concatenate([a for a in tp.axis if len(a)]), np.full(m, AXIS_LENGTH_M), self.aspect(c, m)),
                            sigma=self.o.axis_sigma_px, loss=loss, jacobian=jac)
            self.factor(Group(name, "axis", (c, tool), st_axis, np.full(m, -1), np.arange(m), m, True), f, args)

    def contacts(self) -> None:
        g, cell, loss = self.g, self.g.cell, loss_of(self.o)
        for (tool, point), ct in g.contacts.items():
            args, chain = self._args(self.side(cell.tools[tool], tool, False))
            st = np.asarray(ct.stations, np.int32)
            n = st.size
            fn, jac = contact(chain)
            name = f"contacts:{tool}/{point}"
            f = FactorGroup(name, fn, args + (f"point:{point}",), self.indices(args, st) + (np.zeros_like(st),),
                            np.zeros((n, 1)), sigma=self.o.contact_sigma_m, jacobian=jac, loss=loss)
            self.factor(Group(name, "contact", (tool, point), st, np.full(n, -1), np.arange(n), n, False), f, args)

    def pose_measurements(self) -> None:
        g, cell = self.g, self.g.cell
        for (c, t), pm in g.poses.items():
            args, chain = self.chain(cell.cameras[c], c, cell.targets[t], t)
            st = np.asarray(pm.stations, np.int32)
            n = st.size
            obs = se3_params(np.stack(pm.T_cam_target))
            for part, sigma in (("rotation", np.radians(self.o.pose_sigma_deg)), ("translation", self.o.pose_sigma_m)):
                name = f"pose_{part}:{c}/{t}"
                f = FactorGroup(name, pose_measurement(chain, part), args, self.indices(args, st), obs, sigma=sigma)
                self.factor(Group(name, f"pose_{part}", (c, t), st, np.full(n, -1), np.arange(n), n, False), f, args)

    def positions(self) -> None:
        """Tool tips measured by point sensors (m, σ ``pose_sigma_m`` per axis)."""
        g, cell = self.g, self.g.cell
        for (sensor, tool), ps in g.positions.items():
            args, chain = self.chain(cell.cameras[sensor], sensor, cell.tools[tool], tool)
            st = np.asarray(ps.stations, np.int32)
            n = st.size
            fn, jac = position_measurement(chain)
            name = f"positions:{sensor}/{tool}"
            f = FactorGroup(name, fn, args, self.indices(args, st), np.stack(ps.p_sensor_tool), sigma=self.o.pose_sigma_m,
                            jacobian=jac)
            self.factor(Group(name, "position", (sensor, tool), st, np.full(n, -1), np.arange(n), n, False), f, args)

    def extra_priors(self) -> None:
        fixed = self.s.unobservable_fixed
        if fixed is not None:
            name = fixed["transform"]
            self.factors.append(FactorGroup(
                f"prior:{name} along the rotation axis", axis_translation_prior, (name,), (np.zeros(1, np.int32),),
                (np.asarray(fixed["axis"], np.float64)[None, :], np.array([[fixed["value_m"]]])),
                sigma=fixed["sigma_m"]))
            self.chains.append(())

    def eliminate(self) -> None:
        """Per-station kinds a factor touches together: keep a vertex cover of them in the dense system."""
        edges = {tuple(sorted(set(c))) for c in self.chains if len(set(c)) > 1}
        shared: set[str] = set()
        while edges:
            degree: dict[str, int] = {}
            for e in edges:
                for a in e:
                    degree[a] = degree.get(a, 0) + 1
            pick = max(degree, key=lambda n: (degree[n], -self.variables[n].num))
            shared.add(pick)
            edges = {e for e in edges if pick not in e and len(set(e) - shared) > 1}
        for n in shared:
            v = self.variables[n]
            self.variables[n] = Variable(v.name, v.manifold, v.value, fixed=v.fixed, prior_mean=v.prior_mean,
                                         prior_sqrt_info=v.prior_sqrt_info, eliminate=False,
                                         coord_names=v.coord_names, entry_label=v.entry_label, constant=v.constant)


def _ones_at(size: int, pad: np.ndarray) -> np.ndarray:
    w = np.zeros(size)
    w[pad] = 1.0
    return w


def build(g: Graph, start: Start, options, pose_model: dict[str, bool], priors: dict | None = None) -> Built:
    """The problem of a cell (see the module docstring).

    Args:
        g: the cell graph; start: its closed-form start; options: :class:`CalibrationOptions`.
        pose_model: robot -> whether its flange poses are unknowns under its pose-noise prior.
        priors: name (camera id, transform name, ``point:<name>``) -> ``(mean params, sqrt_info)``
            Gaussian priors, e.g. from a previous result.
    """
    b = _Builder(g, start, options, pose_model, priors or {})
    _check_fixed_names(g)
    b.station_variables()
    b.shared_variables()
    b.corners()
    b.tips_and_axes()
    b.contacts()
    b.pose_measurements()
    b.positions()
    b.extra_priors()
    b.eliminate()
    order = [n for n in b.variables if n in b.per_station] + [n for n in b.variables if n not in b.per_station]
    problem = Problem([b.variables[n] for n in order], b.factors)
    sigma = {"corner": options.sigma_px, "corner_mean": options.sigma_px, "tip": options.tip_sigma_px,
             "axis": options.axis_sigma_px, "contact": options.contact_sigma_m, "pose_rotation": float(np.radians(options.pose_sigma_deg)),
             "pose_translation": options.pose_sigma_m, "position": options.pose_sigma_m}
    return Built(problem, b.groups, sigma, b.flange_entry, b.free_entry, b.transforms, pose_model, b.calibrated,
                 sorted(set(b.used_priors)), b.pose_sqrt_info, b.warps, b.kinematic, b.kinematic_noise)


def _check_fixed_names(g: Graph) -> None:
    """Every name in the cell's ``fixed`` must name something that can be held."""
    import difflib

    cell = g.cell
    names = set(cell.cameras) | set(cell.targets) | set(cell.tools) | set(cell.points) | set(g.robot_names)
    for spec in list(cell.cameras.values()) + list(cell.targets.values()):
        m = g.mount_name(spec)
        if m is not None:
            names.add(m)
    names |= {f"T_flange_{t}" for t in cell.tools} | {f"T_world_{r}" for r in g.robot_names}
    for n in cell.fixed:
        if n not in names:
            close = difflib.get_close_matches(n, sorted(names), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise BadInputError(f"{cell.source}: fixed lists '{n}', which names nothing in the cell{hint}; list camera, "
                                "target, tool, point or robot names, or transform names such as T_base_<camera>")
