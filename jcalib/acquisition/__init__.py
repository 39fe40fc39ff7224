"""Acquisition: drive cameras and robots, write capture sessions (see DESIGN.md, "Capture session").

Cameras (:mod:`jcalib.acquisition.cameras`): GigE Vision through Aravis, opened by IP address; a fake
GigE camera serving rendered frames; in-process simulated and replay cameras. Robots
(:mod:`jcalib.acquisition.robots`): KUKA (KUKAVARPROXY), ABB (jcalib RAPID server), simulated
controllers and their protocol servers. :func:`cell_layout` + :func:`plan_cell` plan stations
(``jcalib plan``); :func:`capture` runs a station plan into a session (``jcalib capture``);
:mod:`jcalib.session_detect` turns a session into observations (``jcalib detect --session``).
"""

from jcalib.acquisition.capture import CaptureInterrupted, CaptureResult, capture
from jcalib.acquisition.layout import CellLayout, cell_layout
from jcalib.acquisition.plan import Plan, Station, load_plan, make_plan, save_plan
from jcalib.acquisition.planner import PlannedStations, plan_cell
from jcalib.acquisition.robocalib import RoboCalibPlan, handeye_stations, viewset_stations
from jcalib.acquisition.servo import ServoResult, servo_tool_tip
from jcalib.acquisition.session import SessionWriter, read_session, read_stations

__all__ = [
    "CaptureInterrupted",
    "CaptureResult",
    "CellLayout",
    "Plan",
    "PlannedStations",
    "RoboCalibPlan",
    "ServoResult",
    "SessionWriter",
    "Station",
    "capture",
    "cell_layout",
    "load_plan",
    "make_plan",
    "plan_cell",
    "read_session",
    "read_stations",
    "servo_tool_tip",
    "handeye_stations",
    "viewset_stations",
    "save_plan",
]
