"""Robot presets: nominal DH models of common arms (standard DH, see ``kinematics.py``).

Joint values are the controller's axis values in radians (``q = radians(axis_deg)``): same zero, same
positive direction. The flange is the frame the controller reports with a null tool (ABB ``tool0``,
KUKA ``$FLANGE``). These are *nominal* models: a real arm differs by up to a millimetre or so.

Sources and checks:

- **ABB IRB 4600-45/2.05**: link dimensions from the ABB product specification (3HAC032885-001,
  figure "dimensions"): axis 2 is 175 mm in front of axis 1 and 495 mm above the base, upper arm
  900 mm, 175 mm from axis 3 up to the axis-4 line, 960 mm from axis 3 to the wrist centre along
  axis 4, 135 mm from the wrist centre to the flange. Axis directions and zero match ROS-Industrial's
  ``abb_irb4600_support`` URDF (zero = upper arm vertical, forearm horizontal, ``tool0`` z forward).
  Working ranges from the datasheet: axis 1 +-180 deg, axis 2 -90/+150, axis 3 -180/+75,
  axis 4 +-400, axis 5 -125/+120, axis 6 +-400.
  Check: the largest horizontal distance of the wrist centre from axis 1 is
  ``175 + 900 + sqrt(175^2 + 960^2) = 2050.8 mm`` = the published reach 2.05 m.
- **KUKA KR 10 R1100 sixx** (KR AGILUS): from the KUKA datasheet / ROS-Industrial
  ``kuka_kr10_support`` URDF: axis 2 is 400 mm above the base and 25 mm in front of axis 1,
  upper arm 560 mm, 35 mm from axis 3 up to the axis-4 line, 515 mm to the wrist centre, 80 mm from
  the wrist centre to the flange. (The often-quoted 25 mm / 90 mm for the last two are not what the
  URDF or the sister model KR 6 R900 sixx, 400/25/455/35/420/80 mm, use; 35 mm gives
  ``25 + 560 + sqrt(35^2 + 515^2) = 1101.2 mm``, the published maximum reach 1101 mm.)
  Axis directions as KUKA's (A1, A4, A6 turn about -z/-x of the base at zero, i.e. sign -1 here);
  zero = arm stretched horizontally forward (A2 = -90 deg is the upper arm vertical); ``$FLANGE`` x
  points out of the flange. Working ranges: A1 +-170 deg, A2 -190/+45, A3 -120/+156, A4 +-185,
  A5 +-120, A6 +-350.
- **Universal Robots UR5e**: UR's own DH table ("DH parameters for calculations of kinematics and dynamics",
  universal-robots.com): ``a = [0, -0.425, -0.3922, 0, 0, 0]`` m, ``d = [0.1625, 0, 0, 0.1333, 0.0997,
  0.0996]`` m, ``alpha = [pi/2, 0, 0, pi/2, -pi/2, 0]``, ``theta = q`` (offsets 0, signs +1). DH frame 0 is
  the controller's base frame and DH frame 6 its flange (the TCP with ``set_tcp(p[0,0,0,0,0,0])``), so the
  pose the controller reports (RTDE ``actual_TCP_pose``) is this model's FK, as ``ur_description``'s
  ``base -> tool0``. Check: at zero joints the flange is at ``(a2 + a3, -(d4 + d6), d1 - d5) = (-817.2,
  -232.9, 62.8)`` mm, the numbers the teach pendant shows; reach (shoulder to wrist centre, stretched)
  ``0.425 + 0.3922 = 0.817`` m + wrist = the published 850 mm. Working ranges +-360 deg on every joint
  (UR's), except the elbow limited to +-180 deg as ``ur_description`` does (beyond, the arm folds through
  itself). Joint speeds 180 deg/s (the datasheet's). A real UR5e's factory calibration (``calibration.conf``:
  delta DH) differs from these by up to millimetres; see :mod:`jcalib.geometry.ur_calibration`.
"""

from __future__ import annotations

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.kinematics import DHRobot

__all__ = ["PRESETS", "abb_irb4600_45_205", "home_joints", "kuka_kr10_r1100_sixx", "robot_preset", "ur5e"]

_HALF_PI = np.pi / 2.0


