"""SE(3) on 4x4 matrices in plain NumPy, and the conversions at the robot-controller boundary.

The one place for NumPy pose helpers (``make_pose``, ``invert``, rotations, ``exp_so3`` / ``log_so3``);
:mod:`jcalib.geometry.lie` is the same algebra on ``wxyz_xyz`` vectors in JAX. No JAX here: robot servers
and drivers must start fast.

A pose is a (4, 4) homogeneous matrix ``T_a_b`` in metres (maps points from b to a).
Controllers speak millimetres and either KUKA ``A, B, C`` (intrinsic Z-Y'-X'' angles, degrees) or
ABB ``q1..q4`` (a unit quaternion in ``wxyz`` order). Quaternions leave here sign-normalised (w >= 0).
"""

from __future__ import annotations

import numpy as np

from jcalib.errors import BadInputError


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


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(3, 3) rotation and (3,) translation (m) -> (4, 4) transform."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform: ``invert(T_a_b) == T_b_a``."""
    R = T[:3, :3]
    return make_pose(R.T, -R.T @ T[:3, 3])


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
    """(3, 3) rotation -> (4,) unit quaternion ``wxyz`` with w >= 0 (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    diag = np.array([tr, R[0, 0], R[1, 1], R[2, 2]])
    i = int(np.argmax(diag))
    if i == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif i == 1:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif i == 2:
        s = 2.0 * np.sqrt(1.0 - R[0, 0] + R[1, 1] - R[2, 2])
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 - R[0, 0] - R[1, 1] + R[2, 2])
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s])
    q = q / np.linalg.norm(q)
    return -q if q[0] < 0 else q


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """(4,) quaternion ``wxyz`` (normalised here) -> (3, 3) rotation."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-9:
        raise BadInputError(f"quaternion: expected a non-zero finite wxyz quaternion, got {q.tolist()}")
    w, x, y, z = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
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


def rotation_angle(R: np.ndarray) -> float:
    """Angle (rad) of a rotation matrix, robust near 0 and pi."""
    c = (np.trace(R) - 1.0) / 2.0
    s = np.linalg.norm(np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])) / 2.0
    return float(np.arctan2(s, c))


def pose_distance(T1: np.ndarray, T2: np.ndarray) -> tuple[float, float]:
    """(translation distance in m, rotation angle in rad) between two poses."""
    return float(np.linalg.norm(T1[:3, 3] - T2[:3, 3])), rotation_angle(T1[:3, :3].T @ T2[:3, :3])


def exp_so3(w: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) in rad -> (3, 3) rotation (Rodrigues)."""
    th = float(np.linalg.norm(w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th**2 * (K @ K)


def log_so3(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> rotation vector (3,) in rad."""
    q = quat_from_matrix(R)
    v = q[1:]
    s = np.linalg.norm(v)
    if s < 1e-15:
        return 2.0 * v
    return 2.0 * np.arctan2(s, q[0]) * v / s


def interpolate_pose(T0: np.ndarray, T1: np.ndarray, s: float) -> np.ndarray:
    """Straight-line position and geodesic (slerp) orientation between two poses, ``s`` in [0, 1]."""
    R = T0[:3, :3] @ exp_so3(s * log_so3(T0[:3, :3].T @ T1[:3, :3]))
    return make_pose(R, (1 - s) * T0[:3, 3] + s * T1[:3, 3])


def log_se3(T: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` rigid transforms -> ``(..., 6)`` tangent ``(rx, ry, rz, tx, ty, tz)`` (rad, m), the
    SE(3) logarithm in jcalib's order: ``T = Exp(δ)`` with the translation part ``V(ω)⁻¹ t``."""
    T = np.asarray(T, dtype=np.float64)
    R, t = T[..., :3, :3], T[..., :3, 3]
    flat_R = R.reshape(-1, 3, 3)
    w = np.stack([log_so3(r) for r in flat_R]).reshape(R.shape[:-2] + (3,))
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    zero = np.zeros(w.shape[:-1])
    K = np.stack([np.stack([zero, -w[..., 2], w[..., 1]], -1), np.stack([w[..., 2], zero, -w[..., 0]], -1),
                  np.stack([-w[..., 1], w[..., 0], zero], -1)], -2)
    small = th < 1e-8
    th_safe = np.where(small, 1.0, th)
    coef = np.where(small, 1.0 / 12.0, (1.0 - th_safe * np.sin(th_safe) / (2.0 * (1.0 - np.cos(th_safe)))) / th_safe**2)
    V_inv = np.eye(3) - 0.5 * K + coef * (K @ K)
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
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K * ((1.0 - c) / s**2)
