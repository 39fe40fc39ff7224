"""Synthetic scenes: cameras, calibration targets and views, their ground truth, and rendered data sets.

A :class:`Scene` holds cameras (any lens model), targets (geometry + printed texture) and views. A
camera or target is mounted ``"free"`` (no robot: each view gives ``T_cam_target`` directly),
``"base"`` (fixed in the robot base frame: ``pose`` = ``T_base_cam`` / ``T_base_target``) or
``"flange"`` (carried by the robot: ``pose`` = ``T_flange_cam`` / ``T_flange_target``). A robot view
(station) gives ``T_base_flange``; the renderer then sees

    T_cam_target = inv(T_base_cam) @ T_base_target,
    T_base_cam = T_base_flange @ T_flange_cam       (camera on the flange, eye-in-hand),
    T_base_target = T_base_flange @ T_flange_target (target on the flange, eye-to-hand).

All poses are (4, 4) float64 arrays, metres. Everything random takes a seed or a numpy Generator.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import equinox as eqx
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import invert, rotation
from jcalib.io.atomic import write_bytes_atomic, write_json_atomic
from jcalib.sim.noise import default_gain_dn_per_e
from jcalib.sim.render import (
    RenderOptions,
    camera_image_size,
    check_texture,
    check_transform,
    render_targets_image,
)
from jcalib.sim.textures import TargetTexture

TRUTH_SCHEMA = "jcalib.sim.truth/1"
MOUNTS = ("free", "base", "flange")


# --------------------------------------------------------------------------------------------------
# Scene


@dataclass(frozen=True)
class SceneCamera:
    """A camera of the scene.

    Attributes:
        model: camera model (``jcalib.geometry.cameras``): ``image_size``, ``project_valid``,
            ``unproject_valid``, ``to_opencv``.
        mount: ``"free"``, ``"base"`` or ``"flange"``.
        pose: (4, 4) ``T_base_cam`` (mount base) or ``T_flange_cam`` (mount flange), m; None when free.
    """

    model: Any
    mount: str = "free"
    pose: np.ndarray | None = None


@dataclass(frozen=True)
class SceneTarget:
    """A calibration target of the scene.

    Attributes:
        target: geometry with ``.points`` (N, 3) target-frame points, m, and ``.ids`` (N,).
        texture: its printed face (the board extent is the texture extent).
        mount: ``"free"``, ``"base"`` or ``"flange"``.
        pose: (4, 4) ``T_base_target`` (mount base) or ``T_flange_target`` (mount flange), m.
    """

    target: Any
    texture: TargetTexture
    mount: str = "free"
    pose: np.ndarray | None = None


@dataclass(frozen=True)
class View:
    """One view (a robot station, or one free placement of the targets).

    Attributes:
        id: view id used in file names, e.g. ``"v000"`` or ``"s007"``.
        T_base_flange: (4, 4) robot flange pose in the base frame, m; needed when anything is mounted
            on the base or the flange.
        T_cam_target: explicit ``{(camera, target): (4, 4) T_cam_target}`` for pairs where the camera
            or the target is free; a missing pair is not seen in this view.
    """

    id: str
    T_base_flange: np.ndarray | None = None
    T_cam_target: Mapping[tuple[str, str], np.ndarray] = field(default_factory=dict)


def _check_mount(kind: str, name: str, mount: str, pose: Any) -> np.ndarray | None:
    if mount not in MOUNTS:
        raise BadInputError(f"{kind} {name!r}: mount {mount!r}, expected one of {MOUNTS}")
    if mount == "free":
        return None
    if pose is None:
        frame = "base" if mount == "base" else "flange"
        raise BadInputError(f"{kind} {name!r}: mount {mount!r} needs pose = T_{frame}_{kind} (4x4, m)")
    return check_transform(pose, f"{kind} {name!r} pose")


@dataclass(frozen=True)
class Scene:
    """Cameras, targets and views of a synthetic cell (see the module docstring for the frames)."""

    cameras: Mapping[str, SceneCamera]
    targets: Mapping[str, SceneTarget]
    views: Sequence[View]

    def __post_init__(self) -> None:
        if not self.cameras:
            raise BadInputError("Scene.cameras: got none, expected at least one camera")
        if not self.targets:
            raise BadInputError("Scene.targets: got none, expected at least one target")
        for name, cam in self.cameras.items():
            _check_mount("cam", name, cam.mount, cam.pose)
            camera_image_size(cam.model)
        for name, tgt in self.targets.items():
            _check_mount("target", name, tgt.mount, tgt.pose)
            check_texture(tgt.texture, f"target {name!r} texture")
            points = np.asarray(tgt.target.points, dtype=np.float64)
            if points.ndim != 2 or points.shape[1] != 3 or not np.all(np.isfinite(points)):
                raise BadInputError(f"target {name!r}: points have shape {points.shape}, expected finite (N, 3)")
        robot = any(c.mount != "free" for c in self.cameras.values()) or any(
            t.mount != "free" for t in self.targets.values()
        )
        ids = set()
        for k, view in enumerate(self.views):
            if view.id in ids:
                raise BadInputError(f"Scene.views[{k}]: duplicate view id {view.id!r}")
            ids.add(view.id)
            if robot and view.T_base_flange is None:
                raise BadInputError(
                    f"Scene.views[{k}] ({view.id!r}): T_base_flange is missing, needed for the base/flange mounts"
                )
            if view.T_base_flange is not None:
                check_transform(view.T_base_flange, f"view {view.id!r} T_base_flange")
            for (cam, tgt), T in view.T_cam_target.items():
                if cam not in self.cameras or tgt not in self.targets:
                    raise BadInputError(
                        f"view {view.id!r}: T_cam_target for ({cam!r}, {tgt!r}) names an unknown camera or target"
                    )
                check_transform(T, f"view {view.id!r} T_cam_target[{cam!r}, {tgt!r}]")

    def T_cam_target(self, view: int | View, camera: str, target: str) -> np.ndarray | None:
        """(4, 4) pose of ``target`` in ``camera`` at ``view`` (index or View), m; None if not seen."""
        v = self.views[view] if isinstance(view, int | np.integer) else view
        cam = self.cameras[camera]
        tgt = self.targets[target]
        if cam.mount == "free" or tgt.mount == "free":
            T = v.T_cam_target.get((camera, target))
            return None if T is None else check_transform(T, f"view {v.id!r} T_cam_target")
        T_base_flange = check_transform(v.T_base_flange, f"view {v.id!r} T_base_flange")
        T_cam_pose = np.asarray(cam.pose, dtype=np.float64)
        T_base_cam = T_base_flange @ T_cam_pose if cam.mount == "flange" else T_cam_pose
        T_tgt_pose = np.asarray(tgt.pose, dtype=np.float64)
        T_base_target = T_base_flange @ T_tgt_pose if tgt.mount == "flange" else T_tgt_pose
        return invert(T_base_cam) @ T_base_target


# --------------------------------------------------------------------------------------------------
# Ground-truth projection


@eqx.filter_jit
def _project_valid(camera: Any, points_cam: Any) -> Any:
    return camera.project_valid(points_cam)


@eqx.filter_jit
def _unproject(camera: Any, pixels: Any) -> Any:
    return camera.unproject(pixels)


def project_target(camera: Any, T_cam_target: Any, points: Any) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth pixels of target points and whether each is seen.

    Args:
        camera: camera model.
        T_cam_target: (4, 4) target -> camera, m.
        points: (N, 3) target-frame points, m.

    Returns:
        pixels: (N, 2) float64 projections, px (NaN where the model cannot project the point).
        visible: (N,) bool: in front of the camera, projectable, on the printed (-z) face side, and
            inside the image (``-0.5 <= u <= W - 0.5``, same for v). Occlusion by other boards is not
            checked.
    """
    T = check_transform(T_cam_target, "T_cam_target")
    P = np.asarray(points, dtype=np.float64)
    p_cam = P @ T[:3, :3].T + T[:3, 3]
    pixels, valid = _project_valid(camera, jnp.asarray(p_cam))
    pixels = np.asarray(pixels, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool) & (p_cam[:, 2] > 0) & np.all(np.isfinite(pixels), axis=-1)
    front = float((-T[:3, :3].T @ T[:3, 3])[2]) < 0.0
    w, h = camera_image_size(camera)
    inside = (
        (pixels[:, 0] >= -0.5) & (pixels[:, 0] <= w - 0.5) & (pixels[:, 1] >= -0.5) & (pixels[:, 1] <= h - 0.5)
    )
    pixels = np.where(valid[:, None], pixels, np.nan)
    return pixels, valid & inside & front


