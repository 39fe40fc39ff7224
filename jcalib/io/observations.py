"""Observations (``observations.json``, schema ``jcalib.observations/1``): what the vision layer produces.

See docs/design.md. Metres; pixels in the OpenCV convention (centre of the top-left pixel is (0, 0)).
Loading validates shapes, finiteness and indices, and names the station and camera of any problem.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.atomic import write_json_atomic
from jcalib.io.schema.observations import validate_observations_document
from jcalib.io.schema.reading import read_document

SCHEMA = "jcalib.observations/1"


@dataclass(frozen=True)
class Detection:
    """What one camera saw at one station: target corners, or one tool-tip pixel.

    Attributes:
        camera: camera id.
        target: target id (None for a tool-tip detection).
        point_index: (n,) int, indices into the target's points.
        pixels: (n, 2) float64, pixels (OpenCV convention).
        tool: tool id for a tool-tip detection (then ``pixels`` is (1, 2), ``point_index`` empty).
        axis: tool-tip detections only: optional ``(L, 2)`` points on the imaged tool axis (pixels), e.g.
            along the axis direction the tip detector found; they determine the tool's orientation.
        orientation_ambiguous: target detections only: the board looks the same turned by 180° (or 90°)
            and nothing printed on it told which way round it was seen, so ``point_index`` is one of the
            labellings its symmetry allows (JSON key ``"orientation_ambiguous": true``, written only
            when set); the calibration resolves it from the robot motion or refuses by name.
    """

    camera: str
    pixels: np.ndarray
    target: str | None = None
    point_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    tool: str | None = None
    axis: np.ndarray | None = None
    orientation_ambiguous: bool = False

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"camera": self.camera}
        if self.tool is not None:
            out["tool"] = self.tool
            out["pixel"] = self.pixels.reshape(2).tolist()
            if self.axis is not None and len(self.axis):
                out["axis"] = self.axis.tolist()
        else:
            out["target"] = self.target
            out["point_index"] = self.point_index.astype(int).tolist()
            out["pixels"] = self.pixels.tolist()
            if self.orientation_ambiguous:
                out["orientation_ambiguous"] = True
        return out


@dataclass(frozen=True)
class Contact:
    """At this station the tip of ``tool`` touches the cell point ``point``."""

    tool: str
    point: str


@dataclass(frozen=True)
class PoseMeasurement:
    """A 6-DOF pose of ``target`` measured by a pose sensor or a camera of the cell: ``T_cam_target``
    (4, 4), m, the target's pose in the measuring frame (a laser tracker, a metrology or motion-capture
    system, a marker's pose from another tool).

    Attributes:
        camera: the measuring sensor's or camera's id.
        target: the target's id.
        T_cam_target: (4, 4) the target in the measuring frame, m.
        sensor_form: written as ``{"sensor", "target", "T_sensor_target"}`` (a pose sensor of the cell's
            ``sensors:``) rather than ``{"camera", "target", "T_cam_target"}``.
    """

    camera: str
    target: str
    T_cam_target: np.ndarray
    sensor_form: bool = False

    def to_dict(self) -> dict[str, Any]:
        if self.sensor_form:
            return {"sensor": self.camera, "target": self.target, "T_sensor_target": self.T_cam_target.tolist()}
        return {"camera": self.camera, "target": self.target, "T_cam_target": self.T_cam_target.tolist()}


@dataclass(frozen=True)
class PositionMeasurement:
    """The tip of ``tool`` (its TCP origin, e.g. a laser tracker's reflector) measured by the point sensor
    ``sensor``: ``p_sensor_tool`` (3,), m, in the sensor frame."""

    sensor: str
    tool: str
    p_sensor_tool: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        return {"sensor": self.sensor, "tool": self.tool, "p_sensor_tool": self.p_sensor_tool.tolist()}


@dataclass(frozen=True)
class Station:
    """One robot station (or one free view when there is no robot).

    Attributes:
        id: station id, unique in the file.
        T_base_flange: (4, 4) measured flange pose in the robot base, metres; None without a robot
            (and in cells with several robots, which use ``flange_poses``).
        detections: what the cameras saw.
        contacts: tool-tip contacts with cell points.
        poses: 6-DOF pose measurements (``"poses": [{"sensor", "target", "T_sensor_target"}]`` or
            ``[{"camera", "target", "T_cam_target"}]``).
        positions: 3-D tool-tip positions measured by point sensors (``"positions": [{"sensor", "tool",
            "p_sensor_tool"}]``).
        flange_poses: robot name -> (4, 4) measured flange pose of that robot in its own base
            (``T_<robot>_flange``), metres: the stations of a cell with named ``robots:``. Empty when
            the station gives ``T_base_flange``. Which robots a station must give is checked against
            the cell (:func:`jcalib.problems.calibrate_cell`).
        lens: camera -> lens setting -> value (e.g. ``{"cam0": {"Zoom": 350.0}}``): the settings of the
            cameras whose cell entry has ``lens:``, as the camera reported them back.
        joints_deg: the robot's joint values as its controller reports them (degrees; prismatic axes
            in mm): ``(n,)``, or robot name -> ``(n,)`` in a cell with named robots; None when not
            recorded. Used by kinematic calibration (and to compute a flange pose from a robot's
            kinematics where the station gives none).
    """

    id: str
    detections: tuple[Detection, ...] = ()
    T_base_flange: np.ndarray | None = None
    contacts: tuple[Contact, ...] = ()
    flange_poses: dict[str, np.ndarray] = field(default_factory=dict)
    poses: tuple[PoseMeasurement, ...] = ()
    joints_deg: np.ndarray | dict[str, np.ndarray] | None = None
    positions: tuple[PositionMeasurement, ...] = ()
    lens: dict[str, dict[str, float]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"id": self.id}
        if self.T_base_flange is not None:
            out["T_base_flange"] = self.T_base_flange.tolist()
        if self.flange_poses:
            out["flange_poses"] = {r: T.tolist() for r, T in self.flange_poses.items()}
        if isinstance(self.joints_deg, dict):
            out["joints_deg"] = {r: q.tolist() for r, q in self.joints_deg.items()}
        elif self.joints_deg is not None:
            out["joints_deg"] = self.joints_deg.tolist()
        out["detections"] = [d.to_dict() for d in self.detections]
        if self.contacts:
            out["contacts"] = [{"tool": c.tool, "point": c.point} for c in self.contacts]
        if self.poses:
            out["poses"] = [m.to_dict() for m in self.poses]
        if self.positions:
            out["positions"] = [m.to_dict() for m in self.positions]
        if self.lens:
            out["lens"] = {c: dict(v) for c, v in self.lens.items()}
        return out


@dataclass(frozen=True)
class Observations:
    """A parsed, validated observations file.

    Attributes:
        cameras: camera id -> image size ``(width, height)`` in pixels.
        targets: target id -> (N, 3) target points, metres, target frame.
        stations: the stations, in file order.
    """

    cameras: dict[str, tuple[int, int]]
    targets: dict[str, np.ndarray]
    stations: tuple[Station, ...]
    source: str = "<dict>"

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema": SCHEMA,
            "cameras": {c: {"image_size": list(s)} for c, s in self.cameras.items()},
            "targets": {t: {"points": p.tolist()} for t, p in self.targets.items()},
            "stations": [s.to_dict() for s in self.stations],
        }

    def num_detections(self) -> int:
        return sum(len(s.detections) for s in self.stations)


def _fail(where: str, msg: str) -> BadInputError:
    return BadInputError(f"{where}: {msg}")


def _array(value: Any, where: str, ndim: int, last: int | None = None, dtype=np.float64) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError):
        raise _fail(where, f"expected numbers, got {str(value)[:80]}") from None
    if arr.ndim != ndim or (last is not None and arr.shape[-1] != last):
        want = "(n,)" if ndim == 1 else f"(n, {last})" if ndim == 2 and last else f"{ndim}-d"
        raise _fail(where, f"expected shape {want}, got {arr.shape}")
    if dtype == np.float64 and not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0].tolist()
        raise _fail(where, f"contains NaN or infinity (first at index {bad}); remove or re-detect it")
    return arr


def _flange_pose(value: Any, where: str) -> np.ndarray:
    """A measured flange pose: 4x4, finite, proper rotation (m)."""
    T = _array(value, where, 2, 4)
    if T.shape != (4, 4):
        raise _fail(where, f"expected a 4x4 matrix, got {T.shape}")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise _fail(where, "the rotation part is not a proper rotation")
    return T


def _parse_detection(d: Any, where: str, obs_cameras: dict, obs_targets: dict,
                     pixels: np.ndarray | None = None) -> Detection:
    """One detection; ``pixels``: its pixel array when the schema check already made it."""
    if not isinstance(d, dict):
        raise _fail(where, "a detection must be a mapping")
    camera = d.get("camera")
    if camera not in obs_cameras:
        raise _fail(where, f"camera {camera!r} is not listed in 'cameras' ({', '.join(obs_cameras)})")
    if "tool" in d:
        raw = d.get("pixel", d.get("pixels"))
        try:
            pixel = np.asarray(raw, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            pixel = np.zeros(0)
        if pixel.shape != (2,) or not np.all(np.isfinite(pixel)):
            raise _fail(where + ".pixel", f"a tool-tip detection needs one finite pixel [u, v], got {raw!r}")
        axis = None
        if d.get("axis") is not None:
            axis = _array(d["axis"], where + ".axis", ndim=2, last=2)
        return Detection(camera=camera, tool=str(d["tool"]), pixels=pixel.reshape(1, 2), axis=axis)
    target = d.get("target")
    if target not in obs_targets:
        raise _fail(where, f"target {target!r} is not listed in 'targets' ({', '.join(obs_targets)})")
    if pixels is None:
        pixels = _array(d.get("pixels"), where + ".pixels", ndim=2, last=2)
    try:
        index = np.asarray(d.get("point_index"), dtype=np.int64)
    except (TypeError, ValueError):
        raise _fail(where + ".point_index", "expected a list of integers") from None
    if index.ndim != 1 or index.shape[0] != pixels.shape[0]:
        raise _fail(
            where,
            f"point_index has {index.size} entries but pixels has {pixels.shape[0]} rows; "
            "they must pair one to one",
        )
    n_points = obs_targets[target].shape[0]
    if index.size and (index.min() < 0 or index.max() >= n_points):
        raise _fail(
            where + ".point_index",
            f"index out of range (target '{target}' has {n_points} points, got "
            f"{int(index.min())}..{int(index.max())}); the detections do not match this target",
        )
    if index.size and np.count_nonzero(np.bincount(index, minlength=n_points)) != index.size:
        raise _fail(where + ".point_index", "a target point appears twice in one detection")
    return Detection(camera=camera, target=target, point_index=index, pixels=pixels,
                     orientation_ambiguous=bool(d.get("orientation_ambiguous", False)))


def parse_observations(data: Any, source: str = "<dict>") -> Observations:
    """Validate an observations document given as a dict.

    Raises:
        BadInputError: naming ``source``, the station id and the camera of the problem.
    """
    if not isinstance(data, dict):
        raise _fail(source, f"expected a mapping with 'schema: {SCHEMA}'")
    if data.get("schema") != SCHEMA:
        raise _fail(source, f"schema is {data.get('schema')!r}; expected '{SCHEMA}'")
    checked = validate_observations_document(data, source)  # types, keys, pixels in the image, units (io.schema)
    cameras: dict[str, tuple[int, int]] = {}
    for name, entry in (data.get("cameras") or {}).items():
        size = (entry or {}).get("image_size")
        if (
            not isinstance(size, (list, tuple))
            or len(size) != 2
            or not all(isinstance(v, int) and v > 0 for v in size)
        ):
            raise _fail(f"{source}: cameras.{name}.image_size", f"expected [width, height] > 0, got {size!r}")
        cameras[str(name)] = (int(size[0]), int(size[1]))
    targets: dict[str, np.ndarray] = {}
    for name, entry in (data.get("targets") or {}).items():
        targets[str(name)] = _array((entry or {}).get("points"), f"{source}: targets.{name}.points", 2, 3)
    stations = []
    seen: set[str] = set()
    for i, s in enumerate(data.get("stations") or []):
        if not isinstance(s, dict) or "id" not in s:
            raise _fail(f"{source}: stations[{i}]", "each station needs an 'id'")
        sid = str(s["id"])
        where = f"{source}: station '{sid}'"
        if sid in seen:
            raise _fail(where, "duplicate station id")
        seen.add(sid)
        T = None
        if s.get("T_base_flange") is not None:
            T = _flange_pose(s["T_base_flange"], where + ".T_base_flange")
        flange_poses = {}
        if s.get("flange_poses") is not None:
            if T is not None:
                raise _fail(where, "has both T_base_flange (one robot) and flange_poses (named robots); give one")
            fp = s["flange_poses"]
            if not isinstance(fp, dict) or not all(isinstance(r, str) and r for r in fp):
                raise _fail(where + ".flange_poses", "expected a mapping of robot names to 4x4 flange poses "
                                                     f"(T_<robot>_flange, m), got {str(fp)[:80]}")
            flange_poses = {r: _flange_pose(v, f"{where}.flange_poses.{r}") for r, v in fp.items()}
        dets = tuple(
            _parse_detection(d, f"{where}.detections[{j}]", cameras, targets, checked.get(id(d)))
            for j, d in enumerate(s.get("detections") or [])
        )
        contacts = tuple(
            Contact(tool=str(c["tool"]), point=str(c["point"])) for c in (s.get("contacts") or [])
        )
        poses = []
        for j, m in enumerate(s.get("poses") or []):
            w = f"{where}.poses[{j}]"
            sensor = isinstance(m, dict) and {"sensor", "target", "T_sensor_target"} <= set(m)
            if not sensor and (not isinstance(m, dict) or not {"camera", "target", "T_cam_target"} <= set(m)):
                raise _fail(w, "a pose measurement is {sensor: <id>, target: <id>, T_sensor_target: [[4x4]]} or "
                               "{camera: <id>, target: <id>, T_cam_target: [[4x4]]} (m)")
            by, key = ("sensor", "T_sensor_target") if sensor else ("camera", "T_cam_target")
            poses.append(PoseMeasurement(str(m[by]), str(m["target"]), _flange_pose(m[key], f"{w}.{key}"),
                                         sensor_form=sensor))
        positions = tuple(
            PositionMeasurement(str(m["sensor"]), str(m["tool"]),
                                _array(m["p_sensor_tool"], f"{where}.positions[{j}].p_sensor_tool", 1).reshape(3))
            for j, m in enumerate(s.get("positions") or []))  # (keys and shapes checked by the schema)
        joints = s.get("joints_deg")
        if isinstance(joints, dict):
            joints = {str(r): _array(q, f"{where}.joints_deg.{r}", 1) for r, q in joints.items()}
        elif joints is not None:
            joints = _array(joints, where + ".joints_deg", 1)
        lens = {}
        for cam, values in (s.get("lens") or {}).items():
            if not isinstance(values, dict) or not all(
                    isinstance(k, str) and isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
                    for k, v in values.items()):
                raise _fail(f"{where}.lens.{cam}", "expected lens setting names mapped to finite numbers, e.g. "
                                                   f"{{Zoom: 350}}, got {str(values)[:80]}")
            lens[str(cam)] = {str(k): float(v) for k, v in values.items()}
        stations.append(Station(id=sid, detections=dets, T_base_flange=T, contacts=contacts,
                                flange_poses=flange_poses, poses=tuple(poses), joints_deg=joints,
                                positions=positions, lens=lens))
    return Observations(cameras=cameras, targets=targets, stations=tuple(stations), source=source)


def load_observations(obs: str | os.PathLike | dict | Observations) -> Observations:
    """Load and validate observations from a JSON file, a dict, or pass an Observations through."""
    if isinstance(obs, Observations):
        return obs
    if isinstance(obs, dict):
        return parse_observations(obs)
    path = Path(obs)
    data = read_document(path, "observations file", fmt="json")  # size, UTF-8, depth limits
    return parse_observations(data, source=str(path))


def save_observations(path: str | os.PathLike, obs: Observations) -> Path:
    """Write observations as JSON, atomically."""
    return write_json_atomic(path, obs.to_dict())
