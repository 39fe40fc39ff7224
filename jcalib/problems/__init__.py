"""User-facing calibration problems built from residuals, initialisers and the engine."""

from jcalib.problems.camera import (
    CameraCalibration,
    CameraCalibrationOptions,
    calibrate_cameras,
    calibrate_cameras_batch,
)
from jcalib.problems.handeye import HandEyeCalibration, HandEyeOptions, calibrate_hand_eye, calibrate_hand_eye_batch
from jcalib.problems.handeye_pairs import HandEyePairsCalibration, PoseNoise, calibrate_hand_eye_pairs
from jcalib.problems.pivot import PivotRefinement, refine_pivot
from jcalib.problems.tcp import TCPCalibration, calibrate_tcp

__all__ = [
    "CameraCalibration",
    "CameraCalibrationOptions",
    "HandEyeCalibration",
    "HandEyeOptions",
    "HandEyePairsCalibration",
    "PivotRefinement",
    "PoseNoise",
    "TCPCalibration",
    "calibrate_cameras",
    "calibrate_cameras_batch",
    "calibrate_hand_eye",
    "calibrate_hand_eye_batch",
    "calibrate_hand_eye_pairs",
    "calibrate_tcp",
    "refine_pivot",
]
