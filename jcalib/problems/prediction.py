"""Prediction from the robot's poses: how far a held-out station's corners land from where the cell says.

The question an integrator asks of a calibrated robot cell: when the robot goes to a pose, where will the
camera see things, and how far off will that be? Sampling σ and residual RMS do not answer it (a residual
is fitted to its own image). Here every station whose camera-to-target geometry runs through a robot is
held out in turn (leave-one-station-out up to :data:`MAX_LOSO` stations, :data:`FOLDS` interleaved folds
above): the final problem is solved again without that station's measurements (weight 0: the one compiled
solve, started from the final estimate) and the held-out corners are predicted from the station's recorded
robot pose (or its joints, through the calibrated kinematics) alone, never from its own images. A station's
flange-pose correction (the pose model) is then held at its prior, zero: the prediction is what the cell
would do at that pose.

Reported per point (the norm of each corner's pixel error, as ``rms_px``), and at the target in its plane
(``rms_mm``: each view's pixel error scaled by its observed millimetres per pixel).
"""

from __future__ import annotations

import numpy as np

from jcalib.errors import JcalibError
from jcalib.problems.build import Built
from jcalib.problems.graph import FREE, Graph
from jcalib.problems.refine import Refined, uses_components
from jcalib.solve import SolveOptions, solve

__all__ = ["FOLDS", "MAX_LOSO", "prediction"]

#: Leave-one-station-out up to this many candidate stations; above, :data:`FOLDS` interleaved folds.
MAX_LOSO = 30
#: Folds above :data:`MAX_LOSO` stations.
FOLDS = 10
#: Fewest stations that can be held out for a prediction to be reported.
MIN_STATIONS = 3


def _robot_pair(g: Graph, camera: str, target: str) -> bool:
    """Whether a robot moves the camera relative to the target (its geometry runs through a robot pose)."""
    hc, ht = g.holder(g.cell.cameras[camera]), g.holder(g.cell.targets[target])
    return hc != ht and FREE not in (hc, ht)


def _mm_per_px(points: np.ndarray, pixels: np.ndarray) -> float:
    """A view's observed scale at the target: RMS spread of its points (mm) over that of their pixels."""
    P = np.asarray(points, np.float64)[:, :2] * 1e3
    u = np.asarray(pixels, np.float64)
    spread_px = float(np.sum((u - u.mean(axis=0)) ** 2))
    return float(np.sqrt(np.sum((P - P.mean(axis=0)) ** 2) / spread_px)) if spread_px > 0 else float("nan")


def _models(g: Graph, built: Built) -> dict[str, str]:
    return {r: "kinematics" if r in built.kinematics else "pose_noise" if built.pose_model.get(r) else "exact"
            for r in g.used_robots}


def prediction(g: Graph, built: Built, r: Refined, options) -> dict | None:
    """The held-out prediction error of a robot cell (module docstring), or None for a cell without a robot.

    Returns ``{"method", "folds", "stations", "points", "rms_px", "median_px", "rms_mm", "per_station":
    {station id: {"rms_px", "rms_mm", "points"}}, "model": {robot: exact | pose_noise | kinematics}}``
    (``"failed_folds"`` when some fold's solve failed), or ``{"skipped": why, "model": ...}``.
    """
    if not g.has_robot or not g.used_robots:
        return None
    models = _models(g, built)
    groups = [gr for gr in built.groups if gr.kind == "corner" and _robot_pair(g, *gr.key)]
    if not groups:
        return {"skipped": "no target corners seen through a robot pose (a camera and a target that a robot "
                           "moves relative to each other)", "model": models}
    free_seen = np.zeros(len(g.station_ids), bool)  # a free target's pose has no other evidence than its view
    for (c, t), p in g.pairs.items():
        if FREE in (g.holder(g.cell.cameras[c]), g.holder(g.cell.targets[t])):
            free_seen[np.asarray(p.views, int)] = True
    seen = np.zeros(len(g.station_ids), bool)
    for gr in groups:
        seen[gr.stations[r.weights[gr.name] > 0]] = True
    candidates = np.flatnonzero(seen & ~free_seen)
    if candidates.size < MIN_STATIONS:
        return {"skipped": f"{candidates.size} station(s) whose corners a robot pose determines; the held-out "
                           f"prediction needs {MIN_STATIONS}", "model": models}
    folds = ([candidates[[k]] for k in range(candidates.size)] if candidates.size <= MAX_LOSO
             else [candidates[f::FOLDS] for f in range(FOLDS)])
    scale: dict[tuple[str, int], float] = {}
    for gr in groups:
        p = g.pairs[gr.key]
        for j, k in enumerate(p.views):
            scale[(gr.name, int(k))] = _mm_per_px(p.points[j], p.pixels[j])
    so = SolveOptions(max_iterations=options.max_iterations, mu0=1e-6)
    traces = uses_components(built, options)  # the rounds' compiled solve: no new compile
    err_px: dict[int, list[np.ndarray]] = {}
    err_mm: dict[int, list[np.ndarray]] = {}
    failed = 0
    for held in folds:
        weights = {n: w.copy() for n, w in r.weights.items()}
        for gr in built.groups:
            weights[gr.name][np.isin(gr.stations, held)] = 0.0
        try:
            sol = solve(built.with_weights(weights, r.components or None, r.views or None), x0=r.sol.values,
                        options=so, traces=traces)
        except JcalibError:
            failed += 1
            continue
        for gr in groups:
            rows = np.isin(gr.stations, held) & (r.weights[gr.name] > 0)  # inliers of the final solve
            if not rows.any():
                continue
            e = np.linalg.norm(np.asarray(sol.residuals[gr.name])[gr.pad][rows], axis=1)
            for k in np.unique(gr.stations[rows]):
                at = gr.stations[rows] == k
                err_px.setdefault(int(k), []).append(e[at])
                err_mm.setdefault(int(k), []).append(e[at] * scale[(gr.name, int(k))])
    if not err_px:
        return {"skipped": f"every fold's solve failed ({failed} of {len(folds)})", "model": models}
    px = np.concatenate([np.concatenate(v) for v in err_px.values()])
    mm = np.concatenate([np.concatenate(v) for v in err_mm.values()])
    per_station = {}
    for k in sorted(err_px):
        a, b = np.concatenate(err_px[k]), np.concatenate(err_mm[k])
        per_station[g.station_ids[k]] = {"rms_px": float(np.sqrt(np.mean(a * a))),
                                         "rms_mm": float(np.sqrt(np.nanmean(b * b))), "points": int(a.size)}
    out = {"method": "leave-one-station-out" if candidates.size <= MAX_LOSO else f"{FOLDS}-fold",
           "folds": len(folds), "stations": len(per_station), "points": int(px.size),
           "rms_px": float(np.sqrt(np.mean(px * px))), "median_px": float(np.median(px)),
           "rms_mm": float(np.sqrt(np.nanmean(mm * mm))), "per_station": per_station, "model": models}
    if failed:
        out["failed_folds"] = failed
    return out
