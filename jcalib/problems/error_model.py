"""The robot error model of a cell, chosen by the data: ``robot: {error_model: auto | exact | pose_noise | kinematics}``.

A robot is never exactly where its controller says. jcalib has three models of that error:

- ``exact``: the reported flange poses are taken as they are;
- ``pose_noise``: every station's flange pose gets its own correction under a Gaussian prior (the pose
  model). Its level is estimated a posteriori (:func:`tune_pose_level`: the prior's variance component,
  with the stated ``pose_noise``, else :data:`DEFAULT_POSE_NOISE`, as its prior worth :data:`LEVEL_PRIOR_DOF`
  pseudo-observations), so a stated level is the prior of the model, never a reason to use it;
- ``kinematics``: the robot's kinematic parameters are calibrated and every station's flange pose is the
  kinematics at its recorded joints (needs a kinematic model and ``joints_deg`` at every station; the
  parameters are the cell's ``calibrate_kinematics``, else :data:`DEFAULT_KINEMATIC_GROUPS`).

``auto`` (the default) calibrates the cell with each model that applies and keeps the one that predicts
held-out stations best (:mod:`jcalib.problems.prediction`, the same held-out computation the result
reports): the lowest held-out RMS, where the models it does not tell apart (within :data:`TIE`, or the
better one wins at too few stations, a sign test at :data:`TIE_Z` standard deviations) are tied and the simplest of the tied
(exact, then pose_noise, then kinematics) is kept unless a more complex one also fits the
corners significantly better (its a-posteriori corner variance below the simpler one's by more than
:data:`SIGNIFICANT_SIGMA` standard errors of that ratio: a robot error the simpler model leaves in the
residuals). With several robots the models are tried for every ``auto`` robot at once (kinematics for
those that can take it, the others as in the pose model).

``auto`` needs the held-out prediction: with ``prediction`` off (``--no-prediction``), the ``pose_model``
option given, or no target corners seen through a robot pose (a TCP or pivot cell of tool tips and
contacts only), the cell's statement decides as before (``calibrate_kinematics`` ->
kinematics, ``pose_noise`` -> the pose model at its stated level, else exact).
"""

from __future__ import annotations

from dataclasses import replace as dc_replace

import numpy as np

from jcalib.errors import BadInputError, JcalibError
from jcalib.geometry.se3 import log_se3
from jcalib.io.cell import CellSpec, RobotSpec
from jcalib.problems.build import Built, se3_matrix
from jcalib.problems.graph import Graph
from jcalib.problems.refine import Refined, uses_components
from jcalib.solve import SolveOptions, replace, solve

__all__ = ["DEFAULT_KINEMATIC_GROUPS", "DEFAULT_POSE_NOISE", "MODELS", "TIE", "available", "candidates", "choose",
           "indistinct", "predictable", "restored_cell", "single", "tune_pose_level", "variant"]

#: The robot error models, simplest first.
MODELS = ("exact", "pose_noise", "kinematics")
#: Prior level of the pose model when the cell states no ``pose_noise``: σ per axis (m, degrees).
DEFAULT_POSE_NOISE = (5e-4, 0.05)
#: Kinematic parameters calibrated by the ``kinematics`` model when the cell names none (the builder keeps
#: their identifiable subset).
DEFAULT_KINEMATIC_GROUPS = ("joint_offsets", "link_lengths", "twists")
#: Held-out RMS within this fraction of the best (or :data:`FLOOR_PX` px) are tied.
TIE = 0.03
FLOOR_PX = 1e-3
#: Held-out RMS where the better model wins at fewer stations than ``n/2 + TIE_Z·√n/2`` (a sign test at
#: about two standard deviations) are tied.
TIE_Z = 2.0
#: A more complex tied model is kept when the simpler one's a-posteriori corner variance exceeds its own by
#: more than this many standard errors of the ratio (``sqrt(2 / redundancy)`` each).
SIGNIFICANT_SIGMA = 3.0
#: Pseudo-observations of the stated (or default) level in the pose model's level estimate.
LEVEL_PRIOR_DOF = 6.0
#: Iterations of the level estimate (each a warm re-solve) and its convergence (relative change).
LEVEL_ITERATIONS = 8
LEVEL_TOLERANCE = 0.02
#: Smallest level factor (the prior σ at least this fraction of the stated one).
MIN_LEVEL = 1e-3


def _robots(cell: CellSpec) -> dict[str, RobotSpec]:
    if cell.robots:
        return dict(cell.robots)
    if cell.robot is not None:
        return {(cell.robot.name or "robot"): cell.robot}
    return {}


