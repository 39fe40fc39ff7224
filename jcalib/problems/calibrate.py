"""``jcalib.calibrate(cell, observations) -> Result``: the one entry point from data to a result file."""

from __future__ import annotations

import os
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.cell import CellSpec, cell_to_dict, load_cell
from jcalib.io.observations import Observations, load_observations
from jcalib.io.result import CameraResult, PointResult, Provenance, ResultFile, TransformResult, hash_inputs


class Result:
    """A calibration result: the ``jcalib.result/1`` contents plus the solver's details.

    Attributes:
        file: the :class:`~jcalib.io.result.ResultFile` (what ``to_json`` writes).
        details: the problem-specific outcome (e.g. :class:`~jcalib.problems.camera.CameraCalibration`),
            with per-view residuals and the solver's solution.
    """

    def __init__(self, file: ResultFile, details: Any = None):
        self.file = file
        self.details = details

    def to_json(self, path: str | os.PathLike) -> Path:
        """Write the result file atomically (JSON, never pickle)."""
        return self.file.save(path)

    def covariance(self, name: str) -> np.ndarray:
        """Covariance of a named unknown.

        ``name`` is a camera id (covariance of its intrinsic vector, order of the camera's
        ``param_names``) or a transform name such as ``T_cam0_cam1`` (6x6, tangent order
        rx, ry, rz, tx, ty, tz, right perturbation; rad and m).
        """
        if name in self.file.cameras and self.file.cameras[name].covariance is not None:
            return np.asarray(self.file.cameras[name].covariance)
        if name in self.file.transforms and self.file.transforms[name].covariance is not None:
            return np.asarray(self.file.transforms[name].covariance)
        known = list(self.file.cameras) + list(self.file.transforms)
        raise BadInputError(f"no covariance for {name!r}; the result has: {', '.join(known)}")

    def __repr__(self) -> str:
        return f"Result(cameras={list(self.file.cameras)}, transforms={list(self.file.transforms)})"


def _input_hash(cell_arg, obs_arg, cell: CellSpec, obs: Observations) -> str:
    import json

    parts = []
    for arg, obj in ((cell_arg, cell_to_dict(cell)), (obs_arg, obs.to_dict())):
        if isinstance(arg, (str, os.PathLike)):
            parts.append(Path(arg))
        else:
            parts.append(json.dumps(obj, sort_keys=True).encode())
    return hash_inputs(*parts)


