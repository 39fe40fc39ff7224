"""export_result: the CLI's entry point over all formats."""

from __future__ import annotations

from pathlib import Path

import pytest

from jcalib.errors import BadInputError
from jcalib.io.export import EXPORT_FORMATS, export_result

GOLDEN = Path(__file__).parent / "golden"

# (format, options, golden file written by the per-format tests)
CASES = [
    ("opencv", {"cameras": "cam0"}, "opencv_cam0.yaml"),
    ("opencv", {}, "opencv_stereo.yaml"),
    ("ros", {"camera": "cam0", "camera_name": None}, "ros_cam0.yaml"),
    ("rapid", {"wobjs": ["board"]}, "abb_jcalib_cal.mod"),
    ("krl", {"tools": {"needle": 3, "gripper": None}, "bases": ["board"]}, "kuka_config.dat"),
]


@pytest.mark.parametrize("fmt, options, golden", CASES)
def test_each_format_writes_its_golden_text(fmt, options, golden, tmp_path):
    out = export_result(GOLDEN / "result.json", fmt, tmp_path / "out" / golden, **options)
    assert out.read_text(encoding="utf-8") == (GOLDEN / golden).read_text(encoding="utf-8")
    assert [p.name for p in out.parent.iterdir()] == [golden]  # atomic: no temporary file left


def test_formats_and_bad_requests(tmp_path):
    assert sorted(EXPORT_FORMATS) == ["kinematics", "krl", "opencv", "rapid", "ros", "ur-calibration", "urdf"]
    with pytest.raises(
        BadInputError, match="format: expected one of opencv, ros, rapid, krl, kinematics, urdf, ur-calibration, got 'sdf'"
    ):
        export_result(GOLDEN / "result.json", "sdf", tmp_path / "x")
    with pytest.raises(
        BadInputError, match="takes the options tools, bases, orientations; got unknown option.*wobjs"
    ):
        export_result(GOLDEN / "result.json", "krl", tmp_path / "x", wobjs=["board"])
    with pytest.raises(BadInputError, match="does not exist"):
        export_result(tmp_path / "missing.json", "krl", tmp_path / "x")
    assert not (tmp_path / "x").exists()
