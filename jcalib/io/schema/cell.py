"""Schema of the cell spec (``jcalib.cell/1``, docs/design.md), including the extensions in force.

:func:`validate_cell_document` runs before :func:`jcalib.io.cell.parse_cell` builds the data
classes: types, shapes, ranges and known keys (with "did you mean"), then the checks that need the
whole document: ``dist`` length against the model (never padded), ``fix`` and ``fixed`` names that
match nothing, ``observed_by`` cameras, unique names, and units (poses beyond the cell, squares of
metres: millimetres written as metres).

Extensions accepted here (their meaning is the calibration code's): targets ``type: points`` (points
come with the observations; no grid fields), ``type: aprilgrid`` / ``type: apriltag``
(:mod:`jcalib.geometry.apriltags`; a ``file:`` entry is expanded before this check,
:mod:`jcalib.io.target_files`) and ``warp: true``; tools ``orientation: [[3x3]]`` or
``axis: [x, y, z]``; cameras ``settings: {GenICamName: number | text | bool}``; robots
``kinematics:`` (a preset name or a table mapping) and ``calibrate_kinematics: [names]``; ``sensors:``
(6-DOF pose sensors with no lens: laser trackers, metrology and motion-capture systems).
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BeforeValidator, Field, StringConstraints, model_validator
from pydantic_core import PydanticCustomError

from jcalib.io.schema.base import (
    Closed, Int, Name, NumericText, SchemaError, YNum, did_you_mean, format_value, validate,
)
from jcalib.io.schema.common import (
    MAX_CELL_EXTENT_M,
    MAX_TARGET_PITCH_M,
    YMat3,
    YMat4,
    YVec3,
    norm,
    pose_problem,
    rotation_problem,
)
from jcalib.io.schema.lens import LENS_DIST_NAMES, dist_problem

__all__ = ["CAMERA_MODELS", "DIST_NAMES", "CellDocument", "fixable_names", "validate_cell_document"]

SCHEMA = "jcalib.cell/1"
CAMERA_MODELS = ("pinhole", "opencv4", "opencv5", "opencv8", "opencv12", "opencv14", "fisheye", "splined")
#: Distortion names of each model, in OpenCV's order (``len`` = the length ``dist`` must have).
DIST_NAMES = LENS_DIST_NAMES
Mount = Literal["flange", "base", "world", "free"]
#: Grid fields of each target type (required, optional).
TARGET_FIELDS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "checkerboard": (("cols", "rows", "square"), ()),
    "charuco": (("squares_x", "squares_y", "square", "marker"), ("dictionary", "legacy")),
    "circles": (("cols", "rows", "spacing"), ("asymmetric", "diameter", "origin_dot")),
    "aprilgrid": (("cols", "rows", "tag_size", "tag_spacing"), ("family",)),
    "apriltag": (("id", "size"), ("family", "border_bits")),
    "points": ((), ()),
}
_GRID_FIELDS = sorted({f for req, opt in TARGET_FIELDS.values() for f in req + opt})
_MAX_GRID = 1000
_MAX_GRID_POINTS = 100_000
_GENICAM = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,127}")


def _custom(why: str, key: str | None = None) -> PydanticCustomError:
    ctx = {"why": why} if key is None else {"why": why, "key": key}
    return PydanticCustomError("jcalib_check", "{why}", ctx)


def _setting(value: Any) -> Any:
    if isinstance(value, bool):
        return value
    if isinstance(value, (int, float)):
        if not np.isfinite(value):
            raise _custom(f"expected a finite number, got {value!r}")
        return value
    if isinstance(value, str):
        if len(value) > 256 or any(ord(c) < 32 or ord(c) == 127 for c in value):
            raise _custom(f"expected a GenICam value (at most 256 printable characters), got {format_value(value)}")
        return value
    raise _custom(f"expected a GenICam value (a number, text or true/false), got {format_value(value)}")


def _genicam_name(value: Any) -> Any:
    if not isinstance(value, str) or not _GENICAM.fullmatch(value):
        raise _custom(f"expected a GenICam feature name such as ExposureTime (a letter, then letters, digits, '_'), "
                      f"got {format_value(value)}")
    return value


def _positive_or_vec3(value: Any) -> Any:
    from jcalib.io.schema.base import yaml_number  # same text-number rule as YNum

    vals = value if isinstance(value, list) else [value]
    vals = [yaml_number(v) for v in vals]
    ok = (len(vals) in (1, 3) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals)
          and all(np.isfinite(v) and v > 0 for v in vals))
    if not ok:
        raise _custom(f"expected a positive number or 3 positive numbers (x, y, z), got {format_value(value)}")
    return vals if isinstance(value, list) else vals[0]


def _kinematics(value: Any) -> Any:
    if isinstance(value, str) and value:
        return value
    if isinstance(value, dict) and all(isinstance(k, str) for k in value):
        return value
    raise _custom(f"expected a kinematics preset name or a table (mapping: DH / MDH / POE parameters), "
                  f"got {format_value(value)}")


#: What the published JSON Schema says of a kinematics table or a GenICam value (the validators check more).
_KinematicsInput = Annotated[str, StringConstraints(min_length=1)] | dict[str, Any]
_PositiveInput = Annotated[float, Field(gt=0)] | NumericText
Setting = Annotated[Any, BeforeValidator(_setting, json_schema_input_type=float | Annotated[str, StringConstraints(
    max_length=256)] | bool)]
GenICamName = Annotated[str, BeforeValidator(_genicam_name, json_schema_input_type=Annotated[
    str, StringConstraints(pattern="^" + _GENICAM.pattern + "$")])]
PositiveOrVec3 = Annotated[Any, BeforeValidator(_positive_or_vec3, json_schema_input_type=_PositiveInput | Annotated[
    list[_PositiveInput], Field(min_length=3, max_length=3)])]
Kinematics = Annotated[Any, BeforeValidator(_kinematics, json_schema_input_type=_KinematicsInput)]
Positive = Annotated[YNum, Field(gt=0)]
GridCount = Annotated[Int, Field(ge=1, le=_MAX_GRID)]
_POSE = "a 4x4 homogeneous transform, rows of [R | t], translation in m"


def _d(text: str, default: Any = ...) -> Any:
    """A field's description (and default) for the published schema."""
    return Field(default, description=text)