def calibrate(cell, observations, options=None, *, prior=None) -> Result:
    """Calibrate a cell from observations.

    Args:
        cell: a ``jcalib.cell/1`` spec: path, dict or :class:`~jcalib.io.cell.CellSpec`.
        observations: a ``jcalib.observations/1`` document: path, dict or
            :class:`~jcalib.io.observations.Observations`.
        options: problem options (for camera-only cells a
            :class:`~jcalib.problems.camera.CameraCalibrationOptions`; for hand-eye cells, cameras on
            the flange and one target on the base or the reverse, a
            :class:`~jcalib.problems.handeye.HandEyeOptions`, e.g. ``HandEyeOptions(pose_model=False)``
            to switch the cell's robot pose model off; for whole cells, mixed mounts or tools, a
            :class:`~jcalib.problems.cell.CellOptions`).
        prior: a previous result (path, :class:`~jcalib.io.result.ResultFile` or :class:`Result`) of the
            same robot cell: re-optimisation (:func:`jcalib.problems.reoptimise.reoptimise`). The new data are
            solved on their own, every unknown is compared with the old value by a χ² test on the
            difference (both covariances), and the final solve keeps the old values as priors for the
            unknowns that did not move. ``stats["reoptimisation"]`` lists each test and what moved.

    Returns:
        :class:`Result`. Uncertainties are sampling noise (pixel noise propagated to the
        unknowns, scaled by the a-posteriori σ by default), not model error.

    Raises:
        BadInputError: malformed input, naming the file, station and camera.
        NotObservableError: the data cannot determine some unknowns, naming them.
    """
    cell_spec = load_cell(cell)
    obs = load_observations(observations)
    if prior is not None:
        from jcalib.problems.reoptimise import reoptimise

        return reoptimise(cell_spec, obs, prior, options, input_hash=_input_hash(cell, observations, cell_spec, obs)).result
    has_robot = any(c.mount != "free" for c in cell_spec.cameras.values()) or any(
        t.mount != "free" for t in cell_spec.targets.values()
    )
    if has_robot:
        from jcalib.problems.handeye import is_hand_eye_cell

        if is_hand_eye_cell(cell_spec) and not isinstance(options, _cell_options_type()):
            return _calibrate_hand_eye(cell, observations, cell_spec, obs, options)
    from jcalib.problems.cell import is_cell_problem

    if is_cell_problem(cell_spec):
        return _calibrate_cell(cell_spec, obs, options, _input_hash(cell, observations, cell_spec, obs))
    if has_robot or cell_spec.tools or cell_spec.points:
        raise BadInputError(
            f"{cell_spec.source}: this version calibrates cameras with free-moving targets "
            "(mount: free); robot-mounted cameras, targets, tools and points come with the "
            "hand-eye and TCP problems"
        )
    from jcalib.problems.camera import CameraCalibrationOptions, calibrate_cameras

    options = options or CameraCalibrationOptions()
    cal = calibrate_cameras(cell_spec, obs, options)
    cameras = {
        name: CameraResult.from_model(model, covariance=cal.intrinsics_covariance[name])
        for name, model in cal.cameras.items()
    }
    transforms = {
        f"T_{cal.reference_camera}_{name}": TransformResult(T, cal.T_ref_cam_covariance[name])
        for name, T in cal.T_ref_cam.items()
        if name != cal.reference_camera
    }
    stats = {
        "rms_px": cal.rms_px,
        "num_residuals": cal.num_residuals,
        "sigma_px": cal.sigma_px,
        "iterations": cal.iterations,
        "status": cal.status,
        "num_outliers": len(cal.outliers),
        "view_rms_px": {f"{c}/{s}": v for (c, s), v in cal.view_rms_px.items()},
    }
    if cal.reseeded_views:
        stats["reseeded_views"] = cal.reseeded_views
    warnings = []
    if cal.rms_px > 5.0 * options.sigma_px:
        warnings.append(
            f"reprojection RMS {cal.rms_px:.3g} px is over 5x the stated corner noise "
            f"({options.sigma_px:g} px): the lens model is probably too simple for this lens (try a model "
            "with more distortion terms, or fisheye) or detections are wrong; the reported σ describe "
            "noise only, not this model error"
        )
    if warnings:
        stats["warnings"] = warnings
    provenance = Provenance.now(
        input_hash=_input_hash(cell, observations, cell_spec, obs), options=asdict(options)
    )
    # Per-view target poses (an optional key; the report re-projects residuals with them).
    poses = {station: {c: T.tolist() for c, T in per_cam.items()} for station, per_cam in cal.T_cam_target.items()}
    file = ResultFile(
        cameras=cameras, transforms=transforms, stats=stats, provenance=provenance, extra={"T_cam_target": poses}
    )
    return Result(file, cal)


def _calibrate_hand_eye(cell_arg, obs_arg, cell_spec: CellSpec, obs: Observations, options) -> Result:
    """Hand-eye cells (cameras on the flange and one target on the base, or the reverse).

    ``options``: a :class:`~jcalib.problems.handeye.HandEyeOptions` (``pose_model`` overrides the
    cell's robot pose model, ``fix_unobservable`` etc.), or the CLI's
    :class:`~jcalib.problems.camera.CameraCalibrationOptions`, of which ``sigma_px``, ``noise``,
    ``loss``, ``loss_scale``, ``outlier_threshold`` and ``max_iterations`` carry over.
    """
    from jcalib.problems.camera import CameraCalibrationOptions
    from jcalib.problems.handeye import HandEyeOptions, calibrate_hand_eye

    options = options or HandEyeOptions()
    if isinstance(options, CameraCalibrationOptions):  # e.g. from the CLI: keep what applies
        options = HandEyeOptions.from_camera_options(options)
    if not isinstance(options, HandEyeOptions):
        raise BadInputError(
            f"options: got {type(options).__name__}, expected HandEyeOptions for a hand-eye cell"
        )
    cal = calibrate_hand_eye(cell_spec, obs, options)
    cameras = {
        name: CameraResult.from_model(c.model, covariance=c.intrinsics_covariance) for name, c in cal.cameras.items()
    }
    transforms = {c.hand_eye_name: TransformResult(c.T_hand_eye, c.T_hand_eye_covariance) for c in cal.cameras.values()}
    transforms[cal.target_name] = TransformResult(cal.T_target, cal.T_target_covariance)
    stats = {
        "rms_px": cal.rms_px,
        "num_residuals": cal.num_residuals,
        "sigma_px": cal.sigma_px,
        # overall a-posteriori variance factor of all residuals (pixels and robot prior together);
        # with the pose model the covariance uses the pixels' own factor, (sigma_px / stated)^2
        "variance_factor": cal.sigma2,
        "iterations": cal.iterations,
        "status": cal.status,
        "num_stations": len(cal.station_ids),
        "num_outliers": len(cal.outliers),
        "view_rms_px": {f"{c.camera}/{s}": v for c in cal.cameras.values() for s, v in c.view_rms_px.items()},
        "hand_eye_init": cal.init.method,
        "robot_pose_model": cal.pose_model,
    }
    if cal.outliers:
        stats["outliers"] = [{"camera": c, "station": s, "point_index": i} for c, s, i in cal.outliers]
    if cal.unobservable_fixed is not None:
        stats["unobservable_fixed"] = cal.unobservable_fixed
    if cal.robot:
        stats["robot"] = cal.robot
    warnings = list(cal.warnings)
    if cal.rms_px > 5.0 * options.sigma_px:
        warnings.append(
            f"reprojection RMS {cal.rms_px:.3g} px is over 5x the stated corner noise ({options.sigma_px:g} px): "
            "the lens model is probably too simple, detections are wrong, or the robot poses are worse "
            "than stated; the reported σ describe noise only, not this model error"
        )
    if warnings:
        stats["warnings"] = warnings
    provenance = Provenance.now(
        input_hash=_input_hash(cell_arg, obs_arg, cell_spec, obs), options=asdict(options)
    )
    file = ResultFile(cameras=cameras, transforms=transforms, stats=stats, provenance=provenance)
    return Result(file, cal)


