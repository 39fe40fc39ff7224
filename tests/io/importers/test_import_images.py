"""Image data sets of other tools -> jcalib session -> detect --session + calibrate, against the rendered truth.

Each test writes the source tool's files in its exact layout (industrial_calibration's cal_data.yaml +
images/ + poses/*.yaml; calibration-rs's dataset.toml + image glob + RobotPosesVec.txt), imports them
with the CLI and calibrates the session without touching it.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import yaml
from importer_roundtrip import assert_pose_near, cli, detect_and_calibrate

from jcalib.geometry.se3 import invert, quat_from_matrix
from jcalib.io.cell import load_cell
from jcalib.io.importers import import_session
from jcalib.io.importers.calibration_rs import rotation_from_values
from jcalib.errors import BadInputError
from jcalib.io.session import read_session


def _xyzq(T):
    w, x, y, z = quat_from_matrix(T[:3, :3])
    return {"x": float(T[0, 3]), "y": float(T[1, 3]), "z": float(T[2, 3]), "qx": float(x), "qy": float(y),
            "qz": float(z), "qw": float(w)}


def write_industrial_calibration(root, data, *, static_camera=False, finder=None, intrinsics=True):
    """cal_data.yaml + images/N.png + poses/N.yaml as the tool's examples/data/test_set_charuco holds them."""
    (root / "images").mkdir(parents=True)
    (root / "poses").mkdir()
    entries = []
    for k, (img, T) in enumerate(zip(data.images, data.T_base_flange, strict=True)):
        cv2.imwrite(str(root / "images" / f"{k}.png"), img)
        (root / "poses" / f"{k}.yaml").write_text(yaml.safe_dump(_xyzq(T), sort_keys=False))
        entries.append({"pose": f"poses/{k}.yaml", "image": f"images/{k}.png"})
    K = data.K
    cfg = {"data": entries}
    if intrinsics:
        cfg["intrinsics"] = {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])}
    cfg["camera_mount_to_camera_guess"] = {"x": 0.0, "y": 0.0, "z": 0.0, "qx": 0.0, "qy": 0.0, "qz": 0.0, "qw": 1.0}
    cfg["target_mount_to_target_guess"] = {"x": 1.0, "y": 0.0, "z": 0.0, "qx": 0.0, "qy": 0.0, "qz": 0.0, "qw": 1.0}
    cfg["homography_threshold"] = 2.0
    if static_camera is not None:
        cfg["static_camera"] = static_camera
    cfg["target_finder"] = finder or {"type": "CharucoGridTargetFinder", "rows": 7, "cols": 5, "chessboard_dim": 0.03,
                                      "aruco_marker_dim": 0.022, "dictionary": 10}
    (root / "cal_data.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    return root / "cal_data.yaml"


def test_industrial_calibration_charuco_round_trip(charuco_set, tmp_path):
    src = write_industrial_calibration(tmp_path / "src", charuco_set)
    code, text = cli("import", "industrial-calibration", src.parent, "--out", tmp_path / "sess")
    assert code == 0, text
    meta, stations = read_session(tmp_path / "sess")
    cam = meta["cell"]["cameras"]["cam0"]
    assert cam["mount"] == "flange" and cam["fix"] == ["fx", "fy", "cx", "cy"]  # the tool holds its intrinsics
    assert meta["cell"]["targets"]["board"] == {"type": "charuco", "squares_x": 5, "squares_y": 7, "square": 0.03,
                                                "marker": 0.022, "dictionary": "DICT_6X6_250", "legacy": True,
                                                "mount": "base"}
    np.testing.assert_allclose([s["T_base_flange"] for s in stations], charuco_set.T_base_flange, atol=1e-12)
    # PNG sources are copied byte for byte
    assert (tmp_path / "sess" / stations[3]["images"]["cam0"]).read_bytes() == (src.parent / "images/3.png").read_bytes()
    assert meta["imported_from"]["guesses"]["target_mount_to_target_guess"]["x"] == 1.0
    res = detect_and_calibrate(tmp_path / "sess", tmp_path)
    t = res["transforms"]["T_flange_cam0"]
    assert_pose_near(t["matrix"], t["covariance"], charuco_set.T_flange_cam)


def test_calibration_rs_round_trip(chessboard_set, tmp_path):
    root = tmp_path / "kuka_like"
    root.mkdir()
    for k, img in enumerate(chessboard_set.images):  # 1.png .. 10.png: natural sort, not 1, 10, 2
        cv2.imwrite(str(root / f"{k + 1}.png"), img)
    (root / "RobotPosesVec.txt").write_text(
        "".join("\t".join(f"{v:.12f}" for v in T.reshape(-1)) + "\n" for T in chessboard_set.T_base_flange))
    (root / "dataset.toml").write_text("""# single-camera eye-in-hand data set, as data/kuka_1/dataset.toml
version = 1
topology = "single_cam_handeye"
description = "rendered"

[[cameras]]
id = "cam0"
images = { kind = "glob", pattern = "*.png" }

[target]
kind = "chessboard"
rows = 6
cols = 8
square_size_m = 0.02

[robot_poses]
path = "RobotPosesVec.txt"
format = "rowmajor4x4"

[pose_pairing]
kind = "by_index"

[pose_convention]
transform = "t_base_tcp"
rotation_format = "matrix4x4_row_major"
translation_units = "m"
""")
    with pytest.raises(BadInputError, match="--mount"):  # the manifest does not say eye-in-hand or eye-to-hand
        import_session("calibration-rs", root, tmp_path / "refused")
    code, text = cli("import", "calibration-rs", root / "dataset.toml", "--out", tmp_path / "sess", "--mount", "flange",
                     "--option", "camera_model=pinhole")
    assert code == 0, text
    meta, stations = read_session(tmp_path / "sess")
    assert [s["source"]["view"] for s in stations] == [str(i) for i in range(10)]
    np.testing.assert_allclose([s["T_base_flange"] for s in stations], chessboard_set.T_base_flange, atol=1e-9)
    res = detect_and_calibrate(tmp_path / "sess", tmp_path)
    t = res["transforms"]["T_flange_cam0"]
    assert_pose_near(t["matrix"], t["covariance"], chessboard_set.T_flange_cam)


def test_calibration_rs_pose_conventions_csv_token_pairing(chessboard_set, tmp_path):
    """CSV rows of T_tcp_base in mm with quaternions (x y z w) / ZYX Euler, paired by filename token."""
    root = tmp_path / "ds"
    root.mkdir()
    T = chessboard_set.T_base_flange[:4]
    rows = ["view,tx,ty,tz,qx,qy,qz,qw"]
    for k in (2, 0, 3, 1):  # file order differs from the view order
        Ti = invert(T[k])
        w, x, y, z = (float(v) for v in quat_from_matrix(Ti[:3, :3]))
        rows.append(f"{k:04d},{float(Ti[0, 3]) * 1e3!r},{float(Ti[1, 3]) * 1e3!r},{float(Ti[2, 3]) * 1e3!r},{x!r},{y!r},{z!r},{w!r}")
        cv2.imwrite(str(root / f"Cam0_{k:04d}.png"), chessboard_set.images[k])
    (root / "poses.csv").write_text("\n".join(rows) + "\n")
    manifest = """version = 1
topology = "single_cam_handeye"
[[cameras]]
id = "left"
images = { kind = "glob", pattern = "Cam0_*.png" }
[target]
kind = "chessboard"
rows = 6
cols = 8
square_size_m = 0.02
[robot_poses]
path = "poses.csv"
format = "csv"
columns = { pose_id = "view", tx = "tx", ty = "ty", tz = "tz", rotation = ["qx", "qy", "qz", "qw"] }
[pose_pairing]
kind = "shared_filename_token"
regex = '^Cam\\d+_(?<view>\\d+)\\.png$'
group = "view"
[pose_convention]
transform = "t_tcp_base"
rotation_format = "quat_xyzw"
translation_units = "mm"
"""
    (root / "dataset.toml").write_text(manifest)
    s = import_session("calibration-rs", root, tmp_path / "sess", mount="base")
    assert s.cameras == ("left",)
    meta, stations = read_session(tmp_path / "sess")
    assert meta["cell"]["cameras"]["left"]["mount"] == "base" and meta["cell"]["targets"]["board"]["mount"] == "flange"
    assert [st["source"]["view"] for st in stations] == ["0000", "0001", "0002", "0003"]
    np.testing.assert_allclose([st["T_base_flange"] for st in stations], T, atol=1e-12)
    # the Euler conventions: intrinsic, composed in the named order
    a = np.deg2rad([30.0, -20.0, 10.0])
    Rx = cv2.Rodrigues(np.array([a[0], 0, 0]))[0]
    Ry = cv2.Rodrigues(np.array([0, a[1], 0]))[0]
    Rz = cv2.Rodrigues(np.array([0, 0, a[2]]))[0]
    np.testing.assert_allclose(rotation_from_values("euler_xyz_deg", np.array([30.0, -20.0, 10.0]), "t"), Rx @ Ry @ Rz, atol=1e-12)
    np.testing.assert_allclose(rotation_from_values("euler_zyx_rad", a[::-1].copy(), "t"), Rz @ Ry @ Rx, atol=1e-12)
    # a quaternion in the wrong order is refused, not normalised into another rotation
    (root / "poses.csv").write_text("view,tx,ty,tz,qx,qy,qz,qw\n0000,0,0,0,1,1,1,1\n")
    with pytest.raises(BadInputError, match="norm"):
        import_session("calibration-rs", root, tmp_path / "sess2", mount="base")


def test_industrial_calibration_refuses_what_it_cannot_know(charuco_set, tmp_path):
    small = type(charuco_set)(charuco_set.images[:2], charuco_set.T_base_flange[:2], charuco_set.T_flange_cam,
                              charuco_set.T_base_target, charuco_set.K, charuco_set.target)
    src = write_industrial_calibration(tmp_path / "a", small, static_camera=None)
    with pytest.raises(BadInputError, match="static_camera"):
        import_session("industrial-calibration", src, tmp_path / "s1")
    src = write_industrial_calibration(tmp_path / "b", small, static_camera=True)
    with pytest.raises(BadInputError, match="--mount flange"):
        import_session("industrial-calibration", src, tmp_path / "s2", mount="flange")
    aruco = {"type": "ArucoGridTargetFinder", "rows": 5, "cols": 5, "aruco_marker_dim": 0.03, "marker_gap": 0.01,
             "dictionary": 0}
    src = write_industrial_calibration(tmp_path / "c", small, finder=aruco)
    with pytest.raises(BadInputError, match="GridBoard"):
        import_session("industrial-calibration", src, tmp_path / "s3")
    code, text = cli("import", "industrial-calibration", src, "--out", tmp_path / "s4", "--option", "colour=red")
    assert code == 2 and "unknown option" in text and "intrinsics" in text
    # the modified circle grid and a static camera: target on the flange, intrinsics as start values
    circles = {"type": "industrial_calibration::ModifiedCircleGridTargetFinderPlugin", "rows": 10, "cols": 10,
               "spacing": 0.0254, "circle_detector_params": {"minThreshold": 20}}
    src = write_industrial_calibration(tmp_path / "d", small, static_camera=True, finder=circles)
    import_session("industrial-calibration", src, tmp_path / "s5", intrinsics="initial")
    cell = yaml.safe_load((tmp_path / "s5" / "cell.yaml").read_text())
    assert cell["cameras"]["cam0"]["mount"] == "base" and "fix" not in cell["cameras"]["cam0"]
    assert cell["targets"]["board"] == {"type": "circles", "cols": 10, "rows": 10, "spacing": 0.0254,
                                        "origin_dot": "bottom_left", "mount": "flange"}
    assert load_cell(tmp_path / "s5" / "cell.yaml").target("board").geometry().origin_index == 90  # bottom left
    assert json.loads((tmp_path / "s5" / "session.json").read_text())["imported_from"]["format"] == "industrial-calibration"
