"""Frame sources for simulated cells: render what a camera sees at the robot's current (true) pose.

:func:`robot_scene_source` composes a :class:`~jcalib.acquisition.robots.simulated.SimulatedController`
(where the flange really is) with the image renderer of :mod:`jcalib.sim.render` (imported on first
use: it needs JAX). The result plugs into :class:`~jcalib.acquisition.cameras.FakeGigECamera` (frames
over real GigE Vision) or :class:`~jcalib.acquisition.cameras.SimulatedCamera` (in-process).

**Tools.** A cell's tool (``tools: {torch: {observed_by: [cam1]}}``) is simulated the way a backlit
tool camera sees it: each base camera that observes the tool has a *tool zone*, a ball of radius
``zone_radius_m`` (default 0.05 m) centred ``zone_distance_m`` in front of it on its optical axis
(default :data:`jcalib.planning.stations.TOOL_VIEW_DISTANCE_M`, where the ``tcp`` planner holds the
tip). While the tool tip (the true TCP) is inside the zone, the camera renders the tool's silhouette on
a backlight (:func:`jcalib.sim.tool.render_tool_image`; the backlight hides the rest of the scene);
otherwise it renders the targets as usual. The tool is a :class:`jcalib.sim.tool.SymmetricTool`
running straight from the tip towards the flange origin. The robot arm and flange are never drawn.

**Kinematic errors.** :func:`simulated_kinematics` draws the true kinematics of a preset arm: seeded
errors of realistic size (:data:`jcalib.sim.kinematic_cells.KINEMATIC_ERRORS`) on its identifiable
joint offsets, link lengths and twists (the minimal set that the calibration keeps,
:func:`jcalib.problems.kinematics.select_parameters` at generic joints, so that the true hand-eye, TCP
and target poses stay the ones a kinematic calibration recovers). The simulated controller then plans
and reports with its nominal model while the cameras see the true flange
(:class:`~jcalib.acquisition.robots.simulated.SimulatedController` ``true_forward``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from jcalib.acquisition.cameras.base import FrameRequest, FrameSource
from jcalib.planning.stations import TOOL_VIEW_DISTANCE_M
from jcalib.geometry.se3 import check_pose, invert, make_pose
from jcalib.errors import BadInputError

#: Shape of a simulated tool: (shaft radius m, cone half-angle deg); its length runs to the flange.
DEFAULT_TOOL_SHAPE = (0.005, 15.0)
#: Radius of a camera's tool zone (see the module docstring), m.
DEFAULT_TOOL_ZONE_RADIUS_M = 0.05


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


@dataclasses.dataclass(frozen=True)
class SceneTool:
    """A tool on the flange of a simulated cell, seen in silhouette by the base cameras observing it.

    Attributes:
        geometry: its shape, a :class:`jcalib.sim.tool.SymmetricTool` (tip at the TCP, axis pointing
            from the tip towards the flange origin).
        T_flange_tool: (4, 4) the true TCP ``T_flange_<tool>``, m; its translation must not be zero.
        observed_by: names of the base cameras that show it.
        zone_distance_m: centre of each observing camera's tool zone on its optical axis, m.
        zone_radius_m: radius of the tool zone, m.
    """

    geometry: Any
    T_flange_tool: np.ndarray
    observed_by: tuple[str, ...] = ()
    zone_distance_m: float = TOOL_VIEW_DISTANCE_M
    zone_radius_m: float = DEFAULT_TOOL_ZONE_RADIUS_M

    def __post_init__(self) -> None:
        T = check_pose(np.asarray(self.T_flange_tool, dtype=np.float64), "SceneTool.T_flange_tool")
        object.__setattr__(self, "T_flange_tool", T)
        object.__setattr__(self, "observed_by", tuple(str(c) for c in self.observed_by))
        if float(np.linalg.norm(T[:3, 3])) < 1e-6:
            raise BadInputError(
                "SceneTool.T_flange_tool: the tip is at the flange origin; expected a tool that sticks out "
                "(translation > 1 um, m)"
            )
        for name in ("zone_distance_m", "zone_radius_m"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise BadInputError(f"SceneTool.{name}: got {value!r}, expected a positive distance (m)")

    @property
    def T_tool_solid(self) -> np.ndarray:
        """(4, 4) pose of the silhouette solid's frame in the TCP frame: same origin (the tip), z
        towards the flange origin (:class:`jcalib.sim.tool.SymmetricTool` runs along its +z)."""
        T = np.asarray(self.T_flange_tool, dtype=np.float64)
        z = -T[:3, :3].T @ T[:3, 3]
        z = z / np.linalg.norm(z)
        x = np.eye(3)[int(np.argmin(np.abs(z)))]
        x = x - np.dot(x, z) * z
        x /= np.linalg.norm(x)
        return make_pose(np.stack([x, np.cross(z, x), z], axis=1), np.zeros(3))

    def in_zone(self, T_cam_flange: np.ndarray) -> bool:
        """Whether the tip lies in the tool zone of a camera at ``T_cam_flange`` (4, 4), m."""
        tip = T_cam_flange[:3, :3] @ self.T_flange_tool[:3, 3] + T_cam_flange[:3, 3]
        return float(np.linalg.norm(tip - np.array([0.0, 0.0, self.zone_distance_m]))) <= self.zone_radius_m


@dataclasses.dataclass(frozen=True)
class CellScene:
    """A simulated robot cell: a :class:`jcalib.sim.scene.Scene` (cameras, targets) plus its tools.

    ``cameras``, ``targets`` and ``views`` are the scene's, so a ``CellScene`` serves wherever a
    scene's cameras are listed (:func:`jcalib.app.simulate.run_simulated_cell`).

    Attributes:
        scene: cameras and targets on "base" / "flange" (views unused).
        tools: tool name -> :class:`SceneTool`.
    """

    scene: Any
    tools: Mapping[str, SceneTool] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, tool in self.tools.items():
            for cam in tool.observed_by:
                if cam not in self.scene.cameras:
                    raise BadInputError(f"tools[{name!r}].observed_by: camera {cam!r} is not in the scene")
                if self.scene.cameras[cam].mount != "base":
                    raise BadInputError(
                        f"tools[{name!r}].observed_by: camera {cam!r} has mount "
                        f"{self.scene.cameras[cam].mount!r}; expected a base camera"
                    )

    @property
    def cameras(self) -> Mapping[str, Any]:
        return self.scene.cameras

    @property
    def targets(self) -> Mapping[str, Any]:
        return self.scene.targets

    @property
    def views(self) -> Sequence[Any]:
        return self.scene.views

    def tool_in_view(self, camera: str, T_base_flange: np.ndarray) -> str | None:
        """The tool whose tip is in ``camera``'s tool zone at ``T_base_flange`` (4, 4, m), or None."""
        cam = self.scene.cameras[camera]
        if cam.mount != "base":
            return None
        T_cam_flange = invert(np.asarray(cam.pose, dtype=np.float64)) @ T_base_flange
        for name, tool in self.tools.items():
            if camera in tool.observed_by and tool.in_zone(T_cam_flange):
                return name
        return None

    def warm_up(self, camera: str) -> None:
        """Render each tool that ``camera`` observes once (side-on at its zone centre, result dropped), so
        the renderer's JAX code is compiled before frames are due: a fake GigE camera must answer within
        about a second (:class:`jcalib.acquisition.cameras.FakeGigECamera`), a first tool frame takes longer."""
        from jcalib.sim.tool import render_tool_image

        cam = self.scene.cameras[camera]
        for tool in self.tools.values():
            if camera in tool.observed_by:
                side_on = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # solid z = camera x
                render_tool_image(cam.model, make_pose(side_on, np.array([0.0, 0.0, tool.zone_distance_m])),
                                  tool.geometry)  # fmt: skip

    def render(self, camera: str, T_base_flange: np.ndarray, options: Any = None, rng: Any = 0) -> np.ndarray:
        """The image ``camera`` takes with the flange at ``T_base_flange`` (4, 4, m): the tool's silhouette
        on the backlight when its tip is in the camera's tool zone, else the targets (module docstring).

        Args:
            options: :class:`jcalib.sim.render.RenderOptions` (None: defaults).
            rng: sensor-noise seed or generator.
        """
        from jcalib.sim.render import RenderOptions, expose

        options = options if options is not None else RenderOptions()
        gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        return expose(self.electrons(camera, T_base_flange, options), options, gen)

    def electrons(self, camera: str, T_base_flange: np.ndarray, options: Any) -> np.ndarray:
        """The noise-free part of :meth:`render`: mean photo-electrons per pixel, (H, W) float64."""
        from jcalib.sim.render import exposure_electrons, render_reflectance

        T_base_flange = np.asarray(T_base_flange, dtype=np.float64)
        tool_name = self.tool_in_view(camera, T_base_flange)
        cam = self.scene.cameras[camera]
        if tool_name is not None:
            from jcalib.sim.tool import tool_radiance

            tool = self.tools[tool_name]
            T_cam_solid = invert(np.asarray(cam.pose, dtype=np.float64)) @ T_base_flange @ tool.T_flange_tool
            T_cam_solid = T_cam_solid @ tool.T_tool_solid
            radiance, cos_theta, lens_valid, _ = tool_radiance(cam.model, T_cam_solid, tool.geometry, options)
            return exposure_electrons(radiance, cos_theta, lens_valid, options)
        from jcalib.sim.scene import View

        live = dataclasses.replace(self.scene, views=[View(id="live", T_base_flange=T_base_flange)])
        pairs = []
        for name, tgt in live.targets.items():
            T = live.T_cam_target(0, camera, name)
            if T is not None:
                pairs.append((T, tgt.texture))
        return exposure_electrons(*render_reflectance(cam.model, pairs, options), options)


