"""Joint hand-eye calibration: one camera on the robot (or fixed), one target fixed (or on the robot).

Eye-in-hand (camera ``mount: flange``, target ``mount: base``): unknowns ``T_flange_cam``,
``T_base_target`` and the intrinsics; corner ``p`` of station ``i`` is seen at

    project(K, inv(T_flange_cam) · inv(T_base_flange_i) · T_base_target · p).

Eye-to-hand (camera ``mount: base``, target ``mount: flange``): unknowns ``T_base_cam``,
``T_flange_target``; ``p_cam = inv(T_base_cam) · T_base_flange_i · T_flange_target · p``.

Robot pose error model: with ``robot: {pose_noise: {translation_m, rotation_deg}}`` in the cell, the
true flange pose of every station is an unknown ``T_base_flange_i = T_meas_i · Exp(δ_i)`` (right
perturbation: ``δ_i`` in the flange frame, ``(rx, ry, rz, tx, ty, tz)``) with a zero-mean Gaussian
prior of those per-axis σ. These per-station poses are the eliminated variable (Schur complement),
so the shared system stays small (intrinsics + two poses). Without ``pose_noise`` the measured poses
are taken as exact (the same variable, fully fixed).

Start: Zhang on all views (or the cell's intrinsics), per-view planar pose, motion observability
check (:func:`jcalib.init.handeye.check_observable`), then a closed-form hand-eye solve
(Park–Martin by default). jcalib's engine refines everything jointly and gives the covariance.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import lie
from jcalib.geometry.cameras import AbstractCameraModel
from jcalib.init.handeye import (
    HAND_EYE_METHODS,
    HandEyeInit,
    analyse_motion,
    check_observable,
    solve_hand_eye,
)
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
from jcalib.solve import (
    SE3,
    Euclidean,
    FactorGroup,
    Problem,
    SolveOptions,
    Variable,
    solve,
)
from jcalib.solve.covariance import covariance as _covariance


@dataclass(frozen=True)
class HandEyeOptions:
    """Options of :func:`calibrate_hand_eye`.

    Attributes:
        method: closed-form start: a key of :data:`jcalib.init.handeye.HAND_EYE_METHODS`
            (``"park_martin"`` default, ``"tsai_lenz"``, ``"horaud"``, ``"andreff"``, ``"daniilidis"``).
        sigma_px: stated corner noise (pixels). It weighs the pixels against the robot-pose prior, so
            state it honestly when the pose model is on.
        noise: covariance scale: ``"a_posteriori"`` (σ̂² from the residuals, default) or ``"stated"``.
        pose_model: per-station robot-pose corrections: ``None`` (default) = on when the cell has
            ``robot.pose_noise``; ``False`` = off (poses exact) even then. ``True`` needs ``pose_noise``.
        max_iterations: LM iteration limit.
    """

    method: str = "park_martin"
    sigma_px: float = 0.25
    noise: str = "a_posteriori"
    pose_model: bool | None = None
    max_iterations: int = 100

    def __post_init__(self):
        if self.method not in HAND_EYE_METHODS:
            raise BadInputError(f"method: got {self.method!r}, expected one of {sorted(HAND_EYE_METHODS)}")
        if self.noise not in ("a_posteriori", "stated"):
            raise BadInputError(f"noise: got {self.noise!r}, expected 'a_posteriori' or 'stated'")
        if not self.sigma_px > 0:
            raise BadInputError(f"sigma_px: got {self.sigma_px!r}, expected a positive number of pixels")


@dataclass
class HandEyeCalibration:
    """The outcome of :func:`calibrate_hand_eye` (see :class:`jcalib.Result` for the file form).

    Attributes:
        mount: ``"flange"`` (eye-in-hand) or ``"base"`` (eye-to-hand): where the camera is.
        camera, target: ids from the cell.
        model: the calibrated camera model.
        intrinsics_covariance: ``(p, p)`` covariance of ``model.params`` (order ``param_names``).
        hand_eye_name: ``"T_flange_<camera>"`` or ``"T_base_<camera>"``.
        T_hand_eye: (4, 4) that transform, m.
        T_hand_eye_covariance: (6, 6) right-perturbation covariance (rx..tz; rad², m²).
        target_name: ``"T_base_<target>"`` or ``"T_flange_<target>"``.
        T_target: (4, 4) that transform, m.
        T_target_covariance: (6, 6), as above.
        station_ids: ids of the stations used (those where the camera sees the target).
        T_base_flange_measured: (N, 4, 4) measured flange poses of those stations, m.
        T_base_flange: (N, 4, 4) estimated true flange poses (equal to the measured ones without the
            pose model), m.
        robot: robot-accuracy statistics (empty without the pose model): ``prior_sigma_*`` (the
            stated σ), ``correction_rms_*`` (RMS of the estimated corrections δ per axis),
            ``a_posteriori_sigma_*`` (variance-component estimate of the robot's σ per axis:
            the prior σ scaled by sqrt(Σ‖Sδ‖² / redundancy of the prior residuals)),
            ``redundancy`` of the prior residuals. Units: ``_m`` metres, ``_deg`` degrees;
            axes in the flange frame.
        init: the closed-form start (:class:`jcalib.init.handeye.HandEyeInit`).
        view_rms_px: station id -> RMS reprojection error (pixels).
        rms_px, sigma_px: overall RMS and a-posteriori corner noise σ (pixels).
        num_residuals, iterations, status, sigma2: solver facts (``sigma2`` the variance factor).
        solution: the :class:`jcalib.solve.Solution`.
    """

    mount: str
    camera: str
    target: str
    model: AbstractCameraModel
    intrinsics_covariance: np.ndarray
    hand_eye_name: str
    T_hand_eye: np.ndarray
    T_hand_eye_covariance: np.ndarray
    target_name: str
    T_target: np.ndarray
    T_target_covariance: np.ndarray
    station_ids: list[str]
    T_base_flange_measured: np.ndarray
    T_base_flange: np.ndarray
    robot: dict
    init: HandEyeInit
    view_rms_px: dict[str, float]
    rms_px: float
    sigma_px: float
    num_residuals: int
    iterations: int
    status: str
    sigma2: float
    pose_model: bool
    solution: object = field(default=None, repr=False)


# ------------------------------------------------------------------------------------ residual


@functools.cache
def _handeye_reprojection_fn(model_cls: type, image_size: tuple[int, int], skew: bool, camera_mount: str):
    """Residual ``(intrinsics, T_hand_eye, T_target, T_base_flange, obs) -> predicted - observed`` (px).

    ``camera_mount="flange"``: ``T_hand_eye = T_flange_cam``, ``T_target = T_base_target``;
    ``"base"``: ``T_hand_eye = T_base_cam``, ``T_target = T_flange_target``. ``obs`` as in
    :func:`jcalib.problems.camera._reprojection_fn`: ``(p_target (3,), pixel (2,), aspect (2,))``.
    One function object per configuration, so new data reuse the compiled solver.
    """
    project = _reprojection_fn(model_cls, image_size, skew)
    if camera_mount == "flange":

        def fn(intrinsics, T_flange_cam, T_base_target, T_base_flange, obs):
            T_cam_base = lie.se3_inverse(lie.se3_compose(T_base_flange, T_flange_cam))
            return project(intrinsics, T_cam_base, T_base_target, obs)

    else:

        def fn(intrinsics, T_base_cam, T_flange_target, T_base_flange, obs):
            T_cam_flange = lie.se3_compose(lie.se3_inverse(T_base_cam), T_base_flange)
            return project(intrinsics, T_cam_flange, T_flange_target, obs)

    return fn


@functools.cache
def _residuals_jit(fn):
    return jax.jit(jax.vmap(fn))


# ------------------------------------------------------------------------------------ data


@dataclass
class _Data:
    camera: object  # CameraSpec
    target_name: str
    mount: str  # camera mount
    cd: _CameraData
    station_ids: list[str]
    T_base_flange: np.ndarray  # (N, 4, 4) measured, for the used stations


def _select(cell: CellSpec) -> tuple[object, object]:
    """The (camera, target) pair of a hand-eye cell, or BadInputError."""
    cams = list(cell.cameras.values())
    tgts = list(cell.targets.values())
    if len(cams) != 1 or len(tgts) != 1:
        raise BadInputError(
            f"{cell.source}: hand-eye calibration takes one camera and one target, the cell has cameras "
            f"{[c.name for c in cams]} and targets {[t.name for t in tgts]}"
        )
    cam, tgt = cams[0], tgts[0]
    pairs = {("flange", "base"), ("base", "flange")}
    if (cam.mount, tgt.mount) not in pairs:
        raise BadInputError(
            f"{cell.source}: camera '{cam.name}' mount '{cam.mount}' with target '{tgt.name}' mount "
            f"'{tgt.mount}': expected camera on the flange and target on the base (eye-in-hand) or camera "
            "on the base and target on the flange (eye-to-hand)"
        )
    return cam, tgt


def is_hand_eye_cell(cell: CellSpec) -> bool:
    """Whether :func:`calibrate_hand_eye` handles ``cell`` (one camera and one target, one on the
    flange and the other on the base, no tools or points)."""
    if cell.tools or cell.points:
        return False
    try:
        _select(cell)
    except BadInputError:
        return False
    return True


def _gather(cell: CellSpec, obs: Observations) -> _Data:
    cam, tgt = _select(cell)
    if tgt.name not in obs.targets:
        raise BadInputError(f"{obs.source}: the observations have no target '{tgt.name}'")
    if cam.name not in obs.cameras:
        raise BadInputError(f"{obs.source}: camera '{cam.name}' of the cell has no image size in the observations")
    points = obs.targets[tgt.name]
    if not np.allclose(points[:, 2], 0.0):
        raise BadInputError(
            f"{obs.source}: target '{tgt.name}' is not planar (z != 0); hand-eye calibration needs a planar target"
        )
    cd = _CameraData(cam.name, cam.model, obs.cameras[cam.name], cam.skew, cam.fix, cam.K, cam.dist, [], [], [], [])
    ids, poses = [], []
    for station in obs.stations:
        dets = [d for d in station.detections if d.camera == cam.name and d.target == tgt.name]
        if not dets:
            continue
        if station.T_base_flange is None:
            raise BadInputError(
                f"{obs.source}: station '{station.id}' has no T_base_flange; a hand-eye cell needs the robot "
                "flange pose of every station"
            )
        det = dets[0]
        n = det.point_index.size
        if n < MIN_POINTS_PER_VIEW:
            raise BadInputError(
                f"{obs.source}: station '{station.id}', camera '{cam.name}': only {n} target points; a view "
                f"needs at least {MIN_POINTS_PER_VIEW}. Drop the view or re-detect it"
            )
        cd.stations.append(len(ids))
        cd.point_index.append(det.point_index)
        cd.points.append(points[det.point_index])
        cd.pixels.append(det.pixels)
        ids.append(station.id)
        poses.append(np.asarray(station.T_base_flange, np.float64))
    if len(ids) < 3:
        hand_eye = f"T_{cam.mount}_{cam.name}"
        raise NotObservableError(
            f"camera '{cam.name}' sees target '{tgt.name}' in {len(ids)} station(s); hand-eye calibration "
            "needs at least 3 stations rotating about two different axes",
            [f"rotation of {hand_eye}", f"translation of {hand_eye}"],
        )
    return _Data(cam, tgt.name, cam.mount, cd, ids, np.stack(poses))


def _pose_sqrt_info(cell: CellSpec) -> np.ndarray:
    """(6, 6) square-root information of one flange-pose correction (rx..tz; 1/rad, 1/m)."""
    rot = np.radians(np.asarray(cell.robot.pose_noise_rotation_deg, np.float64))
    trans = np.asarray(cell.robot.pose_noise_translation_m, np.float64)
    return np.diag(1.0 / np.concatenate([rot, trans]))


def _known_pose(cell: CellSpec, spec, transform_name: str) -> tuple[np.ndarray | None, bool]:
    """A camera's / target's known pose from the cell (start value) and whether it is held fixed
    (its id or the transform name listed in the cell's ``fixed``)."""
    fixed = spec.name in cell.fixed or transform_name in cell.fixed
    if fixed and spec.pose is None:
        raise BadInputError(
            f"{cell.source}: fixed lists '{spec.name}' ({transform_name}) but the cell gives it no pose; "
            "add pose: [[4x4]] (m) or remove it from fixed"
        )
    return (None if spec.pose is None else np.asarray(spec.pose, np.float64)), fixed


# ------------------------------------------------------------------------------------ solve


def calibrate_hand_eye(
    cell: CellSpec, obs: Observations, options: HandEyeOptions = HandEyeOptions()
) -> HandEyeCalibration:
    """Calibrate a hand-eye cell jointly: intrinsics, hand-eye, target pose (and robot pose errors).

    Args:
        cell: a cell with one camera and one target, one mounted on the flange and the other on
            the base; ``robot.pose_noise`` switches the robot pose error model on.
        obs: target detections with ``T_base_flange`` per station (m, px).
        options: :class:`HandEyeOptions`.

    Returns:
        :class:`HandEyeCalibration`. Covariances are sampling noise (pixel noise and, with the pose
        model, robot noise as stated, propagated to first order, scaled by σ̂² by default), not model
        error (wrong lens model, unmodelled robot error beyond the stated prior).

    Raises:
        BadInputError: malformed input (cell layout, missing poses, too few points in a view).
        NotObservableError: degenerate robot motion (fewer than 3 stations, pure translation,
            rotations about one axis only; names e.g. the translation along the axis) or a
            rank-deficient joint problem, naming the unknowns.
    """
    d = _gather(cell, obs)
    cd, cam_name, mount = d.cd, d.camera.name, d.mount
    use_pose_model = options.pose_model
    has_noise = cell.robot is not None and cell.robot.pose_noise_translation_m is not None
    if use_pose_model is None:
        use_pose_model = has_noise
    if use_pose_model and not has_noise:
        raise BadInputError(
            f"options.pose_model: got True, but {cell.source} has no robot.pose_noise; state the robot's "
            "pose accuracy (translation_m, rotation_deg) in the cell"
        )
    hand_eye_name = f"T_{mount}_{cam_name}"
    other_frame = "base" if mount == "flange" else "flange"
    target_name = f"T_{other_frame}_{d.target_name}"

    # --- start: intrinsics and per-view poses, motion check, closed-form hand-eye
    model, poses = _initial_model(cd)
    fixed_mask = _intrinsics_fixed_mask(model, cd.fix)
    ratio = float(cd.K0[0, 0] / cd.K0[1, 1]) if cd.K0 is not None else 1.0
    aspect_flag = 1.0 if "aspect" in cd.fix else 0.0
    if aspect_flag:
        p = np.asarray(model.params).copy()
        p[1] = p[0] / ratio
        model = model.with_params(jnp.asarray(p))
    rot_noise = 0.02
    if has_noise:
        rot_noise = max(rot_noise, float(np.max(cell.robot.pose_noise_rotation_deg)))
    motion = analyse_motion(d.T_base_flange, frame=mount, rotation_noise_deg=rot_noise)
    check_observable(motion, hand_eye_name)
    T_ct = np.stack([poses[i] for i in range(len(d.station_ids))])
    init = solve_hand_eye(d.T_base_flange, T_ct, method=options.method, mount=mount, rotation_noise_deg=rot_noise)

    # --- problem
    n_st = len(d.station_ids)
    intr_name = f"intrinsics:{cam_name}"
    meas = np.stack([_se3_params(T) for T in d.T_base_flange])
    if use_pose_model:
        flange = Variable("T_base_flange", SE3(), meas, prior_mean=meas, prior_sqrt_info=_pose_sqrt_info(cell),
                          eliminate=True, entry_label="station {i} flange pose")
    else:
        flange = Variable("T_base_flange", SE3(), meas, fixed=True, eliminate=True,
                          entry_label="station {i} flange pose")
    he_pose, he_fixed = _known_pose(cell, d.camera, hand_eye_name)
    tg_pose, tg_fixed = _known_pose(cell, cell.targets[d.target_name], target_name)
    variables = [
        Variable(intr_name, Euclidean(len(model.param_names)), np.asarray(model.params, np.float64)[None, :],
                 fixed=fixed_mask[None, :], coord_names=list(model.param_names), entry_label=cam_name),
        Variable(hand_eye_name, SE3(), _se3_params(init.T if he_pose is None else he_pose), fixed=he_fixed),
        Variable(target_name, SE3(), _se3_params(init.T_other if tg_pose is None else tg_pose), fixed=tg_fixed),
        flange,
    ]
    station_flat = np.repeat(np.asarray(cd.stations, np.int32), [p.shape[0] for p in cd.points])
    points_flat = np.concatenate(cd.points)
    pixels_flat = np.concatenate(cd.pixels)
    K = station_flat.shape[0]
    aspect = np.broadcast_to(np.array([aspect_flag, ratio]), (K, 2))
    fn = _handeye_reprojection_fn(type(model), tuple(int(s) for s in model.image_size), bool(model.has_skew), mount)
    zeros = np.zeros(K, np.int32)
    factor = FactorGroup(f"reprojection:{cam_name}", fn, (intr_name, hand_eye_name, target_name, "T_base_flange"),
                         (zeros, zeros, zeros, station_flat), (points_flat, pixels_flat, aspect),
                         sigma=options.sigma_px)
    problem = Problem(variables, [factor])
    sol = solve(problem, options=SolveOptions(max_iterations=options.max_iterations))

    # --- outputs
    scale_noise = options.noise
    vals = {k: np.asarray(v) for k, v in sol.values.items()}
    res = np.asarray(_residuals_jit(fn)(
        jnp.broadcast_to(sol.values[intr_name], (K, vals[intr_name].shape[1])),
        jnp.broadcast_to(sol.values[hand_eye_name], (K, 7)),
        jnp.broadcast_to(sol.values[target_name], (K, 7)),
        sol.values["T_base_flange"][station_flat],
        (jnp.asarray(points_flat), jnp.asarray(pixels_flat), jnp.asarray(aspect)),
    ))
    if scale_noise == "a_posteriori" and not sol.sigma2 == sol.sigma2:
        raise NotObservableError(
            f"The a-posteriori noise level needs more residuals ({sol.num_residuals}) than free unknowns "
            f"({sol.num_free}); use noise='stated'.",
            ["sigma2"],
        )
    prm = vals[intr_name][0].copy()
    cov_i = np.asarray(_covariance(sol, intr_name, noise=scale_noise))
    if aspect_flag:
        prm[1] = prm[0] / ratio
        cov_i[1, :] = cov_i[0, :] / ratio
        cov_i[:, 1] = cov_i[:, 0] / ratio
        cov_i[1, 1] = cov_i[0, 0] / ratio**2
    model = model.with_params(jnp.asarray(prm))
    T_he = _se3_matrix(vals[hand_eye_name][0])
    T_tg = _se3_matrix(vals[target_name][0])
    cov_he = np.asarray(_covariance(sol, hand_eye_name, noise=scale_noise))
    cov_tg = np.asarray(_covariance(sol, target_name, noise=scale_noise))
    if use_pose_model:
        T_bf = np.stack([_se3_matrix(v) for v in vals["T_base_flange"]])
    else:
        T_bf = d.T_base_flange.copy()  # held fixed: the measured poses, without a quaternion round trip

    robot = {}
    if use_pose_model:
        robot = _robot_stats(sol, cell, meas, vals["T_base_flange"])

    sq = np.sum(res**2, axis=1)
    total = np.zeros(n_st)
    count = np.zeros(n_st)
    np.add.at(total, station_flat, sq)
    np.add.at(count, station_flat, 1.0)
    view_rms = {sid: float(np.sqrt(total[i] / max(count[i], 1.0))) for i, sid in enumerate(d.station_ids)}
    return HandEyeCalibration(
        mount=mount,
        camera=cam_name,
        target=d.target_name,
        model=model,
        intrinsics_covariance=cov_i,
        hand_eye_name=hand_eye_name,
        T_hand_eye=T_he,
        T_hand_eye_covariance=cov_he,
        target_name=target_name,
        T_target=T_tg,
        T_target_covariance=cov_tg,
        station_ids=list(d.station_ids),
        T_base_flange_measured=d.T_base_flange,
        T_base_flange=T_bf,
        robot=robot,
        init=init,
        view_rms_px=view_rms,
        rms_px=float(np.sqrt(np.mean(sq))),
        sigma_px=float(np.sqrt(sol.sigma2)) * options.sigma_px,
        num_residuals=int(res.size),
        iterations=sol.iterations,
        status=sol.status.name.lower(),
        sigma2=float(sol.sigma2),
        pose_model=bool(use_pose_model),
        solution=sol,
    )


def _robot_stats(sol, cell: CellSpec, meas: np.ndarray, est: np.ndarray) -> dict:
    """Robot accuracy from the estimated per-station corrections (see :class:`HandEyeCalibration`)."""
    S = _pose_sqrt_info(cell)
    delta = np.asarray(lie.local(jnp.asarray(meas), jnp.asarray(est)))  # (N, 6) rx..tz, flange frame
    n = delta.shape[0]
    # Redundancy of the prior residuals r_i = S δ_i: 6 - tr(S Σ_i Sᵀ) per station, Σ_i the
    # (stated-noise) posterior covariance of station i's pose.
    redundancy = 0.0
    for i in range(n):
        C = np.asarray(_covariance(sol, "T_base_flange", index=i, noise="stated"))
        redundancy += 6.0 - float(np.trace(S @ C @ S.T))
    chi2 = float(np.sum((delta @ S.T) ** 2))
    factor = np.sqrt(chi2 / redundancy) if redundancy > 1e-9 else float("nan")
    prior_t = np.asarray(cell.robot.pose_noise_translation_m, np.float64)
    prior_r = np.asarray(cell.robot.pose_noise_rotation_deg, np.float64)
    rms = np.sqrt(np.mean(delta**2, axis=0))
    return {
        "prior_sigma_translation_m": prior_t.tolist(),
        "prior_sigma_rotation_deg": prior_r.tolist(),
        "correction_rms_translation_m": rms[3:].tolist(),
        "correction_rms_rotation_deg": np.degrees(rms[:3]).tolist(),
        "a_posteriori_sigma_translation_m": (factor * prior_t).tolist(),
        "a_posteriori_sigma_rotation_deg": (factor * prior_r).tolist(),
        "redundancy": redundancy,
    }
