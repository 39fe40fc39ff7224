"""Predicted information of candidate stations, from the one problem builder.

A candidate station's observations are what the nominal cell (or a current estimate) predicts: the
target's corners projected exactly, a tool's tip (and, when the tool's orientation is estimated, points
along its shaft). The station is built by the one builder (:func:`jcalib.problems.calibrate.prepare`) as
the only station of the cell, with the calibration's options and σ, and linearised at the nominal values
by :func:`jcalib.solve.information`, which marginalises its own station unknowns (a robot's per-station
flange correction under its pose noise). Stations add information independently of each other, so the
information of a set of stations is the prior's plus the sum of theirs; its inverse is the covariance a
calibration from those stations would report (stated noise), to first order.

Everything is over the **free coordinates** of the cell's shared unknowns (intrinsics, hand-eye, fixed
camera and target poses, TCPs, cell points, kinematics), in the builder's order (:attr:`Predictor.labels`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from jcalib.planning.candidates import Candidates
from jcalib.planning.layout import CellLayout
from jcalib.errors import BadInputError, JcalibError
from jcalib.geometry.se3 import shaft_points
from jcalib.io.goals import Goal, projection_grid, sigma_from_covariance
from jcalib.io.observations import Detection, Observations, Station
from jcalib.io.result import CameraResult, ResultFile, TransformResult
from jcalib.problems.calibrate import prepare
from jcalib.problems.options import CalibrationOptions
from jcalib.problems.taskspace import camera_model, project, projection_jacobian, unproject
from jcalib.solve import information

__all__ = ["GoalMap", "Predictor", "RIDGE"]
#: Ridge per coordinate, relative to a typical candidate's information on that coordinate: keeps the
#: information of a few stations invertible (σ of what they leave undetermined comes out huge, not inf).
RIDGE = 1e-8


@dataclass(frozen=True)
class GoalMap:
    """Where a goal's quantity sits among the free coordinates.

    Attributes:
        goal: the goal.  index: ``(k,)`` coordinates of the variable block (6 for a transform, 3 for a
            point, the intrinsics for a camera) that are free; block: ``(k,)`` their positions in the block.
        size: the block's size.  jacobian: projection goals: ``(g, 2, size)``.
    """

    goal: Goal
    index: np.ndarray
    block: np.ndarray
    size: int
    jacobian: np.ndarray | None = None

    def sigma(self, cov: np.ndarray) -> np.ndarray:
        """The goal's σ from ``(..., n, n)`` covariances over the free coordinates."""
        sub = cov[..., self.index[:, None], self.index[None, :]]
        full = np.zeros(sub.shape[:-2] + (self.size, self.size))
        full[..., self.block[:, None], self.block[None, :]] = sub
        return sigma_from_covariance(self.goal, full, self.jacobian)