def _through_lens(cell: CellScene, camera: str, lens: Any, zoom: float, focus: float) -> CellScene:
    """The cell with ``camera`` at a lens setting: the lens's intrinsics there and its frame shifted."""
    from jcalib.sim.zoom import mount_at

    cam = cell.scene.cameras[camera]
    moved = dataclasses.replace(cam, model=lens.camera(zoom, focus), pose=mount_at(cam.pose, lens, zoom, focus))
    return dataclasses.replace(cell, scene=dataclasses.replace(cell.scene, cameras={**cell.scene.cameras, camera: moved}))


def scene_frame_source(
    scene: Any,
    camera: str,
    pose_of_flange,
    *,
    options: Any = None,
    reference_exposure_us: float = 10000.0,
    seed: int = 0,
    lens: Any = None,
) -> FrameSource:
    """A frame source rendering camera ``camera`` of a simulated cell at the robot's pose.

    Args:
        scene: a :class:`CellScene` (targets, and tools shown in their cameras' tool zones) or a
            :class:`jcalib.sim.scene.Scene` (targets only); cameras and targets mounted on "base" /
            "flange", views unused.
        camera: camera name in ``scene.cameras``.
        pose_of_flange: callable returning the true ``T_base_flange`` (4, 4), m.
        options: :class:`jcalib.sim.render.RenderOptions`; brightness follows the requested exposure.
        reference_exposure_us: exposure at which ``options`` applies unchanged, us.
        seed: sensor-noise seed; frame ``k`` uses ``seed + k``.
        lens: a motorised zoom lens (:class:`jcalib.sim.zoom.ZoomLensModel`): each frame is rendered through
            it at the request's ``Zoom`` and ``Focus`` (:attr:`FrameRequest.lens`, default 500 each): its
            intrinsics there, the camera frame shifted along its axis from its pose at ``Zoom = 0``.

    A camera that observes a tool renders it once here (:meth:`CellScene.warm_up`). The noise-free exposure
    of the last pose is kept: while the robot stands still (a live view), a frame costs only its sensor
    noise (with ``options.fast_noise``, a few tens of ms at 1280x960).
    """
    if camera not in scene.cameras:
        raise BadInputError(f"camera: {camera!r} is not in the scene (has {', '.join(scene.cameras)})")
    cell = scene if isinstance(scene, CellScene) else CellScene(scene)
    cell.warm_up(camera)
    last: dict[str, Any] = {}  # the noise-free exposure of the last pose (a robot standing still)

    def source(req: FrameRequest) -> np.ndarray:
        from jcalib.sim.render import RenderOptions, expose

        opts = options if options is not None else RenderOptions()
        scale = float(req.exposure_us) / reference_exposure_us
        if scale != 1.0:
            opts = dataclasses.replace(opts, white_electrons=opts.white_electrons * scale)
        T = np.asarray(pose_of_flange(), dtype=np.float64)
        setting = (float(req.lens.get("Zoom", 500.0)), float(req.lens.get("Focus", 500.0))) if lens is not None else None
        key = (T.tobytes(), opts, setting)
        if last.get("key") != key:
            last["electrons"] = (cell if lens is None else _through_lens(cell, camera, lens, *setting)).electrons(
                camera, T, opts)
            last["key"] = key
        return expose(last["electrons"], opts, np.random.default_rng(seed + req.index))

    return source


