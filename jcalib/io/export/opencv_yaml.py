"""Export cameras as OpenCV ``FileStorage`` YAML (``%YAML:1.0``, ``!!opencv-matrix``).

One camera (the layout of OpenCV's ``calibration`` sample)::

    camera_name: "cam0"
    camera_model: "opencv5"          # jcalib model; "fisheye" means cv2.fisheye's D
    image_width: 1600
    image_height: 1200
    camera_matrix: !!opencv-matrix   # 3x3 K, pixels
    distortion_coefficients: !!opencv-matrix   # 1xn, OpenCV order

A stereo pair writes the same keys with suffixes ``_1`` and ``_2`` and adds ``R`` (3x3) and ``T``
(3x1, **metres**) with OpenCV's ``stereoCalibrate`` meaning: ``p_cam2 = R p_cam1 + T``, i.e.
``T_cam2_cam1``. Numbers are written with Python's shortest round-trip repr, so
``cv2.FileStorage`` reads back exactly the float64 values of the result. A pinhole camera is
written with 5 zero distortion coefficients (OpenCV's plain ``calibrateCamera`` layout; the
same projection).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.atomic import write_text_atomic
from jcalib.io.export._common import (checked_export, comment_text, exact_float, lens_setting_lines, pick_camera,
                                      provenance_lines)
from jcalib.io.result import CameraResult, ResultFile, load_result

__all__ = ["OPENCV_MODELS", "opencv_yaml", "write_opencv_yaml"]

#: Lens models an OpenCV reader represents (``fisheye``: cv2.fisheye's ``D``).
OPENCV_MODELS = ("pinhole", "opencv4", "opencv5", "opencv8", "opencv12", "opencv14", "fisheye")


def _matrix(key: str, values: np.ndarray) -> list[str]:
    rows, cols = values.shape
    data = ", ".join(exact_float(v) for v in values.ravel())
    return [
        f"{key}: !!opencv-matrix",
        f"   rows: {rows}",
        f"   cols: {cols}",
        "   dt: d",
        f"   data: [ {data} ]",
    ]


def _camera(name: str, cam: CameraResult, suffix: str) -> list[str]:
    if cam.model not in OPENCV_MODELS:
        raise BadInputError(
            f"camera '{name}' has the {cam.model} lens model, which OpenCV cannot read; convert it first, e.g. "
            "jcalib convert RESULT --to opencv8 --fix k4,k5,k6 -o CONVERTED (prints the approximation error)")
    dist = cam.dist if cam.dist.size else np.zeros(5)
    return [
        f'camera_name{suffix}: "{name}"',
        f'camera_model{suffix}: "{cam.model}"',
        f"image_width{suffix}: {cam.image_size[0]}",
        f"image_height{suffix}: {cam.image_size[1]}",
        *_matrix(f"camera_matrix{suffix}", cam.K),
        *_matrix(f"distortion_coefficients{suffix}", dist[None, :]),
    ]


def _check_name(name: str) -> None:
    if any(c in name for c in '"\\') or comment_text(name) != name:
        raise BadInputError(
            "camera: a camera id for OpenCV YAML must not contain quotes, backslashes, control or "
            f"line-break characters, got {name!r}"
        )


def opencv_yaml(result: ResultFile, cameras: str | Sequence[str] | None = None) -> str:
    """The OpenCV YAML text of one camera or of a stereo pair.

    Args:
        result: the calibration result.
        cameras: one camera id, or two ids ``(first, second)`` for a stereo pair; None = the
            result's only camera, or its two cameras as a pair (in the result's order).

    Returns:
        The file's text (``%YAML:1.0`` header, ends with a newline).

    Raises:
        BadInputError: unknown camera; more than two cameras and none named; a pair whose
            relative pose cannot be formed from the result's transforms (``T_cam2_cam1``,
            ``T_cam1_cam2``, or ``T_x_cam1`` and ``T_x_cam2`` from one rigid frame ``x``).
    """
    if cameras is None:
        names = list(result.cameras)
        if len(names) > 2 or not names:
            raise BadInputError(
                f"cameras: the result has {len(names)} cameras ({', '.join(names) or 'none'}); name "
                "one camera or a stereo pair to export"
            )
    elif isinstance(cameras, str):
        names = [pick_camera(result, cameras)]
    else:
        names = [pick_camera(result, c) for c in cameras]
        if len(names) not in (1, 2) or len(set(names)) != len(names):
            raise BadInputError(
                f"cameras: expected one camera id or two different ids, got {list(cameras)}"
            )
    for name in names:
        _check_name(name)

    lines = ["%YAML:1.0", "---"]
    lines += [f"# {line}" for line in provenance_lines(result)]
    lines += [f"# {line}" for name in names for line in lens_setting_lines(result, name)]
    if len(names) == 1:
        lines += _camera(names[0], result.cameras[names[0]], "")
    else:
        first, second = names
        T_2_1 = result.transform_between(second, first)
        lines.append(
            f"# stereo pair: R, T map points of {comment_text(first)} into {comment_text(second)} "
            "(p2 = R p1 + T); T in metres"
        )
        lines += _camera(first, result.cameras[first], "_1")
        lines += _camera(second, result.cameras[second], "_2")
        lines += _matrix("R", T_2_1[:3, :3])
        lines += _matrix("T", T_2_1[:3, 3:4])
    return checked_export("\n".join(lines) + "\n", "opencv")


def write_opencv_yaml(
    result: ResultFile | str | os.PathLike,
    path: str | os.PathLike,
    cameras: str | Sequence[str] | None = None,
) -> Path:
    """Write :func:`opencv_yaml` of ``result`` (a :class:`ResultFile` or a path) to ``path`` atomically."""
    return write_text_atomic(path, opencv_yaml(load_result(result), cameras))
