"""AprilTag targets in the cell spec, and target files (Kalibr's target YAML) named by ``targets.<id>.file``."""

import numpy as np
import pytest
import yaml

from jcalib.errors import BadInputError
from jcalib.geometry.apriltags import AprilGrid, AprilTag
from jcalib.geometry.targets import Checkerboard
from jcalib.io.cell import cell_to_dict, load_cell, parse_cell
from jcalib.io.target_files import kalibr_target_entry

#: Kalibr's aprilgrid.yaml as its wiki and kalibr_create_target_pdf write it (quoted type, comments)
KALIBR_APRILGRID = """\
target_type: 'aprilgrid' #gridtype
tagCols: 6               #number of apriltags
tagRows: 6               #number of apriltags
tagSize: 0.088           #size of apriltag, edge to edge [m]
tagSpacing: 0.3          #ratio of space between tags to tagSize
"""
KALIBR_CHECKERBOARD = """\
target_type: 'checkerboard' #gridtype
targetCols: 6               #number of internal chessboard corners
targetRows: 7               #number of internal chessboard corners
rowSpacingMeters: 0.06      #size of one chessboard square [m]
colSpacingMeters: 0.06      #size of one chessboard square [m]
"""


def _cell(targets: dict) -> dict:
    return {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
            "targets": targets, "robot": {}}


def test_apriltag_targets_in_the_cell_spec():
    cell = parse_cell(_cell({
        "grid": {"type": "aprilgrid", "family": "tag36h11", "cols": 6, "rows": 6, "tag_size": 0.088,
                 "tag_spacing": 0.3, "mount": "base", "warp": True},
        "tag": {"type": "apriltag", "id": 10, "size": 0.048, "mount": "base"},
    }))
    assert cell.targets["grid"].geometry() == AprilGrid(6, 6, 0.088, 0.3) and cell.targets["grid"].warp
    assert cell.targets["tag"].geometry() == AprilTag(10, 0.048)
    again = parse_cell(cell_to_dict(cell))
    assert again.targets["grid"].geometry() == cell.targets["grid"].geometry()


@pytest.mark.parametrize("entry, words", [
    ({"type": "aprilgrid", "cols": 6, "rows": 6, "tag_size": 88, "tag_spacing": 0.3}, "millimetres"),
    ({"type": "aprilgrid", "cols": 6, "rows": 6, "tag_size": 0.088, "tag_spacing": 30}, "tag_spacing"),
    ({"type": "aprilgrid", "cols": 6, "rows": 6, "tag_size": 0.088}, "tag_spacing"),
    ({"type": "apriltag", "id": 3, "size": 0.05, "family": "tag36h10"}, "family"),
    ({"type": "apriltag", "id": 3, "size": 0.05, "square": 0.03}, "square"),
    ({"type": "aprilgrid", "cols": 30, "rows": 30, "tag_size": 0.01, "tag_spacing": 0.3}, "587"),
])
def test_bad_apriltag_entries_are_named(entry, words):
    with pytest.raises(BadInputError, match=words):
        parse_cell(_cell({"board": entry}))


def test_kalibr_target_yaml_as_a_target_file(tmp_path):
    (tmp_path / "targets").mkdir()
    (tmp_path / "targets" / "april_6x6.yaml").write_text(KALIBR_APRILGRID)
    (tmp_path / "checker.yaml").write_text(KALIBR_CHECKERBOARD)
    spec = _cell({"grid": {"file": "targets/april_6x6.yaml", "mount": "base"},
                  "board": {"file": str(tmp_path / "checker.yaml")}})
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(spec))
    cell = load_cell(tmp_path / "cell.yaml")  # relative to the cell spec's folder, not the working one
    assert cell.targets["grid"].geometry() == AprilGrid(6, 6, 0.088, 0.3, "tag36h11")
    assert cell.targets["grid"].mount == "base"
    assert cell.targets["board"].geometry() == Checkerboard(6, 7, 0.06) and cell.targets["board"].mount == "free"
    written = cell_to_dict(cell)["targets"]["grid"]  # the geometry itself, not the file name
    assert "file" not in written and written["tag_size"] == 0.088 and written["type"] == "aprilgrid"
    np.testing.assert_allclose(cell.targets["grid"].geometry().points[5], [1.3 * 0.088 + 0.088, 0.0, 0.0])  # tag 1, BR


def test_a_jcalib_target_entry_file(tmp_path):
    (tmp_path / "tag.yaml").write_text(yaml.safe_dump({"type": "apriltag", "id": 7, "size": 0.05}))
    cell = parse_cell(_cell({"tag": {"file": "tag.yaml", "mount": "base"}}), base_dir=tmp_path)
    assert cell.targets["tag"].geometry() == AprilTag(7, 0.05)


@pytest.mark.parametrize("content, entry, words", [
    (KALIBR_APRILGRID, {"file": "t.yaml", "tag_size": 0.09}, "not both"),
    ("target_type: circlegrid\ntargetCols: 4\ntargetRows: 5\nspacingMeters: 0.02\n", {"file": "t.yaml"},
     "type: circles"),
    ("target_type: checkerboard\ntargetCols: 6\ntargetRows: 7\nrowSpacingMeters: 0.06\ncolSpacingMeters: 0.05\n",
     {"file": "t.yaml"}, "differ"),
    ("target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\n", {"file": "t.yaml"}, "tagSpacing"),
    ("target_type: aprilgrid\ntagCols: six\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n", {"file": "t.yaml"},
     "tagCols must be an integer"),
    ("type: apriltag\nid: 3\nsize: 0.05\nmount: base\n", {"file": "t.yaml"}, "belong in the cell spec"),
    ("just text\n", {"file": "t.yaml"}, "Kalibr target YAML"),
    (KALIBR_APRILGRID, {"file": "missing.yaml"}, "does not exist"),
])
def test_bad_target_files_are_named(tmp_path, content, entry, words):
    (tmp_path / "t.yaml").write_text(content)
    with pytest.raises(BadInputError, match=words):
        parse_cell(_cell({"grid": entry}), base_dir=tmp_path)


def test_kalibr_entry_types():
    with pytest.raises(BadInputError, match="expected aprilgrid or checkerboard"):
        kalibr_target_entry({"target_type": "assymetric_aprilgrid"}, "x")
