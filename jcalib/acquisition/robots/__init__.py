"""Robot drivers: KUKA (KUKAVARPROXY), ABB (jcalib RAPID socket server), Universal Robots (RTDE + URScript),
simulated controllers."""

from jcalib.acquisition.robots.abb import AbbRobot
from jcalib.acquisition.robots.abb_sim import AbbSimServer
from jcalib.acquisition.robots.base import MotionRefusedError, MotionStoppedError, Robot, RobotState
from jcalib.acquisition.robots.kuka import KukaRobot, KukaVarProxyClient
from jcalib.acquisition.robots.kuka_sim import KukaSimServer
from jcalib.acquisition.robots.model import (
    ControllerModel,
    DHRobotModel,
    IKResult,
    SixAxisArm,
    default_model,
    preset_model,
)
from jcalib.acquisition.robots.serve import make_server, start_subprocess
from jcalib.acquisition.robots.simulated import SimulatedController, SimulatedRobot, UnreachableError
from jcalib.acquisition.robots.ur import UrRobot
from jcalib.acquisition.robots.ur_sim import UrSimServer

__all__ = [
    "AbbRobot",
    "AbbSimServer",
    "ControllerModel",
    "DHRobotModel",
    "IKResult",
    "KukaRobot",
    "KukaSimServer",
    "KukaVarProxyClient",
    "MotionRefusedError",
    "MotionStoppedError",
    "Robot",
    "RobotState",
    "SimulatedController",
    "SimulatedRobot",
    "SixAxisArm",
    "UnreachableError",
    "UrRobot",
    "UrSimServer",
    "default_model",
    "make_server",
    "preset_model",
    "start_subprocess",
]
