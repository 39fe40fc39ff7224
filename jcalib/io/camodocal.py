"""Read the pose-pair files of camodocal's hand-eye tool (``jhu-lcsr/handeye_calib_camodocal``).

``TransformPairsInput.yml`` (OpenCV ``FileStorage``): ``frameCount`` and, per pair ``i``, ``T1_i``
(robot: base -> arm tip) and ``T2_i`` (tracker: camera -> marker), 4x4 in metres.
``CalibratedTransform.yml``: the tool's answer, e.g. ``ArmTipToMarkerTagTransform`` (4x4, m).
Both feed :func:`jcalib.problems.handeye_pairs.calibrate_hand_eye_pairs`.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from jcalib.errors import BadInputError

__all__ = ["read_calibrated_transform", "read_transform_pairs"]


def _open(path: str | os.PathLike) -> cv2.FileStorage:
    path = Path(path)
    if not path.is_file():
        raise BadInputError(f"{path}: no such file (expected a camodocal YAML file)")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise BadInputError(f"{path}: not an OpenCV FileStorage YAML file")
    return fs


def _matrix(fs: cv2.FileStorage, key: str, path) -> np.ndarray:
    m = fs.getNode(key).mat()
    if m is None or np.shape(m) != (4, 4):
        raise BadInputError(f"{path}: {key}: expected a 4x4 matrix, got {None if m is None else np.shape(m)}")
    return np.asarray(m, np.float64)


def read_transform_pairs(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """``(T1 (N, 4, 4), T2 (N, 4, 4))`` from a camodocal ``TransformPairsInput.yml``, metres."""
    fs = _open(path)
    try:
        n = int(fs.getNode("frameCount").real())
        if n < 1:
            raise BadInputError(f"{path}: frameCount: got {n}, expected at least one pair")
        T1 = np.stack([_matrix(fs, f"T1_{i}", path) for i in range(n)])
        T2 = np.stack([_matrix(fs, f"T2_{i}", path) for i in range(n)])
    finally:
        fs.release()
    return T1, T2


def read_calibrated_transform(path: str | os.PathLike, key: str = "ArmTipToMarkerTagTransform") -> np.ndarray:
    """The ``(4, 4)`` transform ``key`` of a camodocal ``CalibratedTransform.yml``, metres."""
    fs = _open(path)
    try:
        return _matrix(fs, key, path)
    finally:
        fs.release()
