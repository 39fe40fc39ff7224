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
``kinematics:`` (a preset name or a table mapping) and ``calibrate_kinematics: [names]``.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BeforeValidator, Field, model_validator
from pydantic_core import PydanticCustomError

from jcalib.io.schema.base import Closed, Int, Name, SchemaError, YNum, did_you_mean, format_value, validate
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


Setting = Annotated[Any, BeforeValidator(_setting)]
GenICamName = Annotated[str, BeforeValidator(_genicam_name)]
PositiveOrVec3 = Annotated[Any, BeforeValidator(_positive_or_vec3)]
Kinematics = Annotated[Any, BeforeValidator(_kinematics)]
Positive = Annotated[YNum, Field(gt=0)]
GridCount = Annotated[Int, Field(ge=1, le=_MAX_GRID)]


class Intrinsics(Closed):
    K: YMat3
    dist: list[YNum] | None = None


class Camera(Closed):
    model: Literal["pinhole", "opencv4", "opencv5", "opencv8", "opencv12", "opencv14", "fisheye", "splined"]
    mount: Mount = "free"
    skew: bool = False
    fix: list[str] | None = None
    intrinsics: Intrinsics | None = None
    pose: YMat4 | None = None
    robot: Name | None = None
    settings: dict[GenICamName, Setting] | None = None


class Target(Closed):
    type: Literal["checkerboard", "charuco", "circles", "aprilgrid", "apriltag", "points"]
    mount: Mount = "free"
    pose: YMat4 | None = None
    robot: Name | None = None
    warp: bool = False
    cols: GridCount | None = None
    rows: GridCount | None = None
    square: Positive | None = None
    squares_x: GridCount | None = None
    squares_y: GridCount | None = None
    marker: Positive | None = None
    dictionary: str | None = None
    legacy: bool | None = None
    spacing: Positive | None = None
    asymmetric: bool | None = None
    diameter: Positive | None = None
    origin_dot: Literal["top_left", "top_right", "bottom_left", "bottom_right"] | None = None
    family: Literal["tag16h5", "tag25h9", "tag36h11"] | None = None
    tag_size: Positive | None = None
    tag_spacing: Annotated[YNum, Field(gt=0, le=1)] | None = None
    id: Annotated[Int, Field(ge=0)] | None = None
    size: Positive | None = None
    border_bits: Literal[1, 2] | None = None

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
    observed_by: list[Name] | None = None
    robot: Name | None = None
    orientation: YMat3 | None = None
    axis: YVec3 | None = None


class Point(Closed):
    position: YVec3 | None = None


class PoseNoise(Closed):
    translation_m: PositiveOrVec3
    rotation_deg: PositiveOrVec3


class Robot(Closed):
    model: str | None = None
    pose_noise: PoseNoise | None = None
    base: YMat4 | None = None
    kinematics: Kinematics | None = None
    calibrate_kinematics: list[str] | None = None


class CellDocument(Closed):
    schema_: Literal["jcalib.cell/1"] = Field(alias="schema")
    cameras: dict[Name, Camera] | None = None
    targets: dict[Name, Target] | None = None
    tools: dict[Name, Tool | None] | None = None
    points: dict[Name, Point | None] | None = None
    robot: Robot | None = None
    robots: dict[Name, Robot | None] | None = None
    fixed: list[str] | None = None
    goals: list[str] | None = None


def intrinsic_names(model: str, skew: bool) -> tuple[str, ...]:
    """The intrinsic names of a camera model (as :attr:`param_names` of the geometry models)."""
    skew_name = ("alpha",) if model == "fisheye" else ("skew",)
    return ("fx", "fy", "cx", "cy") + (skew_name if skew else ()) + DIST_NAMES[model]


def fixable_names(data: dict) -> list[str]:
    """What ``fixed:`` may list in a (schema-valid) cell document: entity names and their transforms."""
    names: list[str] = []
    for group in ("cameras", "targets", "tools", "points", "robots"):
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
    for group in ("cameras", "targets", "tools", "points", "robots"):
        for name in data.get(group) or {}:
            if name in owner and owner[name] != group:
                problems.append((f"{group}.{name}", f"{name!r} has the name of a {owner[name][:-1]}; give each camera, "
                                                    "target, tool, point and robot its own name (transform names such "
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
    _check_tools_points(data, problems)
    _check_names_unique(data, problems)
    _check_robots(data, problems)
    allowed = fixable_names(data)
    for i, f in enumerate(data.get("fixed") or []):
        if f not in allowed:
            problems.append((f"fixed[{i}]", f"{f!r} names nothing in the cell{did_you_mean(f, allowed)} (fixed lists "
                                            "camera, target, tool, point or robot names, or their transforms "
                                            "T_base_<name>, T_flange_<name>, T_world_<name>)"))
    if problems:
        raise SchemaError(source, problems)
    return doc.model_dump(by_alias=True, exclude_unset=True)
