"""Closed-form hand-eye solvers (AX = XB): Tsai-Lenz, Park-Martin, Horaud, Andreff, Daniilidis.

Eye-in-hand (camera on the flange, target fixed in the base): the unknown is ``X = T_flange_cam``.
Every station ``i`` gives the robot pose ``T_base_flange_i`` and the camera's view of the target
``T_cam_target_i``, and ``T_base_flange_i @ X @ T_cam_target_i = T_base_target`` is the same for
all ``i``. Two stations ``i, j`` give one relative motion ``A_ij X = X B_ij`` with (as OpenCV builds
them)::

    A_ij = T_base_flange_j^-1 @ T_base_flange_i      (flange motion, in the flange frame)
    B_ij = T_cam_target_j @ T_cam_target_i^-1        (camera motion, in the camera frame)

Eye-to-hand (camera fixed in the base, target on the flange) is the same problem with the robot
poses inverted (``T_flange_base_i``): ``T_flange_base_i @ T_base_cam @ T_cam_target_i = T_flange_target``,
so the same solvers return ``X = T_base_cam`` (OpenCV documents the same trick).

The five solvers are our numpy implementations of the papers, written to agree with
``cv2.calibrateHandEye`` (OpenCV 4.14) for the matching method: the same equations, the same pair
set (all pairs ``i < j``: that is what OpenCV uses, not consecutive pairs only), the same
least-squares / eigen / SVD steps, quaternions sign-normalised to ``w >= 0`` (as OpenCV 4.14 does
for Horaud and Daniilidis), and Tsai-Lenz's motion filter (OpenCV 4.14 keeps only motions rotating
by 17.3 to 116.4 degrees). Checked to agree to ~1e-13 on noisy data, not only noise-free data.
Caveat shared with OpenCV: Andreff's linear system leaves the scale of ``vec(R)`` free, which the
translations fix only if the camera motions do not all keep one point fixed; stations that all
look at the same target point from the same distance make its translation wrong (the
``motion_translation_rms`` diagnostic shows it). The other methods are not affected.

Before solving, :func:`analyse_motion` looks at the relative rotations and
:func:`check_observable` raises :class:`jcalib.errors.NotObservableError` naming what the data
cannot determine (too few stations, pure translations, rotations small against the stated noise,
one common rotation axis, planar SCARA-like motion). These closed forms only start the joint
solve (``jcalib.problems``); they are not maximum-likelihood estimates.

Units: translations in the unit of the inputs (metres in jcalib), angles in the names' unit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from jcalib.errors import BadInputError, NotObservableError

__all__ = [
    "HAND_EYE_METHODS",
    "HandEyeDiagnostics",
    "HandEyeInit",
    "MotionDiagnostics",
    "analyse_motion",
    "average_poses",
    "check_observable",
    "relative_motions",
    "solve_ax_xb",
    "solve_hand_eye",
]

Mount = Literal["flange", "base"]
Pairs = Literal["all", "consecutive"]

# ---------------------------------------------------------------------------------------------
# small SO(3)/SE(3) helpers (numpy, batched over leading axes)
# ---------------------------------------------------------------------------------------------


def check_poses(T, name: str, tol: float = 1e-6) -> np.ndarray:
    """Validate a stack of 4x4 homogeneous poses; return it as ``(N, 4, 4)`` float64.

    Raises :class:`BadInputError` naming ``name`` for a wrong shape, non-finite values, a bad
    bottom row or a rotation block that is not orthonormal with ``det = +1`` (within ``tol``).
    """
    try:
        arr = np.asarray(T, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise BadInputError(
            f"{name}: expected an array of 4x4 poses, got {type(T).__name__} ({exc})"
        ) from None
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise BadInputError(f"{name}: expected shape (N, 4, 4) (4x4 homogeneous poses), got {arr.shape}")
    bad = ~np.isfinite(arr).all(axis=(1, 2))
    if bad.any():
        k = int(np.argmax(bad))
        raise BadInputError(f"{name}: pose {k} has NaN/inf entries; expected finite 4x4 poses")
    row_err = np.abs(arr[:, 3] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=1)
    if (row_err > tol).any():
        k = int(np.argmax(row_err))
        raise BadInputError(f"{name}: pose {k} has bottom row {arr[k, 3].tolist()}; expected [0, 0, 0, 1]")
    R = arr[:, :3, :3]
    orth_err = np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = (orth_err > tol) | (det < 0.0)
    if bad.any():
        k = int(np.argmax(bad))
        raise BadInputError(
            f"{name}: pose {k} has a rotation block that is not a rotation (max |R R^T - I| = "
            f"{orth_err[k]:.3g}, det = {det[k]:.6g}); expected orthonormal with det +1 (tolerance {tol})"
        )
    return arr


def _inv(T: np.ndarray) -> np.ndarray:
    """Inverse of homogeneous poses ``(..., 4, 4)``."""
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def _skew(v: np.ndarray) -> np.ndarray:
    """``(..., 3) -> (..., 3, 3)`` cross-product matrices."""
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        [np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], axis=-2
    )


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` -> unit quaternions ``(..., 4)`` ``wxyz`` with ``w >= 0``.

    Shepperd's method (largest of trace and diagonal), so it is accurate at every angle.
    """
    m = R
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cand = np.stack([tr, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], axis=-1)
    k = np.argmax(cand, axis=-1)
    q = np.empty(R.shape[:-2] + (4,))
    # branch 0: w largest
    s0 = 2.0 * np.sqrt(np.maximum(1.0 + tr, 1e-300))
    q0 = np.stack(
        [0.25 * s0, (m[..., 2, 1] - m[..., 1, 2]) / s0, (m[..., 0, 2] - m[..., 2, 0]) / s0,
         (m[..., 1, 0] - m[..., 0, 1]) / s0], -1)
    s1 = 2.0 * np.sqrt(np.maximum(1.0 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2], 1e-300))
    q1 = np.stack(
        [(m[..., 2, 1] - m[..., 1, 2]) / s1, 0.25 * s1, (m[..., 0, 1] + m[..., 1, 0]) / s1,
         (m[..., 0, 2] + m[..., 2, 0]) / s1], -1)
    s2 = 2.0 * np.sqrt(np.maximum(1.0 + m[..., 1, 1] - m[..., 0, 0] - m[..., 2, 2], 1e-300))
    q2 = np.stack(
        [(m[..., 0, 2] - m[..., 2, 0]) / s2, (m[..., 0, 1] + m[..., 1, 0]) / s2, 0.25 * s2,
         (m[..., 1, 2] + m[..., 2, 1]) / s2], -1)
    s3 = 2.0 * np.sqrt(np.maximum(1.0 + m[..., 2, 2] - m[..., 0, 0] - m[..., 1, 1], 1e-300))
    q3 = np.stack(
        [(m[..., 1, 0] - m[..., 0, 1]) / s3, (m[..., 0, 2] + m[..., 2, 0]) / s3,
         (m[..., 1, 2] + m[..., 2, 1]) / s3, 0.25 * s3], -1)
    k = k[..., None]
    q = np.where(k == 0, q0, np.where(k == 1, q1, np.where(k == 2, q2, q3)))
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where((q[..., :1] < 0.0), -q, q)


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """``wxyz`` quaternions ``(..., 4)`` -> rotation matrices (the formula OpenCV uses; unit input)."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * z * w, 2 * x * z + 2 * y * w], -1),
            np.stack([2 * x * y + 2 * z * w, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * x * w], -1),
            np.stack([2 * x * z - 2 * y * w, 2 * y * z + 2 * x * w, 1 - 2 * x * x - 2 * y * y], -1),
        ],
        axis=-2,
    )


def _quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of ``wxyz`` quaternions ``(..., 4)``."""
    p0, p1, p2, p3 = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3,
            p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
            p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1,
            p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0,
        ],
        -1,
    )


def rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` -> rotation vectors (axis * angle, rad), angle in [0, pi]."""
    q = _quat_wxyz(R)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 0])
    # angle / sin(angle / 2), with its limit 2 at s -> 0
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    return q[..., 1:] * scale[..., None]


def _project_to_rotation(M: np.ndarray) -> np.ndarray:
    """Nearest rotation to a 3x3 matrix, as OpenCV's ``normalizeRotation`` (unit det, SVD, no reflection)."""
    det = np.linalg.det(M)
    if not np.isfinite(det) or abs(det) < np.finfo(np.float32).eps:
        raise NotObservableError(
            "the closed-form rotation estimate is singular (det = %.3g): the motions do not determine "
            "the rotation" % det,
            unknowns=["rotation"],
        )
    M = np.cbrt(np.copysign(1.0, det) / abs(det)) * M
    u, _, vt = np.linalg.svd(M)
    R = u @ vt
    if np.linalg.det(R) < 0.0:
        R = u @ np.diag([1.0, 1.0, -1.0]) @ vt
    return R


def _lstsq(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Minimum-norm least squares via SVD (as OpenCV's ``solve(..., DECOMP_SVD)``)."""
    return np.linalg.lstsq(A, b, rcond=None)[0]


def _rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (deg) of ``Ra^T Rb`` (batched), accurate for small angles."""
    return np.degrees(np.linalg.norm(rotvec(np.swapaxes(Ra, -1, -2) @ Rb), axis=-1))


# ---------------------------------------------------------------------------------------------
# relative motions
# ---------------------------------------------------------------------------------------------


def _pair_indices(n: int, pairs: str) -> tuple[np.ndarray, np.ndarray]:
    if pairs == "all":
        i, j = np.triu_indices(n, k=1)
    elif pairs == "consecutive":
        i = np.arange(n - 1)
        j = i + 1
    else:
        raise BadInputError(f"pairs: expected 'all' or 'consecutive', got {pairs!r}")
    return i.astype(np.int64), j.astype(np.int64)


def relative_motions(
    T_base_flange, T_cam_target, pairs: Pairs = "all"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The relative motions ``A_ij X = X B_ij`` of an eye-in-hand data set, as OpenCV builds them.

    Args:
        T_base_flange: (N, 4, 4) flange poses in the base frame (for eye-to-hand pass their inverses).
        T_cam_target: (N, 4, 4) target poses in the camera frame.
        pairs: ``"all"`` (every ``i < j``, as ``cv2.calibrateHandEye``) or ``"consecutive"`` (``j = i + 1``).

    Returns:
        ``(A, B, ij)``: A (K, 4, 4) ``= T_base_flange_j^-1 T_base_flange_i``, B (K, 4, 4)
        ``= T_cam_target_j T_cam_target_i^-1``, ij (K, 2) the station indices of each motion.
    """
    Hg = check_poses(T_base_flange, "T_base_flange")
    Hc = check_poses(T_cam_target, "T_cam_target")
    if len(Hg) != len(Hc):
        raise BadInputError(
            f"T_cam_target: expected one pose per robot pose ({len(Hg)} stations), got {len(Hc)}"
        )
    i, j = _pair_indices(len(Hg), pairs)
    A = _inv(Hg[j]) @ Hg[i]
    B = Hc[j] @ _inv(Hc[i])
    return A, B, np.stack([i, j], axis=-1)


# ---------------------------------------------------------------------------------------------
# the five AX = XB solvers on relative motions
# ---------------------------------------------------------------------------------------------


def _translation_from_rotation(A: np.ndarray, B: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Least squares ``(I - R_A) t = t_A - R t_B`` (Park-Martin, Horaud; Tsai's sign-flipped form)."""
    C = (np.eye(3) - A[:, :3, :3]).reshape(-1, 3)
    d = (A[:, :3, 3] - B[:, :3, 3] @ R.T).reshape(-1)
    return _lstsq(C, d)


TSAI_MIN_NORM = 0.3
TSAI_MAX_NORM = 1.7
#: The rotation window of the motions Tsai-Lenz uses (OpenCV's ``0.3 <= 2 sin(theta/2) <= 1.7``), degrees.
TSAI_MIN_ANGLE_DEG = float(np.degrees(2.0 * np.arcsin(TSAI_MIN_NORM / 2.0)))
TSAI_MAX_ANGLE_DEG = float(np.degrees(2.0 * np.arcsin(TSAI_MAX_NORM / 2.0)))


def _tsai(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Tsai & Lenz 1989: modified Rodrigues vectors ``2 sin(theta/2) axis``, then translation.

    Like OpenCV, only motions rotating between ``TSAI_MIN_ANGLE_DEG`` and ``TSAI_MAX_ANGLE_DEG``
    (on both sides) are used, for the rotation and the translation step.
    """
    Pg = 2.0 * _quat_wxyz(A[:, :3, :3])[:, 1:]
    Pc = 2.0 * _quat_wxyz(B[:, :3, :3])[:, 1:]
    # As OpenCV 4.14: keep only motions with 0.3 <= 2 sin(theta/2) <= 1.7 on both sides,
    # i.e. rotations between 17.3 and 116.4 degrees (small ones are noisy, large ones near pi unstable).
    ng = np.linalg.norm(Pg, axis=-1)
    nc = np.linalg.norm(Pc, axis=-1)
    keep = (ng >= TSAI_MIN_NORM) & (nc >= TSAI_MIN_NORM) & (ng <= TSAI_MAX_NORM) & (nc <= TSAI_MAX_NORM)
    if keep.sum() < 2:
        raise NotObservableError(
            f"Tsai-Lenz (as OpenCV) uses only motions rotating by {TSAI_MIN_ANGLE_DEG:.1f} to "
            f"{TSAI_MAX_ANGLE_DEG:.1f} deg; {int(keep.sum())} of {len(keep)} motions qualify, 2 are needed. "
            "Use larger rotations between stations or another method.",
            unknowns=["rotation of the hand-eye transform", "translation of the hand-eye transform"],
        )
    A, B, Pg, Pc = A[keep], B[keep], Pg[keep], Pc[keep]
    # skew(Pg + Pc) P' = Pc - Pg   (Tsai-Lenz eq. 12)
    P_ = _lstsq(_skew(Pg + Pc).reshape(-1, 3), (Pc - Pg).reshape(-1))
    P = 2.0 * P_ / np.sqrt(1.0 + P_ @ P_)  # eq. 14
    q = P / 2.0
    w = np.sqrt(max(1.0 - q @ q, 0.0))
    R = 2.0 * np.outer(q, q) + 2.0 * w * _skew(q) + (1.0 - 2.0 * (q @ q)) * np.eye(3)
    # (R_A - I) t = R t_B - t_A   (eq. 15)
    C = (A[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    d = (B[:, :3, 3] @ R.T - A[:, :3, 3]).reshape(-1)
    return _pose(R, _lstsq(C, d))


def _park_martin(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Park & Martin 1994: ``R = (M^T M)^(-1/2) M^T`` with ``M = sum b a^T`` of rotation vectors."""
    a = rotvec(A[:, :3, :3])
    b = rotvec(B[:, :3, :3])
    M = b.T @ a
    evals, evecs = np.linalg.eigh(M.T @ M)
    if evals.min() <= 0.0:
        raise NotObservableError(
            "Park-Martin: the rotation axes do not span 3 directions' worth of constraints (M^T M singular)",
            unknowns=["rotation"],
        )
    R = evecs @ np.diag(1.0 / np.sqrt(evals)) @ evecs.T @ M.T
    return _pose(R, _translation_from_rotation(A, B, R))


def _horaud(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Horaud & Dornaika 1995: the quaternion minimising ``sum |Q(q_A) q - W(q_B) q|^2`` (4x4 eigen)."""
    qa = _quat_wxyz(A[:, :3, :3])
    qb = _quat_wxyz(B[:, :3, :3])
    r0, rx, ry, rz = qa[:, 0], qa[:, 1], qa[:, 2], qa[:, 3]
    Q = np.stack(
        [np.stack([r0, -rx, -ry, -rz], -1), np.stack([rx, r0, -rz, ry], -1),
         np.stack([ry, rz, r0, -rx], -1), np.stack([rz, -ry, rx, r0], -1)], axis=-2)
    r0, rx, ry, rz = qb[:, 0], qb[:, 1], qb[:, 2], qb[:, 3]
    W = np.stack(
        [np.stack([r0, -rx, -ry, -rz], -1), np.stack([rx, r0, rz, -ry], -1),
         np.stack([ry, -rz, r0, rx], -1), np.stack([rz, ry, -rx, r0], -1)], axis=-2)
    D = Q - W
    S = np.einsum("kji,kjl->il", D, D)
    _, evecs = np.linalg.eigh(S)
    q = evecs[:, 0]  # smallest eigenvalue
    R = _quat_to_matrix(q / np.linalg.norm(q))
    return _pose(R, _translation_from_rotation(A, B, R))


def _andreff(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Andreff, Horaud & Espiau 1999: one linear system in ``vec(R)`` and ``t``, then nearest rotation."""
    K = len(A)
    Ra, Rb, ta, tb = A[:, :3, :3], B[:, :3, :3], A[:, :3, 3], B[:, :3, 3]
    M = np.zeros((K, 12, 12))
    M[:, :9, :9] = np.eye(9) - np.einsum("kij,kab->kiajb", Ra, Rb).reshape(K, 9, 9)  # I - kron(Ra, Rb)
    M[:, 9:, :9] = np.einsum("ij,kb->kijb", np.eye(3), tb).reshape(K, 3, 9)  # kron(I, tb^T)
    M[:, 9:, 9:] = np.eye(3) - Ra
    rhs = np.zeros((K, 12))
    rhs[:, 9:] = ta
    x = _lstsq(M.reshape(-1, 12), rhs.reshape(-1))
    return _pose(_project_to_rotation(x[:9].reshape(3, 3)), x[9:])


def _dual_quat(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    q = _quat_wxyz(T[..., :3, :3])
    tq = np.concatenate([np.zeros(T.shape[:-2] + (1,)), T[..., :3, 3]], axis=-1)
    return q, 0.5 * _quat_mul(tq, q)


def _daniilidis(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Daniilidis 1999: dual quaternions; the solution lies in the 2-D null space of a 6K x 8 matrix."""
    qa, qa_d = _dual_quat(A)
    qb, qb_d = _dual_quat(B)
    a, ap, b, bp = qa[:, 1:], qa_d[:, 1:], qb[:, 1:], qb_d[:, 1:]
    K = len(A)
    S = np.zeros((K, 6, 8))
    S[:, :3, 0] = a - b
    S[:, :3, 1:4] = _skew(a + b)
    S[:, 3:, 0] = ap - bp
    S[:, 3:, 1:4] = _skew(ap + bp)
    S[:, 3:, 4] = a - b
    S[:, 3:, 5:8] = _skew(a + b)
    _, _, vt = np.linalg.svd(S.reshape(-1, 8), full_matrices=False)
    v = vt.T
    u1, v1, u2, v2 = v[:4, 6], v[4:, 6], v[:4, 7], v[4:, 7]
    ca, cb, cc = u1 @ v1, u1 @ v2 + u2 @ v1, u2 @ v2
    disc = np.sqrt(max(cb * cb - 4.0 * ca * cc, 0.0))
    if abs(ca) < 1e-300:
        raise NotObservableError("Daniilidis: degenerate dual-quaternion null space", unknowns=["rotation"])
    s1, s2 = (-cb + disc) / (2.0 * ca), (-cb - disc) / (2.0 * ca)
    sol1 = s1 * s1 * (u1 @ u1) + 2.0 * s1 * (u1 @ u2) + u2 @ u2
    sol2 = s2 * s2 * (u1 @ u1) + 2.0 * s2 * (u1 @ u2) + u2 @ u2
    s, val = (s1, sol1) if sol1 > sol2 else (s2, sol2)
    lam2 = np.sqrt(1.0 / val)
    lam1 = s * lam2
    dq = lam1 * v[:, 6] + lam2 * v[:, 7]
    q, qd = dq[:4], dq[4:]
    R = _quat_to_matrix(q)
    t = 2.0 * _quat_mul(qd, q * np.array([1.0, -1.0, -1.0, -1.0]))[1:]
    return _pose(R, t)


_SOLVERS: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "tsai_lenz": _tsai,
    "park_martin": _park_martin,
    "horaud": _horaud,
    "andreff": _andreff,
    "daniilidis": _daniilidis,
}

#: Method names accepted by :func:`solve_hand_eye`, with the matching ``cv2.CALIB_HAND_EYE_*`` name.
HAND_EYE_METHODS: dict[str, str] = {
    "tsai_lenz": "CALIB_HAND_EYE_TSAI",
    "park_martin": "CALIB_HAND_EYE_PARK",
    "horaud": "CALIB_HAND_EYE_HORAUD",
    "andreff": "CALIB_HAND_EYE_ANDREFF",
    "daniilidis": "CALIB_HAND_EYE_DANIILIDIS",
}


def solve_ax_xb(A, B, method: str = "park_martin") -> np.ndarray:
    """Solve ``A_k X = X B_k`` for ``X`` from relative motions, with one of the closed forms.

    No degeneracy analysis here (see :func:`solve_hand_eye`).

    Args:
        A: (K, 4, 4) motions of the robot side (e.g. ``T_base_flange_j^-1 T_base_flange_i``).
        B: (K, 4, 4) the matching motions of the sensor side (``T_cam_target_j T_cam_target_i^-1``).
        method: one of :data:`HAND_EYE_METHODS`.

    Returns:
        (4, 4) ``X`` (for eye-in-hand data: ``T_flange_cam``), translation in the input unit.
    """
    if method not in _SOLVERS:
        raise BadInputError(f"method: expected one of {sorted(_SOLVERS)}, got {method!r}")
    A = check_poses(A, "A")
    B = check_poses(B, "B")
    if len(A) != len(B) or len(A) < 1:
        raise BadInputError(f"B: expected as many motions as A ({len(A)}, at least 1), got {len(B)}")
    return _SOLVERS[method](A, B)


# ---------------------------------------------------------------------------------------------
# degeneracy analysis
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MotionDiagnostics:
    """How well a set of robot stations determines a hand-eye transform.

    Attributes:
        axes: (K, 3) unit rotation axis of each relative motion, in ``frame`` (sign: largest
            component positive; zero for motions without rotation).
        axes_base: (K, 3) the same axes in the base frame.
        angles_deg: (K,) rotation angle of each relative motion, degrees, in [0, 180].
        pairs: (K, 2) station indices ``(i, j)`` of each motion.
        singular_values_deg: (3,) singular values of the stacked rotation vectors (K, 3), degrees:
            how strongly each direction of the rotation axes is excited.
        axis_spread_deg: largest angle between the axis of a motion that rotates significantly
            (above the noise threshold) and the dominant axis, degrees (0 for one-axis motion).
        dominant_axis: (3,) the dominant rotation axis in ``frame`` (largest component positive).
        rank: number of rotation-axis directions excited above the noise threshold (0..3); a
            hand-eye rotation needs >= 2.
        threshold_deg: the singular-value threshold used for ``rank``, degrees.
        planar: True when every rotation is about the base z axis (SCARA-like motion).
        num_stations: N.
        frame: ``"flange"`` (eye-in-hand) or ``"base"`` (eye-to-hand): the frame of ``axes``.
        warnings: human-readable remarks about weak (but not degenerate) motion.
    """

    axes: np.ndarray
    axes_base: np.ndarray
    angles_deg: np.ndarray
    pairs: np.ndarray
    singular_values_deg: np.ndarray
    axis_spread_deg: float
    dominant_axis: np.ndarray
    rank: int
    threshold_deg: float
    planar: bool
    num_stations: int
    frame: str
    warnings: tuple[str, ...]


def _sign_normalise_axes(v: np.ndarray) -> np.ndarray:
    idx = np.argmax(np.abs(v), axis=-1)
    s = np.take_along_axis(v, idx[..., None], axis=-1)
    return np.where(s < 0.0, -v, v)


def fmt_axis(a: np.ndarray) -> str:
    vals = []
    for x in a:
        r = round(float(x), 3)
        r = 0.0 if r == 0.0 else r
        vals.append(f"{r:g}")
    return "[" + ", ".join(vals) + "]"


def analyse_motion(
    T_base_flange,
    *,
    frame: Mount = "flange",
    pairs: Pairs = "all",
    rotation_noise_deg: float = 0.02,
) -> MotionDiagnostics:
    """Analyse the relative rotations of a set of robot stations for hand-eye observability.

    The rotation vectors ``r_k`` (axis * angle) of the relative motions are stacked into a (K, 3)
    matrix; its singular values say how many axis directions the motion excites. A direction
    counts when its singular value exceeds ``3 * sqrt(2) * sigma * sqrt(K)`` with ``sigma`` the
    stated per-pose rotation noise (a relative motion combines two poses): below that, what looks
    like a second axis can be noise. ``rank`` 0 means no usable rotation (pure translation, or
    rotations small against the noise); 1 means all axes parallel (one-axis motion).

    Args:
        T_base_flange: (N, 4, 4) flange poses in the base frame, metres.
        frame: ``"flange"`` for eye-in-hand (axes of ``T_base_flange_j^-1 T_base_flange_i``, in the
            flange frame) or ``"base"`` for eye-to-hand (axes of ``T_base_flange_j T_base_flange_i^-1``,
            in the base frame).
        pairs: which station pairs make the motions: ``"all"`` (i < j, as OpenCV) or ``"consecutive"``.
        rotation_noise_deg: 1-sigma rotation noise of one pose (robot and camera combined), degrees,
            per axis. Zero leaves only a numerical floor (1e-9 rad).

    Returns:
        :class:`MotionDiagnostics`.
    """
    if not np.isfinite(rotation_noise_deg) or rotation_noise_deg < 0.0:
        raise BadInputError(f"rotation_noise_deg: expected a finite value >= 0, got {rotation_noise_deg!r}")
    if frame not in ("flange", "base"):
        raise BadInputError(f"frame: expected 'flange' or 'base', got {frame!r}")
    T = check_poses(T_base_flange, "T_base_flange")
    n = len(T)
    i, j = _pair_indices(n, pairs)
    R = T[:, :3, :3]
    R_flange = np.swapaxes(R[j], -1, -2) @ R[i]  # rotation of T_base_flange_j^-1 T_base_flange_i
    r_flange = rotvec(R_flange)
    r_base = np.einsum("kab,kb->ka", R[j], r_flange)  # same axis expressed in the base frame
    r = r_flange if frame == "flange" else r_base
    K = len(r)
    angles = np.linalg.norm(r, axis=-1)

    def unit(v: np.ndarray) -> np.ndarray:
        nrm = np.linalg.norm(v, axis=-1, keepdims=True)
        return _sign_normalise_axes(np.where(nrm > 0.0, v / np.where(nrm > 0.0, nrm, 1.0), 0.0))

    sigma_rel = max(np.sqrt(2.0) * np.radians(rotation_noise_deg), 1e-9)
    threshold = 3.0 * sigma_rel * np.sqrt(max(K, 1))
    if K:
        _, sv, vt = np.linalg.svd(r, full_matrices=False)
        sv = np.concatenate([sv, np.zeros(3 - len(sv))])
        dominant = _sign_normalise_axes(vt[0])
    else:
        sv = np.zeros(3)
        dominant = np.zeros(3)
    rank = int((sv > threshold).sum())
    significant = angles > 3.0 * sigma_rel
    if significant.any():
        u = unit(r[significant])
        spread = float(np.degrees(np.arccos(np.clip(np.abs(u @ dominant), 0.0, 1.0))).max())
    else:
        spread = 0.0

    # planar (SCARA-like): rotations only about the base z axis
    planar = False
    if K and significant.any():
        _, sv_b, vt_b = np.linalg.svd(r_base, full_matrices=False)
        sv_b = np.concatenate([sv_b, np.zeros(3 - len(sv_b))])
        planar = bool(sv_b[1] <= threshold and abs(vt_b[0][2]) > np.cos(np.radians(1.0)))

    warnings: list[str] = []
    if K and rank >= 2:
        max_angle = float(np.degrees(angles.max()))
        if max_angle < 10.0:
            warnings.append(
                f"the largest relative rotation is only {max_angle:.3g} deg: closed-form hand-eye "
                "estimates amplify noise; rotate by 30 deg or more between stations"
            )
        if spread < 15.0:
            warnings.append(
                f"rotation axes are within {spread:.3g} deg of one direction: the rotation about and "
                "the translation along that axis are weakly determined; vary the rotation axis"
            )
        if sv[1] < 10.0 * threshold:
            warnings.append(
                f"the second rotation direction is excited only {sv[1] / threshold:.3g}x above the "
                "noise threshold: expect a poorly conditioned hand-eye rotation"
            )
    return MotionDiagnostics(
        axes=unit(r),
        axes_base=unit(r_base),
        angles_deg=np.degrees(angles),
        pairs=np.stack([i, j], axis=-1),
        singular_values_deg=np.degrees(sv),
        axis_spread_deg=spread,
        dominant_axis=dominant,
        rank=rank,
        threshold_deg=float(np.degrees(threshold)),
        planar=planar,
        num_stations=n,
        frame=frame,
        warnings=tuple(warnings),
    )


def check_observable(motion: MotionDiagnostics, unknown: str = "T_flange_cam") -> None:
    """Raise :class:`NotObservableError` when ``motion`` cannot determine the hand-eye transform.

    Args:
        motion: from :func:`analyse_motion`.
        unknown: the name of the hand-eye transform in messages (``T_flange_cam``, ``T_base_cam``...).

    Raises:
        NotObservableError: with ``unknowns`` naming, in words, what is undetermined:
            fewer than 3 stations; no rotation (pure translation); rotations too small against the
            stated noise; all rotation axes parallel (one-axis or planar SCARA-like motion).
    """
    where = f"in the {motion.frame} frame"
    n = motion.num_stations
    if n < 3:
        if n == 2 and motion.rank >= 1:
            ax = fmt_axis(motion.dominant_axis)
            unknowns = [
                f"rotation of {unknown} about the rotation axis of the single motion (axis = {ax} {where})",
                f"translation of {unknown} along the rotation axis of the single motion "
                f"(axis = {ax} {where})",
            ]
        else:
            unknowns = [f"rotation of {unknown}", f"translation of {unknown}"]
        raise NotObservableError(
            f"hand-eye needs at least 3 stations (2 motions with rotations about non-parallel axes); "
            f"got {n} station(s). Undetermined: " + "; ".join(unknowns) + ".",
            unknowns=unknowns,
        )
    max_angle = float(motion.angles_deg.max()) if len(motion.angles_deg) else 0.0
    if motion.rank == 0:
        unknowns = [
            f"rotation of {unknown} (closed forms take it from the rotations, and there are none)",
            f"translation of {unknown} (all 3 components: without rotation it cancels out)",
        ]
        if max_angle < 1e-6:
            why = "the robot only translates (pure translations: no relative rotation between stations)"
        else:
            why = (
                f"the relative rotations are too small relative to the stated noise (largest "
                f"{max_angle:.3g} deg; excitation {motion.singular_values_deg[0]:.3g} deg below the "
                f"noise threshold {motion.threshold_deg:.3g} deg)"
            )
        raise NotObservableError(
            f"{unknown} is not observable: {why}. Undetermined: " + "; ".join(unknowns)
            + ". Rotate the flange about at least two different axes between stations.",
            unknowns=unknowns,
        )
    if motion.rank == 1:
        ax = fmt_axis(motion.dominant_axis)
        unknowns = [
            f"rotation of {unknown} about the common rotation axis (axis = {ax} {where})",
            f"translation of {unknown} along the common rotation axis (axis = {ax} {where})",
        ]
        if motion.planar:
            why = (
                "planar motion (SCARA-like): every rotation is about the base z axis, so all rotation "
                "axes are parallel"
            )
        else:
            why = (
                f"all rotation axes are parallel (spread {motion.axis_spread_deg:.3g} deg, within the "
                "stated noise): one-axis rotations"
            )
        raise NotObservableError(
            f"{unknown} is not observable: {why}. Undetermined: " + "; ".join(unknowns)
            + ". The translation along the axis cannot be determined by any method from these stations; "
            "the rotation about it is not determined by the rotations alone. Add stations rotating about "
            "another axis.",
            unknowns=unknowns,
        )


# ---------------------------------------------------------------------------------------------
# high-level entry point
# ---------------------------------------------------------------------------------------------


def average_poses(T) -> np.ndarray:
    """Chordal mean of poses ``(N, 4, 4)``: nearest rotation to the mean matrix, mean translation."""
    T = np.asarray(T, dtype=np.float64)
    u, _, vt = np.linalg.svd(T[:, :3, :3].mean(axis=0))
    R = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    return _pose(R, T[:, :3, 3].mean(axis=0))


@dataclass(frozen=True)
class HandEyeDiagnostics:
    """Consistency of a closed-form hand-eye solution with the data.

    Attributes:
        motion: the :class:`MotionDiagnostics` the solve was checked with.
        other_rotation_rms_deg: RMS angle between the per-station estimates of ``T_other``
            (``T_base_flange_i X T_cam_target_i`` or its eye-to-hand analogue) and their mean, degrees.
        other_translation_rms: RMS distance of the per-station ``T_other`` translations from
            their mean, input unit (m).
        motion_rotation_rms_deg: RMS rotation angle of ``(A_k X)^-1 X B_k`` over the motions, degrees.
        motion_translation_rms: RMS translation of ``A_k X - X B_k``, input unit (m).
    """

    motion: MotionDiagnostics
    other_rotation_rms_deg: float
    other_translation_rms: float
    motion_rotation_rms_deg: float
    motion_translation_rms: float


@dataclass(frozen=True)
class HandEyeInit:
    """A closed-form hand-eye estimate (a starting point for the joint solve, no covariance).

    Attributes:
        T: (4, 4) the hand-eye transform: ``T_flange_cam`` (mount ``"flange"``) or ``T_base_cam``
            (mount ``"base"``), translation in the input unit (m).
        T_other: (4, 4) the target pose implied by ``T`` and every station, averaged:
            ``T_base_target`` (mount ``"flange"``) or ``T_flange_target`` (mount ``"base"``).
        method: the solver used.
        mount: ``"flange"`` (eye-in-hand) or ``"base"`` (eye-to-hand).
        diagnostics: :class:`HandEyeDiagnostics`.
    """

    T: np.ndarray
    T_other: np.ndarray
    method: str
    mount: str
    diagnostics: HandEyeDiagnostics

    @property
    def name(self) -> str:
        """``"T_flange_cam"`` or ``"T_base_cam"``."""
        return "T_flange_cam" if self.mount == "flange" else "T_base_cam"

    @property
    def other_name(self) -> str:
        """``"T_base_target"`` or ``"T_flange_target"``."""
        return "T_base_target" if self.mount == "flange" else "T_flange_target"


def _check_mount(mount: str) -> None:
    if mount not in ("flange", "base"):
        raise BadInputError(
            f"mount: expected 'flange' (camera on the flange, eye-in-hand) or 'base' (camera fixed, "
            f"eye-to-hand), got {mount!r}"
        )


def solve_hand_eye(
    T_base_flange,
    T_cam_target,
    method: str = "park_martin",
    mount: Mount = "flange",
    *,
    pairs: Pairs = "all",
    rotation_noise_deg: float = 0.02,
) -> HandEyeInit:
    """Closed-form hand-eye calibration (AX = XB) from absolute station poses.

    Checks observability first (:func:`analyse_motion`, :func:`check_observable`), then solves
    with the chosen method on the relative motions of the chosen station pairs.

    Args:
        T_base_flange: (N, 4, 4) robot flange poses in the base frame, metres.
        T_cam_target: (N, 4, 4) target poses in the camera frame (e.g. from PnP), metres.
        method: ``"tsai_lenz"``, ``"park_martin"`` (default), ``"horaud"``, ``"andreff"`` or
            ``"daniilidis"``; each agrees with ``cv2.calibrateHandEye`` with the matching
            ``cv2.CALIB_HAND_EYE_*`` method (with ``pairs="all"``).
        mount: ``"flange"``: eye-in-hand, the target is fixed in the base, returns ``T_flange_cam``;
            ``"base"``: eye-to-hand, the camera is fixed and the target rides on the flange: the
            robot poses are inverted and the same solver returns ``T_base_cam``.
        pairs: ``"all"`` station pairs ``i < j`` (as OpenCV) or ``"consecutive"`` only.
        rotation_noise_deg: stated 1-sigma rotation noise of one pose (robot and camera
            combined), degrees; sets the threshold below which rotations count as absent.

    Returns:
        :class:`HandEyeInit` with ``T`` (``T_flange_cam`` or ``T_base_cam``) and ``T_other``
        (``T_base_target`` or ``T_flange_target``, averaged over the stations).

    Raises:
        BadInputError: malformed poses, mismatched counts, unknown method / mount / pairs.
        NotObservableError: degenerate motion; ``unknowns`` names what is undetermined.
    """
    _check_mount(mount)
    if method not in _SOLVERS:
        raise BadInputError(f"method: expected one of {sorted(_SOLVERS)}, got {method!r}")
    T_bf, T_ct, motion = checked_stations(T_base_flange, T_cam_target, mount, pairs, rotation_noise_deg)

    Hg = T_bf if mount == "flange" else _inv(T_bf)
    A, B, _ = relative_motions(Hg, T_ct, pairs)
    X = _SOLVERS[method](A, B)

    per_station = Hg @ X @ T_ct  # T_base_target_i (eye-in-hand) or T_flange_target_i (eye-to-hand)
    T_other = average_poses(per_station)
    diagnostics = solution_diagnostics(motion, per_station, T_other, A @ X, X @ B)
    return HandEyeInit(T=X, T_other=T_other, method=method, mount=mount, diagnostics=diagnostics)



def checked_stations(T_base_flange, T_cam_target, mount: str, pairs: str, rotation_noise_deg: float):
    """Validated station poses and their motion analysis, raising on degenerate motion.

    Returns:
        ``(T_base_flange (N, 4, 4), T_cam_target (N, 4, 4), MotionDiagnostics)``.

    Raises:
        BadInputError: malformed poses or mismatched counts.
        NotObservableError: degenerate motion, naming the undetermined part of the hand-eye unknown.
    """
    T_bf = check_poses(T_base_flange, "T_base_flange")
    T_ct = check_poses(T_cam_target, "T_cam_target")
    if len(T_bf) != len(T_ct):
        raise BadInputError(
            f"T_cam_target: expected one pose per robot pose ({len(T_bf)} stations), got {len(T_ct)}"
        )
    if len(T_bf) == 0:
        raise BadInputError("T_base_flange: expected at least 3 stations, got none")
    unknown = "T_flange_cam" if mount == "flange" else "T_base_cam"
    motion = analyse_motion(T_bf, frame=mount, pairs=pairs, rotation_noise_deg=rotation_noise_deg)
    check_observable(motion, unknown)
    return T_bf, T_ct, motion

def solution_diagnostics(
    motion: MotionDiagnostics, per_station: np.ndarray, T_other: np.ndarray, lhs: np.ndarray, rhs: np.ndarray
) -> HandEyeDiagnostics:
    """How well a closed-form solution fits the stations.

    Args:
        motion: the motion analysis of the stations.
        per_station: (N, 4, 4) the other transform implied by the solution at each station.
        T_other: (4, 4) their average.
        lhs, rhs: (M, 4, 4) the two sides of the solved equation (``AX`` and ``XB``, or ``AX`` and ``ZB``).
    """
    R_other = np.broadcast_to(T_other[:3, :3], per_station[:, :3, :3].shape)
    rot_other = _rotation_angle_deg(R_other, per_station[:, :3, :3])
    tr_other = np.linalg.norm(per_station[:, :3, 3] - T_other[:3, 3], axis=-1)
    rot_m = _rotation_angle_deg(lhs[:, :3, :3], rhs[:, :3, :3])
    tr_m = np.linalg.norm(lhs[:, :3, 3] - rhs[:, :3, 3], axis=-1)

    def rms(v):
        return float(np.sqrt(np.mean(np.square(v))))

    return HandEyeDiagnostics(
        motion=motion,
        other_rotation_rms_deg=rms(rot_other),
        other_translation_rms=rms(tr_other),
        motion_rotation_rms_deg=rms(rot_m),
        motion_translation_rms=rms(tr_m),
    )