def scene_from_layout(layout: Any, *, texture_px_per_square: float = 24.0) -> CellScene:
    """The simulated cell of a nominal cell layout (its ground truth): cameras, targets and tools.

    Each tool is a :class:`jcalib.sim.tool.SymmetricTool` of :data:`DEFAULT_TOOL_SHAPE` from its
    nominal TCP to the flange, shown by the base cameras of its ``observed_by`` (module docstring).

    Args:
        layout: a :class:`jcalib.planning.layout.CellLayout`.
        texture_px_per_square: resolution of the printed targets, texels per grid spacing.

    Returns:
        :class:`CellScene` (``.scene`` is the :class:`jcalib.sim.scene.Scene` of cameras and targets).
    """
    from jcalib.geometry.cameras.factory import camera_from_opencv
    from jcalib.sim.scene import Scene, SceneCamera
    from jcalib.sim.scene import SceneTarget as SimTarget
    from jcalib.sim.textures import target_texture
    from jcalib.sim.tool import SymmetricTool

    cameras = {
        name: SceneCamera(camera_from_opencv(c.K, c.dist, c.image_size, fisheye=c.model == "fisheye"), c.mount, c.pose)
        for name, c in layout.cameras.items()
    }
    targets = {}
    for name, t in layout.targets.items():
        pts = np.asarray(t.geometry.points, dtype=np.float64)
        d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)  # the finest spacing (an AprilGrid's gap)
        spacing = float(np.min(d[d > 1e-9])) if np.any(d > 1e-9) else 0.01
        tex = target_texture(t.geometry, spacing / texture_px_per_square)
        targets[name] = SimTarget(t.geometry, tex, t.mount, t.pose)
    tools = {}
    for name, T_flange_tool in layout.tools.items():
        observers = tuple(c for c in layout.cell.tools[name].observed_by if layout.cameras[c].mount == "base")
        length = float(np.linalg.norm(np.asarray(T_flange_tool)[:3, 3]))
        shape = SymmetricTool(shaft_radius_m=DEFAULT_TOOL_SHAPE[0], cone_half_angle_deg=DEFAULT_TOOL_SHAPE[1],
                              length_m=length)  # fmt: skip
        tools[name] = SceneTool(shape, np.asarray(T_flange_tool, dtype=np.float64), observers)
    return CellScene(Scene(cameras=cameras, targets=targets, views=[]), tools)


