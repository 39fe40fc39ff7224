"""Joint hand-eye calibration: cameras on the robot (or fixed), one target fixed (or on the robot).

Eye-in-hand (cameras ``mount: flange``, target ``mount: base``): unknowns ``T_flange_<cam>`` and
the intrinsics of every camera and one shared ``T_base_target``; corner ``p`` of station ``i`` is
seen by camera ``c`` at

    project(K_c, inv(T_flange_c) · inv(T_base_flange_i) · T_base_target · p).

Eye-to-hand (cameras ``mount: base``, target ``mount: flange``): unknowns ``T_base_<cam>``,
``T_flange_target``; ``p_cam = inv(T_base_cam) · T_base_flange_i · T_flange_target · p``. Several
cameras share the stations (and the robot poses) and the one target pose.

Robot pose error model: with ``robot: {pose_noise: {translation_m, rotation_deg}}`` in the cell, the
true flange pose of every station is an unknown ``T_base_flange_i = T_meas_i · Exp(δ_i)`` (right
perturbation: ``δ_i`` in the flange frame, ``(rx, ry, rz, tx, ty, tz)``) with a zero-mean Gaussian
prior of those per-axis σ (square-root information ``diag(1/σ)``). These per-station poses are the
eliminated variable (Schur complement), so the shared system stays small (intrinsics + poses).
Without ``pose_noise`` (or with ``HandEyeOptions(pose_model=False)``) the measured poses are taken
as exact (the same variable, fully fixed). On simulated data the estimate with the pose model is
efficient: its median error equals the one its own covariance predicts (the Cramér–Rao bound);
see ``benchmarks/bench_handeye.py``.

Start: Zhang on all views (or the cell's intrinsics), per-view planar pose, motion observability
check (:func:`jcalib.init.handeye.check_observable`) on the first camera whose motion passes it,
then a closed-form hand-eye solve (Park–Martin by default) for that camera; the other cameras start
from the target pose it implies. jcalib's engine refines everything jointly and gives the
covariance. Robust losses (Huber, Cauchy) and outlier rejection act on the corner reprojections.

Degenerate motion raises :class:`NotObservableError` naming the undetermined unknowns. When every
rotation is about one axis (e.g. a SCARA, all rotations about the base z), everything but the
translation of the hand-eye transform along that axis is still determined:
``HandEyeOptions(fix_unobservable=True)`` holds that one component at a stated prior and says so
in the warnings.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import lie
from jcalib.geometry.cameras import AbstractCameraModel
from jcalib.init.handeye import (
    HAND_EYE_METHODS,
    HandEyeInit,
    MotionDiagnostics,
    _fmt_axis,
    _rotvec,
    analyse_motion,
    average_poses,
    check_observable,
    relative_motions,
    solution_diagnostics,
    solve_hand_eye,
)
from jcalib.io.cell import CellSpec
from jcalib.io.observations import Observations
from jcalib.problems.camera import (
    MIN_POINTS_PER_VIEW,
    _CameraData,
    _chain_reprojection_jacobian,
    _initial_model,
    _intrinsics_fixed_mask,
    _reprojection_fn,
    _se3_matrix,
    _se3_params,
)
from jcalib.residuals.losses import CauchyLoss, HuberLoss, TrivialLoss
from jcalib.solve import (
    SE3,
    Euclidean,
    FactorGroup,
    Problem,
    RawSolution,
    Solution,
    SolveOptions,
    Status,
    Variable,
    batch_width,
    bucket_size,
    linear,
    lm_solve,
    pad_problem,
    solve,
)
from jcalib.solve.covariance import covariance as _covariance
from jcalib.solve.lm import _check_finite_input, unobservable_names

#: Rounds of outlier rejection (each re-solves from the previous estimate) before giving up.
MAX_OUTLIER_ROUNDS = 5


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
        loss: robust loss on each corner's whitened reprojection error: ``"none"``, ``"huber"`` or
            ``"cauchy"``.
        loss_scale: the loss scale in units of ``sigma_px``.
        outlier_threshold: corners whose reprojection error exceeds this many σ (a-posteriori σ by
            default, ``sigma_px`` with ``noise="stated"``) are rejected and the problem re-solved,
            up to :data:`MAX_OUTLIER_ROUNDS` times; ``None`` keeps every corner.
        fix_unobservable: when all rotations are about one axis (one-axis or planar SCARA-like
            motion), hold the translation of the hand-eye transform along that axis at
            ``unobservable_prior_m`` instead of raising :class:`NotObservableError`; the result's
            warnings say so. Other degeneracies (fewer than 3 stations, no usable rotation) still raise.
            With several cameras the prior goes on the first camera's transform (the others follow
            through the shared target pose).
        unobservable_prior_m: that component (m): ``a · t`` with ``a`` the reported unit axis in the
            flange frame (eye-in-hand, ``t`` the translation of ``T_flange_cam``) or the base frame
            (eye-to-hand, of ``T_base_cam``).
        unobservable_prior_sigma_m: σ of that prior (m); the default holds it to 1 µm, a larger σ
            (what you know about the mounting) enters the reported covariance.
    """

    method: str = "park_martin"
    sigma_px: float = 0.25
    noise: str = "a_posteriori"
    pose_model: bool | None = None
    max_iterations: int = 100
    loss: str = "none"
    loss_scale: float = 3.0
    outlier_threshold: float | None = 5.0
    fix_unobservable: bool = False
    unobservable_prior_m: float = 0.0
    unobservable_prior_sigma_m: float = 1e-6

    @classmethod
    def from_camera_options(cls, options, **overrides) -> HandEyeOptions:
        """The hand-eye options carrying over what applies from a
        :class:`~jcalib.problems.camera.CameraCalibrationOptions` (``sigma_px``, ``noise``,
        ``max_iterations``, ``loss``, ``loss_scale``, ``outlier_threshold``), then ``overrides``
        (e.g. ``pose_model=False``, ``fix_unobservable=True``). For the CLI, which parses one set
        of options for every cell."""
        keep = ("sigma_px", "noise", "max_iterations", "loss", "loss_scale", "outlier_threshold")
        return cls(**{k: getattr(options, k) for k in keep}, **overrides)

    def __post_init__(self):
        if self.method not in HAND_EYE_METHODS:
            raise BadInputError(f"method: got {self.method!r}, expected one of {sorted(HAND_EYE_METHODS)}")
        if self.noise not in ("a_posteriori", "stated"):
            raise BadInputError(f"noise: got {self.noise!r}, expected 'a_posteriori' or 'stated'")
        if not self.sigma_px > 0:
            raise BadInputError(f"sigma_px: got {self.sigma_px!r}, expected a positive number of pixels")
        if self.pose_model not in (None, True, False):
            raise BadInputError(f"pose_model: got {self.pose_model!r}, expected None, True or False")
        if self.loss not in ("none", "huber", "cauchy"):
            raise BadInputError(f"loss: got {self.loss!r}, expected 'none', 'huber' or 'cauchy'")
        if not self.loss_scale > 0:
            raise BadInputError(f"loss_scale: got {self.loss_scale!r}, expected a positive number of σ")
        if self.outlier_threshold is not None and not self.outlier_threshold > 0:
            raise BadInputError(
                f"outlier_threshold: got {self.outlier_threshold!r}, expected a positive number of σ or None"
            )
        if not np.isfinite(self.unobservable_prior_m):
            raise BadInputError(f"unobservable_prior_m: got {self.unobservable_prior_m!r}, expected a finite value (m)")
        if not self.unobservable_prior_sigma_m > 0:
            raise BadInputError(
                f"unobservable_prior_sigma_m: got {self.unobservable_prior_sigma_m!r}, expected a positive σ (m)"
            )


