"""Acquisition: drive cameras and robots, write capture sessions (see DESIGN.md, "Capture session").

Cameras (:mod:`jcalib.acquisition.cameras`): GigE Vision through Aravis, opened by IP address; a fake
GigE camera serving rendered frames; in-process simulated and replay cameras. Robots
(:mod:`jcalib.acquisition.robots`): KUKA (KUKAVARPROXY), ABB (jcalib RAPID server), simulated
controllers and their protocol servers. :func:`capture` runs a station plan into a session.
"""

from jcalib.acquisition.capture import CaptureInterrupted, CaptureResult, capture
from jcalib.acquisition.plan import Plan, Station, load_plan, make_plan, save_plan
from jcalib.acquisition.session import SessionWriter, read_session, read_stations

__all__ = [
    "CaptureInterrupted",
    "CaptureResult",
    "Plan",
    "SessionWriter",
    "Station",
    "capture",
    "load_plan",
    "make_plan",
    "read_session",
    "read_stations",
    "save_plan",
]
