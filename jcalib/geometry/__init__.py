"""Geometry: Lie groups and pose conventions, camera models, calibration targets, robot kinematics.

Conventions (DESIGN.md): ``T_a_b`` maps points of frame *b* into frame *a*; poses are ``wxyz`` +
``xyz`` 7-vectors (metres) or 4x4 matrices; tangent vectors are ``(rx, ry, rz, tx, ty, tz)`` with
right perturbation ``T · Exp(δ)``.
"""

from jcalib.geometry import conversions, lie
from jcalib.geometry.cameras import (
    CAMERA_MODELS,
    AbstractCameraModel,
    Fisheye,
    OpenCV4,
    OpenCV5,
    OpenCV8,
    OpenCV12,
    OpenCV14,
    Pinhole,
    camera_from_opencv,
    camera_model_from_name,
)
from jcalib.geometry.kinematics import DHRobot, forward_kinematics, inverse_kinematics
from jcalib.geometry.robots import PRESETS as ROBOT_PRESETS
from jcalib.geometry.robots import robot_preset
from jcalib.geometry.targets import Charuco, Checkerboard, CircleGrid, target_from_spec

__all__ = [
    "CAMERA_MODELS",
    "ROBOT_PRESETS",
    "AbstractCameraModel",
    "Charuco",
    "Checkerboard",
    "CircleGrid",
    "DHRobot",
    "Fisheye",
    "OpenCV4",
    "OpenCV5",
    "OpenCV8",
    "OpenCV12",
    "OpenCV14",
    "Pinhole",
    "camera_from_opencv",
    "camera_model_from_name",
    "conversions",
    "forward_kinematics",
    "inverse_kinematics",
    "lie",
    "robot_preset",
    "target_from_spec",
]
