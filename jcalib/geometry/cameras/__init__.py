"""OpenCV-compatible camera models: project points to pixels and pixels back to rays."""

from jcalib.geometry.cameras.base import AbstractCameraModel
from jcalib.geometry.cameras.factory import (
    CAMERA_MODELS,
    camera_from_opencv,
    camera_model_from_name,
)
from jcalib.geometry.cameras.fisheye import Fisheye
from jcalib.geometry.cameras.opencv import OpenCV4, OpenCV5, OpenCV8, OpenCV12, OpenCV14
from jcalib.geometry.cameras.perspective import AbstractPerspectiveModel
from jcalib.geometry.cameras.pinhole import Pinhole
from jcalib.geometry.cameras.splined import SplinedStereographic

__all__ = [
    "CAMERA_MODELS",
    "AbstractCameraModel",
    "AbstractPerspectiveModel",
    "Fisheye",
    "OpenCV4",
    "OpenCV5",
    "OpenCV8",
    "OpenCV12",
    "OpenCV14",
    "Pinhole",
    "SplinedStereographic",
    "camera_from_opencv",
    "camera_model_from_name",
]
