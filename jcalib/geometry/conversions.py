"""Pose conventions in and out: 4x4 matrices, OpenCV rvec/tvec, quaternion orders, ABB, KUKA, Euler.

Every function takes array-likes with leading batch axes and returns:

- numpy ``float64`` arrays when no argument is a JAX array (scripts, file readers, exporters), and
  the input is then checked: wrong shape, NaN/inf, a non-orthonormal rotation block
  (``max |R^T R - I| > ORTHONORMAL_TOL`` or ``det R < 0``), a bad homogeneous row, a zero or
  far-from-unit quaternion raise :class:`jcalib.errors.BadInputError` naming the argument;
- JAX arrays when any argument is a JAX array. The same value checks run on concrete arrays; under
  ``jit``/``vmap``/``grad`` (tracers) only the shape checks run, and the functions are traceable.

Conventions (see docs/design.md): ``T_a_b`` maps points of frame *b* into frame *a*; internal units are
metres and radians; quaternions are ``wxyz`` unit quaternions with ``w >= 0`` on output.

- OpenCV: ``rvec`` = axis * angle (rad), ``tvec`` (m); ``R = cv2.Rodrigues(rvec)[0]``.
- ROS: quaternions ``xyzw``; position in metres.
- ABB (RAPID ``pose``/``robtarget``): ``trans = [x, y, z]`` in mm, ``rot = [q1, q2, q3, q4]`` with
  ``q1 = w`` (``wxyz``). RAPID rounds quaternions to ~6 digits, so quaternions within
  ``QUAT_NORM_TOL`` of unit norm are accepted and normalised.
- KUKA (``E6POS``/``FRAME``): ``X, Y, Z`` in mm and ``A, B, C`` in degrees, intrinsic Z-Y'-X'':
  ``R = Rz(A) Ry(B) Rx(C)``. At gimbal lock (``B = +-90 deg``) only ``A - C`` (B = +90) or
  ``A + C`` (B = -90) is determined; :func:`matrix_to_kuka` then returns ``C = 0``.
- Euler angles: :func:`euler_to_matrix` / :func:`matrix_to_euler` with the axis sequence named
  explicitly: any of the 6 Tait-Bryan (``XYZ``, ``XZY``, ``YXZ``, ``YZX``, ``ZXY``, ``ZYX``) and 6 proper
  (``XYX``, ``XZX``, ``YXY``, ``YZY``, ``ZXZ``, ``ZYZ``) sequences, intrinsic (rotating axes,
  ``R = R1(a) R2(b) R3(c)``) or extrinsic (fixed axes, ``R = R3(c) R2(b) R1(a)``). Angles come back
  with the middle one in ``[-pi/2, pi/2]`` (Tait-Bryan) or ``[0, pi]`` (proper), the others in
  ``[-pi, pi]``. At gimbal lock the **third** angle is set to 0 (as scipy does), for both intrinsic
  and extrinsic sequences.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry import lie_kernels as kernels

__all__ = [
    "GIMBAL_LOCK_TOL",
    "ORTHONORMAL_TOL",
    "QUAT_NORM_TOL",
    "abb_to_matrix",
    "euler_to_matrix",
    "kuka_to_matrix",
    "matrix_to_abb",
    "matrix_to_euler",
    "matrix_to_kuka",
    "matrix_to_pose",
    "matrix_to_quat",
    "matrix_to_ros",
    "matrix_to_rvec",
    "matrix_to_rvec_tvec",
    "pose_to_matrix",
    "quat_to_matrix",
    "quat_wxyz_to_xyzw",
    "quat_xyzw_to_wxyz",
    "ros_to_matrix",
    "rvec_to_matrix",
    "rvec_tvec_to_matrix",
]

ORTHONORMAL_TOL = 1e-5
"""Largest accepted ``max |R^T R - I|`` of an input rotation (a matrix printed to 6 decimals passes)."""

QUAT_NORM_TOL = 1e-3
"""Largest accepted ``| |q| - 1 |`` of an input quaternion; accepted ones are normalised."""

GIMBAL_LOCK_TOL = 1e-12
"""Euler extraction treats ``cos(middle angle)`` (Tait-Bryan) or ``sin(middle angle)`` (proper)
below this as gimbal lock and sets the third angle to 0; the reconstructed matrix is then off by
at most this much."""

_HOMOGENEOUS_TOL = 1e-9


# ----------------------------------------------------------------------------------------------
# Input handling
# ----------------------------------------------------------------------------------------------


def _xp(*args: Any):
    return jnp if any(isinstance(a, jax.Array) for a in args) else np


def _is_concrete(x: Any) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _as_array(x: Any, name: str, trailing: tuple[int, ...], xp) -> Any:
    try:
        arr = xp.asarray(x, dtype=xp.float64)
    except (TypeError, ValueError) as err:
        raise BadInputError(f"{name}: expected a numeric array, got {x!r} ({err})") from None
    if arr.ndim < len(trailing) or tuple(arr.shape[arr.ndim - len(trailing) :]) != trailing:
        want = ", ".join(map(str, trailing))
        raise BadInputError(f"{name}: expected shape (..., {want}), got shape {tuple(arr.shape)}")
    if _is_concrete(arr):
        values = np.asarray(arr)
        if not np.all(np.isfinite(values)):
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(values))[0])
            raise BadInputError(
                f"{name}: expected finite numbers, got {values[bad]} at index {bad}"
            )
    return arr


def _check_rotation(rot: Any, name: str) -> None:
    if not _is_concrete(rot):
        return
    r = np.asarray(rot)
    err = np.abs(np.einsum("...ji,...jk->...ik", r, r) - np.eye(3)).max(axis=(-2, -1))
    det = np.linalg.det(r)
    bad = (err > ORTHONORMAL_TOL) | (det <= 0.0)
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(np.atleast_1d(bad))[0]) if r.ndim > 2 else ()
        e, d = np.asarray(err)[idx] if idx else err, np.asarray(det)[idx] if idx else det
        where = f" at batch index {idx}" if idx else ""
        raise BadInputError(
            f"{name}: expected a proper rotation (orthonormal, det +1){where}, got "
            f"max|R^T R - I| = {float(e):.3g} (tolerance {ORTHONORMAL_TOL:g}) and det = "
            f"{float(d):.6g}"
        )


def _check_homogeneous(mat: Any, name: str) -> None:
    if not _is_concrete(mat):
        return
    row = np.asarray(mat)[..., 3, :]
    err = np.abs(row - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1)
    if np.any(err > _HOMOGENEOUS_TOL):
        bad = np.argwhere(np.atleast_1d(err > _HOMOGENEOUS_TOL))[0]
        got = row[tuple(bad)] if row.ndim > 1 else row
        raise BadInputError(
            f"{name}: expected a 4x4 homogeneous transform with bottom row [0, 0, 0, 1], got "
            f"{np.asarray(got).tolist()}"
        )


def _check_quat(q: Any, name: str) -> None:
    if not _is_concrete(q):
        return
    norm = np.linalg.norm(np.asarray(q), axis=-1)
    if np.any(norm < 1e-12):
        raise BadInputError(f"{name}: expected a unit quaternion, got a zero quaternion")
    if np.any(np.abs(norm - 1.0) > QUAT_NORM_TOL):
        worst = float(np.atleast_1d(norm)[np.argmax(np.atleast_1d(np.abs(norm - 1.0)))])
        raise BadInputError(
            f"{name}: expected a unit quaternion (|q| = 1 within {QUAT_NORM_TOL:g}), got |q| = "
            f"{worst:.6g}; check the component order (wxyz vs xyzw) and the values"
        )


def _rotation_in(rotation: Any, name: str, xp):
    r = _as_array(rotation, name, (3, 3), xp)
    _check_rotation(r, name)
    return r


def _transform_in(matrix: Any, name: str, xp):
    m = _as_array(matrix, name, (4, 4), xp)
    _check_homogeneous(m, name)
    _check_rotation(m[..., :3, :3], f"{name} (rotation block)")
    return m


def _quat_in(q: Any, name: str, xp):
    arr = _as_array(q, name, (4,), xp)
    _check_quat(arr, name)
    return kernels.quat_normalize(arr, xp)


def _homogeneous(rot, trans, xp):
    top = xp.concatenate([rot, trans[..., None]], axis=-1)
    bottom = xp.broadcast_to(xp.asarray([0.0, 0.0, 0.0, 1.0]), top.shape[:-2] + (1, 4))
    return xp.concatenate([top, bottom], axis=-2)


def _broadcast_pair(a, na: int, b, nb: int, xp):
    lead = np.broadcast_shapes(a.shape[: a.ndim - na], b.shape[: b.ndim - nb])
    return (
        xp.broadcast_to(a, lead + tuple(a.shape[a.ndim - na :])),
        xp.broadcast_to(b, lead + tuple(b.shape[b.ndim - nb :])),
    )


# ----------------------------------------------------------------------------------------------
# Quaternions, rotation vectors, 4x4
# ----------------------------------------------------------------------------------------------


def quat_to_matrix(q):
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``q (..., 4)`` in ``wxyz`` order."""
    xp = _xp(q)
    return kernels.quat_to_matrix(_quat_in(q, "q", xp), xp)