#: The parameter groups that carry simulated kinematic errors.
KINEMATIC_ERROR_GROUPS = ("joint_offsets", "link_lengths", "twists")


@dataclasses.dataclass(frozen=True)
class SimulatedKinematics:
    """The true kinematics of a simulated arm whose controller uses the nominal preset.

    Attributes:
        model: the preset's :class:`jcalib.geometry.kinematic_models.Kinematics` (dh; nominal parameters).
        params: ``(P,)`` true parameters (m, rad).
        error_mask: ``(P,)`` bool, the parameters that got an error (the identifiable subset of
            :data:`KINEMATIC_ERROR_GROUPS`).
        preset: the preset name.  seed, scale: the errors' seed and the factor on their σ.
    """

    model: Any
    params: np.ndarray
    error_mask: np.ndarray
    preset: str
    seed: int
    scale: float

    def forward(self):
        """The controller's ``true_forward``: joints (n,) rad -> true ``T_base_flange`` (4, 4), m."""
        from jcalib.acquisition.robots.simulated import kinematics_forward

        return kinematics_forward(self.model, self.params)

    def to_json(self) -> dict:
        """The truth file's ``kinematics`` entry: parameter ``names``, true ``values`` and ``nominal``
        (m, rad), the ones with an error (``errors_on``), and the true per-joint zero offsets in
        controller units (``controller_offsets``: deg; see
        :func:`jcalib.geometry.kinematic_models.controller_offsets`)."""
        from jcalib.geometry import kinematic_models

        names = list(self.model.param_names)
        return {
            "preset": self.preset, "convention": self.model.convention, "units": "m, rad",
            "seed": int(self.seed), "scale": float(self.scale), "names": names,
            "values": np.asarray(self.params, dtype=np.float64).tolist(),
            "nominal": np.asarray(self.model.nominal, dtype=np.float64).tolist(),
            "errors_on": [n for n, m in zip(names, self.error_mask) if m],
            "controller_offsets": kinematic_models.controller_offsets(self.model, self.params),
        }  # fmt: skip


