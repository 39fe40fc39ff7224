"""Hardening of the acquisition layer: simulators that survive bad input, captures that refuse what would
corrupt a session (a second capture of one robot, a robot somewhere else than commanded, a resume without
its station list) and re-take what went missing, camera settings from the cell and the CLI."""

from __future__ import annotations

import socket
import struct
import time

import cv2
import numpy as np
import pytest

from jcalib.acquisition import CaptureInterrupted, capture
from jcalib.acquisition.cameras import SimulatedCamera
from jcalib.acquisition.robots import AbbRobot, AbbSimServer, KukaRobot, KukaSimServer, SimulatedController, SimulatedRobot
from jcalib.acquisition.robots.kuka import KukaVarProxyClient, encode_request
from jcalib.acquisition.robots.lock import RobotLock
from jcalib.workflow.devices import capture_settings, parse_settings
from jcalib.errors import BadInputError, DeviceError
from jcalib.io.cell import parse_cell
from jcalib.io.plan import make_plan
from jcalib.io.session import read_session


def _poses(T0, n):
    out = []
    for i in range(n):
        T = T0.copy()
        T[:3, 3] += [0.01 * i, -0.004 * i, 0.0]
        out.append(T)
    return out


def _camera(name="cam0"):
    return SimulatedCamera(lambda r: np.full((r.height, r.width), 80, np.uint8), name=name, sensor_size=(32, 24))


# --- simulators ---------------------------------------------------------------------------------------
def test_kuka_sim_refuses_non_finite_values_and_keeps_its_program_running():
    with KukaSimServer(SimulatedController(time_scale=0.0)) as srv:
        client = KukaVarProxyClient("127.0.0.1", srv.port)
        for name, value in (("JC_POS", "{FRAME: X 1e999, Y 0, Z 0, A 0, B 0, C 0}"), ("JC_FLAG", "nan"),
                            ("JC_FLAG", "1.5"), ("JC_VEL", "99999999999"), ("JC_POS", "{X nan}")):  # fmt: skip
            with pytest.raises(DeviceError, match="failed"):
                client.write(name, value)
        assert client.read("JC_FLAG") == "0"
        client.close()
        robot = KukaRobot("127.0.0.1", srv.port)  # the KRL program still moves the robot
        T = robot.state().T_base_flange.copy()
        T[0, 3] += 0.02
        assert np.linalg.norm(robot.move(T).T_base_flange[:3, 3] - T[:3, 3]) < 1e-4
        robot.close()
        assert srv.program_errors == []


def test_kuka_sim_drops_a_malformed_client_and_serves_the_next():
    with KukaSimServer(SimulatedController(time_scale=0.0)) as srv:
        for junk in (b"\x00\x01\x00\x02\xff\xff", b"\x00\x01\x00\x05\x00\x00\x09AB", encode_request(1, "$POS_ACT")[:-2]):
            with socket.create_connection(("127.0.0.1", srv.port), timeout=2) as s:
                s.sendall(junk)
                s.shutdown(socket.SHUT_WR)
                s.recv(100)
        robot = KukaRobot("127.0.0.1", srv.port)
        assert robot.state().T_base_flange.shape == (4, 4)
        robot.close()


def test_abb_sim_idle_client_times_out_and_bad_numbers_are_syntax_errors():
    with AbbSimServer(SimulatedController(time_scale=0.0), idle_timeout_s=0.5) as srv:
        idle = socket.create_connection(("127.0.0.1", srv.port))  # holds the one server task...
        t0 = time.monotonic()
        robot = AbbRobot("127.0.0.1", srv.port, timeout_s=5.0)  # ...until it times out
        assert time.monotonic() - t0 < 3.0
        assert robot._request("PING")[0] == "OK"
        for line in ("TOOL nan", "SPEED inf", "WOBJ 1e999", "MOVJ 1 2 3 nan 0 0 0"):
            with pytest.raises(DeviceError, match="malformed request"):
                robot._request(line)
        robot.close()
        idle.close()


