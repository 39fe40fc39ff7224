"""One result assembler: the final solve of any cell -> :class:`Calibration` and the result file.

Covariances are the solve's sampling noise (every kind of measurement noise propagated to first
order, with each kind's variance component), not model error. What was not estimated is said so:
every transform lists the tangent coordinates it ``calibrated``; a tool's orientation is
``"calibrated"`` (tilt of its axis estimated; the rotation about the axis held at the convention
"smallest rotation from the flange z to the axis"), ``"given"`` (the cell's ``orientation``/``axis``)
or ``"not calibrated"`` (identity, held).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jcalib.geometry.se3 import log_se3
from jcalib.problems.kinematics import forward_batch
from jcalib.geometry.cameras import AbstractCameraModel
from jcalib.problems.build import CORNER_KINDS, Built, kinematic_prior_sigma, se3_matrix
from jcalib.problems.graph import FREE, Graph
from jcalib.problems.lens import lens_result
from jcalib.problems.outcome import outcome_warnings
from jcalib.problems.refine import Refined, residuals
from jcalib.problems.start import Start
from jcalib.geometry.se3 import rotation_z_to
from jcalib.problems.tools import given_orientation


@dataclass
class Calibration:
    """The outcome of a calibration (see :class:`jcalib.Result` for the file form). Metres, radians, pixels.

    Attributes:
        cameras: camera id -> calibrated model; ``intrinsics_covariance``: camera id -> ``(p, p)``
            covariance of ``model.params`` (zero where fixed).
        transforms: name (``T_flange_cam0``, ``T_base_board``, ``T_flange_torch``, ``T_world_r2``,
            ``T_cam0_cam1`` in a rig) -> ``(4, 4)``; ``transform_covariance``: name -> ``(6, 6)``
            right-perturbation covariance (rx..tz); ``calibrated``: name -> estimated coordinates;
            ``tool_orientation``: tool -> ``"calibrated"``, ``"given"`` or ``"not calibrated"``.
        points, point_covariance: cell point -> ``(3,)`` in ``frame``, ``(3, 3)``.
        warps, warp_covariance: target -> ``(2,)`` board warp ``(c0, c1)`` (m, mrcal's parabolic
            definition, :func:`jcalib.residuals.reprojection.warped_reprojection`), ``(2, 2)`` m², for the
            targets whose warp was estimated.
        frame: ``"base"``, ``"world"`` or the reference camera of a rig.
        station_ids: the used stations; ``flange_poses``: robot -> ``{"station_ids", "measured"
            (n, 4, 4), "estimated" (n, 4, 4)}``.
        T_cam_target: station id -> camera id -> ``(4, 4)`` target pose at the estimate, for every view.
        view_rms_px: ``(camera, station id)`` -> RMS of the view's inlier corners (per point);
            ``view_rms_px_per_coordinate``: the same per coordinate; view_noise: ``(camera,
            station id)`` -> the view's noise factor on its kind's σ² (:mod:`jcalib.problems.refine`).
        residuals: factor group -> ``(n, m)`` final residuals of its observations (kind's unit);
            weights: factor group -> ``(n,)`` (0 = rejected).
        rms: kind (``corner``, ``tip``, ``axis``, ``contact``, ``pose_rotation``, ``pose_translation``)
            -> root mean square of its inlier residuals' norms (per point, as OpenCV's RMS);
            ``rms_per_coordinate``: the same kinds, RMS of the residuals' coordinates (per coordinate, as mrcal
            prints: ``per point / √2`` for 2-D residuals when x and y errors are alike); ``sigma_px``:
            a-posteriori corner noise per coordinate.
        outliers, reseeded_views, variance_components, robot (robot -> accuracy statistics with the
            pose model), warnings, start (transform -> closed-form start), start_method, inits and
            motions (hand-eye closed forms and motion analyses), unobservable_fixed, priors.
        joint_covariance: ``{"names", "dims", "matrix"}`` of every shared unknown (intrinsics, transforms).
        status, iterations, sigma2, num_residuals, pose_model: solver facts.
        solution, graph, built: the :class:`jcalib.solve.Solution` and how it was built (for the report).
        kinematics: robot -> its calibrated kinematics (:func:`kinematic_result`), for the robots whose
            kinematic parameters were estimated.
        lenses: camera -> its zoom lens's result entry (:func:`jcalib.problems.lens.lens_result`).
        covariance_noise: how the covariances read the solution: ``"a_posteriori"`` (scaled by its
            ``sigma2``) or ``"stated"`` (its factor groups' σ, which carry the variance components).
    """

    cameras: dict[str, AbstractCameraModel]
    intrinsics_covariance: dict[str, np.ndarray]
    transforms: dict[str, np.ndarray]
    transform_covariance: dict[str, np.ndarray]
    calibrated: dict[str, list[str]]
    tool_orientation: dict[str, str]
    points: dict[str, np.ndarray]
    point_covariance: dict[str, np.ndarray]
    warps: dict[str, np.ndarray]
    warp_covariance: dict[str, np.ndarray]
    frame: str
    station_ids: list[str]
    flange_poses: dict[str, dict]
    T_cam_target: dict[str, dict[str, np.ndarray]]
    view_rms_px: dict[tuple[str, str], float]
    view_noise: dict[tuple[str, str], float]
    residuals: dict[str, np.ndarray]
    weights: dict[str, np.ndarray]
    rms: dict[str, float]
    sigma_px: float
    outliers: list[tuple[str, str, int]]
    reseeded_views: list[str]
    variance_components: dict[str, float]
    robot: dict[str, dict]
    warnings: list[str]
    start: dict[str, np.ndarray]
    start_method: dict[str, str]
    inits: dict
    motions: dict
    unobservable_fixed: dict | None
    priors: list[str]
    joint_covariance: dict
    status: str
    iterations: int
    sigma2: float
    num_residuals: int
    pose_model: bool
    solution: object = field(default=None, repr=False)
    graph: object = field(default=None, repr=False)
    built: object = field(default=None, repr=False)
    covariance_noise: str = "a_posteriori"
    kinematics: dict[str, dict] = field(default_factory=dict)
    prediction: dict | None = None
    robot_error_model: dict | None = None
    rms_per_coordinate: dict[str, float] = field(default_factory=dict)
    view_rms_px_per_coordinate: dict[tuple[str, str], float] = field(default_factory=dict)
    lenses: dict[str, dict] = field(default_factory=dict)
    budget: dict | None = None  # the error budget (jcalib.problems.budget)

    @property
    def rms_px(self) -> float:
        """RMS of the inlier corners' reprojection error norms (pixels, OpenCV's RMS), nan without corners."""
        return self.rms.get("corner", self.rms.get("corner_mean", float("nan")))

    @property
    def rms_px_per_coordinate(self) -> float:
        """RMS of the inlier corners' reprojection error coordinates (pixels, mrcal's RMS: over x and y
        separately, from the residuals), nan without corners."""
        c = self.rms_per_coordinate
        return c.get("corner", c.get("corner_mean", float("nan")))

    @property
    def reference_camera(self) -> str:
        return self.frame


def _aspect_tie(cov: np.ndarray, ratio: float, row: int = 1, src: int = 0) -> None:
    """With ``fy = fx / ratio`` the ``fy`` row and column follow ``fx``'s."""
    cov[row, :] = cov[src, :] / ratio
    cov[:, row] = cov[:, src] / ratio
    cov[row, row] = cov[src, src] / ratio**2


