"""Exports of a result to what cells run on: OpenCV YAML, ROS camera_info, ABB RAPID, KUKA KRL, calibrated robot
kinematics (cell-spec YAML, URDF, Universal Robots' delta DH)."""

from jcalib.io.export.abb_rapid import (
    DEFAULT_TOOL_LOAD,
    ToolLoad,
    abb_rapid_module,
    abb_tooldata,
    abb_wobjdata,
    write_abb_rapid,
)
from jcalib.io.export.formats import EXPORT_FORMATS, export_result, export_text
from jcalib.io.export.kinematics import kinematics_urdf, kinematics_yaml, write_kinematics_yaml, write_urdf
from jcalib.io.export.kuka_krl import kuka_config_lines, kuka_frame_literal, write_kuka_krl
from jcalib.io.export.opencv_yaml import opencv_yaml, write_opencv_yaml
from jcalib.io.export.ros import ros_camera_info, write_ros_camera_info
from jcalib.io.export.ur_calibration import ur_calibration_export

__all__ = [
    "DEFAULT_TOOL_LOAD",
    "EXPORT_FORMATS",
    "ToolLoad",
    "abb_rapid_module",
    "abb_tooldata",
    "abb_wobjdata",
    "export_result",
    "export_text",
    "kinematics_urdf",
    "kinematics_yaml",
    "kuka_config_lines",
    "kuka_frame_literal",
    "opencv_yaml",
    "ros_camera_info",
    "ur_calibration_export",
    "write_abb_rapid",
    "write_kinematics_yaml",
    "write_kuka_krl",
    "write_opencv_yaml",
    "write_ros_camera_info",
    "write_urdf",
]
