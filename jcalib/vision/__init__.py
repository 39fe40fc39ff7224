"""Vision: images -> observations with OpenCV (chessboards, ChArUco boards, circle grids, AprilGrids and
AprilTags, tool tips)."""

from jcalib.vision.detect import DETECTION_FAILURE_REASONS, TargetDetection, detect_many, detect_target
from jcalib.vision.image import load_image
from jcalib.vision.tooltip import TOOLTIP_FAILURE_REASONS, ToolTipDetection, detect_tool_tip

__all__ = [
    "DETECTION_FAILURE_REASONS",
    "TOOLTIP_FAILURE_REASONS",
    "TargetDetection",
    "ToolTipDetection",
    "detect_many",
    "detect_target",
    "detect_tool_tip",
    "load_image",
]
