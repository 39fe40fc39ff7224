"""Schema of a session's ``exclusions.json`` (``jcalib.exclusions/1``), for the published JSON Schema.

:func:`jcalib.io.exclusions.parse_exclusions` checks the file when a session is read; this model states the
same rules (known keys only, non-empty printable ids of at most 200 characters, a text note) so that the
format has a schema and a reference page like every other file. A test checks that the two agree.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, StringConstraints

from jcalib.io.schema.base import Closed

__all__ = ["ExclusionsDocument"]

#: A station or camera id as the exclusions file takes it (``jcalib.io.exclusions``).
ExclusionId = Annotated[str, StringConstraints(min_length=1, max_length=200, pattern=r"^[^\x00-\x1f]*$")]


class Excluded(Closed):
    """A station (no camera) or one camera's view of it, left out of the calibration."""

    station: ExclusionId = Field(description="the station id")
    camera: ExclusionId = Field(None, description="the camera whose view is left out; omitted: the whole station")
    note: str | None = Field(None, description="why it is left out")


class ExclusionsDocument(Closed):
    """What an operator left out of a capture session's calibration (SESSION/exclusions.json); honoured by
    jcalib detect --session and jcalib calibrate."""

    schema_: Literal["jcalib.exclusions/1"] = Field(alias="schema",
                                                    description="format and version: jcalib.exclusions/1")
    excluded: list[Excluded] = Field([], description="what is left out")
    updated: Any = Field(None, description="when the file was last changed, ISO 8601 UTC (informative)")
