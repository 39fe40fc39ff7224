"""Visual servo: bring the tool tip onto a pixel (the image centre) by moving the flange.

The thesis' algorithm 4.1 (Toffano 2015, camera-based TCP calibration): a camera is fixed in the
cell, its orientation in the robot base ``R_base_cam`` is known (a hand-eye result, or measured by
pure flange translations), and the robot holds a tool whose tip the camera sees on a backlight.
Repeat until the tip is within ``tolerance_px`` of the target pixel:

1. grab an image and detect the tip (:func:`jcalib.vision.tooltip.detect_tool_tip`);
2. pixel error ``e = target - tip``;
3. map it through the image Jacobian ``J`` (2x2, pixels per metre of flange translation along the
   camera's x and y axes) to a translation in the camera's x-y plane, ``dx = gain * J^-1 e``, and
   through the camera-to-base rotation to the base frame, ``dt = R_base_cam[:, :2] dx``;
4. command the flange to its current pose translated by ``dt`` (orientation unchanged) through the
   robot driver interface (:class:`jcalib.acquisition.robots.base.Robot`).

Moving in the camera's x-y plane keeps the tip's depth, so ``J`` stays nearly constant. ``J`` is
given (``fx / depth``, ``fy / depth`` for a camera near its principal point) or measured by two
probing moves of ``probe_m`` along the camera x and y axes, and refined after every move by a
Broyden update from the measured pixel motion and the robot's reported translation, so a rough
start (unknown depth, lens distortion, a slightly wrong ``R_base_cam``) still converges.

Frames: ``T_base_flange`` maps flange points to base (m); pixels follow OpenCV (the centre of the
top-left pixel is (0, 0)); the default target is the image centre ``((W - 1) / 2, (H - 1) / 2)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jcalib.acquisition.cameras.base import Camera
from jcalib.acquisition.robots.base import Robot
from jcalib.errors import BadInputError, DetectionError

#: Shortest image motion (px) of a correction move that updates the image Jacobian (Broyden).
BROYDEN_MIN_PX = 2.0

__all__ = ["ServoResult", "ServoStep", "servo_tool_tip"]


@dataclass(frozen=True)
class ServoStep:
    """One image of the servo loop.

    Attributes:
        kind: ``"start"``, ``"probe"`` or ``"correction"`` (the move that preceded this image).
        pixel: ``(2,)`` detected tip, px.
        error_px: distance of the tip from the target pixel, px.
        T_base_flange: ``(4, 4)`` flange pose reported by the robot when the image was taken, m.
    """

    kind: str
    pixel: np.ndarray
    error_px: float
    T_base_flange: np.ndarray


@dataclass(frozen=True)
class ServoResult:
    """Outcome of :func:`servo_tool_tip`.

    Attributes:
        converged: the tip ended within ``tolerance_px`` of the target.
        iterations: number of correction moves made (probing moves not counted).
        pixel: ``(2,)`` the last detected tip, px.
        target_px: ``(2,)`` the target pixel, px.
        error_px: distance of the last tip from the target, px.
        T_base_flange: ``(4, 4)`` the flange pose at the last image, m (base frame).
        image_jacobian: ``(2, 2)`` final estimate, px per m of flange translation along camera x, y.
        steps: every image of the loop in order (:class:`ServoStep`).
    """

    converged: bool
    iterations: int
    pixel: np.ndarray
    target_px: np.ndarray
    error_px: float
    T_base_flange: np.ndarray
    image_jacobian: np.ndarray
    steps: tuple[ServoStep, ...] = field(default=())


def _rotation(R_base_cam: Any) -> np.ndarray:
    try:
        R = np.asarray(R_base_cam, dtype=np.float64)
    except (TypeError, ValueError):
        raise BadInputError(f"R_base_cam: expected a (3, 3) rotation or (4, 4) T_base_cam, got {R_base_cam!r}") from None
    if R.shape == (4, 4):
        R = R[:3, :3]
    if R.shape != (3, 3) or not np.isfinite(R).all() or np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise BadInputError(
            f"R_base_cam: expected a (3, 3) rotation (or a (4, 4) T_base_cam), the camera axes in the base frame; "
            f"got shape {R.shape}"
        )
    return R


def _positive(value: Any, name: str) -> float:
    if not (isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value) and value > 0):
        raise BadInputError(f"{name}: expected a positive number, got {value!r}")
    return float(value)


def servo_tool_tip(
    robot: Robot,
    camera: Camera,
    R_base_cam: Any,
    detect: Callable[[np.ndarray, str], np.ndarray],
    *,
    target_px: Any = None,
    image_jacobian: Any = None,
    tolerance_px: float = 0.5,
    max_iterations: int = 10,
    gain: float = 1.0,
    probe_m: float = 0.002,
    max_step_m: float = 0.02,
    move_kind: str = "linear",
) -> ServoResult:
    """Move the flange (translations only) until the tool tip is on ``target_px`` (algorithm 4.1).

    Args:
        robot: the robot driver (KUKA, ABB or simulated), with the tool mounted.
        camera: the fixed camera watching the tip (a driver of :mod:`jcalib.acquisition.cameras`).
        R_base_cam: ``(3, 3)`` camera axes in the base frame (or the ``(4, 4)`` ``T_base_cam``).
        detect: ``detect(image, name) -> (2,) pixel``, the tip detector (e.g. a closure over
            :func:`jcalib.vision.tooltip.detect_tool_tip` with the camera model); the acquisition
            layer does not import the vision layer.
        target_px: ``(2,)`` pixel to bring the tip to; None = the image centre.
        image_jacobian: ``(2, 2)`` px per m of flange translation along the camera x and y axes
            (e.g. ``diag(fx, fy) / depth``); None = measured by two probing moves.
        tolerance_px: stop when the tip is closer than this to the target, px.
        max_iterations: at most this many correction moves.
        gain: fraction of the predicted correction applied per move, in (0, 1].
        probe_m: length of each probing move, m.
        max_step_m: largest correction move, m (a bad detection cannot throw the robot far).
        move_kind: ``"linear"`` (LIN / MoveL, default) or ``"joint"``.

    Returns:
        :class:`ServoResult` (``converged`` False when ``max_iterations`` ran out).

    Raises:
        BadInputError: malformed arguments; probing moves that do not move the tip in two
            independent image directions (``R_base_cam`` does not match the camera).
        DetectionError: the tip was not found in an image (the message names the step).
        DeviceError: from the robot or camera driver (unreachable pose, lost connection).
    """
    R = _rotation(R_base_cam)
    tolerance_px = _positive(tolerance_px, "tolerance_px")
    probe_m = _positive(probe_m, "probe_m")
    max_step_m = _positive(max_step_m, "max_step_m")
    gain = _positive(gain, "gain")
    if gain > 1.0:
        raise BadInputError(f"gain: expected a value in (0, 1], got {gain!r}")
    if not isinstance(max_iterations, (int, np.integer)) or max_iterations < 0:
        raise BadInputError(f"max_iterations: expected a non-negative int, got {max_iterations!r}")
    if move_kind not in ("linear", "joint"):
        raise BadInputError(f"move_kind: expected 'linear' or 'joint', got {move_kind!r}")
    steps: list[ServoStep] = []
    target: np.ndarray | None = None if target_px is None else np.asarray(target_px, dtype=np.float64)
    if target is not None and (target.shape != (2,) or not np.isfinite(target).all()):
        raise BadInputError(f"target_px: expected a finite (u, v) pixel, got {target_px!r}")

    def look(kind: str) -> ServoStep:
        nonlocal target
        T = np.asarray(robot.state().T_base_flange, dtype=np.float64)
        frame = camera.grab()
        name = f"servo image {len(steps)} ({kind}) of camera {camera.name}"
        try:
            px = np.asarray(detect(frame.image, name), dtype=np.float64)
        except DetectionError as e:
            raise DetectionError(f"visual servo: {e}", e.reason) from None
        if target is None:
            h, w = frame.image.shape[:2]
            target = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
        step = ServoStep(kind, px, float(np.linalg.norm(target - px)), T)
        steps.append(step)
        return step

    def translate(step: ServoStep, d_cam_xy: np.ndarray, kind: str) -> ServoStep:
        T = step.T_base_flange.copy()
        T[:3, 3] += R[:, :2] @ d_cam_xy
        robot.move(T, kind=move_kind)
        return look(kind)

    def planar(a: ServoStep, b: ServoStep) -> np.ndarray:
        """Flange translation from a to b along the camera x, y axes (reported poses), m."""
        return R[:, :2].T @ (b.T_base_flange[:3, 3] - a.T_base_flange[:3, 3])

    cur = look("start")
    if image_jacobian is not None:
        J = np.asarray(image_jacobian, dtype=np.float64)
        if J.shape != (2, 2) or not np.isfinite(J).all():
            raise BadInputError(f"image_jacobian: expected a finite (2, 2) matrix (px/m), got shape {J.shape}")
    else:
        cols, moves = [], []
        for axis in range(2):
            step = translate(cur, probe_m * np.eye(2)[axis], "probe")
            cols.append(step.pixel - cur.pixel)
            moves.append(planar(cur, step))
            cur = step
        # pixel motion = J @ planar motion, from the two (reported) probing moves
        J = np.column_stack(cols) @ np.linalg.inv(np.column_stack(moves))
    s = np.linalg.svd(J, compute_uv=False)
    if not np.isfinite(s).all() or s[-1] <= 1e-6 * max(s[0], 1e-300) or s[0] == 0.0:
        raise BadInputError(
            f"R_base_cam / image_jacobian: translating the flange along the camera x and y axes does not move the "
            f"tip in two independent image directions (singular values {s.tolist()} px/m); check the camera "
            f"orientation R_base_cam and that the tip is in view"
        )
    iterations = 0
    while cur.error_px >= tolerance_px and iterations < max_iterations:
        d = gain * np.linalg.solve(J, target - cur.pixel)
        norm = float(np.linalg.norm(d))
        if norm > max_step_m:
            d *= max_step_m / norm
        nxt = translate(cur, d, "correction")
        iterations += 1
        moved = planar(cur, nxt)
        # Broyden's rank-one update from the observed motion, when the motion is long enough that the
        # detection noise and the robot's repeatability (~0.1 px each) do not set the secant
        if float(np.linalg.norm(J @ moved)) > BROYDEN_MIN_PX:
            J = J + np.outer(nxt.pixel - cur.pixel - J @ moved, moved) / float(moved @ moved)
        cur = nxt
    return ServoResult(
        converged=cur.error_px < tolerance_px,
        iterations=iterations,
        pixel=cur.pixel,
        target_px=np.asarray(target),
        error_px=cur.error_px,
        T_base_flange=cur.T_base_flange,
        image_jacobian=J,
        steps=tuple(steps),
    )
