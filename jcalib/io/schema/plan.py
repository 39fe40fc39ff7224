"""Schema of station plans (``jcalib.plan/1``): known keys, 4x4 flange poses within a robot's reach."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, StringConstraints

from jcalib.io.schema.base import Closed, SchemaError, YNum, validate
from jcalib.io.schema.common import YMat4, max_reach_m, pose_problem

__all__ = ["PlanDocument", "validate_plan_document"]

SCHEMA = "jcalib.plan/1"
PlanId = Annotated[str, StringConstraints(pattern=r"^[A-Za-z0-9_.-]{1,64}$")]


class PlanStation(Closed):
    """One station to visit."""

    id: PlanId | None = Field(None, description="station id (letters, digits, '_', '.', '-')")
    T_base_flange: YMat4 = Field(description="the flange pose to reach, in the robot's base frame (4x4 homogeneous "
                                             "transform, translation in m)")
    move: Literal["joint", "linear"] = Field("joint", description="how the robot moves there")
    joints_deg: Annotated[list[YNum], Field(min_length=1, max_length=32)] | None = Field(
        None, description="joint values in controller units (degrees; prismatic axes mm)")
    lens: dict[str, dict[str, YNum]] | None = Field(
        None, description="lens settings to set before grabbing, camera -> GenICam feature -> value (e.g. "
                          "{cam0: {Zoom: 350}}); capture records what the camera reads back")


class PlanDocument(Closed):
    """A station plan (jcalib plan -o PLAN, jcalib capture --plan PLAN): flange poses to visit, in order."""

    schema_: Literal["jcalib.plan/1"] = Field(alias="schema", description="format and version: jcalib.plan/1")
    stations: Annotated[list[PlanStation], Field(min_length=1)] = Field(description="the stations, in visiting order")
    digest: str | None = Field(None, description="digest of the plan (a session's copy of its plan)")
    planner: Any = Field(None, description="what jcalib plan planned for (kind, robot, camera, ...; a list when "
                                           "plans are joined)")


def _station_label(data: Any, path: str) -> str:
    """``stations[k].rest`` shown as ``station k (id) rest`` (as the plan's own messages name stations)."""
    if not path.startswith("stations["):
        return path
    end = path.index("]")
    k = path[len("stations["):end]
    try:
        sid = data["stations"][int(k)].get("id")
    except (ValueError, IndexError, KeyError, TypeError, AttributeError):
        sid = None
    label = f"station {k}" + (f" ({sid})" if isinstance(sid, str) else "")
    rest = path[end + 1:].lstrip(".")
    return f"{label} {rest}" if rest else label


def validate_plan_document(data: Any, source: str = "plan") -> PlanDocument:
    """Check a plan document: keys, shapes, and flange poses rigid and within reach (m).

    Raises:
        SchemaError: naming ``source``, the station and key.
    """
    try:
        doc = validate(PlanDocument, data, source)
        reach = max_reach_m()
        problems = []
        for i, st in enumerate(data["stations"]):
            why = pose_problem(st["T_base_flange"], reach, "flange translation")
            if why:
                problems.append((f"stations[{i}].T_base_flange", why))
        if problems:
            raise SchemaError(source, problems)
    except SchemaError as e:
        raise SchemaError(source, [(_station_label(data, p), m) for p, m in e.problems], total=e.total) from None
    return doc
