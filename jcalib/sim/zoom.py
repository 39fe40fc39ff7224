"""A simulated motorised zoom lens and a hand-eye cell that captures each station at several zoom settings.

The lens (:class:`ZoomLensModel`, GenICam ``Zoom`` in motor steps ``0..1000``): focal length from 1x to
6x over the range (about geometric in the motor position, ``f ∝ 6^v``), radial distortion from barrel
at the wide end to a little pincushion at the tele end (``k1`` changes sign), a principal point that
drifts by a few pixels, and an entrance pupil (the camera frame's origin) that moves 20 mm forward along
the optical axis. ``Focus`` (``0..1000``) moves the pupil by a further millimetre and scales the focal
length by up to 1 % (used by the fake GigE camera; the cell here holds it at 500).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from jcalib.geometry.cameras import camera_model_from_name
from jcalib.geometry.se3 import invert, make_pose, rotation

#: Image size of the zoom camera (px).
ZOOM_IMAGE_SIZE = (1280, 960)
#: The motor ranges of the lens's features (GenICam ``Zoom``, ``Focus``).
ZOOM_RANGE = (0.0, 1000.0)
FOCUS_RANGE = (0.0, 1000.0)


@dataclass(frozen=True)
class ZoomLensModel:
    """The truth of a simulated zoom lens (opencv5 intrinsics; metres).

    Attributes:
        f_wide_px: focal length at ``Zoom = 0``; zoom_ratio: ``f(1000) / f(0)``.
        pupil_shift_m: the camera frame's shift along +z from ``Zoom = 0`` to ``Zoom = 1000``.
    """

    f_wide_px: float = 1000.0
    zoom_ratio: float = 6.0
    pupil_shift_m: float = 0.02
    image_size: tuple[int, int] = ZOOM_IMAGE_SIZE

    def params(self, zoom: float, focus: float = 500.0) -> np.ndarray:
        """``(9,)`` opencv5 intrinsics ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)`` at a setting."""
        v = (float(zoom) - ZOOM_RANGE[0]) / (ZOOM_RANGE[1] - ZOOM_RANGE[0])
        w = (float(focus) - 500.0) / 500.0
        f = self.f_wide_px * np.exp(np.log(self.zoom_ratio) * v + 0.06 * v * (1.0 - v)) * (1.0 + 0.005 * w)
        cx = (self.image_size[0] - 1) / 2 + 6.0 * v - 3.0 * v * v + 1.5
        cy = (self.image_size[1] - 1) / 2 - 5.0 * v + 4.0 * v * v - 2.0
        k1 = -0.22 + 0.30 * v - 0.04 * v * v
        k2 = 0.06 - 0.05 * v
        return np.array([f, f * 1.0006, cx, cy, k1, k2, 0.0003, -0.0002, 0.0])

    def shift_m(self, zoom: float, focus: float = 500.0) -> float:
        """The camera frame's shift along its optical axis (m) from ``Zoom = 0`` (and ``Focus = 500``)."""
        v = (float(zoom) - ZOOM_RANGE[0]) / (ZOOM_RANGE[1] - ZOOM_RANGE[0])
        w = (float(focus) - 500.0) / 500.0
        return self.pupil_shift_m * (v + 0.3 * v * (1.0 - v)) + 0.001 * w

    def camera(self, zoom: float, focus: float = 500.0):
        return camera_model_from_name("opencv5", self.image_size, self.params(zoom, focus))

    def functions(self, settings) -> dict:
        """The lens's functions tabulated at ``settings`` (what ``jcalib simulate --truth`` writes)."""
        settings = [float(s) for s in settings]
        return {"setting": "Zoom", "settings": settings, "model": "opencv5", "image_size": list(self.image_size),
                "param_names": ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"],
                "params": [self.params(s).tolist() for s in settings],
                "shift_m": [self.shift_m(s) for s in settings],
                "note": "shift_m: the camera frame's offset along its optical axis from Zoom = 0 (Focus = 500)"}


def mount_at(T_mount_cam_wide: np.ndarray, lens: ZoomLensModel, zoom: float, focus: float = 500.0) -> np.ndarray:
    """The camera frame on its mount at a setting: ``T · Trans(0, 0, shift)``."""
    T = np.eye(4)
    T[2, 3] = lens.shift_m(zoom, focus)
    return np.asarray(T_mount_cam_wide, np.float64) @ T


