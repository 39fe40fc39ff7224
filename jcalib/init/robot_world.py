"""Closed-form robot-world / hand-eye calibration (AX = ZB): Shah (Kronecker) and Li (Kronecker + linear).

Unlike AX = XB, both unknowns are solved at once from the absolute poses of every station, with no
relative motions. OpenCV's form (``cv2.calibrateRobotWorldHandEye``)::

    T_cam_world_i @ T_world_base = T_cam_gripper @ T_gripper_base_i        (A_i X = Z B_i)

In jcalib's frames:

- eye-in-hand (``mount="flange"``; camera on the flange, target fixed in the base):
  ``T_cam_target_i @ T_target_base = T_cam_flange @ T_flange_base_i``, so ``A_i = T_cam_target_i``,
  ``B_i = T_base_flange_i^-1``, ``X = T_target_base``, ``Z = T_cam_flange``;
- eye-to-hand (``mount="base"``; camera fixed, target on the flange):
  ``T_cam_target_i @ T_target_flange = T_cam_base @ T_base_flange_i``, so ``A_i = T_cam_target_i``,
  ``B_i = T_base_flange_i``, ``X = T_target_flange``, ``Z = T_cam_base``.

Both solvers are our numpy implementations written to agree with OpenCV 4.14's
``CALIB_ROBOT_WORLD_HAND_EYE_SHAH`` / ``_LI`` (same equations, same SVD / least-squares steps, same
nearest-rotation projection). Observability is checked first with the hand-eye motion analysis
(:func:`jcalib.init.handeye_motion.analyse_motion`): AX = ZB has the same degeneracies as AX = XB.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import check_poses, invert, make_pose
from jcalib.init.handeye import HandEyeInit, lstsq_min_norm, project_to_rotation
from jcalib.init.handeye_motion import Mount, check_mount, checked_stations, solution_diagnostics

__all__ = [
    "ROBOT_WORLD_METHODS",
    "RobotWorldInit",
    "solve_ax_zb",
    "solve_robot_world_hand_eye",
]


def _shah(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shah 2013: rotations from the top singular vectors of ``sum kron(R_B, R_A)``, then translations."""
    Ra, ta, Rb, tb = A[:, :3, :3], A[:, :3, 3], B[:, :3, :3], B[:, :3, 3]
    n = len(A)
    T = np.einsum("kij,kab->iajb", Rb, Ra).reshape(9, 9)  # sum_k kron(R_B_k, R_A_k)
    u, _, vt = np.linalg.svd(T)
    # kron(R_B, R_A) vec(R_X) = vec(R_A^T ... ): column-major vec, as OpenCV reads them
    RX = project_to_rotation(vt[0].reshape(3, 3).T)
    RZ = project_to_rotation(u[:, 0].reshape(3, 3).T)
    # -R_A t_X + t_Z = t_A - R_Z t_B
    M = np.zeros((n, 3, 6))
    M[:, :, :3] = -Ra
    M[:, :, 3:] = np.eye(3)
    rhs = ta - tb @ RZ.T
    t = lstsq_min_norm(M.reshape(-1, 6), rhs.reshape(-1))
    return make_pose(RX, t[:3]), make_pose(RZ, t[3:])


