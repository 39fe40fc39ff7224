"""No field of a result can start a new line in a RAPID / KRL / ROS / OpenCV export (issue 17), and
independent readers read every export: OpenCV's ``cv2.FileStorage`` every OpenCV YAML export, and
``cameramodels`` (a third-party reader of ROS ``camera_info`` YAML) plus the field layout ROS's
``camera_calibration_parsers`` reads, every ROS export (issue 18).
"""

from __future__ import annotations

import copy

import cv2
import numpy as np
import pytest
import yaml
from fuzz_files import result

from jcalib.errors import BadInputError
from jcalib.io.export import export_text
from jcalib.io.result import ResultFile
from jcalib.io.schema import validate_result_document

#: Every ASCII control, DEL, every C1 control, and the Unicode line / paragraph separators and format
#: characters that some reader (YAML 1.1, Python, a Latin-1 controller) takes as a line break.
CONTROL = [chr(i) for i in range(32)] + ["\x7f"] + [chr(i) for i in range(0x80, 0xA0)] + [
    "\u2028", "\u2029", "\ufeff", "\u200b", "\u202e", "\u0085"]
PAYLOAD = "PERS tooldata evil := [TRUE,[[0,0,0],[1,0,0,0]],[1,[0,0,0],[1,0,0,0],0,0,0]];"


def _set(doc: dict, field: str, value: str) -> dict:
    """``doc`` with the string field ``field`` set to ``value`` (keys are renamed)."""
    d = copy.deepcopy(doc)
    if field == "camera name":
        d["cameras"][value] = d["cameras"].pop("cam_hand")
        d["transforms"][f"T_flange_{value}"] = d["transforms"].pop("T_flange_cam_hand")
    elif field == "tool name":
        d["transforms"][f"T_flange_{value}"] = d["transforms"].pop("T_flange_torch")
    elif field == "work object name":
        d["transforms"][f"T_base_{value}"] = d["transforms"].pop("T_base_board")
    elif field == "point name":
        d["points"][value] = d["points"].pop("divot")
    elif field == "point frame":
        d["points"]["divot"]["frame"] = value
    elif field == "stats text":
        d["stats"]["note"] = value
    elif field == "option text":
        d["provenance"]["options"]["loss"] = value
    elif field == "extra key":
        d["comment"] = value
    else:
        d["provenance"][field] = value
    return d


FIELDS = ["jcalib_version", "input_hash", "created", "camera name", "tool name", "work object name",
          "point name", "point frame", "stats text", "option text", "extra key"]
FORMATS = [("rapid", {}), ("krl", {}), ("opencv", {"cameras": None}), ("ros", {"camera": None})]


def _load(doc: dict) -> ResultFile | None:
    try:
        validate_result_document(doc, "result.json")
        return ResultFile.from_dict(doc, "result.json")
    except BadInputError:
        return None


def _exports(res: ResultFile) -> list[str]:
    texts = []
    for fmt, options in FORMATS:
        for cam in res.cameras if fmt in ("opencv", "ros") else [None]:
            opts = {k: cam for k in options}
            try:
                texts.append(export_text(res, fmt, **opts))
            except BadInputError:
                pass  # refused: nothing written
    return texts


BASE_LINES = {i: len(t.split("\n")) for i, t in enumerate(_exports(ResultFile.from_dict(result())))}


@pytest.mark.parametrize("field", FIELDS)
def test_no_field_of_a_result_starts_a_line_in_any_export(field):
    accepted = exported = 0
    for c in CONTROL:
        res = _load(_set(result(), field, f"x{c}{PAYLOAD}{c}y"))
        if res is None:
            continue
        accepted += 1
        texts = _exports(res)
        assert len(texts) == len(BASE_LINES), (field, repr(c))  # no export refused for free text
        for i, text in enumerate(texts):
            exported += 1
            assert len(text.split("\n")) == BASE_LINES[i], (field, repr(c))  # no line added
            assert c == "\n" or c not in text, (field, repr(c))
            for line in text.split("\n"):
                stripped = line.lstrip()
                assert "evil" not in line or stripped.startswith(("!", ";", "#")), (field, repr(c), line)
    # free-text fields are accepted (and escaped); names with control characters are refused at load
    if field in ("jcalib_version", "input_hash", "stats text", "option text", "extra key"):
        assert accepted == len(CONTROL) and exported > 0
    if field.endswith("name") or field == "point frame":
        assert accepted == 0


def test_export_line_counts_do_not_change_with_hostile_provenance():
    doc = result()
    doc["provenance"]["jcalib_version"] = "\n".join(["1"] + [PAYLOAD] * 3) + "\r\x85\u2028"
    texts = _exports(ResultFile.from_dict(doc))
    assert {i: len(t.split("\n")) for i, t in enumerate(texts)} == BASE_LINES


def test_names_given_as_export_options_are_checked():
    res = ResultFile.from_dict(result())
    for fmt, options in [("rapid", {"module": "m\nPROC evil()"}), ("rapid", {"tools": {"torch": "t\nx"}}),
                         ("rapid", {"wobjs": {"board": "b;\nx"}}), ("ros", {"camera": "cam_hand", "camera_name": "a\nb"}),
                         ("krl", {"tools": {"torch": 1}, "bases": {"board": 1}})]:
        try:
            text = export_text(res, fmt, **options)
        except BadInputError:
            continue
        assert "\r" not in text and all("evil" not in line for line in text.split("\n"))


# ---------------------------------------------------------------------------- independent readers

