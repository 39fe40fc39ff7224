"""Schema of observations (``jcalib.observations/1``, docs/design.md), including the extensions in force.

:func:`validate_observations_document` runs before :func:`jcalib.io.observations.parse_observations`
builds the data classes: types and shapes (a fractional ``point_index`` is refused, never
truncated), finite numbers, known keys, then plausibility: pixels inside their camera's
``image_size``, flange poses rigid and
within a robot's reach (millimetres written as metres are caught), target points within a cell.
An ``image_size`` smaller than the pixels it holds is refused (more than 5 % of a camera's pixels
outside its image, or any pixel farther than an image size beyond it: ``1e300``, another camera's
pixel); a few pixels just outside give an :class:`~jcalib.errors.InputWarning` naming the first.

Extensions accepted here (their meaning is the calibration code's): stations ``joints_deg`` (a list,
or a mapping robot -> list, as sessions record them) and ``poses: [{sensor, target, T_sensor_target}]``
(6-DOF pose measurements by a pose sensor of the cell, m; the camera form ``{camera, target, T_cam_target}``
stays valid), ``positions: [{sensor, tool, p_sensor_tool}]`` (3-D tool-tip positions by a point sensor, m); target detections ``orientation_ambiguous: true`` (the labelling is one of
those the board's symmetry allows).
"""

from __future__ import annotations

import itertools

import warnings
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BeforeValidator, Field, model_validator
from pydantic_core import PydanticCustomError

from jcalib.errors import InputWarning

from jcalib.io.schema.base import Closed, Int, Name, Num, SchemaError, StationId, did_you_mean, format_value, validate
from jcalib.io.schema.common import MAX_CELL_EXTENT_M, MAX_IMAGE_SIDE_PX, Mat4, Vec3, max_reach_m, norm, pose_problem

__all__ = ["ObservationsDocument", "pixels_outside", "station_label", "validate_observations_document",
           "warn_pixels_outside"]

SCHEMA = "jcalib.observations/1"
#: A pixel may lie this far (px) outside the image area [-0.5, size - 0.5] (sub-pixel refinement).
PIXEL_MARGIN_PX = 0.5
#: More than this fraction of a camera's pixels outside its image: the image_size is wrong (refused);
#: fewer give a warning (synthetic data with a few corners off the image).
MAX_OUTSIDE_FRACTION = 0.05

Pixel = Annotated[list[Num], Field(min_length=2, max_length=2)]
ImageSide = Annotated[Int, Field(ge=1, le=MAX_IMAGE_SIDE_PX)]


def _joints(value: Any) -> Any:
    def is_list(v: Any) -> bool:
        return isinstance(v, list) and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in v)

    if is_list(value) or (isinstance(value, dict) and all(isinstance(k, str) and is_list(v) for k, v in value.items())):
        return value
    raise PydanticCustomError("jcalib_check", "{why}", {
        "why": "expected joint values in degrees (mm for prismatic axes): a list of finite numbers, or a mapping "
               f"robot -> list; got {format_value(value)}"})


_POSE = "4x4 homogeneous transform, translation in m"


class CameraEntry(Closed):
    """A camera of the observations."""

    image_size: Annotated[list[ImageSide], Field(min_length=2, max_length=2)] = Field(
        description="[width, height] of the camera's images, px")


class TargetEntry(Closed):
    """A target's points as detected (the target frame)."""

    points: Annotated[list[Vec3], Field(min_length=1)] = Field(
        description="target points [x, y, z], m, in the target frame; point_index counts into this list")


