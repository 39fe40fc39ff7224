"""Nominal cell layout: where the robot, cameras, targets and tools are, for planning and simulation.

A cell spec says *what* is in the cell and what is unknown; a planner (and a simulator) also needs to
know roughly *where* things are. :func:`cell_layout` fills in what the spec leaves open with documented
defaults, so ``jcalib plan`` and ``jcalib simulate`` agree on one geometry for the same cell file:

- **robot**: ``robot: {model: PRESET}`` in the cell (a preset of :mod:`jcalib.geometry.robots`), else
  ``kuka_kr10_r1100_sixx``. Home posture: :func:`jcalib.geometry.robots.home_joints` (where the simulated
  controllers start).
  The *tool axis* (the flange axis the tool points along: x for KUKA's ``$FLANGE``, z for ABB's
  ``tool0``) is derived from the kinematics (joint-6 axis, pointing away from the wrist).
- **intrinsics**: the camera's ``intrinsics`` when given (image size ``2 (cx, cy) + 1``), else a
  640 x 480 sensor (or ``image_size``) with ``fx = fy = 1.2 width`` (45 deg horizontal field of view),
  centred principal point and zero distortion of the cell's model.
- **work point**: 0.7 m below the flange at home; a base target's centre sits there, face up (target
  z down, so a camera above sees the printed side), the k-th base target 0.3 m further along base y.
- **flange camera**: looking along the tool axis, 50 mm in front of the flange (the k-th one 80 mm
  aside along its x: a stereo pair).
- **flange target**: centre 30 mm along the tool axis, printed side facing along it.
- **base camera**: looking at the first base target from 1.3 x its viewing distance, tilted 25 deg;
  without a base target it looks back (along -x) at a *presentation point* 0.2 m below and 0.1 m in
  front of the home flange, where the robot presents a flange target facing +x (from the target's viewing
  distance; in a cell without targets, where it observes a tool, from 0.35 m).
- **tool** (TCP): 150 mm along the tool axis; its z axis along the tool axis (``rotation_z_to``).

A ``pose`` in the cell spec (camera, target) replaces the default. Lengths in metres.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.geometry.se3 import invert, make_pose, rot_x, rotation_z_to
from jcalib.errors import BadInputError

DEFAULT_ROBOT = "kuka_kr10_r1100_sixx"
DEFAULT_IMAGE_SIZE = (640, 480)
#: A fixed camera of a cell without targets looks at the presentation point from this far, m (the distance
#: at which ``plan --kind tcp`` holds a tool tip in front of a camera).
TOOL_VIEW_DISTANCE_M = 0.35
_DIST_LEN = {"pinhole": 0, "opencv4": 4, "opencv5": 5, "opencv8": 8, "opencv12": 12, "opencv14": 14, "fisheye": 4}


@dataclass(frozen=True)
class CameraLayout:
    """A camera's nominal intrinsics (OpenCV form) and mounting.

    Attributes:
        name: camera id.
        model: lens model name of the cell spec.
        K: (3, 3) camera matrix, px.  dist: OpenCV distortion vector.
        image_size: (width, height), px.
        mount: "flange" or "base".
        pose: (4, 4) ``T_flange_cam`` or ``T_base_cam``, m.
    """

    name: str
    model: str
    K: np.ndarray
    dist: np.ndarray
    image_size: tuple[int, int]
    mount: str
    pose: np.ndarray


@dataclass(frozen=True)
class TargetLayout:
    """A target's geometry and nominal mounting.

    Attributes:
        name: target id.  geometry: :mod:`jcalib.geometry.targets` object.
        mount: "flange" or "base".
        pose: (4, 4) ``T_flange_target`` or ``T_base_target``, m.
        centre: (3,) centroid of the target points, target frame, m.
        radius: largest distance of a point from the centroid, m.
    """

    name: str
    geometry: Any
    mount: str
    pose: np.ndarray
    centre: np.ndarray
    radius: float


@dataclass(frozen=True)
class CellLayout:
    """Nominal geometry of a robot cell (see the module docstring for the defaults).

    Attributes:
        robot: preset name.  home_rad: (6,) home joints, rad.
        T_base_flange_home: (4, 4) flange at home, m.
        tool_axis: (3,) unit vector in the flange frame along which tools point.
        work_point: (3,) base-frame point where base targets are centred, m.
        cameras, targets: by name.  tools: tool name -> nominal ``T_flange_tool`` (4, 4), m.
        cell: the parsed :class:`jcalib.io.cell.CellSpec`; ``cell_dict``: the spec as loaded.
    """

    robot: str
    home_rad: np.ndarray
    T_base_flange_home: np.ndarray
    tool_axis: np.ndarray
    work_point: np.ndarray
    cameras: dict[str, CameraLayout]
    targets: dict[str, TargetLayout]
    tools: dict[str, np.ndarray]
    cell: Any
    cell_dict: dict = field(default_factory=dict)

    def dh_robot(self):
        """The :class:`jcalib.geometry.kinematics.DHRobot` of :attr:`robot`."""
        from jcalib.geometry.robots import robot_preset

        return robot_preset(self.robot)

    def viewing_distance(self, camera: str, target: str, fill: float = 0.5) -> float:
        """Distance (m) at which ``target`` spans ``fill`` of the smaller image side of ``camera``."""
        cam, tgt = self.cameras[camera], self.targets[target]
        f = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
        return float(f * 2.0 * tgt.radius / (fill * min(cam.image_size)))


def load_cell_dict(cell: str | os.PathLike | dict) -> tuple[dict, str]:
    """The cell spec as a plain mapping and its source name (a path is read as YAML)."""
    if isinstance(cell, dict):
        return cell, "<dict>"
    import yaml

    path = Path(cell)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise BadInputError(f"--cell: cannot read the cell spec {path}: {e}") from None
    except yaml.YAMLError as e:
        raise BadInputError(f"--cell: {path} is not valid YAML: {e}") from None
    if not isinstance(data, dict):
        raise BadInputError(f"--cell: {path} must hold a mapping with 'schema: jcalib.cell/1', got {type(data).__name__}")
    return data, str(path)


def _tool_axis(dh, q: np.ndarray) -> np.ndarray:
    """Unit vector in the flange frame along the joint-6 axis, pointing away from the wrist."""
    from jcalib.geometry.kinematics import forward_kinematics, link_frames

    L = np.asarray(link_frames(dh, q))
    T_flange = np.asarray(forward_kinematics(dh, q))
    axis = L[-2][:3, 2]
    if float(np.dot(axis, T_flange[:3, 3] - L[-2][:3, 3])) < 0:
        axis = -axis
    a = T_flange[:3, :3].T @ axis
    return a / np.linalg.norm(a)


def frame_with_z(z: np.ndarray) -> np.ndarray:
    """(3, 3) rotation whose z column is ``z`` (a flange axis) and x the next flange axis cyclically."""
    i = int(np.argmax(np.abs(z)))
    x = np.zeros(3)
    x[(i + 1) % 3] = 1.0
    x = x - np.dot(x, z) * z
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def look_at(position: np.ndarray, point: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    """(4, 4) camera pose at ``position`` with z towards ``point`` and x as close as possible to ``x_hint``."""
    z = np.asarray(point, dtype=np.float64) - np.asarray(position, dtype=np.float64)
    z /= np.linalg.norm(z)
    x = np.asarray(x_hint, dtype=np.float64) - np.dot(x_hint, z) * z
    if np.linalg.norm(x) < 1e-9:
        x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    x /= np.linalg.norm(x)
    return make_pose(np.stack([x, np.cross(z, x), z], axis=1), position)


def _parse_size(image_size: Any) -> tuple[int, int] | None:
    if image_size is None:
        return None
    try:
        w, h = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise BadInputError(f"image_size: expected (width, height) in pixels, got {image_size!r}") from None
    if not (16 <= w <= 16384 and 16 <= h <= 16384):
        raise BadInputError(f"image_size: expected width and height in 16..16384 px, got {image_size!r}")
    return w, h


def cell_layout(
    cell: str | os.PathLike | dict,
    *,
    robot: str | None = None,
    image_size: tuple[int, int] | None = None,
) -> CellLayout:
    """Nominal layout of a robot cell from its spec (defaults in the module docstring).

    Args:
        cell: path of ``cell.yaml`` or the loaded mapping.
        robot: robot preset name (default: the cell's ``robot.model``, else ``kuka_kr10_r1100_sixx``).
        image_size: (width, height) of cameras without ``intrinsics`` in the spec, px.

    Raises:
        BadInputError: invalid cell, unknown preset, or a ``free`` camera / target (no robot to plan for).
    """
    from jcalib.geometry.kinematics import forward_kinematics
    from jcalib.geometry.robots import home_joints, robot_preset
    from jcalib.io.cell import parse_cell

    data, source = load_cell_dict(cell)
    spec = parse_cell(data, source)
    robot_name = robot or ((data.get("robot") or {}).get("model") if isinstance(data.get("robot"), dict) else None)
    robot_name = robot_name or DEFAULT_ROBOT
    dh = robot_preset(str(robot_name))  # BadInputError for an unknown preset
    home = home_joints(dh)
    T_home = np.asarray(forward_kinematics(dh, home), dtype=np.float64)
    a = _tool_axis(dh, home)
    work = T_home[:3, 3] + np.array([0.0, 0.0, -0.7])
    size_default = _parse_size(image_size) or DEFAULT_IMAGE_SIZE

    for name, c in spec.cameras.items():
        if c.mount == "free":
            raise BadInputError(f"{source}: cameras.{name} has mount 'free': planning and simulation need a robot cell (mount flange or base)")
    for name, t in spec.targets.items():
        if t.mount == "free":
            raise BadInputError(f"{source}: targets.{name} has mount 'free': planning and simulation need a robot cell (mount flange or base)")
    if not spec.targets and not any(spec.cameras[c].mount == "base" for t in spec.tools.values() for c in t.observed_by):
        raise BadInputError(f"{source}: the cell has no target (and no tool seen by a fixed camera); planning and "
                            "simulation need one")

    targets: dict[str, TargetLayout] = {}
    k_base = 0
    for name, t in spec.targets.items():
        geom = t.geometry()
        pts = np.asarray(geom.points, dtype=np.float64)
        centre = pts.mean(axis=0)
        radius = float(np.max(np.linalg.norm(pts - centre, axis=1)))
        if t.pose is not None:
            pose = t.pose
        elif t.mount == "base":
            R = rot_x(np.pi)  # face up: target z points down into the table
            pose = make_pose(R, work + np.array([0.0, 0.3 * k_base, 0.0]) - R @ centre)
            k_base += 1
        else:
            R = frame_with_z(-a)  # printed side (seen from -z) faces along the tool axis
            pose = make_pose(R, 0.03 * a - R @ centre)
        targets[name] = TargetLayout(name, geom, t.mount, np.asarray(pose, dtype=np.float64), centre, radius)

    base_targets = [t for t in targets.values() if t.mount == "base"]
    flange_targets = [t for t in targets.values() if t.mount == "flange"]
    cameras: dict[str, CameraLayout] = {}
    k_flange = 0
    for name, c in spec.cameras.items():
        n_dist = _DIST_LEN[c.model]
        if c.K is not None:
            K = np.asarray(c.K, dtype=np.float64)
            size = (int(round(2 * K[0, 2] + 1)), int(round(2 * K[1, 2] + 1)))
            dist = np.zeros(n_dist) if c.dist is None or c.dist.size == 0 else np.asarray(c.dist, dtype=np.float64)
            if image_size is not None:
                size = size_default
        else:
            w, h = size = size_default
            K = np.array([[1.2 * w, 0.0, (w - 1) / 2.0], [0.0, 1.2 * w, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
            dist = np.zeros(n_dist)
        cameras[name] = CameraLayout(name, c.model, K, dist, size, c.mount, np.eye(4))
    # poses need the intrinsics (viewing distances), so a second pass
    for name, c in spec.cameras.items():
        cam = cameras[name]
        if c.pose is not None:
            pose = c.pose
        elif c.mount == "flange":
            R = frame_with_z(a)
            pose = make_pose(R, 0.05 * a + 0.08 * k_flange * R[:, 0])
            k_flange += 1
        else:
            tmp = CellLayout(str(robot_name), home, T_home, a, work, cameras, targets, {}, spec, data)
            if base_targets:
                t = base_targets[0]
                D = 1.3 * tmp.viewing_distance(name, t.name)
                c_base = t.pose[:3, :3] @ t.centre + t.pose[:3, 3]
                # on the printed side (-z of the target), tilted 25 deg about the target x axis
                d = t.pose[:3, :3] @ np.array([0.0, np.sin(np.radians(25.0)), -np.cos(np.radians(25.0))])
                pose = look_at(c_base + D * d, c_base, t.pose[:3, :3][:, 0])
            else:
                # the presentation point; without a flange target, at the tool-viewing distance of a TCP plan
                D = tmp.viewing_distance(name, flange_targets[0].name) if flange_targets else TOOL_VIEW_DISTANCE_M
                p = T_home[:3, 3] + np.array([0.1, 0.0, -0.2])
                pose = look_at(p + np.array([D, 0.0, 0.0]), p, np.array([0.0, -1.0, 0.0]))
        cameras[name] = CameraLayout(name, cam.model, cam.K, cam.dist, cam.image_size, cam.mount, np.asarray(pose, dtype=np.float64))

    # the TCP's z axis is the tool axis, from the flange towards the tip (jcalib's tool convention)
    tools = {name: make_pose(rotation_z_to(a), 0.15 * a) for name in spec.tools}
    return CellLayout(str(robot_name), home, T_home, a, work, cameras, targets, tools, spec, data)


def presentation_pose(layout: CellLayout, camera: str, target: str, T_cam_target: np.ndarray) -> np.ndarray:
    """``T_base_flange`` that shows ``target`` to ``camera`` at ``T_cam_target`` (one of them on the flange).

    Eye-in-hand (camera on the flange, target on the base):
    ``T_base_flange = T_base_target @ inv(T_cam_target) @ inv(T_flange_cam)``;
    eye-to-hand (camera on the base, target on the flange):
    ``T_base_flange = T_base_cam @ T_cam_target @ inv(T_flange_target)``.
    """
    cam, tgt = layout.cameras[camera], layout.targets[target]
    if cam.mount == "flange" and tgt.mount == "base":
        return tgt.pose @ invert(T_cam_target) @ invert(cam.pose)
    if cam.mount == "base" and tgt.mount == "flange":
        return cam.pose @ T_cam_target @ invert(tgt.pose)
    raise BadInputError(
        f"camera {camera!r} (mount {cam.mount}) and target {target!r} (mount {tgt.mount}): one must be on "
        "the flange and the other on the base for the robot to change their relative pose"
    )
