"""Camera-based analytic TCP: the tool tip seen by a fixed camera, held on one pixel while the flange turns.

The method of Toffano's thesis ("camera-based tool centre point calibration", 2015), derived here
from the geometry (the thesis' equation numbers are given for orientation only). A camera is fixed in
the cell; its orientation in the robot base ``R_base_cam`` is known (the thesis measures it first by
pure flange translations and watching the tip move in the image; a hand-eye result serves as well).
The unknown is the tip in the flange frame ``x = p_flange_tip`` (a 3-DoF TCP).

**Geometry.** With flange pose ``(R_i, t_i)`` the tip is at ``p_i = R_i x + t_i`` (base frame). If
the tip were at the *same 3-D point* ``p`` for every pose, ``R_i x + t_i = p`` (3 equations per pose),
and three poses with two independent rotation axes determine ``x`` and ``p`` (that is the pivot method,
:mod:`jcalib.init.pivot`). One camera only sees that the tip is on the same *pixel*, i.e. on one
viewing ray with unit direction ``d`` (base frame); its depth along the ray is not measured. So only
the components of ``p_i`` across the ray are constrained::

    P (R_i x + t_i) = q          for all i,   P = I - d d^T,   q = the ray's offset (unknown)

two equations per pose; the depth ``d . p_i`` is free per pose.

**The thesis' three-pose procedure** (:func:`tcp_three_pose`, eqs. 4.33, 4.37, 4.40): pose 0 is the
initial pose; pose 1 is pose 0 rotated by ``alpha`` about an axis parallel to the camera z axis, pose 2
is pose 0 rotated by ``beta`` about an axis parallel to the camera x axis (the centre of each rotation
does not matter), each followed by a visual-servo translation that brings the tip back to the initial
pixel. In camera coordinates, with ``y = R_cam_base R_0 x`` and ``s_k = R_cam_base (t_k - t_0)``::

    (R_z(alpha) - I) y = -s_1                 -> y_x, y_y   (2x2, solvable for alpha != 0)
    [(R_x(beta) - I) y]_y = -s_2,y            -> y_z = (s_2,y + (cos beta - 1) y_y) / sin beta
    x = R_0^T R_base_cam y

What the thesis assumes: the viewing ray is the camera z axis (the tip is imaged near the principal
point) and the servo translates in the camera x-y plane. Then the tip returns to the same 3-D point
after the rotation about z (its depth is unchanged), and after the rotation about x only the image-y
component of the correction carries information (the depth change along z is not seen; the x
component of ``s_2`` should be zero and is ignored). Off the principal point this closed form is
biased by ``(depth change) * d_y``.

**The least-squares variant** (:func:`tcp_from_camera_ray`, eqs. 4.17-4.18 in spirit): any number of
poses (``>= 3``), any rotations, and the actual ray direction ``d = R_base_cam @ camera.unproject(pixel)``
(:func:`viewing_ray_base`), so the near-axis assumption is gone. The only extra constraint it uses is
the one the measurement gives: the tip is on one ray; the per-pose depth is eliminated, never
assumed. With ``ray_base=None`` it uses the 3-D same-point constraint instead (tip measured in 3-D,
e.g. by stereo or a touch fixture). Both are linear in the flange translations.

**Error amplification** (the thesis' eq. 4.43): ``jacobian_translation = d x / d (t_0, ..., t_{N-1})``
``(3, 3N)`` maps errors of the recorded flange positions (robot repeatability, servo residuals converted
to metres) to the TCP; ``jacobian_rotation`` does the same for flange orientation errors (right
perturbation ``R_i Exp(omega_i)``, radians). For the three-pose closed form both come from JAX
(forward-mode autodiff, compiled once for its fixed shape); for the least-squares variant they are
analytic (numpy, no compilation per pose count). Tests check both against finite differences.
For iid noise of ``sigma`` per coordinate the TCP covariance is ``sigma^2 J J^T``
(:meth:`AnalyticTCPResult.covariance`): sampling noise of the poses only, not camera or model error.

Units: the unit of the input translations (metres in jcalib).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import lie_kernels
from jcalib.geometry.se3 import as_pose_matrices, make_pose, rotvec, skew
from jcalib.init.pivot import DEFAULT_MIN_ROTATION_DEG

__all__ = [
    "AnalyticTCPResult",
    "tcp_from_camera_ray",
    "tcp_three_pose",
    "viewing_ray_base",
]

#: Largest angle (degrees) between a relative rotation's axis and the camera axis it should be
#: parallel to in :func:`tcp_three_pose`.
AXIS_TOLERANCE_DEG = 0.5


@dataclass(frozen=True)
class AnalyticTCPResult:
    """A 3-DoF TCP from a camera-based analytic method, with its error amplification.

    Attributes:
        p_flange_tip: ``(3,)`` tool tip in the flange frame (input unit).
        residuals: ``(N, 3)`` base frame: the tip's offset from the fitted ray (ray mode, the
            component across the ray) or from the mean tip position (point mode). For the
            three-pose closed form: ``residuals[1]`` the tip displacement of step 1 (only its
            camera-z part can be nonzero: the servo moved in depth), ``residuals[2]`` the camera-x
            part of the tip displacement of step 2 (the unused ``s_2,x``); both zero under the
            thesis' assumptions.
        rms: RMS of ``residuals`` per coordinate (input unit).
        jacobian_translation: ``(3, 3N)`` ``d p_flange_tip / d (t_0x, t_0y, t_0z, t_1x, ...)``,
            flange translations in the base frame (dimensionless).
        jacobian_rotation: ``(3, 3N)`` ``d p_flange_tip / d omega_i``, right perturbation
            ``R_i Exp(omega_i)`` (input unit per radian).
        method: ``"three_pose"``, ``"ray_lsq"`` or ``"point_lsq"``.
    """

    p_flange_tip: np.ndarray
    residuals: np.ndarray
    rms: float
    jacobian_translation: np.ndarray
    jacobian_rotation: np.ndarray
    method: str

    @property
    def T_flange_tcp(self) -> np.ndarray:
        """``(4, 4)`` TCP with the flange's orientation and the tip as origin."""
        return make_pose(np.eye(3), self.p_flange_tip)

    def covariance(self, sigma_translation: float, sigma_rotation_rad: float = 0.0) -> np.ndarray:
        """``(3, 3)`` TCP covariance for iid flange-pose noise (linear propagation).

        Args:
            sigma_translation: standard deviation of each flange-translation coordinate (input
                unit), e.g. the robot's position repeatability.
            sigma_rotation_rad: standard deviation of each flange-rotation component (rad).

        Returns:
            ``sigma_t^2 J_t J_t^T + sigma_r^2 J_r J_r^T`` (input unit squared). Pose noise only.
        """
        Jt, Jr = self.jacobian_translation, self.jacobian_rotation
        return sigma_translation**2 * Jt @ Jt.T + sigma_rotation_rad**2 * Jr @ Jr.T