class Intrinsics(Closed):
    """Initial (or, with ``fix``, held) intrinsics in OpenCV form, as in the result file."""

    K: YMat3 = _d("camera matrix [[fx, skew, cx], [0, fy, cy], [0, 0, 1]], px")
    dist: list[YNum] | None = _d("distortion coefficients in OpenCV's order, as many as the model has (never padded)",
                                 None)


class Lens(Closed):
    """A zoom (focus) lens: the intrinsics and the camera frame's shift along its optical axis are smooth
    functions of a lens setting, estimated jointly from stations taken at several settings."""

    settings: list[GenICamName] = _d("the GenICam feature the lens depends on, e.g. [Zoom] (one so far); every "
                                     "station records its value under lens.<camera>")
    degree: Int | None = _d("degree of each function's B-spline in the normalised setting (1-5)", 3)
    knots: Int | None = _d("uniform interior knots of the B-splines (0-8; 0: one polynomial piece)", 0)


class Camera(Closed):
    """A camera: its lens model, where it is mounted, what of it is known."""

    model: Literal["pinhole", "opencv4", "opencv5", "opencv8", "opencv12", "opencv14", "fisheye", "splined"] = _d(
        "lens model; dist has its coefficients in OpenCV's order")
    mount: Mount = _d("flange: moves with the robot (unknown T_flange_<camera>); base / world: fixed (unknown "
                      "T_base_<camera>); free: one unknown pose per view (no robot)", "free")
    skew: bool = _d("estimate a skew (alpha for fisheye) intrinsic", False)
    fix: list[str] | None = _d("intrinsic names held at their value in intrinsics (e.g. [p1, p2]), or aspect (fx/fy "
                               "held)", None)
    intrinsics: Intrinsics | None = _d("initial values of the intrinsics (held where named in fix)", None)
    pose: YMat4 | None = _d(f"known pose of a fixed camera ({_POSE}); list the camera in fixed to hold it", None)
    robot: Name | None = _d("the robot whose flange carries the camera (cells with several robots)", None)
    settings: dict[GenICamName, Setting] | None = _d("GenICam features applied at capture, e.g. {ExposureTime: 5000}",
                                                      None)
    lens: Lens | None = _d("a zoom (focus) lens: intrinsics and axial position as functions of a setting", None)