def matrix_to_quat(rotation):
    """Unit quaternions ``(..., 4)`` ``wxyz``, ``w >= 0``, of rotation matrices ``(..., 3, 3)``."""
    xp = _xp(rotation)
    return kernels.matrix_to_quat(_rotation_in(rotation, "rotation", xp), xp)


def quat_wxyz_to_xyzw(q):
    """Reorder quaternions ``(..., 4)`` from ``wxyz`` (jcalib, ABB) to ``xyzw`` (ROS, scipy)."""
    xp = _xp(q)
    arr = _as_array(q, "q", (4,), xp)
    return xp.concatenate([arr[..., 1:], arr[..., :1]], axis=-1)


def quat_xyzw_to_wxyz(q):
    """Reorder quaternions ``(..., 4)`` from ``xyzw`` (ROS, scipy) to ``wxyz`` (jcalib, ABB)."""
    xp = _xp(q)
    arr = _as_array(q, "q", (4,), xp)
    return xp.concatenate([arr[..., 3:], arr[..., :3]], axis=-1)


def rvec_to_matrix(rvec):
    """Rotation matrices ``(..., 3, 3)`` of OpenCV rotation vectors ``(..., 3)`` (rad)."""
    xp = _xp(rvec)
    return kernels.quat_to_matrix(kernels.so3_exp(_as_array(rvec, "rvec", (3,), xp), xp), xp)