# --- capture ------------------------------------------------------------------------------------------
def test_second_capture_of_one_robot_is_refused(tmp_path):
    lock = RobotLock("kuka://127.0.0.1:7000", "first-session")
    try:
        with pytest.raises(DeviceError, match="driven by another capture .*first-session"):
            RobotLock("kuka://127.0.0.1:7000", "second")
    finally:
        lock.release()
    RobotLock("kuka://127.0.0.1:7000").release()  # free again
    with KukaSimServer(SimulatedController(time_scale=0.0)) as srv:
        r1, r2 = KukaRobot("127.0.0.1", srv.port), KukaRobot("127.0.0.1", srv.port)
        plan = make_plan(_poses(r1.state().T_base_flange, 3))
        seen = []

        def second_capture(event, sid, detail):
            if event == "moved" and not seen:
                with pytest.raises(DeviceError, match="driven by another capture"):
                    capture(plan, r2, {"cam0": _camera()}, tmp_path / "b", progress=False)
                seen.append(sid)

        res = capture(plan, r1, {"cam0": _camera()}, tmp_path / "a", progress=False, listener=second_capture)
        assert res.captured == ["s000", "s001", "s002"] and seen == ["s000"]
        assert not (tmp_path / "b" / "session.json").exists()
        r1.close(), r2.close()


class _Elsewhere(SimulatedRobot):
    """A robot that something else moves after each of our moves (reports a pose 0.2 m away)."""

    def state(self):
        st = super().state()
        T = st.T_base_flange.copy()
        T[2, 3] += 0.2
        return type(st)(T, st.joints_deg)


def test_measured_pose_far_from_commanded_stops_the_capture(tmp_path):
    robot = _Elsewhere(SimulatedController(time_scale=0.0))
    T0 = SimulatedRobot(SimulatedController(time_scale=0.0)).state().T_base_flange
    with pytest.raises(CaptureInterrupted, match=r"station s000: robot: .* (199\.9\d*|200\.0\d*) mm .* from the commanded one"):
        capture(make_plan(_poses(T0, 2)), robot, {"cam0": _camera()}, tmp_path / "s", progress=False)
    assert read_session(tmp_path / "s")[1] == []


def test_resume_retakes_missing_images_and_refuses_without_station_list(tmp_path):
    robot = SimulatedRobot(SimulatedController(time_scale=0.0))
    plan = make_plan(_poses(robot.state().T_base_flange, 3))
    d = tmp_path / "s"
    capture(plan, robot, {"cam0": _camera()}, d, progress=False)
    (d / "images" / "cam0" / "s001.png").unlink()
    (d / "images" / "cam0" / "s002.png").write_bytes(b"not a png")
    res = capture(plan, robot, {"cam0": _camera()}, d, resume=True, progress=False)
    assert res.captured == ["s001", "s002"] and res.already_done == 1
    _, stations = read_session(d)
    assert [s["id"] for s in stations] == ["s000", "s001", "s002"]
    assert [s.get("retake", False) for s in stations] == [False, True, True]
    for s in stations:
        assert cv2.imread(str(d / s["images"]["cam0"])) is not None
    # the station list is lost: resuming must not capture every station again over the images
    (d / "stations.jsonl").unlink()
    before = {p.name: p.read_bytes() for p in (d / "images" / "cam0").iterdir()}
    with pytest.raises(BadInputError, match="stations.jsonl is missing.*3 images"):
        capture(plan, robot, {"cam0": _camera()}, d, resume=True, progress=False)
    assert {p.name: p.read_bytes() for p in (d / "images" / "cam0").iterdir()} == before


def test_camera_settings_applied_recorded_and_checked(tmp_path):
    robot = SimulatedRobot(SimulatedController(time_scale=0.0))
    plan = make_plan(_poses(robot.state().T_base_flange, 2))
    cam = _camera()
    capture(plan, robot, {"cam0": cam}, tmp_path / "s", progress=False,
            camera_settings={"cam0": {"ExposureTime": 2500.0, "Gain": 3}})  # fmt: skip
    meta, _ = read_session(tmp_path / "s")
    rec = meta["devices"]["cameras"]["cam0"]
    assert rec["settings_requested"] == {"ExposureTime": 2500.0, "Gain": 3}
    assert rec["settings"]["ExposureTime"] == 2500.0 and rec["settings"]["Gain"] == 3
    with pytest.raises(BadInputError, match=r"cameras\.cam0\.settings: .*resume with the same settings"):
        capture(plan, robot, {"cam0": cam}, tmp_path / "s", resume=True, progress=False,
                camera_settings={"cam0": {"ExposureTime": 9000.0}})  # fmt: skip
    for bad, match in (({"cam0": {"Zoom": 2.0}}, r"cameras\.cam0\.settings\.Zoom: .*does not support 'Zoom'"),
                       ({"cam0": {"Focus": float("nan")}}, "finite number"),
                       ({"cam9": {"Gain": 1}}, "no camera 'cam9'")):  # fmt: skip
        with pytest.raises(BadInputError, match=match):
            capture(plan, robot, {"cam0": _camera()}, tmp_path / "t", progress=False, camera_settings=bad)
        assert not (tmp_path / "t").exists()