@dataclass
class HandEyeCamera:
    """One camera's part of a :class:`HandEyeCalibration`.

    Attributes:
        camera: camera id.
        model: the calibrated camera model.
        intrinsics_covariance: ``(p, p)`` covariance of ``model.params`` (order ``param_names``).
        hand_eye_name: ``"T_flange_<camera>"`` or ``"T_base_<camera>"``.
        T_hand_eye: (4, 4) that transform, m.
        T_hand_eye_covariance: (6, 6) right-perturbation covariance (rx..tz; rad², m²).
        station_ids: the stations where this camera sees the target.
        view_rms_px: station id -> RMS reprojection error of the inlier corners (pixels).
        rms_px: RMS over this camera's inlier corners (pixels).
        num_residuals: residual components of this camera's inlier corners.
        init: the closed-form (or derived) start (:class:`jcalib.init.handeye.HandEyeInit`).
        motion: the motion analysis of this camera's stations.
    """

    camera: str
    model: AbstractCameraModel
    intrinsics_covariance: np.ndarray
    hand_eye_name: str
    T_hand_eye: np.ndarray
    T_hand_eye_covariance: np.ndarray
    station_ids: list[str]
    view_rms_px: dict[str, float]
    rms_px: float
    num_residuals: int
    init: HandEyeInit
    motion: MotionDiagnostics