def abb_irb4600_45_205() -> DHRobot:
    """Nominal ABB IRB 4600-45/2.05 (standard DH, joints in rad, flange = ``tool0``)."""
    return DHRobot(
        a=[0.175, 0.900, 0.175, 0.0, 0.0, 0.0],
        alpha=[-_HALF_PI, 0.0, -_HALF_PI, _HALF_PI, -_HALF_PI, 0.0],
        d=[0.495, 0.0, 0.0, 0.960, 0.0, 0.135],
        theta_offset=[0.0, -_HALF_PI, 0.0, 0.0, 0.0, np.pi],
        joint_sign=[1.0, 1.0, 1.0, 1.0, 1.0, 1.0],
        lower=np.radians([-180.0, -90.0, -180.0, -400.0, -125.0, -400.0]),
        upper=np.radians([180.0, 150.0, 75.0, 400.0, 120.0, 400.0]),
        name="ABB IRB 4600-45/2.05",
        joint_names=("axis 1", "axis 2", "axis 3", "axis 4", "axis 5", "axis 6"),
    )


def kuka_kr10_r1100_sixx() -> DHRobot:
    """Nominal KUKA KR 10 R1100 sixx (standard DH, joints in rad, flange = ``$FLANGE``, x out)."""
    # DH frame 6 has z along the flange normal and x up at zero; $FLANGE has x along the normal.
    link6_flange = np.array(
        [[0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    )
    return DHRobot(
        a=[0.025, 0.560, 0.035, 0.0, 0.0, 0.0],
        alpha=[-_HALF_PI, 0.0, -_HALF_PI, _HALF_PI, -_HALF_PI, 0.0],
        d=[0.400, 0.0, 0.0, 0.515, 0.0, 0.080],
        theta_offset=[0.0, 0.0, -_HALF_PI, 0.0, 0.0, 0.0],
        joint_sign=[-1.0, 1.0, 1.0, -1.0, 1.0, -1.0],
        lower=np.radians([-170.0, -190.0, -120.0, -185.0, -120.0, -350.0]),
        upper=np.radians([170.0, 45.0, 156.0, 185.0, 120.0, 350.0]),
        T_link_flange=link6_flange,
        name="KUKA KR 10 R1100 sixx",
        joint_names=("A1", "A2", "A3", "A4", "A5", "A6"),
    )


#: UR's names of the joints (``ur_description``'s, without ``_joint``).
UR_JOINT_NAMES = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
#: The UR5e's nominal DH table (UR's published values): ``a`` (m), ``d`` (m), ``alpha`` (rad); ``theta = q``.
UR5E_DH = {
    "a": (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0),
    "d": (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996),
    "alpha": (_HALF_PI, 0.0, 0.0, _HALF_PI, -_HALF_PI, 0.0),
}


def ur5e() -> DHRobot:
    """Nominal Universal Robots UR5e (UR's standard DH table, joints in rad, flange = ``tool0``)."""
    return DHRobot(
        a=UR5E_DH["a"],
        alpha=UR5E_DH["alpha"],
        d=UR5E_DH["d"],
        lower=np.radians([-360.0, -360.0, -180.0, -360.0, -360.0, -360.0]),
        upper=np.radians([360.0, 360.0, 180.0, 360.0, 360.0, 360.0]),
        name="Universal Robots UR5e",
        joint_names=UR_JOINT_NAMES,
    )


PRESETS = {
    "abb_irb4600_45_205": abb_irb4600_45_205,
    "kuka_kr10_r1100_sixx": kuka_kr10_r1100_sixx,
    "ur5e": ur5e,
}
"""Preset name -> constructor."""


def robot_preset(name: str) -> DHRobot:
    """The preset robot called ``name`` (a key of :data:`PRESETS`)."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise BadInputError(
            f"robot: unknown preset {name!r}; expected one of {sorted(PRESETS)}"
        ) from None


def home_joints(robot: DHRobot) -> np.ndarray:
    """``(n,)`` the usual home posture of ``robot``, rad: zeros, with axis 5 at 30 deg on a six-axis arm and,
    for a KUKA, A2 = -90 deg, A3 = +90 deg; for a Universal Robots arm ``(0, -100, 100, -90, -90, 0)`` deg
    (elbow up, the tool pointing down, the flange 0.42 m out along base -x and 0.48 m up: UR's zero is
    the arm stretched out); clipped to the joint limits. The simulated controllers start there and the planners
    seed their inverse kinematics there."""
    lower, upper = np.asarray(robot.lower, dtype=np.float64), np.asarray(robot.upper, dtype=np.float64)
    home = np.zeros(int(robot.num_joints))
    if home.size == 6:
        home[4] = np.radians(30.0)
        if "KUKA" in robot.name.upper():
            home[1], home[2] = np.radians(-90.0), np.radians(90.0)
        elif robot.name.startswith("Universal Robots"):
            home[:] = np.radians([0.0, -100.0, 100.0, -90.0, -90.0, 0.0])
    return np.clip(home, lower, upper)