def _with_robots(cell: CellSpec, specs: dict[str, RobotSpec]) -> CellSpec:
    if cell.robots:
        return dc_replace(cell, robots={**cell.robots, **specs})
    return dc_replace(cell, robot=next(iter(specs.values())))


def _has_joints(obs, name: str, multi: bool) -> bool:
    """Every station that gives the robot's pose or joints gives its joints."""
    seen = False
    for st in obs.stations:
        q = st.joints_deg.get(name) if isinstance(st.joints_deg, dict) else (None if multi else st.joints_deg)
        pose = st.flange_poses.get(name) if (multi or st.flange_poses) else st.T_base_flange
        if q is None and pose is not None:
            return False
        seen = seen or q is not None
    return seen


def _holder(cell: CellSpec, spec) -> str:
    if spec.mount == "flange":
        return f"flange:{spec.robot or ''}"
    return "free" if spec.mount == "free" else "fixed"


def predictable(cell: CellSpec, obs) -> bool:
    """Whether some station's target corners are seen through a robot pose (a camera and a target that a
    robot moves relative to each other): what the held-out prediction, and so ``auto``, needs."""
    pairs = {(d.camera, d.target) for st in obs.stations for d in st.detections if d.target is not None}
    for c, t in pairs:
        if c not in cell.cameras or t not in cell.targets:
            continue
        hc, ht = _holder(cell, cell.cameras[c]), _holder(cell, cell.targets[t])
        if hc != ht and "free" not in (hc, ht):
            return True
    return False


def available(cell: CellSpec, obs, name: str, spec: RobotSpec) -> dict[str, str | None]:
    """Model -> None where it applies to robot ``name``, else why not."""
    kin = None
    if spec.kinematics is None:
        kin = "the robot has no kinematic model (kinematics: or a model: preset)"
    elif not _has_joints(obs, name, bool(cell.robots) and len(cell.robots) > 1):
        kin = "the stations do not all record the robot's joints (joints_deg)"
    return {"exact": None, "pose_noise": None, "kinematics": kin}


def variant(spec: RobotSpec, model: str) -> RobotSpec:
    """The robot spec that makes the builder use ``model`` (its ``error_model`` set to it)."""
    if model == "exact":
        return dc_replace(spec, pose_noise_translation_m=None, pose_noise_rotation_deg=None, calibrate_kinematics=(),
                          error_model="exact")
    if model == "pose_noise":
        t, r = spec.pose_noise_translation_m, spec.pose_noise_rotation_deg
        if t is None:
            t, r = np.full(3, DEFAULT_POSE_NOISE[0]), np.full(3, DEFAULT_POSE_NOISE[1])
        return dc_replace(spec, pose_noise_translation_m=t, pose_noise_rotation_deg=r, calibrate_kinematics=(),
                          error_model="pose_noise")
    return dc_replace(spec, calibrate_kinematics=spec.calibrate_kinematics or DEFAULT_KINEMATIC_GROUPS,
                      error_model="kinematics")


def candidates(cell: CellSpec, obs, options) -> tuple[list[tuple[str, CellSpec]], dict[str, str]]:
    """``([(model, cell variant)], {model: why it does not apply})`` of a cell.

    One entry: the cell's model is decided (every robot forced, or ``auto`` off: see the module docstring);
    several: ``auto`` compares them.

    Raises:
        BadInputError: ``error_model: kinematics`` on a robot whose stations lack joints.
    """
    robots = {n: s for n, s in _robots(cell).items() if s is not None}
    if not robots:
        return [("", cell)], {}
    legacy = not options.prediction or options.pose_model is not None or not predictable(cell, obs)
    forced, auto = {}, []
    for n, s in robots.items():
        if s.error_model == "kinematics" and available(cell, obs, n, s)["kinematics"] is not None:
            raise BadInputError(f"{cell.source}: error_model: kinematics: {available(cell, obs, n, s)['kinematics']}; "
                                "record joints_deg at every station or choose another error_model")
        if s.error_model != "auto":
            forced[n] = variant(s, s.error_model)
        elif not legacy:
            auto.append(n)
    if not auto:
        return [("", _with_robots(cell, forced) if forced else cell)], {}
    out, why = [], {}
    for model in MODELS:
        specs = dict(forced)
        usable = []
        for n in auto:
            reason = available(cell, obs, n, robots[n])[model]
            specs[n] = variant(robots[n], model if reason is None else "pose_noise")
            if reason is None:
                usable.append(n)
        if usable:
            out.append((model, _with_robots(cell, specs)))
        else:
            why[model] = available(cell, obs, auto[0], robots[auto[0]])[model]
    return out, why


