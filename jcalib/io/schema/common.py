"""Shapes shared by several schemas (matrices, poses) and the plausibility limits on units.

Plausibility limits catch values given in the wrong unit, the commonest silent error in cell data:
a flange translation of 600 "m" is 600 mm written as metres. They are deliberately loose (no robot
reaches 5 m from its base; no cell is 50 m across; no calibration square is 1 m wide), and can be
raised for a genuine exception (a robot on a long track, a gantry) with ``JCALIB_MAX_REACH_M``.
"""

from __future__ import annotations

import os
from typing import Annotated, Any

import numpy as np
from pydantic import Field

from jcalib.errors import BadInputError
from jcalib.io.schema.base import Num, YNum

__all__ = [
    "MAX_CELL_EXTENT_M",
    "MAX_IMAGE_SIDE_PX",
    "MAX_TARGET_PITCH_M",
    "Mat3",
    "Mat4",
    "Vec3",
    "YMat3",
    "YMat4",
    "YVec3",
    "max_reach_m",
    "norm",
    "pose_problem",
    "rotation_problem",
]

#: A calibration target's square / circle spacing above this (m) is a unit error (mm as m).
MAX_TARGET_PITCH_M = 1.0
#: Fixed things in a cell (camera poses, targets, points, robot bases) lie within this (m) of the origin.
MAX_CELL_EXTENT_M = 50.0
#: Largest image side (px) accepted in any file.
MAX_IMAGE_SIDE_PX = 100_000
_DEFAULT_REACH_M = 5.0


def max_reach_m() -> float:
    """The largest flange translation (m) accepted from a robot (``JCALIB_MAX_REACH_M``, default 5 m)."""
    raw = os.environ.get("JCALIB_MAX_REACH_M", "")
    if not raw:
        return _DEFAULT_REACH_M
    try:
        value = float(raw)
    except ValueError:
        raise BadInputError(f"JCALIB_MAX_REACH_M: expected a distance in metres, got {raw!r}") from None
    if not np.isfinite(value) or value <= 0:
        raise BadInputError(f"JCALIB_MAX_REACH_M: expected a positive distance in metres, got {raw!r}")
    return value


def _rows(n: int, cell: Any) -> Any:
    return Annotated[list[Annotated[list[cell], Field(min_length=n, max_length=n)]], Field(min_length=n, max_length=n)]


#: A 3-vector / 3x3 / 4x4 matrix of finite numbers (JSON files).
Vec3 = Annotated[list[Num], Field(min_length=3, max_length=3)]
Mat3 = _rows(3, Num)
Mat4 = _rows(4, Num)
#: The same in YAML files (numbers written as text accepted).
YVec3 = Annotated[list[YNum], Field(min_length=3, max_length=3)]
YMat3 = _rows(3, YNum)
YMat4 = _rows(4, YNum)


def norm(x: Any, axis: int | None = None) -> Any:
    """Euclidean norm of finite numbers that may be huge (1e300): ``inf`` on overflow, no warning."""
    with np.errstate(over="ignore", invalid="ignore"):
        return np.linalg.norm(np.asarray(x, dtype=np.float64), axis=axis)


def rotation_problem(R: Any, tol: float = 1e-6) -> str | None:
    """Why the 3x3 ``R`` is not a proper rotation (None if it is)."""
    R = np.asarray(R, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        err = float(np.max(np.abs(R.T @ R - np.eye(3))))
        det = float(np.linalg.det(R))
    if not err <= tol or not det > 0:
        return (f"the rotation is not a proper rotation matrix (max |R^T R - I| = {err:.3g}, det = {det:.4g}); "
                "write it with at least 7 significant digits")
    return None


def pose_problem(T: Any, max_translation_m: float | None = None, what: str = "translation") -> str | None:
    """Why the 4x4 ``T`` (m) is not a rigid transform within ``max_translation_m`` (None if it is)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return _pose_problem(np.asarray(T, dtype=np.float64), max_translation_m, what)


def _pose_problem(T: np.ndarray, max_translation_m: float | None, what: str) -> str | None:
    if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
        return f"the last row of a pose must be [0, 0, 0, 1], got {T[3].tolist()}"
    why = rotation_problem(T[:3, :3])
    if why:
        return why
    if max_translation_m is not None:
        dist = float(norm(T[:3, 3]))
        if dist > max_translation_m:
            return (f"the {what} is {dist:.4g} m from the origin, more than {max_translation_m:g} m: poses are in "
                    f"metres; are these millimetres? (divide by 1000)")
    return None