def _li(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Li, Wang & Wu 2010: one linear system in ``vec(R_X), vec(R_Z), t_X, t_Z``, then nearest rotations."""
    Ra, ta, Rb, tb = A[:, :3, :3], A[:, :3, 3], B[:, :3, :3], B[:, :3, 3]
    n = len(A)
    I3 = np.eye(3)
    M = np.zeros((n, 12, 24))
    M[:, :9, :9] = np.einsum("kij,ab->kiajb", Ra, I3).reshape(n, 9, 9)  # kron(R_A, I)
    M[:, :9, 9:18] = -np.einsum("ij,kba->kiajb", I3, Rb).reshape(n, 9, 9)  # kron(-I, R_B^T)
    M[:, 9:, 9:18] = np.einsum("ij,kb->kijb", I3, tb).reshape(n, 3, 9)  # kron(I, t_B^T)
    M[:, 9:, 18:21] = -Ra
    M[:, 9:, 21:24] = I3
    rhs = np.zeros((n, 12))
    rhs[:, 9:] = ta
    x = lstsq_min_norm(M.reshape(-1, 24), rhs.reshape(-1))
    RX = project_to_rotation(x[:9].reshape(3, 3))
    RZ = project_to_rotation(x[9:18].reshape(3, 3))
    return make_pose(RX, x[18:21]), make_pose(RZ, x[21:24])


_SOLVERS: dict[str, Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]] = {
    "shah": _shah,
    "li": _li,
}

#: Method names accepted by :func:`solve_robot_world_hand_eye`, with the matching OpenCV constant.
ROBOT_WORLD_METHODS: dict[str, str] = {
    "shah": "CALIB_ROBOT_WORLD_HAND_EYE_SHAH",
    "li": "CALIB_ROBOT_WORLD_HAND_EYE_LI",
}


def solve_ax_zb(A, B, method: str = "shah") -> tuple[np.ndarray, np.ndarray]:
    """Solve ``A_i X = Z B_i`` for ``X`` and ``Z`` (no degeneracy analysis).

    Args:
        A: (N, 4, 4) e.g. ``T_cam_world_i`` (OpenCV's ``world2cam``).
        B: (N, 4, 4) e.g. ``T_gripper_base_i`` (OpenCV's ``base2gripper``).
        method: ``"shah"`` or ``"li"``.

    Returns:
        ``(X, Z)``, each (4, 4): OpenCV's ``base2world`` (``T_world_base``) and ``gripper2cam``
        (``T_cam_gripper``), translations in the input unit.
    """
    if method not in _SOLVERS:
        raise BadInputError(f"method: expected one of {sorted(_SOLVERS)}, got {method!r}")
    A = check_poses(A, "A")
    B = check_poses(B, "B")
    if len(A) != len(B):
        raise BadInputError(f"B: expected one pose per pose of A ({len(A)}), got {len(B)}")
    if len(A) < 3:
        raise BadInputError(f"A: expected at least 3 stations, got {len(A)}")
    return _SOLVERS[method](A, B)


class RobotWorldInit(HandEyeInit):
    """A closed-form robot-world / hand-eye estimate (starting point, no covariance).

    Attributes:
        T: (4, 4) ``T_flange_cam`` (mount ``"flange"``) or ``T_base_cam`` (mount ``"base"``), m.
        T_other: (4, 4) ``T_base_target`` (mount ``"flange"``) or ``T_flange_target`` (mount ``"base"``), m.
        method: ``"shah"`` or ``"li"``.
        mount: ``"flange"`` (eye-in-hand) or ``"base"`` (eye-to-hand).
        diagnostics: the motion analysis and the consistency of the solution with the stations
            (``other_*``: spread of the per-station ``T_other`` implied by ``T``; ``motion_*``:
            residual of ``A_i X`` against ``Z B_i`` over the stations).
    """


def solve_robot_world_hand_eye(
    T_base_flange,
    T_cam_target,
    method: str = "shah",
    mount: Mount = "flange",
    *,
    rotation_noise_deg: float = 0.02,
) -> RobotWorldInit:
    """Closed-form simultaneous hand-eye and target (robot-world) calibration, AX = ZB.

    Args:
        T_base_flange: (N, 4, 4) flange poses in the base frame, metres.
        T_cam_target: (N, 4, 4) target poses in the camera frame, metres.
        method: ``"shah"`` (default) or ``"li"``; agree with ``cv2.calibrateRobotWorldHandEye``.
        mount: ``"flange"`` (eye-in-hand: returns ``T_flange_cam`` and ``T_base_target``) or
            ``"base"`` (eye-to-hand: returns ``T_base_cam`` and ``T_flange_target``).
        rotation_noise_deg: stated 1-sigma rotation noise of one pose, degrees (see
            :func:`jcalib.init.handeye_motion.analyse_motion`).

    Returns:
        :class:`RobotWorldInit`.

    Raises:
        BadInputError: malformed poses, mismatched counts, unknown method / mount.
        NotObservableError: degenerate motion (fewer than 3 stations, no rotation, one rotation axis).
    """
    check_mount(mount)
    if method not in _SOLVERS:
        raise BadInputError(f"method: expected one of {sorted(_SOLVERS)}, got {method!r}")
    T_bf, T_ct, motion = checked_stations(T_base_flange, T_cam_target, mount, "all", rotation_noise_deg)

    B = invert(T_bf) if mount == "flange" else T_bf
    X, Z = _SOLVERS[method](T_ct, B)
    T = invert(Z)  # T_flange_cam or T_base_cam
    T_other = invert(X)  # T_base_target or T_flange_target

    # per-station estimate of T_other implied by T: eye-in-hand T_base_flange_i T T_cam_target_i,
    # eye-to-hand T_base_flange_i^-1 T T_cam_target_i
    Hg = T_bf if mount == "flange" else invert(T_bf)
    per_station = Hg @ T @ T_ct
    diagnostics = solution_diagnostics(motion, per_station, T_other, T_ct @ X, Z @ B)
    return RobotWorldInit(T=T, T_other=T_other, method=method, mount=mount, diagnostics=diagnostics)