def _significant(simple, complex_) -> bool:
    """The complex model's corners fit significantly better than the simple one's (module docstring)."""
    a, b = simple.sigma_px ** 2, complex_.sigma_px ** 2
    if not (a == a and b == b and b > 0) or simple.sigma_px < FLOOR_PX:
        return False
    r = max(float(simple.num_residuals), 1.0)
    return a / b > 1.0 + SIGNIFICANT_SIGMA * np.sqrt(2.0 / r) * np.sqrt(2.0)


def indistinct(a: dict, b: dict) -> bool:
    """Held-out predictions ``a`` (the worse) and ``b`` (the best) are not told apart: within :data:`TIE` or
    :data:`FLOOR_PX`, or ``b`` better at too few stations (a sign test: fewer than ``n/2 + TIE_Z·√n/2`` of
    the ``n`` stations both predicted; robust to one station far off in either)."""
    if a["rms_px"] <= b["rms_px"] * (1.0 + TIE) + FLOOR_PX:
        return True
    sa, sb = a.get("per_station") or {}, b.get("per_station") or {}
    ids = sorted(set(sa) & set(sb))
    if len(ids) < 3:
        return False
    wins = sum(sb[k]["rms_px"] < sa[k]["rms_px"] for k in ids)
    return wins < 0.5 * len(ids) + 0.5 * TIE_Z * np.sqrt(len(ids))


def choose(results: dict[str, object], errors: dict[str, str], why: dict[str, str]) -> tuple[str, dict]:
    """``(chosen model, stats.robot_error_model)`` from each model's :class:`Calibration` (its
    ``prediction``) and the models that failed or did not apply."""
    scores = {m: (c.prediction or {}).get("rms_px") for m, c in results.items()}
    usable = {m: s for m, s in scores.items() if s is not None and s == s}
    if not usable:
        chosen = next(iter(results))  # nothing to compare: the simplest that solved
        how = "no held-out prediction could be computed; the simplest model that solved is kept"
    else:
        best = min(usable, key=usable.get)
        tied = [m for m in MODELS if m in usable
                and (m == best or indistinct(results[m].prediction, results[best].prediction))]
        chosen = tied[0]
        for m in tied[1:]:
            if _significant(results[chosen], results[m]):
                chosen = m
        how = (f"the lowest held-out prediction error; models it does not tell apart (within {TIE:.0%}, or the "
               f"better one wins at too few stations, a sign test at {TIE_Z:g} σ) are tied, and the simplest of "
               "them is kept unless a more complex one also fits the corners significantly better")
    info = {"chosen": chosen, "scores": {m: {"rms_px": s, "sigma_px": float(results[m].sigma_px)}
                                         for m, s in scores.items()},
            "criterion": how}
    level = (results[chosen].robot_error_model or {}).get("pose_noise_level")
    if level:
        info["pose_noise_level"] = level
    elif "pose_noise" in results and (results["pose_noise"].robot_error_model or {}).get("pose_noise_level"):
        info["pose_noise_level_estimated"] = results["pose_noise"].robot_error_model["pose_noise_level"]
    if errors:
        info["failed"] = dict(errors)
    if why:
        info["not_applicable"] = dict(why)
    return chosen, info


def _prior_index(built: Built, name: str) -> int:
    return [f.name for f in built.problem.factors].index(f"prior:{name}")


