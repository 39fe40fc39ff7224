"""The study table: one row per trial and estimator, errors against the truth and reported σ.

Columns (:func:`columns`): ``trial``, ``estimator``, ``status`` (``ok``, ``not_observable: ...``,
``bad_input: ...``, ``error (Type): ...``), ``num_stations`` (stations the estimator used),
``runtime_s``, ``rms_px`` (corner reprojection RMS), ``nees`` and ``nees_dof`` (the normalised
estimation error squared of everything the estimator reports a joint covariance for: intrinsics and
transforms, χ²(nees_dof) when the covariance is honest), then one block per unknown of the cell
(:func:`unknowns`), named after it:

- transform ``T`` (``T_flange_cam0``, ``T_base_board``, ``T_flange_tool``, ``T_world_r2``, a rig's
  ``T_cam0_cam1``): ``err_T_rot_deg`` (rotation angle), ``err_T_trans_mm`` (distance), ``err_T_r{x,y,z}_deg``
  and ``err_T_t{x,y,z}_mm``: the tangent error ``δ = Log(T_true⁻¹ · T_est)`` (estimate − truth, right perturbation, the
  tangent of the reported covariance), ``sigma_T_*`` the reported standard deviations, ``nees_T``
  (χ² with as many degrees of freedom as coordinates estimated). Coordinates an estimator does not
  estimate are NaN. A tool's true rotation is taken by the estimator's convention (its symmetry axis
  with the smallest rotation from the flange z when the orientation is calibrated, else the estimated
  rotation: only the tip is compared);
- camera ``c``: ``err_c_<param>`` (estimate − truth; ``_px`` for fx, fy, cx, cy, skew), ``sigma_c_<param>``,
  ``nees_c`` (over its estimated parameters);
- cell point ``p``: ``err_p_{x,y,z}_mm``, ``err_p_norm_mm``, ``sigma_p_{x,y,z}_mm``, ``nees_p``.

Failures are rows too (status says why, numbers NaN): a study counts how often a strategy fails.
"""

from __future__ import annotations

import math

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.se3 import invert, log_se3
from jcalib.io.cell import CellSpec
from jcalib.problems.tools import rotation_z_to
from jcalib.study.estimate import Estimate
from jcalib.study.scenario import Scenario
from jcalib.study.stations import holder
from jcalib.study.truth import cell_frame, reference_camera

__all__ = ["COMMON", "columns", "error_row", "row", "status", "unknowns"]

COMMON = ["trial", "estimator", "status", "num_stations", "runtime_s", "rms_px", "nees", "nees_dof"]
_AXES = ["rx", "ry", "rz", "tx", "ty", "tz"]
_UNITS = ["deg"] * 3 + ["mm"] * 3
_SCALE = np.array([180.0 / np.pi] * 3 + [1e3] * 3)  # rad -> deg, m -> mm
_PX = {"fx", "fy", "cx", "cy", "skew"}


def unknowns(scenario: Scenario) -> tuple[list[str], list[str], list[str]]:
    """``(cameras with estimated intrinsics, estimated transforms, estimated points)`` of the scenario's cell,
    named as the builder reports them (a rig's transforms in its first camera's frame)."""
    cell: CellSpec = scenario.cell_spec
    from jcalib.geometry.cameras import camera_model_from_name

    fixed = set(cell.fixed)
    frame = cell_frame(cell)
    ref = reference_camera(cell)
    pose_only = {b.camera for b in scenario.stations if b.kind == "pair" and b.measure == "poses"}
    pose_only -= {b.camera for b in scenario.stations if b.kind != "pair" or b.measure == "corners"}
    pose_only -= {c for t in cell.tools.values() for c in t.observed_by}
    cams = []
    for c, spec in cell.cameras.items():
        names = camera_model_from_name(spec.model, (100, 100), skew=spec.skew).param_names
        if c not in pose_only and not set(names) <= set(spec.fix) and c not in scenario.given:
            cams.append(c)
    transforms = []
    for spec in list(cell.cameras.values()) + list(cell.targets.values()):
        h = holder(cell, spec.name)
        if h == "free" or spec.name == ref:
            continue
        name = f"T_flange_{spec.name}" if h is not None else f"T_{frame}_{spec.name}"
        if spec.name not in fixed and name not in fixed:
            transforms.append(name)
    transforms += [f"T_flange_{t}" for t in cell.tools if t not in fixed and f"T_flange_{t}" not in fixed]
    if len(cell.robots) > 1:
        anchored = any(s.base is not None and (r in fixed or f"T_world_{r}" in fixed) for r, s in cell.robots.items())
        anchored |= any(s.mount == "world" and s.pose is not None and (s.name in fixed or f"T_world_{s.name}" in fixed)
                        for s in list(cell.cameras.values()) + list(cell.targets.values()))
        for i, (r, s) in enumerate(cell.robots.items()):
            held = (i == 0 and not anchored) or (s.base is not None and (r in fixed or f"T_world_{r}" in fixed))
            if not held:
                transforms.append(f"T_world_{r}")
    points = [p for p, s in cell.points.items() if s.position is None and p not in fixed and p not in scenario.given]
    return cams, transforms, points


