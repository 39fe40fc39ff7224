"""SE(3) on 4x4 matrices in plain NumPy, and the conversions at the robot-controller boundary.

The one place for NumPy pose helpers (``make_pose``, ``invert``, ``skew``, rotations, ``exp_so3`` /
``rotvec`` (``log_so3``), ``adjoint``, ``log_se3``); :mod:`jcalib.geometry.lie` is the same algebra on
``wxyz_xyz`` vectors in JAX, and the tests hold the two (and scipy) against each other. No JAX here:
robot servers and drivers must start fast.

A pose is a (4, 4) homogeneous matrix ``T_a_b`` in metres (maps points from b to a). The algebra
(``make_pose``, ``invert``, ``skew``, ``exp_so3``, ``rotvec``, ``rotation``, ``adjoint``, quaternions,
``log_se3``) is batched over leading axes: ``(..., 4, 4)``, ``(..., 3, 3)``, ``(..., 3)``. Input checks:
``check_pose`` (one pose), ``check_poses`` (a stack), ``as_pose_matrices`` (a stack of matrices or of
``wxyz_xyz`` 7-vectors).

Controllers speak millimetres and either KUKA ``A, B, C`` (intrinsic Z-Y'-X'' angles, degrees) or
ABB ``q1..q4`` (a unit quaternion in ``wxyz`` order). Quaternions leave here sign-normalised (w >= 0).
"""

from __future__ import annotations

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry import lie_kernels


def check_pose(T: np.ndarray, name: str = "T_base_flange") -> np.ndarray:
    """Validate a homogeneous transform and return it as a float64 (4, 4) array.

    Raises:
        BadInputError: wrong shape, non-finite entries, or a rotation block that is not orthonormal
            with determinant +1 (tolerance 1e-6, the precision of a controller's 32-bit floats).
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise BadInputError(f"{name}: expected a (4, 4) homogeneous matrix in metres, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise BadInputError(f"{name}: expected finite entries, got {T.tolist()}")
    R = T[:3, :3]
    if (
        np.max(np.abs(R.T @ R - np.eye(3))) > 1e-6
        or abs(np.linalg.det(R) - 1.0) > 1e-6
        or np.max(np.abs(T[3] - np.array([0.0, 0.0, 0.0, 1.0]))) > 0.0
    ):
        raise BadInputError(
            f"{name}: expected a rigid transform (orthonormal rotation, det +1, last row 0 0 0 1), "
            f"got {np.round(T, 6).tolist()}"
        )
    return T


def check_poses(T, name: str, tol: float = 1e-6) -> np.ndarray:
    """Validate a stack of 4x4 homogeneous poses (one pose counts as ``N = 1``); return ``(N, 4, 4)`` float64.

    Raises :class:`BadInputError` naming ``name`` and the pose for a wrong shape, non-finite values, a
    bad bottom row or a rotation block that is not orthonormal with ``det = +1`` (within ``tol``).
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