def matrix_to_rvec(rotation):
    """OpenCV rotation vectors ``(..., 3)`` (rad, angle in [0, pi]) of rotations ``(..., 3, 3)``."""
    xp = _xp(rotation)
    return kernels.so3_log(kernels.matrix_to_quat(_rotation_in(rotation, "rotation", xp), xp), xp)


def rvec_tvec_to_matrix(rvec, tvec):
    """4x4 transforms ``(..., 4, 4)`` of OpenCV ``rvec (..., 3)`` (rad) and ``tvec (..., 3)`` (m).

    For ``rvec, tvec`` from ``cv2.solvePnP`` this is ``T_cam_target``.
    """
    xp = _xp(rvec, tvec)
    r = _as_array(rvec, "rvec", (3,), xp)
    t = _as_array(tvec, "tvec", (3,), xp)
    r, t = _broadcast_pair(r, 1, t, 1, xp)
    return _homogeneous(kernels.quat_to_matrix(kernels.so3_exp(r, xp), xp), t, xp)


def matrix_to_rvec_tvec(matrix):
    """OpenCV ``(rvec (..., 3) rad, tvec (..., 3) m)`` of 4x4 transforms ``(..., 4, 4)``."""
    xp = _xp(matrix)
    m = _transform_in(matrix, "matrix", xp)
    return kernels.so3_log(kernels.matrix_to_quat(m[..., :3, :3], xp), xp), m[..., :3, 3]


def pose_to_matrix(pose):
    """4x4 transforms ``(..., 4, 4)`` (m) of jcalib poses ``(..., 7)`` (``wxyz`` then ``xyz`` m)."""
    xp = _xp(pose)
    p = _as_array(pose, "pose", (7,), xp)
    _check_quat(p[..., :4], "pose (quaternion part)")
    return _homogeneous(kernels.quat_to_matrix(p[..., :4], xp), p[..., 4:], xp)


def matrix_to_pose(matrix):
    """jcalib poses ``(..., 7)`` (``wxyz`` with ``w >= 0``, then ``xyz`` m) of 4x4 transforms."""
    xp = _xp(matrix)
    m = _transform_in(matrix, "matrix", xp)
    return xp.concatenate([kernels.matrix_to_quat(m[..., :3, :3], xp), m[..., :3, 3]], axis=-1)


def ros_to_matrix(position, quat_xyzw):
    """4x4 transforms (m) of ROS ``position (..., 3)`` (m) and ``orientation`` quaternion ``xyzw``."""
    xp = _xp(position, quat_xyzw)
    p = _as_array(position, "position", (3,), xp)
    q = _quat_in(quat_xyzw, "quat_xyzw", xp)
    q = xp.concatenate([q[..., 3:], q[..., :3]], axis=-1)
    p, q = _broadcast_pair(p, 1, q, 1, xp)
    return _homogeneous(kernels.quat_to_matrix(q, xp), p, xp)


