"""Observations of any cell spec at given stations, from a given ground truth: what a study simulates.

One function, :func:`simulate_observations`, for every kind of cell (camera-only and rigs, eye-in-hand,
eye-to-hand, TCP from tool tips and axes, pivots from contacts, 6-DOF pose measurements, whole cells,
several robots): at each station it places every camera, target and tool in the cell's frame from the
truth and the station's true flange poses, and records what the cell's sensors would measure:

- target corners every camera sees (in front of it, inside the image, the printed face towards it),
  with Gaussian pixel noise; a view with fewer than ``min_points`` corners is not detected;
- 6-DOF poses ``T_cam_target`` instead of corners for the pairs a station lists in ``pose_pairs``
  (a pose sensor, a marker tracker), with a right-perturbation noise;
- the tip of every tool (its frame's origin) that a camera in its ``observed_by`` sees, with pixel noise,
  and optionally points on the imaged tool axis (the tool frame's -z, towards the flange);
- the contacts the station lists (the station's true poses put the tip there);
- the measured flange poses: the true ones times ``Exp(δ)``, δ ~ N(0, diag(σ_rot², σ_t²)) (right
  perturbation, flange frame), as the robot pose model of the builder assumes.

Frames and names follow the builder (docs/design.md): the cell's frame is ``base`` (one robot), ``world``
(several robots) or, without robots, the frame of the rig's reference camera. Every random draw happens
whatever the outcome (a detection out of view still consumes its noise), so a station's noise does not
depend on what the other stations saw.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import exp_so3, invert, make_pose
from jcalib.geometry.targets import warped_points
from jcalib.io.cell import CellSpec, load_cell
from jcalib.sim.render import camera_image_size

__all__ = ["CellTruth", "ObservationNoise", "SimStation", "perturb_pose", "simulate_observations",
           "thing_poses"]


@dataclass(frozen=True)
class CellTruth:
    """The true state of a cell (metres, radians, pixels).

    Attributes:
        cameras: camera id -> true camera model (its ``image_size`` is the image size).
        poses: thing name (camera, target, tool) -> its true pose on its holder: ``T_<frame>_<x>`` for
            a thing fixed in the cell's frame (in a cell without robots: the camera's pose in the rig
            frame, identity for the reference camera), ``T_flange_<x>`` for a thing on a flange (a
            tool's TCP). Free targets have none (their pose is per station).
        bases: robot -> ``T_world_<robot>`` (several robots; identity for the one whose base is the
            world frame). Empty with one robot or none.
        points: cell point -> ``(3,)`` position in the cell's frame.
        target_points: target id -> ``(N, 3)`` its points in its own frame, as designed (the
            observations carry these).
        target_warp: target id -> ``(2,)`` true warp ``(c0, c1)`` m of a bent board
            (:func:`jcalib.geometry.targets.warp_bow`): its points are seen there. Flat if absent.
        frame: the cell's frame name (``base``, ``world`` or the rig's reference camera).
    """

    cameras: Mapping[str, object]
    poses: Mapping[str, np.ndarray]
    target_points: Mapping[str, np.ndarray]
    frame: str
    bases: Mapping[str, np.ndarray] = field(default_factory=dict)
    points: Mapping[str, np.ndarray] = field(default_factory=dict)
    target_warp: Mapping[str, np.ndarray] = field(default_factory=dict)

    def transform(self, name: str) -> np.ndarray | None:
        """The true value of a transform the builder reports (``T_flange_cam0``, ``T_base_board``,
        ``T_world_r2``, ``T_cam0_cam1`` in a rig whatever its reference camera), or None."""
        if not name.startswith("T_"):
            return None
        for thing, T in self.poses.items():
            if name == f"T_flange_{thing}" or name == f"T_{self.frame}_{thing}":
                return np.asarray(T, np.float64)
        for robot, T in self.bases.items():
            if name == f"T_world_{robot}":
                return np.asarray(T, np.float64)
        for a in self.cameras:  # a rig seen from another reference camera
            for b, Tb in self.poses.items():
                if name == f"T_{a}_{b}" and a in self.poses:
                    return invert(np.asarray(self.poses[a], np.float64)) @ np.asarray(Tb, np.float64)
        return None


@dataclass(frozen=True)
class SimStation:
    """One station to simulate: where everything truly is.

    Attributes:
        id: station id.
        flange: robot -> true flange pose ``T_<robot base>_flange`` (4, 4), m, for the robots that
            take part in this station (one robot: key ``"robot"`` or the robot's name).
        free: free target -> its true pose in the cell's frame (4, 4), m.
        contacts: ``(tool, point)`` pairs whose tip touches the point at this station.
        pose_pairs: ``(camera, target)`` pairs measured as 6-DOF poses here instead of corners.
        axis_points: points detected on each imaged tool axis (0: the tip alone).
        axis_length_m: length of the tool axis they span, from the tip towards the flange (m).
    """

    id: str
    flange: Mapping[str, np.ndarray] = field(default_factory=dict)
    free: Mapping[str, np.ndarray] = field(default_factory=dict)
    contacts: tuple[tuple[str, str], ...] = ()
    pose_pairs: tuple[tuple[str, str], ...] = ()
    axis_points: int = 0
    axis_length_m: float = 0.1


@dataclass(frozen=True)
class ObservationNoise:
    """Measurement noise of a simulation (σ per coordinate).

    Attributes:
        pixel_sigma_px: target corners.  tip_sigma_px: tool tips.  axis_sigma_px: tool-axis points.
        robot: robot -> ``(translation σ (3,) m, rotation σ (3,) deg)`` of its recorded flange poses
            (a robot not listed records its poses exactly).
        pose_rotation_deg, pose_translation_m: 6-DOF pose measurements.
        dropout_rate: probability that a detection (a camera's view of a target, or a tool tip) is lost.
        min_points: fewest corners of a view that count as a detection (the builder needs 6; a target of
            fewer points, a single AprilTag, is detected when all its points are seen).
    """

    pixel_sigma_px: float = 0.0
    tip_sigma_px: float = 0.0
    axis_sigma_px: float = 0.0
    robot: Mapping[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    pose_rotation_deg: float = 0.0
    pose_translation_m: float = 0.0
    dropout_rate: float = 0.0
    min_points: int = 6


def perturb_pose(T: np.ndarray, rng: np.random.Generator, sigma_m, sigma_deg) -> np.ndarray:
    """``T · [Exp(ω) | v]``: ω ~ N(0, σ_rot²) (deg in, per axis), v ~ N(0, σ_t²) (m, per axis); always
    draws 6 numbers (rotation first)."""
    w = np.radians(np.asarray(sigma_deg, np.float64)) * rng.normal(size=3)
    v = np.asarray(sigma_m, np.float64) * rng.normal(size=3)
    return np.asarray(T, np.float64) @ make_pose(exp_so3(w), v)


def _robot_names(cell: CellSpec) -> list[str]:
    if cell.robots:
        return list(cell.robots)
    return [(cell.robot.name or "robot")] if cell.robot is not None else []


def _holder(cell: CellSpec, spec) -> str | None:
    """A robot name (on its flange), None (fixed in the cell's frame) or ``"free"`` (per station)."""
    mount = getattr(spec, "mount", "flange")
    if mount == "flange":
        return spec.robot or _robot_names(cell)[0]
    if mount == "free" and spec.name in cell.targets:
        return "free"
    return None


def _flange(cell: CellSpec, station: SimStation) -> dict[str, np.ndarray]:
    """The station's flange poses by robot name (``"robot"`` stands for the only robot)."""
    robots = _robot_names(cell)
    out = {r: np.asarray(T, np.float64) for r, T in station.flange.items()}
    if len(robots) == 1 and "robot" in out and robots[0] != "robot":
        out[robots[0]] = out.pop("robot")
    return out


def thing_poses(cell: CellSpec, truth: CellTruth, station: SimStation) -> dict[str, np.ndarray]:
    """The pose in the cell's frame of every camera, target and tool present at ``station``.

    A thing on a robot that has no flange pose at the station, or a free target the station does not
    place, is absent.
    """
    flange = _flange(cell, station)
    out: dict[str, np.ndarray] = {}
    specs = list(cell.cameras.values()) + list(cell.targets.values()) + list(cell.tools.values())
    for spec in specs:
        h = _holder(cell, spec)
        if h == "free":
            if spec.name in station.free:
                out[spec.name] = np.asarray(station.free[spec.name], np.float64)
            continue
        if spec.name not in truth.poses:
            raise BadInputError(f"truth: no pose for '{spec.name}' (its mount is {getattr(spec, 'mount', 'flange')})")
        mount = np.asarray(truth.poses[spec.name], np.float64)
        if h is None:
            out[spec.name] = mount
        elif h in flange:
            base = np.asarray(truth.bases.get(h, np.eye(4)), np.float64)
            out[spec.name] = base @ flange[h] @ mount
    return out


@eqx.filter_jit
def _project_valid(model, p_cam):
    return model.project_valid(p_cam)


def _project(model, p_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(n, 2)`` of camera-frame points and whether each is in front and inside the image."""
    u, valid = _project_valid(model, jnp.asarray(p_cam))
    u = np.asarray(u, np.float64)
    w, h = camera_image_size(model)
    ok = (np.asarray(valid, bool) & (p_cam[:, 2] > 1e-3) & np.all(np.isfinite(u), axis=1)
          & (u[:, 0] >= -0.5) & (u[:, 0] <= w - 0.5) & (u[:, 1] >= -0.5) & (u[:, 1] <= h - 0.5))
    return u, ok


def _check_stations(cell: CellSpec, stations: Sequence[SimStation]) -> None:
    robots = set(_robot_names(cell))
    one = next(iter(robots)) if len(robots) == 1 else None
    seen = set()
    for s in stations:
        if s.id in seen:
            raise BadInputError(f"stations: duplicate station id {s.id!r}")
        seen.add(s.id)
        for r in s.flange:
            if r not in robots and not (one is not None and r == "robot"):
                raise BadInputError(f"station {s.id!r}: flange pose of robot {r!r}, which the cell does not have "
                                    f"(robots: {', '.join(sorted(robots)) or 'none'})")
        for tool, point in s.contacts:
            if tool not in cell.tools or point not in cell.points:
                raise BadInputError(f"station {s.id!r}: contact ({tool!r}, {point!r}) names a tool or point the cell "
                                    "does not have")


def simulate_observations(
    cell,
    truth: CellTruth,
    stations: Sequence[SimStation],
    noise: ObservationNoise,
    rng: np.random.Generator,
) -> tuple[dict, list[str]]:
    """Noisy observations of ``cell`` at ``stations`` (see the module docstring).

    Args:
        cell: a ``jcalib.cell/1`` spec (dict, path or :class:`~jcalib.io.cell.CellSpec`).
        truth: the true cameras, mount poses, robot bases, cell points and target points.
        stations: what to simulate, in order.
        noise: measurement noise.
        rng: the generator every draw comes from (in station order, then cell order).

    Returns:
        ``(observations, kept)``: a ``jcalib.observations/1`` dict with the stations that observed
        something, and their ids. A one-robot station records ``T_base_flange``, a station of a cell with
        several robots ``flange_poses``.
    """
    cell = load_cell(cell)
    _check_stations(cell, stations)
    robots = _robot_names(cell)
    multi = len(cell.robots) > 1
    for c in cell.cameras:
        if c not in truth.cameras:
            raise BadInputError(f"truth: no camera model for camera '{c}'")
    for t in cell.targets:
        if t not in truth.target_points:
            raise BadInputError(f"truth: no points for target '{t}'")
    out_stations, kept = [], []
    for s in stations:
        where = thing_poses(cell, truth, s)
        flange = _flange(cell, s)
        dets, poses = [], []
        for cam in cell.cameras.values():
            model = truth.cameras[cam.name]
            W_c = where.get(cam.name)
            for tgt in cell.targets.values():
                P = np.asarray(truth.target_points[tgt.name], np.float64)
                if tgt.name in truth.target_warp:
                    P = warped_points(P, truth.target_warp[tgt.name])
                pix_noise = rng.normal(size=(len(P), 2))
                lost = rng.random() < noise.dropout_rate
                pose_noise = rng.normal(size=6)
                W_t = where.get(tgt.name)
                if W_c is None or W_t is None or lost:
                    continue
                T_ct = invert(W_c) @ W_t
                if (cam.name, tgt.name) in s.pose_pairs:
                    w = np.radians(noise.pose_rotation_deg) * pose_noise[:3]
                    T_meas = T_ct @ make_pose(exp_so3(w), noise.pose_translation_m * pose_noise[3:])
                    poses.append({"camera": cam.name, "target": tgt.name, "T_cam_target": T_meas.tolist()})
                    continue
                p_cam = P @ T_ct[:3, :3].T + T_ct[:3, 3]
                u, ok = _project(model, p_cam)
                if tgt.type != "points":  # a printed board is seen from its printed (-z) side only
                    ok &= float((invert(T_ct)[:3, 3])[2]) < 0.0
                idx = np.flatnonzero(ok)
                if idx.size < min(noise.min_points, len(P)):  # a single AprilTag has 4 points in all
                    continue
                px = u[idx] + noise.pixel_sigma_px * pix_noise[idx]
                dets.append({"camera": cam.name, "target": tgt.name, "point_index": idx.tolist(), "pixels": px.tolist()})
            for tool in cell.tools.values():
                if cam.name not in tool.observed_by:
                    continue
                tip_noise = rng.normal(size=2)
                axis_noise = rng.normal(size=(max(int(s.axis_points), 0), 2))
                lost = rng.random() < noise.dropout_rate
                W_k = where.get(tool.name)
                if W_c is None or W_k is None or lost:
                    continue
                T_ck = invert(W_c) @ W_k
                n_ax = int(s.axis_points)
                lengths = s.axis_length_m * np.arange(1, n_ax + 1) / max(n_ax, 1)
                pts = np.concatenate([np.zeros((1, 3)), np.stack([np.zeros(n_ax), np.zeros(n_ax), -lengths], 1)])
                u, ok = _project(model, pts @ T_ck[:3, :3].T + T_ck[:3, 3])
                if not ok[0]:
                    continue
                det = {"camera": cam.name, "tool": tool.name,
                       "pixel": (u[0] + noise.tip_sigma_px * tip_noise).tolist()}
                if n_ax and ok[1:].all():
                    det["axis"] = (u[1:] + noise.axis_sigma_px * axis_noise).tolist()
                dets.append(det)
        recorded = {}
        for r in robots:
            d = rng.normal(size=6)
            if r not in flange:
                continue
            sig_t, sig_r = noise.robot.get(r, (np.zeros(3), np.zeros(3)))
            w = np.radians(np.asarray(sig_r, np.float64)) * d[:3]
            v = np.asarray(sig_t, np.float64) * d[3:]
            recorded[r] = np.asarray(flange[r], np.float64) @ make_pose(exp_so3(w), v)
        contacts = [{"tool": t, "point": p} for t, p in s.contacts]
        if not (dets or poses or contacts):
            continue
        station: dict = {"id": s.id}
        if recorded:
            if multi:
                station["flange_poses"] = {r: T.tolist() for r, T in recorded.items()}
            else:
                station["T_base_flange"] = next(iter(recorded.values())).tolist()
        station["detections"] = dets
        if contacts:
            station["contacts"] = contacts
        if poses:
            station["poses"] = poses
        out_stations.append(station)
        kept.append(s.id)
    obs = {
        "schema": "jcalib.observations/1",
        "cameras": {c: {"image_size": [int(v) for v in camera_image_size(truth.cameras[c])]} for c in cell.cameras},
        "targets": {t: {"points": np.asarray(truth.target_points[t], np.float64).tolist()} for t in cell.targets},
        "stations": out_stations,
    }
    return obs, kept