@dataclass
class HandEyeCalibration:
    """The outcome of :func:`calibrate_hand_eye` (see :class:`jcalib.Result` for the file form).

    The single-camera fields (``camera`` ... ``init``, ``view_rms_px``) describe the first camera of
    the cell; ``cameras`` holds every camera.

    Attributes:
        mount: ``"flange"`` (eye-in-hand) or ``"base"`` (eye-to-hand): where the cameras are.
        camera, target: ids from the cell (first camera).
        model: the calibrated camera model (first camera).
        intrinsics_covariance: ``(p, p)`` covariance of ``model.params`` (order ``param_names``).
        hand_eye_name: ``"T_flange_<camera>"`` or ``"T_base_<camera>"``.
        T_hand_eye: (4, 4) that transform, m.
        T_hand_eye_covariance: (6, 6) right-perturbation covariance (rx..tz; rad², m²).
        target_name: ``"T_base_<target>"`` or ``"T_flange_<target>"``.
        T_target: (4, 4) that transform, m.
        T_target_covariance: (6, 6), as above.
        station_ids: ids of the stations used (where some camera sees the target).
        T_base_flange_measured: (N, 4, 4) measured flange poses of those stations, m.
        T_base_flange: (N, 4, 4) estimated true flange poses (equal to the measured ones without the
            pose model), m.
        robot: robot-accuracy statistics (empty without the pose model): ``prior_sigma_*`` (the
            stated σ), ``correction_rms_*`` (RMS of the estimated corrections δ per axis),
            ``a_posteriori_sigma_*`` (variance-component estimate of the robot's σ per axis:
            the prior σ scaled by sqrt(Σ‖Sδ‖² / redundancy of the prior residuals)),
            ``redundancy`` of the prior residuals. Units: ``_m`` metres, ``_deg`` degrees;
            axes in the flange frame.
        init: the closed-form start of the first camera.
        view_rms_px: station id -> RMS reprojection error of the first camera (pixels).
        rms_px, sigma_px: overall RMS (inlier corners, all cameras) and a-posteriori corner noise σ
            (pixels).
        num_residuals, iterations, status, sigma2: solver facts (``sigma2`` the variance factor).
        pose_model: whether the robot pose model was on.
        cameras: camera id -> :class:`HandEyeCamera`, every camera of the cell.
        outliers: (camera id, station id, point index) of rejected corners.
        unobservable_fixed: ``{"transform", "axis", "frame", "value_m", "sigma_m"}`` when
            ``fix_unobservable`` held a translation component at its prior, else ``None``.
        warnings: remarks on weak motion and on what was held at a prior.
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
    cameras: dict[str, HandEyeCamera] = field(default_factory=dict)
    outliers: list[tuple[str, str, int]] = field(default_factory=list)
    unobservable_fixed: dict | None = None
    warnings: list[str] = field(default_factory=list)
    solution: object = field(default=None, repr=False)


# ------------------------------------------------------------------------------------ residuals


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


def _handeye_reprojection_jacobian(model_cls: type, image_size: tuple[int, int], skew: bool, camera_mount: str):
    """Hand-derived linearisation of :func:`_handeye_reprojection_fn` (``FactorGroup.jacobian``):
    ``p_cam = T_flange_cam⁻¹ · T_base_flange⁻¹ · T_base_target · p`` (flange camera) or
    ``T_base_cam⁻¹ · T_base_flange · T_flange_target · p`` (fixed camera); see
    :func:`jcalib.problems.camera._chain_reprojection_jacobian`."""
    if camera_mount == "flange":  # args (intrinsics, X = T_flange_cam, Y = T_base_target, F = T_base_flange)
        chain = ((0, True), (2, True), (1, False))
    else:  # args (intrinsics, C = T_base_cam, T = T_flange_target, F = T_base_flange)
        chain = ((0, True), (2, False), (1, False))
    return _chain_reprojection_jacobian(model_cls, image_size, skew, chain)


def _axis_translation_prior(T_hand_eye, obs):
    """``(T (7,) wxyz_xyz, (axis (3,), value (1,))) -> (1,)``: ``axis · t - value`` (m), the translation
    of the hand-eye transform along the unobservable axis against its stated value."""
    axis, value = obs
    return jnp.matmul(axis, T_hand_eye[4:7])[None] - value


@functools.cache
def _residuals_jit(fn):
    return jax.jit(jax.vmap(fn))


def _loss(options: HandEyeOptions):
    if options.loss == "huber":
        return HuberLoss(options.loss_scale)
    if options.loss == "cauchy":
        return CauchyLoss(options.loss_scale)
    return TrivialLoss()


# ------------------------------------------------------------------------------------ data


@dataclass
class _Data:
    cameras: list  # CameraSpec, cell order
    cds: list[_CameraData]  # one per camera; cd.stations index the used stations
    target_name: str
    mount: str  # the cameras' mount
    station_ids: list[str]
    T_base_flange: np.ndarray  # (N, 4, 4) measured, for the used stations


def _select(cell: CellSpec) -> tuple[list, object]:
    """The cameras (one mount) and the target of a hand-eye cell, or BadInputError."""
    cams = list(cell.cameras.values())
    tgts = list(cell.targets.values())
    if not cams or len(tgts) != 1:
        raise BadInputError(
            f"{cell.source}: hand-eye calibration takes cameras and one target, the cell has cameras "
            f"{[c.name for c in cams]} and targets {[t.name for t in tgts]}"
        )
    tgt = tgts[0]
    mounts = sorted({c.mount for c in cams})
    pairs = {("flange", "base"), ("base", "flange")}
    if len(mounts) != 1 or (mounts[0], tgt.mount) not in pairs:
        raise BadInputError(
            f"{cell.source}: cameras {[(c.name, c.mount) for c in cams]} (name, mount) with target "
            f"'{tgt.name}' mount '{tgt.mount}': expected every camera on the flange and the target on the "
            "base (eye-in-hand) or every camera on the base and the target on the flange (eye-to-hand)"
        )
    return cams, tgt


def is_hand_eye_cell(cell: CellSpec) -> bool:
    """Whether :func:`calibrate_hand_eye` handles ``cell``: cameras all on the flange and one target
    on the base, or cameras all on the base and one target on the flange; no tools or points."""
    if cell.tools or cell.points:
        return False
    try:
        _select(cell)
    except BadInputError:
        return False
    return True


def _gather(cell: CellSpec, obs: Observations) -> _Data:
    cams, tgt = _select(cell)
    if tgt.name not in obs.targets:
        raise BadInputError(f"{obs.source}: the observations have no target '{tgt.name}'")
    for cam in cams:
        if cam.name not in obs.cameras:
            raise BadInputError(f"{obs.source}: camera '{cam.name}' of the cell has no image size in the observations")
    points = obs.targets[tgt.name]
    if not np.allclose(points[:, 2], 0.0):
        raise BadInputError(
            f"{obs.source}: target '{tgt.name}' is not planar (z != 0); hand-eye calibration needs a planar target"
        )
    cds = [_CameraData(c.name, c.model, obs.cameras[c.name], c.skew, c.fix, c.K, c.dist, [], [], [], [])
           for c in cams]
    by_name = {c.name: k for k, c in enumerate(cams)}
    ids, poses = [], []
    for station in obs.stations:
        dets = {}
        for det in station.detections:
            if det.target == tgt.name and det.camera in by_name and det.camera not in dets:
                dets[det.camera] = det
        if not dets:
            continue
        if station.T_base_flange is None:
            raise BadInputError(
                f"{obs.source}: station '{station.id}' has no T_base_flange; a hand-eye cell needs the robot "
                "flange pose of every station"
            )
        for name, det in dets.items():
            n = det.point_index.size
            if n < MIN_POINTS_PER_VIEW:
                raise BadInputError(
                    f"{obs.source}: station '{station.id}', camera '{name}': only {n} target points; a view "
                    f"needs at least {MIN_POINTS_PER_VIEW}. Drop the view or re-detect it"
                )
            cd = cds[by_name[name]]
            cd.stations.append(len(ids))
            cd.point_index.append(det.point_index)
            cd.points.append(points[det.point_index])
            cd.pixels.append(det.pixels)
        ids.append(station.id)
        poses.append(np.asarray(station.T_base_flange, np.float64))
    for cam, cd in zip(cams, cds):
        if len(cd.stations) < 3:
            hand_eye = f"T_{cam.mount}_{cam.name}"
            unknowns = [f"rotation of {hand_eye}", f"translation of {hand_eye}"]
            raise NotObservableError(
                f"camera '{cam.name}' sees target '{tgt.name}' in {len(cd.stations)} station(s); hand-eye "
                "calibration needs at least 3 stations rotating about two different axes. Undetermined: "
                + "; ".join(unknowns) + ".",
                unknowns,
            )
    return _Data(cams, cds, tgt.name, cams[0].mount, ids, np.stack(poses))


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


# ------------------------------------------------------------------------------------ start


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _rotation_between(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``b`` to unit vector ``a`` (3, 3)."""
    v = np.cross(b, a)
    c = float(b @ a)
    if c < -1.0 + 1e-12:  # opposite: half a turn about any axis perpendicular to b
        p = np.cross(b, np.eye(3)[int(np.argmin(np.abs(b)))])
        p /= np.linalg.norm(p)
        return 2.0 * np.outer(p, p) - np.eye(3)
    V = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + V + V @ V / (1.0 + c)


def _one_axis_init(T_bf, T_ct, mount: str, motion: MotionDiagnostics, along_m: float) -> HandEyeInit:
    """Closed-form start when every rotation is about one axis ``a`` (``motion.dominant_axis``).

    ``A X = X B`` then fixes the rotation of ``X`` up to an angle ``φ`` about ``a`` (the axis of
    ``B`` maps to ``a``), and the translation equations ``(R_A − I) t = R_X t_B − t_A`` are linear in
    ``(cos φ, sin φ)`` and the two components of ``t`` across ``a``; the component along ``a`` is
    in the null space of every ``R_A − I`` and is set to ``along_m``.
    """
    Hg = T_bf if mount == "flange" else np.linalg.inv(T_bf)
    A, B, _ = relative_motions(Hg, T_ct)
    rA, rB = _rotvec(A[:, :3, :3]), _rotvec(B[:, :3, :3])
    a = np.asarray(motion.dominant_axis, np.float64)
    a = a / np.linalg.norm(a)
    _, _, vt = np.linalg.svd(rB, full_matrices=False)
    b = vt[0] if np.sum(rB @ vt[0]) * np.sum(rA @ a) >= 0.0 else -vt[0]
    R0 = _rotation_between(b, a)
    P = np.linalg.svd(np.eye(3) - np.outer(a, a))[0][:, :2]  # (3, 2) basis across the axis
    u = B[:, :3, 3] @ R0.T  # R0 t_B
    au = u @ a
    RmI = A[:, :3, :3] - np.eye(3)
    M = np.concatenate([RmI @ P, -(u - au[:, None] * a)[..., None], -np.cross(a, u)[..., None]], axis=-1)
    rhs = -A[:, :3, 3] + au[:, None] * a - along_m * (RmI @ a)
    z = np.linalg.lstsq(M.reshape(-1, 4), rhs.reshape(-1), rcond=None)[0]
    phi = float(np.arctan2(z[3], z[2]))
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    R_X = (np.eye(3) + np.sin(phi) * K + (1.0 - np.cos(phi)) * K @ K) @ R0
    rhs = B[:, :3, 3] @ R_X.T - A[:, :3, 3] - along_m * (RmI @ a)  # re-solve t for the rounded rotation
    w = np.linalg.lstsq((RmI @ P).reshape(-1, 2), rhs.reshape(-1), rcond=None)[0]
    X = _pose(R_X, P @ w + along_m * a)
    per_station = Hg @ X @ T_ct
    Y = average_poses(per_station)
    diagnostics = solution_diagnostics(motion, per_station, Y, A @ X, X @ B)
    return HandEyeInit(T=X, T_other=Y, method="one_axis", mount=mount, diagnostics=diagnostics)


