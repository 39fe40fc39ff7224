"""Camera drivers: GigE Vision through Aravis (opened by address), its fake device, simulated and replay cameras."""

from jcalib.acquisition.cameras.aravis import GigECamera, aravis_available
from jcalib.acquisition.cameras.base import (
    FEATURE_ALIASES,
    Camera,
    Frame,
    FrameRequest,
    FrameSource,
    GrabStats,
    UnsupportedFeatureError,
)
from jcalib.acquisition.cameras.fake_gige import FakeGigECamera
from jcalib.acquisition.cameras.simulated import ReplayCamera, SimulatedCamera

__all__ = [
    "FEATURE_ALIASES",
    "Camera",
    "FakeGigECamera",
    "Frame",
    "FrameRequest",
    "FrameSource",
    "GigECamera",
    "GrabStats",
    "ReplayCamera",
    "SimulatedCamera",
    "UnsupportedFeatureError",
    "aravis_available",
]