def tune_pose_level(g: Graph, built: Built, r: Refined, options) -> tuple[Graph, Built, Refined, dict]:
    """The pose model's level estimated a posteriori (module docstring) for every robot whose spec says
    ``error_model: pose_noise``: ``level² = (χ² + ν₀) / (r + ν₀)`` of its flange corrections ``S₀ δ``
    against the stated (or default) prior ``S₀``, ``r`` the prior's redundancy, iterated with warm
    re-solves. Returns the graph (its robot specs at the estimated level), problem and solve at that
    level, and robot -> ``{"factor", "translation_m", "rotation_deg", "redundancy"}``."""
    from jcalib.problems.assemble import robot_statistics

    robots = [rb for rb in g.used_robots if built.pose_model.get(rb) and rb not in built.kinematics
              and g.robot_specs[rb].error_model == "pose_noise"]
    if not robots:
        return g, built, r, {}
    stated = {rb: (np.asarray(g.robot_specs[rb].pose_noise_translation_m, np.float64),
                   np.asarray(g.robot_specs[rb].pose_noise_rotation_deg, np.float64)) for rb in robots}
    S0 = {rb: built.pose_sqrt_info[rb] for rb in robots}
    level = dict.fromkeys(robots, 1.0)
    so = SolveOptions(max_iterations=options.max_iterations, mu0=1e-6)
    traces = uses_components(built, options)
    sol = r.sol
    for _ in range(LEVEL_ITERATIONS):
        new = {}
        for rb in robots:
            st = robot_statistics(g, built, sol, rb)
            red = float(st["redundancy"])
            meas = g.flange[rb][g.need[rb]]
            delta = log_se3(np.linalg.inv(meas) @ se3_matrix(sol.values[g.flange_name(rb)]))
            chi2 = float(np.sum((delta @ S0[rb].T) ** 2))  # in units of the stated level
            new[rb] = float(np.sqrt(max((chi2 + LEVEL_PRIOR_DOF) / (max(red, 0.0) + LEVEL_PRIOR_DOF), MIN_LEVEL ** 2)))
        moved = max(abs(new[rb] / level[rb] - 1.0) for rb in robots)
        level = new
        factors = list(built.problem.factors)
        for rb in robots:
            j = _prior_index(built, g.flange_name(rb))
            mean, S = factors[j].observations
            factors[j] = replace(factors[j], observations=(mean, np.broadcast_to(S0[rb] / level[rb], np.shape(S)).copy()))
        built = dc_replace(built, problem=replace(built.problem, factors=tuple(factors)),
                           pose_sqrt_info={**built.pose_sqrt_info, **{rb: S0[rb] / level[rb] for rb in robots}})
        try:
            sol = solve(built.with_weights(r.weights, r.components or None, r.views or None), x0=sol.values,
                        options=so, traces=traces)
        except JcalibError:
            break
        if moved < LEVEL_TOLERANCE:
            break
    specs = dict(g.robot_specs)
    info = {}
    for rb in robots:
        t, d = stated[rb]
        specs[rb] = dc_replace(specs[rb], pose_noise_translation_m=t * level[rb], pose_noise_rotation_deg=d * level[rb])
        info[rb] = {"factor": level[rb], "translation_m": float(np.max(t) * level[rb]),
                    "rotation_deg": float(np.max(d) * level[rb]), "prior_translation_m": float(np.max(t)),
                    "prior_rotation_deg": float(np.max(d))}
    g.robot_specs = specs
    return g, built, dc_replace(r, sol=sol), info


def single(g: Graph, built: Built, level: dict) -> dict | None:
    """``stats.robot_error_model`` of a cell calibrated with one model (forced, or ``auto`` off), None
    without a robot."""
    if not g.has_robot or not g.used_robots:
        return None
    models = {rb: "kinematics" if rb in built.kinematics else "pose_noise" if built.pose_model.get(rb) else "exact"
              for rb in g.used_robots}
    forced = all(g.robot_specs[rb].error_model != "auto" for rb in g.used_robots)
    how = ("error_model in the cell" if forced else
           "as the cell states it (auto compares the models by held-out prediction, which --no-prediction or the "
           "pose_model option turn off)")
    one = len(set(models.values())) == 1 and not g.multi
    info = {"chosen": next(iter(models.values())) if one else models, "criterion": how}
    if level:
        info["pose_noise_level"] = level
    return info


def restored_cell(cell: CellSpec, stats: dict) -> CellSpec:
    """The cell variant a result was calibrated with (its ``stats.robot_error_model``): the model chosen for
    its ``auto`` robots, the forced ones, and the estimated pose level, so that the problem rebuilt from a
    result file is the one that was solved."""
    info = stats.get("robot_error_model") or {}
    chosen, level = info.get("robots", info.get("chosen")), info.get("pose_noise_level") or {}
    compared = "scores" in info
    robots = {n: s for n, s in _robots(cell).items() if s is not None}
    if not robots or not info:
        return cell
    specs = {}
    for n, s in robots.items():
        model = chosen.get(n) if isinstance(chosen, dict) else chosen
        if s.error_model != "auto":
            s = variant(s, s.error_model)
        elif compared and model in MODELS:
            s = variant(s, model)
        if n in level and s.pose_noise_translation_m is not None:
            f = float(level[n]["factor"])
            s = dc_replace(s, pose_noise_translation_m=s.pose_noise_translation_m * f,
                           pose_noise_rotation_deg=s.pose_noise_rotation_deg * f)
        specs[n] = s
    return _with_robots(cell, specs)
