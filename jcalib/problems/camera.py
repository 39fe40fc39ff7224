"""Camera calibration: one or more rigidly mounted cameras seeing a free-moving planar target.

Unknowns: the intrinsics of every camera (any lens model of :mod:`jcalib.geometry.cameras`), the
pose of the target at every station in the reference camera (``T_ref_target``, eliminated by Schur
complement), and the pose of the reference camera in every other camera (``T_cam_ref``, the rig).
Residuals: target-corner reprojection errors in pixels. Closed forms start it (Zhang per camera,
planar PnP per view, rig poses by rotation averaging); jcalib's engine refines it and gives the
covariance. OpenCV serves nothing but a per-view PnP inside the initialiser.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import conversions, lie
from jcalib.geometry.cameras import AbstractCameraModel, camera_model_from_name
from jcalib.init import planar_pnp, zhang_init
from jcalib.io.cell import CellSpec
from jcalib.io.observations import Observations
from jcalib.residuals.losses import CauchyLoss, HuberLoss, TrivialLoss
from jcalib.solve import SE3, Euclidean, FactorGroup, Problem, SolveOptions, Variable, solve

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
    if not np.allclose(points[:, 2], 0.0):
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
    if cd.K0 is not None:
        K, dist_given = cd.K0, (cd.dist0 if cd.dist0 is not None else np.zeros(0))
    else:
        principal_point = None
        if "cx" in cd.fix and "cy" in cd.fix:
            principal_point = ((cd.image_size[0] - 1) / 2, (cd.image_size[1] - 1) / 2)
        z = zhang_init(
            [p[:, :2] for p in cd.points],
            cd.pixels,
            skew=cd.skew,
            aspect_ratio=1.0 if "aspect" in cd.fix else None,
            principal_point=principal_point,
            image_size=cd.image_size,
            view_names=[f"{cd.name} view {i}" for i in range(n_views)],
        )
        K = z.K
        dist_given = np.asarray(z.dist_opencv) if cd.model_name not in ("pinhole", "fisheye") else np.zeros(0)
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


def _loss(options: CameraCalibrationOptions):
    if options.loss == "huber":
        return HuberLoss(options.loss_scale)
    if options.loss == "cauchy":
        return CauchyLoss(options.loss_scale)
    return TrivialLoss()


# ------------------------------------------------------------------------------------ problem


def _build_problem(data, models, fixed_masks, aspects, T_ref_target, T_cam_ref, weights, options, ref):
    variables = [
        Variable(
            "T_ref_target",
            SE3(),
            np.stack([_se3_params(T) for T in T_ref_target]),
            eliminate=True,
            entry_label="station {i} target pose",
        ),
        Variable(
            "T_cam_ref",
            SE3(),
            np.stack([_se3_params(T_cam_ref[cd.name]) for cd in data]),
            fixed=np.array([[cd.name == ref] * 6 for cd in data]),
            entry_label="rig pose of camera {i}",
        ),
    ]
    factors = []
    for ci, cd in enumerate(data):
        model = models[cd.name]
        variables.append(
            Variable(
                f"intrinsics:{cd.name}",
                Euclidean(len(model.param_names)),
                np.asarray(model.params),
                fixed=fixed_masks[cd.name],
                coord_names=list(model.param_names),
                entry_label=cd.name,
            )
        )
        num = sum(p.shape[0] for p in cd.points)
        station = np.concatenate([np.full(p.shape[0], s) for s, p in zip(cd.stations, cd.points)])
        flag, ratio = aspects[cd.name]
        factors.append(
            FactorGroup(
                f"reprojection:{cd.name}",
                _reprojection_fn(type(model), tuple(model.image_size), bool(model.has_skew)),
                (f"intrinsics:{cd.name}", "T_cam_ref", "T_ref_target"),
                (np.zeros(num, np.int32), np.full(num, ci, np.int32), station.astype(np.int32)),
                (
                    np.concatenate(cd.points),
                    np.concatenate(cd.pixels),
                    np.broadcast_to(np.array([flag, ratio]), (num, 2)).copy(),
                ),
                sigma=options.sigma_px,
                sqrt_weight=weights[cd.name],
                loss=_loss(options),
            )
        )
    return Problem(variables, factors)


@eqx.filter_jit
def _factor_residuals(f: FactorGroup, values: dict):
    rows = [values[a][idx] for a, idx in zip(f.args, f.indices)]
    return jax.vmap(f.fn)(*rows, f.observations)


def _residuals(problem: Problem, values: dict) -> dict[str, np.ndarray]:
    """Unwhitened residuals (pixels) of every reprojection factor group at ``values``."""
    return {
        f.name.split(":", 1)[1]: np.asarray(_factor_residuals(f, values))
        for f in problem.factors
        if f.name.startswith("reprojection:")
    }


def calibrate_cameras(
    cell: CellSpec, obs: Observations, options: CameraCalibrationOptions = CameraCalibrationOptions()
) -> CameraCalibration:
    """Calibrate the free cameras of ``cell`` from target detections ``obs``.

    Returns:
        A :class:`CameraCalibration` with every camera's model and intrinsic covariance, rig poses
        and per-view diagnostics.

    Raises:
        BadInputError: malformed input (too few points in a view, non-planar target, unknown names).
        NotObservableError: the data cannot determine some unknowns (fronto-parallel views, a camera
            sharing no station with the others), naming them.
    """
    data, target_name, _, station_ids = _gather(cell, obs)
    ref = options.reference_camera or data[0].name
    if ref not in [cd.name for cd in data]:
        raise BadInputError(f"reference_camera: no camera '{ref}' in the cell")
    data.sort(key=lambda cd: cd.name != ref)  # reference first

    models, poses, fixed_masks, aspects = {}, {}, {}, {}
    for cd in data:
        models[cd.name], poses[cd.name] = _initial_model(cd)
        fixed_masks[cd.name] = _intrinsics_fixed_mask(models[cd.name], cd.fix)
        ratio = 1.0
        if cd.K0 is not None:
            ratio = float(cd.K0[0, 0] / cd.K0[1, 1])
        aspects[cd.name] = (1.0 if "aspect" in cd.fix else 0.0, ratio)
        if "aspect" in cd.fix:
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
    T_ref_target = []
    for k in range(len(used)):
        for cd in data:
            if k in poses[cd.name]:
                T_ref_target.append(np.linalg.inv(T_cam_ref[cd.name]) @ poses[cd.name][k])
                break

    weights = {cd.name: np.ones(sum(p.shape[0] for p in cd.points)) for cd in data}
    solve_options = SolveOptions(max_iterations=options.max_iterations)

    def run(T_ref_target, T_cam_ref, weights):
        problem = _build_problem(data, models, fixed_masks, aspects, T_ref_target, T_cam_ref, weights, options, ref)
        return problem, solve(problem, options=solve_options)

    problem, sol = run(T_ref_target, T_cam_ref, weights)

    def view_rms(problem, values):
        res = _residuals(problem, values)
        out = {}
        for cd in data:
            r = res[cd.name]
            start = 0
            for s, p in zip(cd.stations, cd.points):
                n = p.shape[0]
                w = weights[cd.name][start : start + n]
                rr = r[start : start + n][w > 0]
                out[(cd.name, s)] = float(np.sqrt(np.mean(np.sum(rr**2, axis=1)))) if rr.size else 0.0
                start += n
        return out, res

    reseeded = []
    if options.reseed_views:
        rms, _ = view_rms(problem, sol.values)
        median = float(np.median(list(rms.values())))
        suspects = sorted({s for (c, s), v in rms.items() if v > 3.0 * max(median, 1e-3)})
        if suspects:
            values = {k: np.asarray(v) for k, v in sol.values.items()}
            new_T = [_se3_matrix(p) for p in values["T_ref_target"][: len(used)]]
            for s in suspects:
                cd = next(cd for cd in data if s in cd.stations)
                v = cd.stations.index(s)
                model = models[cd.name].with_params(jnp.asarray(values[f"intrinsics:{cd.name}"][0]))
                K_cv, dist_cv = model.to_opencv()
                if cd.model_name == "fisheye":
                    continue
                cand = planar_pnp(cd.points[v], cd.pixels[v], K_cv, dist_cv if dist_cv.size else None)
                T_cam = _se3_matrix(values["T_cam_ref"][data.index(cd)])
                new_T[s] = np.linalg.inv(T_cam) @ cand.T_cam_target[1]
            for cd in data:
                models[cd.name] = models[cd.name].with_params(jnp.asarray(values[f"intrinsics:{cd.name}"][0]))
            T_cam_ref_now = {cd.name: _se3_matrix(values["T_cam_ref"][i]) for i, cd in enumerate(data)}
            problem2, sol2 = run(new_T, T_cam_ref_now, weights)
            if sol2.cost < sol.cost:
                problem, sol, reseeded = problem2, sol2, [station_ids[used[s]] for s in suspects]

    outliers = []
    if options.outlier_threshold is not None:
        _, res = view_rms(problem, sol.values)
        sigma = float(np.sqrt(sol.sigma2)) * options.sigma_px if options.noise == "a_posteriori" else options.sigma_px
        changed = False
        for cd in data:
            norm = np.linalg.norm(res[cd.name], axis=1)
            bad = norm > options.outlier_threshold * sigma
            if np.any(bad & (weights[cd.name] > 0)):
                weights[cd.name] = np.where(bad, 0.0, weights[cd.name])
                changed = True
                index = np.concatenate(cd.point_index)
                station = np.concatenate([np.full(p.shape[0], s) for s, p in zip(cd.stations, cd.points)])
                outliers += [(cd.name, station_ids[used[station[k]]], int(index[k])) for k in np.flatnonzero(bad)]
        if changed:
            values = {k: np.asarray(v) for k, v in sol.values.items()}
            for cd in data:
                models[cd.name] = models[cd.name].with_params(jnp.asarray(values[f"intrinsics:{cd.name}"][0]))
            problem, sol = run(
                [_se3_matrix(p) for p in values["T_ref_target"][: len(used)]],
                {cd.name: _se3_matrix(values["T_cam_ref"][i]) for i, cd in enumerate(data)},
                weights,
            )

    values = {k: np.asarray(v) for k, v in sol.values.items()}
    noise = "a_posteriori" if options.noise == "a_posteriori" else "stated"
    cameras, intr_cov, T_ref_cam, T_ref_cam_cov = {}, {}, {}, {}
    T_cam_target: dict[str, dict[str, np.ndarray]] = {}
    for i, cd in enumerate(data):
        p = values[f"intrinsics:{cd.name}"][0].copy()
        cov = np.asarray(sol.covariance(f"intrinsics:{cd.name}", noise=noise))
        flag, ratio = aspects[cd.name]
        if flag:
            p[1] = p[0] / ratio
            cov[1, :] = cov[0, :] / ratio
            cov[:, 1] = cov[:, 0] / ratio
            cov[1, 1] = cov[0, 0] / ratio**2
        cameras[cd.name] = models[cd.name].with_params(jnp.asarray(p))
        intr_cov[cd.name] = cov
        T_cr = _se3_matrix(values["T_cam_ref"][i])
        T_ref_cam[cd.name] = np.linalg.inv(T_cr)
        # Cov of T_ref_cam = inv(T_cam_ref): right perturbation maps by -Ad(T_cam_ref).
        cov_cr = np.asarray(sol.covariance("T_cam_ref", index=i, noise=noise))
        Ad = _adjoint_rot_first(T_cr)
        T_ref_cam_cov[cd.name] = Ad @ cov_cr @ Ad.T
        for s in cd.stations:
            T_rt = _se3_matrix(values["T_ref_target"][s])
            T_cam_target.setdefault(station_ids[used[s]], {})[cd.name] = T_cr @ T_rt

    rms, res = view_rms(problem, sol.values)
    all_res = np.concatenate([res[cd.name][weights[cd.name] > 0] for cd in data])
    return CameraCalibration(
        cameras=cameras,
        intrinsics_covariance=intr_cov,
        T_ref_cam=T_ref_cam,
        T_ref_cam_covariance=T_ref_cam_cov,
        T_cam_target=T_cam_target,
        view_rms_px={(c, station_ids[used[s]]): v for (c, s), v in rms.items()},
        residuals_px=res,
        outliers=outliers,
        rms_px=float(np.sqrt(np.mean(np.sum(all_res**2, axis=1)))),
        sigma_px=float(np.sqrt(sol.sigma2)) * options.sigma_px,
        num_residuals=int(all_res.size),
        iterations=int(sol.iterations),
        status=sol.status.name.lower(),
        reference_camera=ref,
        reseeded_views=reseeded,
        solution=sol,
    )


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
