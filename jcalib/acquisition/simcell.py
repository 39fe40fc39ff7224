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


def scene_from_layout(layout: Any, *, texture_px_per_square: float = 24.0) -> Any:
    """The :class:`jcalib.sim.scene.Scene` of a nominal cell layout (the simulated cell's ground truth).

    Args:
        layout: a :class:`jcalib.acquisition.layout.CellLayout`.
        texture_px_per_square: resolution of the printed targets, texels per grid spacing.
    """
    from jcalib.geometry.cameras.factory import camera_from_opencv
    from jcalib.sim.scene import Scene, SceneCamera
    from jcalib.sim.scene import SceneTarget as SimTarget
    from jcalib.sim.textures import target_texture

    cameras = {
        name: SceneCamera(camera_from_opencv(c.K, c.dist, c.image_size, fisheye=c.model == "fisheye"), c.mount, c.pose)
        for name, c in layout.cameras.items()
    }
    targets = {}
    for name, t in layout.targets.items():
        pts = np.asarray(t.geometry.points, dtype=np.float64)
        d = np.linalg.norm(pts[1:] - pts[:-1], axis=1)
        spacing = float(np.min(d[d > 1e-9])) if np.any(d > 1e-9) else 0.01
        tex = target_texture(t.geometry, spacing / texture_px_per_square)
        targets[name] = SimTarget(t.geometry, tex, t.mount, t.pose)
    return Scene(cameras=cameras, targets=targets, views=[])


def layout_truth(layout: Any, **controller: Any) -> dict:
    """Ground truth of a simulated cell as a JSON-ready mapping (``jcalib.sim.cell/1``).

    Holds the robot preset, every camera's OpenCV ``K``, ``dist``, image size and pose
    (``T_flange_<cam>`` or ``T_base_<cam>``), every target's points and pose, the tools' TCPs
    (``T_flange_<tool>``), and ``controller`` (e.g. repeatability, seed). Metres, pixels.
    """
    cams = {}
    for name, c in layout.cameras.items():
        cams[name] = {
            "model": c.model, "image_size": list(c.image_size), "K": c.K.tolist(), "dist": c.dist.tolist(),
            "mount": c.mount, f"T_{c.mount}_{name}": c.pose.tolist(),
        }  # fmt: skip
    tgts = {}
    for name, t in layout.targets.items():
        tgts[name] = {
            "spec": t.geometry.to_spec() if hasattr(t.geometry, "to_spec") else {},
            "points": np.asarray(t.geometry.points, dtype=np.float64).tolist(),
            "mount": t.mount, f"T_{t.mount}_{name}": t.pose.tolist(),
        }  # fmt: skip
    return {
        "schema": "jcalib.sim.cell/1",
        "units": "metres, pixels (centre of the top-left pixel is (0, 0))",
        "robot": {"preset": layout.robot, "home_deg": np.degrees(layout.home_rad).tolist(), **controller},
        "cameras": cams,
        "targets": tgts,
        "tools": {name: {f"T_flange_{name}": T.tolist()} for name, T in layout.tools.items()},
    }
