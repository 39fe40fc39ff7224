"""Joint TCP calibration from fixed cameras: the tool tip (and optionally its axis) seen at many flange poses.

One or more cameras are fixed in the cell (pose ``T_base_cam`` in the robot base, known or unknown).
The robot presents the tool at ``N`` flange poses ``T_base_flange_i``; each camera that sees the tip
reports its pixel ``u_ic``. The unknown is the TCP ``T_flange_tcp``: its translation (the tip in the
flange frame, always) and, when the imaged tool axis is given, the direction of the tool axis (the
TCP's z axis; the rotation about it is not observable for a symmetric tool and stays at its start).
The residual of a tip detection is

    project_c( T_base_cam_c⁻¹ · T_base_flange_i · p_flange_tip ) − u_ic          (pixels, 2 per detection)

and of a point ``v`` on the imaged tool axis, its signed distance (pixels) from the image line through
the projections of the tip and of a point ``axis_length_m`` further along the axis (the distortion of
the axis' image over that segment is neglected).

Optional unknowns, each free or fixed, with a Gaussian prior where a covariance is given:

- the intrinsics of each camera (``free_intrinsics``: all or some of ``model.param_names``);
- the camera poses ``T_base_cam`` (``free_camera_pose``);
- the **robot pose error model** (``pose_noise_translation_m`` / ``pose_noise_rotation_deg``): the true
  flange pose of every pose is ``T_meas_i · Exp(δ_i)`` with ``δ_i`` (flange frame, ``rx..tz``) an
  unknown under a zero-mean Gaussian prior of the robot's repeatability, as in
  :mod:`jcalib.problems.handeye`. These per-pose corrections are eliminated by Schur complement. Without
  it the measured poses are taken as exact and robot noise ends up in the a-posteriori pixel σ —
  the covariance is then only as right as the assumption that robot noise looks like pixel noise.

Start: the tip lies on the viewing ray of each detection, ``P_ic (R_i x + t_i − c_c) = 0`` with
``P_ic = I − d_ic d_icᵀ`` the projector across the ray and ``c_c`` the camera centre; this is linear
in ``x`` (and in the camera centres when the camera pose is free: then it is
:func:`jcalib.init.tcp_analytic.tcp_from_camera_ray` generalised to many rays and cameras). The
tool axis starts from the planes through each camera centre and imaged axis line:
``n_icᵀ R_i a = 0``.

Observability is checked on that linear system before the solve and named in words: rotations about
one axis only with a free camera position leave the "TCP offset along the rotation axis" free; a tip
seen along one viewing direction only leaves its depth free; fewer than 3 poses are refused. The
engine's rank check at the solution catches the rest (e.g. free intrinsics the data cannot fix).

Uncertainty: the covariances are first-order sampling noise of the tip pixels (``sigma_px``), the
axis points (``axis_sigma_px``) and, with the pose model, the robot's stated repeatability, scaled by
the a-posteriori variance factor (``noise="a_posteriori"``, default) or not (``"stated"``). They do not
include model error: tip-detection bias, robot absolute-accuracy errors beyond the stated
repeatability, a wrong lens model.

Units: metres, radians, pixels (OpenCV convention).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import conversions, lie
from jcalib.geometry.cameras import AbstractCameraModel
from jcalib.init.pivot import (
    DEFAULT_MIN_ROTATION_DEG,
    as_pose_matrices,
    rotation_spread,
)
from jcalib.solve import (
    SE3,
    Euclidean,
    FactorGroup,
    Problem,
    SolveOptions,
    Status,
    Variable,
    solve,
)

__all__ = ["MIN_TCP_POSES", "TCPCalibration", "calibrate_tcp"]

#: Fewest flange poses :func:`calibrate_tcp` accepts (the thesis' three-pose method is the minimum
#: that determines the tip without knowing where the camera is).
MIN_TCP_POSES = 3

_E_Z = np.array([0.0, 0.0, 1.0])


# ------------------------------------------------------------------------------------ result


@dataclass
class TCPCalibration:
    """Result of :func:`calibrate_tcp` (metres, radians, pixels).

    Attributes:
        T_flange_tcp: ``(4, 4)`` the TCP in the flange frame. Its origin is the tool tip; its z axis
            the tool axis when ``axis_lines`` were given (else the flange's orientation or the
            start's).
        p_flange_tip: ``(3,)`` tip in the flange frame, m.
        tip_covariance: ``(3, 3)`` covariance of ``p_flange_tip`` in the flange frame, m².
        axis_flange: ``(3,)`` unit tool axis in the flange frame, or None without ``axis_lines``.
        axis_covariance: ``(3, 3)`` covariance of ``axis_flange`` (rank 2), or None.
        camera_names: one name per camera.
        cameras: the camera models (with the estimated intrinsics when they were free).
        intrinsics_covariance: per camera ``(p, p)`` covariance of ``model.params`` (zero where fixed).
        T_base_cam: ``(C, 4, 4)`` camera poses (estimated when free), m.
        T_base_cam_covariance: ``(C, 6, 6)`` right-perturbation covariance (rx..tz; rad², m²).
        T_base_flange: ``(N, 4, 4)`` estimated true flange poses (the measured ones without the pose
            model), m.
        residuals_px: ``(N, C, 2)`` tip reprojection residuals (predicted − observed), NaN where the
            camera did not see the tip.
        axis_residuals_px: ``(N, C, L)`` signed distances of the axis points from the projected axis,
            NaN where missing; None without ``axis_lines``.
        rms_px: RMS of the tip residual coordinates.
        sigma2: a-posteriori variance factor (≈ 1 when the stated σ are right).
        noise: ``"a_posteriori"`` or ``"stated"``: how the covariances are scaled.
        p_flange_tip_init: ``(3,)`` the linear start, m.
        pose_model: whether per-pose robot corrections were estimated.
        iterations, status: solver facts.
        solution: the :class:`jcalib.solve.Solution`.
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


# ------------------------------------------------------------------------------------ residuals


@functools.cache
def _tip_fn(model_cls: type, image_size: tuple[int, int], skew: bool):
    """``(intrinsics, T_base_cam, T_flange_tcp, T_base_flange, pixel (2,)) -> (2,)`` px residual.

    One function object per camera configuration, so new data reuse the compiled solver.
    """

    def fn(intrinsics, T_base_cam, T_flange_tcp, T_base_flange, pixel):
        model = model_cls.from_params(image_size, intrinsics, skew=skew)
        p_base = lie.se3_apply(T_base_flange, T_flange_tcp[4:])
        p_cam = lie.se3_apply(lie.se3_inverse(T_base_cam), p_base)
        return model.project(p_cam) - pixel

    return fn


@functools.cache
def _axis_fn(model_cls: type, image_size: tuple[int, int], skew: bool):
    """``(intrinsics, T_base_cam, T_flange_tcp, T_base_flange, (point (2,), length ())) -> (1,)`` px.

    Signed distance of an observed axis point from the image line through the projected tip and the
    projected point ``length`` metres along the TCP z axis. A degenerate line (axis along the
    viewing ray) gives a finite residual with finite derivatives (safe branch).
    """

    def fn(intrinsics, T_base_cam, T_flange_tcp, T_base_flange, obs):
        point, length = obs
        model = model_cls.from_params(image_size, intrinsics, skew=skew)
        T_base_tcp = lie.se3_compose(T_base_flange, T_flange_tcp)
        T_cam_base = lie.se3_inverse(T_base_cam)
        zero = jnp.zeros_like(length)
        p0 = lie.se3_apply(T_cam_base, T_base_tcp[4:])
        p1 = lie.se3_apply(T_cam_base, lie.se3_apply(T_base_tcp, jnp.stack([zero, zero, length])))
        u0 = model.project(p0)
        e = model.project(p1) - u0
        n2 = jnp.sum(e * e)
        ok = n2 > 1e-12
        inv_n = 1.0 / jnp.sqrt(jnp.where(ok, n2, 1.0))
        d = point - u0
        cross = e[0] * d[1] - e[1] * d[0]
        return jnp.where(ok, cross * inv_n, jnp.sqrt(jnp.sum(d * d) + 1e-12))[None]

    return fn


@functools.cache
def _residuals_jit(fn):
    return jax.jit(jax.vmap(fn))


def _tip_of(values: dict) -> jax.Array:
    """Tip in the flange frame ``(3,)`` (module level: one compiled propagation)."""
    return values["T_flange_tcp"][0, 4:]


def _axis_of(values: dict) -> jax.Array:
    """Tool axis (TCP z) in the flange frame ``(3,)``."""
    q = values["T_flange_tcp"][0, :4]
    return lie.quat_rotate(q, jnp.array([0.0, 0.0, 1.0]))


@eqx.filter_jit
def _unproject(camera, pixels):
    return camera.unproject(pixels)


# ------------------------------------------------------------------------------------ helpers


def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{c:.4f}" for c in v) + "]"