class Target(Closed):
    """A calibration target; the grid fields it takes depend on its type (see the reference)."""

    type: Literal["checkerboard", "charuco", "circles", "aprilgrid", "apriltag", "points"] = _d(
        "kind of target; points: its points come with the observations (observations.targets.<id>.points)")
    mount: Mount = _d("flange / base / world / free, as for cameras (unknown T_base_<target>, ...)", "free")
    pose: YMat4 | None = _d(f"known pose of a fixed target ({_POSE}); list it in fixed to hold it", None)
    robot: Name | None = _d("the robot whose flange carries the target (cells with several robots)", None)
    warp: bool = _d("estimate the board's non-flatness", False)
    cols: GridCount | None = _d("inner corners (checkerboard), circles (circles) or tags (aprilgrid) along x", None)
    rows: GridCount | None = _d("inner corners, circles or tags along y", None)
    square: Positive | None = _d("square side, m (checkerboard, charuco)", None)
    squares_x: GridCount | None = _d("squares along x (charuco)", None)
    squares_y: GridCount | None = _d("squares along y (charuco)", None)
    marker: Positive | None = _d("ArUco marker side, m (charuco; smaller than square)", None)
    dictionary: str | None = _d("ArUco dictionary name, e.g. DICT_5X5_100 (charuco)", None)
    legacy: bool | None = _d("OpenCV's legacy ChArUco layout (charuco)", None)
    spacing: Positive | None = _d("distance between neighbouring circle centres, m (circles; asymmetric: between "
                                   "rows)", None)
    asymmetric: bool | None = _d("an asymmetric circle grid (circles)", None)
    diameter: Positive | None = _d("circle diameter, m (circles)", None)
    origin_dot: Literal["top_left", "top_right", "bottom_left", "bottom_right"] | None = _d(
        "the corner whose circle is printed larger (a modified symmetric circle grid)", None)
    family: Literal["tag16h5", "tag25h9", "tag36h11"] | None = _d("AprilTag family (aprilgrid, apriltag)", None)
    tag_size: Positive | None = _d("outer black square of a tag, m (aprilgrid)", None)
    tag_spacing: Annotated[YNum, Field(gt=0, le=1)] | None = _d("gap between tags / tag_size (aprilgrid, as Kalibr)",
                                                                None)
    id: Annotated[Int, Field(ge=0)] | None = _d("tag id (apriltag)", None)
    size: Positive | None = _d("tag side, m (apriltag; origin at its centre)", None)
    border_bits: Literal[1, 2] | None = _d("black border width in bits (apriltag)", None)

    @model_validator(mode="after")
    def _fields_of_type(self) -> "Target":
        required, optional = TARGET_FIELDS[self.type]
        given = {f for f in self.model_fields_set if f in _GRID_FIELDS}
        for f in sorted(given - set(required) - set(optional)):
            if self.type == "points":
                raise _custom("a target of type points takes its points from the observations "
                              "(observations.targets.<id>.points); remove the grid fields", key=f)
            raise _custom(f"not a field of a {self.type} target (its fields: {', '.join(required + optional)})", key=f)
        for f in required:
            if f not in given or getattr(self, f) is None:
                raise _custom(f"missing: a {self.type} target needs {', '.join(required)}", key=f)
        return self


class Tool(Closed):
    """A tool on a robot's flange: its tip is unknown (T_flange_<tool>, the TCP)."""

    observed_by: list[Name] | None = _d("cameras that see the tool tip (tool-tip detections)", None)
    robot: Name | None = _d("the robot that holds the tool (cells with several robots)", None)
    orientation: YMat3 | None = _d("known tool orientation (3x3 rotation, flange frame); or axis", None)
    axis: YVec3 | None = _d("known tool axis direction [x, y, z] in the flange frame; or orientation", None)