class Predictor:
    """Predicted information of stations of a cell at its nominal (or estimated) values.

    Args:
        layout: the nominal cell (:func:`jcalib.planning.layout.cell_layout`).
        goals: what must be accurate.
        options: calibration options (σ of corners, tips, ...); default :class:`CalibrationOptions` with
            stated noise.
        estimate: a result file whose cameras and transforms replace the nominal ones (adaptive capture
            re-linearises at the current estimate).

    Raises:
        BadInputError: a goal names something the cell does not estimate.
    """

    def __init__(self, layout: CellLayout, goals: tuple[Goal, ...], options: CalibrationOptions | None = None,
                 estimate: ResultFile | None = None):
        self.layout, self.spec, self.goals = layout, layout.cell, tuple(goals)
        self.options = replace(options or CalibrationOptions(), noise="stated", loss="none")
        cams = {c: CameraResult.from_model(camera_model_of(cl)) for c, cl in layout.cameras.items()}
        transforms = {}
        for c, cl in layout.cameras.items():
            transforms[f"T_{cl.mount}_{c}"] = cl.pose
        for t, tl in layout.targets.items():
            transforms[f"T_{tl.mount}_{t}"] = tl.pose
        for tool, T in layout.tools.items():
            transforms[f"T_flange_{tool}"] = T
        if estimate is not None:
            cams.update(estimate.cameras)
            transforms.update({n: np.asarray(t.matrix, np.float64) for n, t in estimate.transforms.items()
                               if n in transforms})
        self.cameras = {c: camera_model(e) for c, e in cams.items()}
        self.transforms = transforms
        self.seed = ResultFile(cameras=cams, transforms={n: TransformResult(T) for n, T in transforms.items()})
        self.targets = {t: np.asarray(tl.geometry.points, np.float64) for t, tl in layout.targets.items()}
        self.sizes = {c: tuple(int(s) for s in cl.image_size) for c, cl in layout.cameras.items()}
        robot = self.spec.robot
        self.kinematics = robot.kinematics if robot is not None and robot.calibrate_kinematics else None
        self.names: list[str] = []
        self.labels: list[str] = []
        self._coords: dict[str, np.ndarray] = {}
        self._dims: dict[str, int] = {}
        self._priors: dict[tuple[str, ...], np.ndarray] = {}

    # ------------------------------------------------------------------ predicted stations

    def station(self, T_base_flange: np.ndarray, pair: tuple[str, str], sid: str = "candidate",
                joints_rad: np.ndarray | None = None) -> Station:
        """The station a candidate would give: exact projections at the nominal values. In a cell that
        calibrates its robot's kinematics, the station carries its joints (``joints_rad``, from the
        candidate's inverse kinematics) and its flange pose is the nominal model's at those joints."""
        joints_deg = None
        if self.kinematics is not None and joints_rad is not None:
            from jcalib.geometry.kinematic_models import forward, joints_to_controller

            joints_deg = joints_to_controller(self.kinematics, joints_rad)
            T_base_flange = np.asarray(forward(self.kinematics, self.kinematics.nominal, joints_rad))
        c, thing = pair
        cam = self.layout.cameras[c]
        T_base_cam = self.transforms[f"T_base_{c}"] if cam.mount == "base" else \
            T_base_flange @ self.transforms[f"T_flange_{c}"]
        T_cam_base = np.linalg.inv(T_base_cam)
        if thing in self.targets:
            tl = self.layout.targets[thing]
            T_base_t = self.transforms[f"T_base_{thing}"] if tl.mount == "base" else \
                T_base_flange @ self.transforms[f"T_flange_{thing}"]
            T_ct = T_cam_base @ T_base_t
            P = self.targets[thing]
            pix = project(self.cameras[c], P @ T_ct[:3, :3].T + T_ct[:3, 3])
            det = Detection(camera=c, pixels=pix, target=thing, point_index=np.arange(len(P)))
        else:
            T_ft = self.transforms[f"T_flange_{thing}"]
            T_ct = T_cam_base @ T_base_flange @ T_ft
            q = np.concatenate([np.zeros((1, 3)), shaft_points(T_ft) if self._tool_axis(thing) else np.zeros((0, 3))])
            pix = project(self.cameras[c], q @ T_ct[:3, :3].T + T_ct[:3, 3])
            det = Detection(camera=c, pixels=pix[:1], tool=thing, axis=pix[1:] if len(pix) > 1 else None)
        return Station(sid, (det,), T_base_flange=np.asarray(T_base_flange, np.float64), joints_deg=joints_deg)

    def _tool_axis(self, tool: str) -> bool:
        spec = self.spec.tools[tool]
        return spec.orientation is None and spec.axis is None

    def _observations(self, stations: tuple[Station, ...]) -> Observations:
        return Observations(dict(self.sizes), dict(self.targets), stations)

    def _build(self, stations: tuple[Station, ...]):
        _, _, built = prepare(self.spec, self._observations(stations), self.options, start=self.seed)
        return built

    # ------------------------------------------------------------------ information

    def setup(self, candidates: Candidates) -> None:
        """Fix the free coordinates from a problem holding every candidate (and the goals' positions)."""
        stations = tuple(self.station(T, p, f"c{i}", q) for i, (T, p, q) in enumerate(
            zip(candidates.T_base_flange, candidates.pair, candidates.joints_rad)))
        if not stations:
            raise BadInputError("plan: no candidate station is reachable and shows a target or a tool to a camera; "
                                "check the cell's poses (pose: [[4x4]], m) and the robot preset")
        problem = self._build(stations).problem
        self.names, self.labels = [], []
        for v in problem.variables:
            if v.eliminate or v.constant:
                continue
            free = ~np.asarray(v.fixed).reshape(-1)
            if not free.any():
                continue
            self.names.append(v.name)
            self._dims[v.name] = v.tangent_dim
            self._coords[v.name] = free
            self.labels += [v.coordinate_name(0, j) for j in range(v.tangent_dim) if free[j]]
        self.maps = [self._goal_map(g) for g in self.goals]

    def _offsets(self) -> dict[str, int]:
        out, off = {}, 0
        for n in self.names:
            out[n] = off
            off += int(self._coords[n].sum())
        return out

    @property
    def size(self) -> int:
        return sum(int(self._coords[n].sum()) for n in self.names)

    def _goal_map(self, goal: Goal) -> GoalMap:
        if goal.measures == "projection":
            var = f"intrinsics:{goal.name}"
            if goal.name not in self.spec.cameras:
                raise BadInputError(f"goal {goal.text!r}: no camera {goal.name!r} in the cell (has "
                                    f"{', '.join(self.spec.cameras)})")
        elif goal.is_transform:
            var = goal.name
        else:
            var = f"point:{goal.name}"
        if var not in self.names:
            known = [n for n in self.names if n.startswith("T_")] + [n[6:] for n in self.names if n.startswith("point:")]
            raise BadInputError(f"goal {goal.text!r}: {goal.name} is not estimated in this cell (it is given, held "
                                f"fixed, or nothing observes it); goals can name {', '.join(known) or 'nothing'}"
                                + (", or a camera's projection_px" if self.spec.cameras else ""))
        free = self._coords[var]
        block = np.flatnonzero(free)
        if goal.measures in ("translation", "rotation") and self._dims[var] == 6:
            part = np.arange(3, 6) if goal.measures == "translation" else np.arange(3)
            if not np.isin(part, block).any():
                raise BadInputError(f"goal {goal.text!r}: the {goal.measures} of {goal.name} is not estimated in this "
                                    "cell (held at a given or conventional value); drop the goal")
        index = self._offsets()[var] + np.arange(block.size)
        jac = None
        if goal.measures == "projection":
            model = self.cameras[goal.name]
            rays, ok = unproject(model, projection_grid(self.sizes[goal.name]))
            jac = projection_jacobian(model, rays[ok])
        return GoalMap(goal, index, block, self._dims[var], jac)

    def informations(self, candidates: Candidates) -> np.ndarray:
        """``(M, n, n)`` information each candidate adds (stated noise), over the free coordinates.

        A candidate the builder refuses (too few points in view, ...) gets zero information.
        """
        out = np.zeros((len(candidates), self.size, self.size))
        offsets = self._offsets()
        for i, (T, pair, q) in enumerate(zip(candidates.T_base_flange, candidates.pair, candidates.joints_rad)):
            try:
                built = self._build((self.station(T, pair, joints_rad=q),))
            except JcalibError:
                continue
            names = [v.name for v in built.problem.variables if not v.eliminate and v.name in self._coords]
            if not names:
                continue
            with_data = built.with_weights(built.unit_weights(), None)
            key = tuple(names)
            if key not in self._priors:  # the same for every candidate with these unknowns
                prior_only = built.with_weights({k: np.zeros_like(w) for k, w in built.unit_weights().items()}, None)
                self._priors[key] = information(prior_only, names)
            M = information(with_data, names) - self._priors[key]
            rows, cols, k = [], [], 0
            for n in names:
                d = self._dims[n]
                free = self._coords[n]
                rows.append(k + np.flatnonzero(free))
                cols.append(offsets[n] + np.arange(int(free.sum())))
                k += d
            rows, cols = np.concatenate(rows), np.concatenate(cols)
            out[i][np.ix_(cols, cols)] = M[np.ix_(rows, rows)]
        return 0.5 * (out + np.swapaxes(out, -1, -2))

    def prior_information(self, candidates: Candidates) -> np.ndarray:
        """``(n, n)`` information of the cell's priors (intrinsics std, kinematic prior, ...): the problem of
        all candidates with every measurement weighted 0."""
        stations = tuple(self.station(T, p, f"c{i}", q) for i, (T, p, q) in enumerate(
            zip(candidates.T_base_flange, candidates.pair, candidates.joints_rad)))
        built = self._build(stations)
        prior_only = built.with_weights({k: np.zeros_like(w) for k, w in built.unit_weights().items()}, None)
        return information(prior_only, self.names)[np.ix_(self._free_index(), self._free_index())]

    def _free_index(self) -> np.ndarray:
        """Positions of the free coordinates among all coordinates of :attr:`names`."""
        return np.flatnonzero(np.concatenate([self._coords[n] for n in self.names]))

    def check_start(self, candidates: Candidates) -> None:
        """Refuse stations from which a calibration could not start (its closed forms need what the
        prediction took from the nominal cell, e.g. a fixed camera's rough pose to start a TCP from tips).

        Raises:
            BadInputError: the calibration's own message, prefixed with what it means for the plan.
        """
        stations = tuple(self.station(T, p, f"s{i}", q) for i, (T, p, q) in enumerate(
            zip(candidates.T_base_flange, candidates.pair, candidates.joints_rad)))
        try:
            prepare(self.spec, self._observations(stations), self.options)
        except JcalibError as e:
            raise BadInputError(f"plan --kind optimal: a calibration from the planned stations could not start, so the "
                                f"plan would not reach its prediction: {e}") from None

    def goal_sigmas(self, cov: np.ndarray) -> np.ndarray:
        """``(..., G)`` each goal's σ (its unit) from ``(..., n, n)`` covariances."""
        return np.stack([m.sigma(cov) for m in self.maps], axis=-1)

    def limits(self) -> np.ndarray:
        return np.array([g.limit for g in self.goals])


def camera_model_of(cam_layout):
    """The geometry camera model of a layout camera (nominal intrinsics)."""
    from jcalib.geometry.cameras import camera_from_opencv

    return camera_from_opencv(cam_layout.K, cam_layout.dist, cam_layout.image_size, fisheye=cam_layout.model == "fisheye")
