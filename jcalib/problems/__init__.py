"""User-facing calibration problems built from residuals, initialisers and the engine."""

from jcalib.problems.camera import CameraCalibration, CameraCalibrationOptions, calibrate_cameras

__all__ = ["CameraCalibration", "CameraCalibrationOptions", "calibrate_cameras"]
