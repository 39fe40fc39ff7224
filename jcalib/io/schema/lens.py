"""Distortion coefficient names of each camera model, in OpenCV's order (``len`` = the length of ``dist``).

Mirrors :mod:`jcalib.geometry.cameras` (kept here so reading a cell or result needs no JAX; a test
checks that the two agree).
"""

from __future__ import annotations

__all__ = ["LENS_DIST_NAMES"]

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