def _init_from_target(T_bf, T_ct, Y, mount: str, motion: MotionDiagnostics) -> HandEyeInit:
    """Start of a further camera from the target pose ``Y`` of the first: ``X = Hg_i⁻¹ Y T_ct_i⁻¹``
    averaged over its stations (``Hg = T_base_flange`` eye-in-hand, its inverse eye-to-hand)."""
    Hg = T_bf if mount == "flange" else np.linalg.inv(T_bf)
    X = average_poses(np.linalg.inv(Hg) @ Y @ np.linalg.inv(T_ct))
    A, B, _ = relative_motions(Hg, T_ct)
    per_station = Hg @ X @ T_ct
    diagnostics = solution_diagnostics(motion, per_station, Y, A @ X, X @ B)
    return HandEyeInit(T=X, T_other=Y, method="from_target", mount=mount, diagnostics=diagnostics)


@dataclass
class _Start:
    model: AbstractCameraModel
    fixed_mask: np.ndarray
    ratio: float
    aspect_flag: float
    T_cam_target: np.ndarray  # (n_views, 4, 4)
    motion: MotionDiagnostics


def _camera_start(cd: _CameraData, T_bf: np.ndarray, mount: str, rot_noise: float) -> _Start:
    model, poses = _initial_model(cd)
    fixed_mask = _intrinsics_fixed_mask(model, cd.fix)
    ratio = float(cd.K0[0, 0] / cd.K0[1, 1]) if cd.K0 is not None else 1.0
    aspect_flag = 1.0 if "aspect" in cd.fix else 0.0
    if aspect_flag:
        p = np.asarray(model.params).copy()
        p[1] = p[0] / ratio
        model = model.with_params(jnp.asarray(p))
    T_ct = np.stack([poses[s] for s in cd.stations])
    motion = analyse_motion(T_bf[cd.stations], frame=mount, rotation_noise_deg=rot_noise)
    return _Start(model, fixed_mask, ratio, aspect_flag, T_ct, motion)


def _choose_reference(d: _Data, starts: list[_Start], options: HandEyeOptions):
    """The camera whose motion determines its hand-eye transform (its closed form starts the
    solve), or the first camera with one-axis motion under ``fix_unobservable``.

    Returns ``(index, None)`` or ``(0, (axis (3,), why))`` for the one-axis case; raises the first
    camera's :class:`NotObservableError` otherwise.
    """
    first_error = None
    for k, (cam, s) in enumerate(zip(d.cameras, starts)):
        try:
            check_observable(s.motion, f"T_{d.mount}_{cam.name}")
            return k, None
        except NotObservableError as err:
            first_error = first_error or err
    m = starts[0].motion
    if options.fix_unobservable and m.rank == 1 and m.num_stations >= 3:
        why = "planar (SCARA-like) motion, every rotation about the base z" if m.planar else "one-axis rotations"
        return 0, (np.asarray(m.dominant_axis, np.float64), why)
    raise first_error


# ------------------------------------------------------------------------------------ prepare / solve / finish
#
# calibrate_hand_eye = _prepare (host: gather, closed-form starts, the problem's variables and
# factors) → one solve → _refine (outlier rounds, a-posteriori checks, the robot's variance
# component) → an optional covariance re-solve → _finish (the result). calibrate_hand_eye_batch runs
# the same pieces with the main solves (and the covariance re-solves) of many data sets vmapped.


#: Options of the covariance re-solve (pose model, a-posteriori noise): no iteration, only the
#: Gauss–Newton system at the solution with the pixel σ re-weighted.
_COV_OPTIONS = SolveOptions(max_iterations=0)


@dataclass
class _Prepared:
    """One hand-eye data set, gathered, started (closed forms) and laid out as a problem (host side)."""

    cell: CellSpec
    options: HandEyeOptions
    d: _Data
    use_pose_model: bool
    target_name: str
    he_names: list[str]
    intr_names: list[str]
    starts: list[_Start]
    inits: list[HandEyeInit]
    meas: np.ndarray  # (N, 7) measured flange poses, wxyz_xyz (m)
    variables: list[Variable]
    fns: list
    jacobians: list  # per camera, the hand-derived linearisation of its fn (FactorGroup.jacobian)
    obs_arrays: list[tuple]  # per camera, padded layout: (points (P, 3), pixels (P, 2), aspect (P, 2))
    station_flat: list[np.ndarray]  # per camera (K_c,) station index of each corner
    station_runs: list[np.ndarray]  # per camera (P,) station index in the padded layout
    pad_index: list[np.ndarray]  # per camera (K_c,) position of each corner in the padded layout
    chunk: int  # corners per view in the padded layout
    extra_factors: list[FactorGroup]
    unobservable_fixed: dict | None
    warnings: list[str]
    solve_options: SolveOptions

    def build(self, weights: list[np.ndarray], sigma_px: float | None = None) -> Problem:
        """The problem with per-corner weights ``weights`` (one ``(K_c,)`` array per camera, 0 = rejected).

        Corners are laid out by view in runs of :attr:`chunk` (the target's point count rounded up to
        8; short views filled with zero-weight copies of their first corner), so the normal equations
        are summed per view with one matrix product (``FactorGroup.chunk``): several times faster
        under ``vmap`` than a scatter per corner."""
        sigma_px = self.options.sigma_px if sigma_px is None else sigma_px
        loss = _loss(self.options)
        factors = []
        for cam, fn, jac, intr_name, he_name, st, o, w, pi in zip(self.d.cameras, self.fns, self.jacobians,
                                                                  self.intr_names, self.he_names, self.station_runs,
                                                                  self.obs_arrays, weights, self.pad_index):
            w_pad = np.zeros(st.shape[0])
            w_pad[pi] = w
            factors.append(FactorGroup(
                f"reprojection:{cam.name}", fn, (intr_name, he_name, self.target_name, "T_base_flange"),
                (np.zeros_like(st), np.zeros_like(st), np.zeros_like(st), st), o,
                sigma=sigma_px, sqrt_weight=w_pad, loss=loss, chunk=self.chunk, jacobian=jac))
        return Problem(self.variables, factors + self.extra_factors)

    def residuals(self, sol) -> list[np.ndarray]:
        """Per camera ``(K_c, 2)`` reprojection errors (px, predicted − observed) at ``sol``."""
        out = []
        for fn, intr_name, he_name, st, o, pi in zip(self.fns, self.intr_names, self.he_names, self.station_runs,
                                                     self.obs_arrays, self.pad_index):
            n = st.shape[0]
            out.append(np.asarray(_residuals_jit(fn)(
                jnp.broadcast_to(sol.values[intr_name], (n, sol.values[intr_name].shape[1])),
                jnp.broadcast_to(sol.values[he_name], (n, 7)),
                jnp.broadcast_to(sol.values[self.target_name], (n, 7)),
                jnp.asarray(sol.values["T_base_flange"])[st],
                tuple(jnp.asarray(a) for a in o),
            ))[pi])
        return out

    def start_weights(self) -> list[np.ndarray]:
        return [np.ones(st.shape[0]) for st in self.station_flat]


