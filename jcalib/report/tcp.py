"""TCP uncertainty for the report: a TCP calibration as a result file, σ of the TCP per flange axis
and of a gripped point in the robot base frame.

A TCP is the transform ``T_flange_<tool>`` of a result file (docs/design.md), its covariance ``(6, 6)``
over the right-perturbation tangent ``(rx, ry, rz, tx, ty, tz)`` (rad, m) in the TCP frame. The TCP
*position* a robot controller takes is the tip in the flange frame, ``t = T_flange_tcp[:3, 3]``; to
first order a tangent ``δ = (ω, v)`` moves it by ``R_flange_tcp · v``, so its covariance in the
flange frame is ``R C_vv Rᵀ``. A point ``p`` held in the TCP frame (a gripped part's point) sits in
the base frame at ``p_base = T_base_flange · T_flange_tcp · p``; its covariance is propagated from
the TCP's (and, optionally, from the robot's pose repeatability) with closed-form first-order
Jacobians.

What the σ include: the sampling noise the TCP calibration propagated (tip pixel noise, robot pose
noise when its pose model was on, free camera pose / intrinsics), scaled as the solver scaled it;
with ``robot_covariance`` also the robot's repeatability at the pose where the point is used. What
they do not: model error (tip-detection bias, robot absolute-accuracy error beyond the stated
repeatability), and, when the TCP orientation was not estimated (no tool axis observed), the
orientation error of the TCP frame (its rotation covariance is zero: held at its start).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.result import CameraResult, Provenance, ResultFile, TransformResult

__all__ = [
    "DEFAULT_GRIPPED_POINT_M",
    "GRIP_REFERENCE_KEY",
    "gripped_point_covariance",
    "is_tcp",
    "robot_covariance",
    "tcp_position_covariance",
    "tcp_result_file",
    "tcp_std_mm",
]

#: Optional top-level key of a result file: ``(4, 4)`` flange pose ``T_base_flange`` (m) at which
#: the report evaluates the σ of a gripped point in the base frame (a typical working pose; the
#: per-axis σ in the base frame depend on the flange orientation, their total does not).
GRIP_REFERENCE_KEY = "T_base_flange_reference"

#: The gripped point the report shows by default, in the TCP frame (m): 100 mm along the tool z
#: axis beyond the tip (where a gripped part's far end typically is).
DEFAULT_GRIPPED_POINT_M = (0.0, 0.0, 0.1)


def _skew(p: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])


def is_tcp(name: str, file: ResultFile) -> bool:
    """Whether transform ``name`` of ``file`` is a TCP.

    A TCP is ``T_flange_<x>`` with ``x`` not a camera. An eye-to-hand cell's flange-mounted target is
    ``T_flange_<target>`` too, next to ``T_base_<camera>``; so a transform is taken for a TCP when it
    says so: the extra key ``"orientation"`` (every tool of a calibration result has it) or ``"kind":
    "tcp"`` (:func:`tcp_result_file` writes it), or, without either, when the file has no
    ``T_base_<camera>`` (then it cannot be an eye-to-hand target).
    """
    if not name.startswith("T_flange_"):
        return False
    child = name[len("T_flange_"):]
    if child in file.cameras:
        return False
    tr = file.transforms[name]
    if tr.extra.get("kind") == "tcp" or tr.extra.get("orientation") is not None:
        return True
    if tr.extra.get("kind") is not None:
        return False
    # eye-to-hand cell: T_base_<camera> plus one T_flange_<target> observed by that camera
    return not any(f"T_base_{c}" in file.transforms for c in file.cameras)


def tcp_position_covariance(tcp: TransformResult) -> np.ndarray:
    """``(3, 3)`` covariance (m²) of the TCP position (the tip) in the flange frame.

    Args:
        tcp: ``T_flange_tcp`` with its right-perturbation covariance.

    Raises:
        BadInputError: the transform has no covariance.
    """
    if tcp.covariance is None:
        raise BadInputError("tcp: the transform has no covariance; the TCP σ needs one")
    R = np.asarray(tcp.matrix, np.float64)[:3, :3]
    C = np.asarray(tcp.covariance, np.float64)[3:, 3:]
    out = R @ C @ R.T
    return 0.5 * (out + out.T)


def tcp_std_mm(tcp: TransformResult) -> np.ndarray:
    """``(3,)`` 1σ of the TCP position per flange axis (x, y, z), mm."""
    return 1e3 * np.sqrt(np.maximum(np.diag(tcp_position_covariance(tcp)), 0.0))


def gripped_point_covariance(
    tcp: TransformResult,
    T_base_flange: np.ndarray,
    p_tcp: Sequence[float] = (0.0, 0.0, 0.0),
    robot_covariance: np.ndarray | None = None,
) -> np.ndarray:
    """``(3, 3)`` covariance (m², base frame) of a point held in the TCP frame.

    ``p_base = R_bf (t_ft + R_ft p) + t_bf``. With ``δ = (ω, v)`` the right perturbation of
    ``T_flange_tcp`` (its covariance), ``∂p_base/∂δ = R_bf R_ft [-[p]×, I]``; with ``ε = (ω_B, v_B)``
    that of ``T_base_flange`` (``robot_covariance``, flange frame, the robot's repeatability),
    ``∂p_base/∂ε = R_bf [-[q]×, I]`` with ``q = T_flange_tcp · p`` (flange frame). The two are
    independent.

    Args:
        tcp: ``T_flange_tcp`` with covariance.
        T_base_flange: ``(4, 4)`` flange pose where the point is used, m.
        p_tcp: ``(3,)`` the point in the TCP frame, m (``0``: the tool tip).
        robot_covariance: optional ``(6, 6)`` right-perturbation covariance (rad², m²) of the
            reached flange pose (the robot's repeatability); None: the TCP's uncertainty only.

    Returns:
        ``(3, 3)`` covariance, m², in the base frame.
    """
    if tcp.covariance is None:
        raise BadInputError("tcp: the transform has no covariance; the gripped point's σ needs one")
    B = np.asarray(T_base_flange, np.float64)
    if B.shape != (4, 4) or not np.all(np.isfinite(B)):
        raise BadInputError(f"T_base_flange: expected a finite 4x4 matrix (m), got shape {B.shape}")
    p = np.asarray(p_tcp, np.float64)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise BadInputError(f"p_tcp: expected 3 finite coordinates (m), got {p_tcp!r}")
    T = np.asarray(tcp.matrix, np.float64)
    J = B[:3, :3] @ T[:3, :3] @ np.concatenate([-_skew(p), np.eye(3)], axis=1)
    C = J @ np.asarray(tcp.covariance, np.float64) @ J.T
    if robot_covariance is not None:
        Cr = np.asarray(robot_covariance, np.float64)
        if Cr.shape != (6, 6):
            raise BadInputError(f"robot_covariance: expected shape (6, 6) (rad², m²), got {Cr.shape}")
        q = T[:3, :3] @ p + T[:3, 3]
        Jb = B[:3, :3] @ np.concatenate([-_skew(q), np.eye(3)], axis=1)
        C = C + Jb @ Cr @ Jb.T
    return 0.5 * (C + C.T)


def robot_covariance(file: ResultFile, name: str | None = None, estimate: bool = False) -> np.ndarray | None:
    """``(6, 6)`` flange-pose covariance from the file's robot prior (``stats.robot.prior_sigma_*``; with
    several robots ``stats.robot.<name>``, the only one when ``name`` is None), or None when the file
    states none. ``estimate``: from the a-posteriori σ the calibration estimated instead
    (``stats.robot.a_posteriori_sigma_*``; None when it has none or could not estimate it)."""
    robot = file.stats.get("robot") or {}
    if "prior_sigma_translation_m" not in robot and robot:  # several robots: robot name -> statistics
        if name is None and len(robot) == 1:
            name = next(iter(robot))
        robot = robot.get(name) or {}
    key = "a_posteriori_sigma" if estimate else "prior_sigma"
    t = robot.get(f"{key}_translation_m")
    if t is None or not np.all(np.isfinite(np.asarray(t, np.float64))):
        return None
    r = robot.get(f"{key}_rotation_deg")
    rot = np.radians(np.asarray(0.0 if r is None else r, np.float64)) * np.ones(3)
    return np.diag(np.concatenate([rot, np.asarray(t, np.float64) * np.ones(3)]) ** 2)


def tcp_result_file(
    cal: Any,
    tool: str = "tool",
    sigma_px: float | None = None,
    pose_noise_translation_m: float | None = None,
    pose_noise_rotation_deg: float | None = None,
    provenance: Provenance | None = None,
) -> ResultFile:
    """A ``jcalib.result/1`` file carrying a :class:`jcalib.problems.tcp.TCPCalibration`.

    ``transforms["T_flange_<tool>"]`` holds the TCP with its joint ``(6, 6)`` covariance (from the
    solution; the rotation rows are zero where the orientation was not estimated: no tool axis, or
    the roll about it), ``transforms["T_base_<camera>"]`` each camera pose (zero covariance when it
    was held), ``cameras`` the intrinsics (σ 0 where held), ``stats`` the residual statistics and the
    robot prior (``robot.prior_sigma_*``) when the pose model was on; the first flange pose is the
    :data:`GRIP_REFERENCE_KEY`.

    Args:
        cal: the TCP calibration.
        tool: tool id (the transform is ``T_flange_<tool>``).
        sigma_px: the stated tip noise σ the calibration used (px): with it, ``stats.sigma_px`` is
            the a-posteriori noise level.
        pose_noise_translation_m, pose_noise_rotation_deg: the robot repeatability the calibration was
            given (its pose model; m and degrees per axis): written as ``stats.robot.prior_sigma_*``,
            the report adds it to the gripped point's σ.
        provenance: optional provenance.
    """
    scale = float(cal.sigma2) if cal.noise == "a_posteriori" else 1.0
    sol = getattr(cal, "solution", None)
    if sol is not None:
        C = scale * np.asarray(sol.covariance("T_flange_tcp", noise="stated"), np.float64)
    else:  # block-diagonal from the tip and axis covariances (their correlation unknown)
        R = np.asarray(cal.T_flange_tcp, np.float64)[:3, :3]
        C = np.zeros((6, 6))
        C[3:, 3:] = R.T @ np.asarray(cal.tip_covariance, np.float64) @ R
        if cal.axis_covariance is not None:
            # δa = R (ω_y, −ω_x, 0): ω_x, ω_y from the axis covariance, roll about the axis held
            A = R.T @ np.asarray(cal.axis_covariance, np.float64) @ R
            M = np.array([[0.0, -1.0], [1.0, 0.0]])  # (ω_x, ω_y) = M (δa_x, δa_y)
            C[:2, :2] = M @ A[:2, :2] @ M.T
    C = 0.5 * (C + C.T)
    transforms = {f"T_flange_{tool}": TransformResult(cal.T_flange_tcp, C, {"kind": "tcp"})}
    cameras = {}
    for name, cam, icov, T, Tc in zip(cal.camera_names, cal.cameras, cal.intrinsics_covariance,
                                      cal.T_base_cam, cal.T_base_cam_covariance):
        cameras[name] = CameraResult.from_model(cam, covariance=np.asarray(icov, np.float64))
        transforms[f"T_base_{name}"] = TransformResult(T, 0.5 * (np.asarray(Tc) + np.asarray(Tc).T))
    res = np.asarray(cal.residuals_px, np.float64)
    stats: dict[str, Any] = {"rms_px": float(cal.rms_px), "num_residuals": int(np.count_nonzero(np.isfinite(res))),
                             "sigma2": float(cal.sigma2), "status": str(cal.status),
                             "iterations": int(cal.iterations), "num_poses": int(res.shape[0])}
    if sigma_px is not None:
        stats["sigma_px"] = float(sigma_px) * (float(np.sqrt(cal.sigma2)) if cal.noise == "a_posteriori" else 1.0)
    if pose_noise_translation_m is not None:
        stats["robot"] = {"prior_sigma_translation_m": [float(pose_noise_translation_m)] * 3,
                          "prior_sigma_rotation_deg": [float(pose_noise_rotation_deg or 0.0)] * 3}
    extra = {GRIP_REFERENCE_KEY: np.asarray(cal.T_base_flange, np.float64)[0].tolist()}
    return ResultFile(cameras=cameras, transforms=transforms, stats=stats, provenance=provenance, extra=extra)