# --------------------------------------------------------------------------------------------------
# Random calibration views


def _opencv_params(camera: Any) -> tuple[np.ndarray, np.ndarray]:
    """(K (3, 3), dist) of a camera model, from ``to_opencv()`` (tuple or dict form)."""
    out = camera.to_opencv()
    if isinstance(out, Mapping):
        K, dist = out["K"], out["dist"]
    elif hasattr(out, "K"):
        K, dist = out.K, out.dist
    else:
        K, dist = out[0], out[1]
    return np.asarray(K, dtype=np.float64), np.asarray(dist, dtype=np.float64).ravel()


def random_calibration_views(
    camera: Any,
    points: Any,
    num_views: int,
    rng: np.random.Generator | int = 0,
    *,
    fill: tuple[float, float] = (0.35, 0.8),
    max_tilt_deg: float = 45.0,
    max_roll_deg: float = 30.0,
    margin_px: float = 20.0,
    max_attempts: int = 200,
) -> list[np.ndarray]:
    """Well-spread random poses of a planar target for camera calibration.

    Each view's board faces the camera (its -z side, tilted by up to ``max_tilt_deg`` about a random
    in-plane axis and rolled by up to ``max_roll_deg`` about its normal), spans a fraction ``fill`` of
    the smaller image side (which sets its distance), and every point is in front of the camera and
    inside the image with ``margin_px`` to spare. Image position, tilt and fill are stratified across
    the views (Latin hypercube), so the set covers the image and the tilt range.

    Args:
        camera: camera model (``image_size``, ``project_valid``, ``unproject_valid``, ``to_opencv``).
        points: (N, 3) target-frame points (e.g. ``target.points``), m.
        num_views: number of poses, >= 1.
        rng: seed or generator.
        fill: (min, max) board diameter over the smaller image side.
        max_tilt_deg: largest angle between board normal and optical axis, degrees.
        max_roll_deg: largest rotation about the board normal, degrees (keep < 90 for checkerboards,
            whose detection order is ambiguous under half turns).
        margin_px: distance every point keeps from the image border, px.
        max_attempts: candidate poses tried per view before giving up.

    Returns:
        ``num_views`` (4, 4) ``T_cam_target`` arrays, m.

    Raises:
        BadInputError: bad arguments, or no pose satisfies the constraints (target too large for the
            field of view or the margin).
    """
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    if int(num_views) != num_views or num_views < 1:
        raise BadInputError(f"num_views: got {num_views!r}, expected an integer >= 1")
    lo, hi = (float(f) for f in fill)
    if not 0 < lo <= hi <= 1.5:
        raise BadInputError(f"fill: got {fill!r}, expected 0 < min <= max <= 1.5")
    if not 0 <= max_tilt_deg < 80:
        raise BadInputError(f"max_tilt_deg: got {max_tilt_deg!r}, expected a value in [0, 80)")
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 1 or not np.all(np.isfinite(P)):
        raise BadInputError(f"points: got shape {P.shape}, expected finite (N, 3) target points")
    w, h = camera_image_size(camera)
    K, _ = _opencv_params(camera)
    f = 0.5 * (K[0, 0] + K[1, 1])
    centroid = P.mean(axis=0)
    radius = float(np.max(np.linalg.norm(P - centroid, axis=1)))
    if radius <= 0:
        raise BadInputError("points: all target points coincide, expected a spread-out target")
    side = float(min(w, h))

    def strata() -> np.ndarray:  # (num_views, 4) Latin hypercube in [0, 1)
        return np.stack([(gen.permutation(num_views) + gen.random(num_views)) / num_views for _ in range(4)], axis=1)

    cells = strata()
    poses: list[np.ndarray] = []
    for k in range(num_views):
        su, sv, stilt, sfill = cells[k]
        for attempt in range(max_attempts):
            if attempt and attempt % 20 == 0:  # stratum too hard (e.g. a big board at an edge): re-draw
                su, sv, stilt, sfill = gen.random(4)
            shrink = 1.0 - 0.5 * attempt / max_attempts  # later attempts allow a smaller board
            phi = (lo + (hi - lo) * sfill) * shrink
            distance = 2.0 * radius * f / (phi * side)
            r_img = 0.5 * phi * side
            umin, umax = margin_px + r_img, w - 1 - margin_px - r_img
            vmin, vmax = margin_px + r_img, h - 1 - margin_px - r_img
            uc = (umin + (umax - umin) * su) if umax > umin else 0.5 * (w - 1)
            vc = (vmin + (vmax - vmin) * sv) if vmax > vmin else 0.5 * (h - 1)
            uc += gen.normal(0.0, 0.02 * w) * (attempt > 0)
            vc += gen.normal(0.0, 0.02 * h) * (attempt > 0)
            ray = np.asarray(_unproject(camera, jnp.asarray([uc, vc], dtype=jnp.float64)), dtype=np.float64)
            if not (np.all(np.isfinite(ray)) and ray[2] > 0.2 * np.linalg.norm(ray)):
                continue
            tilt = math.radians(max_tilt_deg) * stilt
            alpha = gen.uniform(0.0, 2.0 * math.pi)
            roll = math.radians(gen.uniform(-max_roll_deg, max_roll_deg))
            R = rotation(np.array([math.cos(alpha), math.sin(alpha), 0.0]), tilt) @ rotation(
                np.array([0.0, 0.0, 1.0]), roll
            )
            p_centre = ray / ray[2] * distance
            T = np.eye(4)
            T[:3, :3] = R
            T[:3, 3] = p_centre - R @ centroid
            pixels, visible = project_target(camera, T, P)
            if not np.all(visible):
                continue
            inside = (
                (pixels[:, 0] >= margin_px)
                & (pixels[:, 0] <= w - 1 - margin_px)
                & (pixels[:, 1] >= margin_px)
                & (pixels[:, 1] <= h - 1 - margin_px)
            )
            if np.all(inside):
                poses.append(T)
                break
        else:
            raise BadInputError(
                f"random_calibration_views: no pose found for view {k} after {max_attempts} attempts: the "
                f"target (radius {radius:.3f} m) does not fit the {w}x{h} image with fill={fill} and "
                f"margin_px={margin_px}; lower fill or margin_px"
            )
    return poses


