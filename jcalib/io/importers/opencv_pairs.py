"""OpenCV ``FileStorage`` pose-pair files (camodocal's ``TransformPairsInput.yml``) -> session of pose pairs.

Layout (``jhu-lcsr/handeye_calib_camodocal``, read by :mod:`jcalib.io.camodocal`): ``frameCount`` and,
per pair ``i``, ``T1_i`` and ``T2_i`` (4x4 ``!!opencv-matrix``, metres). A ``CalibratedTransform.yml``
beside it (the tool's answer) is recorded in ``session.json`` (``imported_from.reference``), not used.

Conventions (camodocal's ROS node): ``T1_i`` is the pose of the robot's end effector in its base
(``p_base = T1 p_ee``) = ``T_base_flange``; ``T2_i`` is the pose of the tracked marker in the camera
(``p_cam = T2 p_marker``) = ``T_cam_target``. Whether the camera or the marker rides on the robot is not
in the file: ``--mount`` is required.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from jcalib.io.camodocal import read_calibrated_transform, read_transform_pairs
from jcalib.io.importers.common import (
    cell_entries_for_mount,
    check_options,
    pose_from_matrix,
    pose_pair_session,
    resolve_source,
)

FORMAT = "opencv-pairs"
OPTIONS = {"camera": "camera id (default cam0)", "target": "marker id (default marker)"}


def import_source(source: str | os.PathLike, out: str | os.PathLike, *, mount: str | None = None, **options: Any):
    """Import a camodocal / OpenCV FileStorage pose-pair file (or its folder) into session ``out``.

    Raises:
        BadInputError: not a pose-pair file, a matrix that is not a pose, or no ``mount``.
    """
    check_options(FORMAT, options, OPTIONS)
    path = resolve_source(source, "TransformPairsInput.yml", f"import {FORMAT}")
    cell_entries_for_mount(mount, FORMAT, "the pose-pair file does not say whether the camera or the marker "
                                          "rides on the robot")
    T1, T2 = read_transform_pairs(path)
    pairs = [(pose_from_matrix(a, f"{path}: T1_{i}"), pose_from_matrix(b, f"{path}: T2_{i}"))
             for i, (a, b) in enumerate(zip(T1, T2, strict=True))]
    extra = None
    ref = path.parent / "CalibratedTransform.yml"
    if ref.is_file():
        extra = {"reference": {"file": ref.name, "ArmTipToMarkerTagTransform": np.asarray(
            read_calibrated_transform(ref)).tolist()}}
    return pose_pair_session(out, pairs, mount=mount, fmt=FORMAT, source=path,
                             conventions="T1_i = T_base_flange (p_base = T1 p_ee), T2_i = T_cam_target "
                                         "(p_cam = T2 p_marker), 4x4, m",
                             camera=str(options.get("camera", "cam0")), target=str(options.get("target", "marker")),
                             extra=extra)