def matrix_to_ros(matrix):
    """ROS ``(position (..., 3) m, quaternion (..., 4) xyzw with w >= 0)`` of 4x4 transforms."""
    xp = _xp(matrix)
    m = _transform_in(matrix, "matrix", xp)
    q = kernels.matrix_to_quat(m[..., :3, :3], xp)
    return m[..., :3, 3], xp.concatenate([q[..., 1:], q[..., :1]], axis=-1)


# ----------------------------------------------------------------------------------------------
# Robot controllers
# ----------------------------------------------------------------------------------------------


def abb_to_matrix(trans_mm, quat):
    """4x4 transforms (m) of an ABB pose: ``trans_mm (..., 3)`` in mm, ``quat (..., 4)`` = [q1..q4]
    with ``q1 = w``. Quaternions within ``QUAT_NORM_TOL`` of unit norm are normalised."""
    xp = _xp(trans_mm, quat)
    t = _as_array(trans_mm, "trans_mm", (3,), xp) * 1e-3
    q = _quat_in(quat, "quat", xp)
    t, q = _broadcast_pair(t, 1, q, 1, xp)
    return _homogeneous(kernels.quat_to_matrix(q, xp), t, xp)


def matrix_to_abb(matrix):
    """ABB ``(trans_mm (..., 3), quat (..., 4))`` of 4x4 transforms (m); ``quat = [q1..q4]``,
    ``q1 = w >= 0``."""
    xp = _xp(matrix)
    m = _transform_in(matrix, "matrix", xp)
    return m[..., :3, 3] * 1e3, kernels.matrix_to_quat(m[..., :3, :3], xp)


def kuka_to_matrix(xyzabc):
    """4x4 transforms (m) of KUKA frames ``[X, Y, Z, A, B, C] (..., 6)`` (mm, degrees),
    ``R = Rz(A) Ry(B) Rx(C)``."""
    xp = _xp(xyzabc)
    v = _as_array(xyzabc, "xyzabc", (6,), xp)
    rot = _euler_to_matrix(v[..., 3:] * (np.pi / 180.0), (2, 1, 0), True, xp)
    return _homogeneous(rot, v[..., :3] * 1e-3, xp)


def matrix_to_kuka(matrix):
    """KUKA frames ``[X, Y, Z, A, B, C] (..., 6)`` (mm, degrees) of 4x4 transforms (m).

    ``B`` is in ``[-90, 90]``, ``A`` and ``C`` in ``[-180, 180]``; at ``B = +-90`` (gimbal lock)
    ``C = 0``.
    """
    xp = _xp(matrix)
    m = _transform_in(matrix, "matrix", xp)
    abc = _matrix_to_euler_intrinsic(m[..., :3, :3], (2, 1, 0), False, xp) * (180.0 / np.pi)
    return xp.concatenate([m[..., :3, 3] * 1e3, abc], axis=-1)


# ----------------------------------------------------------------------------------------------
# Euler angles
# ----------------------------------------------------------------------------------------------


def _parse_axes(axes: Any) -> tuple[int, int, int]:
    if not isinstance(axes, str) or len(axes) != 3 or any(c not in "XYZxyz" for c in axes):
        raise BadInputError(
            f"axes: expected three letters from X, Y, Z such as 'ZYX' or 'ZYZ', got {axes!r}"
        )
    idx = tuple("XYZ".index(c) for c in axes.upper())
    if idx[0] == idx[1] or idx[1] == idx[2]:
        raise BadInputError(
            f"axes: consecutive axes must differ (Tait-Bryan like 'ZYX' or proper Euler like "
            f"'ZYZ'), got {axes!r}"
        )
    return idx  # type: ignore[return-value]


def _elementary(axis: int, angle, xp):
    c, s = xp.cos(angle), xp.sin(angle)
    one, zero = xp.ones_like(angle), xp.zeros_like(angle)
    if axis == 0:
        rows = [[one, zero, zero], [zero, c, -s], [zero, s, c]]
    elif axis == 1:
        rows = [[c, zero, s], [zero, one, zero], [-s, zero, c]]
    else:
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    return xp.stack([xp.stack(r, axis=-1) for r in rows], axis=-2)


def _mm(a, b, xp):
    return xp.einsum("...ij,...jk->...ik", a, b)


def _mtm(a, b, xp):
    """a^T b."""
    return xp.einsum("...ji,...jk->...ik", a, b)


def _euler_to_matrix(angles, seq, intrinsic: bool, xp):
    r = [_elementary(seq[n], angles[..., n], xp) for n in range(3)]
    if intrinsic:
        return _mm(_mm(r[0], r[1], xp), r[2], xp)
    return _mm(_mm(r[2], r[1], xp), r[0], xp)