# --------------------------------------------------------------------------------------------- cores


def _lsq_solve(R: np.ndarray, t: np.ndarray, P: np.ndarray):
    """``argmin_x sum_i |P((R_i - Rbar) x + t_i - tbar)|^2`` (ray offset / point eliminated), with
    its Jacobians w.r.t. the translations and the right rotation perturbations (analytic).

    With ``D_i = R_i - Rbar``, ``M = sum D_i^T P D_i``, residuals ``r_i = P(D_i x + t_i - tbar)``
    (``sum r_i = 0``, ``sum D_i = 0``), perturbing ``t_i`` gives ``M dx = -D_i^T P dt_i`` and
    perturbing ``R_i -> R_i (I + [w]x)`` gives ``M dx = -([R_i^T r_i]x - D_i^T P R_i [x]x) w``.
    Numpy, so no compilation per pose count; checked against finite differences in the tests.
    """
    D = R - R.mean(axis=0, keepdims=True)
    e = t - t.mean(axis=0, keepdims=True)
    M = np.einsum("nji,jk,nkl->il", D, P, D)
    x = np.linalg.solve(M, -np.einsum("nji,jk,nk->i", D, P, e))
    r = np.einsum("ij,njk,k->ni", P, D, x) + e @ P.T
    Minv = np.linalg.inv(M)
    n = R.shape[0]
    Jt = -np.einsum("ij,nkj,kl->inl", Minv, D, P).reshape(3, 3 * n)
    A = skew(np.einsum("nji,nj->ni", R, r)) - np.einsum("nji,jk,nkl,lm->nim", D, P, R, skew(x))
    Jr = -np.einsum("ij,njk->ink", Minv, A).reshape(3, 3 * n)
    return x, Jt, Jr


