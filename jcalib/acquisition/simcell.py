"""Frame sources for simulated cells: render what a camera sees at the robot's current (true) pose.

:func:`robot_scene_source` composes a :class:`~jcalib.acquisition.robots.simulated.SimulatedController`
(where the flange really is) with the image renderer of :mod:`jcalib.sim.render` (imported on first
use: it needs JAX). The result plugs into :class:`~jcalib.acquisition.cameras.FakeGigECamera` (frames
over real GigE Vision) or :class:`~jcalib.acquisition.cameras.SimulatedCamera` (in-process).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from jcalib.acquisition.cameras.base import FrameRequest, FrameSource
from jcalib.acquisition.robots.poses import check_pose, invert
from jcalib.errors import BadInputError


@dataclasses.dataclass(frozen=True)
class SceneTarget:
    """A target in the simulated cell.

    Attributes:
        texture: its printed face (:class:`jcalib.sim.textures.TargetTexture`).
        pose: (4, 4) ``T_base_target`` (mount "base") or ``T_flange_target`` (mount "flange"), m.
        mount: "base" or "flange".
    """

    texture: Any
    pose: np.ndarray
    mount: str = "base"


def robot_scene_source(
    pose_of_flange,
    camera: Any,
    targets: Sequence[SceneTarget],
    *,
    T_flange_cam: np.ndarray | None = None,
    T_base_cam: np.ndarray | None = None,
    options: Any = None,
    reference_exposure_us: float = 10000.0,
    seed: int = 0,
) -> FrameSource:
    """A frame source rendering ``targets`` through ``camera`` at the robot's current pose.

    Args:
        pose_of_flange: callable returning the true ``T_base_flange`` (4, 4), m, e.g.
            ``controller.true_T_base_flange``.
        camera: a camera model of :mod:`jcalib.geometry.cameras` (its ``image_size`` is the sensor).
        targets: the targets in the cell.
        T_flange_cam: (4, 4) eye-in-hand camera pose on the flange, m; or
        T_base_cam: (4, 4) fixed camera pose in the base, m (exactly one of the two).
        options: :class:`jcalib.sim.render.RenderOptions`; brightness scales with
            ``exposure_us / reference_exposure_us`` of each request.
        reference_exposure_us: exposure at which ``options`` applies unchanged, us.
        seed: sensor-noise seed; frame ``k`` uses ``seed + k``.
    """
    if (T_flange_cam is None) == (T_base_cam is None):
        raise BadInputError("robot_scene_source: give exactly one of T_flange_cam (eye-in-hand) and T_base_cam")
    T_flange_cam = None if T_flange_cam is None else check_pose(T_flange_cam, "T_flange_cam")
    T_base_cam = None if T_base_cam is None else check_pose(T_base_cam, "T_base_cam")
    for i, t in enumerate(targets):
        if t.mount not in ("base", "flange"):
            raise BadInputError(f"targets[{i}].mount: expected 'base' or 'flange', got {t.mount!r}")
        check_pose(t.pose, f"targets[{i}].pose")

    def source(req: FrameRequest) -> np.ndarray:
        from jcalib.sim.render import RenderOptions, render_targets_image

        T_base_flange = np.asarray(pose_of_flange(), dtype=np.float64)
        T_cam_base = invert(T_base_flange @ T_flange_cam if T_flange_cam is not None else T_base_cam)
        scene = []
        for t in targets:
            T_base_target = t.pose if t.mount == "base" else T_base_flange @ t.pose
            scene.append((T_cam_base @ T_base_target, t.texture))
        opts = options if options is not None else RenderOptions()
        scale = float(req.exposure_us) / reference_exposure_us
        if scale != 1.0:
            opts = dataclasses.replace(opts, white_electrons=opts.white_electrons * scale)
        return render_targets_image(camera, scene, opts, rng=seed + req.index)

    return source


def scene_frame_source(
    scene: Any,
    camera: str,
    pose_of_flange,
    *,
    options: Any = None,
    reference_exposure_us: float = 10000.0,
    seed: int = 0,
) -> FrameSource:
    """A frame source rendering camera ``camera`` of a :class:`jcalib.sim.scene.Scene` at the robot's pose.

    Args:
        scene: the synthetic cell (its cameras and targets mounted on "base" / "flange"; views unused).
        camera: camera name in ``scene.cameras``.
        pose_of_flange: callable returning the true ``T_base_flange`` (4, 4), m.
        options: :class:`jcalib.sim.render.RenderOptions`; brightness follows the requested exposure.
        reference_exposure_us: exposure at which ``options`` applies unchanged, us.
        seed: sensor-noise seed; frame ``k`` uses ``seed + k``.
    """
    if camera not in scene.cameras:
        raise BadInputError(f"camera: {camera!r} is not in the scene (has {', '.join(scene.cameras)})")

    def source(req: FrameRequest) -> np.ndarray:
        from jcalib.sim.render import RenderOptions
        from jcalib.sim.scene import View, render_view

        view = View(id=f"live{req.index}", T_base_flange=np.asarray(pose_of_flange(), dtype=np.float64))
        live = dataclasses.replace(scene, views=[view])
        opts = options if options is not None else RenderOptions()
        scale = float(req.exposure_us) / reference_exposure_us
        if scale != 1.0:
            opts = dataclasses.replace(opts, white_electrons=opts.white_electrons * scale)
        return render_view(live, 0, camera, opts, rng=seed + req.index)

    return source