class Detection(Closed):
    """What one camera saw at one station: target points (target, point_index, pixels) or a tool tip (tool, pixel)."""

    camera: Name = Field(description="the camera")
    target: Name | None = Field(None, description="the target seen (a target detection)")
    tool: Name | None = Field(None, description="the tool whose tip is seen (a tool-tip detection)")
    point_index: list[Int] | None = Field(None, description="indices into the target's points, one per pixel")
    pixels: list[Pixel] | None = Field(None, description="[u, v] of each detected point, px (OpenCV convention)")
    pixel: Pixel | None = Field(None, description="[u, v] of the tool tip, px (a tool-tip detection)")
    axis: Annotated[list[Pixel], Field(min_length=1)] | None = Field(
        None, description="pixels on the imaged tool axis (a tool-tip detection)")
    orientation_ambiguous: bool = Field(False, description="the labelling is one of those the board's symmetry "
                                                           "allows")

    @model_validator(mode="after")
    def _kind(self) -> "Detection":
        if self.tool is not None:
            for key in ("target", "point_index", "orientation_ambiguous"):
                if key in self.model_fields_set:
                    raise PydanticCustomError("jcalib_check", "{why}", {
                        "key": key, "why": "a tool-tip detection has 'tool' and one 'pixel', no target or point_index"})
            pixels = [self.pixel] if self.pixel is not None else self.pixels
            if pixels is None or len(pixels) != 1 or (self.pixel is not None and self.pixels is not None):
                raise PydanticCustomError("jcalib_check", "{why}", {
                    "key": "pixel", "why": "a tool-tip detection needs exactly one pixel [u, v]"})
            return self
        if self.target is None:
            raise PydanticCustomError("jcalib_check", "{why}", {
                "key": "target", "why": "missing: a detection names a 'target' (with point_index and pixels) "
                                        "or a 'tool' (with one pixel)"})
        for key in ("point_index", "pixels"):
            if key not in self.model_fields_set or getattr(self, key) is None:
                raise PydanticCustomError("jcalib_check", "{why}", {"key": key, "why": "missing (required)" if key not in
                                          self.model_fields_set else "expected a list, got null"})
        if "pixel" in self.model_fields_set:
            raise PydanticCustomError("jcalib_check", "{why}", {
                "key": "pixel", "why": "a target detection has 'pixels' (one per point_index), not 'pixel'"})
        if "axis" in self.model_fields_set:
            raise PydanticCustomError("jcalib_check", "{why}", {
                "key": "axis", "why": "only a tool-tip detection has 'axis' (points on the imaged tool axis)"})
        return self


class Contact(Closed):
    """The tool tip touches a cell point at this station."""

    tool: Name = Field(description="the tool")
    point: Name = Field(description="the cell point it touches")


class PoseMeasurement(Closed):
    """A 6-DOF pose of a target measured by a pose sensor (``sensor``, ``T_sensor_target``) or by a camera
    (``camera``, ``T_cam_target``)."""

    sensor: Name | None = Field(None, description="the pose sensor (cell sensors); or camera")
    camera: Name | None = Field(None, description="the camera; or sensor")
    target: Name = Field(description="the target")
    T_sensor_target: Mat4 | None = Field(None, description=f"the target's pose in the sensor frame ({_POSE})")
    T_cam_target: Mat4 | None = Field(None, description=f"the target's pose in the camera frame ({_POSE})")

    @model_validator(mode="after")
    def _form(self) -> "PoseMeasurement":
        sensor_form = self.sensor is not None or self.T_sensor_target is not None
        camera_form = self.camera is not None or self.T_cam_target is not None
        if sensor_form == camera_form:
            raise PydanticCustomError("jcalib_check", "{why}", {
                "why": "a pose measurement is {sensor, target, T_sensor_target} (a pose sensor) or {camera, target, "
                       "T_cam_target} (a camera), one of the two forms"})
        for key in (("sensor", "T_sensor_target") if sensor_form else ("camera", "T_cam_target")):
            if getattr(self, key) is None:
                raise PydanticCustomError("jcalib_check", "{why}", {"key": key, "why": "missing (required)"})
        return self


class PositionMeasurement(Closed):
    """A 3-D position of a tool's tip (its TCP origin, e.g. a laser tracker's reflector) measured by a point sensor."""

    sensor: Name = Field(description="the point sensor (cell sensors of kind point)")
    tool: Name = Field(description="the tool whose tip is measured")
    p_sensor_tool: Vec3 = Field(description="the tip's position [x, y, z] in the sensor frame, m")


#: Joint values as sessions record them, for the published schema (the validator checks finiteness).
JointValues = list[float] | dict[str, list[float]] | None


