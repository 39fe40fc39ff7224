"""Schemas of the files of ``jcalib triangulate`` (``jcalib.pixels/1``) and ``jcalib frame`` (points).

The pixels file names cameras and points; pixels are checked finite (and, where the file gives the
camera's ``image_size``, inside the image), flange poses rigid and within reach. A points file is
``jcalib.pipeline.points/1`` as triangulate writes it, or any JSON with ``points`` of that form
(a result file): its known keys are typed, extra keys kept.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field

from jcalib.io.schema.base import Closed, Int, Name, Num, Open, SchemaError, StationId, validate
from jcalib.io.schema.common import MAX_CELL_EXTENT_M, MAX_IMAGE_SIDE_PX, Mat3, Mat4, Vec3, max_reach_m, norm, pose_problem
from jcalib.io.schema.observations import pixels_outside, warn_pixels_outside

__all__ = ["PixelsDocument", "PointsDocument", "validate_pixels_document", "validate_points_document"]

Pixel = Annotated[list[Num], Field(min_length=2, max_length=2)]
ImageSide = Annotated[Int, Field(ge=1, le=MAX_IMAGE_SIDE_PX)]


class PixelCamera(Closed):
    image_size: Annotated[list[ImageSide], Field(min_length=2, max_length=2)]


class PixelStation(Closed):
    id: StationId | None = None
    T_base_flange: Mat4 | None = None
    pixels: dict[Name, dict[Name, Pixel]]


class PixelsDocument(Closed):
    schema_: Literal["jcalib.pixels/1"] = Field(alias="schema")
    sigma_px: Annotated[Num, Field(gt=0)] | None = None
    cameras: dict[Name, PixelCamera] | None = None
    stations: Annotated[list[PixelStation], Field(min_length=1)]


class PointEntry(Open):
    position: Vec3
    frame: Name | None = None
    covariance: Mat3 | None = None


class JointCovariance(Open):
    points: list[Name]
    matrix: list[list[Num]]


class PointsDocument(Open):
    points: Annotated[dict[Name, PointEntry], Field(min_length=1)]
    frame: Name | None = None
    joint_covariance: JointCovariance | None = None


def validate_pixels_document(data: Any, source: str) -> PixelsDocument:
    """Check a ``jcalib.pixels/1`` document.

    Raises:
        SchemaError: naming ``source``, the station and key.
    """
    doc = validate(PixelsDocument, data, source)
    sizes = {c: tuple(e["image_size"]) for c, e in (data.get("cameras") or {}).items()}
    reach = max_reach_m()
    problems = []
    outside: dict[str, list] = {}
    for i, st in enumerate(data["stations"]):
        if st.get("T_base_flange") is not None:
            why = pose_problem(st["T_base_flange"], reach, "flange translation")
            if why:
                problems.append((f"stations[{i}].T_base_flange", why))
        for cam, pts in st["pixels"].items():
            if cam not in sizes:
                continue
            for name, uv in pts.items():
                out, far = pixels_outside(np.asarray([uv]), sizes[cam])
                where = f"stations[{i}].pixels.{cam}.{name}"
                if far[0]:
                    w, h = sizes[cam]
                    problems.append((where, f"pixel {uv} lies far outside camera {cam!r}'s image of {w}x{h} px"))
                elif out[0]:
                    outside.setdefault(cam, [0, sizes[cam], where, np.asarray(uv)])[0] += 1
    if problems:
        raise SchemaError(source, problems)
    warn_pixels_outside(source, outside)
    return doc


def validate_points_document(data: Any, source: str) -> PointsDocument:
    """Check a points document (``jcalib.pipeline.points/1`` or a result with ``points``).

    Raises:
        SchemaError: naming ``source`` and the key.
    """
    doc = validate(PointsDocument, data, source)
    problems = []
    for name, entry in data["points"].items():
        d = float(norm(entry["position"]))
        if d > MAX_CELL_EXTENT_M:
            problems.append((f"points.{name}.position", f"{d:.4g} m from the origin, more than {MAX_CELL_EXTENT_M:g} m: "
                                                        "positions are in metres; are these millimetres? (divide by 1000)"))
    if problems:
        raise SchemaError(source, problems)
    return doc
