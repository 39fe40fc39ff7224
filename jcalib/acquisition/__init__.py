"""Acquisition: drive cameras and robots, write capture sessions (see docs/design.md, "Capture session").

Cameras (:mod:`jcalib.acquisition.cameras`): GigE Vision through Aravis, opened by IP address; a fake
GigE camera serving rendered frames; in-process simulated and replay cameras. Robots
(:mod:`jcalib.acquisition.robots`): KUKA (KUKAVARPROXY), ABB (jcalib RAPID server), simulated
controllers and their protocol servers. :func:`capture` runs a station plan (:mod:`jcalib.io.plan`, made
by :mod:`jcalib.planning`, ``jcalib plan``) into a session (:mod:`jcalib.io.session`, ``jcalib capture``);
:func:`servo_tool_tip` is the TCP capture's station step; :mod:`jcalib.pipeline.session` turns a session
into observations (``jcalib detect --session``).
"""

from jcalib.acquisition.capture import CaptureInterrupted, CaptureResult, SkipStation, apply_camera_settings, capture
from jcalib.acquisition.servo import ServoResult, servo_tool_tip
from jcalib.acquisition.capture import CaptureControl

__all__ = [
    "CaptureControl",
    "CaptureInterrupted",
    "CaptureResult",
    "ServoResult",
    "SkipStation",
    "apply_camera_settings",
    "capture",
    "servo_tool_tip",
]