def camera_calibration_scene(
    camera: Any,
    target: Any,
    texture: TargetTexture,
    num_views: int,
    seed: int | np.random.Generator = 0,
    *,
    camera_name: str = "cam0",
    target_name: str = "board",
    **view_options: Any,
) -> Scene:
    """A camera-only scene: one free camera, one free target, ``num_views`` random views
    (:func:`random_calibration_views`, which takes ``view_options``), ids ``v000``, ``v001``, ..."""
    poses = random_calibration_views(camera, target.points, num_views, seed, **view_options)
    views = [View(id=f"v{k:03d}", T_cam_target={(camera_name, target_name): T}) for k, T in enumerate(poses)]
    return Scene(
        cameras={camera_name: SceneCamera(camera)},
        targets={target_name: SceneTarget(target, texture)},
        views=views,
    )


# --------------------------------------------------------------------------------------------------
# Rendering a data set


def render_view(
    scene: Scene,
    view: int,
    camera: str,
    options: RenderOptions | None = None,
    rng: np.random.Generator | int = 0,
) -> np.ndarray:
    """Render the image ``camera`` takes at ``view`` (all targets it sees; background otherwise)."""
    pairs = []
    for name, tgt in scene.targets.items():
        T = scene.T_cam_target(view, camera, name)
        if T is not None:
            pairs.append((T, tgt.texture))
    return render_targets_image(scene.cameras[camera].model, pairs, options, rng)


