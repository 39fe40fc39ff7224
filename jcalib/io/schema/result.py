"""Schema of result files (``jcalib.result/1``) as far as the data classes do not check it already.

:class:`jcalib.io.result.ResultFile` validates every value (shapes, finiteness, rotations,
covariances) and keeps unknown keys (a newer file survives a round trip through older code), so this
schema adds what protects the readers of a result (console, HTML report, exports): every name
(camera, transform, point, point frame) is a valid name (:func:`jcalib.io.schema.base.check_name`:
no control characters, brackets, quotes or path separators), and the known sections have the right
types. Free text (provenance) may hold anything; the exports escape it.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from jcalib.io.schema.base import Name, Open, SchemaError, validate

__all__ = ["ResultDocument", "validate_result_document"]

SCHEMA = "jcalib.result/1"


class PointEntry(Open):
    frame: Name


class ResultDocument(Open):
    schema_: Literal["jcalib.result/1"] = Field(alias="schema")
    cameras: dict[Name, dict] | None = None
    transforms: dict[Name, dict] | None = None
    points: dict[Name, PointEntry] | None = None
    stats: dict | None = None
    provenance: dict | None = None


def validate_result_document(data: Any, source: str = "<dict>") -> ResultDocument:
    """Check the names and section types of a result document.

    Raises:
        SchemaError: naming ``source`` and the key path.
    """
    if isinstance(data, dict) and isinstance(data.get("schema"), str) and data["schema"] != SCHEMA:
        other = data["schema"]
        hint = "" if not other.startswith("jcalib.") or other.startswith("jcalib.result/") else (
            f"; this looks like a {other} file, not a result")
        raise SchemaError(source, [("schema", f"expected {SCHEMA!r}, got {other!r}{hint}")])
    return validate(ResultDocument, data, source)