def _world_poses(g: Graph, built: Built, values: dict, spec, thing: str, ks: np.ndarray) -> np.ndarray:
    """``(n, 4, 4)`` cell-frame poses of a thing at stations ``ks``, at the estimate."""
    h = g.holder(spec)
    if h == FREE:
        entries = [built.free_entry[thing][int(k)] for k in ks]
        return se3_matrix(values[g.free_name(thing)][entries])
    T = np.broadcast_to(np.eye(4), (len(ks), 4, 4))
    if h is not None:
        b = g.base_name(h)
        if b is not None:
            T = se3_matrix(values[b][0]) @ T
        T = T @ se3_matrix(values[g.flange_name(h)][built.flange_entry[h][ks]])
    m = g.mount_name(spec)
    return T @ se3_matrix(values[m][0]) if m is not None else np.array(T)


def robot_statistics(g: Graph, built: Built, sol, robot: str) -> dict:
    """Robot accuracy from the estimated per-station flange corrections ``δ_k = Log(T_meas⁻¹ T_est)``.

    ``correction_rms_*``: RMS of the corrections per axis; ``a_posteriori_sigma_*``: the stated prior σ
    scaled by ``sqrt(Σ‖S δ‖² / r)``, ``r = 6n − Σ tr(S Σ_k Sᵀ)`` the redundancy of the prior residuals
    (its variance component). Units: ``_m`` metres, ``_deg`` degrees; axes in the flange frame.
    """
    name = g.flange_name(robot)
    spec = g.robot_specs[robot]
    meas = g.flange[robot][g.need[robot]]
    delta = log_se3(np.linalg.inv(meas) @ se3_matrix(sol.values[name]))
    S = built.pose_sqrt_info[robot]
    n = delta.shape[0]
    hat = sol.hat.get(f"prior:{name}", float("nan"))
    if hat == hat:
        redundancy = float(sol.count[f"prior:{name}"] - hat)
    else:  # no traces: from the stated-noise covariance of the flange poses
        C = sol.covariance(name, noise="stated").reshape(n, 6, n, 6)
        C_ii = C[np.arange(n), :, np.arange(n), :]
        rows = int(np.count_nonzero(np.any(S != 0, axis=1)))
        redundancy = float(rows * n - np.einsum("ab,nbc,ac->", S, C_ii, S))
    chi2 = float(np.sum((delta @ S.T) ** 2))
    factor = float(np.sqrt(chi2 / redundancy)) if redundancy > 1e-9 else float("nan")
    prior_t = np.asarray(spec.pose_noise_translation_m, np.float64)
    prior_r = np.zeros(3) if spec.pose_noise_rotation_deg is None else np.asarray(spec.pose_noise_rotation_deg,
                                                                                  np.float64)
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


