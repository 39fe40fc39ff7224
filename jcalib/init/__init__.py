"""Closed-form initialisers: they only start the joint solve, never finish it."""

from jcalib.init.fisheye import FisheyeInit, fisheye_init
from jcalib.init.frames import FrameResult, frame_from_points, frame_from_three_points
from jcalib.init.handeye import HAND_EYE_METHODS, HandEyeInit, solve_hand_eye
from jcalib.init.handeye_motion import MotionDiagnostics, analyse_motion, check_observable
from jcalib.init.homography import estimate_homographies, estimate_homography
from jcalib.init.pivot import PivotResult, SphereFitResult, pivot_calibration, pivot_sphere_fit
from jcalib.init.pnp import PlanarPnPResult, PnPResult, planar_pnp, planar_pnp_views, solve_pnp
from jcalib.init.robot_world import ROBOT_WORLD_METHODS, RobotWorldInit, solve_robot_world_hand_eye
from jcalib.init.tcp_analytic import AnalyticTCPResult, tcp_from_camera_ray, tcp_three_pose, viewing_ray_base
from jcalib.init.pose_chains import PointInFrame, compose_pose_chains, point_in_frame
from jcalib.init.triangulation import (
    TriangulatedPoint,
    TriangulatedPoints,
    point_distance,
    triangulate_dlt,
    triangulate_point,
    triangulate_points,
)
from jcalib.init.zhang import ZhangInit, zhang_init

__all__ = [
    "HAND_EYE_METHODS",
    "ROBOT_WORLD_METHODS",
    "AnalyticTCPResult",
    "FisheyeInit",
    "FrameResult",
    "HandEyeInit",
    "MotionDiagnostics",
    "PivotResult",
    "PlanarPnPResult",
    "PointInFrame",
    "PnPResult",
    "RobotWorldInit",
    "SphereFitResult",
    "TriangulatedPoint",
    "TriangulatedPoints",
    "ZhangInit",
    "analyse_motion",
    "check_observable",
    "compose_pose_chains",
    "estimate_homographies",
    "estimate_homography",
    "fisheye_init",
    "frame_from_points",
    "frame_from_three_points",
    "pivot_calibration",
    "pivot_sphere_fit",
    "point_distance",
    "point_in_frame",
    "planar_pnp",
    "planar_pnp_views",
    "solve_hand_eye",
    "solve_pnp",
    "solve_robot_world_hand_eye",
    "tcp_from_camera_ray",
    "tcp_three_pose",
    "triangulate_dlt",
    "triangulate_point",
    "triangulate_points",
    "viewing_ray_base",
    "zhang_init",
]
