"""Export one camera as a ROS ``camera_info`` YAML file (``camera_calibration_parsers`` layout).

Keys: ``image_width``, ``image_height``, ``camera_name``, ``camera_matrix`` (3x3 K),
``distortion_model``, ``distortion_coefficients`` (1xn), ``rectification_matrix`` (3x3) and
``projection_matrix`` (3x4), each matrix as ``{rows, cols, data}`` in row-major order.

Distortion models (ROS ``sensor_msgs/distortion_models``):

- ``pinhole``, ``opencv4``, ``opencv5`` -> ``plumb_bob`` with 5 coefficients ``k1 k2 p1 p2 k3``
  (missing ones are 0: the same projection);
- ``opencv8`` -> ``rational_polynomial`` (8);
- ``opencv12`` / ``opencv14`` -> ``rational_polynomial`` only when the thin-prism and tilt
  coefficients (``s1..s4``, ``tx, ty``) are all exactly 0; ROS has no model for them otherwise;
- ``fisheye`` -> ``equidistant`` (``k1..k4``, cv2.fisheye's ``D``).

A monocular camera has no rectification: ``rectification_matrix`` is the identity and
``projection_matrix = [K | 0]`` (the undistorted image keeps the camera matrix K). Numbers use
the shortest exact float text, so a reader gets the result's float64 values back.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.atomic import write_text_atomic
from jcalib.io.export._common import (
    check_identifier,
    checked_export,
    comment_text,
    exact_float,
    lens_setting_lines,
    pick_camera,
    provenance_lines,
)
from jcalib.io.result import ResultFile, load_result

__all__ = ["ros_camera_info", "ros_distortion", "write_ros_camera_info"]

#: ROS ``camera_info_manager`` accepts camera names of letters, digits and ``_``.
_ROS_NAME = r"[A-Za-z0-9_]+"


def ros_distortion(model: str, dist: np.ndarray) -> tuple[str, np.ndarray]:
    """The ROS ``(distortion_model, coefficients)`` of a jcalib camera model and its ``dist``.

    Raises:
        BadInputError: a thin-prism/tilted model (``opencv12``/``opencv14``) with nonzero
            ``s1..s4``/``tx, ty``, which no ROS distortion model represents.
    """
    dist = np.asarray(dist, dtype=np.float64)
    if model == "fisheye":
        return "equidistant", dist
    if model in ("pinhole", "opencv4", "opencv5"):
        return "plumb_bob", np.concatenate([dist, np.zeros(5 - dist.size)])
    if model == "opencv8":
        return "rational_polynomial", dist
    if model in ("opencv12", "opencv14"):
        if np.any(dist[8:] != 0.0):
            raise BadInputError(
                f"camera model {model!r}: ROS camera_info has no distortion model for the thin-prism "
                f"and tilt coefficients s1..s4, tx, ty = {dist[8:].tolist()} (nonzero); calibrate "
                "with opencv8, or export to OpenCV YAML instead"
            )
        return "rational_polynomial", dist[:8]
    raise BadInputError(f"camera model {model!r} has no ROS distortion model; convert it first, e.g. jcalib convert "
                        "RESULT --to opencv8 --fix k4,k5,k6 -o CONVERTED (prints the approximation error)")


def _matrix(key: str, values: np.ndarray) -> list[str]:
    rows, cols = values.shape
    return [
        f"{key}:",
        f"  rows: {rows}",
        f"  cols: {cols}",
        f"  data: [{', '.join(exact_float(v) for v in values.ravel())}]",
    ]


def ros_camera_info(
    result: ResultFile, camera: str | None = None, camera_name: str | None = None
) -> str:
    """The ROS ``camera_info`` YAML text of one camera.

    Args:
        result: the calibration result.
        camera: the camera id; None = the result's only camera.
        camera_name: the ``camera_name`` written (letters, digits, ``_``; quoted so YAML never
            reads it as a number or a boolean); default the camera id.

    Raises:
        BadInputError: unknown camera, an invalid ``camera_name``, or a model ROS cannot represent.
    """
    camera = pick_camera(result, camera)
    name = check_identifier(
        camera if camera_name is None else camera_name, "camera_name", 256, _ROS_NAME
    )
    cam = result.cameras[camera]
    model, coeffs = ros_distortion(cam.model, cam.dist)
    P = np.concatenate([cam.K, np.zeros((3, 1))], axis=1)
    lines = [
        f"# {line}"
        for line in [f"jcalib camera '{comment_text(camera)}' (model {cam.model})", *provenance_lines(result),
                     *lens_setting_lines(result, camera)]
    ]
    lines += [
        f"image_width: {cam.image_size[0]}",
        f"image_height: {cam.image_size[1]}",
        f'camera_name: "{name}"',
        *_matrix("camera_matrix", cam.K),
        f"distortion_model: {model}",
        *_matrix("distortion_coefficients", coeffs[None, :]),
        *_matrix("rectification_matrix", np.eye(3)),
        *_matrix("projection_matrix", P),
    ]
    return checked_export("\n".join(lines) + "\n", "ros")


def write_ros_camera_info(
    result: ResultFile | str | os.PathLike,
    path: str | os.PathLike,
    camera: str | None = None,
    camera_name: str | None = None,
) -> Path:
    """Write :func:`ros_camera_info` of ``result`` (a :class:`ResultFile` or a path) atomically."""
    return write_text_atomic(path, ros_camera_info(load_result(result), camera, camera_name))