def _canonical_sign(v: np.ndarray) -> np.ndarray:
    return v * (1.0 if v[np.argmax(np.abs(v))] > 0 else -1.0)


def _rotation_z_to(a: np.ndarray) -> np.ndarray:
    """Smallest rotation taking the z axis to the unit vector ``a`` (3, 3)."""
    v = np.cross(_E_Z, a)
    s, c = np.linalg.norm(v), float(a @ _E_Z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K * ((1.0 - c) / s**2)


def _pose7(T: np.ndarray) -> np.ndarray:
    return np.asarray(conversions.matrix_to_pose(np.asarray(T, np.float64)))


def _matrix(p) -> np.ndarray:
    return np.asarray(conversions.pose_to_matrix(np.asarray(p, np.float64)))


def _prior_sqrt_info(cov, name: str, dim: int) -> np.ndarray:
    """Square-root information ``S`` (``SᵀS = Σ⁻¹``) of a prior covariance ``(dim, dim)``.

    A diagonal entry of ``inf`` means "no prior on this coordinate" (its row of ``S`` is zero); the
    finite block must be symmetric positive definite.
    """
    C = np.asarray(cov, dtype=np.float64)
    if C.shape != (dim, dim) or np.isnan(C).any():
        raise BadInputError(f"{name}: expected a ({dim}, {dim}) covariance (inf on the diagonal = no prior), "
                            f"got shape {C.shape}")
    fin = np.isfinite(np.diag(C))
    S = np.zeros((dim, dim))
    if fin.any():
        B = C[np.ix_(fin, fin)]
        try:
            L = np.linalg.cholesky(0.5 * (B + B.T))
        except np.linalg.LinAlgError:
            raise BadInputError(
                f"{name}: expected a symmetric positive-definite covariance (finite block), got {B.tolist()}"
            ) from None
        S[np.ix_(fin, fin)] = np.linalg.inv(L)
    return S


def _as_cameras(cameras) -> list[AbstractCameraModel]:
    cams = [cameras] if isinstance(cameras, AbstractCameraModel) else list(cameras)
    if not cams or not all(isinstance(c, AbstractCameraModel) for c in cams):
        raise BadInputError(
            f"cameras: expected a camera model or a non-empty sequence of them "
            f"(jcalib.geometry.cameras), got {type(cameras).__name__}"
        )
    return cams


def _pixel_array(x, name: str, n: int, c: int, extra: tuple[int, ...]) -> np.ndarray:
    """``(N, C, *extra, 2)`` float64 (a missing camera axis is added when C == 1); NaN = missing."""
    arr = np.asarray(x, dtype=np.float64)
    want = (n, c) + extra + (2,)
    if c == 1 and arr.shape == (n,) + extra + (2,):
        arr = arr[:, None]
    if arr.shape != want:
        raise BadInputError(
            f"{name}: expected shape {want} (poses, cameras{', points' if extra else ''}, xy px; NaN where "
            f"not seen), got {arr.shape}"
        )
    if np.isinf(arr).any():
        raise BadInputError(f"{name}: contains inf; expected finite pixels or NaN for a missing detection")
    return arr


# ------------------------------------------------------------------------------------ start + checks


def _ray_system(R, t, rays, cam_of, centres, free_centre: bool):
    """Least-squares system of ``P_k (R_i x + t_i − c) = 0`` over detections ``k = (i, c)``.

    Returns ``(M_x, b_x, x)``: the 3x3 information of ``x`` with the free camera centres eliminated,
    and the linear solution ``x``.
    """
    n_cam = centres.shape[0]
    idx_pose, dirs = rays
    P = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]  # (K, 3, 3)
    Rk = R[idx_pose]
    A_x = np.einsum("kab,kbc->kac", P, Rk)  # (K, 3, 3)
    rhs = -np.einsum("kab,kb->ka", P, t[idx_pose] - centres[cam_of])
    if not free_centre:
        M = np.einsum("kab,kac->bc", A_x, A_x)
        b = np.einsum("kab,ka->b", A_x, rhs)
        x = np.linalg.lstsq(M, b, rcond=None)[0]
        return M, x
    # unknowns (x, δc_0 .. δc_{C-1}); the camera-centre part is eliminated (pseudo-inverse: a camera
    # seeing the tip along one ray cannot place itself along that ray, which does not affect x)
    cols = 3 + 3 * n_cam
    A = np.zeros((rhs.shape[0], 3, cols))
    A[:, :, :3] = A_x
    for k, cc in enumerate(cam_of):
        A[k, :, 3 + 3 * cc: 6 + 3 * cc] = -P[k]
    N = np.einsum("kab,kac->bc", A, A)
    b = np.einsum("kab,ka->b", A, rhs)
    Ncc_pinv = np.linalg.pinv(N[3:, 3:], rcond=1e-10)
    M = N[:3, :3] - N[:3, 3:] @ Ncc_pinv @ N[3:, :3]
    sol = np.linalg.lstsq(N, b, rcond=None)[0]
    return M, sol[:3]