#: A calibrated kinematic parameter whose σ exceeds this fraction of its prior σ is reported as weakly
#: determined by the data.
WEAK_PRIOR_RATIO = 0.3


def _repeatability(S: np.ndarray, source: str) -> dict:
    """The stated σ of one flange pose (per flange axis) from its square-root information, and its source."""
    sigma = 1.0 / np.diag(S)
    return {"translation_m": sigma[3:].tolist(), "rotation_deg": np.degrees(sigma[:3]).tolist(), "source": source}


def kinematic_result(g: Graph, built: Built, sol, robot: str, noise: str) -> dict:
    """A robot's calibrated kinematics: ``model`` (:class:`~jcalib.geometry.kinematic_models.Kinematics`),
    ``params (P,)`` and their ``covariance (P, P)`` (zero for held parameters; m, rad), ``free``
    ``(P,)`` bool, ``held`` (name -> why), ``repeatability`` (the flange-pose σ per axis and where it came from), and
    the stations' flange corrections against the calibrated model: ``correction_rms_translation_m``
    and ``correction_rms_rotation_deg`` (per flange axis; what the kinematics does not explain)."""
    sel = built.kinematics[robot]
    name = f"kinematics:{robot}"
    model = g.robot_specs[robot].kinematics
    params = np.asarray(sol.values[name][0], np.float64).copy()
    ks = np.flatnonzero(g.need[robot])
    T_model = np.asarray(forward_batch(model, params, g.joints[robot][ks]), np.float64)
    delta = log_se3(np.linalg.inv(T_model) @ se3_matrix(sol.values[g.flange_name(robot)]))
    rms = np.sqrt(np.mean(delta**2, axis=0))
    cov = sol.covariance(name, noise=noise)
    ratio = np.sqrt(np.maximum(np.diag(cov), 0.0)) / kinematic_prior_sigma(model)
    weak = {n: float(x) for n, x, f in zip(model.param_names, ratio, sel.free) if f and x > WEAK_PRIOR_RATIO}
    return {"weak": weak, "model": model, "params": params, "covariance": cov, "free": sel.free.copy(),
            "held": dict(sel.held), "repeatability": _repeatability(built.pose_sqrt_info[robot], built.kinematic_noise[robot]),
            "correction_rms_translation_m": rms[3:].tolist(), "correction_rms_rotation_deg": np.degrees(rms[:3]).tolist()}


