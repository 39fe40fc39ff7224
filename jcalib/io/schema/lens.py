"""Distortion coefficient names of each camera model, in OpenCV's order (``len`` = the length of ``dist``).

Mirrors :mod:`jcalib.geometry.cameras` (kept here so reading a cell or result needs no JAX; a test
checks that the two agree).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["FOV_X_DEG_RANGE", "LENS_DIST_NAMES", "dist_problem"]

_OPENCV = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty")

#: model name -> its distortion coefficient names. ``splined``: the spline's extent and the two values of
#: each of its (16, 13) control points (:mod:`jcalib.geometry.cameras.splined`).
LENS_DIST_NAMES: dict[str, tuple[str, ...]] = {
    "pinhole": (),
    "opencv4": _OPENCV[:4],
    "opencv5": _OPENCV[:5],
    "opencv8": _OPENCV[:8],
    "opencv12": _OPENCV[:12],
    "opencv14": _OPENCV[:14],
    "fisheye": ("k1", "k2", "k3", "k4"),
    "splined": ("fov_x_deg",) + tuple(f"s{ax}{j}_{i}" for j in range(13) for i in range(16) for ax in ("u", "v")),
}

#: A splined camera's ``fov_x_deg`` (the spline's horizontal extent): a real lens's field of view, above 0
#: and at most the 350° that :func:`jcalib.geometry.cameras.splined.fov_covering` gives the widest fisheye
#: (the stereographic plane ends at 360°).
FOV_X_DEG_RANGE = (0.0, 350.0)


def dist_problem(model: str, dist: Sequence[float]) -> str | None:
    """Why ``dist`` of a ``model`` camera is not physical (None if it is): a ``splined`` camera's ``fov_x_deg``
    (``dist[0]``) outside :data:`FOV_X_DEG_RANGE`."""
    if model == "splined" and len(dist) > 0:
        lo, hi = FOV_X_DEG_RANGE
        fov = float(dist[0])
        if not (math.isfinite(fov) and lo < fov <= hi):
            return (f"fov_x_deg (dist[0] of a splined camera) is {fov:g}; expected a horizontal field of view in "
                    f"({lo:g}, {hi:g}] degrees")
    return None