class Point(Closed):
    """A fixed point of the cell (a divot a tool touches): unknown unless its position is given."""

    position: YVec3 | None = _d("known position [x, y, z], m, in the base frame (world with several robots)", None)


class PoseNoise(Closed):
    """The flange-pose error prior: σ of the robot's reported flange pose."""

    translation_m: PositiveOrVec3 = _d("translation σ, m: one number or [x, y, z]")
    rotation_deg: PositiveOrVec3 = _d("rotation σ, degrees: one number or [rx, ry, rz]")


class Sensor(Closed):
    """A measuring sensor with no lens (a laser tracker, a metrology or motion-capture system): it measures
    6-DOF target poses (``kind: pose``; stations' ``poses: [{sensor, target, T_sensor_target}]``) or 3-D points
    (``kind: point``: a tool's tip, e.g. a laser tracker's reflector; stations' ``positions: [{sensor, tool,
    p_sensor_tool}]``)."""

    kind: Literal["pose", "point"] = _d("pose: it measures a target's 6-DOF pose T_sensor_target (m); point: it "
                                        "measures a tool tip's position p_sensor_tool (m); neither has a lens model "
                                        "or an image size")
    mount: Literal["flange", "base", "world"] = _d("base / world: fixed (unknown T_base_<sensor>, T_world_<sensor> "
                                                   "with several robots); flange: moves with the robot (unknown "
                                                   "T_flange_<sensor>)", "base")
    pose: YMat4 | None = _d(f"known pose of a fixed sensor ({_POSE}); list the sensor in fixed to hold it", None)
    robot: Name | None = _d("the robot whose flange carries the sensor (cells with several robots)", None)


class Robot(Closed):
    """A robot: its kinematics preset, pose noise, base pose and kinematic model."""

    model: str | None = _d("kinematics preset name (jcalib.geometry.ROBOT_PRESETS), for planning and simulation",
                           None)
    pose_noise: PoseNoise | None = _d("flange-pose error prior; omitted: flange poses are exact", None)
    base: YMat4 | None = _d(f"known T_world_<robot> ({_POSE}; cells with several robots)", None)
    kinematics: Kinematics | None = _d("kinematic model: a preset name or a DH / MDH / POE table", None)
    calibrate_kinematics: list[str] | None = _d("kinematic parameters or groups to estimate, e.g. [joint_offsets, "
                                                "link_lengths]", None)
    error_model: Literal["auto", "exact", "pose_noise", "kinematics"] = _d(
        "robot error model: auto (chosen by held-out prediction), exact (poses as reported), pose_noise (per-station "
        "flange corrections, pose_noise their prior level) or kinematics (calibrated kinematics at the joints)", "auto")


class CellDocument(Closed):
    """A robot cell: what is in it, where it is mounted, what is unknown (cell.yaml)."""

    schema_: Literal["jcalib.cell/1"] = Field(alias="schema", description="format and version: jcalib.cell/1")
    cameras: dict[Name, Camera] | None = _d("cameras by name", None)
    sensors: dict[Name, Sensor] | None = _d("pose sensors with no lens (laser tracker, metrology or motion-capture "
                                            "system) by name", None)
    targets: dict[Name, Target] | None = _d("calibration targets by name", None)
    tools: dict[Name, Tool | None] | None = _d("tools by name (unknown TCP T_flange_<tool>); {} for a tool with no "
                                               "options", None)
    points: dict[Name, Point | None] | None = _d("fixed cell points by name (e.g. a pivot divot); {} for an unknown "
                                                 "point", None)
    robot: Robot | None = _d("the one robot of the cell; or robots", None)
    robots: dict[Name, Robot | None] | None = _d("several robots by name (the cell's frame is then world); or robot",
                                                 None)
    fixed: list[str] | None = _d("names held at their prior value: entities (cam1) or transforms (T_base_cam1)", None)
    goals: list[str] | None = _d("accuracy goals NAME:QUANTITY<=VALUE (e.g. T_flange_cam0:translation_mm<=0.05) for "
                                 "station planning and adaptive capture; they do not change a calibration", None)
    assumptions: dict[str, dict[str, Any]] | None = _d(
        "stated inputs and their uncertainty, <entry>.<quantity>: {sigma...} (e.g. board.square: {sigma_rel: "
        "0.001}); propagated into the result's error budget, never into its sampling covariance", None)


