"""Camera calibration: one or more rigidly mounted cameras seeing a free-moving planar target.

Unknowns: the intrinsics of every camera (any lens model of :mod:`jcalib.geometry.cameras`), the
pose of the target at every station in the reference camera (``T_ref_target``, eliminated by Schur
complement), and the pose of the reference camera in every other camera (``T_cam_ref``, the rig).
Residuals: target-corner reprojection errors in pixels. Closed forms start it (Zhang per camera,
planar PnP per view, rig poses by rotation averaging); jcalib's engine refines it and gives the
covariance. OpenCV serves nothing but a per-view PnP inside the initialiser.

One camera with unknown intrinsics (not fisheye) starts inside the jitted solve instead:
:func:`jcalib.init.zhang_jax.zhang_start` computes Zhang's closed form and its checks in the same
compiled function (one call, and ``vmap``-able for batches). When those checks fail, the host's
numpy closed form runs and either names the problem (fronto-parallel views, collinear points) or
starts the solve itself; either way the optimum is the same.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import conversions, lie
from jcalib.geometry.cameras import AbstractCameraModel, camera_model_from_name
from jcalib.init import planar_pnp, zhang_init
from jcalib.init.zhang_jax import zhang_start
from jcalib.io.cell import CellSpec
from jcalib.io.observations import Observations
from jcalib.residuals.losses import CauchyLoss, HuberLoss, TrivialLoss
from jcalib.solve import SE3, Euclidean, FactorGroup, Problem, SolveOptions, Variable, batch_width, bucket_size, linear
from jcalib.solve.lm import Status, lm_solve, unobservable_names

#: Fewest target points per view: a homography has 8 degrees of freedom (4 points), and fewer
#: than 6 points leave a view pose with almost no redundancy.
MIN_POINTS_PER_VIEW = 6


@dataclass(frozen=True)
class CameraCalibrationOptions:
    """Options of :func:`calibrate_cameras`.

    Attributes:
        loss: robust loss on the whitened residual: ``"none"``, ``"huber"`` or ``"cauchy"``.
        loss_scale: loss scale in units of the noise σ.
        sigma_px: stated corner noise (pixels), used when ``noise="stated"``.
        noise: covariance scale: ``"a_posteriori"`` (σ from the residuals, default) or ``"stated"``.
        outlier_threshold: corners whose whitened residual norm exceeds this many a-posteriori σ
            are rejected after the first solve (and the problem re-solved); ``None`` keeps all.
        reseed_views: re-seed views whose RMS is far above the rest with their other planar-PnP
            pose (a far view can start flipped and stay in that wrong minimum).
        max_iterations: LM iteration limit.
        reference_camera: camera whose frame is the rig frame (default: first in the cell).
    """

    loss: str = "none"
    loss_scale: float = 3.0
    sigma_px: float = 0.25
    noise: str = "a_posteriori"
    outlier_threshold: float | None = 5.0
    reseed_views: bool = True
    max_iterations: int = 100
    reference_camera: str | None = None

    def __post_init__(self):
        if self.loss not in ("none", "huber", "cauchy"):
            raise BadInputError(f"loss: got {self.loss!r}, expected 'none', 'huber' or 'cauchy'")
        if self.noise not in ("a_posteriori", "stated"):
            raise BadInputError(f"noise: got {self.noise!r}, expected 'a_posteriori' or 'stated'")
        if not self.sigma_px > 0 or not self.loss_scale > 0:
            raise BadInputError("sigma_px and loss_scale must be positive")


@dataclass
class CameraCalibration:
    """The outcome of :func:`calibrate_cameras` (see :class:`jcalib.Result` for the file form).

    Attributes:
        cameras: camera id -> calibrated model.
        intrinsics_covariance: camera id -> covariance of ``model.params`` (order
            ``model.param_names``), pixels² / unitless; sampling noise only, not model error.
        T_ref_cam: camera id -> (4, 4) pose of the camera in the reference camera, m.
        T_ref_cam_covariance: camera id -> (6, 6) right-perturbation covariance (rx..tz; rad, m).
        T_cam_target: station id -> {camera id: (4, 4)} target pose per station and camera, m.
        view_rms_px: (camera id, station id) -> RMS reprojection error of that view, pixels.
        residuals_px: camera id -> (n, 2) final residuals (pixels) in the order of ``corners``.
        outliers: (camera id, station id, point index) of rejected corners.
        rms_px, sigma_px: overall RMS and a-posteriori noise σ (pixels).
        num_residuals, iterations, status: solver facts.
        reseeded_views: station ids whose start pose was replaced by the other PnP candidate.
    """

    cameras: dict[str, AbstractCameraModel]
    intrinsics_covariance: dict[str, np.ndarray]
    T_ref_cam: dict[str, np.ndarray]
    T_ref_cam_covariance: dict[str, np.ndarray]
    T_cam_target: dict[str, dict[str, np.ndarray]]
    view_rms_px: dict[tuple[str, str], float]
    residuals_px: dict[str, np.ndarray]
    outliers: list[tuple[str, str, int]]
    rms_px: float
    sigma_px: float
    num_residuals: int
    iterations: int
    status: str
    reference_camera: str
    reseeded_views: list[str] = field(default_factory=list)
    solution: object = None


# ------------------------------------------------------------------------------------ residual


@functools.lru_cache(maxsize=None)
def _reprojection_fn(model_cls: type, image_size: tuple[int, int], skew: bool):
    """Residual ``(intrinsics, T_cam_ref, T_ref_target, obs) -> predicted - observed`` (pixels).

    One function object per (model, image size, skew), so problems built from new data reuse the
    compiled solver. ``obs = (p_target (3,), pixel (2,), aspect (2,))`` where ``aspect = (flag,
    ratio)``: with flag 1, fy is replaced by ``fx / ratio`` (OpenCV's CALIB_FIX_ASPECT_RATIO).
    """

    def fn(intrinsics, T_cam_ref, T_ref_target, obs):
        p_target, pixel, aspect = obs
        fy = jnp.where(aspect[0] > 0.5, intrinsics[0] / aspect[1], intrinsics[1])
        intrinsics = intrinsics.at[1].set(fy)
        model = model_cls.from_params(image_size, intrinsics, skew=skew)
        p_cam = lie.se3_apply(T_cam_ref, lie.se3_apply(T_ref_target, p_target))
        return model.project(p_cam) - pixel

    return fn


@functools.cache
def _chain_reprojection_jacobian(model_cls: type, image_size: tuple[int, int], skew: bool,
                                 chain: tuple[tuple[int, bool], ...]):
    """Hand-derived linearisation (the engine's ``FactorGroup.jacobian``) of a reprojection through a
    chain of poses: ``fn(intrinsics, *poses, obs)`` with ``obs = (p (3,), pixel (2,), aspect (2,))``
    and ``p_cam = A_1 · A_2 ⋯ A_n · p``, where ``A_j`` is ``poses[chain[j][0]]``, inverted when
    ``chain[j][1]`` (first entry on the camera side).

    Autodiff runs through the lens model only, ``(p_cam, intrinsics) -> pixel`` (any model, skew,
    fixed aspect); the poses enter by the chain rule in closed form. With the engine's right
    perturbation ``A · Exp(ω, v)``, ``q_j`` the point on the target side of ``A_j`` and ``u_j = A_j q_j``,
    and ``L_j`` the rotation of ``A_1 ⋯ A_{j-1}``:
    ``∂p_cam/∂(ω, v)_j = L_j R_j [−[q_j]×, I]``, or ``L_j [[u_j]×, −I]`` when ``A_j`` is inverted.
    With reverse-mode autodiff of the whole chain (quaternion rotations included) a camera
    calibration's jitted solve takes ~20 % longer (``benchmarks/bench_linearize_floor.py``).
    """

    def project(p_cam, intrinsics, obs):
        _, pixel, aspect = obs
        fy = jnp.where(aspect[0] > 0.5, intrinsics[0] / aspect[1], intrinsics[1])
        model = model_cls.from_params(image_size, intrinsics.at[1].set(fy), skew=skew)
        r = model.project(p_cam) - pixel
        return r, r

    def jacobian(intrinsics, *rest):
        *poses, obs = rest
        q = obs[0]
        blocks = []  # (pose index, rotation to the left applied later, 3x6 block in the local frame)
        for a, inverted in reversed(chain):  # target side first
            R, t = lie.so3_to_matrix(poses[a][:4]), poses[a][4:]
            if inverted:
                u = R.T @ (q - t)
                blocks.append((a, R.T, jnp.concatenate([_skew(u), -jnp.eye(3, dtype=u.dtype)], axis=1)))
            else:
                u = R @ q + t
                blocks.append((a, R, R @ jnp.concatenate([-_skew(q), jnp.eye(3, dtype=q.dtype)], axis=1)))
            q = u
        (J_cam, J_intr), r = jax.jacrev(project, argnums=(0, 1), has_aux=True)(q, intrinsics, obs)
        J_poses = [jnp.zeros((r.shape[0], 6), r.dtype) for _ in poses]
        left = J_cam  # (2, 3): the camera-side rotations folded in, walking towards the target
        for a, R_a, block in reversed(blocks):
            J_poses[a] = J_poses[a] + left @ block
            left = left @ R_a
        return r, (J_intr, *J_poses)

    return jacobian


def _reprojection_jacobian(model_cls: type, image_size: tuple[int, int], skew: bool):
    """:func:`_chain_reprojection_jacobian` of :func:`_reprojection_fn`: ``p_cam = T_cam_ref · T_ref_target · p``."""
    return _chain_reprojection_jacobian(model_cls, image_size, skew, ((0, False), (1, False)))


def _skew(p):
    """``[p]×`` of ``p (3,)``: ``[p]× q = p × q``."""
    zero = jnp.zeros((), p.dtype)
    return jnp.stack([zero, -p[2], p[1], p[2], zero, -p[0], -p[1], p[0], zero]).reshape(3, 3)


# ------------------------------------------------------------------------------------ helpers


@dataclass
class _CameraData:
    name: str
    model_name: str
    image_size: tuple[int, int]
    skew: bool
    fix: tuple[str, ...]
    K0: np.ndarray | None
    dist0: np.ndarray | None
    stations: list[int]  # station index of each view
    points: list[np.ndarray]  # (n, 3) per view
    pixels: list[np.ndarray]  # (n, 2) per view
    point_index: list[np.ndarray]
    # filled by _prepare: all views concatenated, station (view) index per corner, view offsets
    station_flat: np.ndarray | None = None
    points_flat: np.ndarray | None = None
    pixels_flat: np.ndarray | None = None
    view_starts: np.ndarray | None = None
    chunk: int = 0  # corners per view in the padded layout (max over views, rounded up to 8)
    pad_index: np.ndarray | None = None  # position of each flat corner in the padded layout


def _gather(cell: CellSpec, obs: Observations) -> tuple[list[_CameraData], str, np.ndarray, list[str]]:
    free = [c for c in cell.cameras.values()]
    bad = [c.name for c in free if c.mount != "free"]
    if bad:
        raise BadInputError(
            f"{cell.source}: cameras {bad} are mounted on a robot; camera calibration takes "
            "'mount: free' cameras (hand-eye cells are calibrated by the hand-eye problem)"
        )
    if len(cell.targets) != 1:
        raise BadInputError(
            f"{cell.source}: camera calibration needs exactly one target, the cell has "
            f"{len(cell.targets)} ({', '.join(cell.targets) or 'none'})"
        )
    target = next(iter(cell.targets.values()))
    if target.name not in obs.targets:
        raise BadInputError(f"{obs.source}: the observations have no target '{target.name}'")
    points = obs.targets[target.name]
    if not np.all(np.abs(points[:, 2]) <= 1e-8):  # np.allclose(z, 0), without its overhead
        raise BadInputError(
            f"{obs.source}: target '{target.name}' is not planar (z != 0); camera calibration "
            "needs a planar target"
        )
    station_ids = [s.id for s in obs.stations]
    data = []
    for c in free:
        if c.name not in obs.cameras:
            raise BadInputError(
                f"{obs.source}: camera '{c.name}' of the cell has no image size in the observations"
            )
        cd = _CameraData(c.name, c.model, obs.cameras[c.name], c.skew, c.fix, c.K, c.dist, [], [], [], [])
        for si, station in enumerate(obs.stations):
            for det in station.detections:
                if det.camera != c.name or det.target != target.name:
                    continue
                n = det.point_index.size
                if n < MIN_POINTS_PER_VIEW:
                    raise BadInputError(
                        f"{obs.source}: station '{station.id}', camera '{c.name}': only {n} target "
                        f"points; a view needs at least {MIN_POINTS_PER_VIEW}. Drop the view or "
                        "re-detect it"
                    )
                cd.stations.append(si)
                cd.point_index.append(det.point_index)
                cd.points.append(points[det.point_index])
                cd.pixels.append(det.pixels)
        if not cd.stations:
            raise NotObservableError(
                f"camera '{c.name}' sees the target in no station: nothing determines its intrinsics",
                [f"{c.name} intrinsics"],
            )
        data.append(cd)
    return data, target.name, points, station_ids


def _initial_model(cd: _CameraData) -> tuple[AbstractCameraModel, dict[int, np.ndarray]]:
    """Start intrinsics (from the cell, else Zhang) and per-station target poses for one camera."""
    n_views = len(cd.stations)
    zhang_poses = None
    if cd.K0 is not None:
        K, dist_given = cd.K0, (cd.dist0 if cd.dist0 is not None else np.zeros(0))
    else:
        principal_point = None
        if "cx" in cd.fix and "cy" in cd.fix:
            principal_point = ((cd.image_size[0] - 1) / 2, (cd.image_size[1] - 1) / 2)
        # Cheap Zhang (single pass on the raw homographies): the joint solve does the distortion,
        # and the re-seed check catches a view that starts in the flipped minimum.
        z = zhang_init(
            [p[:, :2] for p in cd.points],
            cd.pixels,
            skew=cd.skew,
            aspect_ratio=1.0 if "aspect" in cd.fix else None,
            principal_point=principal_point,
            image_size=cd.image_size,
            estimate_distortion=False,
            distortion_iterations=0,
            refine_homographies=False,
            view_names=[f"{cd.name} view {i}" for i in range(n_views)],
        )
        K = z.K
        dist_given = np.zeros(0)
        zhang_poses = z.T_cam_target
    template = camera_model_from_name(cd.model_name, cd.image_size, skew=cd.skew)
    names = template.param_names
    values = dict(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])
    if cd.skew:
        values["skew" if "skew" in names else "alpha"] = K[0, 1] if "skew" in names else K[0, 1] / K[0, 0]
    dist_names = [n for n in names if n not in ("fx", "fy", "cx", "cy", "skew", "alpha")]
    for name, value in zip(dist_names, dist_given):
        values[name] = value
    params = np.array([values.get(n, 0.0) for n in names], dtype=np.float64)
    model = template.with_params(jnp.asarray(params))
    if zhang_poses is not None and cd.model_name != "fisheye":
        return model, dict(zip(cd.stations, zhang_poses))
    K_cv, dist_cv = model.to_opencv()
    poses = {}
    for si, pts, pix in zip(cd.stations, cd.points, cd.pixels):
        if cd.model_name == "fisheye":
            und = np.asarray(model.unproject(jnp.asarray(pix)))
            und = und[:, :2] / und[:, 2:3]
            res = planar_pnp(pts, und, np.eye(3))
        else:
            res = planar_pnp(pts, pix, K_cv, dist_cv if dist_cv.size else None)
        poses[si] = res.T_cam_target[0]
    return model, poses


def _average_pose(Ts: list[np.ndarray]) -> np.ndarray:
    """Chordal L2 mean of rotations (SVD projection) and mean of translations."""
    R = sum(T[:3, :3] for T in Ts)
    U, _, Vt = np.linalg.svd(R)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    out = np.eye(4)
    out[:3, :3] = U @ D @ Vt
    out[:3, 3] = np.mean([T[:3, 3] for T in Ts], axis=0)
    return out


def _se3_params(T: np.ndarray) -> np.ndarray:
    return conversions.matrix_to_pose(np.asarray(T, dtype=np.float64))


def _se3_matrix(p) -> np.ndarray:
    return conversions.pose_to_matrix(np.asarray(p, dtype=np.float64))


def _intrinsics_fixed_mask(model: AbstractCameraModel, fix: tuple[str, ...]) -> np.ndarray:
    names = model.param_names
    allowed = set(names) | {"aspect"}
    unknown = sorted(set(fix) - allowed)
    if unknown:
        raise BadInputError(
            f"fix: unknown intrinsic names {unknown} for model '{model.name}'; "
            f"allowed: {', '.join(names)}, aspect"
        )
    mask = np.array([n in fix for n in names])
    if "aspect" in fix:
        mask[names.index("fy")] = True
    return mask


@functools.lru_cache(maxsize=16)
def _solve_options(max_iterations: int) -> SolveOptions:
    # mu0 1e-6: the Zhang start is close enough that near-Gauss-Newton steps are accepted at
    # once (6 instead of 9 iterations on benchmarks/bench_calibrate.py's data, same optimum)
    return SolveOptions(max_iterations=max_iterations, mu0=1e-6)


def _loss(options: CameraCalibrationOptions):
    if options.loss == "huber":
        return HuberLoss(options.loss_scale)
    if options.loss == "cauchy":
        return CauchyLoss(options.loss_scale)
    return TrivialLoss()


# ------------------------------------------------------------------------------------ problem


# ------------------------------------------------------------------------------------ problem
#
# Speed (see benchmarks/bench_calibrate.py): the problem is built from plain arrays *inside* one
# jitted function that solves, evaluates the residuals and inverts the Schur complement (the
# intrinsics and rig covariances are blocks of it). Views and observations are padded to buckets
# (:func:`jcalib.solve.bucket_size`), so data sets of similar size reuse one compiled function, and
# ``jax.vmap`` of the same function solves a batch of same-shape calibrations in one call.


@dataclass(frozen=True)
class _CameraConfig:
    """Static (hashable) description of one camera's factor group and intrinsics variable."""

    name: str
    model_cls: type
    image_size: tuple[int, int]
    skew: bool
    coord_names: tuple[str, ...]
    chunk: int  # corners per view in the padded (views x corners) layout
    # Zhang's closed form inside the jit (one camera, intrinsics not given, not fisheye):
    # ``(skew, aspect_ratio, principal_point)`` of :func:`jcalib.init.zhang_jax.zhang_start`
    zhang: tuple | None = None


@dataclass(frozen=True)
class _Config:
    """Static (hashable) part of a camera problem: one compiled function per config and shapes."""

    cameras: tuple[_CameraConfig, ...]
    loss: object
    sigma_px: float
    solve_options: SolveOptions


def _problem_from_arrays(config: _Config, a: dict) -> Problem:
    """The engine problem from arrays ``a`` (numpy or traced); see :func:`_arrays` for the keys."""
    variables = [
        Variable("T_ref_target", SE3(), a["pose"], fixed=a["pose_fixed"], eliminate=True,
                 entry_label="station {i} target pose"),
        # one camera: its rig pose is the identity, known at trace time (no Jacobian columns)
        Variable("T_cam_ref", SE3(), a["rig"], fixed=a["rig_fixed"], entry_label="rig pose of camera {i}",
                 constant=len(config.cameras) == 1),
    ]
    factors = []
    for ci, cc in enumerate(config.cameras):
        variables.append(
            Variable(f"intrinsics:{cc.name}", Euclidean(len(cc.coord_names)), a[f"intr{ci}"][None, :],
                     fixed=a[f"intr_fixed{ci}"][None, :], coord_names=list(cc.coord_names), entry_label=cc.name)
        )
        station = a[f"station{ci}"]
        factors.append(
            FactorGroup(
                f"reprojection:{cc.name}",
                _reprojection_fn(cc.model_cls, cc.image_size, cc.skew),
                (f"intrinsics:{cc.name}", "T_cam_ref", "T_ref_target"),
                (jnp.zeros(station.shape, jnp.int32), jnp.full(station.shape, ci, jnp.int32), station),
                (a[f"points{ci}"], a[f"pixels{ci}"], a[f"aspect{ci}"]),
                sigma=config.sigma_px,
                sqrt_weight=a[f"weight{ci}"],
                loss=config.loss,
                chunk=cc.chunk,
                jacobian=_reprojection_jacobian(cc.model_cls, cc.image_size, cc.skew),
            )
        )
    return Problem(variables, factors)


def _zhang_start(config: _Config, a: dict):
    """Zhang's closed form on the padded layout of the one camera: (intrinsics, poses, ok, spread)."""
    cc = config.cameras[0]
    skew, aspect_ratio, principal_point = cc.zhang
    V = a["pose"].shape[0]
    K, pose, ok, spread = zhang_start(
        a["points0"][:, :2].reshape(V, cc.chunk, 2), a["pixels0"].reshape(V, cc.chunk, 2),
        (a["weight0"] > 0.0).reshape(V, cc.chunk), image_size=cc.image_size, skew=skew,
        aspect_ratio=aspect_ratio, principal_point=principal_point)
    values = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "skew": K[0, 1],
              "alpha": K[0, 1] / K[0, 0]}
    zero = jnp.zeros((), K.dtype)
    intr = jnp.stack([values.get(n, zero) for n in cc.coord_names])
    real = ~jnp.all(a["pose_fixed"], axis=-1)  # padded views are fixed copies of view 0
    pose = jnp.where(real[:, None], pose, pose[:1])
    return intr, pose, ok, spread


def _core(config: _Config, a: dict):
    """Start, solve, residuals (pixels, unwhitened) and the inverse Schur complement, in one traced function.

    With ``config.cameras[0].zhang`` set, the start is Zhang's closed form computed here, unless
    ``a["use_start"]`` asks for the given one (re-solves after a re-seed or outlier rejection);
    the returned ``start`` is ``(ok, spread)`` of :func:`jcalib.init.zhang_jax.zhang_start`
    (``ok = False``: the caller re-initialises on the host, which names what is wrong).
    """
    start = (jnp.ones((), bool), jnp.zeros((), jnp.float64))
    if config.cameras[0].zhang is not None:
        intr, pose, ok, spread = _zhang_start(config, a)
        given = a["use_start"]
        a = dict(a, pose=jnp.where(given, a["pose"], pose), intr0=jnp.where(given, a["intr0"], intr))
        start = (ok | given, spread)
    problem = _problem_from_arrays(config, a)
    raw = lm_solve(problem, config.solve_options)
    residuals = []
    for f in problem.factors:
        rows = [raw.values[name][idx] for name, idx in zip(f.args, f.indices)]
        residuals.append(jax.vmap(f.fn)(*rows, f.observations))
    S, _ = linear.reduced_system(raw.system, None, None)
    n = S.shape[0]
    sigma_ss = jsl.cho_solve(jsl.cho_factor(S, lower=True), jnp.eye(n, dtype=S.dtype))
    return raw, tuple(residuals), sigma_ss, start


_core_jit = jax.jit(_core, static_argnums=0)


@functools.partial(jax.jit, static_argnums=0)
def _core_batch_jit(config: _Config, a: dict):
    return jax.vmap(functools.partial(_core, config))(a)


@dataclass
class _Prepared:
    """One calibration data set, initialised and laid out for :func:`_core` (numpy only)."""

    config: _Config
    data: list[_CameraData]
    ref: str
    station_ids: list[str]
    used: list[int]
    models: dict[str, AbstractCameraModel]
    fixed_masks: dict[str, np.ndarray]
    aspects: dict[str, tuple[float, float]]
    pose0: np.ndarray  # (V, 7) T_ref_target start
    rig0: np.ndarray  # (C, 7) T_cam_ref start
    weights: dict[str, np.ndarray]
    num_views_padded: int = 0
    num_obs_padded: tuple[int, ...] = ()  # per camera: padded number of views (runs of ``chunk`` corners)
    fast: bool = False  # the start is computed inside the jit (Zhang, :func:`_zhang_start`)

    def shape_key(self):
        return (self.num_views_padded, self.num_obs_padded)


def _pad_rows(x: np.ndarray, n: int) -> np.ndarray:
    extra = n - x.shape[0]
    if extra <= 0:
        return x
    return np.concatenate([x, np.broadcast_to(x[:1], (extra,) + x.shape[1:])])


def _arrays(p: _Prepared, pose: np.ndarray, rig: np.ndarray, intr: dict[str, np.ndarray],
            weights: dict[str, np.ndarray], use_start: bool = True) -> dict[str, np.ndarray]:
    """Padded input arrays of :func:`_core` (padding: fixed copies of entry 0, zero-weight copies of obs 0).

    ``use_start=False`` lets the jitted solve start from its own closed form (``p.fast`` data sets).
    """
    V, Vp = pose.shape[0], p.num_views_padded
    pose_fixed = np.zeros((Vp, 6), bool)
    pose_fixed[V:] = True
    rig_fixed = np.zeros((len(p.data), 6), bool)
    rig_fixed[0] = True  # the reference camera comes first
    a = dict(pose=_pad_rows(pose, Vp), pose_fixed=pose_fixed, rig=rig, rig_fixed=rig_fixed)
    if p.config.cameras[0].zhang is not None:
        a["use_start"] = np.asarray(use_start)
    for ci, cd in enumerate(p.data):
        # (views x corners) layout: view v's corners at v * chunk + [0, n_v); padding (short views,
        # extra views) repeats corner 0 of the camera with weight 0, in a run of one station
        Kp = p.num_obs_padded[ci] * cd.chunk
        flag, ratio = p.aspects[cd.name]
        a[f"intr{ci}"] = np.asarray(intr[cd.name], np.float64)
        a[f"intr_fixed{ci}"] = p.fixed_masks[cd.name]
        a[f"station{ci}"] = np.repeat(_pad_rows(np.asarray(cd.stations, np.int32), p.num_obs_padded[ci]), cd.chunk)
        for key, flat in (("points", cd.points_flat), ("pixels", cd.pixels_flat)):
            full = np.empty((Kp, flat.shape[1]))
            full[:] = flat[0]
            full[cd.pad_index] = flat
            a[f"{key}{ci}"] = full
        a[f"aspect{ci}"] = np.broadcast_to(np.array([flag, ratio]), (Kp, 2))
        w = np.zeros(Kp)
        w[cd.pad_index] = weights[cd.name]
        a[f"weight{ci}"] = w
    return a


@dataclass
class _Outcome:
    """Host-side result of one :func:`_core` call (unpadded where it matters)."""

    raw: object
    values: dict[str, np.ndarray]
    residuals: dict[str, np.ndarray]
    sigma_ss: np.ndarray
    cost: float
    iterations: int
    status: Status
    num_residuals: int
    num_free: int
    sigma2: float
    arrays: dict
    start_ok: bool = True
    view_rms: tuple | None = None  # (weights, rms) cache of :func:`_view_rms`


def _outcome(p: _Prepared, a: dict, out) -> _Outcome:
    raw, residuals, sigma_ss, (start_ok, _) = out
    V = p.pose0.shape[0]
    vals = {k: np.asarray(v) for k, v in raw.values.items()}
    vals["T_ref_target"] = vals["T_ref_target"][:V]
    res = {cd.name: np.asarray(r)[cd.pad_index] for cd, r in zip(p.data, residuals)}
    num_residuals, num_free, cost = int(raw.num_residuals), int(raw.num_free), float(raw.cost)
    dof = num_residuals - num_free
    return _Outcome(raw, vals, res, np.asarray(sigma_ss), cost, int(raw.iterations), Status(int(raw.status)),
                    num_residuals, num_free, 2.0 * cost / dof if dof > 0 else float("nan"), a, bool(start_ok))


def _raise_if_unobservable(p: _Prepared, o: _Outcome) -> None:
    if o.status != Status.NOT_OBSERVABLE:
        return
    padded = _problem_from_arrays(p.config, o.arrays)
    opts = p.config.solve_options
    unknowns = unobservable_names(padded, linear.make_layout(padded), o.raw.observability, opts.rank_rtol)
    raise NotObservableError(
        "The data do not determine these unknowns (rank-deficient information matrix at the "
        f"solution): {', '.join(unknowns)}. Fix them, add a prior, or collect data that constrains them.",
        unknowns,
    )


def _check_finite_start(p: _Prepared, a: dict) -> None:
    for key, label in (("pose", "T_ref_target"), ("rig", "T_cam_ref")):
        if not np.all(np.isfinite(a[key])):
            raise BadInputError(f"Variable {label!r} value: contains non-finite numbers, expected finite numbers.")
    for ci, cd in enumerate(p.data):
        if not np.all(np.isfinite(a[f"intr{ci}"])):
            raise BadInputError(
                f"Variable 'intrinsics:{cd.name}' value: got {a[f'intr{ci}']}, expected finite numbers."
            )


@functools.lru_cache(maxsize=64)
def _template(model_name: str, image_size: tuple[int, int], skew: bool) -> AbstractCameraModel:
    return camera_model_from_name(model_name, image_size, skew=skew)


def _zhang_options(data: list[_CameraData]) -> tuple | None:
    """Static options of the in-jit Zhang start, or None where the start needs the host.

    The host start handles several cameras (rig poses by rotation averaging), given intrinsics
    (planar PnP) and the fisheye model (PnP on unprojected rays).
    """
    if len(data) != 1 or data[0].K0 is not None or data[0].model_name == "fisheye":
        return None
    cd = data[0]
    principal_point = None
    if "cx" in cd.fix and "cy" in cd.fix:
        principal_point = ((cd.image_size[0] - 1) / 2, (cd.image_size[1] - 1) / 2)
    return (bool(cd.skew), 1.0 if "aspect" in cd.fix else None, principal_point)


def _prepare(cell: CellSpec, obs: Observations, options: CameraCalibrationOptions, fast: bool = True) -> _Prepared:
    """Validate, initialise (Zhang, poses, rig) and lay out one data set; numpy only.

    With ``fast`` and a camera that :func:`_zhang_options` accepts, the start is left to the jitted
    solve (:func:`_zhang_start`): the host only validates and lays out the data.
    """
    data, _, _, station_ids = _gather(cell, obs)
    ref = options.reference_camera or data[0].name
    if ref not in [cd.name for cd in data]:
        raise BadInputError(f"reference_camera: no camera '{ref}' in the cell")
    data.sort(key=lambda cd: cd.name != ref)  # reference first
    zhang = _zhang_options(data)
    fast = fast and zhang is not None

    models, poses, fixed_masks, aspects = {}, {}, {}, {}
    for cd in data:
        if fast:  # placeholders: the jitted solve starts from its own closed form
            models[cd.name] = _template(cd.model_name, tuple(int(v) for v in cd.image_size), bool(cd.skew))
            poses[cd.name] = {}
        else:
            models[cd.name], poses[cd.name] = _initial_model(cd)
        fixed_masks[cd.name] = _intrinsics_fixed_mask(models[cd.name], cd.fix)
        ratio = 1.0
        if cd.K0 is not None:
            ratio = float(cd.K0[0, 0] / cd.K0[1, 1])
        aspects[cd.name] = (1.0 if "aspect" in cd.fix else 0.0, ratio)
        if "aspect" in cd.fix and not fast:
            p = np.asarray(models[cd.name].params).copy()
            p[1] = p[0] / ratio
            models[cd.name] = models[cd.name].with_params(jnp.asarray(p))

    # Rig: T_cam_ref from stations shared with the reference camera (breadth-first over cameras).
    T_cam_ref = {ref: np.eye(4)}
    pending = [cd for cd in data if cd.name != ref]
    while pending:
        progress = False
        for cd in list(pending):
            pairs = []
            for other, T_o in T_cam_ref.items():
                for si, T_ct in poses[cd.name].items():
                    if si in poses[other]:
                        T_ref_target = np.linalg.inv(T_o) @ poses[other][si]
                        pairs.append(T_ct @ np.linalg.inv(T_ref_target))
            if pairs:
                T_cam_ref[cd.name] = _average_pose(pairs)
                pending.remove(cd)
                progress = True
        if not progress:
            names = [cd.name for cd in pending]
            raise NotObservableError(
                f"cameras {names} share no station with camera '{ref}' (directly or through other "
                "cameras): their pose in the rig is not determined; add stations where both see the target",
                [f"T_{ref}_{n}" for n in names],
            )

    used = sorted({si for cd in data for si in cd.stations})
    index_of = {si: k for k, si in enumerate(used)}
    for cd in data:
        cd.stations = [index_of[s] for s in cd.stations]
        poses[cd.name] = {index_of[s]: T for s, T in poses[cd.name].items()}
        cd.station_flat = np.repeat(np.asarray(cd.stations, np.int32), [p.shape[0] for p in cd.points])
        cd.points_flat = np.concatenate(cd.points)
        cd.pixels_flat = np.concatenate(cd.pixels)
        cd.view_starts = np.concatenate([[0], np.cumsum([p.shape[0] for p in cd.points])[:-1]]).astype(np.int64)
        counts = np.array([p.shape[0] for p in cd.points])
        cd.chunk = int(-(-counts.max() // 8) * 8)
        cd.pad_index = (np.repeat(np.arange(len(counts)) * cd.chunk, counts)
                        + np.arange(counts.sum()) - np.repeat(cd.view_starts, counts))
    identity = np.array([1.0, 0, 0, 0, 0, 0, 0])
    if fast:  # placeholders (one camera, the rig is its identity)
        pose0, rig0 = np.tile(identity, (len(used), 1)), identity[None, :].copy()
    else:
        T_ref_target = []
        for k in range(len(used)):
            for cd in data:
                if k in poses[cd.name]:
                    T_ref_target.append(np.linalg.inv(T_cam_ref[cd.name]) @ poses[cd.name][k])
                    break
        pose0 = _se3_params_many(np.stack(T_ref_target))
        rig0 = _se3_params_many(np.stack([T_cam_ref[cd.name] for cd in data]))
    config = _Config(
        cameras=tuple(
            _CameraConfig(cd.name, type(models[cd.name]), tuple(int(s) for s in models[cd.name].image_size),
                          bool(models[cd.name].has_skew), tuple(models[cd.name].param_names), cd.chunk,
                          zhang)
            for cd in data
        ),
        loss=_loss(options),
        sigma_px=float(options.sigma_px),
        solve_options=_solve_options(options.max_iterations),
    )
    return _Prepared(
        config=config,
        data=data,
        ref=ref,
        station_ids=station_ids,
        used=used,
        models=models,
        fixed_masks=fixed_masks,
        aspects=aspects,
        pose0=pose0,
        rig0=rig0,
        weights={cd.name: np.ones(cd.station_flat.shape[0]) for cd in data},
        num_views_padded=bucket_size(len(used)),
        num_obs_padded=tuple(bucket_size(len(cd.stations)) for cd in data),
        fast=fast,
    )


def _se3_params_many(T: np.ndarray) -> np.ndarray:
    """(n, 4, 4) -> (n, 7) ``wxyz_xyz`` (one vectorised :func:`conversions.matrix_to_pose` call)."""
    return np.asarray(conversions.matrix_to_pose(np.asarray(T, dtype=np.float64)))


def _start_arrays(p: _Prepared) -> dict:
    if p.fast:  # placeholders: the jitted solve starts from its own closed form
        intr = {cd.name: np.zeros(len(p.models[cd.name].param_names)) for cd in p.data}
    else:
        intr = {cd.name: np.asarray(p.models[cd.name].params, np.float64) for cd in p.data}
    a = _arrays(p, p.pose0, p.rig0, intr, p.weights, use_start=not p.fast)
    _check_finite_start(p, a)
    return a


def _view_rms(p: _Prepared, o: _Outcome) -> dict:
    """(camera, view index) -> RMS of the corners with nonzero weight (pixels), of outcome ``o``
    under the current weights ``p.weights`` (computed once for both)."""
    if o.view_rms is None or o.view_rms[0] is not p.weights:
        o.view_rms = (p.weights, _compute_view_rms(p, o.residuals, p.weights))
    return o.view_rms[1]


def _compute_view_rms(p: _Prepared, res: dict[str, np.ndarray], weights: dict[str, np.ndarray]) -> dict:
    out = {}
    for cd in p.data:
        sq = np.sum(res[cd.name] ** 2, axis=1) * (weights[cd.name] > 0)
        total = np.add.reduceat(sq, cd.view_starts)
        count = np.add.reduceat((weights[cd.name] > 0).astype(np.float64), cd.view_starts)
        rms = np.sqrt(total / np.maximum(count, 1.0))
        rms = np.where(count > 0, rms, 0.0)
        for s, v in zip(cd.stations, rms.tolist()):
            out[(cd.name, s)] = v
    return out


def _intrinsics_now(p: _Prepared, o: _Outcome) -> dict[str, np.ndarray]:
    return {cd.name: o.values[f"intrinsics:{cd.name}"][0] for cd in p.data}


def _reseed_arrays(p: _Prepared, o: _Outcome):
    """Start arrays with suspect views re-seeded by their other planar-PnP pose, or None."""
    rms = _view_rms(p, o)
    median = float(np.median(list(rms.values())))
    suspects = sorted({s for (c, s), v in rms.items() if v > 3.0 * max(median, 1e-3)})
    if not suspects:
        return None, []
    intr = _intrinsics_now(p, o)
    new_pose = o.values["T_ref_target"].copy()
    for s in suspects:
        cd = next(cd for cd in p.data if s in cd.stations)
        if cd.model_name == "fisheye":
            continue
        v = cd.stations.index(s)
        K_cv, dist_cv = p.models[cd.name].with_params(jnp.asarray(intr[cd.name])).to_opencv()
        cand = planar_pnp(cd.points[v], cd.pixels[v], K_cv, dist_cv if dist_cv.size else None)
        T_cam = _se3_matrix(o.values["T_cam_ref"][p.data.index(cd)])
        new_pose[s] = _se3_params(np.linalg.inv(T_cam) @ cand.T_cam_target[1])
    return _arrays(p, new_pose, o.values["T_cam_ref"], intr, p.weights), suspects


def _outlier_update(p: _Prepared, o: _Outcome, options: CameraCalibrationOptions):
    """Reject corners above the threshold; returns (new weights or None, outlier list)."""
    sigma = float(np.sqrt(o.sigma2)) * options.sigma_px if options.noise == "a_posteriori" else options.sigma_px
    weights = dict(p.weights)
    outliers, changed = [], False
    for cd in p.data:
        bad = np.linalg.norm(o.residuals[cd.name], axis=1) > options.outlier_threshold * sigma
        if np.any(bad & (weights[cd.name] > 0)):
            weights[cd.name] = np.where(bad, 0.0, weights[cd.name])
            changed = True
            index = np.concatenate(cd.point_index)
            outliers += [(cd.name, p.station_ids[p.used[cd.station_flat[k]]], int(index[k])) for k in np.flatnonzero(bad)]
    return (weights if changed else None), outliers


@functools.lru_cache(maxsize=1)
def _host_device():
    """The CPU device: results are built there, also when the solves run on a GPU (each small
    array put on the GPU would be a transfer of its own)."""
    return jax.local_devices(backend="cpu")[0]


def _final_params(p: _Prepared, o: _Outcome, cd: _CameraData) -> np.ndarray:
    """A camera's model parameters at the solution (``fy`` from ``fx`` under a fixed aspect ratio)."""
    prm = o.values[f"intrinsics:{cd.name}"][0].copy()
    flag, ratio = p.aspects[cd.name]
    if flag:
        prm[1] = prm[0] / ratio
    return prm


def _pose_params(o: _Outcome) -> np.ndarray:
    """``(V + C, 7)``: the target poses ``T_ref_target``, then the rig poses ``T_cam_ref``."""
    return np.concatenate([o.values["T_ref_target"], o.values["T_cam_ref"]])


def _finish(p: _Prepared, o: _Outcome, options: CameraCalibrationOptions, outliers, reseeded,
            cameras: dict[str, AbstractCameraModel], pose_matrices: np.ndarray) -> CameraCalibration:
    """Assemble the :class:`CameraCalibration` from the final solve (covariances: blocks of Σ_ss).

    ``cameras`` (the calibrated models) and ``pose_matrices`` (the 4x4 matrices of
    :func:`_pose_params`) come from :func:`_finish_all`, which builds them for all data sets at once.
    """
    if options.noise == "a_posteriori":
        if not o.sigma2 == o.sigma2:
            raise NotObservableError(
                f"The a-posteriori noise level needs more residuals ({o.num_residuals}) than free "
                f"unknowns ({o.num_free}); use noise='stated'.",
                ["sigma2"],
            )
        scale = o.sigma2
    else:
        scale = 1.0
    C = len(p.data)
    intr_cov, T_ref_cam, T_ref_cam_cov = {}, {}, {}
    T_cam_target: dict[str, dict[str, np.ndarray]] = {}
    off = 6 * C
    rig_fixed = np.zeros((C, 6), bool)
    rig_fixed[0] = True
    V = o.values["T_ref_target"].shape[0]
    T_ref_target_all, T_cam_ref_all = pose_matrices[:V], pose_matrices[V:]
    for i, cd in enumerate(p.data):
        n = len(p.models[cd.name].param_names)
        f = (~p.fixed_masks[cd.name]).astype(np.float64)
        cov = scale * o.sigma_ss[off : off + n, off : off + n] * f[:, None] * f[None, :]
        off += n
        flag, ratio = p.aspects[cd.name]
        if flag:
            cov[1, :] = cov[0, :] / ratio
            cov[:, 1] = cov[:, 0] / ratio
            cov[1, 1] = cov[0, 0] / ratio**2
        intr_cov[cd.name] = cov
        T_cr = T_cam_ref_all[i]
        T_ref_cam[cd.name] = np.linalg.inv(T_cr)
        fr = (~rig_fixed[i]).astype(np.float64)
        cov_cr = scale * o.sigma_ss[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] * fr[:, None] * fr[None, :]
        # Cov of T_ref_cam = inv(T_cam_ref): right perturbation maps by -Ad(T_cam_ref).
        Ad = _adjoint_rot_first(T_cr)
        T_ref_cam_cov[cd.name] = Ad @ cov_cr @ Ad.T
        for s, T_ct in zip(cd.stations, T_cr @ T_ref_target_all[cd.stations]):
            T_cam_target.setdefault(p.station_ids[p.used[s]], {})[cd.name] = T_ct

    rms = _view_rms(p, o)
    all_res = np.concatenate([o.residuals[cd.name][p.weights[cd.name] > 0] for cd in p.data])
    return CameraCalibration(
        cameras=cameras,
        intrinsics_covariance=intr_cov,
        T_ref_cam=T_ref_cam,
        T_ref_cam_covariance=T_ref_cam_cov,
        T_cam_target=T_cam_target,
        view_rms_px={(c, p.station_ids[p.used[s]]): v for (c, s), v in rms.items()},
        residuals_px=o.residuals,
        outliers=outliers,
        rms_px=float(np.sqrt(np.mean(np.sum(all_res**2, axis=1)))),
        sigma_px=float(np.sqrt(o.sigma2)) * options.sigma_px,
        num_residuals=int(all_res.size),
        iterations=o.iterations,
        status=o.status.name.lower(),
        reference_camera=p.ref,
        reseeded_views=reseeded,
        solution=o.raw,
    )


def _finish_all(finals: dict, options: CameraCalibrationOptions, raise_errors: bool = True) -> dict:
    """:func:`_finish` of data sets ``key -> (p, o, outliers, reseeded)``: their calibrated models
    in one build per camera (:meth:`~jcalib.geometry.AbstractCameraModel.with_params_many`, on the
    host CPU device) and their pose matrices in one conversion. Returns ``key -> CameraCalibration``
    (or the data set's error, with ``raise_errors=False``)."""
    stacks: dict = {}
    for key, (p, o, _, _) in finals.items():
        for cd in p.data:
            m = p.models[cd.name]
            stacks.setdefault((cd.name, type(m), m.image_size, m.has_skew), []).append((key, _final_params(p, o, cd)))
    cameras: dict = {key: {} for key in finals}
    with jax.default_device(_host_device()):  # results live on the host, also when solving on a GPU
        for (name, *_), members in stacks.items():
            template = finals[members[0][0]][0].models[name]
            for (key, _), model in zip(members, template.with_params_many(np.stack([prm for _, prm in members]))):
                cameras[key][name] = model
    poses = [_pose_params(o) for _, o, _, _ in finals.values()]
    matrices = np.split(conversions.pose_to_matrix(np.concatenate(poses)), np.cumsum([len(x) for x in poses])[:-1])
    out = {}
    for (key, (p, o, outliers, reseeded)), T_all in zip(finals.items(), matrices):
        try:
            out[key] = _finish(p, o, options, outliers, reseeded, cameras[key], T_all)
        except (BadInputError, NotObservableError) as err:
            if raise_errors:
                raise
            out[key] = err
    return out


def _run_one(p: _Prepared, a: dict) -> _Outcome:
    """Solve; an in-jit start that failed its checks (``start_ok`` False) is returned, not raised on."""
    o = _outcome(p, a, jax.device_get(_core_jit(p.config, a)))
    if o.start_ok:
        _raise_if_unobservable(p, o)
    return o


def _solve_prepared(cell: CellSpec, obs: Observations, options: CameraCalibrationOptions,
                    p: _Prepared, o: _Outcome) -> tuple[_Prepared, _Outcome, list, list]:
    """Refine a first solve (:func:`_refine`); when its in-jit start was rejected, start again from
    the host's closed form first. Returns what :func:`_finish` takes."""
    if not o.start_ok:
        p = _prepare(cell, obs, options, fast=False)  # names what is wrong, or starts it properly
        o = _run_one(p, _start_arrays(p))
    return (p, *_refine(p, o, options))


def _refine(p: _Prepared, o: _Outcome, options: CameraCalibrationOptions, run=None) -> tuple[_Outcome, list, list]:
    """Re-seed check and outlier rejection after the first solve (each re-solves only when needed).

    Returns the final outcome, the rejected corners and the re-seeded station ids.
    """
    run = run or _run_one
    reseeded = []
    if options.reseed_views:
        a2, suspects = _reseed_arrays(p, o)
        if a2 is not None:
            o2 = run(p, a2)
            if o2.cost < o.cost:
                o, reseeded = o2, [p.station_ids[p.used[s]] for s in suspects]
    outliers = []
    if options.outlier_threshold is not None:
        weights, outliers = _outlier_update(p, o, options)
        if weights is not None:
            p.weights = weights
            o = run(p, _arrays(p, o.values["T_ref_target"], o.values["T_cam_ref"], _intrinsics_now(p, o), weights))
    return o, outliers, reseeded


def calibrate_cameras(
    cell: CellSpec, obs: Observations, options: CameraCalibrationOptions = CameraCalibrationOptions()
) -> CameraCalibration:
    """Calibrate the free cameras of ``cell`` from target detections ``obs``.

    One jitted call solves, evaluates the residuals and forms the covariances; a second (same
    compiled function) runs only when a view is re-seeded or corners are rejected.

    Returns:
        A :class:`CameraCalibration` with every camera's model and intrinsic covariance, rig poses
        and per-view diagnostics.

    Raises:
        BadInputError: malformed input (too few points in a view, non-planar target, unknown names).
        NotObservableError: the data cannot determine some unknowns (fronto-parallel views, a camera
            sharing no station with the others), naming them.
    """
    p = _prepare(cell, obs, options)
    return _finish_all({0: _solve_prepared(cell, obs, options, p, _run_one(p, _start_arrays(p)))}, options)[0]


def calibrate_cameras_batch(
    cell: CellSpec,
    observations: Sequence[Observations],
    options: CameraCalibrationOptions = CameraCalibrationOptions(),
    *,
    raise_errors: bool = True,
    batch_size: int | None = None,
) -> list[CameraCalibration | Exception]:
    """Calibrate many data sets of one cell (e.g. a Monte-Carlo study) with one vmapped solve.

    Every data set is laid out on the host (and initialised there, unless the jitted solve starts
    it with its own closed form, see the module docstring), padded to the largest bucket of the batch, and all are solved by ``jax.vmap`` of the same jitted function as
    :func:`calibrate_cameras` (one compilation per cell and padded shape). Data sets that need a
    re-seeded view or outlier rejection are re-solved one by one afterwards. Results equal
    :func:`calibrate_cameras` on each data set to solver tolerance.

    Args:
        cell: the cell (free cameras, one planar target).
        observations: data sets, each an :class:`Observations` of that cell.
        options: :class:`CameraCalibrationOptions`, shared.
        raise_errors: raise the first data set's error (default); ``False`` returns the exception
            (``BadInputError`` / ``NotObservableError``) in that data set's place instead.
        batch_size: data sets per vmapped call (the last call is filled with copies); default
            :func:`jcalib.solve.batch_width`: 8 on the CPU, all of them on a GPU.

    Returns:
        One :class:`CameraCalibration` (or exception) per data set, in order.
    """
    if len(observations) == 0:
        raise BadInputError("observations: got an empty list, expected at least one data set")
    if batch_size is not None and (not isinstance(batch_size, int) or batch_size < 1):
        raise BadInputError(f"batch_size: got {batch_size!r}, expected a positive integer or None (automatic)")
    results: list = [None] * len(observations)
    prepared = []
    for i, obs in enumerate(observations):
        try:
            p = _prepare(cell, obs, options)
            prepared.append((i, p, _start_arrays(p)))
        except (BadInputError, NotObservableError) as err:
            if raise_errors:
                raise
            results[i] = err
    # one vmapped call per (config, padded shape) group; pad groups to a common shape first
    groups: dict = {}
    for i, p, a in prepared:
        groups.setdefault(p.config, []).append((i, p, a))
    for members in groups.values():
        Vp = max(p.num_views_padded for _, p, _ in members)
        Kp = tuple(max(k) for k in zip(*(p.num_obs_padded for _, p, _ in members)))
        fixed = []
        for i, p, a in members:
            if (p.num_views_padded, p.num_obs_padded) != (Vp, Kp):
                p.num_views_padded, p.num_obs_padded = Vp, Kp
                a = _start_arrays(p)
            fixed.append((i, p, a))
        # calls of `width` data sets (the last one filled with copies): one compiled shape; 8 on
        # XLA:CPU, the whole group on an accelerator (jcalib.solve.batch_width)
        width = batch_size or batch_width(len(fixed))
        outs = []
        for start in range(0, len(fixed), width):
            part = fixed[start:start + width]
            part = part + [part[0]] * (width - len(part))
            stacked = {k: np.stack([a[k] for _, _, a in part]) for k in part[0][2]}
            outs.append(jax.device_get(_core_batch_jit(fixed[0][1].config, stacked)))
        flat = [jax.tree.flatten(out) for out in outs]  # once per call, not per member
        for j, (i, p, a) in enumerate(fixed):
            try:
                leaves, treedef = flat[j // width]
                o = _outcome(p, a, jax.tree.unflatten(treedef, [x[j % width] for x in leaves]))
                if o.start_ok:
                    _raise_if_unobservable(p, o)
                results[i] = _solve_prepared(cell, observations[i], options, p, o)
            except (BadInputError, NotObservableError) as err:
                if raise_errors:
                    raise
                results[i] = err
    finals = {i: r for i, r in enumerate(results) if isinstance(r, tuple)}  # refined, not yet finished
    if finals:
        for i, r in _finish_all(finals, options, raise_errors).items():
            results[i] = r
    return results


def _adjoint_rot_first(T: np.ndarray) -> np.ndarray:
    """Covariance map for inversion under right perturbation, tangent order (rot, trans).

    If ``T' = T · Exp(δ)`` then ``T'^-1 = T^-1 · Exp(-Ad(T) δ)``, with ``Ad(T) = [[R, 0], [t^ R, R]]``
    in (rot, trans) order. The sign does not matter for a covariance.
    """
    R, t = T[:3, :3], T[:3, 3]
    t_hat = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[3:, 3:] = R
    Ad[3:, :3] = t_hat @ R
    return Ad
