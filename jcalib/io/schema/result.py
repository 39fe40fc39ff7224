"""Schema of result files (``jcalib.result/1``) as far as the data classes do not check it already.

:class:`jcalib.io.result.ResultFile` validates every value (shapes, finiteness, rotations,
covariances) and keeps unknown keys (a newer file survives a round trip through older code), so this
schema adds what protects the readers of a result (console, HTML report, exports): every name
(camera, transform, point, point frame) is a valid name (:func:`jcalib.io.schema.base.check_name`:
no control characters, brackets, quotes or path separators), and the known sections have the right
types. Free text (provenance) may hold anything; the exports escape it.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field

from jcalib.io.schema.base import Int, Name, Num, Open, SchemaError, validate
from jcalib.io.schema.common import MAX_IMAGE_SIDE_PX, Mat3, Mat4, Vec3

__all__ = ["ResultDocument", "validate_result_document"]

SCHEMA = "jcalib.result/1"


class CameraEntry(Open):
    model: Literal["pinhole", "opencv4", "opencv5", "opencv8", "opencv12", "opencv14", "fisheye", "splined"]
    image_size: Annotated[list[Annotated[Int, Field(ge=1, le=MAX_IMAGE_SIDE_PX)]], Field(min_length=2, max_length=2)]
    K: Mat3
    dist: list[Num]
    std: dict[str, Num] | None = None
    covariance: list[list[Num]] | None = None
    skew: bool | None = None


class TransformEntry(Open):
    matrix: Mat4
    covariance: list[list[Num]] | None = None


class PointEntry(Open):
    position: Vec3
    frame: Name
    covariance: Mat3 | None = None


class Provenance(Open):
    input_hash: str | None = None
    jcalib_version: str | None = None
    options: dict | None = None
    created: str | None = None


class ResultDocument(Open):
    schema_: Literal["jcalib.result/1"] = Field(alias="schema")
    cameras: dict[Name, CameraEntry] | None = None
    transforms: dict[Name, TransformEntry] | None = None
    points: dict[Name, PointEntry] | None = None
    stats: dict | None = None
    provenance: Provenance | None = None


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