def _param_cols(scenario: Scenario, cam: str) -> list[str]:
    from jcalib.geometry.cameras import camera_model_from_name

    spec = scenario.cell_spec.cameras[cam]
    names = camera_model_from_name(spec.model, (100, 100), skew=spec.skew).param_names
    return [f"{p}_px" if p in _PX else p for p in names]


def columns(scenario: Scenario) -> list[str]:
    """The table's columns, in order, for this scenario's cell."""
    cams, transforms, points = unknowns(scenario)
    out = list(COMMON)
    for T in transforms:
        out += [f"err_{T}_rot_deg", f"err_{T}_trans_mm"]
        out += [f"err_{T}_{a}_{u}" for a, u in zip(_AXES, _UNITS)]
        out += [f"sigma_{T}_{a}_{u}" for a, u in zip(_AXES, _UNITS)]
        out.append(f"nees_{T}")
    for c in cams:
        p = _param_cols(scenario, c)
        out += [f"err_{c}_{n}" for n in p] + [f"sigma_{c}_{n}" for n in p] + [f"nees_{c}"]
    for p in points:
        out += [f"err_{p}_{a}_mm" for a in "xyz"] + [f"err_{p}_norm_mm"] + [f"sigma_{p}_{a}_mm" for a in "xyz"]
        out.append(f"nees_{p}")
    return out


def status(err: Exception) -> str:
    """The status cell of a failed estimator or trial."""
    kind = ("not_observable" if isinstance(err, NotObservableError) else
            "bad_input" if isinstance(err, BadInputError) else f"error ({type(err).__name__})")
    return f"{kind}: {' '.join(str(err).split())}"


def nees(delta: np.ndarray, cov: np.ndarray) -> tuple[float, int]:
    """``(δᵀ Σ⁺ δ, rank Σ)`` over the coordinates with a positive variance (a pseudo-inverse of the
    correlation matrix, so ties such as a fixed aspect ratio count once)."""
    delta, cov = np.asarray(delta, np.float64), np.asarray(cov, np.float64)
    d = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    keep = (d > 0) & np.isfinite(d) & np.isfinite(delta)
    if not keep.any():
        return math.nan, 0
    C = cov[np.ix_(keep, keep)] / np.outer(d[keep], d[keep])
    z = delta[keep] / d[keep]
    try:
        w, V = np.linalg.eigh(0.5 * (C + C.T))
    except np.linalg.LinAlgError:
        return math.nan, 0
    good = w > 1e-10 * max(float(w.max()), 1e-300)
    y = V[:, good].T @ z
    return float(np.sum(y**2 / w[good])), int(good.sum())


def _true_transform(name: str, est: Estimate, truth) -> np.ndarray | None:
    T_true = truth.transform(name)
    if T_true is None:
        return None
    if name.startswith("T_flange_") and name[9:] in truth.poses and name[9:] in est.tool_orientation:
        T_true = T_true.copy()
        if est.tool_orientation[name[9:]] == "calibrated":
            T_true[:3, :3] = rotation_z_to(T_true[:3, 2])
        else:
            T_true[:3, :3] = est.transforms[name][:3, :3]
    return T_true


def _transform_cells(out: dict, name: str, est: Estimate, truth) -> np.ndarray | None:
    """Fill the columns of transform ``name``; returns its tangent error δ (6,) or None."""
    if name not in est.transforms:
        return None
    T_est = est.transforms[name]
    T_true = _true_transform(name, est, truth)
    if T_true is None:
        return None
    delta = log_se3(invert(T_true) @ T_est)
    coords = est.calibrated.get(name, _AXES)
    mask = np.array([a in coords for a in _AXES])
    if mask[:3].any():
        out[f"err_{name}_rot_deg"] = float(np.degrees(np.linalg.norm(delta[:3])))
    if mask[3:].any():
        out[f"err_{name}_trans_mm"] = float(1e3 * np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))
    for k, (a, u) in enumerate(zip(_AXES, _UNITS)):
        if mask[k]:
            out[f"err_{name}_{a}_{u}"] = float(delta[k] * _SCALE[k])
    cov = est.transform_covariance.get(name)
    if cov is not None:
        cov = np.asarray(cov, np.float64)
        for k, (a, u) in enumerate(zip(_AXES, _UNITS)):
            if mask[k]:
                out[f"sigma_{name}_{a}_{u}"] = float(np.sqrt(max(cov[k, k], 0.0)) * _SCALE[k])
        out[f"nees_{name}"] = nees(delta[mask], cov[np.ix_(mask, mask)])[0]
    return delta