def _look_at(eye, target, up):
    z = np.asarray(target, np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    return make_pose(np.stack([x, np.cross(z, x), z], axis=1), eye)


def synthetic_zoom_cell(seed: int = 0, *, settings=(100, 200, 300, 400, 500, 600, 700, 800), num_stations: int = 6,
                        sigma_px: float = 0.2, lens: ZoomLensModel | None = None, degree: int = 3, knots: int = 0,
                        geometry_seed: int = 7, square: float = 0.025, jitter: float = 0.0) -> tuple[dict, dict, dict]:
    """An eye-in-hand zoom camera ``cam0`` looking at a fixed checkerboard; every robot station is
    captured at every zoom setting (one observation station each, ``lens: {cam0: {Zoom: s}}``); exact
    flange poses (the robot does not move while the lens zooms).

    Args:
        seed: noise seed; geometry_seed: the stations' seed (the same stations for every noise draw).
        settings: the captured ``Zoom`` settings; num_stations: robot stations.
        sigma_px: corner noise σ.
        jitter: σ (motor steps) of where the lens actually stops around each commanded setting; the
            station records (and the images show) the actual value, as a camera reads it back.
        square: the checkerboard's square (m); the board spans about 0.35 m x 0.25 m whatever the square
            (a finer board gives the narrow tele views more corners).

    Returns:
        ``(cell dict, observations dict, truth dict)``; truth: ``lens`` (the :class:`ZoomLensModel`),
        ``T_flange_cam0_wide`` (the camera frame at ``Zoom = 0``), ``T_base_board``, ``stations``
        (``(num_stations, 4, 4)`` flange poses).
    """
    from jcalib.geometry.targets import Checkerboard

    lens = lens or ZoomLensModel()
    rng, geo = np.random.default_rng(seed), np.random.default_rng(geometry_seed)
    cols, rows = round(0.35 / square), round(0.25 / square)
    board = Checkerboard(cols=cols, rows=rows, square=square)
    pts = np.asarray(board.points, np.float64)
    T_base_board = make_pose(rotation((1, 0, 0), np.pi), [0.6, -0.05, 0.0])
    centre = T_base_board[:3, :3] @ pts.mean(axis=0) + T_base_board[:3, 3]
    T_flange_cam_wide = make_pose(rotation((0.2, 0.1, 1.0), 0.3), [0.05, -0.03, 0.09])
    w, h = lens.image_size
    flanges = []
    while len(flanges) < num_stations:
        dirn = np.array([geo.uniform(-0.6, 0.6), geo.uniform(-0.6, 0.6), 1.0])
        eye = centre + geo.uniform(0.28, 0.42) * dirn / np.linalg.norm(dirn)
        aim = centre + np.array([geo.uniform(-0.07, 0.07), geo.uniform(-0.05, 0.05), 0.0])
        T_base_c = _look_at(eye, aim, up=(1.0, 0.0, 0.0))
        T_base_c[:3, :3] = T_base_c[:3, :3] @ rotation((0, 0, 1), geo.uniform(-0.8, 0.8))
        flanges.append(T_base_c @ invert(T_flange_cam_wide))
    stations = []
    for i, T_bf in enumerate(flanges):
        for commanded in settings:
            s = float(commanded) + (jitter * geo.normal() if jitter > 0 else 0.0)
            T_cam_board = invert(T_bf @ mount_at(T_flange_cam_wide, lens, s)) @ T_base_board
            p = pts @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
            u = np.asarray(lens.camera(s).project(jnp.asarray(p)))
            ok = (p[:, 2] > 0.05) & (u[:, 0] > 5) & (u[:, 0] < w - 6) & (u[:, 1] > 5) & (u[:, 1] < h - 6)
            idx = np.flatnonzero(ok)
            dets = []
            if idx.size >= 12:
                px = u[idx] + sigma_px * rng.normal(size=(idx.size, 2))
                dets.append({"camera": "cam0", "target": "board", "point_index": idx.tolist(), "pixels": px.tolist()})
            stations.append({"id": f"s{i:02d}z{int(commanded):04d}", "T_base_flange": T_bf.tolist(), "detections": dets,
                             "lens": {"cam0": {"Zoom": float(s)}}})
    cell = {"schema": "jcalib.cell/1",
            "cameras": {"cam0": {"model": "opencv5", "mount": "flange",
                                 "lens": {"settings": ["Zoom"], "degree": degree, "knots": knots}}},
            "targets": {"board": {"type": "checkerboard", "cols": cols, "rows": rows, "square": square, "mount": "base"}},
            "robot": {}}
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(lens.image_size)}},
           "targets": {"board": {"points": pts.tolist()}}, "stations": stations}
    truth = {"lens": lens, "T_flange_cam0_wide": T_flange_cam_wide, "T_base_board": T_base_board,
             "stations": np.stack(flanges)}
    return cell, obs, truth


def heldout_projection_rms_px(lens: ZoomLensModel, zoom: float, params, grid: tuple[int, int] = (16, 12)) -> float:
    """RMS (px, per point) over a grid of pixels covering the image of the distance between each pixel and
    the projection by the camera ``params`` (opencv5, ``(9,)``) of the ray the true lens sees there."""
    truth = lens.camera(zoom)
    w, h = lens.image_size
    gx, gy = np.meshgrid(np.linspace(10, w - 11, grid[0]), np.linspace(10, h - 11, grid[1]))
    pix = np.stack([gx.ravel(), gy.ravel()], axis=1)
    rays = np.asarray(truth.unproject(jnp.asarray(pix)))
    est = camera_model_from_name("opencv5", lens.image_size, np.asarray(params, np.float64))
    u = np.asarray(est.project(jnp.asarray(rays / rays[:, 2:3])))
    return float(np.sqrt(np.mean(np.sum((u - pix) ** 2, axis=1))))