def _camera_record(name: str, cam: SceneCamera) -> dict[str, Any]:
    K, dist = _opencv_params(cam.model)
    model = None
    for attr in ("model_name", "name", "model"):
        value = getattr(cam.model, attr, None)
        if isinstance(value, str):
            model = value
            break
    if model is None:
        cls = type(cam.model).__name__.lower()
        fisheye = "fisheye" in cls or "kannala" in cls
        model = "fisheye" if fisheye else ("pinhole" if dist.size == 0 else f"opencv{dist.size}")
    rec: dict[str, Any] = {
        "model": model,
        "image_size": list(camera_image_size(cam.model)),
        "K": K.tolist(),
        "dist": dist.tolist(),
        "mount": cam.mount,
    }
    if cam.mount != "free":
        rec[f"T_{cam.mount}_{name}"] = np.asarray(cam.pose, dtype=np.float64).tolist()
    return rec


def _target_record(name: str, tgt: SceneTarget) -> dict[str, Any]:
    rec: dict[str, Any] = {
        "type": type(tgt.target).__name__,
        "points": np.asarray(tgt.target.points, dtype=np.float64).tolist(),
        "ids": np.asarray(getattr(tgt.target, "ids", np.arange(len(tgt.target.points)))).tolist(),
        "mount": tgt.mount,
        "texture": {
            "metres_per_pixel": float(tgt.texture.metres_per_pixel),
            "origin_m": [float(o) for o in tgt.texture.origin_m],
            "size_px": [int(tgt.texture.image.shape[1]), int(tgt.texture.image.shape[0])],
        },
    }
    if tgt.mount != "free":
        rec[f"T_{tgt.mount}_{name}"] = np.asarray(tgt.pose, dtype=np.float64).tolist()
    return rec


