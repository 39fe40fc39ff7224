"""User-facing calibration problems built from residuals, initialisers and the engine."""

from jcalib.problems.camera import (
    CameraCalibration,
    CameraCalibrationOptions,
    calibrate_cameras,
    calibrate_cameras_batch,
)

__all__ = ["CameraCalibration", "CameraCalibrationOptions", "calibrate_cameras", "calibrate_cameras_batch"]