def simulated_kinematics(
    controller_model: Any,
    preset: str,
    seed: int,
    scale: float = 1.0,
    *,
    repeatability_m: float = 1.3e-5,
    repeatability_rad: float = 2e-5,
) -> SimulatedKinematics:
    """Seeded true kinematics for a simulated arm (module docstring: *Kinematic errors*).

    Args:
        controller_model: the simulated controller's model; it must be the preset's
            :class:`~jcalib.acquisition.robots.model.DHRobotModel` (its joints are the kinematics').
        preset: the robot preset (a key of :data:`jcalib.geometry.kinematic_models.PRESETS`).
        seed: seed of the errors.  scale: factor on their σ (1: a real arm's, about 0.05 deg and 0.5 mm).
        repeatability_m, repeatability_rad: the controller's repeatability (σ per axis), which whitens
            the identifiability scan as in the calibration.

    Raises:
        BadInputError: a controller model that is not a preset's DH model, an unknown preset, or a bad scale.
    """
    from jcalib.acquisition.robots.model import DHRobotModel
    from jcalib.geometry import kinematic_models
    from jcalib.problems.kinematics import generic_joints, select_parameters
    from jcalib.sim.kinematic_cells import kinematic_errors

    if not isinstance(controller_model, DHRobotModel):
        raise BadInputError(
            f"--kinematic-errors: the simulated robot must be a robot preset (DH kinematics) for its kinematics "
            f"to carry errors, got the controller model {type(controller_model).__name__}; name the robot with "
            f"robot: {{model: <preset>}} in the cell or --robot ({', '.join(kinematic_models.PRESETS)})"
        )
    if preset not in kinematic_models.PRESETS:
        raise BadInputError(
            f"--kinematic-errors: robot {preset!r} has no kinematics preset; use one of {', '.join(kinematic_models.PRESETS)}"
        )
    if not (np.isfinite(scale) and scale >= 0.0):
        raise BadInputError(f"--kinematic-error-scale: expected a factor >= 0 on the errors' σ, got {scale!r}")
    model = kinematic_models.PRESETS[preset]()
    S = np.diag(np.concatenate([np.full(3, 1.0 / repeatability_rad), np.full(3, 1.0 / repeatability_m)]))
    mask = select_parameters(model, KINEMATIC_ERROR_GROUPS, generic_joints(model), S, preset).free
    params = kinematic_errors(model, np.random.default_rng(seed), mask, float(scale))
    return SimulatedKinematics(model, params, mask, preset, int(seed), float(scale))


def layout_truth(layout: Any, kinematics: SimulatedKinematics | None = None, **controller: Any) -> dict:
    """Ground truth of a simulated cell as a JSON-ready mapping (``jcalib.sim.cell/1``).

    Holds the robot preset, every camera's OpenCV ``K``, ``dist``, image size and pose
    (``T_flange_<cam>`` or ``T_base_<cam>``), every target's points and pose, the tools' TCPs
    (``T_flange_<tool>``), and ``controller`` (e.g. repeatability, seed). Metres, pixels. With
    ``kinematics`` (a robot with kinematic errors), ``robot.kinematics`` holds its true parameters
    (:meth:`SimulatedKinematics.to_json`).
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
    robot = {"preset": layout.robot, "home_deg": np.degrees(layout.home_rad).tolist(), **controller}
    if kinematics is not None:
        robot["kinematics"] = kinematics.to_json()
    return {
        "schema": "jcalib.sim.cell/1",
        "units": "metres, pixels (centre of the top-left pixel is (0, 0))",
        "robot": robot,
        "cameras": cams,
        "targets": tgts,
        "tools": {name: {f"T_flange_{name}": T.tolist()} for name, T in layout.tools.items()},
    }