def _cell_options_type():
    from jcalib.problems.cell import CellOptions

    return CellOptions


def cell_result(cal, cell_spec: CellSpec, options, input_hash: str, extra_stats: dict | None = None) -> Result:
    """The :class:`Result` of a :class:`~jcalib.problems.cell.CellCalibration`."""
    cameras = {
        name: CameraResult.from_model(model, covariance=cal.intrinsics_covariance[name])
        for name, model in cal.cameras.items()
    }
    transforms = {n: TransformResult(T, cal.transform_covariance[n]) for n, T in cal.transforms.items()}
    frame = getattr(cal, "frame", "base")  # "world" in cells with several robots
    points = {n: PointResult(p, frame, cal.point_covariance[n]) for n, p in getattr(cal, "points", {}).items()}
    stats = {
        "num_residuals": cal.num_residuals,
        "iterations": cal.iterations,
        "status": cal.status,
        "num_stations": len(cal.station_ids),
        "robot_pose_model": cal.pose_model,
        "start": dict(cal.start_method),
        "problem": "cell",
    }
    if cal.rms_px == cal.rms_px:  # a cell calibrated by contacts alone has no pixels
        stats.update(rms_px=cal.rms_px, sigma_px=cal.sigma_px)
    if cal.sigma2 == cal.sigma2:
        stats["variance_factor"] = cal.sigma2
    if getattr(cal, "variance_components", None):
        stats["variance_components"] = {k: float(v) for k, v in cal.variance_components.items()}
    if cal.tip_rms_px == cal.tip_rms_px:
        stats["tip_rms_px"] = cal.tip_rms_px
    if getattr(cal, "contact_rms_m", float("nan")) == cal.contact_rms_m:
        stats["contact_rms_m"] = cal.contact_rms_m
    if getattr(cal, "outliers", None) is not None:
        stats["num_outliers"] = len(cal.outliers)
        if cal.outliers:
            stats["outliers"] = [f"{who}/{sid}/{idx}" for who, sid, idx in cal.outliers]
    if cal.priors:
        stats["priors"] = list(cal.priors)
    if cal.warnings:
        stats["warnings"] = list(cal.warnings)
    stats.update(extra_stats or {})
    provenance = Provenance.now(input_hash=input_hash, options=asdict(options))
    extra = {}
    if cal.joint_covariance:
        jc = cal.joint_covariance
        extra["joint_covariance"] = {"names": list(jc["names"]), "dims": [int(d) for d in jc["dims"]],
                                     "matrix": np.asarray(jc["matrix"]).tolist(),
                                     "order": "camera ids: intrinsics (param_names); transforms: rx, ry, rz, tx, ty, tz"}
    file = ResultFile(cameras=cameras, transforms=transforms, points=points, stats=stats, provenance=provenance,
                      extra=extra)
    return Result(file, cal)


def _calibrate_cell(cell_spec: CellSpec, obs: Observations, options, input_hash: str) -> Result:
    """Whole robot cells: mixed flange/base cameras and targets, tools seen by fixed cameras."""
    from jcalib.problems.cell import CellOptions, calibrate_cell

    options = CellOptions.from_options(options)
    return cell_result(calibrate_cell(cell_spec, obs, options), cell_spec, options, input_hash)
