"""Schema of capture sessions (``jcalib.session/1``): ``session.json`` and each ``stations.jsonl`` record.

Both are forward compatible (unknown keys are kept: the capture records more over time), but every
known key is typed, flange poses are rigid and within reach, and image paths stay inside the
session folder (``images/<camera>/<station>.png``; an absolute path or ``..`` is refused: a session
from elsewhere must not make jcalib read other files).
"""

from __future__ import annotations

from pathlib import PurePosixPath
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BeforeValidator, Field, StringConstraints
from pydantic_core import PydanticCustomError

from jcalib.io.schema.base import Name, Num, Open, SchemaError, StationId, format_value, validate
from jcalib.io.schema.common import Mat4, max_reach_m, pose_problem

__all__ = ["SessionMeta", "StationRecord", "validate_session_meta", "validate_station_record"]

SCHEMA = "jcalib.session/1"


def _relative_path(value: Any) -> Any:
    ok = isinstance(value, str) and value and "\\" not in value and not any(ord(c) < 32 for c in value)
    if ok:
        p = PurePosixPath(value)
        ok = not p.is_absolute() and ".." not in p.parts
    if not ok:
        raise PydanticCustomError("jcalib_check", "{why}", {
            "why": f"expected a path inside the session folder such as images/cam0/s000.png, got {format_value(value)}"})
    return value


def _joints(value: Any) -> Any:
    def is_list(v: Any) -> bool:
        return isinstance(v, list) and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in v)

    if value is None or is_list(value) or (isinstance(value, dict) and all(
            isinstance(k, str) and is_list(v) for k, v in value.items())):
        return value
    raise PydanticCustomError("jcalib_check", "{why}", {
        "why": f"expected joint values (a list of finite numbers, or robot -> list), got {format_value(value)}"})


RelativePath = Annotated[str, BeforeValidator(_relative_path, json_schema_input_type=Annotated[
    str, StringConstraints(min_length=1, pattern=r"^(?!/)(?!.*(^|/)\.\.(/|$))[^\\\x00-\x1f]+$")])]
#: Joint values as sessions record them, for the published schema (the validator checks finiteness).
JointValues = list[float] | dict[str, list[float]] | None
_POSE = "4x4 homogeneous transform, translation in m"


class StationRecord(Open):
    """One finished station of a capture session (a line of stations.jsonl)."""

    id: StationId = Field(description="station id")
    T_base_flange: Mat4 | None = Field(None, description=f"the flange pose in the robot's base frame ({_POSE})")
    flange_poses: dict[Name, Mat4] | None = Field(None, description="flange pose of each robot by name (several "
                                                                    "robots)")
    joints_deg: Annotated[Any, BeforeValidator(_joints, json_schema_input_type=JointValues)] = Field(
        None, description="joint values, degrees (prismatic axes mm): a list, or robot -> list")
    time: str | None = Field(None, description="when the station was captured, ISO 8601 UTC")
    images: dict[Name, RelativePath] | None = Field(None, description="image of each camera, a path inside the "
                                                                      "session folder (images/<camera>/<station>.png)")
    status: str = Field("ok", description="ok, or 'skipped: <reason>'")
    lens: dict[Name, dict[Name, Num]] | None = Field(
        None, description="lens settings each camera read back after capture set them (plan stations with lens), "
                          "e.g. {cam0: {Zoom: 350}}")


class SessionMeta(Open):
    """A capture session's session.json: what was captured, with what, when."""

    schema_: Literal["jcalib.session/1"] = Field(alias="schema", description="format and version: jcalib.session/1")
    jcalib_version: str | None = Field(None, description="the jcalib that wrote the session")
    created: str | None = Field(None, description="creation time, ISO 8601 UTC")
    cell: dict | None = Field(None, description="the cell spec (jcalib.cell/1) as loaded from cell.yaml")
    devices: dict | None = Field(None, description="device addresses and settings (robot, cameras)")
    plan: dict | None = Field(None, description="the station plan (jcalib.plan/1) the capture ran")


def validate_session_meta(data: Any, source: str) -> SessionMeta:
    """Check ``session.json``.

    Raises:
        SchemaError: naming the file and the key.
    """
    return validate(SessionMeta, data, source)


def validate_station_record(data: Any, source: str) -> StationRecord:
    """Check one ``stations.jsonl`` record (``source`` names the file and line).

    Raises:
        SchemaError: naming the file, line and key.
    """
    rec = validate(StationRecord, data, source)
    poses = {"T_base_flange": data["T_base_flange"]} if data.get("T_base_flange") is not None else {}
    poses.update({f"flange_poses.{r}": T for r, T in (data.get("flange_poses") or {}).items()})
    reach = max_reach_m()
    problems = [(k, why) for k, T in poses.items() if (why := pose_problem(T, reach, "flange translation"))]
    if problems:
        raise SchemaError(source, problems)
    return rec