def _check_observable(M, R, rays, n_det, free_centre, min_rotation_deg) -> None:
    """NotObservableError naming the tip directions the linear ray system leaves free."""
    M = 0.5 * (M + M.T) / max(n_det, 1)
    evals, evecs = np.linalg.eigh(M)
    lim = np.deg2rad(min_rotation_deg)
    weak = np.sqrt(np.maximum(evals, 0.0)) < lim
    if not weak.any():
        return
    spread, axes = rotation_spread(R)
    idx_pose, dirs = rays
    P = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
    unknowns = []
    for k in np.flatnonzero(weak):
        v = _canonical_sign(evecs[:, k])
        if spread[-1] < lim and free_centre:
            unknowns = [("TCP offset (all components): the flange does not rotate and the camera position "
                        "is free")]
            break
        if spread[0] < lim and abs(v @ axes[:, 0]) > np.cos(np.deg2rad(10.0)):
            a = _canonical_sign(axes[:, 0])
            unknowns.append(
                f"TCP offset along the rotation axis {_fmt(a)} of the flange (all rotations are about "
                f"one axis{'' if free_centre else ' parallel to the viewing ray'})"
            )
            continue
        across = np.linalg.norm(np.einsum("kab,kbc,c->ka", P, R[idx_pose], v), axis=1)
        if np.max(across) < 0.2:
            unknowns.append(
                f"TCP offset along the viewing ray (depth), {_fmt(v)} of the flange: fewer than 2 distinct "
                "views of the tip (it is seen along one direction only)"
            )
            continue
        unknowns.append(
            f"TCP offset along {_fmt(v)} of the flange"
            + (" (with a free camera position the image measures no distances: motions that are all "
               "rotations about one point leave the scale free; add flange translations)" if free_centre else "")
        )
    raise NotObservableError(
        "calibrate_tcp: the poses and views do not determine the tool tip (RMS spread "
        f"{np.rad2deg(np.sqrt(max(evals[0], 0.0) / 1.0)):.3g} deg < {min_rotation_deg} deg about the weakest "
        "direction): not observable: " + "; ".join(unknowns)
        + ". Rotate the flange about two different axes (across the viewing ray) or add a second view.",
        unknowns,
    )