class Station(Closed):
    """One robot station (or one view without a robot) and what was measured there."""

    id: StationId = Field(description="station id (unique in the file)")
    T_base_flange: Mat4 | None = Field(None, description=f"the robot's flange pose in its base frame ({_POSE}); "
                                                         "present when a robot is in the cell")
    flange_poses: dict[Name, Mat4] | None = Field(None, description="flange pose of each robot by name (cells with "
                                                                    "several robots)")
    joints_deg: Annotated[Any, BeforeValidator(_joints, json_schema_input_type=JointValues)] = Field(
        None, description="joint values, degrees (prismatic axes mm): a list, or robot -> list")
    detections: list[Detection] | None = Field(None, description="what the cameras detected")
    contacts: list[Contact] | None = Field(None, description="tool-tip contacts with cell points")
    poses: list[PoseMeasurement] | None = Field(None, description="6-DOF pose measurements")
    positions: list[PositionMeasurement] | None = Field(None, description="3-D tool-tip positions measured by "
                                                                          "point sensors")
    lens: dict[Name, dict[Name, Num]] | None = Field(
        None, description="lens settings each camera had (cameras with lens: in the cell), e.g. {cam0: {Zoom: 350}}")


class ObservationsDocument(Closed):
    """What the vision layer produces and the calibration consumes (observations.json); metres, pixels in
    OpenCV convention."""

    schema_: Literal["jcalib.observations/1"] = Field(alias="schema",
                                                      description="format and version: jcalib.observations/1")
    cameras: dict[Name, CameraEntry] | None = Field(None, description="cameras by name, with their image size")
    targets: dict[Name, TargetEntry] | None = Field(None, description="targets by name, with their points")
    stations: list[Station] | None = Field(None, description="the stations, in capture order")


def station_label(data: Any, path: str) -> str:
    """``path`` with a leading ``stations[i]`` shown as ``station 'id'`` (ids are what users know)."""
    if not path.startswith("stations["):
        return path
    end = path.index("]")
    try:
        i = int(path[len("stations["):end])
        sid = data["stations"][i]["id"]
    except (ValueError, KeyError, IndexError, TypeError):
        return path
    if not isinstance(sid, (str, int)) or isinstance(sid, bool):
        return path
    return f"station {str(sid)!r}" + path[end + 1:]


