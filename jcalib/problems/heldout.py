"""Held-out accuracy of a calibrated robot kinematics: how well it predicts flange poses it was not fitted to.

The stations of a robot whose kinematics is calibrated are split into ``folds`` interleaved folds. For
each fold the final problem is solved again (warm, same shapes: the one compiled solve) with the
kinematic factor of the fold's stations switched off (weight 0): their flange poses are then determined
by their own observations alone (a camera's view of a target, a pose sensor's measurement), and the
kinematics by the other stations alone. The error of the kinematics' prediction ``FK(params, q)`` at the
fold's joint values against those observed flange poses is the held-out error; the nominal
kinematics' prediction against the same observed poses is the baseline. Only stations whose flange is
fully determined by their own observations (6 DOF: a view of at least one target whose pose relative to
the flange is estimated, or a pose measurement) are held out; others keep their kinematic factor.

The observed poses carry their own noise (a view's pose σ), so the held-out error is an upper bound of
the model's prediction error, the same for the calibrated and the nominal model.
"""

from __future__ import annotations

import equinox as eqx
import numpy as np

from jcalib.errors import JcalibError
from jcalib.geometry.se3 import log_se3
from jcalib.problems.build import Built, se3_matrix
from jcalib.problems.graph import FREE, Graph
from jcalib.problems.kinematics import forward_batch
from jcalib.problems.refine import Refined, uses_components
from jcalib.solve import SolveOptions, solve

#: Interleaved folds of the held-out check.
FOLDS = 5


def _determined(g: Graph, robot: str) -> np.ndarray:
    """``(N,)`` bool: stations where the robot's flange pose is fixed by that station's own observations."""
    cell = g.cell
    out = np.zeros(len(g.station_ids), bool)
    for (c, t), p in g.pairs.items():
        hc, ht = g.holder(cell.cameras[c]), g.holder(cell.targets[t])
        if robot in (hc, ht) and hc != ht and FREE not in (hc, ht):
            out[np.asarray(p.views, int)] = True
    for (c, t), pm in g.poses.items():
        hc, ht = g.holder(cell.cameras[c]), g.holder(cell.targets[t])
        if robot in (hc, ht) and hc != ht and FREE not in (hc, ht):
            out[np.asarray(pm.stations, int)] = True
    return out & g.need[robot]


def _errors(T_pred: np.ndarray, T_obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = log_se3(np.linalg.inv(T_pred) @ T_obs)
    return np.linalg.norm(d[:, 3:], axis=1), np.degrees(np.linalg.norm(d[:, :3], axis=1))


def _summary(pos_m: np.ndarray, rot_deg: np.ndarray) -> dict:
    return {"position_median_mm": float(1e3 * np.median(pos_m)), "position_p95_mm": float(1e3 * np.percentile(pos_m, 95)),
            "rotation_median_deg": float(np.median(rot_deg)), "rotation_p95_deg": float(np.percentile(rot_deg, 95))}


def heldout_accuracy(g: Graph, built: Built, r: Refined, options, folds: int = FOLDS) -> dict[str, dict]:
    """Robot -> held-out accuracy of its calibrated kinematics (see the module docstring): ``stations``
    held out, ``folds``, and for ``calibrated`` and ``nominal`` the median and 95th percentile of the
    flange position (mm) and rotation (deg) errors; ``{"skipped": why}`` when it cannot be computed."""
    out: dict[str, dict] = {}
    base = built.with_weights(r.weights, r.components or None, r.views or None)
    names = [f.name for f in base.factors]
    so = SolveOptions(max_iterations=options.max_iterations, mu0=1e-6)
    traces = uses_components(built, options)  # the rounds' compiled solve: no new compile
    for robot in built.kinematics:
        model = g.robot_specs[robot].kinematics
        ks = np.flatnonzero(g.need[robot])  # the robot's stations, in its flange-variable order
        determined = _determined(g, robot)[ks]
        candidates = np.flatnonzero(determined)
        if candidates.size < 2 * folds:
            out[robot] = {"skipped": f"{candidates.size} stations whose flange the observations determine alone; "
                                     f"the held-out check needs {2 * folds}"}
            continue
        j = names.index(f"kinematic:{robot}")
        factor = base.factors[j]
        pos_c, rot_c, pos_n, rot_n = [], [], [], []
        for f in range(folds):
            held = candidates[f::folds]
            w = np.asarray(factor.sqrt_weight, np.float64).copy()
            w[held] = 0.0
            problem = eqx.tree_at(lambda p: p.factors[j].sqrt_weight, base, w)
            try:
                sol = solve(problem, x0=r.sol.values, options=so, traces=traces)
            except JcalibError as err:
                out[robot] = {"skipped": f"a fold's solve failed: {err}"}
                break
            params = np.asarray(sol.values[f"kinematics:{robot}"][0], np.float64)
            q = g.joints[robot][ks[held]]
            T_obs = se3_matrix(sol.values[g.flange_name(robot)][held])
            for p, pos, rot in ((params, pos_c, rot_c), (np.asarray(model.nominal, np.float64), pos_n, rot_n)):
                a, b = _errors(np.asarray(forward_batch(model, p, q), np.float64), T_obs)
                pos.append(a)
                rot.append(b)
        else:
            out[robot] = {"stations": int(candidates.size), "folds": folds,
                          "calibrated": _summary(np.concatenate(pos_c), np.concatenate(rot_c)),
                          "nominal": _summary(np.concatenate(pos_n), np.concatenate(rot_n))}
    return out
