"""Vision: images -> observations with OpenCV (chessboards, ChArUco boards, circle grids, AprilGrids and
AprilTags, tool tips), and tracking a target through a live stream."""

from jcalib.vision.detect import DETECTION_FAILURE_REASONS, TargetDetection, default_jobs, detect_many, detect_target
from jcalib.vision.image import load_image
from jcalib.vision.tooltip import TOOLTIP_FAILURE_REASONS, ToolTipDetection, detect_tool_tip
from jcalib.vision.track import track_target

__all__ = [
    "DETECTION_FAILURE_REASONS",
    "TOOLTIP_FAILURE_REASONS",
    "TargetDetection",
    "ToolTipDetection",
    "default_jobs",
    "detect_many",
    "detect_target",
    "detect_tool_tip",
    "load_image",
    "track_target",
]