def _three_pose_core(R: jax.Array, t: jax.Array, R_base_cam: jax.Array) -> jax.Array:
    """The thesis' closed form; ``R (3, 3, 3)``, ``t (3, 3)`` base frame."""
    Rc = R_base_cam
    Rz = Rc.T @ R[1] @ R[0].T @ Rc
    Rx = Rc.T @ R[2] @ R[0].T @ Rc
    alpha = jnp.arctan2(Rz[1, 0], Rz[0, 0])
    beta = jnp.arctan2(Rx[2, 1], Rx[1, 1])
    s1 = Rc.T @ (t[1] - t[0])
    s2 = Rc.T @ (t[2] - t[0])
    a, b = jnp.cos(alpha) - 1.0, jnp.sin(alpha)
    den = a * a + b * b  # = 2 (1 - cos alpha)
    yx = -(a * s1[0] + b * s1[1]) / den
    yy = -(-b * s1[0] + a * s1[1]) / den
    yz = (s2[1] + (jnp.cos(beta) - 1.0) * yy) / jnp.sin(beta)
    y = jnp.stack([yx, yy, yz])
    return R[0].T @ (Rc @ y)


@partial(jax.jit, static_argnums=0)
def _solve_and_jacobians(core, R, t, extra):
    """Run ``core(R, t, extra)`` and its Jacobians w.r.t. translations and rotation perturbations."""
    n = R.shape[0]

    def of_t(tf):
        return core(R, tf.reshape(n, 3), extra)

    def of_w(wf):
        w = wf.reshape(n, 3)
        return core(R @ (jnp.eye(3)[None] + lie_kernels.skew(w, jnp)), t, extra)  # first order of R Exp(w)

    x = core(R, t, extra)
    Jt = jax.jacfwd(of_t)(t.reshape(-1))
    Jr = jax.jacfwd(of_w)(jnp.zeros(3 * n, dtype=jnp.float64))
    return x, Jt, Jr


# --------------------------------------------------------------------------------------------- helpers


def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{c:.4f}" for c in v) + "]"


def _unit(v, name: str) -> np.ndarray:
    arr = np.asarray(v, dtype=np.float64)
    if arr.shape != (3,) or not np.isfinite(arr).all() or np.linalg.norm(arr) < 1e-12:
        raise BadInputError(
            f"{name}: expected a finite nonzero 3-vector (a ray direction), got {np.asarray(v).tolist()}"
        )
    return arr / np.linalg.norm(arr)


def _rotation(Rm, name: str) -> np.ndarray:
    arr = np.asarray(Rm, dtype=np.float64)
    if arr.shape != (3, 3) or not np.isfinite(arr).all():
        raise BadInputError(f"{name}: expected a finite (3, 3) rotation matrix, got shape {arr.shape}")
    if np.abs(arr @ arr.T - np.eye(3)).max() > 1e-6 or np.linalg.det(arr) < 0:
        raise BadInputError(f"{name}: not a rotation (orthonormal, det +1): {arr.tolist()}")
    return arr


@eqx.filter_jit
def _unproject(camera, pixel):
    return camera.unproject(pixel)


def viewing_ray_base(camera, pixel, R_base_cam) -> np.ndarray:
    """Unit direction ``(3,)`` in the base frame of the viewing ray through ``pixel``.

    Args:
        camera: a :class:`jcalib.geometry.cameras.AbstractCameraModel` (intrinsics, distortion).
        pixel: ``(2,)`` pixel (OpenCV convention) where the tip is held.
        R_base_cam: ``(3, 3)`` orientation of the camera in the robot base.
    """
    px = np.asarray(pixel, dtype=np.float64)
    if px.shape != (2,) or not np.isfinite(px).all():
        raise BadInputError(f"pixel: expected a finite (2,) pixel, got {np.asarray(pixel).tolist()}")
    ray_cam = np.asarray(_unproject(camera, jnp.asarray(px)))
    return _rotation(R_base_cam, "R_base_cam") @ ray_cam


