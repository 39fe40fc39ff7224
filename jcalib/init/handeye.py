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

Before solving, :func:`solve_hand_eye` checks the motion (:mod:`jcalib.init.handeye_motion`:
:func:`~jcalib.init.handeye_motion.analyse_motion` and
:func:`~jcalib.init.handeye_motion.check_observable` raise :class:`jcalib.errors.NotObservableError`
naming what the data cannot determine). These closed forms only start the joint solve
(``jcalib.problems``); they are not maximum-likelihood estimates.

Units: translations in the unit of the inputs (metres in jcalib), angles in the names' unit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.lie_kernels import quat_multiply
from jcalib.geometry.se3 import check_poses, invert, make_pose, matrix_from_quat, quat_from_matrix, rotvec, skew
from jcalib.init.handeye_motion import (
    HandEyeDiagnostics,
    Mount,
    Pairs,
    check_mount,
    checked_stations,
    pair_indices,
    solution_diagnostics,
)

__all__ = [
    "HAND_EYE_METHODS",
    "HandEyeInit",
    "average_poses",
    "lstsq_min_norm",
    "project_to_rotation",
    "relative_motions",
    "solve_ax_xb",
    "solve_hand_eye",
]


def project_to_rotation(M: np.ndarray) -> np.ndarray:
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


def lstsq_min_norm(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Minimum-norm least squares via SVD (as OpenCV's ``solve(..., DECOMP_SVD)``)."""
    return np.linalg.lstsq(A, b, rcond=None)[0]


# ---------------------------------------------------------------------------------------------
# relative motions
# ---------------------------------------------------------------------------------------------


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
    i, j = pair_indices(len(Hg), pairs)
    A = invert(Hg[j]) @ Hg[i]
    B = Hc[j] @ invert(Hc[i])
    return A, B, np.stack([i, j], axis=-1)


# ---------------------------------------------------------------------------------------------
# the five AX = XB solvers on relative motions
# ---------------------------------------------------------------------------------------------


def _translation_from_rotation(A: np.ndarray, B: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Least squares ``(I - R_A) t = t_A - R t_B`` (Park-Martin, Horaud; Tsai's sign-flipped form)."""
    C = (np.eye(3) - A[:, :3, :3]).reshape(-1, 3)
    d = (A[:, :3, 3] - B[:, :3, 3] @ R.T).reshape(-1)
    return lstsq_min_norm(C, d)


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
    Pg = 2.0 * quat_from_matrix(A[:, :3, :3])[:, 1:]
    Pc = 2.0 * quat_from_matrix(B[:, :3, :3])[:, 1:]
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
    P_ = lstsq_min_norm(skew(Pg + Pc).reshape(-1, 3), (Pc - Pg).reshape(-1))
    P = 2.0 * P_ / np.sqrt(1.0 + P_ @ P_)  # eq. 14
    q = P / 2.0
    w = np.sqrt(max(1.0 - q @ q, 0.0))
    R = 2.0 * np.outer(q, q) + 2.0 * w * skew(q) + (1.0 - 2.0 * (q @ q)) * np.eye(3)
    # (R_A - I) t = R t_B - t_A   (eq. 15)
    C = (A[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    d = (B[:, :3, 3] @ R.T - A[:, :3, 3]).reshape(-1)
    return make_pose(R, lstsq_min_norm(C, d))


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
    return make_pose(R, _translation_from_rotation(A, B, R))


def _horaud(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Horaud & Dornaika 1995: the quaternion minimising ``sum |Q(q_A) q - W(q_B) q|^2`` (4x4 eigen)."""
    qa = quat_from_matrix(A[:, :3, :3])
    qb = quat_from_matrix(B[:, :3, :3])
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
    R = matrix_from_quat(q / np.linalg.norm(q))
    return make_pose(R, _translation_from_rotation(A, B, R))


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
    x = lstsq_min_norm(M.reshape(-1, 12), rhs.reshape(-1))
    return make_pose(project_to_rotation(x[:9].reshape(3, 3)), x[9:])


def _dual_quat(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    q = quat_from_matrix(T[..., :3, :3])
    tq = np.concatenate([np.zeros(T.shape[:-2] + (1,)), T[..., :3, 3]], axis=-1)
    return q, 0.5 * quat_multiply(tq, q, np)


def _daniilidis(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Daniilidis 1999: dual quaternions; the solution lies in the 2-D null space of a 6K x 8 matrix."""
    qa, qa_d = _dual_quat(A)
    qb, qb_d = _dual_quat(B)
    a, ap, b, bp = qa[:, 1:], qa_d[:, 1:], qb[:, 1:], qb_d[:, 1:]
    K = len(A)
    S = np.zeros((K, 6, 8))
    S[:, :3, 0] = a - b
    S[:, :3, 1:4] = skew(a + b)
    S[:, 3:, 0] = ap - bp
    S[:, 3:, 1:4] = skew(ap + bp)
    S[:, 3:, 4] = a - b
    S[:, 3:, 5:8] = skew(a + b)
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
    R = matrix_from_quat(q)
    t = 2.0 * quat_multiply(qd, q * np.array([1.0, -1.0, -1.0, -1.0]), np)[1:]
    return make_pose(R, t)


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
# high-level entry point
# ---------------------------------------------------------------------------------------------


def average_poses(T) -> np.ndarray:
    """Chordal mean of poses ``(N, 4, 4)``: nearest rotation to the mean matrix, mean translation."""
    T = np.asarray(T, dtype=np.float64)
    u, _, vt = np.linalg.svd(T[:, :3, :3].mean(axis=0))
    R = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    return make_pose(R, T[:, :3, 3].mean(axis=0))


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
        diagnostics: :class:`~jcalib.init.handeye_motion.HandEyeDiagnostics`.
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

    Checks observability first (:func:`jcalib.init.handeye_motion.checked_stations`), then solves
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
    check_mount(mount)
    if method not in _SOLVERS:
        raise BadInputError(f"method: expected one of {sorted(_SOLVERS)}, got {method!r}")
    T_bf, T_ct, motion = checked_stations(T_base_flange, T_cam_target, mount, pairs, rotation_noise_deg)

    Hg = T_bf if mount == "flange" else invert(T_bf)
    A, B, _ = relative_motions(Hg, T_ct, pairs)
    X = _SOLVERS[method](A, B)

    per_station = Hg @ X @ T_ct  # T_base_target_i (eye-in-hand) or T_flange_target_i (eye-to-hand)
    T_other = average_poses(per_station)
    diagnostics = solution_diagnostics(motion, per_station, T_other, A @ X, X @ B)
    return HandEyeInit(T=X, T_other=T_other, method=method, mount=mount, diagnostics=diagnostics)
