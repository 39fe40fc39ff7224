"""Schema of station plans (``jcalib.plan/1``): known keys, 4x4 flange poses within a robot's reach."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, StringConstraints

from jcalib.io.schema.base import Closed, SchemaError, validate
from jcalib.io.schema.common import YMat4, max_reach_m, pose_problem

__all__ = ["PlanDocument", "validate_plan_document"]

SCHEMA = "jcalib.plan/1"
PlanId = Annotated[str, StringConstraints(pattern=r"^[A-Za-z0-9_.-]{1,64}$")]


class PlanStation(Closed):
    id: PlanId | None = None
    T_base_flange: YMat4
    move: Literal["joint", "linear"] = "joint"


class PlanDocument(Closed):
    schema_: Literal["jcalib.plan/1"] = Field(alias="schema")
    stations: Annotated[list[PlanStation], Field(min_length=1)]
    digest: str | None = None


def validate_plan_document(data: Any, source: str = "plan") -> PlanDocument:
    """Check a plan document: keys, shapes, and flange poses rigid and within reach (m).

    Raises:
        SchemaError: naming ``source``, the station and key.
    """
    doc = validate(PlanDocument, data, source)
    reach = max_reach_m()
    problems = []
    for i, st in enumerate(data["stations"]):
        why = pose_problem(st["T_base_flange"], reach, "flange translation")
        if why:
            problems.append((f"stations[{i}].T_base_flange", why))
    if problems:
        raise SchemaError(source, problems)
    return doc
