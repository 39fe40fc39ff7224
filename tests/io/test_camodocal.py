"""camodocal pose-pair files: read back what cv2.FileStorage wrote, refuse malformed files."""

import cv2
import numpy as np
import pytest

from jcalib.errors import BadInputError
from jcalib.io.importers.opencv_pairs import read_calibrated_transform, read_transform_pairs


def _write(path, mats: dict, count=None):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if count is not None:
        fs.write("frameCount", count)
    for k, m in mats.items():
        fs.write(k, m)
    fs.release()


def test_pairs_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    T1, T2 = rng.standard_normal((3, 4, 4)), rng.standard_normal((3, 4, 4))
    _write(tmp_path / "p.yml", {**{f"T1_{i}": T1[i] for i in range(3)}, **{f"T2_{i}": T2[i] for i in range(3)}}, 3)
    a, b = read_transform_pairs(tmp_path / "p.yml")
    np.testing.assert_array_equal(a, T1)
    np.testing.assert_array_equal(b, T2)
    _write(tmp_path / "c.yml", {"ArmTipToMarkerTagTransform": T1[0]})
    np.testing.assert_array_equal(read_calibrated_transform(tmp_path / "c.yml"), T1[0])


def test_bad_files_are_named(tmp_path):
    with pytest.raises(BadInputError, match="no such file"):
        read_transform_pairs(tmp_path / "missing.yml")
    _write(tmp_path / "p.yml", {"T1_0": np.eye(4)}, 1)  # T2_0 missing
    with pytest.raises(BadInputError, match="T2_0 is missing"):
        read_transform_pairs(tmp_path / "p.yml")