def intrinsic_names(model: str, skew: bool) -> tuple[str, ...]:
    """The intrinsic names of a camera model (as :attr:`param_names` of the geometry models)."""
    skew_name = ("alpha",) if model == "fisheye" else ("skew",)
    return ("fx", "fy", "cx", "cy") + (skew_name if skew else ()) + DIST_NAMES[model]


def fixable_names(data: dict) -> list[str]:
    """What ``fixed:`` may list in a (schema-valid) cell document: entity names and their transforms."""
    names: list[str] = []
    for group in ("cameras", "sensors", "targets", "tools", "points", "robots"):
        names += list(data.get(group) or {})
    out = list(names)
    for n in names:
        out += [f"T_base_{n}", f"T_flange_{n}", f"T_world_{n}"]
    return out


def _check_camera(name: str, cam: dict, problems: list) -> None:
    where = f"cameras.{name}"
    model, skew = cam["model"], bool(cam.get("skew", False))
    allowed = intrinsic_names(model, skew)
    for i, f in enumerate(cam.get("fix") or []):
        if f not in allowed and f != "aspect":
            hint = did_you_mean(f, (*allowed, "aspect"))
            extra = " (set skew: true to estimate or fix the skew)" if f in ("skew", "alpha") and not skew else ""
            problems.append((f"{where}.fix[{i}]", f"{f!r} is not an intrinsic of model {model}{hint}{extra} "
                                                  f"(names: {', '.join(allowed)}, aspect)"))
    intr = cam.get("intrinsics")
    if intr is not None:
        K = np.asarray(intr["K"], dtype=np.float64)
        if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1 or K[0, 0] <= 0 or K[1, 1] <= 0:
            problems.append((f"{where}.intrinsics.K", f"expected [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, "
                                                      f"got {K.tolist()}"))
        dist = intr.get("dist") or []
        n = len(DIST_NAMES[model])
        if dist and len(dist) != n:
            problems.append((f"{where}.intrinsics.dist", f"model {model} has {n} distortion coefficients "
                             f"({', '.join(DIST_NAMES[model]) or 'none'}), got {len(dist)}; give all of them "
                             "(0.0 where unknown) or choose the model that matches (jcalib never pads or cuts dist)"))
        elif dist and dist_problem(model, dist):
            problems.append((f"{where}.intrinsics.dist", dist_problem(model, dist)))
    if cam.get("pose") is not None:
        why = pose_problem(cam["pose"], MAX_CELL_EXTENT_M, "camera position")
        if why:
            problems.append((f"{where}.pose", why))


def _check_target(name: str, tgt: dict, problems: list) -> None:
    where = f"targets.{name}"
    for f in ("square", "spacing", "marker", "diameter", "tag_size", "size"):
        v = tgt.get(f)
        if v is not None and float(v) > MAX_TARGET_PITCH_M:
            problems.append((f"{where}.{f}", f"{float(v):g} m is larger than any calibration target's "
                                             f"{MAX_TARGET_PITCH_M:g} m: lengths are in metres; are these millimetres? "
                                             "(divide by 1000)"))
    cols = tgt.get("cols") or tgt.get("squares_x") or 1
    rows = tgt.get("rows") or tgt.get("squares_y") or 1
    if cols * rows > _MAX_GRID_POINTS:
        problems.append((where, f"{cols} x {rows} points is more than the {_MAX_GRID_POINTS} a target may have"))
    if tgt.get("marker") is not None and tgt.get("square") is not None and tgt["marker"] >= tgt["square"]:
        problems.append((f"{where}.marker", f"a ChArUco marker ({tgt['marker']:g} m) must be smaller than its square "
                                            f"({tgt['square']:g} m)"))
    if tgt.get("pose") is not None:
        why = pose_problem(tgt["pose"], MAX_CELL_EXTENT_M, "target position")
        if why:
            problems.append((f"{where}.pose", why))