def test_settings_from_the_cell_spec_and_the_command_line():
    cell = parse_cell({"schema": "jcalib.cell/1",
                       "cameras": {"cam0": {"model": "opencv5", "mount": "flange",
                                            "settings": {"ExposureTime": 5000, "PixelFormat": "Mono8"}}},
                       "targets": {"b": {"type": "checkerboard", "cols": 4, "rows": 3, "square": 0.02, "mount": "base"}}})  # fmt: skip
    assert cell.cameras["cam0"].settings == {"ExposureTime": 5000, "PixelFormat": "Mono8"}
    cli = parse_settings(["cam0.ExposureTime=7000", "cam0.Gain=1.5", "cam1.TriggerSource=Software"])
    assert cli == {"cam0": {"ExposureTime": 7000, "Gain": 1.5}, "cam1": {"TriggerSource": "Software"}}
    assert capture_settings(cell, cli) == {"cam0": {"ExposureTime": 7000, "PixelFormat": "Mono8", "Gain": 1.5},
                                           "cam1": {"TriggerSource": "Software"}}  # fmt: skip
    for bad in (["cam0.Gain"], ["Gain=1"], ["cam0.Gain=inf"]):
        with pytest.raises(BadInputError, match="--setting"):
            parse_settings(bad)
    for bad in ([1, 2], {"Gain": [1]}, {"Gain": float("nan")}, {"Gain": True}):
        with pytest.raises(BadInputError, match=r"cameras\.cam0\.settings"):
            parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "settings": bad}},
                        "targets": {}})  # fmt: skip


# --- the fake GigE camera's GVCP front ------------------------------------------------------------------
def _gvcp(command, body, req_id=1, flags=1):
    return struct.pack("!BBHHH", 0x42, flags, command, len(body), req_id) + body


def test_fake_camera_refuses_malformed_gvcp_and_keeps_serving(aravis):
    from jcalib.acquisition.cameras import FakeGigECamera, GigECamera
    from jcalib.acquisition.cameras.gvcp_guard import udp_sockets

    scene = np.random.default_rng(3).integers(0, 256, (48, 64), dtype=np.uint8)
    with FakeGigECamera(lambda r: scene, "127.0.0.1", sensor_size=(64, 48)) as fake:
        assert all(addr == "127.0.0.1" for addr, _ in udp_sockets().values())  # no broadcast / wildcard socket
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.settimeout(1.0)
        # the 16-byte READMEM past the GenICam data that crashed libaravis: a NACK (invalid address)
        s.sendto(_gvcp(0x84, struct.pack("!IHH", 0x7FFF0000, 0, 512)), ("127.0.0.1", 3956))
        status, answer, _, req = struct.unpack("!HHHH", s.recv(64)[:8])
        assert (status, answer, req) == (0x8003, 0x85, 1)
        for pkt in (_gvcp(0x82, struct.pack("!II", 0x0D04, 8)),  # packet size below the overhead
                    _gvcp(0x82, struct.pack("!II", 0x0D18, 0x08080808)),  # stream off the host
                    _gvcp(0x82, struct.pack("!II", 0x11C, 99999)),  # sensor size
                    _gvcp(0x86, struct.pack("!I", 0x100) + struct.pack("!I", 0)),  # Width 0
                    _gvcp(0x84, struct.pack("!IHH", 0x0, 0, 4096))):  # fmt: skip
            s.sendto(pkt, ("127.0.0.1", 3956))
            assert struct.unpack("!H", s.recv(64)[:2])[0] >= 0x8000
        rng = np.random.default_rng(0)
        cmds = [0x02, 0x40, 0x80, 0x82, 0x84, 0x86, 0x100]
        for i in range(4000):  # random bytes, and random packets with a GVCP header
            n = int(rng.integers(0, 600))
            data = bytearray(rng.integers(0, 256, n, dtype=np.uint8).tobytes())
            if n >= 8 and i % 2:
                data[0:6] = struct.pack("!BBHH", 0x42, 0, int(rng.choice(cmds)), n - 8)
            s.sendto(bytes(data), ("127.0.0.1", 3956))
        cam = GigECamera("127.0.0.1", packet_size=1400)
        np.testing.assert_array_equal(cam.grab().image, scene)
        cam.close()
        assert fake.guard.stats.refused > 0 and not fake.source_errors
