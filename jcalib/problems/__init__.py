"""User-facing calibration problems built from residuals, initialisers and the engine."""

from jcalib.problems.camera import (
    CameraCalibration,
    CameraCalibrationOptions,
    calibrate_cameras,
    calibrate_cameras_batch,
)

from jcalib.problems.handeye import HandEyeCalibration, HandEyeOptions, calibrate_hand_eye

__all__ = [
    "CameraCalibration",
    "CameraCalibrationOptions",
    "HandEyeCalibration",
    "HandEyeOptions",
    "calibrate_cameras",
    "calibrate_cameras_batch",
    "calibrate_hand_eye",
]
