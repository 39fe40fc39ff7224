"""What would help: the predicted effect of one more station, for any cell.

A *candidate* is a hypothetical station at the current estimate: a view of a target from a new pose
(closer, tilted, in the worst image corner; or the robot turned about a camera axis through the
target), the tool turned about its tip in front of the camera that sees it, or one more contact with
the flange turned about the touched point. Its observations are what the estimate predicts (pixels
exactly on the projections). Its information is computed the way the solve computes every station's:
the candidate is built as a station of the cell by the one builder
(:func:`jcalib.problems.calibrate.prepare`) and linearised at the estimate by
:func:`jcalib.solve.information` (its own station unknowns marginalised). Added to the model's
information it gives the covariance that one more station of that kind would leave.

Candidates exist for every pair the calibration used: each camera/target pair that moves (a free
target, or a robot between them), each camera that sees a tool's tip, each tool touching a cell
point. Static pairs (camera and target on the same holder) are left out: more images of a static
scene add no information (the builder merges them into one view).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from jcalib.errors import JcalibError
from jcalib.geometry.se3 import shaft_points
from jcalib.io.observations import Contact, Detection, Station
from jcalib.io.result import CameraResult, ResultFile, TransformResult
from jcalib.report.model import LinearModel
from jcalib.problems.taskspace import image_grid, project, projection_sigma_at, unproject

__all__ = ["STATION_KINDS", "Candidate", "Suggestion", "candidates", "station_information", "what_would_help"]

#: Candidate kinds: key -> what the station is (``{pair}`` names the camera and target or tool).
STATION_KINDS = {
    "tilt_x": "a view of {target} tilted 40° about the camera X axis ({camera})",
    "tilt_y": "a view of {target} tilted 40° about the camera Y axis ({camera})",
    "closer": "a closer view of {target} (filling ~90 % of the image height of {camera}, tilted 20°)",
    "corner": "a view of {target} in the worst image corner of {camera} (tilted 20°)",
    "rot_x": "a station rotated 30° about the camera X axis ({camera} orbiting {target})",
    "rot_y": "a station rotated 30° about the camera Y axis ({camera} orbiting {target})",
    "rot_z": "a station rotated 30° about the camera Z (optical) axis ({camera} and {target})",
    "tip_x": "a station with {target} turned 30° about the X axis of {camera} through its tip",
    "tip_y": "a station with {target} turned 30° about the Y axis of {camera} through its tip",
    "tip_z": "a station with {target} turned 30° about the optical axis of {camera} through its tip",
    "touch_x": "one more contact of {camera} with {target}, the flange turned 30° about the X axis",
    "touch_y": "one more contact of {camera} with {target}, the flange turned 30° about the Y axis",
    "touch_z": "one more contact of {camera} with {target}, the flange turned 30° about the Z axis",
}
_FREE_KINDS = ("tilt_x", "tilt_y", "closer", "corner")
_ROBOT_KINDS = ("rot_x", "rot_y", "rot_z", "closer", "corner")
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


@dataclass(frozen=True)
class Candidate:
    """One hypothetical station.

    Attributes:
        key: unique name, ``"<camera>/<target or tool> <kind>"`` or ``"<tool>/<point> <kind>"``.
        kind: a key of :data:`STATION_KINDS`; pair: the two names it connects.
        description: what the station is, in words.
        station: the station, as observations hold it (id ``"candidate"``).
        values: start values of its own station unknowns that the builder would not know
            (a free target's pose), ``{variable: (1, 7)}``.
    """

    key: str
    kind: str
    pair: tuple[str, str]
    description: str
    station: Station
    values: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Suggestion:
    """The predicted effect of one more station.

    Attributes:
        kind: the candidate's key; description: what the station is.
        sigma_before, sigma_after: ``{unknown label: σ}`` in display units for the unknowns asked for.
    """

    kind: str
    description: str
    sigma_before: dict[str, float]
    sigma_after: dict[str, float]

    def gain(self, label: str) -> float:
        """σ before / after for one unknown (> 1: the station helps)."""
        return self.sigma_before[label] / max(self.sigma_after[label], 1e-300)


# ------------------------------------------------------------------------------------ geometry


def _rot(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


class _Cell:
    """Where things are at the estimate, per station (cell frame)."""

    def __init__(self, cal):
        from jcalib.problems.build import se3_matrix, se3_params

        self.cal, self.g = cal, cal.graph
        self.se3, self.params = se3_matrix, se3_params
        self.flange = {}
        for r, fp in cal.flange_poses.items():
            self.flange[r] = dict(zip(fp["station_ids"], fp["estimated"]))

    def base(self, robot: str) -> np.ndarray:
        name = self.g.base_name(robot)
        return np.eye(4) if name is None else self.cal.transforms[name]

    def flange_at(self, robot: str, k: int) -> np.ndarray:
        return self.flange[robot][self.g.station_ids[k]]

    def mount(self, spec) -> np.ndarray:
        name = self.g.mount_name(spec)
        return self.cal.transforms.get(name, np.eye(4)) if name is not None else np.eye(4)

    def world(self, spec, thing: str, k: int) -> np.ndarray:
        from jcalib.problems.graph import FREE

        h = self.g.holder(spec)
        if h == FREE:
            built = self.cal.built
            return self.se3(self.cal.solution.values[self.g.free_name(thing)][built.free_entry[thing][k]])
        if h is None:
            return self.mount(spec)
        return self.base(h) @ self.flange_at(h, k) @ self.mount(spec)

    def station(self, k: int, moved: dict[str, np.ndarray], robots: set) -> dict:
        """Flange poses of a candidate at station ``k``: ``moved`` ones replaced (Station keywords)."""
        g = self.g
        if not g.has_robot:
            return {}
        if not g.multi:
            r = g.robot_names[0]
            return {"T_base_flange": moved.get(r, self.flange_at(r, k) if r in self.flange else np.eye(4))}
        poses = {r: moved.get(r, self.flange_at(r, k)) for r in robots if r in g.robot_names}
        return {"flange_poses": poses}


def _fits(cam, p_cam: np.ndarray, margin: float = 10.0) -> bool:
    if np.any(p_cam[:, 2] <= 1e-3):
        return False
    pix = project(cam, p_cam)
    w, h = cam.image_size
    return bool(np.all((pix >= margin) & (pix <= np.array([w - 1 - margin, h - 1 - margin]))))


def _move_back(cam, T: np.ndarray, pts: np.ndarray, tries: int = 40) -> np.ndarray | None:
    """``T`` (target in camera) pushed along its centre's ray until every point is in the image."""
    centre = T[:3, :3] @ pts.mean(axis=0) + T[:3, 3]
    for i in range(tries):
        T2 = T.copy()
        T2[:3, 3] = T[:3, 3] + (1.08**i - 1.0) * centre
        if _fits(cam, pts @ T2[:3, :3].T + T2[:3, 3]):
            return T2
    return None


def _view_pose(cam, pts: np.ndarray, T_views: list, kind: str, worst_pixel=None) -> np.ndarray | None:
    """``T_cam_target`` of a new view of ``kind`` (tilt_x, tilt_y, closer, corner)."""
    centroid = pts.mean(axis=0)
    depth = float(np.median([(T[:3, :3] @ centroid + T[:3, 3])[2] for T in T_views]))
    w, h = cam.image_size
    axis, angle = {"tilt_x": ((1.0, 0, 0), 40.0), "tilt_y": ((0, 1.0, 0), 40.0)}.get(kind, ((1.0, 1.0, 0), 20.0))
    R = _rot(axis, math.radians(angle))
    centre = np.array([(w - 1) / 2, (h - 1) / 2])
    aim = centre if worst_pixel is None else worst_pixel + 0.25 * (centre - worst_pixel)
    d = depth
    if kind == "closer":
        radius = float(np.max(np.linalg.norm(pts - centroid, axis=1)))
        d = 2.0 * radius * float(np.asarray(cam.K)[1, 1]) / (0.9 * h)  # the diameter spans ~90 % of the height
    for _ in range(60):
        ray = unproject(cam, aim[None, :])[0][0]
        ray = ray / ray[2]
        T = _pose(R, d * ray - R @ centroid)
        if _fits(cam, pts @ T[:3, :3].T + T[:3, 3]):
            return T
        if kind == "corner":
            aim = aim + 0.1 * (centre - aim)
        else:
            d *= 1.08
    return None


def _reference(values: list[np.ndarray]) -> int:
    """Index of the value nearest the median (the most typical station)."""
    v = np.asarray(values, np.float64)
    return int(np.argmin(np.linalg.norm(v - np.median(v, axis=0), axis=1)))


# ------------------------------------------------------------------------------------ candidates


def _pair_candidates(model: LinearModel, where: _Cell, c: str, t: str) -> list[Candidate]:
    from jcalib.problems.graph import FREE

    cal, g = model.calibration, where.g
    cs, ts = g.cell.cameras[c], g.cell.targets[t]
    hc, ht = g.holder(cs), g.holder(ts)
    cam = cal.cameras.get(c)
    if cam is None or not g.moving(c, t):
        return []
    pair = g.pairs[(c, t)]
    pts = np.asarray(g.obs.targets[t], np.float64)
    T_views = [np.linalg.inv(where.world(cs, c, k)) @ where.world(ts, t, k) for k in pair.views]
    ref = _reference([T[:3, :3] @ pts.mean(axis=0) + T[:3, 3] for T in T_views])
    k = pair.views[ref]
    kinds = _FREE_KINDS if ht == FREE else _ROBOT_KINDS
    worst = None
    cov = model.camera_covariance(c)
    if cov is not None:
        u, v = image_grid(cam.image_size, (9, 7))
        grid = np.stack([u.ravel(), v.ravel()], -1)
        s = projection_sigma_at(cam, grid, cov)
        worst = grid[int(np.nanargmax(s))] if np.any(np.isfinite(s)) else None
    out = []
    for kind in kinds:
        if kind == "corner" and worst is None:
            continue
        if kind.startswith("rot_"):
            L = T_views[ref][:3, :3] @ pts.mean(axis=0) + T_views[ref][:3, 3]
            R = _rot(_AXES[kind[-1]], math.radians(30.0))
            T_new = _move_back(cam, _pose(R, L - R @ L) @ T_views[ref], pts)
        else:
            T_new = _view_pose(cam, pts, T_views, kind, worst if kind == "corner" else None)
        if T_new is None:
            continue
        pix = project(cam, pts @ T_new[:3, :3].T + T_new[:3, 3])
        moved, values = {}, {}
        W_c, W_t = where.world(cs, c, k), where.world(ts, t, k)
        if ht == FREE:
            values[g.free_name(t)] = where.params(W_c @ T_new)[None]
        elif hc not in (None, FREE):
            moved[hc] = np.linalg.inv(where.base(hc)) @ W_t @ np.linalg.inv(T_new) @ np.linalg.inv(where.mount(cs))
        else:
            moved[ht] = np.linalg.inv(where.base(ht)) @ W_c @ T_new @ np.linalg.inv(where.mount(ts))
        det = Detection(camera=c, pixels=pix, target=t, point_index=np.arange(len(pts)))
        station = Station("candidate", (det,), **where.station(k, moved, {hc, ht}))
        out.append(Candidate(f"{c}/{t} {kind}", kind, (c, t), STATION_KINDS[kind].format(camera=c, target=t),
                             station, values))
    return out


def _tip_candidates(where: _Cell, c: str, tool: str) -> list[Candidate]:
    cal, g = where.cal, where.g
    cs, spec = g.cell.cameras[c], g.cell.tools[tool]
    r = g.holder(spec)
    cam = cal.cameras.get(c)
    tips = g.tips[(c, tool)]
    if cam is None or r is None or not tips.stations:
        return []
    k = tips.stations[_reference([np.asarray(p) for p in tips.pixels])]
    T_ft = cal.transforms[f"T_flange_{tool}"]
    W_f = where.base(r) @ where.flange_at(r, k)
    p = (W_f @ T_ft)[:3, 3]
    W_c = where.world(cs, c, k)
    with_axis = cal.tool_orientation.get(tool) == "calibrated"
    out = []
    for kind in ("tip_x", "tip_y", "tip_z"):
        R_w = W_c[:3, :3] @ _rot(_AXES[kind[-1]], math.radians(30.0)) @ W_c[:3, :3].T
        W_f_new = _pose(R_w, p - R_w @ p) @ W_f
        T_ct = np.linalg.inv(W_c) @ W_f_new @ T_ft
        q = np.concatenate([np.zeros((1, 3)), shaft_points(T_ft) if with_axis else np.zeros((0, 3))])
        p_cam = q @ T_ct[:3, :3].T + T_ct[:3, 3]
        if not _fits(cam, p_cam, margin=5.0):
            continue
        pix = project(cam, p_cam)
        det = Detection(camera=c, pixels=pix[:1], tool=tool, axis=pix[1:] if with_axis else None)
        moved = {r: np.linalg.inv(where.base(r)) @ W_f_new}
        station = Station("candidate", (det,), **where.station(k, moved, {r, g.holder(cs)}))
        out.append(Candidate(f"{c}/{tool} {kind}", kind, (c, tool), STATION_KINDS[kind].format(camera=c, target=tool),
                             station))
    return out


def _contact_candidates(where: _Cell, tool: str, point: str) -> list[Candidate]:
    cal, g = where.cal, where.g
    r = g.holder(g.cell.tools[tool])
    ks = g.contacts[(tool, point)].stations
    if r is None or not ks:
        return []
    k = ks[0]
    W_f = where.base(r) @ where.flange_at(r, k)
    p = np.asarray(cal.points[point], np.float64)
    out = []
    for kind in ("touch_x", "touch_y", "touch_z"):
        R_w = _rot(_AXES[kind[-1]], math.radians(30.0))
        W_f_new = _pose(R_w, p - R_w @ p) @ W_f
        moved = {r: np.linalg.inv(where.base(r)) @ W_f_new}
        station = Station("candidate", (), contacts=(Contact(tool, point),), **where.station(k, moved, {r}))
        out.append(Candidate(f"{tool}/{point} {kind}", kind, (tool, point),
                             STATION_KINDS[kind].format(camera=tool, target=point), station))
    return out


def candidates(model: LinearModel) -> list[Candidate]:
    """Every candidate station of the model's calibration (empty for a model without one).

    One set of kinds per pair the calibration used: camera/target pairs with a free target get
    ``tilt_x, tilt_y, closer, corner``, pairs a robot moves ``rot_x, rot_y, rot_z, closer, corner``;
    camera/tool pairs ``tip_x, tip_y, tip_z``; tool/point contacts ``touch_x, touch_y, touch_z``. Each
    starts from the pair's most typical station (nearest the median) at the estimate.
    """
    cal = model.calibration
    if cal is None or cal.graph is None:
        return []
    if "candidates" in model.predictions:
        return model.predictions["candidates"]
    where = _Cell(cal)
    out = []
    for c, t in cal.graph.pairs:
        out += _pair_candidates(model, where, c, t)
    for c, tool in cal.graph.tips:
        out += _tip_candidates(where, c, tool)
    for tool, point in cal.graph.contacts:
        out += _contact_candidates(where, tool, point)
    model.predictions["candidates"] = out
    return out


# ------------------------------------------------------------------------------------ information


def _seed(cal) -> ResultFile:
    """The calibration's values as a start for the builder."""
    cameras = {c: CameraResult.from_model(m) for c, m in cal.cameras.items()}
    return ResultFile(cameras=cameras, transforms={n: TransformResult(T) for n, T in cal.transforms.items()})


def station_information(model: LinearModel, candidate: Candidate) -> np.ndarray:
    """Predicted information ``(n, n)`` one more station adds (units of ``model.information``).

    The candidate is built by the one builder as the only station of the cell, with the calibration's
    options, σ and variance components; :func:`jcalib.solve.information` linearises it at the estimate
    (the calibration's values for everything shared, the candidate's own station unknowns at their
    predicted values) and marginalises its station unknowns.

    Raises:
        JcalibError: the builder or the solve refused the candidate (e.g. too few points visible).
    """
    if candidate.key in model.predictions:
        return model.predictions[candidate.key]
    from jcalib.problems.calibrate import prepare
    from jcalib.solve import information

    cal = model.calibration
    g = cal.graph
    obs = replace(g.obs, stations=(candidate.station,))
    _, _, built = prepare(g.cell, obs, model.options, start=_seed(cal), points=cal.points)
    problem = built.with_weights(built.unit_weights(), dict(cal.variance_components) or None)
    shared = set(model.variables)
    x0 = {v.name: cal.solution.values[v.name] for v in problem.variables if v.name in shared}
    x0.update({k: v for k, v in candidate.values.items() if k in {v.name for v in problem.variables}})
    names = [v.name for v in problem.variables if v.name in shared and not v.eliminate]
    dims = [problem.variable(n).tangent_dim for n in names]
    M = information(problem, names, x0)
    added = model.expand(names, dims, M) / model.variance_factor
    model.predictions[candidate.key] = added
    return added


def what_would_help(model: LinearModel, labels: Sequence[str] | None = None,
                    among: Sequence[Candidate] | None = None) -> list[Suggestion]:
    """Predicted σ of the ``labels`` unknowns if one candidate station were added.

    Args:
        model: a linear model with its calibration.
        labels: unknown labels (:attr:`Unknown.label`) to report; default all.
        among: the candidates (default :func:`candidates`); one the builder refuses is left out.

    Returns:
        One :class:`Suggestion` per candidate, best first (largest gain on the first label).
    """
    all_labels = model.labels
    labels = list(labels) if labels is not None else all_labels
    idx = [all_labels.index(lab) for lab in labels]
    before = model.sigma()
    out = []
    for cand in (candidates(model) if among is None else among):
        try:
            after = model.sigma(station_information(model, cand))
        except JcalibError:
            continue
        out.append(Suggestion(cand.key, cand.description, {labels[k]: float(before[i]) for k, i in enumerate(idx)},
                              {labels[k]: float(after[i]) for k, i in enumerate(idx)}))
    if labels:
        out.sort(key=lambda s: -s.gain(labels[0]))
    return out