def _axis_start(R, rays_cam_planes, x) -> np.ndarray:
    """Tool axis in the flange frame from plane normals ``n_k`` (base) of the imaged axis lines."""
    idx_pose, normals = rays_cam_planes
    A = np.einsum("ka,kab->kb", normals, R[idx_pose])
    _, s, Vt = np.linalg.svd(A)
    a = Vt[-1]
    if s.size < 2 or s[-2] < 1e-6 * max(s[0], 1e-300):
        raise NotObservableError(
            "calibrate_tcp: the imaged tool axis lines do not determine the tool axis direction (seen in "
            "fewer than 2 sufficiently different orientations)",
            ["tool axis direction (TCP orientation)"],
        )
    if float(a @ x) < 0.0:  # the axis points from the flange towards the tip
        a = -a
    return a / np.linalg.norm(a)


# ------------------------------------------------------------------------------------ public


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
    axis_length_m: float = 0.05,
    T_flange_tcp0=None,
    noise: str = "a_posteriori",
    camera_names: Sequence[str] | None = None,
    min_rotation_deg: float = DEFAULT_MIN_ROTATION_DEG,
    max_iterations: int = 100,
) -> TCPCalibration:
    """Calibrate the TCP from tool-tip detections in fixed cameras, jointly with what else is free.

    Args:
        cameras: one camera model or a sequence of ``C`` (:mod:`jcalib.geometry.cameras`).
        T_base_cam: ``(4, 4)`` or ``(C, 4, 4)`` camera poses in the base frame, m (the start values
            when ``free_camera_pose``).
        T_base_flange: ``(N, 4, 4)`` (or ``(N, 7)``) measured flange poses, m, ``N >= 3``.
        tip_pixels: ``(N, C, 2)`` (or ``(N, 2)`` for one camera) detected tip pixels, OpenCV
            convention; NaN where a camera did not see the tip.
        axis_lines: optional ``(N, C, L, 2)`` (or ``(N, L, 2)``) points on the imaged tool axis, px,
            NaN where missing; turns on the estimation of the tool axis direction.
        free_intrinsics: False, True (all intrinsics) or the names of the free ones (e.g.
            ``("fx", "fy")``); applies to every camera.
        free_camera_pose: estimate ``T_base_cam`` (for every camera).
        intrinsics_covariance: optional per camera ``(p, p)`` covariance of ``model.params``: a
            Gaussian prior on the free intrinsics (e.g. from the camera calibration); a zero
            variance holds that parameter fixed, ``inf`` leaves it free without a prior.
        T_base_cam_covariance: optional ``(C, 6, 6)`` right-perturbation covariance (rx..tz; rad², m²)
            of the given camera poses: a prior when ``free_camera_pose``. ``inf`` on the diagonal:
            no prior on that coordinate (e.g. orientation known, position free).
        pose_noise_translation_m: robot repeatability, σ per axis of the flange position (m); turns
            on the per-pose robot correction model.
        pose_noise_rotation_deg: σ per axis of the flange orientation (degrees); None holds the
            orientation of each pose exact.
        sigma_px: tip detection noise, px.
        axis_sigma_px: noise of an axis point across the line, px.
        axis_length_m: length along the tool axis of the segment whose projection defines the
            projected axis line, m.
        T_flange_tcp0: optional ``(4, 4)`` start; default from the viewing rays.
        noise: ``"a_posteriori"`` (scale covariances by σ̂²) or ``"stated"``.
        camera_names: names for messages and results (default ``cam0``, ``cam1``, ...).
        min_rotation_deg: smallest accepted RMS spread (degrees) of the rotations / viewing
            directions about the weakest tip direction.
        max_iterations: LM iteration limit.

    Returns:
        :class:`TCPCalibration`.

    Raises:
        BadInputError: malformed input (shapes, NaN poses, unknown intrinsic names, a tip behind a
            camera at the start).
        NotObservableError: fewer than 3 poses with a detected tip, rotations about one axis only
            (with a free camera position: "TCP offset along the rotation axis"), a tip seen along
            one direction only (its depth), or unknowns the engine finds undetermined.
    """
    cams = _as_cameras(cameras)
    n_cam = len(cams)
    names = [f"cam{i}" for i in range(n_cam)] if camera_names is None else [str(s) for s in camera_names]
    if len(names) != n_cam or len(set(names)) != n_cam:
        raise BadInputError(f"camera_names: expected {n_cam} distinct names, got {camera_names!r}")
    Tc = as_pose_matrices(T_base_cam, "T_base_cam")
    if Tc.shape[0] != n_cam:
        raise BadInputError(f"T_base_cam: expected {n_cam} poses (one per camera), got {Tc.shape[0]}")
    Tf = as_pose_matrices(T_base_flange, "T_base_flange")
    n = Tf.shape[0]
    if n < MIN_TCP_POSES:
        raise NotObservableError(
            f"calibrate_tcp: {n} flange pose(s); the TCP needs at least {MIN_TCP_POSES} poses rotated about "
            "two different axes",
            ["TCP offset (too few poses)"],
        )
    px = _pixel_array(tip_pixels, "tip_pixels", n, n_cam, ())
    seen = np.isfinite(px).all(axis=-1)  # (N, C)
    lines = None
    if axis_lines is not None:
        arr = np.asarray(axis_lines, dtype=np.float64)
        L = arr.shape[-2] if arr.ndim >= 3 else 0
        lines = _pixel_array(arr, "axis_lines", n, n_cam, (L,))
    if noise not in ("a_posteriori", "stated"):
        raise BadInputError(f"noise: got {noise!r}, expected 'a_posteriori' or 'stated'")
    for nm, val in (("sigma_px", sigma_px), ("axis_sigma_px", axis_sigma_px), ("axis_length_m", axis_length_m)):
        if not (np.isfinite(val) and val > 0):
            raise BadInputError(f"{nm}: expected a positive number, got {val!r}")
    pose_model = pose_noise_translation_m is not None
    if pose_model and not (np.isfinite(pose_noise_translation_m) and pose_noise_translation_m > 0):
        raise BadInputError(
            f"pose_noise_translation_m: expected a positive σ in metres or None, got {pose_noise_translation_m!r}"
        )
    if pose_noise_rotation_deg is not None and not pose_model:
        raise BadInputError("pose_noise_rotation_deg: given without pose_noise_translation_m; state both")
    if pose_noise_rotation_deg is not None and not (np.isfinite(pose_noise_rotation_deg) and pose_noise_rotation_deg > 0):
        raise BadInputError(
            f"pose_noise_rotation_deg: expected a positive σ in degrees or None, got {pose_noise_rotation_deg!r}"
        )

    R, t = Tf[:, :3, :3], Tf[:, :3, 3]
    posed = seen.any(axis=1)
    if int(posed.sum()) < MIN_TCP_POSES:
        raise NotObservableError(
            f"calibrate_tcp: the tip is detected at {int(posed.sum())} pose(s); at least {MIN_TCP_POSES} are needed",
            ["TCP offset (too few poses with a detected tip)"],
        )

    # --- viewing rays of the detections (base frame)
    det_pose, det_cam, dirs = [], [], []
    for c, cam in enumerate(cams):
        ii = np.flatnonzero(seen[:, c])
        if ii.size == 0:
            continue
        d = np.asarray(_unproject(cam, jnp.asarray(px[ii, c])))
        dirs.append(d @ Tc[c, :3, :3].T)
        det_pose.append(ii)
        det_cam.append(np.full(ii.size, c))
    det_pose = np.concatenate(det_pose)
    det_cam = np.concatenate(det_cam)
    dirs = np.concatenate(dirs)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    centres = Tc[:, :3, 3]
    # a camera pose under a prior is not free for this check: the prior places it (the engine's
    # rank check and covariance then say how well)
    free_centre = bool(free_camera_pose) and (
        T_base_cam_covariance is None
        or bool(np.all(np.isinf(np.diagonal(np.asarray(T_base_cam_covariance, np.float64).reshape(-1, 6, 6),
                                            axis1=1, axis2=2)[:, 3:])))
    )
    M, x_lin = _ray_system(R, t, (det_pose, dirs), det_cam, centres, free_centre)
    _check_observable(M, R, (det_pose, dirs), det_pose.size, free_centre, min_rotation_deg)
    if free_camera_pose and not free_centre:
        # the start does not trust the given camera position (it is free, under a prior)
        _, x_lin = _ray_system(R, t, (det_pose, dirs), det_cam, centres, True)

    # --- start of the TCP
    if T_flange_tcp0 is not None:
        T0 = as_pose_matrices(T_flange_tcp0, "T_flange_tcp0")
        if T0.shape[0] != 1:
            raise BadInputError(f"T_flange_tcp0: expected one (4, 4) pose, got {T0.shape[0]}")
        T0 = T0[0]
    else:
        T0 = np.eye(4)
        T0[:3, 3] = x_lin
    if lines is not None and T_flange_tcp0 is None:
        normals, line_pose = [], []
        for c, cam in enumerate(cams):
            for i in range(n):
                pts = lines[i, c][np.isfinite(lines[i, c]).all(axis=-1)]
                if pts.shape[0] < 2:
                    continue
                mean = pts.mean(axis=0)
                _, _, vt = np.linalg.svd(pts - mean)
                span = (pts - mean) @ vt[0]
                ends = np.stack([mean + span.min() * vt[0], mean + span.max() * vt[0]])
                if np.linalg.norm(ends[1] - ends[0]) < 2.0:
                    continue
                r = np.asarray(_unproject(cam, jnp.asarray(ends)))
                nrm = np.cross(r[0], r[1])
                normals.append(Tc[c, :3, :3] @ (nrm / np.linalg.norm(nrm)))
                line_pose.append(i)
        if len(normals) < 2:
            raise NotObservableError(
                "calibrate_tcp: axis_lines give fewer than 2 usable imaged axis lines (>= 2 points, >= 2 px apart)",
                ["tool axis direction (TCP orientation)"],
            )
        a = _axis_start(R, (np.asarray(line_pose), np.stack(normals)), T0[:3, 3])
        T0[:3, :3] = _rotation_z_to(a)

    # --- is the tip in front of every camera at the start?
    p_base = np.einsum("nab,b->na", R, T0[:3, 3]) + t
    for c in range(n_cam):
        ii = np.flatnonzero(seen[:, c])
        z = (p_base[ii] - Tc[c, :3, 3]) @ Tc[c, :3, 2]
        if ii.size and (z <= 0).any():
            raise BadInputError(
                f"T_base_cam: the start puts the tip behind camera '{names[c]}' at pose {int(ii[np.argmax(z <= 0)])}; "
                "check T_base_cam (it maps camera to base coordinates) and the detections"
            )

    # --- problem
    variables, factors = [], []
    tcp_fixed = np.array([True, True, True, False, False, False])
    if lines is not None:
        tcp_fixed[:2] = False
    variables.append(Variable("T_flange_tcp", SE3(), _pose7(T0), fixed=tcp_fixed, entry_label="T_flange_tcp"))
    free_names = None
    if free_intrinsics is True:
        free_names = "all"
    elif free_intrinsics is False or free_intrinsics is None:
        free_names = ()
    else:
        free_names = tuple(free_intrinsics)
    icov_in = None if intrinsics_covariance is None else list(intrinsics_covariance)
    if icov_in is not None and len(icov_in) != n_cam:
        raise BadInputError(f"intrinsics_covariance: expected {n_cam} matrices (one per camera), got {len(icov_in)}")
    ccov_in = None
    dead_rows = 0  # prior rows that are identically zero (no prior on a coordinate): not redundancy
    if T_base_cam_covariance is not None:
        ccov_in = np.asarray(T_base_cam_covariance, np.float64).reshape(-1, 6, 6)
        if ccov_in.shape[0] != n_cam:
            raise BadInputError(
                f"T_base_cam_covariance: expected shape ({n_cam}, 6, 6), got {np.shape(T_base_cam_covariance)}"
            )
    for c, cam in enumerate(cams):
        pnames = tuple(cam.param_names)
        if free_names == "all":
            mask = np.zeros(len(pnames), bool)
        else:
            unknown = sorted(set(free_names) - set(pnames))
            if unknown:
                raise BadInputError(
                    f"free_intrinsics: got {unknown} for camera '{names[c]}', expected names from {list(pnames)}"
                )
            mask = np.array([p not in free_names for p in pnames])
        prior = {}
        if icov_in is not None and not mask.all():
            C = np.array(icov_in[c], dtype=np.float64)
            if C.shape != (len(pnames), len(pnames)):
                raise BadInputError(
                    f"intrinsics_covariance[{c}]: expected shape ({len(pnames)}, {len(pnames)}), got {C.shape}"
                )
            mask = mask | (np.diag(C) <= 0.0)  # zero variance: known exactly, held fixed
            C[mask, :] = 0.0
            C[:, mask] = 0.0
            C[mask, mask] = np.inf  # fixed coordinates carry no prior row
            S = _prior_sqrt_info(C, f"intrinsics_covariance[{c}]", len(pnames))
            prior = {"prior_mean": np.asarray(cam.params, np.float64), "prior_sqrt_info": S}
            dead_rows += int(np.sum(~S.any(axis=1)))
        variables.append(Variable(f"intrinsics:{names[c]}", Euclidean(len(pnames)),
                                  np.asarray(cam.params, np.float64)[None], fixed=mask[None],
                                  coord_names=pnames, entry_label=names[c], **prior))
        cprior = {}
        if free_camera_pose and ccov_in is not None:
            S = _prior_sqrt_info(ccov_in[c], f"T_base_cam_covariance[{c}]", 6)
            cprior = {"prior_mean": _pose7(Tc[c]), "prior_sqrt_info": S}
            dead_rows += int(np.sum(~S.any(axis=1)))
        variables.append(Variable(f"T_base_{names[c]}", SE3(), _pose7(Tc[c]), fixed=not free_camera_pose,
                                  entry_label=f"T_base_{names[c]}", **cprior))
    meas = _pose7(Tf)
    if pose_model:
        sig = np.concatenate([
            np.full(3, np.deg2rad(pose_noise_rotation_deg) if pose_noise_rotation_deg is not None else 1.0),
            np.full(3, float(pose_noise_translation_m)),
        ])
        fixed = np.array([pose_noise_rotation_deg is None] * 3 + [False] * 3)
        variables.append(Variable("T_base_flange", SE3(), meas, fixed=fixed, prior_mean=meas,
                                  prior_sqrt_info=np.diag(1.0 / sig), eliminate=True,
                                  entry_label="pose {i} flange"))
    else:
        variables.append(Variable("T_base_flange", SE3(), meas, fixed=True, eliminate=True,
                                  entry_label="pose {i} flange"))
    tip_obs = []  # (camera, pose indices, pixels)
    axis_obs = []
    for c, cam in enumerate(cams):
        size = tuple(int(s) for s in cam.image_size)
        args = (f"intrinsics:{names[c]}", f"T_base_{names[c]}", "T_flange_tcp", "T_base_flange")
        ii = np.flatnonzero(seen[:, c]).astype(np.int32)
        if ii.size:
            z = np.zeros(ii.size, np.int32)
            fn = _tip_fn(type(cam), size, bool(cam.has_skew))
            factors.append(FactorGroup(f"tip:{names[c]}", fn, args, (z, z, z, ii), px[ii, c], sigma=sigma_px))
            tip_obs.append((c, ii, fn))
        if lines is not None:
            ok = np.isfinite(lines[:, c]).all(axis=-1)  # (N, L)
            pi, li = np.nonzero(ok)
            if pi.size:
                z = np.zeros(pi.size, np.int32)
                fa = _axis_fn(type(cam), size, bool(cam.has_skew))
                obs = (lines[pi, c, li], np.full(pi.size, float(axis_length_m)))
                factors.append(FactorGroup(f"axis:{names[c]}", fa, args, (z, z, z, pi.astype(np.int32)), obs,
                                           sigma=axis_sigma_px))
                axis_obs.append((c, pi, li, fa, obs))
    problem = Problem(variables, factors)
    try:
        sol = solve(problem, options=SolveOptions(max_iterations=max_iterations))
    except NotObservableError as err:
        raise NotObservableError(f"calibrate_tcp: {err}", err.unknowns) from None
    if sol.status == Status.NON_FINITE:
        raise BadInputError("calibrate_tcp: residuals are not finite at the start; check the inputs")
    # residual components that carry information: the prior rows of held-fixed flange rotations
    # (pose model without rotation noise) are constant and must not count as redundancy
    m = sol.num_residuals - (3 * n if pose_model and pose_noise_rotation_deg is None else 0) - dead_rows
    dof = m - sol.num_free
    if noise == "a_posteriori" and dof <= 0:
        raise NotObservableError(
            f"calibrate_tcp: the a-posteriori noise level needs more residuals ({m}) than free "
            f"unknowns ({sol.num_free}); add poses or use noise='stated'",
            ["noise level (sigma2)"],
        )
    sigma2 = 2.0 * sol.cost / dof if dof > 0 else float("nan")
    scale = sigma2 if noise == "a_posteriori" else 1.0

    # --- outputs
    vals = {k: np.asarray(v) for k, v in sol.values.items()}
    T_ft = _matrix(vals["T_flange_tcp"][0])
    tip_cov = scale * np.asarray(sol.propagate(_tip_of, noise="stated"))
    axis = axis_cov = None
    if lines is not None:
        axis = T_ft[:3, 2].copy()
        axis_cov = scale * np.asarray(sol.propagate(_axis_of, noise="stated"))
    out_cams, icovs, Tcs, ccovs = [], [], [], []
    for c, cam in enumerate(cams):
        iname = f"intrinsics:{names[c]}"
        out_cams.append(cam.with_params(jnp.asarray(vals[iname][0])))
        icovs.append(scale * np.asarray(sol.covariance(iname, noise="stated")))
        Tcs.append(_matrix(vals[f"T_base_{names[c]}"][0]))
        ccovs.append(scale * np.asarray(sol.covariance(f"T_base_{names[c]}", noise="stated")))
    Tbf = np.stack([_matrix(v) for v in vals["T_base_flange"]]) if pose_model else Tf.copy()
    res = np.full((n, n_cam, 2), np.nan)
    bf = jnp.asarray(vals["T_base_flange"])
    for c, ii, fn in tip_obs:
        k = ii.size
        iname = f"intrinsics:{names[c]}"
        r = _residuals_jit(fn)(
            jnp.broadcast_to(jnp.asarray(vals[iname][0]), (k, vals[iname].shape[1])),
            jnp.broadcast_to(jnp.asarray(vals[f"T_base_{names[c]}"][0]), (k, 7)),
            jnp.broadcast_to(jnp.asarray(vals["T_flange_tcp"][0]), (k, 7)),
            bf[ii], jnp.asarray(px[ii, c]),
        )
        res[ii, c] = np.asarray(r)
    axis_res = None
    if lines is not None:
        axis_res = np.full(lines.shape[:3], np.nan)
        for c, pi, li, fa, obs in axis_obs:
            k = pi.size
            iname = f"intrinsics:{names[c]}"
            r = _residuals_jit(fa)(
                jnp.broadcast_to(jnp.asarray(vals[iname][0]), (k, vals[iname].shape[1])),
                jnp.broadcast_to(jnp.asarray(vals[f"T_base_{names[c]}"][0]), (k, 7)),
                jnp.broadcast_to(jnp.asarray(vals["T_flange_tcp"][0]), (k, 7)),
                bf[pi], (jnp.asarray(obs[0]), jnp.asarray(obs[1])),
            )
            axis_res[pi, c, li] = np.asarray(r)[:, 0]
    return TCPCalibration(
        T_flange_tcp=T_ft,
        p_flange_tip=T_ft[:3, 3].copy(),
        tip_covariance=0.5 * (tip_cov + tip_cov.T),
        axis_flange=axis,
        axis_covariance=axis_cov,
        camera_names=names,
        cameras=out_cams,
        intrinsics_covariance=icovs,
        T_base_cam=np.stack(Tcs),
        T_base_cam_covariance=np.stack(ccovs),
        T_base_flange=Tbf,
        residuals_px=res,
        axis_residuals_px=axis_res,
        rms_px=float(np.sqrt(np.nanmean(res**2))),
        sigma2=float(sigma2),
        noise=noise,
        p_flange_tip_init=x_lin.copy(),
        pose_model=pose_model,
        iterations=sol.iterations,
        status=sol.status.name.lower(),
        solution=sol,
    )