def _check_tools_points(data: dict, problems: list) -> None:
    cameras = list(data.get("cameras") or {})
    for name, tool in (data.get("tools") or {}).items():
        tool = tool or {}
        for i, c in enumerate(tool.get("observed_by") or []):
            if c not in cameras:
                problems.append((f"tools.{name}.observed_by[{i}]", f"camera {c!r} is not in cameras{did_you_mean(c, cameras)} "
                                                                  f"(cameras: {', '.join(cameras) or 'none'})"))
        if tool.get("orientation") is not None and tool.get("axis") is not None:
            problems.append((f"tools.{name}", "give the tool's orientation or its axis, not both"))
        if tool.get("orientation") is not None:
            why = rotation_problem(tool["orientation"])
            if why:
                problems.append((f"tools.{name}.orientation", why))
        if tool.get("axis") is not None and not norm(tool["axis"]) > 1e-9:
            problems.append((f"tools.{name}.axis", "expected a non-zero direction [x, y, z]"))
    for name, point in (data.get("points") or {}).items():
        pos = (point or {}).get("position")
        if pos is not None and float(norm(pos)) > MAX_CELL_EXTENT_M:
            problems.append((f"points.{name}.position", f"{float(norm(pos)):.4g} m from the origin, more than "
                                                        f"{MAX_CELL_EXTENT_M:g} m: positions are in metres; are these "
                                                        "millimetres? (divide by 1000)"))


def _check_names_unique(data: dict, problems: list) -> None:
    owner: dict[str, str] = {}
    for group in ("cameras", "sensors", "targets", "tools", "points", "robots"):
        for name in data.get(group) or {}:
            if name in owner and owner[name] != group:
                problems.append((f"{group}.{name}", f"{name!r} has the name of a {owner[name][:-1]}; give each camera, "
                                                    "sensor, target, tool, point and robot its own name (transform names such "
                                                    f"as T_base_{name} must be unique)"))
            owner.setdefault(name, group)


def _check_robots(data: dict, problems: list) -> None:
    entries = {"robot": data.get("robot")} if data.get("robot") is not None else {}
    entries.update({f"robots.{n}": r for n, r in (data.get("robots") or {}).items() if r is not None})
    for where, robot in entries.items():
        if robot.get("base") is not None:
            why = pose_problem(robot["base"], MAX_CELL_EXTENT_M, "robot base position")
            if why:
                problems.append((f"{where}.base", why))


def validate_cell_document(data: Any, source: str = "<dict>") -> dict:
    """Check a cell spec document (a loaded YAML / JSON mapping) against the schema.

    Returns:
        The document as validated: a new mapping, numbers written as text (``1e-4``) converted,
        keys not given left out.

    Raises:
        SchemaError: naming ``source``, the key path and what to do.
    """
    if isinstance(data, dict) and "schema" in data and data["schema"] != SCHEMA and isinstance(data["schema"], str):
        other = data["schema"]
        hint = ("" if not other.startswith("jcalib.") or other.startswith("jcalib.cell/")
                else f"; this looks like a {other} file, not a cell spec")
        raise SchemaError(source, [("schema", f"expected {SCHEMA!r}, got {other!r}{hint}")])
    doc = validate(CellDocument, data, source)
    problems: list[tuple[str, str]] = []
    for name, cam in (data.get("cameras") or {}).items():
        _check_camera(name, cam, problems)
    for name, tgt in (data.get("targets") or {}).items():
        _check_target(name, tgt, problems)
    for name, sensor in (data.get("sensors") or {}).items():
        why = pose_problem(sensor["pose"], MAX_CELL_EXTENT_M, "sensor position") if sensor.get("pose") else None
        if why:
            problems.append((f"sensors.{name}.pose", why))
    _check_tools_points(data, problems)
    _check_names_unique(data, problems)
    _check_robots(data, problems)
    allowed = fixable_names(data)
    for i, f in enumerate(data.get("fixed") or []):
        if f not in allowed:
            problems.append((f"fixed[{i}]", f"{f!r} names nothing in the cell{did_you_mean(f, allowed)} (fixed lists "
                                            "camera, sensor, target, tool, point or robot names, or their transforms "
                                            "T_base_<name>, T_flange_<name>, T_world_<name>)"))
    if problems:
        raise SchemaError(source, problems)
    return doc.model_dump(by_alias=True, exclude_unset=True)