def pixels_outside(pixels: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Which pixels lie outside the image ``size = (width, height)`` (OpenCV convention: the image
    covers [-0.5, width - 0.5] x [-0.5, height - 0.5], plus :data:`PIXEL_MARGIN_PX`), and which lie
    farther than one image size beyond it (no detection of this image: another camera, image scale
    or unit).

    Returns:
        ``(outside, far)``: boolean masks, shape ``(n,)``.
    """
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    w, h = float(size[0]), float(size[1])
    lo = -0.5 - PIXEL_MARGIN_PX
    outside = (px[:, 0] < lo) | (px[:, 1] < lo) | (px[:, 0] > w - 0.5 + PIXEL_MARGIN_PX) | (
        px[:, 1] > h - 0.5 + PIXEL_MARGIN_PX)
    far = (px[:, 0] < -w) | (px[:, 1] < -h) | (px[:, 0] > 2 * w) | (px[:, 1] > 2 * h)
    return outside, far


def warn_pixels_outside(source: str, outside: dict[str, list]) -> None:
    """One :class:`~jcalib.errors.InputWarning` per camera with pixels outside its image:
    ``outside`` maps camera -> ``[count, size, first key path, first pixel]``."""
    for cam, (count, size, where, px) in outside.items():
        warnings.warn(
            f"{source}: {count} pixel(s) of camera {cam!r} lie outside its {size[0]}x{size[1]} image (first: "
            f"{where} = {np.round(px, 2).tolist()}); a detection cannot lie outside the image it was found in: "
            "is the image_size right?", InputWarning, stacklevel=4)


def _check_station(i: int, st: dict, sizes: dict, targets: dict, reach: float, problems: list,
                   outside: dict, checked: dict[int, np.ndarray]) -> None:
    where = f"stations[{i}]"
    poses = {"T_base_flange": st["T_base_flange"]} if st.get("T_base_flange") is not None else {}
    poses.update({f"flange_poses.{r}": T for r, T in (st.get("flange_poses") or {}).items()})
    for key, T in poses.items():
        why = pose_problem(T, reach, "flange translation")
        if why:
            problems.append((f"{where}.{key}", why + ("" if "millimetres" not in why else
                             "; a robot on a track or a gantry: set JCALIB_MAX_REACH_M")))
    for j, pm in enumerate(st.get("poses") or []):
        key = "T_sensor_target" if "T_sensor_target" in pm else "T_cam_target"
        why = pose_problem(pm[key], MAX_CELL_EXTENT_M, "target position")
        if why:
            problems.append((f"{where}.poses[{j}].{key}", why))
    for j, pm in enumerate(st.get("positions") or []):
        if float(norm(pm["p_sensor_tool"])) > MAX_CELL_EXTENT_M:
            problems.append((f"{where}.positions[{j}].p_sensor_tool", f"{float(norm(pm['p_sensor_tool'])):.4g} m from "
                             f"the sensor, more than {MAX_CELL_EXTENT_M:g} m: positions are in metres; are these "
                             "millimetres? (divide by 1000)"))
    for j, det in enumerate(st.get("detections") or []):
        at = f"{where}.detections[{j}]"
        cam = det["camera"]
        if cam not in sizes:
            problems.append((f"{at}.camera", f"camera {cam!r} is not listed in 'cameras'{did_you_mean(cam, sizes)} "
                                             f"(listed: {', '.join(sizes) or 'none'}); add it with its image_size"))
            continue
        if det.get("tool") is not None:
            px = np.asarray([det["pixel"]] if det.get("pixel") is not None else det["pixels"], dtype=np.float64)
            key = "pixel"
        else:
            tgt = det["target"]
            if tgt not in targets:
                problems.append((f"{at}.target", f"target {tgt!r} is not listed in 'targets'"
                                                 f"{did_you_mean(tgt, targets)} (listed: {', '.join(targets) or 'none'})"))
                continue
            px = checked.get(id(det))
            if px is None:
                px = np.asarray(det["pixels"], dtype=np.float64).reshape(-1, 2)
            index, key = det["point_index"], "pixels"
            if len(index) != len(px):
                problems.append((at, f"point_index has {len(index)} entries but pixels has {len(px)} rows; they pair "
                                     "one to one"))
                continue
            n = targets[tgt]
            bad = [] if not index or 0 <= min(index) and max(index) < n else [
                k for k, v in enumerate(index) if not 0 <= v < n]
            if bad:
                problems.append((f"{at}.point_index[{bad[0]}]", f"index {index[bad[0]]} is out of range: target {tgt!r} "
                                                                f"has {n} points (0..{n - 1})"))
                continue
            if len(set(index)) != len(index):
                problems.append((f"{at}.point_index", "a target point appears twice in one detection"))
                continue
        out, far = pixels_outside(px, sizes[cam])
        if far.any():
            k = int(np.flatnonzero(far)[0])
            w, h = sizes[cam]
            problems.append((f"{at}.{key}" + ("" if key == "pixel" else f"[{k}]"),
                             f"pixel {px[k].tolist()} lies far outside camera {cam!r}'s image of {w}x{h} px: the "
                             "image_size is wrong, or the pixel belongs to another camera, image scale or unit"))
        else:
            entry = outside.setdefault(cam, [0, sizes[cam], None, None, 0])
            entry[4] += len(px)
            if out.any():
                k = int(np.flatnonzero(out)[0])
                entry[0] += int(out.sum())
                if entry[2] is None:
                    entry[2], entry[3] = f"{at}.{key}" + ("" if key == "pixel" else f"[{k}]"), px[k]


def _numbers_checked(det: Any) -> np.ndarray | None:
    """A target detection's ``pixels`` as an ``(N, 2)`` array when they and ``point_index`` pass what the
    schema asks of them (lists of ``[u, v]`` finite numbers, not bools; a list of ints), else None.
    Checked without pydantic, whose per-number validation was a quarter of a 400-view calibration's host
    time."""
    if not isinstance(det, dict) or "tool" in det:
        return None
    px, idx = det.get("pixels"), det.get("point_index")
    if type(px) is not list or not px or type(idx) is not list or not set(map(type, idx)) <= {int}:
        return None  # (an empty list takes the long way, to the parser's message)
    # exact types (bool is not int here, numpy scalars go the long way), C-speed iteration
    if not set(map(type, px)) <= {list} or not set(map(len, px)) <= {2}:
        return None
    if not set(map(type, itertools.chain.from_iterable(px))) <= {float, int}:
        return None
    try:
        arr = np.array(px, dtype=np.float64).reshape(-1, 2)
    except OverflowError:  # an int beyond float range: the schema says what is wrong
        return None
    return arr if np.all(np.isfinite(arr)) else None


def _skeleton(data: Any) -> tuple[Any, dict[int, np.ndarray]]:
    """``data`` with the number lists of target detections that :func:`_numbers_checked` accepts emptied
    (shallow copies: the document is not changed), for pydantic to check the rest; and those detections'
    pixel arrays by ``id`` of the detection mapping."""
    checked: dict[int, np.ndarray] = {}
    stations = data.get("stations") if isinstance(data, dict) else None
    if type(stations) is not list:
        return data, checked
    out = []
    for st in stations:
        dets = st.get("detections") if isinstance(st, dict) else None
        arrays = [_numbers_checked(d) for d in dets] if type(dets) is list else []
        if any(a is not None for a in arrays):
            checked.update((id(d), a) for d, a in zip(dets, arrays) if a is not None)
            st = {**st, "detections": [d if a is None else {**d, "pixels": [], "point_index": []}
                                        for d, a in zip(dets, arrays)]}
        out.append(st)
    return {**data, "stations": out}, checked


def validate_observations_document(data: Any, source: str = "<dict>") -> dict[int, np.ndarray]:
    """Check an observations document (a loaded JSON mapping) against the schema and for plausibility.

    Returns the ``(N, 2)`` pixel arrays it made of target detections, by ``id`` of the detection mapping
    (valid while ``data`` is unchanged), so that the parser does not convert them again.

    Raises:
        SchemaError: naming ``source``, the station id and key path, and what to do.
    """
    if isinstance(data, dict) and isinstance(data.get("schema"), str) and data["schema"] != SCHEMA:
        other = data["schema"]
        hint = "" if not other.startswith("jcalib.") or other.startswith("jcalib.observations/") else (
            f"; this looks like a {other} file, not observations")
        raise SchemaError(source, [("schema", f"expected {SCHEMA!r}, got {other!r}{hint}")])
    try:
        skeleton, checked = _skeleton(data)
        validate(ObservationsDocument, skeleton, source)
        problems: list[tuple[str, str]] = []
        sizes = {c: tuple(e["image_size"]) for c, e in (data.get("cameras") or {}).items()}
        targets = {t: len(e["points"]) for t, e in (data.get("targets") or {}).items()}
        for t, e in (data.get("targets") or {}).items():
            extent = float(np.max(norm(e["points"], axis=1)))
            if extent > MAX_CELL_EXTENT_M:
                problems.append((f"targets.{t}.points", f"a point lies {extent:.4g} m from the target's origin, more than "
                                                        f"{MAX_CELL_EXTENT_M:g} m: points are in metres; are these "
                                                        "millimetres? (divide by 1000)"))
        reach = max_reach_m()
        outside: dict[str, list] = {}
        seen: dict[str, int] = {}
        for i, st in enumerate(data.get("stations") or []):
            sid = str(st["id"])
            if sid in seen:
                problems.append((f"stations[{i}].id", f"duplicate station id {sid!r} (also stations[{seen[sid]}])"))
            seen.setdefault(sid, i)
            _check_station(i, st, sizes, targets, reach, problems, outside, checked)
            if len(problems) >= 20:
                break
        for cam, (n, size, where, px, total) in outside.items():
            if n > MAX_OUTSIDE_FRACTION * total:
                problems.append((where, f"{n} of the {total} pixels of camera {cam!r} lie outside its image of "
                                        f"{size[0]}x{size[1]} px (first: {np.round(px, 2).tolist()}): its image_size is "
                                        "wrong (too small), or the pixels belong to another camera or image scale"))
        if problems:
            raise SchemaError(source, problems)
    except SchemaError as e:
        raise SchemaError(source, [(station_label(data, p), m) for p, m in e.problems],
                          total=e.total) from None
    warn_pixels_outside(source, {c: [n, size, station_label(data, w), px]
                                 for c, (n, size, w, px, total) in outside.items() if n})
    return checked