def _camera_cells(out: dict, scenario: Scenario, cam: str, est: Estimate, truth) -> np.ndarray | None:
    if cam not in est.cameras:
        return None
    true = np.asarray(truth.cameras[cam].params, np.float64)
    err = np.asarray(est.cameras[cam], np.float64) - true
    spec = scenario.cell_spec.cameras[cam]
    names = truth.cameras[cam].param_names
    free = np.array([n not in spec.fix for n in names])
    cols = _param_cols(scenario, cam)
    cov = est.camera_covariance.get(cam)
    for k, c in enumerate(cols):
        if free[k]:
            out[f"err_{cam}_{c}"] = float(err[k])
            if cov is not None:
                out[f"sigma_{cam}_{c}"] = float(np.sqrt(max(cov[k, k], 0.0)))
    if cov is not None:
        out[f"nees_{cam}"] = nees(np.where(free, err, 0.0), np.asarray(cov) * np.outer(free, free))[0]
    return err


def _point_cells(out: dict, point: str, est: Estimate, truth) -> None:
    if point not in est.points:
        return
    err = np.asarray(est.points[point], np.float64) - np.asarray(truth.points[point], np.float64)
    for a, e in zip("xyz", err):
        out[f"err_{point}_{a}_mm"] = float(1e3 * e)
    out[f"err_{point}_norm_mm"] = float(1e3 * np.linalg.norm(err))
    cov = est.point_covariance.get(point)
    if cov is not None:
        for a, v in zip("xyz", np.diag(cov)):
            out[f"sigma_{point}_{a}_mm"] = float(1e3 * np.sqrt(max(v, 0.0)))
        out[f"nees_{point}"] = nees(err, cov)[0]


def _joint(scenario: Scenario, est: Estimate, deltas: dict) -> tuple[float, int]:
    """NEES over the estimated coordinates of the joint covariance (transforms: their ``calibrated``
    coordinates; cameras: the intrinsics the cell does not fix)."""
    jc = est.joint
    if not jc or not jc.get("names"):
        return math.nan, 0
    parts, masks = [], []
    cams = scenario.cell_spec.cameras
    for name, dim in zip(jc["names"], jc["dims"]):
        d = deltas.get(name)
        if d is None or len(d) != dim:
            return math.nan, 0
        if name in cams and name in est.cameras:
            from jcalib.geometry.cameras import camera_model_from_name

            spec = cams[name]
            names = camera_model_from_name(spec.model, (100, 100), skew=spec.skew).param_names
            masks.append(np.array([n not in spec.fix for n in names]))
        else:
            masks.append(np.array([a in est.calibrated.get(name, _AXES) for a in _AXES]))
        parts.append(d)
    mask = np.concatenate(masks)
    M = np.asarray(jc["matrix"], np.float64)
    return nees(np.concatenate(parts)[mask], M[np.ix_(mask, mask)])


def row(scenario: Scenario, cols: list[str], trial: int, estimator: str, est: Estimate, truth) -> dict:
    """The table row of one estimate (see the module docstring)."""
    out = dict.fromkeys(cols, math.nan)
    out.update(trial=int(trial), estimator=estimator, status="ok", num_stations=int(est.num_stations),
               runtime_s=float(est.runtime_s), rms_px=float(est.rms_px))
    cams, transforms, points = unknowns(scenario)
    deltas = {}
    for name in est.transforms:
        if name in transforms:
            d = _transform_cells(out, name, est, truth)
        else:  # reported, no column (e.g. fixed): still part of the joint NEES
            T_true = _true_transform(name, est, truth)
            d = None if T_true is None else log_se3(invert(T_true) @ est.transforms[name])
        if d is not None:
            deltas[name] = d
    for cam in est.cameras:
        if cam in cams:
            d = _camera_cells(out, scenario, cam, est, truth)
        else:
            d = np.asarray(est.cameras[cam], np.float64) - np.asarray(truth.cameras[cam].params, np.float64)
        deltas[cam] = d
    for p in points:
        _point_cells(out, p, est, truth)
    out["nees"], out["nees_dof"] = _joint(scenario, est, deltas)
    if not out["nees_dof"]:
        out["nees"], out["nees_dof"] = math.nan, math.nan
    return {k: out[k] for k in cols}


def error_row(cols: list[str], trial: int, estimator: str, err: Exception, num_stations: int = 0) -> dict:
    out = dict.fromkeys(cols, math.nan)
    out.update(trial=int(trial), estimator=estimator, status=status(err), num_stations=int(num_stations),
               runtime_s=float(getattr(err, "runtime_s", math.nan)))
    return out
