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


_BUDGET = ("error budget: coords, units, sampling (σ per coordinate), assumptions (stated input -> its σ "
           "contribution per coordinate), combined (docs/guides/error-budget.md)")
_COMBINED = "sampling covariance plus every stated input's contribution, same shape and order as covariance"
_COV6 = "6x6 covariance, tangent order (rx, ry, rz, tx, ty, tz), rad and m, right perturbation in frame b"


class CameraEntry(Open):
    """A calibrated camera: intrinsics in OpenCV form (cv2 takes K and dist unchanged) and their σ."""

    model: Literal["pinhole", "opencv4", "opencv5", "opencv8", "opencv12", "opencv14", "fisheye", "splined"] = Field(
        description="lens model")
    image_size: Annotated[list[Annotated[Int, Field(ge=1, le=MAX_IMAGE_SIDE_PX)]], Field(
        min_length=2, max_length=2)] = Field(description="[width, height], px")
    K: Mat3 = Field(description="camera matrix [[fx, skew, cx], [0, fy, cy], [0, 0, 1]], px")
    dist: list[Num] = Field(description="distortion coefficients in OpenCV's order")
    std: dict[str, Num] | None = Field(None, description="σ of each intrinsic by name (fx, fy, cx, cy, k1, ...)")
    covariance: list[list[Num]] | None = Field(None, description="covariance of the intrinsics, in the order of std")
    budget: dict[str, Any] | None = Field(None, description=_BUDGET)
    covariance_combined: list[list[Num]] | None = Field(None, description=_COMBINED)
    skew: bool | None = Field(None, description="whether the model has a skew (K[0][1])")


class TransformEntry(Open):
    """A calibrated transform T_a_b (the pose of frame b in frame a) and its covariance."""

    matrix: Mat4 = Field(description="4x4 homogeneous transform, translation in m")
    covariance: list[list[Num]] | None = Field(None, description=_COV6)
    budget: dict[str, Any] | None = Field(None, description=_BUDGET)
    covariance_combined: list[list[Num]] | None = Field(None, description=_COMBINED)


class PointEntry(Open):
    """A calibrated cell point."""

    position: Vec3 = Field(description="[x, y, z], m")
    frame: Name = Field(description="the frame of position (base, or world with several robots)")
    covariance: Mat3 | None = Field(None, description="3x3 covariance, m^2")


class Provenance(Open):
    """Where the result came from."""

    input_hash: str | None = Field(None, description="hash of the cell spec and observations")
    jcalib_version: str | None = Field(None, description="the jcalib that computed it")
    options: dict | None = Field(None, description="the calibration options")
    created: str | None = Field(None, description="creation time, ISO 8601 UTC")


class ResultDocument(Open):
    """A calibration result (result.json): estimates, covariances, statistics, provenance."""

    schema_: Literal["jcalib.result/1"] = Field(alias="schema", description="format and version: jcalib.result/1")
    cameras: dict[Name, CameraEntry] | None = Field(None, description="calibrated cameras by name")
    transforms: dict[Name, TransformEntry] | None = Field(
        None, description="calibrated transforms by name: T_flange_<camera or tool>, T_base_<camera or target>, ...")
    points: dict[Name, PointEntry] | None = Field(None, description="calibrated cell points by name")
    targets: dict[Name, dict] | None = Field(None, description="what was estimated of a target itself by name: "
                                                               "warp_m (c0, c1), m, and warp_covariance, m^2")
    kinematics: dict[Name, dict] | None = Field(
        None, description="calibrated kinematic model of each robot by name: convention (dh, mdh, poe), names, values, "
                          "nominal, calibrated, covariance (m, rad)")
    stats: dict | None = Field(None, description="residual statistics and diagnostics (rms_px, num_residuals, "
                                                 "sigma_px, warnings, ...)")
    provenance: Provenance | None = Field(None, description="input hash, jcalib version, options, creation time")
    joint_covariance: dict | None = Field(None, description="covariance over several unknowns: names, dims, matrix, "
                                                            "order")
    T_cam_target: dict | None = Field(None, description="the target's pose in each camera at the estimate, for every "
                                                        "view: station -> camera -> 4x4, m")
    lenses: dict[Name, dict] | None = Field(
        None, description="zoom lenses by camera: setting, range, settings_used, degree, knots, model, image_size, "
                          "param_names, columns, intrinsics (at the lowest setting), lens (further control points), "
                          "control_points, mount, covariance over (intrinsics, lens, mount tangent)")


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
