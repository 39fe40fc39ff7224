"""ROS bags -> jcalib session: bags written with rosbags' own writers (ROS 2 sqlite3, ROS 1 .bag) hold
rendered images, camera_info and /tf (base_link -> link_6 moving, link_6 -> tool0 static), with the robot
moving between stations; the time-synchronisation rules pick the images taken at rest, and the ROS 2
session goes through detect --session + calibrate against the rendered truth."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from importer_roundtrip import assert_pose_near, cli, detect_and_calibrate

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import exp_so3, interpolate_pose, invert, make_pose, quat_from_matrix
from jcalib.io.importers import import_session
from jcalib.io.session import read_session

pytest.importorskip("rosbags")  # jcalib[ros]; in the dev extra, so present in every test run
from rosbags.typesys import Stores, get_typestore  # noqa: E402

T_LINK6_TOOL0 = make_pose(exp_so3(np.array([0.0, 0.0, 0.3])), np.array([0.0, 0.0, 0.08]))
SEC = 1_000_000_000


def _msgs(store):
    ts = get_typestore(store)
    ros1 = store == Stores.ROS1_NOETIC
    if ros1:  # rosbags' noetic store lacks tf2_msgs; its definition (tf2_msgs/TFMessage.msg) is one line
        from rosbags.typesys import get_types_from_msg

        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]

    def stamp(ns):
        return Time(sec=ns // SEC, nanosec=ns % SEC)

    def header(ns, frame):
        kw = {"seq": 0} if ros1 else {}
        return T["std_msgs/msg/Header"](**kw, stamp=stamp(ns), frame_id=frame)

    def tf(ns, parent, child, M):
        w, x, y, z = (float(v) for v in quat_from_matrix(M[:3, :3]))
        tr = T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=float(M[0, 3]), y=float(M[1, 3]), z=float(M[2, 3])),
            rotation=T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w))
        return T["geometry_msgs/msg/TransformStamped"](header=header(ns, parent), child_frame_id=child, transform=tr)

    def tfm(items):
        return T["tf2_msgs/msg/TFMessage"](transforms=items)

    def image(ns, img):
        return T["sensor_msgs/msg/Image"](header=header(ns, "camera"), height=img.shape[0], width=img.shape[1],
                                          encoding="mono8", is_bigendian=0, step=img.shape[1],
                                          data=np.ascontiguousarray(img).reshape(-1))

    def info(ns, K, size):
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        names = ("D", "K", "R", "P") if ros1 else ("d", "k", "r", "p")
        arrays = dict(zip(names, (np.zeros(5), K.reshape(-1), np.eye(3).reshape(-1),
                                  np.hstack([K, np.zeros((3, 1))]).reshape(-1)), strict=True))
        return T["sensor_msgs/msg/CameraInfo"](header=header(ns, "camera"), height=size[1], width=size[0],
                                               distortion_model="plumb_bob", **arrays, binning_x=0, binning_y=0, roi=roi)

    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    return ts, ser, tf, tfm, image, info


def write_bag(path, data, store, *, ros2: bool):
    """Robot at rest at each station for 1 s (tf at 100 Hz, one image in the middle), moving in between;
    one extra image while moving, which the rules must skip."""
    ts, ser, tf, tfm, image, info = _msgs(store)
    T_base_link6 = data.T_base_flange @ invert(T_LINK6_TOOL0)  # the flange is tool0
    if ros2:
        from rosbags.rosbag2 import Writer
        w = Writer(path, version=9)
    else:
        from rosbags.rosbag1 import Writer
        w = Writer(path)
    with w:
        c_tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        c_static = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
        c_img = w.add_connection("/camera/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        c_info = w.add_connection("/camera/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        t0 = 100 * SEC
        w.write(c_static, t0, ser(tfm([tf(t0, "link_6", "tool0", T_LINK6_TOOL0)]), "tf2_msgs/msg/TFMessage"))
        events = []
        n = len(T_base_link6)
        for k in range(n):
            start = t0 + 2 * k * SEC
            for j in range(200):  # 1 s at rest, then 1 s moving to the next station
                t = start + j * SEC // 100
                M = T_base_link6[k] if j < 100 or k == n - 1 else interpolate_pose(T_base_link6[k], T_base_link6[k + 1], (j - 100) / 100)
                events.append((t, c_tf, tfm([tf(t, "base_link", "link_6", M)]), "tf2_msgs/msg/TFMessage"))
            ti = start + 503 * SEC // 1000  # between two tf samples
            events.append((ti + 1000, c_img, image(ti, data.images[k]), "sensor_msgs/msg/Image"))
            events.append((ti + 2000, c_info, info(ti, data.K, data.images[k].shape[::-1]), "sensor_msgs/msg/CameraInfo"))
            if k == 1:  # an image while the robot moves (to station 2)
                tm = start + 1505 * SEC // 1000
                events.append((tm + 1000, c_img, image(tm, data.images[k]), "sensor_msgs/msg/Image"))
        for t, c, msg, typ in sorted(events, key=lambda e: e[0]):
            w.write(c, t, ser(msg, typ))
    return path


def _target_file(tmp_path, data):
    f = tmp_path / "target.yaml"
    f.write_text(yaml.safe_dump(data.target))
    return f


def test_ros2_bag_round_trip(chessboard_set, tmp_path):
    bag = write_bag(tmp_path / "bag2", chessboard_set, Stores.ROS2_HUMBLE, ros2=True)
    target = _target_file(tmp_path, chessboard_set)
    with pytest.raises(BadInputError, match="base_frame"):
        import_session("rosbag", bag, tmp_path / "refused", mount="flange", target=str(target))
    code, text = cli("import", "rosbag", bag, "--out", tmp_path / "sess", "--mount", "flange",
                     "--option", f"target={target}", "--option", "base_frame=base_link",
                     "--option", "flange_frame=tool0", "--option", "camera_model=pinhole")
    assert code == 0, text
    assert "robot moving while the image was exposed" in text  # the image taken in motion was skipped
    meta, stations = read_session(tmp_path / "sess")
    assert len(stations) == len(chessboard_set.images)
    np.testing.assert_allclose([s["T_base_flange"] for s in stations], chessboard_set.T_base_flange, atol=1e-9)
    cam = meta["cell"]["cameras"]["cam0"]  # camera_info: start values, estimated
    assert cam["model"] == "opencv5" and "fix" not in cam
    np.testing.assert_allclose(cam["intrinsics"]["K"], chessboard_set.K)
    res = detect_and_calibrate(tmp_path / "sess", tmp_path)
    t = res["transforms"]["T_flange_cam0"]
    assert_pose_near(t["matrix"], t["covariance"], chessboard_set.T_flange_cam)


def test_ros1_bag_poses_images_and_sync_window(chessboard_set, tmp_path):
    small = type(chessboard_set)(chessboard_set.images[:3], chessboard_set.T_base_flange[:3], chessboard_set.T_flange_cam,
                                 chessboard_set.T_base_target, chessboard_set.K, chessboard_set.target)
    bag = write_bag(tmp_path / "calib.bag", small, Stores.ROS1_NOETIC, ros2=False)
    opts = dict(mount="flange", target=str(_target_file(tmp_path, small)), base_frame="base_link", flange_frame="tool0")
    s = import_session("rosbag", bag, tmp_path / "sess", **opts)
    meta, stations = read_session(tmp_path / "sess")
    assert s.num_stations == 3 and any("moving" in n for n in s.notes)
    np.testing.assert_allclose([st["T_base_flange"] for st in stations], small.T_base_flange, atol=1e-9)
    import cv2

    png = cv2.imread(str(tmp_path / "sess" / stations[1]["images"]["cam0"]), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(png, small.images[1])  # lossless
    # tf at 100 Hz: a 2 ms window holds no sample on both sides of the image -> nothing passes
    with pytest.raises(BadInputError, match="synchronisation"):
        import_session("rosbag", bag, tmp_path / "s2", max_dt_ms="2", **opts)
    with pytest.raises(BadInputError, match="no /tf chain"):
        import_session("rosbag", bag, tmp_path / "s3", **{**opts, "flange_frame": "gripper"})
    with pytest.raises(BadInputError, match="target"):
        import_session("rosbag", bag, tmp_path / "s4", **{k: v for k, v in opts.items() if k != "target"})


def test_ros2_bag_with_a_kalibr_aprilgrid_yaml(aprilgrid_set, tmp_path):
    """A Kalibr user's inputs: a bag and the aprilgrid.yaml of the printed grid (target=FILE)."""
    bag = write_bag(tmp_path / "bag2", aprilgrid_set, Stores.ROS2_HUMBLE, ros2=True)
    kalibr = tmp_path / "april_5x4.yaml"
    kalibr.write_text("target_type: 'aprilgrid' #gridtype\ntagCols: 5\ntagRows: 4\ntagSize: 0.03\ntagSpacing: 0.3\n")
    import_session("rosbag", bag, tmp_path / "sess", mount="flange", target=str(kalibr), base_frame="base_link",
                   flange_frame="tool0", camera_model="pinhole")
    meta, _ = read_session(tmp_path / "sess")
    assert meta["cell"]["targets"]["board"] == {**aprilgrid_set.target, "mount": "base"}
    res = detect_and_calibrate(tmp_path / "sess", tmp_path)
    t = res["transforms"]["T_flange_cam0"]
    assert_pose_near(t["matrix"], t["covariance"], aprilgrid_set.T_flange_cam)