def _matrix_to_euler_intrinsic(rot, seq, zero_first: bool, xp):
    """Angles (a, b, c) with rot = R_i(a) R_j(b) R_l(c); at gimbal lock a = 0 (zero_first) or c = 0.

    The angle not fixed at lock is recovered last from the matrix with the other two removed, so
    the reconstruction is exact to rounding even close to gimbal lock.
    """
    i, j, l = seq
    k = 3 - i - j
    e = 1.0 if (i, j, k) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)) else -1.0
    if l == k:  # Tait-Bryan
        cb = xp.hypot(rot[..., i, i], rot[..., i, j])
        b = xp.arctan2(e * rot[..., i, k], cb)
        lock = cb < GIMBAL_LOCK_TOL
    else:  # proper Euler (l == i)
        sb = xp.hypot(rot[..., i, j], rot[..., i, k])
        b = xp.arctan2(sb, rot[..., i, i])
        lock = sb < GIMBAL_LOCK_TOL
    if zero_first:
        if l == k:
            a = xp.arctan2(-e * rot[..., j, k], rot[..., k, k])
        else:
            a = xp.arctan2(rot[..., j, i], -e * rot[..., k, i])
        a = xp.where(lock, 0.0, a)
        n = _mtm(_elementary(j, b, xp), _mtm(_elementary(i, a, xp), rot, xp), xp)  # = R_l(c)
        if l == k:
            c = xp.arctan2(e * n[..., j, i], n[..., i, i])
        else:
            c = xp.arctan2(e * n[..., k, j], n[..., j, j])
    else:
        if l == k:
            c = xp.arctan2(-e * rot[..., i, j], rot[..., i, i])
        else:
            c = xp.arctan2(rot[..., i, j], e * rot[..., i, k])
        c = xp.where(lock, 0.0, c)
        rc_t = xp.swapaxes(_elementary(l, c, xp), -1, -2)
        rb_t = xp.swapaxes(_elementary(j, b, xp), -1, -2)
        m = _mm(_mm(rot, rc_t, xp), rb_t, xp)  # = R_i(a)
        a = xp.arctan2(e * m[..., k, j], m[..., j, j])
    return xp.stack([a, b, c], axis=-1)


def euler_to_matrix(angles, axes: str = "ZYX", intrinsic: bool = True, degrees: bool = False):
    """Rotation matrices ``(..., 3, 3)`` of Euler angles ``(..., 3)``.

    Args:
        angles: ``(a, b, c)`` about the axes of ``axes`` in order (rad, or degrees if ``degrees``).
        axes: the sequence, e.g. ``"ZYX"`` (Tait-Bryan) or ``"ZYZ"`` (proper Euler); case-insensitive.
        intrinsic: rotating axes, ``R = R1(a) R2(b) R3(c)`` (KUKA ABC is intrinsic ``ZYX``); if
            False, fixed (extrinsic) axes applied in order, ``R = R3(c) R2(b) R1(a)``.
        degrees: angles in degrees.
    """
    seq = _parse_axes(axes)
    xp = _xp(angles)
    ang = _as_array(angles, "angles", (3,), xp)
    if degrees:
        ang = ang * (np.pi / 180.0)
    return _euler_to_matrix(ang, seq, bool(intrinsic), xp)


def matrix_to_euler(rotation, axes: str = "ZYX", intrinsic: bool = True, degrees: bool = False):
    """Euler angles ``(..., 3)`` of rotation matrices ``(..., 3, 3)``; inverse of
    :func:`euler_to_matrix` with the same ``axes``/``intrinsic``/``degrees``.

    The middle angle is in ``[-pi/2, pi/2]`` (Tait-Bryan) or ``[0, pi]`` (proper), the others in
    ``[-pi, pi]``. At gimbal lock (see ``GIMBAL_LOCK_TOL``) the third angle is 0. Not
    differentiable exactly at gimbal lock.
    """
    seq = _parse_axes(axes)
    xp = _xp(rotation)
    rot = _rotation_in(rotation, "rotation", xp)
    if intrinsic:
        ang = _matrix_to_euler_intrinsic(rot, seq, False, xp)
    else:
        # R = R3(c) R2(b) R1(a) is the intrinsic sequence (3, 2, 1) with angles (c, b, a); the third
        # listed angle c is that sequence's first one.
        rev = _matrix_to_euler_intrinsic(rot, seq[::-1], True, xp)
        ang = rev[..., ::-1]
    if degrees:
        ang = ang * (180.0 / np.pi)
    return ang
