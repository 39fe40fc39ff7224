"""Preset: the TCP from tool tips (and tool axes) seen by fixed cameras, from Python arrays.

:func:`calibrate_tcp` builds the cell (cameras fixed in the base at given poses, one tool, a robot
whose flange poses are exact or under a pose-noise prior) and its observations from arrays and
solves it with the one builder (:func:`jcalib.problems.calibrate.calibrate_cell`): tip pixels are the
reprojection of the tool frame's origin, imaged axis points its z axis, as in every cell. The tip's
closed-form start is the viewing-ray least squares of :mod:`jcalib.problems.tools`, which names what the
poses leave free (rotations about one axis, a tip seen along one viewing direction).

Uncertainty: first-order sampling noise of the tip pixels, the axis points and, with the pose model,
the robot's stated repeatability, each kind with its own a-posteriori variance component
(:mod:`jcalib.problems.refine`); not model error (tip-detection bias, robot errors beyond the stated
repeatability, a wrong lens model).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.cameras import AbstractCameraModel
from jcalib.geometry.se3 import as_pose_matrices
from jcalib.io.cell import CameraSpec, CellSpec, RobotSpec, ToolSpec
from jcalib.io.observations import Detection, Observations, Station
from jcalib.problems.build import se3_params
from jcalib.problems.calibrate import calibrate_cell
from jcalib.problems.options import CalibrationOptions

__all__ = ["MIN_TCP_POSES", "TCPCalibration", "calibrate_tcp"]

#: Fewest flange poses :func:`calibrate_tcp` accepts (the thesis' three-pose method is the minimum
#: that determines the tip without knowing where the camera is).
MIN_TCP_POSES = 3

_TOOL = "tcp"


@dataclass
class TCPCalibration:
    """Result of :func:`calibrate_tcp` (metres, radians, pixels).

    Attributes:
        T_flange_tcp: ``(4, 4)`` the TCP in the flange frame: origin the tool tip; z axis the tool axis
            when ``axis_lines`` were given (the rotation about it by the convention "smallest rotation
            from the flange z"), else the flange's orientation (not calibrated).
        p_flange_tip: ``(3,)`` tip in the flange frame; ``tip_covariance``: ``(3, 3)`` in the flange frame.
        axis_flange: ``(3,)`` unit tool axis in the flange frame, or None without ``axis_lines``;
            ``axis_covariance``: ``(3, 3)`` (rank 2), or None.
        camera_names, cameras: the cameras (estimated intrinsics where they were free);
            ``intrinsics_covariance``: per camera ``(p, p)``.
        T_base_cam: ``(C, 4, 4)``; ``T_base_cam_covariance``: ``(C, 6, 6)`` (rx..tz; rad², m²).
        T_base_flange: ``(N, 4, 4)`` estimated flange poses (the measured ones without the pose model).
        residuals_px: ``(N, C, 2)`` tip residuals (predicted − observed), NaN where not seen;
            ``axis_residuals_px``: ``(N, C, L)`` axis-point distances, NaN where missing (or None).
        rms_px: RMS of the tip residual coordinates; ``sigma2``: the tips' variance factor.
        noise, p_flange_tip_init, pose_model, iterations, status, calibration (the whole
            :class:`jcalib.problems.assemble.Calibration`), solution.
    """

    T_flange_tcp: np.ndarray
    p_flange_tip: np.ndarray
    tip_covariance: np.ndarray
    axis_flange: np.ndarray | None
    axis_covariance: np.ndarray | None
    camera_names: list[str]
    cameras: list[AbstractCameraModel]
    intrinsics_covariance: list[np.ndarray]
    T_base_cam: np.ndarray
    T_base_cam_covariance: np.ndarray
    T_base_flange: np.ndarray
    residuals_px: np.ndarray
    axis_residuals_px: np.ndarray | None
    rms_px: float
    sigma2: float
    noise: str
    p_flange_tip_init: np.ndarray
    pose_model: bool
    iterations: int
    status: str
    calibration: object = field(default=None, repr=False)
    solution: object = field(default=None, repr=False)

    @property
    def tip_std_mm(self) -> np.ndarray:
        """``(3,)`` standard deviations of the tip in the flange frame, mm."""
        return 1e3 * np.sqrt(np.diag(self.tip_covariance))

    @property
    def axis_std_deg(self) -> float | None:
        """RMS tilt uncertainty of the tool axis, degrees (``sqrt(trace(axis_covariance))``), or None."""
        if self.axis_covariance is None:
            return None
        return float(np.degrees(np.sqrt(max(np.trace(self.axis_covariance), 0.0))))


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _prior_sqrt_info(cov, name: str, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """``(S, held)``: square-root information of a prior covariance and the coordinates it holds.

    A diagonal ``inf`` is "no prior on this coordinate" (a zero row of ``S``), a zero variance is
    "known exactly" (held fixed); the finite block must be symmetric positive definite.
    """
    C = np.asarray(cov, dtype=np.float64)
    if C.shape != (dim, dim) or np.isnan(C).any():
        raise BadInputError(f"{name}: expected a ({dim}, {dim}) covariance (inf on the diagonal = no prior), "
                            f"got shape {C.shape}")
    d = np.diag(C)
    if np.any(d < 0.0):
        raise BadInputError(f"{name}: expected a symmetric positive-definite covariance (0 on the diagonal = known "
                            f"exactly, inf = no prior), got negative variances {d[d < 0.0].tolist()}")
    held = d == 0.0
    fin = np.isfinite(d) & ~held
    S = np.zeros((dim, dim))
    if fin.any():
        B = C[np.ix_(fin, fin)]
        try:
            L = np.linalg.cholesky(0.5 * (B + B.T))
        except np.linalg.LinAlgError:
            raise BadInputError(f"{name}: expected a symmetric positive-definite covariance (finite block), "
                                f"got {B.tolist()}") from None
        S[np.ix_(fin, fin)] = np.linalg.inv(L)
    return S, held


def _pixels(x, name: str, n: int, c: int, extra: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    want = (n, c) + extra + (2,)
    if c == 1 and arr.shape == (n,) + extra + (2,):
        arr = arr[:, None]
    if arr.shape != want:
        raise BadInputError(f"{name}: expected shape {want} (poses, cameras{', points' if extra else ''}, xy px; NaN "
                            f"where not seen), got {arr.shape}")
    if np.isinf(arr).any():
        raise BadInputError(f"{name}: contains inf; expected finite pixels or NaN for a missing detection")
    return arr


def calibrate_tcp(
    cameras,
    T_base_cam,
    T_base_flange,
    tip_pixels,
    *,
    axis_lines=None,
    free_intrinsics: bool | Sequence[str] = False,
    free_camera_pose: bool = False,
    intrinsics_covariance=None,
    T_base_cam_covariance=None,
    pose_noise_translation_m: float | None = None,
    pose_noise_rotation_deg: float | None = None,
    sigma_px: float = 0.25,
    axis_sigma_px: float = 0.5,
    T_flange_tcp0=None,
    noise: str = "a_posteriori",
    camera_names: Sequence[str] | None = None,
    max_iterations: int = 100,
) -> TCPCalibration:
    """Calibrate the TCP from tool-tip detections in fixed cameras, jointly with what else is free.

    Args:
        cameras: one camera model or a sequence of ``C`` (:mod:`jcalib.geometry.cameras`).
        T_base_cam: ``(4, 4)`` or ``(C, 4, 4)`` camera poses in the base frame, m (start values when
            ``free_camera_pose``).
        T_base_flange: ``(N, 4, 4)`` (or ``(N, 7)``) measured flange poses, m, ``N >= 3``.
        tip_pixels: ``(N, C, 2)`` (or ``(N, 2)`` for one camera) tip pixels, NaN where not seen.
        axis_lines: optional ``(N, C, L, 2)`` (or ``(N, L, 2)``) points on the imaged tool axis, px, NaN
            where missing: the tool axis direction is estimated too.
        free_intrinsics: False, True (all) or the names of the free intrinsics (every camera).
        free_camera_pose: estimate ``T_base_cam``.
        intrinsics_covariance: optional per camera ``(p, p)`` prior covariance of ``model.params`` on the
            free intrinsics; zero variance holds a parameter, ``inf`` leaves it free without a prior.
        T_base_cam_covariance: optional ``(C, 6, 6)`` prior covariance of the camera poses (rx..tz;
            rad², m²) when ``free_camera_pose``; ``inf`` on the diagonal: no prior on that coordinate.
        pose_noise_translation_m: robot repeatability per axis of the flange position (m): turns on
            the per-pose robot correction model. ``pose_noise_rotation_deg``: per axis of the flange
            orientation (degrees); None holds each pose's orientation exact.
        sigma_px, axis_sigma_px: tip and axis-point noise, px.
        T_flange_tcp0: optional ``(4, 4)`` start instead of the viewing-ray closed form.
        noise: ``"a_posteriori"`` (variance components) or ``"stated"``.
        camera_names: names for messages and results (default ``cam0``, ``cam1``, ...).
        max_iterations: LM iteration limit.

    Raises:
        BadInputError: malformed input (shapes, NaN poses, unknown intrinsic names).
        NotObservableError: fewer than 3 poses with a detected tip, rotations about one axis only, a
            tip seen along one direction only, or unknowns the engine finds undetermined.
    """
    cams = [cameras] if isinstance(cameras, AbstractCameraModel) else list(cameras)
    if not cams or not all(isinstance(c, AbstractCameraModel) for c in cams):
        raise BadInputError(f"cameras: expected a camera model or a non-empty sequence of them, got "
                            f"{type(cameras).__name__}")
    n_cam = len(cams)
    names = [f"cam{i}" for i in range(n_cam)] if camera_names is None else [str(s) for s in camera_names]
    if len(names) != n_cam or len(set(names)) != n_cam:
        raise BadInputError(f"camera_names: expected {n_cam} distinct names, got {camera_names!r}")
    Tc = as_pose_matrices(T_base_cam, "T_base_cam")
    if Tc.shape[0] != n_cam:
        raise BadInputError(f"T_base_cam: expected {n_cam} poses (one per camera), got {Tc.shape[0]}")
    Tf = as_pose_matrices(T_base_flange, "T_base_flange")
    n = Tf.shape[0]
    px = _pixels(tip_pixels, "tip_pixels", n, n_cam, ())
    seen = np.isfinite(px).all(axis=-1)
    lines = None
    if axis_lines is not None:
        arr = np.asarray(axis_lines, dtype=np.float64)
        lines = _pixels(arr, "axis_lines", n, n_cam, (arr.shape[-2] if arr.ndim >= 3 else 0,))
    if int(seen.any(axis=1).sum()) < MIN_TCP_POSES:
        raise NotObservableError(
            f"calibrate_tcp: the tip is detected at {int(seen.any(axis=1).sum())} pose(s); at least {MIN_TCP_POSES} "
            "rotated about two different axes are needed", ["TCP offset (too few poses with a detected tip)"])
    if pose_noise_rotation_deg is not None and pose_noise_translation_m is None:
        raise BadInputError("pose_noise_rotation_deg: given without pose_noise_translation_m; state both")
    for nm, val in (("pose_noise_translation_m", pose_noise_translation_m),
                    ("pose_noise_rotation_deg", pose_noise_rotation_deg)):
        if val is not None and not (np.isfinite(val) and val > 0):
            raise BadInputError(f"{nm}: expected a positive σ or None, got {val!r}")

    # --- the cell: cameras fixed in the base, one tool, one robot
    if free_intrinsics is True:
        free_names = None
    elif free_intrinsics is False or free_intrinsics is None:
        free_names = ()
    else:
        free_names = tuple(free_intrinsics)
    icov = None if intrinsics_covariance is None else list(intrinsics_covariance)
    if icov is not None and len(icov) != n_cam:
        raise BadInputError(f"intrinsics_covariance: expected {n_cam} matrices (one per camera), got {len(icov)}")
    ccov = None
    if T_base_cam_covariance is not None:
        ccov = np.asarray(T_base_cam_covariance, np.float64).reshape(-1, 6, 6)
        if ccov.shape[0] != n_cam:
            raise BadInputError(f"T_base_cam_covariance: expected shape ({n_cam}, 6, 6), got "
                                f"{np.shape(T_base_cam_covariance)}")
    specs, priors, fixed = {}, {}, []
    for c, (cam, name) in enumerate(zip(cams, names)):
        pnames = tuple(cam.param_names)
        if free_names is not None:
            unknown = sorted(set(free_names) - set(pnames))
            if unknown:
                raise BadInputError(f"free_intrinsics: got {unknown} for camera '{name}', expected names from "
                                    f"{list(pnames)}")
        held = np.array([free_names is not None and p not in free_names for p in pnames])
        if icov is not None and not held.all():
            C = np.asarray(icov[c], np.float64)
            if C.shape != (len(pnames), len(pnames)):
                raise BadInputError(f"intrinsics_covariance[{c}]: expected shape ({len(pnames)}, {len(pnames)}), got "
                                    f"{C.shape}")
            C = C.copy()
            C[held, :] = 0.0
            C[:, held] = 0.0
            C[held, held] = np.inf
            S, zero = _prior_sqrt_info(C, f"intrinsics_covariance[{c}]", len(pnames))
            held = held | zero
            priors[name] = (np.asarray(cam.params, np.float64), S)
        K, dist = (np.asarray(a, np.float64) for a in cam.to_opencv())
        specs[name] = CameraSpec(name=name, model=cam.name, mount="base", skew=bool(cam.has_skew),
                                 fix=tuple(p for p, h in zip(pnames, held) if h), K=K, dist=dist, pose=Tc[c])
        if free_camera_pose:
            if ccov is not None:
                S, zero = _prior_sqrt_info(ccov[c], f"T_base_cam_covariance[{c}]", 6)
                if zero.any():
                    raise BadInputError(f"T_base_cam_covariance[{c}]: a zero variance; give the camera pose as known "
                                        "(free_camera_pose=False) or a positive σ")
                priors[f"T_base_{name}"] = (se3_params(Tc[c]), S)
        else:
            fixed.append(name)
    robot = RobotSpec(
        pose_noise_translation_m=None if pose_noise_translation_m is None else np.full(3, float(pose_noise_translation_m)),
        pose_noise_rotation_deg=None if pose_noise_rotation_deg is None else np.full(3, float(pose_noise_rotation_deg)))
    cell = CellSpec(cameras=specs, targets={}, tools={_TOOL: ToolSpec(_TOOL, tuple(names))}, robot=robot,
                    fixed=tuple(fixed), source="calibrate_tcp")
    stations = []
    for i in range(n):
        dets = []
        for c, name in enumerate(names):
            if not seen[i, c]:
                continue
            axis = None
            if lines is not None:
                pts = lines[i, c][np.isfinite(lines[i, c]).all(axis=-1)]
                axis = pts if len(pts) else None
            dets.append(Detection(camera=name, tool=_TOOL, pixels=px[i, c][None], axis=axis))
        stations.append(Station(id=f"pose{i}", detections=tuple(dets), T_base_flange=Tf[i]))
    obs = Observations(cameras={nm: tuple(int(v) for v in cam.image_size) for nm, cam in zip(names, cams)},
                       targets={}, stations=tuple(stations), source="calibrate_tcp")
    options = CalibrationOptions(sigma_px=sigma_px, tip_sigma_px=sigma_px, axis_sigma_px=axis_sigma_px, noise=noise,
                                 outlier_threshold=None, max_iterations=max_iterations)
    known = {f"T_flange_{_TOOL}": as_pose_matrices(T_flange_tcp0, "T_flange_tcp0")[0]} if T_flange_tcp0 is not None \
        else None
    try:
        cal = calibrate_cell(cell, obs, options, priors=priors, known=known)
    except NotObservableError as err:
        raise NotObservableError(f"calibrate_tcp: {err}", err.unknowns) from None
    return _result(cal, names, n, n_cam, seen, lines, noise)


def _result(cal, names, n, n_cam, seen, lines, noise) -> TCPCalibration:
    tname = f"T_flange_{_TOOL}"
    T = cal.transforms[tname]
    C = cal.transform_covariance[tname]
    R = T[:3, :3]
    tip_cov = R @ C[3:, 3:] @ R.T
    axis = axis_cov = None
    if cal.tool_orientation[_TOOL] == "calibrated":
        axis = R[:, 2].copy()
        A = R @ _skew(np.array([0.0, 0.0, 1.0])) @ C[:3, :3] @ _skew(np.array([0.0, 0.0, 1.0])).T @ R.T
        axis_cov = 0.5 * (A + A.T)
    pose_index = np.asarray([int(s[4:]) for s in cal.station_ids])
    res = np.full((n, n_cam, 2), np.nan)
    axis_res = None if lines is None else np.full(lines.shape[:3], np.nan)
    for gr in cal.built.groups:
        c = names.index(gr.key[0])
        poses = pose_index[gr.stations]
        if gr.kind == "tip":
            res[poses, c] = cal.residuals[gr.name]
        elif gr.kind == "axis" and axis_res is not None:
            for p in np.unique(poses):
                ok = np.flatnonzero(np.isfinite(lines[p, c]).all(axis=-1))
                axis_res[p, c, ok] = cal.residuals[gr.name][poses == p, 0]
    fl = cal.flange_poses[next(iter(cal.flange_poses))]
    T_bf = np.full((n, 4, 4), np.nan)
    T_bf[pose_index] = fl["estimated"]
    start = cal.start[tname] if tname in cal.start else T
    factor = cal.variance_components.get("tip", cal.sigma2 if noise == "a_posteriori" else 1.0)
    return TCPCalibration(
        T_flange_tcp=T, p_flange_tip=T[:3, 3].copy(), tip_covariance=0.5 * (tip_cov + tip_cov.T), axis_flange=axis,
        axis_covariance=axis_cov, camera_names=list(names), cameras=[cal.cameras[nm] for nm in names],
        intrinsics_covariance=[cal.intrinsics_covariance[nm] for nm in names],
        T_base_cam=np.stack([cal.transforms[f"T_base_{nm}"] for nm in names]),
        T_base_cam_covariance=np.stack([cal.transform_covariance[f"T_base_{nm}"] for nm in names]),
        T_base_flange=T_bf, residuals_px=res, axis_residuals_px=axis_res,
        rms_px=float(np.sqrt(np.nanmean(res**2))), sigma2=float(factor), noise=noise,
        p_flange_tip_init=np.asarray(start)[:3, 3].copy(), pose_model=cal.pose_model, iterations=cal.iterations,
        status=cal.status, calibration=cal, solution=cal.solution)