def render_dataset(
    scene: Scene,
    out_dir: str | Path,
    options: RenderOptions | None = None,
    seed: int = 0,
) -> Path:
    """Render every view of every camera to PNG and write the ground truth beside the images.

    Layout (as in a capture session)::

        out_dir/images/<camera>/<view id>.png
        out_dir/truth.json     schema jcalib.sim.truth/1

    ``truth.json`` holds: ``seed``; ``render_options`` (all :class:`RenderOptions`, noise in
    electrons and DN, plus the effective ``gain_dn_per_e``); ``cameras`` (model, image_size [w, h],
    OpenCV ``K`` and ``dist``, mount and pose); ``targets`` (points (N, 3) m, ids, mount, pose,
    texture resolution); ``views``: id, ``T_base_flange`` (robot scenes), ``images`` {camera:
    relative path}, and ``observations``: per (camera, target) seen, ``T_cam_target`` (4x4, m), the
    ground-truth ``pixels`` of every target point (px, OpenCV convention, null where the model cannot
    project it) and ``visible`` (in front, projectable, on the printed face side, inside the image;
    occlusion between boards is not checked). Images and truth.json are written atomically; the
    image of view ``i`` and camera ``c`` uses noise seed ``[seed, i, c]``: same seed, same files.

    Returns:
        path of ``truth.json``.
    """
    options = RenderOptions() if options is None else options
    if not isinstance(options, RenderOptions):
        raise BadInputError(f"options: got {type(options).__name__}, expected RenderOptions or None")
    if int(seed) != seed or seed < 0:
        raise BadInputError(f"seed: got {seed!r}, expected an integer >= 0")
    out = Path(out_dir)
    camera_names = list(scene.cameras)
    views_out = []
    for i, view in enumerate(scene.views):
        images: dict[str, str] = {}
        observations = []
        for c, cam_name in enumerate(camera_names):
            cam = scene.cameras[cam_name]
            for tgt_name, tgt in scene.targets.items():
                T = scene.T_cam_target(i, cam_name, tgt_name)
                if T is None:
                    continue
                pixels, visible = project_target(cam.model, T, tgt.target.points)
                observations.append(
                    {
                        "camera": cam_name,
                        "target": tgt_name,
                        "T_cam_target": T.tolist(),
                        "pixels": [None if np.any(np.isnan(p)) else [float(p[0]), float(p[1])] for p in pixels],
                        "visible": [bool(v) for v in visible],
                    }
                )
            image = render_view(scene, i, cam_name, options, np.random.default_rng([int(seed), i, c]))
            ok, png = cv2.imencode(".png", image)
            if not ok:  # pragma: no cover - cv2 encodes any uint8/uint16 image
                raise BadInputError(f"render_dataset: PNG encoding failed for view {view.id!r}, camera {cam_name!r}")
            rel = f"images/{cam_name}/{view.id}.png"
            write_bytes_atomic(out / rel, png.tobytes())
            images[cam_name] = rel
        record: dict[str, Any] = {"id": view.id, "images": images, "observations": observations}
        if view.T_base_flange is not None:
            record["T_base_flange"] = np.asarray(view.T_base_flange, dtype=np.float64).tolist()
        views_out.append(record)
    render = options.to_dict()
    render["gain_dn_per_e_effective"] = (
        default_gain_dn_per_e(options.bit_depth, options.full_well_e)
        if options.gain_dn_per_e is None
        else float(options.gain_dn_per_e)
    )
    truth = {
        "schema": TRUTH_SCHEMA,
        "units": "metres, pixels (centre of the top-left pixel is (0, 0)), electrons, DN",
        "seed": int(seed),
        "render_options": render,
        "cameras": {name: _camera_record(name, cam) for name, cam in scene.cameras.items()},
        "targets": {name: _target_record(name, tgt) for name, tgt in scene.targets.items()},
        "views": views_out,
    }
    return write_json_atomic(out / "truth.json", truth)