def assemble(g: Graph, start: Start, built: Built, r: Refined) -> Calibration:
    """The :class:`Calibration` of the final solve."""
    sol, cell, noise = r.sol, g.cell, r.cov_noise
    vals = sol.values
    res = residuals(built, sol)
    cameras, intr_cov = {}, {}
    for cam in cell.cameras.values():
        if cam.name not in start.models:
            continue
        prm = vals[f"intrinsics:{cam.name}"][0].copy()
        cov = sol.covariance(f"intrinsics:{cam.name}", noise=noise)
        flag, ratio = start.aspects[cam.name]
        if flag:
            prm[1] = prm[0] / ratio
            _aspect_tie(cov, ratio)
        cameras[cam.name] = start.models[cam.name].with_params(prm)
        intr_cov[cam.name] = cov
    transforms = {n: se3_matrix(vals[n][0]) for n in built.transforms}
    tcov = {n: sol.covariance(n, noise=noise) for n in built.transforms}
    tool_orientation = {}
    for tool in cell.tools.values():
        name = f"T_flange_{tool.name}"
        if start.tool_axes.get(tool.name):
            tool_orientation[tool.name] = "calibrated"
            T = transforms[name]
            R_conv = rotation_z_to(T[:3, 2])  # the held rotation about the axis, by convention
            Q = R_conv.T @ T[:3, :3]
            B = np.kron(np.eye(2), Q)
            transforms[name] = np.block([[R_conv, T[:3, 3:]], [np.zeros((1, 3)), np.ones((1, 1))]])
            C = B @ tcov[name] @ B.T
            C[2, :] = C[:, 2] = 0.0  # Q is a rotation about z: the held rotation about the axis stays held
            tcov[name] = C
        else:
            tool_orientation[tool.name] = "given" if given_orientation(tool) is not None else "not calibrated"
    points = {n: vals[f"point:{n}"][0].copy() for n in cell.points}
    point_cov = {n: sol.covariance(f"point:{n}", noise=noise) for n in cell.points}
    warps = {t: vals[f"warp:{t}"][0].copy() for t in built.warps}
    warp_cov = {t: sol.covariance(f"warp:{t}", noise=noise) for t in built.warps}

    joint_names = [(c, f"intrinsics:{c}") for c in cameras] + [(n, n) for n in built.transforms]
    joint_names += [(f"warp:{t}", f"warp:{t}") for t in built.warps]
    joint_names += [(f"kinematics:{rb}", f"kinematics:{rb}") for rb in built.kinematics]
    joint_names = [(a, b) for a, b in joint_names if not sol.layout.eliminate[sol.layout.kind(b)]]
    M = sol.joint_covariance([b for _, b in joint_names], noise=noise)
    dims = [sol.layout.dims[sol.layout.kind(b)] for _, b in joint_names]
    offsets = np.concatenate([[0], np.cumsum(dims)[:-1]]).astype(int)
    for (a, b), o in zip(joint_names, offsets):
        if a in cell.cameras and start.aspects[a][0]:
            ratio = start.aspects[a][1]
            M[o + 1, :] = M[o, :] / ratio
            M[:, o + 1] = M[:, o] / ratio
        if b.startswith("T_flange_") and b[9:] in cell.tools and tool_orientation.get(b[9:]) == "calibrated":
            T = se3_matrix(vals[b][0])
            B = np.eye(M.shape[0])
            B[o:o + 6, o:o + 6] = np.kron(np.eye(2), rotation_z_to(T[:3, 2]).T @ T[:3, :3])
            M = B @ M @ B.T
    joint = {"names": [a for a, _ in joint_names], "dims": dims, "matrix": M}
    lenses = {}
    for c, ls in start.lenses.items():
        mount = g.mount_name(cell.cameras[c])
        names = [f"intrinsics:{c}", f"lens:{c}"] + ([mount] if mount in built.transforms else [])
        C = sol.joint_covariance(names, noise=noise)
        lenses[c] = lens_result(c, ls, cameras[c], vals[f"intrinsics:{c}"][0], vals[f"lens:{c}"][0], C,
                                mount if mount in built.transforms else None)

    # per-view target poses, RMS, residual statistics
    T_cam_target: dict[str, dict[str, np.ndarray]] = {}
    view_rms: dict[tuple[str, str], float] = {}
    view_noise: dict[tuple[str, str], float] = {}
    rms: dict[str, float] = {}
    rms_coordinate: dict[str, float] = {}
    view_rms_coordinate: dict[tuple[str, str], float] = {}
    sq: dict[str, list] = {}
    for gr in built.groups:
        w = r.weights[gr.name] > 0
        sq.setdefault(gr.kind, []).append(np.sum(res[gr.name][w] ** 2, axis=1))
        coordinates = res[gr.name][w].size
        rms_coordinate[gr.kind] = rms_coordinate.get(gr.kind, 0.0) + float(np.sum(res[gr.name][w] ** 2))
        rms_coordinate[f"{gr.kind}#"] = rms_coordinate.get(f"{gr.kind}#", 0.0) + coordinates
        if gr.name in r.views:
            for k, f in zip(gr.stations, r.views[gr.name]):
                view_noise[(gr.key[0], g.station_ids[int(k)])] = float(f)
        if gr.kind not in CORNER_KINDS:
            continue
        c, t = gr.key
        per = np.sum(res[gr.name] ** 2, axis=1) * w
        total = np.bincount(gr.stations, weights=per)
        count = np.bincount(gr.stations, weights=w.astype(float))
        ks = np.asarray(g.pairs[gr.key].views)
        T_ct = np.linalg.inv(_world_poses(g, built, vals, cell.cameras[c], c, ks)) @ _world_poses(
            g, built, vals, cell.targets[t], t, ks)
        for k, T in zip(ks, T_ct):
            sid = g.station_ids[k]
            view_rms[(c, sid)] = float(np.sqrt(total[k] / max(count[k], 1.0))) if count[k] else 0.0
            view_rms_coordinate[(c, sid)] = (float(np.sqrt(total[k] / (count[k] * res[gr.name].shape[1])))
                                             if count[k] else 0.0)
            T_cam_target.setdefault(sid, {})[c] = T
    for kind, parts in sq.items():
        a = np.concatenate([p.reshape(-1) for p in parts])
        rms[kind] = float(np.sqrt(np.mean(a))) if a.size else float("nan")
    rms_coordinate = {k: float(np.sqrt(v / rms_coordinate[f"{k}#"])) if rms_coordinate[f"{k}#"] else float("nan")
                      for k, v in rms_coordinate.items() if not k.endswith("#")}
    corner_factor = r.components.get("corner", sol.sigma2 if r.cov_noise == "a_posteriori" else 1.0)
    if r.cov_noise == "stated" and "corner" not in r.components and g.pairs:
        corner_factor = 1.0

    flange = {}
    for rb in g.used_robots:
        ks = np.flatnonzero(g.need[rb])
        measured = g.flange[rb][ks]
        estimated = se3_matrix(vals[g.flange_name(rb)]) if built.pose_model[rb] else measured.copy()
        flange[rb] = {"station_ids": [g.station_ids[k] for k in ks], "measured": measured, "estimated": estimated}
    robot = {rb: robot_statistics(g, built, sol, rb) for rb in g.used_robots
             if built.pose_model[rb] and rb not in built.kinematics}
    kinematics = {rb: kinematic_result(g, built, sol, rb, noise) for rb in built.kinematics}
    warnings = list(start.warnings)
    for rb, k in kinematics.items():
        if k["weak"]:
            warnings.append(
                f"{g.label(rb)}: the stations barely determine the kinematic parameter(s) "
                f"{', '.join(f'{n} (σ {x:.0%} of the prior)' for n, x in k['weak'].items())}: their estimates lean "
                "on the nominal model's prior; add stations that move every joint through more of its range "
                "(jcalib plan --kind kinematics)")
    warnings += [f"{g.label(rb)} has no observations; its base ({g.base_name(rb)}) is not estimated"
                 for rb in g.robot_names if g.multi and rb not in g.used_robots]
    measured = int(sum(sol.count.get(gr.name, 0) for gr in built.groups))
    warnings += outcome_warnings(sol.status.name.lower(), int(sol.iterations), rms, built.sigma,
                                 max_iterations=int(sol.options.max_iterations), num_measurements=measured,
                                 num_free=int(sol.num_free))
    num_res = int(sum(np.sum(r.weights[gr.name] > 0) * res[gr.name].shape[1] for gr in built.groups))
    return Calibration(
        cameras=cameras, intrinsics_covariance=intr_cov, transforms=transforms, transform_covariance=tcov,
        calibrated=dict(built.calibrated), tool_orientation=tool_orientation, points=points,
        point_covariance=point_cov, warps=warps, warp_covariance=warp_cov, frame=g.frame,
        station_ids=list(g.station_ids), flange_poses=flange,
        T_cam_target=T_cam_target, view_rms_px=view_rms, view_noise=view_noise, residuals=res, weights=r.weights,
        rms=rms, rms_per_coordinate=rms_coordinate, view_rms_px_per_coordinate=view_rms_coordinate,
        sigma_px=float(np.sqrt(corner_factor)) * built.sigma["corner"], outliers=r.outliers,
        reseeded_views=r.reseeded, variance_components=r.components, robot=robot, warnings=warnings,
        start={n: start.known[n] for n in built.transforms if n in start.known},
        start_method={n: start.how.get(n, "known") for n in built.transforms}, inits=dict(start.inits),
        motions=dict(start.motions), unobservable_fixed=start.unobservable_fixed, priors=list(built.priors),
        lenses=lenses, joint_covariance=joint, status=sol.status.name.lower(), iterations=sol.iterations, sigma2=float(sol.sigma2),
        num_residuals=num_res, pose_model=any(built.pose_model.values()), solution=sol, graph=g, built=built,
        covariance_noise=noise, kinematics=kinematics)
