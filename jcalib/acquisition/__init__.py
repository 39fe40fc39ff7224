"""Acquisition: drive cameras and robots, write capture sessions (see DESIGN.md, "Capture session").

Cameras (:mod:`jcalib.acquisition.cameras`): GigE Vision through Aravis, opened by IP address; a fake
GigE camera serving rendered frames; in-process simulated and replay cameras. Robots
(:mod:`jcalib.acquisition.robots`): KUKA (KUKAVARPROXY), ABB (jcalib RAPID server), simulated
controllers and their protocol servers. :func:`cell_layout` + :func:`plan_cell` plan stations
(``jcalib plan``); :func:`capture` runs a station plan (:mod:`jcalib.io.plan`) into a session (:mod:`jcalib.io.session`, ``jcalib capture``);
:mod:`jcalib.pipeline.session` turns a session into observations (``jcalib detect --session``).
"""

from jcalib.acquisition.capture import CaptureInterrupted, CaptureResult, SkipStation, apply_camera_settings, capture
from jcalib.acquisition.layout import CellLayout, cell_layout
from jcalib.acquisition.planner import PlannedStations, plan_cell
from jcalib.acquisition.robocalib import RoboCalibPlan, handeye_stations, viewset_stations
from jcalib.acquisition.servo import ServoResult, servo_tool_tip
from jcalib.acquisition.capture import CaptureControl

__all__ = [
    "CaptureControl",
    "CaptureInterrupted",
    "CaptureResult",
    "CellLayout",
    "PlannedStations",
    "RoboCalibPlan",
    "ServoResult",
    "SkipStation",
    "apply_camera_settings",
    "capture",
    "cell_layout",
    "plan_cell",
    "servo_tool_tip",
    "handeye_stations",
    "viewset_stations",
]
