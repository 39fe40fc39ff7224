"""Synthetic cells: scenes, target and tool image rendering, sensor noise — what tests, benchmarks
and the demo use when no hardware is there."""

from jcalib.sim.observe import CellTruth, ObservationNoise, SimStation, simulate_observations
from jcalib.sim.render import RenderOptions, render_target_image, render_targets_image
from jcalib.sim.scene import (
    Scene,
    SceneCamera,
    SceneTarget,
    View,
    camera_calibration_scene,
    project_target,
    random_calibration_views,
    render_dataset,
)
from jcalib.sim.textures import TargetTexture, target_texture
from jcalib.sim.tool import SymmetricTool, render_tool_image

__all__ = [
    "CellTruth",
    "ObservationNoise",
    "SimStation",
    "RenderOptions",
    "Scene",
    "SceneCamera",
    "SceneTarget",
    "SymmetricTool",
    "TargetTexture",
    "View",
    "camera_calibration_scene",
    "project_target",
    "random_calibration_views",
    "render_dataset",
    "render_target_image",
    "render_targets_image",
    "render_tool_image",
    "simulate_observations",
    "target_texture",
]
