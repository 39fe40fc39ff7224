"""Vision: images -> target observations with OpenCV (chessboards, ChArUco boards, circle grids)."""

from jcalib.vision.detect import DETECTION_FAILURE_REASONS, TargetDetection, detect_many, detect_target
from jcalib.vision.image import load_image

__all__ = ["DETECTION_FAILURE_REASONS", "TargetDetection", "detect_many", "detect_target", "load_image"]
