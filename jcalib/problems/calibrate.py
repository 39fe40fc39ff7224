"""Every cell, one path from data to a result: :func:`calibrate_cell` and :func:`result_file`.

:func:`calibrate_cell` is the pipeline: the graph (:mod:`jcalib.problems.graph`), the closed-form
start (:mod:`jcalib.problems.start`, :mod:`jcalib.problems.tools`), the one builder
(:mod:`jcalib.problems.build`), the solve and its rounds (:mod:`jcalib.problems.refine`) and the one
assembler (:mod:`jcalib.problems.assemble`). Camera-only, stereo rigs, eye-in-hand, eye-to-hand, TCP
from tips or contacts, pivots, pose-pair hand-eye and multi-robot cells are all cell specs of it.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError, JcalibError
from jcalib.io.cell import CameraSpec, CellSpec, RobotSpec, cell_to_dict
from jcalib.io.observations import Observations
from jcalib.geometry import kinematic_models, kinematic_tables
from jcalib.io.result import (CameraResult, KinematicsResult, PointResult, Provenance, ResultFile, TargetResult,
                              TransformResult, hash_inputs)
from jcalib.problems.assemble import Calibration, assemble
from jcalib.problems.budget import error_budget
from jcalib.problems.budget_file import attach as attach_budget
from jcalib.problems.build import CORNER_KINDS, build, se3_params, sqrt_info
from jcalib.problems.graph import Graph
from jcalib.problems import error_model
from jcalib.problems.absorb import absorbed_intrinsics
from jcalib.problems.heldout import heldout_accuracy
from jcalib.problems.options import CalibrationOptions, check_applicable
from jcalib.problems.prediction import prediction
from jcalib.problems.refine import refine
from jcalib.problems.orientation import relabel, resolve_orientations
from jcalib.problems.start import Start, start_intrinsics, start_poses
from jcalib.problems.positions import start_point_sensors
from jcalib.problems.tools import start_tools


class Result:
    """A calibration result: the ``jcalib.result/1`` contents plus the solver's details.

    Attributes:
        file: the :class:`~jcalib.io.result.ResultFile` (what ``to_json`` writes).
        details: the :class:`~jcalib.problems.assemble.Calibration` (residuals, per-view statistics,
            the solver's :class:`~jcalib.solve.Solution`).
    """

    def __init__(self, file: ResultFile, details: Any = None):
        self.file = file
        self.details = details

    def to_json(self, path: str | os.PathLike) -> Path:
        """Write the result file atomically (JSON, never pickle)."""
        return self.file.save(path)

    def covariance(self, name: str) -> np.ndarray:
        """Covariance of a camera's intrinsic vector (order of its ``param_names``) or of a transform
        (6x6, tangent order rx, ry, rz, tx, ty, tz, right perturbation; rad and m)."""
        if name in self.file.cameras and self.file.cameras[name].covariance is not None:
            return np.asarray(self.file.cameras[name].covariance)
        if name in self.file.transforms and self.file.transforms[name].covariance is not None:
            return np.asarray(self.file.transforms[name].covariance)
        known = list(self.file.cameras) + list(self.file.transforms)
        raise BadInputError(f"no covariance for {name!r}; the result has: {', '.join(known)}")

    def camera_at(self, camera: str | None = None, *, extrapolate: bool = False, **settings: float):
        """A camera with a zoom lens at one setting, e.g. ``result.camera_at("cam0", Zoom=350)``.

        Returns:
            ``(CameraResult, TransformResult | None)``: the intrinsics with their covariance, and the
            camera's pose on its holder at that setting (``T_flange_cam0``, ...) with its 6x6 covariance
            (sampling noise, first order). ``camera`` may be omitted when one camera has a lens.
        Raises:
            BadInputError: no lens, another setting, or a value outside the calibrated range (without
                ``extrapolate``).
        """
        from jcalib.problems.lens import camera_at

        lenses = list(self.file.extra.get("lenses") or {})
        if camera is None and len(lenses) == 1:
            camera = lenses[0]
        if camera is None or len(settings) != 1:
            raise BadInputError(f"camera_at: give the camera ({', '.join(lenses) or 'none has a lens'}) and one setting, "
                                "e.g. camera_at('cam0', Zoom=350)")
        (name, value), = settings.items()
        cam, _, tr = camera_at(self.file, camera, name, float(value), extrapolate)
        return cam, tr

    def __repr__(self) -> str:
        return f"Result(cameras={list(self.file.cameras)}, transforms={list(self.file.transforms)})"


def input_hash(cell_arg, obs_arg, cell: CellSpec, obs: Observations) -> str:
    """Hash of the inputs as given: files by content, a cell object by its JSON form, observations by
    their numbers (ids, poses, detections) in file order."""
    parts = [Path(cell_arg) if isinstance(cell_arg, (str, os.PathLike))
             else json.dumps(cell_to_dict(cell), sort_keys=True).encode()]
    if isinstance(obs_arg, (str, os.PathLike)):
        parts.append(Path(obs_arg))
    else:
        chunks = [json.dumps({"cameras": obs.cameras, "targets": sorted(obs.targets)}, sort_keys=True).encode()]
        chunks += [np.ascontiguousarray(obs.targets[t]).tobytes() for t in sorted(obs.targets)]
        for st in obs.stations:
            chunks.append(st.id.encode())
            if st.T_base_flange is not None:
                chunks.append(np.ascontiguousarray(st.T_base_flange).tobytes())
            for r, T in sorted(st.flange_poses.items()):
                chunks += [r.encode(), np.ascontiguousarray(T).tobytes()]
            for d in st.detections:
                chunks += [f"{d.camera}|{d.target}|{d.tool}".encode(), np.ascontiguousarray(d.point_index).tobytes(),
                           np.ascontiguousarray(d.pixels).tobytes()]
                if d.axis is not None:
                    chunks.append(np.ascontiguousarray(d.axis).tobytes())
            for c in st.contacts:
                chunks.append(f"{c.tool}|{c.point}".encode())
            for m in st.poses:
                chunks += [f"{m.camera}|{m.target}".encode(), np.ascontiguousarray(m.T_cam_target).tobytes()]
            if st.lens:
                chunks.append(json.dumps(st.lens, sort_keys=True).encode())
        parts.append(b"\x00".join(chunks))
    return hash_inputs(*parts)


def options_and_given(options) -> tuple[CalibrationOptions, set[str]]:
    if options is None:
        return CalibrationOptions(), set()
    """The options and the names set to something other than their default (for the applicability check)."""
    if isinstance(options, CalibrationOptions):
        defaults = CalibrationOptions()
        return options, {k for k in asdict(options) if getattr(options, k) != getattr(defaults, k)}
    if isinstance(options, dict):
        return CalibrationOptions().replace(**options), set(options)
    raise BadInputError(f"options: got {type(options).__name__}, expected CalibrationOptions or a dict of its fields")


def tracked_tools(cell: CellSpec) -> CellSpec:
    """A cell with tools and no robot as the cell with ``robot: {}``: each tool is a tracked tool (a pointer
    with a marker body, e.g. for pivot calibration with an optical tracker), its "flange" the tracked
    body, whose pose in the tracker ("base") frame every station gives as ``T_base_flange`` (taken as
    exact, as a robot without ``pose_noise``). Other cells unchanged."""
    if cell.tools and cell.robot is None and not cell.robots:
        return replace(cell, robot=RobotSpec())
    return cell


def pose_sensors(cell: CellSpec) -> CellSpec:
    """The cell with its pose sensors (``sensors:``) among the things that measure: for the builder a pose
    sensor is a camera without a lens (its 6-DOF measurements are pose-measurement factors, its mount pose
    ``T_<frame>_<sensor>`` / ``T_flange_<sensor>`` an unknown like a camera's; it has no intrinsics and no
    image size). The sensors stay listed in ``cell.sensors``."""
    if not cell.sensors:
        return cell
    as_cameras = {n: CameraSpec(name=n, model="pinhole", mount=x.mount, pose=x.pose, robot=x.robot)
                  for n, x in cell.sensors.items()}
    return replace(cell, cameras={**cell.cameras, **as_cameras})


def _priors(prior, names, graph: Graph, start: Start) -> dict:
    """Gaussian priors (mean, sqrt information) from an old result on the unknowns ``names`` (all: None)."""
    out = {}
    if prior is None:
        return out
    wanted = None if names is None else set(names)
    for n, tr in prior.transforms.items():
        if tr.covariance is not None and (wanted is None or n in wanted):
            out[n] = (se3_params(tr.matrix), sqrt_info(tr.covariance))
    for n, cr in prior.cameras.items():
        if cr.covariance is not None and (wanted is None or n in wanted) and n in start.models \
                and tuple(cr.param_names) == tuple(start.models[n].param_names):
            out[n] = (np.asarray(cr.params, np.float64), sqrt_info(cr.covariance))
    for n, pr in prior.points.items():
        if pr.covariance is not None and (wanted is None or n in wanted):
            out[f"point:{n}"] = (np.asarray(pr.position, np.float64), sqrt_info(pr.covariance))
    return out


def prepare(cell: CellSpec, obs: Observations, options: CalibrationOptions | None = None, *, prior=None,
            prior_names=None, start=None, given: set[str] | None = None, priors: dict | None = None,
            known: dict | None = None, points: dict | None = None, unobservable_fixed: dict | None = None
            ) -> tuple[Graph, Start, object]:
    """The graph, closed-form start and problem of a cell (everything before the solve).

    Arguments as :func:`calibrate_cell`; ``points``: cell point -> ``(3,)`` start value (m, cell frame)
    instead of the one the contacts give; ``unobservable_fixed``: the prior of a hand-eye translation
    along a common rotation axis that an earlier start decided (``Calibration.unobservable_fixed``).
    Returns ``(graph, start, built)``.
    """
    options = options or CalibrationOptions()
    cell = pose_sensors(tracked_tools(cell))
    g = Graph(cell, obs, options.reference_camera)
    check_applicable(options, g, set(given or ()))
    pose_model = {r: g.has_noise(r) if options.pose_model is None else bool(options.pose_model) for r in g.used_robots}
    for r in g.kinematic_robots:
        if options.pose_model is False:
            raise BadInputError(f"option --no-pose-model: {g.label(r)} calibrates its kinematics, which models every "
                                "station's flange pose as the kinematics at its joints within the robot's repeatability "
                                "(its pose_noise); drop the option, or drop calibrate_kinematics")
        pose_model[r] = True
    seed = prior if prior is not None else start
    s = Start()
    start_intrinsics(g, s, seed)
    turns, turned = resolve_orientations(g, s.views)  # symmetric boards: labels from the robot motion
    if turns:
        obs = relabel(obs, turns)
        g = Graph(cell, obs, options.reference_camera)
        s = Start()
        start_intrinsics(g, s, seed)
    s.warnings += turned
    for spec in list(cell.cameras.values()) + list(cell.targets.values()):
        m = g.mount_name(spec)
        if spec.pose is not None and m is not None:
            s.known[m], s.how[m] = np.asarray(spec.pose, np.float64), "cell"
    if g.reference_camera is not None:
        ref = g.mount_name(cell.cameras[g.reference_camera])
        s.known[ref], s.how[ref] = np.eye(4), "gauge"
    gauge, _ = g.gauge()
    for r in g.robot_names:
        b = g.base_name(r)
        if b is None:
            continue
        if g.robot_specs[r].base is not None:
            s.known[b], s.how[b] = np.asarray(g.robot_specs[r].base, np.float64), "gauge:cell" if r == gauge else "cell"
        elif r == gauge:
            s.known[b], s.how[b] = np.eye(4), "gauge"
        if (r in cell.fixed or b in cell.fixed) and g.robot_specs[r].base is None and r != gauge:
            raise BadInputError(f"{cell.source}: fixed lists '{r}' ({b}) but the cell gives it no base; add "
                                f"robots.{r}.base: [[4x4]] (m) or remove it from fixed")
    if seed is not None:
        for n, tr in seed.transforms.items():
            if n not in s.known:
                s.known[n], s.how[n] = np.asarray(tr.matrix, np.float64), "prior"
    for n, T in (known or {}).items():
        s.known[n], s.how[n] = np.asarray(T, np.float64), "given"
    noisy = [r for r in g.used_robots if g.has_noise(r) and g.robot_specs[r].pose_noise_rotation_deg is not None]
    rot_noise = max([0.02] + [float(np.max(g.robot_specs[r].pose_noise_rotation_deg)) for r in noisy])
    tool_robots = frozenset(g.holder(cell.tools[t]) for (_, t) in g.tips) | frozenset(
        g.holder(cell.tools[t]) for (t, _) in g.contacts)
    start_poses(g, s, method=options.method, rot_noise=rot_noise, fix_unobservable=options.fix_unobservable,
                prior_m=options.unobservable_prior_m, prior_sigma_m=options.unobservable_prior_sigma_m,
                tool_robots=tool_robots)
    for n, p in (points or {}).items():
        if n in cell.points and cell.points[n].position is None:
            s.points[n] = np.asarray(p, np.float64).reshape(3)
    start_point_sensors(g, s)
    start_tools(g, s)
    if unobservable_fixed is not None and s.unobservable_fixed is None:
        s.unobservable_fixed = dict(unobservable_fixed)
    if options.fix_unobservable and s.unobservable_fixed is None:
        s.warnings.append("fix_unobservable: the stations' rotations determine every hand-eye translation; nothing "
                          "was held at the stated prior (unobservable_prior_m)")
    built = build(g, s, options, pose_model, {**_priors(prior, prior_names, g, s), **(priors or {})})
    return g, s, built


def calibrate_cell(cell: CellSpec, obs: Observations, options: CalibrationOptions | None = None, *,
                   prior=None, prior_names=None, start=None, given: set[str] | None = None,
                   priors: dict | None = None, known: dict | None = None) -> Calibration:
    """Calibrate any cell jointly (see the module docstring).

    Args:
        cell, obs: the parsed cell spec and observations.
        options: :class:`CalibrationOptions`.
        prior: an old :class:`jcalib.io.result.ResultFile`: its values start the solve and its
            covariances become Gaussian priors on the unknowns in ``prior_names`` (None: all it holds).
        start: an old result whose values only start the solve.
        given: option names the user set explicitly; those the cell cannot use are refused.
        priors: further Gaussian priors, name (camera id, transform name, ``point:<name>``) ->
            ``(mean params, sqrt_info)`` (a zero row of ``sqrt_info``: no prior on that coordinate).
        known: transform name -> ``(4, 4)`` start values (instead of the closed form).

    Returns:
        :class:`Calibration`. Covariances are sampling noise (every measurement kind's noise and the
        stated priors, first order, with each kind's a-posteriori variance component), not model error.

    Raises:
        BadInputError: malformed input (missing poses, too few points, an option the cell cannot use).
        NotObservableError: unknowns the data cannot determine, named.
    """
    options = options or CalibrationOptions()
    kw = dict(prior=prior, prior_names=prior_names, start=start, given=given, priors=priors, known=known)
    # the error budget (jcalib.problems.budget) when the cell states assumptions: it compiles a program of its
    # own (a cold calibrate of a camera cell took 15 s without it, 30 s with it), so it is asked for
    kw["budget"] = bool(cell.assumptions)
    runs, why = error_model.candidates(tracked_tools(cell), obs, options)
    if len(runs) == 1:
        cal = _calibrate_one(runs[0][1], obs, options, **kw)
    else:  # error_model: auto (jcalib.problems.error_model)
        results, errors = {}, {}
        for model, variant in runs:
            try:
                results[model] = _calibrate_one(variant, obs, options, **kw)
            except JcalibError as err:
                errors[model] = err
        if not results:
            raise errors[runs[0][0]]
        chosen, info = error_model.choose(results, {m: str(e) for m, e in errors.items()}, why)
        cal = results[chosen]
        own = cal.robot_error_model
        cal.robot_error_model = {**info, **({"robots": own["chosen"]} if isinstance(own["chosen"], dict) else {})}
    cal.warnings += absorbed_intrinsics(cal, obs, options, _calibrate_one)
    return cal


def _calibrate_one(cell: CellSpec, obs: Observations, options: CalibrationOptions, *, budget: bool = False,
                   **kw) -> Calibration:
    """One calibration of a cell whose robot error model is decided (:func:`calibrate_cell`); with its error
    budget when ``budget``."""
    g, s, built = prepare(cell, obs, options, **kw)
    r = refine(g, s, built, options)
    g, built, r, level = error_model.tune_pose_level(g, built, r, options)
    cal = assemble(g, s, built, r)
    cal.robot_error_model = error_model.single(g, built, level)
    if budget:
        cal.budget = error_budget(g, built, s, r, cal)
    for robot, held in heldout_accuracy(g, built, r, options).items():
        cal.kinematics[robot]["heldout"] = held
    if options.prediction:
        cal.prediction = prediction(g, built, r, options)
    return cal


def options_of(file: ResultFile) -> CalibrationOptions:
    """The :class:`CalibrationOptions` a result file was computed with (its provenance; defaults
    for what it does not record)."""
    recorded = {} if file.provenance is None else dict(file.provenance.options)
    known = set(asdict(CalibrationOptions()))
    return CalibrationOptions().replace(**{k: v for k, v in recorded.items() if k in known})


def restore(cell: CellSpec, obs: Observations, file: ResultFile, options: CalibrationOptions | None = None
            ) -> Calibration:
    """The :class:`Calibration` behind a result file, with its solution: the problem of ``cell`` and
    ``obs`` built by the one builder, started at the file's intrinsics, transforms and points, with the
    measurements the file rejected as outliers left out and its variance components applied, solved
    once (no rounds: the file records what they decided).

    The solve starts at the file's optimum, so it stays there: the estimate and covariances agree with
    the file's to the solver's convergence tolerance. A hand-eye translation held at a prior along a
    common rotation axis (``stats.unobservable_fixed``) is held again.

    Priors from an earlier result (re-optimisation, ``stats.priors``) are not in a result file: such a
    result is refused.

    Args:
        cell, obs: the parsed cell spec and observations the result was computed from.
        file: the result.
        options: the options of the calibration (default: :func:`options_of` the file).

    Raises:
        BadInputError: the cell, observations and result do not belong together.
        NotObservableError: as :func:`calibrate_cell`.
    """
    from jcalib.problems.refine import Refined, uses_components
    from jcalib.solve import SolveOptions, solve

    if file.stats.get("priors"):
        raise BadInputError(
            f"result: it was re-optimised with priors from an earlier result ({', '.join(map(str, file.stats['priors']))}), "
            "which the result file does not hold; its solve can be used only in the process that computed it")
    options = options or options_of(file)
    cell = error_model.restored_cell(tracked_tools(cell), file.stats)
    points = {n: p.position for n, p in file.points.items()}
    g, s, built = prepare(cell, obs, options, start=file, points=points,
                          unobservable_fixed=file.stats.get("unobservable_fixed"))
    x0 = {}
    for c, model in s.models.items():
        saved = file.cameras.get(c)
        if saved is not None and tuple(saved.param_names) == tuple(model.param_names):
            x0[f"intrinsics:{c}"] = np.asarray(saved.params, np.float64)[None, :]
    for c in s.lenses:  # a zoom lens's functions (the file's lenses.<cam>)
        saved = (file.extra.get("lenses") or {}).get(c)
        if saved is None or len(saved.get("lens", [])) != built.problem.variable(f"lens:{c}").value.shape[-1]:
            raise BadInputError(f"result: the cell gives camera '{c}' a zoom lens, but the result has no matching "
                                f"lenses.{c} section; give the cell spec the result was computed from")
        x0[f"lens:{c}"] = np.asarray(saved["lens"], np.float64)[None, :]
    for t in built.warps:
        saved = file.targets.get(t)
        if saved is None:
            raise BadInputError(f"result: the cell estimates target '{t}''s warp (warp: true), but the result has no "
                                f"targets.{t}.warp_m; give the cell spec the result was computed from")
        x0[f"warp:{t}"] = np.asarray(saved.warp_m, np.float64)[None, :]
    for r in built.kinematics:
        saved = file.kinematics.get(r)
        model = g.robot_specs[r].kinematics
        if saved is None or tuple(saved.names) != tuple(model.param_names):
            raise BadInputError(f"result: the cell calibrates {g.label(r)}'s kinematics, but the result has no matching "
                                f"kinematics.{r} section; give the cell spec the result was computed from")
        x0[f"kinematics:{r}"] = np.asarray(saved.values, np.float64)[None, :]
    rejected = {(o["of"], str(o["station"]), int(o["point_index"])) for o in file.stats.get("outliers") or []}
    weights = built.unit_weights()
    for gr in built.groups:
        who = "/".join(gr.key) if gr.kind not in CORNER_KINDS else gr.key[0]
        hit = [(who, g.station_ids[int(k)], int(i)) in rejected for k, i in zip(gr.stations, gr.index)]
        weights[gr.name] = np.where(hit, 0.0, 1.0)
    components = {k: float(v) for k, v in (file.stats.get("variance_components") or {}).items()}
    traced = uses_components(built, options)
    scale = {**dict.fromkeys({gr.kind for gr in built.groups}, 1.0), **components} if traced else None
    views = built.view_factors(g.station_ids, file.stats.get("view_noise_factor") or {}) if traced else {}
    sol = solve(built.with_weights(weights, scale, views or None), x0=x0 or None,
                options=SolveOptions(max_iterations=options.max_iterations), traces=traced)
    outliers = [(who, sid, idx) for (who, sid, idx) in sorted(rejected)]
    noise = "stated" if traced and components else options.noise
    return assemble(g, s, built, Refined(sol, weights, outliers, [], components, noise, views))


def result_file(cal: Calibration, options: CalibrationOptions, hash_: str, extra_stats: dict | None = None) -> ResultFile:
    """The ``jcalib.result/1`` contents of a :class:`Calibration`."""
    cameras = {n: CameraResult.from_model(m, covariance=cal.intrinsics_covariance[n]) for n, m in cal.cameras.items()}
    transforms = {}
    for n, T in cal.transforms.items():
        extra = {}
        if len(cal.calibrated.get(n, [])) < 6:
            extra["calibrated"] = list(cal.calibrated.get(n, []))
        if n.startswith("T_flange_") and n[9:] in cal.tool_orientation:
            extra["orientation"] = cal.tool_orientation[n[9:]]
            extra["calibrated"] = list(cal.calibrated.get(n, []))
        transforms[n] = TransformResult(T, cal.transform_covariance[n], extra)
    frame = cal.frame if cal.graph is None or cal.graph.has_robot else cal.frame
    points = {n: PointResult(p, frame, cal.point_covariance[n]) for n, p in cal.points.items()}
    targets = {t: TargetResult(w, cal.warp_covariance[t]) for t, w in cal.warps.items()}
    stats: dict[str, Any] = {
        "num_residuals": cal.num_residuals,
        "iterations": cal.iterations,
        "status": cal.status,
        "num_stations": len(cal.station_ids),
        "num_outliers": len(cal.outliers),
    }
    if cal.rms_px == cal.rms_px:  # cells calibrated by contacts or poses alone have no corners
        stats.update(rms_px=cal.rms_px, rms_px_per_coordinate=cal.rms_px_per_coordinate, sigma_px=cal.sigma_px)
    for kind, key, scale in (("tip", "tip_rms_px", 1.0), ("axis", "axis_rms_px", 1.0), ("contact", "contact_rms_m", 1.0),
                             ("pose_rotation", "pose_rms_deg", float(np.degrees(1.0))),
                             ("pose_translation", "pose_rms_m", 1.0), ("position", "position_rms_m", 1.0)):
        if kind in cal.rms and cal.rms[kind] == cal.rms[kind]:
            stats[key] = cal.rms[kind] * scale
    tip = cal.rms_per_coordinate.get("tip")
    if tip is not None and np.isfinite(tip):
        stats["tip_rms_px_per_coordinate"] = tip
    if cal.sigma2 == cal.sigma2:
        stats["variance_factor"] = cal.sigma2
    if cal.variance_components:
        stats["variance_components"] = {k: float(v) for k, v in cal.variance_components.items()}
    if cal.view_rms_px:
        stats["view_rms_px"] = {f"{c}/{s}": v for (c, s), v in cal.view_rms_px.items()}
        stats["view_rms_px_per_coordinate"] = {f"{c}/{s}": v for (c, s), v in cal.view_rms_px_per_coordinate.items()}
    if cal.view_noise:
        stats["view_noise_factor"] = {f"{c}/{s}": v for (c, s), v in cal.view_noise.items()}
    if cal.graph is not None and cal.graph.has_robot:
        stats["robot_pose_model"] = cal.pose_model
        stats["start"] = dict(cal.start_method)
    if cal.outliers:
        stats["outliers"] = [{"of": who, "station": sid, "point_index": idx} for who, sid, idx in cal.outliers]
    if cal.reseeded_views:
        stats["reseeded_views"] = list(cal.reseeded_views)
    if cal.prediction is not None:
        stats["prediction"] = cal.prediction
    if cal.robot_error_model:
        stats["robot_error_model"] = cal.robot_error_model
    if cal.robot:
        stats["robot"] = next(iter(cal.robot.values())) if len(cal.robot) == 1 and not cal.graph.multi else cal.robot
    if cal.unobservable_fixed is not None:
        stats["unobservable_fixed"] = cal.unobservable_fixed
    if cal.priors:
        stats["priors"] = list(cal.priors)
    warnings = list(cal.warnings)  # with the solve's outcome (jcalib.problems.outcome), for every kind of cell
    for tool, how in cal.tool_orientation.items():
        if how == "not calibrated":
            warnings.append(f"tool '{tool}': only its tip (the TCP translation) is calibrated; its orientation is not "
                            "(no imaged tool axis): state it in the cell (tools.<name>.orientation or axis) before "
                            "exporting the tool to a controller")
    if warnings:
        stats["warnings"] = warnings
    notes = kinematics_notes(cal.graph)
    if notes:
        stats["notes"] = notes
    stats.update(extra_stats or {})
    extra: dict[str, Any] = {}
    jc = cal.joint_covariance
    if jc and jc["names"]:
        extra["joint_covariance"] = {"names": list(jc["names"]), "dims": [int(d) for d in jc["dims"]],
                                     "matrix": np.asarray(jc["matrix"]).tolist(),
                                     "order": "camera ids: intrinsics (param_names); transforms: rx, ry, rz, tx, ty, "
                                              "tz; warp:<target>: c0, c1"}
    if cal.lenses:
        extra["lenses"] = cal.lenses
    if cal.T_cam_target:
        extra["T_cam_target"] = {s: {c: T.tolist() for c, T in per.items()} for s, per in cal.T_cam_target.items()}
    provenance = Provenance.now(input_hash=hash_, options=asdict(options))
    kinematics = {r: kinematics_result(k) for r, k in cal.kinematics.items()}
    return attach_budget(ResultFile(cameras=cameras, transforms=transforms, points=points, targets=targets, stats=stats,
                                    provenance=provenance, extra=extra, kinematics=kinematics), cal.budget)


def kinematics_notes(g: Graph | None) -> list[str]:
    """One note per used robot whose nominal kinematics is its ``model`` preset (no ``kinematics:`` in the
    cell) where the solve used it: kinematics calibrated, or a station's flange pose from its joints."""
    if g is None:
        return []
    notes = []
    for r in g.used_robots:
        spec = g.robot_specs[r]
        if spec is None or not spec.kinematics_from_model:
            continue
        from_joints = any((st.flange_poses.get(r) if g.multi or st.flange_poses else st.T_base_flange) is None
                          for st in g.obs.stations)
        if spec.calibrate_kinematics or from_joints:
            notes.append(f"nominal kinematics: {g.label(r)}'s model preset {spec.model} (the cell has no "
                         "kinematics:; write kinematics: <preset or table> to use another)")
    return notes


def kinematics_result(k: dict) -> KinematicsResult:
    """The result-file entry of a robot's calibrated kinematics (:func:`jcalib.problems.assemble.kinematic_result`)."""
    model, params, free = k["model"], k["params"], k["free"]
    names = list(model.param_names)
    cov = np.asarray(k["covariance"], np.float64)[np.ix_(free, free)]
    extra = {"held": dict(k["held"]), "repeatability": k["repeatability"], "spec": kinematic_tables.to_spec(model, params),
             "weakly_determined": {n: {"std_over_prior_std": x} for n, x in k.get("weak", {}).items()},
             **({"heldout": k["heldout"]} if "heldout" in k else {}),
             "controller_offsets": kinematic_models.controller_offsets(model, params),
             "table": kinematic_tables.table(model, params),
             "correction_rms_translation_m": k["correction_rms_translation_m"],
             "correction_rms_rotation_deg": k["correction_rms_rotation_deg"]}
    return KinematicsResult(model.convention, tuple(names), params, np.asarray(model.nominal, np.float64),
                            tuple(n for n, f in zip(names, free) if f), cov, extra)
