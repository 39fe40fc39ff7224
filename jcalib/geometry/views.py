"""Camera poses that look at a target: the view constructions of RoboCalib's station patterns.

Pure geometry on (4, 4) ``T_target_cam`` matrices in metres (camera +z is the optical axis): a frontal
view at a distance, tilted and rolled variants, rotations of the camera about its own axes and
re-centring on a point. The station planners, the simulated studies and the tests build stations
from them.
"""

from __future__ import annotations

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import invert, make_pose, rot_x, rot_y, rot_z

__all__ = ["AXES", "frontal_view", "height_view", "origin_view", "recentre", "rotate_camera", "tilted_view",
           "viewing_distance"]

#: Camera / target axis name -> unit vector.
AXES = {"X": np.array([1.0, 0.0, 0.0]), "Y": np.array([0.0, 1.0, 0.0]), "Z": np.array([0.0, 0.0, 1.0])}
_ROT = {"X": rot_x, "Y": rot_y, "Z": rot_z}
_E_Z = AXES["Z"]


def frontal_view(centre, distance_m: float) -> np.ndarray:
    """(4.1) ``T_target_cam`` (4, 4): camera axes parallel to the target's, ``centre`` at distance ``D`` on the optical axis."""
    return make_pose(np.eye(3), np.asarray(centre, dtype=np.float64) - distance_m * _E_Z)


def tilted_view(centre, distance_m: float, axis: str, angle_rad: float) -> np.ndarray:
    """(4.2, 4.3) the frontal view rotated by ``angle_rad`` about the line through ``centre`` along target ``axis`` ("X"/"Y")."""
    R = _ROT[axis](angle_rad)
    c = np.asarray(centre, dtype=np.float64)
    return make_pose(R, c - distance_m * (R @ _E_Z))


def origin_view(distance_m: float) -> np.ndarray:
    """World-origin view: the target origin on the optical axis at distance ``D``, axes parallel."""
    return frontal_view(np.zeros(3), distance_m)


def height_view(centre, distance_m: float, height_scale: float, roll_rad: float) -> np.ndarray:
    """(4.4) the frontal view at distance ``height_scale · D``, rolled by ``roll_rad`` about the optical axis."""
    return make_pose(rot_z(roll_rad), np.asarray(centre, dtype=np.float64) - height_scale * distance_m * _E_Z)


def rotate_camera(T_target_cam: np.ndarray, axis: str, angle_rad: float) -> np.ndarray:
    """(4.5) rotate the camera about its own ``axis`` ("X", "Y" or "Z") at its centre: ``T · [Rot(e_a, θ) | 0]``."""
    return T_target_cam @ make_pose(_ROT[axis](angle_rad), np.zeros(3))


def recentre(T_target_cam: np.ndarray, centre, distance_m: float) -> np.ndarray:
    """(4.6, 4.7) translate the camera in its own frame so ``centre`` is on its optical axis at distance ``D``.

    ``p = T⁻¹ c`` (4.6), then ``T · [I | p − D e_z]`` (4.7); the orientation is unchanged.
    """
    c = np.asarray(centre, dtype=np.float64)
    p = invert(T_target_cam)[:3, :3] @ c + invert(T_target_cam)[:3, 3]
    return T_target_cam @ make_pose(np.eye(3), p - distance_m * _E_Z)


def viewing_distance(K, image_size: tuple[int, int], target_points, fill: float = 0.5) -> float:
    """Distance (m) at which the target spans ``fill`` of the smaller image side (pinhole ``K``, px)."""
    K = np.asarray(K, dtype=np.float64)
    P = np.asarray(target_points, dtype=np.float64)
    radius = float(np.max(np.linalg.norm(P - P.mean(axis=0), axis=1)))
    if not (0.0 < fill <= 1.0) or radius <= 0.0:
        raise BadInputError(f"fill: expected 0 < fill <= 1 and a target of positive size, got {fill}, radius {radius} m")
    f = 0.5 * (K[0, 0] + K[1, 1])
    return float(f * 2.0 * radius / (fill * min(image_size)))
