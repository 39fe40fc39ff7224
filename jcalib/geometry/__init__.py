"""Geometry: Lie groups and pose conventions, camera models, calibration targets, robot kinematics.

Conventions (docs/design.md): ``T_a_b`` maps points of frame *b* into frame *a*; poses are ``wxyz`` +
``xyz`` 7-vectors (metres) or 4x4 matrices; tangent vectors are ``(rx, ry, rz, tx, ty, tz)`` with
right perturbation ``T · Exp(δ)``.
"""

import importlib

#: Public names and the module that defines each, imported on first use: NumPy-only users (robot
#: servers, :mod:`jcalib.geometry.se3`) do not pay for JAX.
_LAZY = {
    "conversions": None,
    "kinematic_models": None,
    "kinematic_tables": None,
    "lie": None,
    "se3": None,
    "views": None,
    **dict.fromkeys(("CAMERA_MODELS", "AbstractCameraModel", "Fisheye", "OpenCV4", "OpenCV5", "OpenCV8", "OpenCV12",
                     "OpenCV14", "Pinhole", "camera_from_opencv", "camera_model_from_name"), "cameras"),
    **dict.fromkeys(("DHRobot", "forward_kinematics", "inverse_kinematics"), "kinematics"),
    "ROBOT_PRESETS": "robots",
    "robot_preset": "robots",
    **dict.fromkeys(("Charuco", "Checkerboard", "CircleGrid", "target_from_spec"), "targets"),
    **dict.fromkeys(("AprilGrid", "AprilTag"), "apriltags"),
}


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module 'jcalib.geometry' has no attribute {name!r}")
    module = _LAZY[name]
    if module is None:
        value = importlib.import_module(f"jcalib.geometry.{name}")
    else:
        value = getattr(importlib.import_module(f"jcalib.geometry.{module}"), "PRESETS" if name == "ROBOT_PRESETS" else name)
    globals()[name] = value
    return value


__all__ = [
    "CAMERA_MODELS",
    "ROBOT_PRESETS",
    "AbstractCameraModel",
    "AprilGrid",
    "AprilTag",
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
    "kinematic_models",
    "kinematic_tables",
    "lie",
    "robot_preset",
    "se3",
    "target_from_spec",
    "views",
]