MODELS = {
    "pinhole": [],
    "opencv4": [-0.1, 0.02, 0.001, -0.002],
    "opencv5": [-0.1, 0.02, 0.001, -0.002, 0.003],
    "opencv8": [-0.1, 0.02, 0.001, -0.002, 0.003, 0.01, -0.02, 0.004],
    "opencv12": [-0.1, 0.02, 0.001, -0.002, 0.003, 0.01, -0.02, 0.004, 1e-4, -2e-4, 3e-4, -4e-4],
    "opencv14": [-0.1, 0.02, 0.001, -0.002, 0.003, 0.01, -0.02, 0.004, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    "fisheye": [0.01, -0.002, 0.0003, -0.00004],
}


def _hostile(model: str) -> dict:
    doc = result()
    doc["cameras"]["cam_hand"].update(model=model, dist=MODELS[model])
    doc["cameras"]["cam_hand"].pop("std")
    doc["cameras"]["cam_hand"]["K"][0][1] = 0.0
    doc["provenance"]["jcalib_version"] = f"0.1\ncamera_matrix: !!opencv-matrix\r{PAYLOAD}\u2028"
    doc["provenance"]["input_hash"] = "sha256:\x00\x1b[2J"
    return doc


@pytest.mark.parametrize("model", list(MODELS))
def test_cv2_filestorage_reads_every_opencv_export_exactly(model, tmp_path):
    res = ResultFile.from_dict(_hostile(model))
    path = tmp_path / "cam.yaml"
    path.write_text(export_text(res, "opencv", cameras="cam_hand"))
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        cam = res.cameras["cam_hand"]
        np.testing.assert_array_equal(fs.getNode("camera_matrix").mat(), cam.K)
        dist = cam.dist if cam.dist.size else np.zeros(5)
        np.testing.assert_array_equal(fs.getNode("distortion_coefficients").mat().ravel(), dist)
        assert int(fs.getNode("image_width").real()) == 640 and int(fs.getNode("image_height").real()) == 480
        assert fs.getNode("camera_name").string() == "cam_hand"
        assert fs.getNode("camera_model").string() == model
    finally:
        fs.release()


def test_cv2_filestorage_reads_the_stereo_export(tmp_path):
    doc = _hostile("opencv5")
    doc["transforms"]["T_flange_cam_fixed"] = doc["transforms"].pop("T_base_cam_fixed")
    res = ResultFile.from_dict(doc)
    path = tmp_path / "stereo.yaml"
    path.write_text(export_text(res, "opencv", cameras=["cam_hand", "cam_fixed"]))
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        T_2_1 = res.transform_between("cam_fixed", "cam_hand")
        np.testing.assert_array_equal(fs.getNode("R").mat(), T_2_1[:3, :3])
        np.testing.assert_array_equal(fs.getNode("T").mat().ravel(), T_2_1[:3, 3])
        np.testing.assert_array_equal(fs.getNode("camera_matrix_1").mat(), res.cameras["cam_hand"].K)
        np.testing.assert_array_equal(fs.getNode("camera_matrix_2").mat(), res.cameras["cam_fixed"].K)
    finally:
        fs.release()


ROS_MODELS = {"pinhole": ("plumb_bob", 5), "opencv4": ("plumb_bob", 5), "opencv5": ("plumb_bob", 5),
              "opencv8": ("rational_polynomial", 8), "opencv14": ("rational_polynomial", 8),
              "fisheye": ("equidistant", 4)}
#: The keys ROS's camera_calibration_parsers (parse_yml.cpp) reads from a camera_info YAML file.
ROS_KEYS = {"image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
            "distortion_coefficients", "rectification_matrix", "projection_matrix"}


@pytest.mark.parametrize("model", list(ROS_MODELS))
def test_ros_camera_info_parsers_read_every_ros_export(model, tmp_path):
    from cameramodels import PinholeCameraModel

    res = ResultFile.from_dict(_hostile(model))
    cam = res.cameras["cam_hand"]
    path = tmp_path / "camera_info.yaml"
    path.write_text(export_text(res, "ros", camera="cam_hand"))
    # the fields and shapes camera_calibration_parsers reads (rows x cols == len(data))
    data = yaml.safe_load(path.read_text())
    assert set(data) == ROS_KEYS
    ros_model, n = ROS_MODELS[model]
    assert data["distortion_model"] == ros_model and data["camera_name"] == "cam_hand"
    for key, shape in (("camera_matrix", (3, 3)), ("distortion_coefficients", (1, n)),
                       ("rectification_matrix", (3, 3)), ("projection_matrix", (3, 4))):
        m = data[key]
        assert (m["rows"], m["cols"]) == shape and len(m["data"]) == shape[0] * shape[1], key
    np.testing.assert_array_equal(np.reshape(data["camera_matrix"]["data"], (3, 3)), cam.K)
    # an independent reader of the same layout (float32 inside: compared to 1e-6 relative)
    info = PinholeCameraModel.from_yaml_file(str(path))
    assert (info.width, info.height) == (640, 480)
    np.testing.assert_allclose(info.K, cam.K, rtol=1e-6)
    np.testing.assert_allclose(info.P, np.hstack([cam.K, np.zeros((3, 1))]), rtol=1e-6)
    np.testing.assert_allclose(info.R, np.eye(3), rtol=1e-6)
    padded = np.concatenate([cam.dist, np.zeros(max(0, n - cam.dist.size))])[:n]
    np.testing.assert_allclose(info.D, padded, rtol=1e-6, atol=1e-12)