def _check_normal_matrix(R: np.ndarray, P: np.ndarray, min_rotation_deg: float, what: str) -> None:
    """NotObservableError naming the flange directions the rotations leave undetermined."""
    n = R.shape[0]
    D = R - R.mean(axis=0)
    M = np.einsum("nji,jk,nkl->il", D, P, D) / n
    evals, evecs = np.linalg.eigh(M)
    spread = np.sqrt(np.maximum(evals, 0.0))
    weak = spread < np.deg2rad(min_rotation_deg)
    if not weak.any():
        return
    unknowns = []
    for k in np.flatnonzero(weak):
        a = evecs[:, k] * (1.0 if evecs[np.argmax(np.abs(evecs[:, k])), k] > 0 else -1.0)
        unknowns.append(f"tip position along {_fmt(a)} of the flange")
    raise NotObservableError(
        f"{what}: the rotations do not determine the tool tip (RMS rotation spread "
        f"{np.rad2deg(spread[0]):.3g} deg < {min_rotation_deg} deg about the weakest direction; all "
        f"rotations about one axis leave the tip along that axis, or along the viewing ray, free): "
        f"not observable: " + "; ".join(unknowns) + ". Rotate about two different axes across the ray.",
        unknowns=unknowns,
    )


# --------------------------------------------------------------------------------------------- public


def tcp_from_camera_ray(
    T_base_flange,
    ray_base=None,
    min_rotation_deg: float = DEFAULT_MIN_ROTATION_DEG,
) -> AnalyticTCPResult:
    """TCP by least squares over poses that all put the tip on one camera ray (or one point).

    Solves ``min_x sum_i |P (R_i x + t_i - q)|^2`` over ``x = p_flange_tip`` and the ray offset
    ``q`` (eliminated), with ``P = I - d d^T`` for a ray of direction ``d`` or ``P = I`` when
    ``ray_base`` is None (the tip at one 3-D point). See the module docstring.

    Args:
        T_base_flange: ``(N, 4, 4)`` (or ``(N, 7)``) flange poses, ``N >= 3``, with the tip on the
            same pixel of a fixed camera (input length unit).
        ray_base: ``(3,)`` direction of the viewing ray in the base frame
            (:func:`viewing_ray_base`), or None for the same-3-D-point constraint.
        min_rotation_deg: smallest accepted RMS rotation spread about the weakest direction.

    Returns:
        :class:`AnalyticTCPResult` (``method`` ``"ray_lsq"`` or ``"point_lsq"``).

    Raises:
        BadInputError: malformed poses or ray.
        NotObservableError: fewer than 3 poses, or rotations that leave a tip direction free (e.g.
            all about one axis).
    """
    T = as_pose_matrices(T_base_flange, "T_base_flange")
    if T.shape[0] < 3:
        raise NotObservableError(
            f"camera-ray TCP needs at least 3 poses (two rotations about different axes); got {T.shape[0]}",
            unknowns=["tip position (too few poses)"],
        )
    if ray_base is None:
        P, method = np.eye(3), "point_lsq"
    else:
        d = _unit(ray_base, "ray_base")
        P, method = np.eye(3) - np.outer(d, d), "ray_lsq"
    R, t = T[:, :3, :3], T[:, :3, 3]
    _check_normal_matrix(R, P, min_rotation_deg, "camera-ray TCP")
    x, Jt, Jr = _lsq_solve(R, t, P)
    tips = np.einsum("nij,j->ni", R, x) + t
    residuals = (tips - tips.mean(axis=0)) @ P.T
    return AnalyticTCPResult(
        p_flange_tip=x,
        residuals=residuals,
        rms=float(np.sqrt(np.mean(residuals**2))),
        jacobian_translation=Jt,
        jacobian_rotation=Jr,
        method=method,
    )