def as_pose_matrices(T, name: str) -> np.ndarray:
    """Validate poses and return them as ``(N, 4, 4)`` float64 homogeneous matrices.

    Args:
        T: ``(N, 4, 4)`` homogeneous transforms, or ``(N, 7)`` poses (``wxyz`` quaternion then
            translation, as in :mod:`jcalib.geometry.lie`); a single pose is read as ``N = 1``.
        name: argument name used in error messages.

    Raises:
        BadInputError: wrong shape, non-finite values, a rotation block that is not a rotation.
    """
    try:
        arr = np.asarray(T, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise BadInputError(f"{name}: expected (N, 4, 4) or (N, 7) poses, got {type(T).__name__} ({exc})") from None
    if arr.ndim >= 1 and arr.shape[-1] == 7 and arr.ndim in (1, 2):
        arr = np.atleast_2d(arr)
        if not np.isfinite(arr).all():
            raise BadInputError(f"{name}: poses (N, 7) contain NaN/inf; expected finite values")
        q = arr[:, :4]
        norm = np.linalg.norm(q, axis=1)
        if (np.abs(norm - 1.0) > 1e-6).any():
            k = int(np.argmax(np.abs(norm - 1.0)))
            raise BadInputError(
                f"{name}: pose {k} has a quaternion of norm {norm[k]:.6g}; expected unit quaternions (wxyz)"
            )
        return make_pose(matrix_from_quat(q), arr[:, 4:])
    if arr.ndim not in (2, 3) or arr.shape[-2:] != (4, 4):
        raise BadInputError(f"{name}: expected shape (N, 4, 4) (homogeneous poses) or (N, 7), got {arr.shape}")
    return check_poses(arr, name)


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Rotations ``(..., 3, 3)`` and translations ``(..., 3)`` (m) -> transforms ``(..., 4, 4)``.

    Leading axes broadcast (one rotation with many translations, or the reverse).
    """
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    T = np.zeros(np.broadcast_shapes(R.shape[:-2], t.shape[:-1]) + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)``: ``invert(T_a_b) == T_b_a``."""
    T = np.asarray(T, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_pose(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``(..., 3, 3)`` of vectors ``(..., 3)``: ``skew(a) @ b == np.cross(a, b)``."""
    return lie_kernels.skew(np.asarray(v, dtype=np.float64), np)


def adjoint(T: np.ndarray) -> np.ndarray:
    """Adjoints ``(..., 6, 6)`` of transforms ``(..., 4, 4)`` in the ``(omega, v)`` order:
    ``T Exp(d) = Exp(adjoint(T) d) T`` (``[[R, 0], [[t]x R, R]]``, as :func:`jcalib.geometry.lie.se3_adjoint`)."""
    T = np.asarray(T, dtype=np.float64)
    R = T[..., :3, :3]
    out = np.zeros(T.shape[:-2] + (6, 6))
    out[..., :3, :3] = R
    out[..., 3:, :3] = skew(T[..., :3, 3]) @ R
    out[..., 3:, 3:] = R
    return out


def rot_x(a: float) -> np.ndarray:
    """Rotation about x by ``a`` rad."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Rotation about y by ``a`` rad."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation about z by ``a`` rad."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Rotations ``(..., 3, 3)`` -> unit quaternions ``(..., 4)`` ``wxyz`` with ``w >= 0``.

    Shepperd's method (the largest of the trace and the diagonal picks the formula), accurate at
    every angle.
    """
    m = np.asarray(R, dtype=np.float64)
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    k = np.argmax(np.stack([tr, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], axis=-1), axis=-1)[..., None]
    # every branch is computed; a pivot that is not the largest may be ~0, hence the floor under sqrt
    s0 = 2.0 * np.sqrt(np.maximum(1.0 + tr, 1e-300))
    q0 = np.stack([0.25 * s0, (m[..., 2, 1] - m[..., 1, 2]) / s0, (m[..., 0, 2] - m[..., 2, 0]) / s0,
                   (m[..., 1, 0] - m[..., 0, 1]) / s0], -1)
    s1 = 2.0 * np.sqrt(np.maximum(1.0 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2], 1e-300))
    q1 = np.stack([(m[..., 2, 1] - m[..., 1, 2]) / s1, 0.25 * s1, (m[..., 0, 1] + m[..., 1, 0]) / s1,
                   (m[..., 0, 2] + m[..., 2, 0]) / s1], -1)
    s2 = 2.0 * np.sqrt(np.maximum(1.0 + m[..., 1, 1] - m[..., 0, 0] - m[..., 2, 2], 1e-300))
    q2 = np.stack([(m[..., 0, 2] - m[..., 2, 0]) / s2, (m[..., 0, 1] + m[..., 1, 0]) / s2, 0.25 * s2,
                   (m[..., 1, 2] + m[..., 2, 1]) / s2], -1)
    s3 = 2.0 * np.sqrt(np.maximum(1.0 + m[..., 2, 2] - m[..., 0, 0] - m[..., 1, 1], 1e-300))
    q3 = np.stack([(m[..., 1, 0] - m[..., 0, 1]) / s3, (m[..., 0, 2] + m[..., 2, 0]) / s3,
                   (m[..., 1, 2] + m[..., 2, 1]) / s3, 0.25 * s3], -1)
    q = np.where(k == 0, q0, np.where(k == 1, q1, np.where(k == 2, q2, q3)))
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """Quaternions ``(..., 4)`` ``wxyz`` (normalised here) -> rotations ``(..., 3, 3)``."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(n)) or np.any(n < 1e-9):
        raise BadInputError(f"quaternion: expected non-zero finite wxyz quaternions, got {q.tolist()}")
    q = q / n
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def kuka_abc_from_matrix(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> KUKA ``(A, B, C)`` in degrees, ``R = Rz(A) Ry(B) Rx(C)``.

    ``C`` is taken from what remains after removing ``Rz(A) Ry(B)``, so the angles reproduce ``R`` to
    float64 precision even next to the gimbal lock (B = +-90 deg), where ``A`` and ``C`` are ill-defined.
    """
    R = np.asarray(R, dtype=np.float64)
    B = np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0]))
    A = np.arctan2(R[1, 0], R[0, 0]) if np.hypot(R[0, 0], R[1, 0]) > 1e-12 else np.arctan2(-R[0, 1], R[1, 1])
    M = rot_y(B).T @ rot_z(A).T @ R  # = Rx(C)
    C = np.arctan2(M[2, 1], M[1, 1])
    return np.degrees(np.array([A, B, C]))


def matrix_from_kuka_abc(abc_deg: np.ndarray) -> np.ndarray:
    """KUKA ``(A, B, C)`` in degrees -> (3, 3) rotation ``Rz(A) Ry(B) Rx(C)``."""
    A, B, C = np.radians(np.asarray(abc_deg, dtype=np.float64))
    return rot_z(A) @ rot_y(B) @ rot_x(C)


def pose_to_mm_quat(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(4, 4) pose in m -> (position (3,) in mm, quaternion (4,) wxyz, w >= 0)."""
    return T[:3, 3] * 1000.0, quat_from_matrix(T[:3, :3])


def pose_from_mm_quat(xyz_mm: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
    """Position in mm and quaternion ``wxyz`` -> (4, 4) pose in m."""
    return make_pose(matrix_from_quat(q_wxyz), np.asarray(xyz_mm, dtype=np.float64) / 1000.0)


def pose_to_kuka(T: np.ndarray) -> np.ndarray:
    """(4, 4) pose in m -> ``[X, Y, Z, A, B, C]`` (mm, degrees)."""
    return np.concatenate([T[:3, 3] * 1000.0, kuka_abc_from_matrix(T[:3, :3])])


def pose_from_kuka(xyzabc: np.ndarray) -> np.ndarray:
    """``[X, Y, Z, A, B, C]`` (mm, degrees) -> (4, 4) pose in m."""
    v = np.asarray(xyzabc, dtype=np.float64)
    return make_pose(matrix_from_kuka_abc(v[3:6]), v[:3] / 1000.0)


def pose_to_ur(T: np.ndarray) -> np.ndarray:
    """(4, 4) pose in m -> Universal Robots' ``[x, y, z, rx, ry, rz]`` (m, rotation vector in rad, angle in [0, pi])."""
    return np.concatenate([np.asarray(T, dtype=np.float64)[:3, 3], rotvec(np.asarray(T, dtype=np.float64)[:3, :3])])


def pose_from_ur(pose: np.ndarray) -> np.ndarray:
    """Universal Robots' ``[x, y, z, rx, ry, rz]`` (m, rotation vector in rad) -> (4, 4) pose in m."""
    v = np.asarray(pose, dtype=np.float64)
    return make_pose(exp_so3(v[3:6]), v[:3])


def rotation_angle(R: np.ndarray) -> float:
    """Angle (rad) of a rotation matrix, robust near 0 and pi."""
    c = (np.trace(R) - 1.0) / 2.0
    s = np.linalg.norm(np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])) / 2.0
    return float(np.arctan2(s, c))


def pose_distance(T1: np.ndarray, T2: np.ndarray) -> tuple[float, float]:
    """(translation distance in m, rotation angle in rad) between two poses."""
    return float(np.linalg.norm(T1[:3, 3] - T2[:3, 3])), rotation_angle(T1[:3, :3].T @ T2[:3, :3])


def exp_so3(w: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` in rad -> rotations ``(..., 3, 3)`` (Rodrigues; first order below 1e-12 rad)."""
    w = np.asarray(w, dtype=np.float64)
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    small = th < 1e-12
    th = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(th) / th)
    b = np.where(small, 0.0, (1 - np.cos(th)) / th**2)
    return np.eye(3) + a * K + b * (K @ K)


def rotvec(R: np.ndarray) -> np.ndarray:
    """Rotations ``(..., 3, 3)`` -> rotation vectors ``(..., 3)`` (axis * angle, rad), angle in [0, pi].

    The SO(3) logarithm, through the quaternion (accurate at every angle, including 0 and pi, where
    the sign of the axis follows the quaternion's vector part).
    """
    q = quat_from_matrix(R)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 0])
    # angle / sin(angle / 2), with its limit 2 at s -> 0
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    return q[..., 1:] * scale[..., None]


#: The SO(3) logarithm: :func:`rotvec` under its group-theory name.
log_so3 = rotvec


def rotation(axis: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """Rotations ``(..., 3, 3)`` by ``angle (...)`` rad about ``axis (..., 3)`` (any non-zero length), right-handed."""
    axis = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(axis) if axis.ndim == 1 else np.linalg.norm(axis, axis=-1, keepdims=True)
    if not np.all(np.isfinite(n)) or np.any(n == 0.0):
        raise BadInputError(f"axis: expected a finite non-zero rotation axis, got {axis.tolist()}")
    K = skew(axis / n)
    angle = np.asarray(angle, dtype=np.float64)[..., None, None]
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def interpolate_pose(T0: np.ndarray, T1: np.ndarray, s: float) -> np.ndarray:
    """Straight-line position and geodesic (slerp) orientation between two poses, ``s`` in [0, 1]."""
    R = T0[:3, :3] @ exp_so3(s * log_so3(T0[:3, :3].T @ T1[:3, :3]))
    return make_pose(R, (1 - s) * T0[:3, 3] + s * T1[:3, 3])


def log_se3(T: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` rigid transforms -> ``(..., 6)`` tangent ``(rx, ry, rz, tx, ty, tz)`` (rad, m), the
    SE(3) logarithm in jcalib's order: ``T = Exp(δ)`` with the translation part ``V(ω)⁻¹ t``."""
    T = np.asarray(T, dtype=np.float64)
    w, t = rotvec(T[..., :3, :3]), T[..., :3, 3]
    th2 = np.sum(w * w, axis=-1)[..., None, None]
    K = skew(w)
    # V⁻¹ = I - K/2 + D K² with D = (1 - (θ/2) cot(θ/2)) / θ², by its series below 0.01 rad (where the
    # closed form cancels; the first dropped term is < 1e-20) as in jcalib.geometry.lie
    small = th2 < 1e-4
    th = np.sqrt(np.where(small, 1.0, th2))
    D = np.where(small, 1.0 / 12.0 + th2 / 720.0 + th2**2 / 30240.0 + th2**3 / 1209600.0,
                 (1.0 - 0.5 * th / np.tan(0.5 * th)) / th**2)
    V_inv = np.eye(3) - 0.5 * K + D * (K @ K)
    return np.concatenate([w, np.einsum("...ij,...j->...i", V_inv, t)], axis=-1)


def rotation_z_to(a: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the z axis to the unit vector ``a`` (3, 3).

    jcalib's convention for the rotation of a symmetric tool about its own axis: a TCP whose z axis is
    the tool axis ``a`` (in the flange frame) has the orientation ``rotation_z_to(a)``.
    """
    a = np.asarray(a, dtype=np.float64)
    e = np.array([0.0, 0.0, 1.0])
    v = np.cross(e, a)
    s, c = np.linalg.norm(v), float(a @ e)
    if s < 1e-12 and c < 0:  # a = -z: a half turn about x
        return np.diag([1.0, -1.0, -1.0])
    K = skew(v)
    # (1 - c) / s² = 1 / (1 + c) for a unit a: the form without cancellation on either side of the equator
    return np.eye(3) + K + K @ K * (1.0 / (1.0 + c) if c >= 0 else (1.0 - c) / s**2)


#: Distances from a tool's tip (m) of the points on its shaft that a station shows along the imaged tool axis.
SHAFT_POINTS_M = (0.01, 0.02, 0.03, 0.04)


def shaft_points(T_flange_tool: np.ndarray, distances=SHAFT_POINTS_M) -> np.ndarray:
    """``(k, 3)`` points of a tool's shaft in its TCP frame: on the TCP's z axis (the tool axis), ``distances``
    (m) from the tip towards the flange (the side of the tip the tool is on, whichever way its z points).

    Args:
        T_flange_tool: (4, 4) the TCP in the flange frame, m.
    """
    T = np.asarray(T_flange_tool, np.float64)
    flange_in_tool = -T[:3, :3].T @ T[:3, 3]
    side = 1.0 if flange_in_tool[2] >= 0.0 else -1.0
    return np.array([[0.0, 0.0, side * s] for s in distances], np.float64)