def _prepare(cell: CellSpec, obs: Observations, options: HandEyeOptions) -> _Prepared:
    """Validate and gather one data set, start it (intrinsics, per-view poses, motion check, closed
    form) and lay out its variables and factors. Numpy and host only; raises the input errors."""
    d = _gather(cell, obs)
    mount = d.mount
    has_noise = cell.robot is not None and cell.robot.pose_noise_translation_m is not None
    use_pose_model = has_noise if options.pose_model is None else bool(options.pose_model)
    if use_pose_model and not has_noise:
        raise BadInputError(
            f"options.pose_model: got True, but {cell.source} has no robot.pose_noise; state the robot's "
            "pose accuracy (translation_m, rotation_deg) in the cell"
        )
    other_frame = "base" if mount == "flange" else "flange"
    target_name = f"T_{other_frame}_{d.target_name}"
    he_names = [f"T_{mount}_{cam.name}" for cam in d.cameras]
    intr_names = [f"intrinsics:{cam.name}" for cam in d.cameras]

    # --- start: intrinsics and per-view poses, motion check, closed-form hand-eye
    rot_noise = 0.02
    if has_noise:
        rot_noise = max(rot_noise, float(np.max(cell.robot.pose_noise_rotation_deg)))
    starts = [_camera_start(cd, d.T_base_flange, mount, rot_noise) for cd in d.cds]
    ref, one_axis = _choose_reference(d, starts, options)
    T_bf_ref = d.T_base_flange[d.cds[ref].stations]
    if one_axis is None:
        init_ref = solve_hand_eye(T_bf_ref, starts[ref].T_cam_target, method=options.method, mount=mount,
                                  rotation_noise_deg=rot_noise)
    else:
        init_ref = _one_axis_init(T_bf_ref, starts[ref].T_cam_target, mount, starts[ref].motion,
                                  options.unobservable_prior_m)
    inits = [
        init_ref if k == ref else
        _init_from_target(d.T_base_flange[cd.stations], s.T_cam_target, init_ref.T_other, mount, s.motion)
        for k, (cd, s) in enumerate(zip(d.cds, starts))
    ]

    # --- problem
    meas = np.stack([_se3_params(T) for T in d.T_base_flange])
    if use_pose_model:
        flange = Variable("T_base_flange", SE3(), meas, prior_mean=meas, prior_sqrt_info=_pose_sqrt_info(cell),
                          eliminate=True, entry_label="station {i} flange pose")
    else:
        flange = Variable("T_base_flange", SE3(), meas, fixed=True, eliminate=True,
                          entry_label="station {i} flange pose")
    tg_pose, tg_fixed = _known_pose(cell, cell.targets[d.target_name], target_name)
    variables = [
        Variable(target_name, SE3(), _se3_params(init_ref.T_other if tg_pose is None else tg_pose), fixed=tg_fixed),
        flange,
    ]
    fns, jacobians, obs_arrays, station_flat, station_runs, pad_index = [], [], [], [], [], []
    chunk = int(-(-obs.targets[d.target_name].shape[0] // 8) * 8)
    for cam, cd, s, init, intr_name, he_name in zip(d.cameras, d.cds, starts, inits, intr_names, he_names):
        he_pose, he_fixed = _known_pose(cell, cam, he_name)
        variables += [
            Variable(intr_name, Euclidean(len(s.model.param_names)), np.asarray(s.model.params, np.float64)[None, :],
                     fixed=s.fixed_mask[None, :], coord_names=list(s.model.param_names), entry_label=cam.name),
            Variable(he_name, SE3(), _se3_params(init.T if he_pose is None else he_pose), fixed=he_fixed),
        ]
        counts = np.array([pt.shape[0] for pt in cd.points])
        st = np.repeat(np.asarray(cd.stations, np.int32), counts)
        # padded layout: view v's corners at v * chunk + [0, n_v), then copies of its first corner
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        pi = np.repeat(np.arange(len(counts)) * chunk, counts) + np.arange(counts.sum()) - np.repeat(first, counts)
        fill = np.repeat(first, chunk)  # the first corner of each run's view
        points, pixels = np.concatenate(cd.points)[fill], np.concatenate(cd.pixels)[fill]
        points[pi], pixels[pi] = np.concatenate(cd.points), np.concatenate(cd.pixels)
        aspect = np.broadcast_to(np.array([s.aspect_flag, s.ratio]), (points.shape[0], 2))
        station_flat.append(st)
        station_runs.append(np.repeat(np.asarray(cd.stations, np.int32), chunk))
        pad_index.append(pi)
        obs_arrays.append((points, pixels, aspect))
        config = (type(s.model), tuple(int(v) for v in s.model.image_size), bool(s.model.has_skew), mount)
        fns.append(_handeye_reprojection_fn(*config))
        jacobians.append(_handeye_reprojection_jacobian(*config))
    extra_factors = []
    unobservable_fixed = None
    warnings = []
    for k, s in enumerate(starts):
        warnings += [f"camera '{d.cameras[k].name}': {w}" if len(starts) > 1 else w for w in s.motion.warnings]
    if one_axis is not None:
        axis, why = one_axis
        value, sigma = float(options.unobservable_prior_m), float(options.unobservable_prior_sigma_m)
        extra_factors.append(FactorGroup(
            f"prior:{he_names[ref]} along the rotation axis", _axis_translation_prior, (he_names[ref],),
            (np.zeros(1, np.int32),), (axis[None, :], np.array([[value]])), sigma=sigma))
        unobservable_fixed = {"transform": he_names[ref], "axis": axis.tolist(), "frame": mount,
                              "value_m": value, "sigma_m": sigma}
        warnings.append(
            f"{why}: the translation of {he_names[ref]} along the common rotation axis (axis = {_fmt_axis(axis)} "
            f"in the {mount} frame) is not observable from these stations; it is held at the stated prior "
            f"{value:g} m ± {sigma:g} m (fix_unobservable), and {target_name} shifts with it. Everything else "
            "is estimated from the data."
        )
    return _Prepared(
        cell=cell, options=options, d=d, use_pose_model=use_pose_model, target_name=target_name,
        he_names=he_names, intr_names=intr_names, starts=starts, inits=inits, meas=meas, variables=variables,
        fns=fns, jacobians=jacobians, obs_arrays=obs_arrays, station_flat=station_flat, station_runs=station_runs, pad_index=pad_index,
        chunk=chunk, extra_factors=extra_factors,
        unobservable_fixed=unobservable_fixed, warnings=warnings,
        solve_options=SolveOptions(max_iterations=options.max_iterations),
    )


@dataclass
class _Refined:
    """The state after the main solve and the outlier rounds (see :func:`_refine`)."""

    sol: Solution
    res: list[np.ndarray]  # per camera (K_c, 2) px at sol
    weights: list[np.ndarray]
    outliers: list[tuple[str, str, int]]
    robot: dict
    pixel_factor: float
    scale_noise: str
    cov_problem: Problem | None  # re-weighted problem at sol whose stated-noise covariance is reported


def _refine(p: _Prepared, sol: Solution, res: list[np.ndarray], weights: list[np.ndarray]) -> _Refined:
    """Outlier rounds (each re-solves from the previous estimate), the a-posteriori checks and, with
    the pose model, the variance components (pixel factor; the problem to take the covariance from)."""
    options, d = p.options, p.d
    outliers: list[tuple[str, str, int]] = []
    rounds = MAX_OUTLIER_ROUNDS if options.outlier_threshold is not None else 0
    for _ in range(rounds):
        sigma = options.sigma_px * (float(np.sqrt(sol.sigma2)) if options.noise == "a_posteriori" else 1.0)
        changed = False
        for k, (r, w, cd) in enumerate(zip(res, weights, d.cds)):
            bad = (np.linalg.norm(r, axis=1) > options.outlier_threshold * sigma) & (w > 0)
            if np.any(bad):
                changed = True
                weights[k] = np.where(bad, 0.0, w)
                index = np.concatenate(cd.point_index)
                outliers += [(d.cameras[k].name, d.station_ids[int(p.station_flat[k][j])], int(index[j]))
                             for j in np.flatnonzero(bad)]
        if not changed:
            break
        sol = solve(p.build(weights), x0=sol.values, options=p.solve_options)
        res = p.residuals(sol)
    if options.noise == "a_posteriori" and not sol.sigma2 == sol.sigma2:
        raise NotObservableError(
            f"The a-posteriori noise level needs more residuals ({sol.num_residuals}) than free unknowns "
            f"({sol.num_free}); use noise='stated'.",
            ["sigma2"],
        )

    # --- covariance scale. Without the pose model one a-posteriori factor σ̂² scales everything. With
    # it, the pixel noise and the robot prior are two variance components: σ̂² of all residuals
    # would rescale the robot prior with the pixels' factor (a mis-stated pixel σ would then shrink
    # or inflate the robot-driven directions). The pixels get their own factor (their χ² over their
    # redundancy) and the prior stays as stated; the covariance is the stated-noise one of the
    # problem re-weighted that way, at the solution.
    scale_noise = options.noise
    pixel_factor = float(sol.sigma2)
    robot: dict = {}
    cov_problem = None
    if p.use_pose_model:
        robot = _robot_stats(sol, p.cell, p.meas, np.asarray(sol.values["T_base_flange"]))
        if options.noise == "a_posteriori":
            chi2_px = float(sum(np.sum((r / options.sigma_px) ** 2 * (w > 0)[:, None]) for r, w in zip(res, weights)))
            redundancy_px = (sol.num_residuals - sol.num_free) - robot["redundancy"]
            if redundancy_px > 0.5 and chi2_px > 0.0:
                pixel_factor = chi2_px / redundancy_px
                cov_problem = p.build(weights, options.sigma_px * np.sqrt(pixel_factor)).with_values(sol.values)
                scale_noise = "stated"
    return _Refined(sol, res, weights, outliers, robot, pixel_factor, scale_noise, cov_problem)


def _finish(p: _Prepared, r: _Refined, cov_sol: Solution) -> HandEyeCalibration:
    """The :class:`HandEyeCalibration` of the refined solve; covariances from ``cov_sol``."""
    d, sol, res, weights = p.d, r.sol, r.res, r.weights
    scale_noise = r.scale_noise
    vals = {k: np.asarray(v) for k, v in sol.values.items()}
    cameras = {}
    all_sq = []
    for k, (cam, cd, s) in enumerate(zip(d.cameras, d.cds, p.starts)):
        prm = vals[p.intr_names[k]][0].copy()
        cov_i = np.asarray(_covariance(cov_sol, p.intr_names[k], noise=scale_noise))
        if s.aspect_flag:
            prm[1] = prm[0] / s.ratio
            cov_i[1, :] = cov_i[0, :] / s.ratio
            cov_i[:, 1] = cov_i[:, 0] / s.ratio
            cov_i[1, 1] = cov_i[0, 0] / s.ratio**2
        inlier = weights[k] > 0
        sq = np.sum(res[k] ** 2, axis=1)
        total = np.bincount(p.station_flat[k], weights=sq * inlier, minlength=len(d.station_ids))
        count = np.bincount(p.station_flat[k], weights=inlier.astype(np.float64), minlength=len(d.station_ids))
        all_sq.append(sq[inlier])
        cameras[cam.name] = HandEyeCamera(
            camera=cam.name,
            model=s.model.with_params(jnp.asarray(prm)),
            intrinsics_covariance=cov_i,
            hand_eye_name=p.he_names[k],
            T_hand_eye=_se3_matrix(vals[p.he_names[k]][0]),
            T_hand_eye_covariance=np.asarray(_covariance(cov_sol, p.he_names[k], noise=scale_noise)),
            station_ids=[d.station_ids[i] for i in cd.stations],
            view_rms_px={d.station_ids[i]: float(np.sqrt(total[i] / max(count[i], 1.0))) for i in cd.stations},
            rms_px=float(np.sqrt(np.mean(sq[inlier]))) if np.any(inlier) else float("nan"),
            num_residuals=2 * int(np.sum(inlier)),
            init=p.inits[k],
            motion=s.motion,
        )
    T_tg = _se3_matrix(vals[p.target_name][0])
    cov_tg = np.asarray(_covariance(cov_sol, p.target_name, noise=scale_noise))
    if p.use_pose_model:
        T_bf = np.stack([_se3_matrix(v) for v in vals["T_base_flange"]])
    else:
        T_bf = d.T_base_flange.copy()  # held fixed: the measured poses, without a quaternion round trip
    all_sq = np.concatenate(all_sq)
    first = cameras[d.cameras[0].name]
    return HandEyeCalibration(
        mount=d.mount,
        camera=first.camera,
        target=d.target_name,
        model=first.model,
        intrinsics_covariance=first.intrinsics_covariance,
        hand_eye_name=first.hand_eye_name,
        T_hand_eye=first.T_hand_eye,
        T_hand_eye_covariance=first.T_hand_eye_covariance,
        target_name=p.target_name,
        T_target=T_tg,
        T_target_covariance=cov_tg,
        station_ids=list(d.station_ids),
        T_base_flange_measured=d.T_base_flange,
        T_base_flange=T_bf,
        robot=r.robot,
        init=first.init,
        view_rms_px=first.view_rms_px,
        rms_px=float(np.sqrt(np.mean(all_sq))),
        sigma_px=float(np.sqrt(r.pixel_factor)) * p.options.sigma_px,
        num_residuals=2 * int(all_sq.size),
        iterations=sol.iterations,
        status=sol.status.name.lower(),
        sigma2=float(sol.sigma2),
        pose_model=bool(p.use_pose_model),
        cameras=cameras,
        outliers=r.outliers,
        unobservable_fixed=p.unobservable_fixed,
        warnings=p.warnings,
        solution=sol,
    )


def calibrate_hand_eye(
    cell: CellSpec, obs: Observations, options: HandEyeOptions = HandEyeOptions()
) -> HandEyeCalibration:
    """Calibrate a hand-eye cell jointly: intrinsics, hand-eye, target pose (and robot pose errors).

    Args:
        cell: a cell with one or more cameras all mounted on the flange and one target on the base
            (eye-in-hand), or cameras all on the base and one target on the flange (eye-to-hand);
            ``robot.pose_noise`` switches the robot pose error model on (``options.pose_model``
            overrides).
        obs: target detections with ``T_base_flange`` per station (m, px); cameras share stations.
        options: :class:`HandEyeOptions`.

    Returns:
        :class:`HandEyeCalibration`. Covariances are sampling noise (pixel noise and, with the pose
        model, robot noise as stated, propagated to first order, scaled by σ̂² by default), not model
        error (wrong lens model, unmodelled robot error beyond the stated prior). A component held
        by ``fix_unobservable`` has the prior's σ.

    Raises:
        BadInputError: malformed input (cell layout, missing poses, too few points in a view).
        NotObservableError: degenerate robot motion (fewer than 3 stations, pure translation,
            rotations too small for the noise, rotations about one axis only; names e.g. the
            translation along the axis) or a rank-deficient joint problem, naming the unknowns.
    """
    p = _prepare(cell, obs, options)
    weights = p.start_weights()
    sol = solve(p.build(weights), options=p.solve_options)
    r = _refine(p, sol, p.residuals(sol), weights)
    cov_sol = r.sol
    if r.cov_problem is not None:
        cov_sol = solve(r.cov_problem, options=_COV_OPTIONS, raise_on_unobservable=False)
    return _finish(p, r, cov_sol)


# ------------------------------------------------------------------------------------ batch

def _inverse_blocks(system: linear.System):
    """``(Σ_ss, V_i⁻¹)`` of an information system: what :mod:`jcalib.solve.covariance` caches."""
    S, Vinvs = linear.reduced_system(system, None, None)
    sigma_ss = jsl.cho_solve(jsl.cho_factor(S, lower=True), jnp.eye(S.shape[0], dtype=S.dtype))
    return sigma_ss, Vinvs


def _batch_core(problem: Problem, options: SolveOptions):
    """One data set's solve, its reprojection residuals (px, every padded corner) and the inverse
    blocks of its information, traced once and vmapped by :data:`_batch_core_jit`."""
    raw = lm_solve(problem, options)
    residuals = tuple(
        jax.vmap(f.fn)(*(raw.values[a][i] for a, i in zip(f.args, f.indices)), f.observations)
        for f in problem.factors if f.name.startswith("reprojection:")
    )
    return raw, residuals, _inverse_blocks(raw.system)


def _system_core(problem: Problem):
    """The Gauss–Newton system at the problem's values and its inverse blocks: what a solve with
    ``max_iterations=0`` (:data:`_COV_OPTIONS`) computes, without compiling the LM loop again."""
    layout = linear.make_layout(problem)
    cost, system, m_eff = linear.linearize(problem, layout, problem.initial_values(), linear.free_masks(problem))
    return (cost, system, m_eff), _inverse_blocks(system)


_batch_core_jit = eqx.filter_jit(eqx.filter_vmap(_batch_core, in_axes=(0, None)))
_system_core_jit = eqx.filter_jit(eqx.filter_vmap(_system_core))


def _raise_if_unobservable(sol: Solution) -> None:
    """What :func:`jcalib.solve.solve` raises for a rank-deficient solution."""
    if sol.status != Status.NOT_OBSERVABLE:
        return
    unknowns = unobservable_names(sol.padded_problem, sol.layout, sol.raw.observability, sol.options.rank_rtol)
    raise NotObservableError(
        "The data do not determine these unknowns (rank-deficient information matrix at the "
        f"solution): {', '.join(unknowns)}. Fix them, add a prior, or collect data that constrains them.",
        unknowns,
    )


def _solve_batch(problems: list[Problem], options: SolveOptions) -> list[tuple[Solution, list[np.ndarray]]]:
    """Solve problems in vmapped calls of :func:`jcalib.solve.batch_width`: one group per problem structure, padded to
    the group's largest bucket (:func:`jcalib.solve.bucket_size`) of every count. Returns per problem
    its :class:`Solution` (covariance blocks already cached) and its per-camera residuals (px) in
    the batch's padded layout (the problem's own layout is a prefix of it).

    With ``options`` :data:`_COV_OPTIONS` (no iteration) only the system at the start values is
    formed (:func:`_system_core`); the solutions then carry no observability analysis and no residuals.
    """
    system_only = options.max_iterations == 0
    out: list = [None] * len(problems)
    groups: dict = {}
    for k, pr in enumerate(problems):
        groups.setdefault(jax.tree.structure(pr), []).append(k)
    for members in groups.values():
        first = problems[members[0]]
        var_num = {v.name: max(bucket_size(problems[k].variable(v.name).num) for k in members)
                   for v in first.variables}
        obs_num = {f.name: max(bucket_size(g.num_obs // (g.chunk or 1)) * (g.chunk or 1)  # whole runs
                               for k in members for g in problems[k].factors if g.name == f.name)
                   for f in first.factors}
        padded = [pad_problem(problems[k], num_entries=var_num, num_obs=obs_num) for k in members]
        width = batch_width(len(members))  # 8 on XLA:CPU, the whole group on an accelerator
        for start in range(0, len(members), width):
            part = padded[start:start + width]
            part = part + [part[0]] * (width - len(part))  # one compiled width: fill with copies
            stacked = jax.tree.map(lambda *xs: np.stack(xs), *part)
            if system_only:
                (cost, system, m_eff), inv = jax.device_get(_system_core_jit(stacked))
                res = ()
            else:
                raw, res, inv = jax.device_get(_batch_core_jit(stacked, options))
            for j, k in enumerate(members[start:start + width]):
                def pick(a, j=j):
                    return a[j]

                pp = padded[start + j]
                if system_only:
                    num_free = sum(int(np.sum(~np.asarray(v.fixed))) for v in pp.variables)
                    raw_j = RawSolution(
                        values=pp.initial_values(), cost=cost[j], iterations=np.int32(0),
                        status=np.int32(Status.CONVERGED), num_residuals=m_eff[j], num_free=np.int32(num_free),
                        system=jax.tree.map(pick, system), observability=None,
                    )
                else:
                    raw_j = jax.tree.map(pick, raw)
                sol = Solution(problems[k], pp, raw_j, options)
                sol._cov_cache = jax.tree.map(pick, inv)  # what covariance() would compute from sol.raw.system
                out[k] = (sol, [np.asarray(r[j]) for r in res])
    return out


def calibrate_hand_eye_batch(
    cell: CellSpec,
    observations: Sequence[Observations],
    options: HandEyeOptions = HandEyeOptions(),
    *,
    raise_errors: bool = True,
) -> list[HandEyeCalibration | Exception]:
    """Calibrate many hand-eye data sets of one cell (e.g. the trials of a study) with vmapped solves.

    Each data set is gathered and started on the host (intrinsics, per-view poses, closed form) as in
    :func:`calibrate_hand_eye`; the main solves of all of them are padded to one shape (the largest
    bucket of the batch, so different numbers of stations and dropped corners still batch) and run by
    ``jax.vmap`` of one jitted solve, :func:`jcalib.solve.batch_width` data sets per call. Outlier re-solves run per data
    set; the covariance re-solves of the robot pose model (a-posteriori noise) are batched again.
    Results equal :func:`calibrate_hand_eye` on each data set to solver tolerance.

    Args:
        cell: the hand-eye cell (see :func:`calibrate_hand_eye`).
        observations: data sets, each an :class:`Observations` of that cell.
        options: :class:`HandEyeOptions`, shared.
        raise_errors: raise the first error (default); ``False`` returns the exception a data set
            raised (``BadInputError``, ``NotObservableError``, or any other from its own data) in its
            place instead.

    Returns:
        One :class:`HandEyeCalibration` (or exception) per data set, in order.

    Raises:
        BadInputError: an empty list; with ``raise_errors``, as :func:`calibrate_hand_eye`.
        NotObservableError: with ``raise_errors``, as :func:`calibrate_hand_eye`.
    """
    if len(observations) == 0:
        raise BadInputError("observations: got an empty list, expected at least one data set")
    results: list = [None] * len(observations)

    def failed(i: int, err: Exception) -> None:
        if raise_errors:
            raise err
        results[i] = err

    # host: gather, closed-form starts, problems
    prepared = []
    for i, obs in enumerate(observations):
        try:
            p = _prepare(cell, obs, options)
            weights = p.start_weights()
            problem = p.build(weights)
            _check_finite_input(problem)
            prepared.append((i, p, weights, problem))
        except Exception as err:  # noqa: BLE001  (returned in place when raise_errors is False)
            failed(i, err)
    # the main solves, vmapped; then per data set the outlier rounds and variance components
    refined = []
    if prepared:
        options_solve = prepared[0][1].solve_options
        for (i, p, weights, _), (sol, res) in zip(prepared, _solve_batch([x[3] for x in prepared], options_solve)):
            try:
                _raise_if_unobservable(sol)
                res = [r[pi] for r, pi in zip(res, p.pad_index)]
                refined.append((i, p, _refine(p, sol, res, weights)))
            except Exception as err:  # noqa: BLE001
                failed(i, err)
    # the covariance re-solves (pose model, a-posteriori noise), vmapped
    resolve = [k for k, (_, _, r) in enumerate(refined) if r.cov_problem is not None]
    cov_sols = {k: r.sol for k, (_, _, r) in enumerate(refined)}
    if resolve:
        for k, (cs, _) in zip(resolve, _solve_batch([refined[k][2].cov_problem for k in resolve], _COV_OPTIONS)):
            cov_sols[k] = cs
    for k, (i, p, r) in enumerate(refined):
        try:
            results[i] = _finish(p, r, cov_sols[k])
        except Exception as err:  # noqa: BLE001
            failed(i, err)
    return results


def _robot_stats(sol, cell: CellSpec, meas: np.ndarray, est: np.ndarray) -> dict:
    """Robot accuracy from the estimated per-station corrections (see :class:`HandEyeCalibration`)."""
    S = _pose_sqrt_info(cell)
    # (N, 6) rx..tz, flange frame: lie.local's formula in numpy (eagerly dispatched JAX ops on these
    # small arrays cost ~10 ms per data set, more than the batched solve of one)
    delta = np.asarray(lie._se3_log(lie._se3_compose(lie._se3_inverse(meas, np), est, np), np), np.float64)
    n = delta.shape[0]
    # Redundancy of the prior residuals r_i = S δ_i: 6 - tr(S Σ_i Sᵀ) per station, Σ_i the
    # (stated-noise) posterior covariance of station i's pose.
    C = np.asarray(_covariance(sol, "T_base_flange", noise="stated")).reshape(n, 6, n, 6)
    C_ii = C[np.arange(n), :, np.arange(n), :]  # (n, 6, 6) per-station blocks
    redundancy = float(6 * n - np.einsum("ab,nbc,ac->", S, C_ii, S))
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