def tcp_three_pose(
    T_base_flange,
    R_base_cam,
    min_rotation_deg: float = DEFAULT_MIN_ROTATION_DEG,
    axis_tolerance_deg: float = AXIS_TOLERANCE_DEG,
) -> AnalyticTCPResult:
    """The thesis' closed-form TCP from three poses: initial, rotated about camera z, about camera x.

    Args:
        T_base_flange: ``(3, 4, 4)`` (or ``(3, 7)``) flange poses: pose 0 initial, pose 1 = pose 0
            rotated about an axis parallel to the camera z axis (then servoed back to the pixel),
            pose 2 = pose 0 rotated about an axis parallel to the camera x axis (then servoed).
        R_base_cam: ``(3, 3)`` camera orientation in the base frame.
        min_rotation_deg: smallest accepted rotation angle of each step.
        axis_tolerance_deg: how far (degrees) each relative rotation axis may be from its camera axis.

    Returns:
        :class:`AnalyticTCPResult` (``method="three_pose"``); its ``residuals`` hold the unused
        consistency checks (see the class).

    Raises:
        BadInputError: not 3 poses, or a rotation not about the camera axis it should be.
        NotObservableError: both rotations about one axis, or a rotation angle below
            ``min_rotation_deg``.
    """
    T = as_pose_matrices(T_base_flange, "T_base_flange")
    if T.shape[0] != 3:
        raise BadInputError(
            f"T_base_flange: the three-pose method takes exactly 3 poses (initial, about camera z, "
            f"about camera x), got {T.shape[0]}; use tcp_from_camera_ray for more"
        )
    Rc = _rotation(R_base_cam, "R_base_cam")
    R, t = T[:, :3, :3], T[:, :3, 3]
    w1 = rotvec(Rc.T @ R[1] @ R[0].T @ Rc)  # relative rotations in camera coordinates
    w2 = rotvec(Rc.T @ R[2] @ R[0].T @ Rc)
    a1, a2 = np.linalg.norm(w1), np.linalg.norm(w2)
    lim = np.deg2rad(min_rotation_deg)
    y_dir_flange = R[0].T @ Rc
    if a1 < lim or a2 < lim:
        which = "first (about camera z)" if a1 < lim else "second (about camera x)"
        lost = (
            f"tip position across the viewing ray, along {_fmt(y_dir_flange[:, 0])} and "
            f"{_fmt(y_dir_flange[:, 1])} of the flange"
            if a1 < lim
            else f"tip position along the viewing ray (camera z), {_fmt(y_dir_flange[:, 2])} of the flange"
        )
        raise NotObservableError(
            f"three-pose TCP: the {which} rotation is {np.rad2deg(min(a1, a2)):.3g} deg < "
            f"{min_rotation_deg} deg: not observable: {lost}",
            unknowns=[lost],
        )
    if abs(np.dot(w1, w2)) / (a1 * a2) > np.cos(lim):
        axis = R[0].T @ Rc @ (w1 / a1)
        lost = f"tip position along the common rotation axis {_fmt(axis)} of the flange"
        raise NotObservableError(
            f"three-pose TCP: both rotations are about one axis: not observable: {lost}", unknowns=[lost]
        )
    tol = np.deg2rad(axis_tolerance_deg)
    for w, a, k, name in ((w1, a1, 2, "z"), (w2, a2, 0, "x")):
        off = np.arccos(min(abs(w[k]) / a, 1.0))
        if off > tol:
            raise BadInputError(
                f"T_base_flange: the rotation to pose {1 if name == 'z' else 2} is about camera axis "
                f"{_fmt(w / a)} (camera frame), {np.rad2deg(off):.3g} deg from the camera {name} axis "
                f"(tolerance {axis_tolerance_deg} deg); use tcp_from_camera_ray for general rotations"
            )
    x, Jt, Jr = _solve_and_jacobians(_three_pose_core, jnp.asarray(R), jnp.asarray(t), jnp.asarray(Rc))
    x = np.asarray(x)
    tips = np.einsum("nij,j->ni", R, x) + t
    residuals = np.zeros((3, 3))
    residuals[1] = tips[1] - tips[0]  # zero by construction (2 equations, 2 unknowns)
    residuals[2] = Rc[:, 0] * (Rc[:, 0] @ (tips[2] - tips[0]))  # the unused camera-x check
    return AnalyticTCPResult(
        p_flange_tip=x,
        residuals=residuals,
        rms=float(np.sqrt(np.mean(residuals**2))),
        jacobian_translation=np.asarray(Jt),
        jacobian_rotation=np.asarray(Jr),
        method="three_pose",
    )
