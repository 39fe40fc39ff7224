"""Universal Robots: the RTDE wire format, the driver against the UR simulator over its real protocols on
127.0.0.1 (free ports), its device errors, and fuzzed RTDE and URScript input the simulator survives.

The PyPI client ``ur_rtde`` against ``jcalib simulate --robot-protocol ur`` is in ``test_interop.py`` (it needs
UR's fixed ports, so a private network namespace); stop() is in ``test_stop.py``, the SIGKILL-and-resume capture
in ``test_kill_resume.py``.
"""

from __future__ import annotations

import socket
import struct
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jcalib.acquisition.robots import MotionRefusedError, SimulatedController, UrRobot, UrSimServer
from jcalib.acquisition.robots import rtde
from jcalib.acquisition.robots.ur import move_program
from jcalib.acquisition.robots.urscript import ScriptError, parse_program, split_program
from jcalib.errors import BadInputError, DeviceError
from jcalib.geometry.se3 import pose_distance, pose_from_ur


@pytest.fixture
def ur():
    ctrl = SimulatedController(time_scale=0.0, seed=3)
    srv = UrSimServer(ctrl, port=0, idle_timeout_s=2.0).start()
    robot = UrRobot("127.0.0.1", rtde_port=srv.port, script_port=srv.script_port, motion_timeout_s=20.0,
                    start_timeout_s=1.0)  # fmt: skip
    yield srv, robot, ctrl
    robot.close()
    srv.stop()


def _offset(T, d):
    T = T.copy()
    T[:3, 3] += d
    return T


def test_rtde_packages_and_recipes_follow_the_wire_format():
    # header: u16 size (header included), u8 command; big-endian (UR's RTDE guide)
    assert rtde.encode_package(rtde.REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2)) == b"\x00\x05V\x00\x02"
    assert rtde.encode_package(rtde.START) == b"\x00\x03S"
    names, types = ("timestamp", "actual_q", "robot_mode", "output_bit_register_64"), ("DOUBLE", "VECTOR6D", "INT32", "BOOL")
    assert tuple(rtde.field_type(n) for n in names) == types
    recipe = rtde.Recipe(3, names, types)
    values = {"timestamp": 1.5, "actual_q": (0.1, 0.2, 0.3, 0.4, 0.5, 0.6), "robot_mode": 7, "output_bit_register_64": True}
    payload = recipe.pack(values)
    assert payload == struct.pack(">Bd6di?", 3, 1.5, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 7, True)
    assert recipe.unpack(payload) == values
    with pytest.raises(ValueError):
        recipe.unpack(payload[:-1])
    assert rtde.field_type("output_int_register_24") == "INT32" and rtde.field_type("input_double_register_47") == "DOUBLE"
    assert rtde.field_type("output_int_register_48") is None and rtde.field_type("output_bit_register_3") is None
    assert rtde.field_type("input_int_register_0", inputs=True) == "INT32"
    assert rtde.field_type("output_int_register_0", inputs=True) is None and rtde.field_type("no_such") is None
    msg = rtde.encode_text_message("hello", "src", rtde.WARNING_MESSAGE)
    assert msg == b"\x00\x0eM\x05hello\x03src\x02"
    assert rtde.decode_text_message(msg[3:]) == ("hello", "src", rtde.WARNING_MESSAGE)
    assert rtde.parse_names(b"actual_q,timestamp,") == ["actual_q", "timestamp"]  # ur_rtde's trailing comma
    assert rtde.parse_names(b"a,,b") is None and rtde.parse_names(b"\xff") is None


def test_move_reaches_the_target_and_state_is_the_flange_whatever_tcp_is_active(ur):
    srv, robot, ctrl = ur
    T_tool = pose_from_ur([0.0, 0.02, 0.15, 0.0, 0.3, 0.0])
    ctrl.set_tool(1, T_tool)  # the installation's TCP: actual_TCP_pose is the tool's, state() still the flange
    s0 = robot.state()
    q = ctrl.joints_rad()
    assert np.abs(s0.T_base_flange - ctrl.model.forward(q)).max() < 1e-12
    assert np.abs(s0.joints_deg - np.degrees(q)).max() < 1e-12
    T = _offset(s0.T_base_flange, [0.1, -0.1, -0.05])
    s1 = robot.move(T)
    assert pose_distance(s1.T_base_flange, T)[0] < 1e-4  # the flange went there (repeatability noise is below)
    assert ctrl.tool == 0  # the program set the TCP to the flange
    s2 = robot.move(_offset(T, [0.0, 0.08, 0.0]), kind="linear")
    assert pose_distance(s2.T_base_flange, _offset(T, [0.0, 0.08, 0.0]))[0] < 1e-4
    assert srv.num_programs == 2 and srv.errors == []


def test_unreachable_target_is_refused_without_moving(ur):
    srv, robot, ctrl = ur
    s0 = robot.state()
    moves = ctrl.num_moves
    for kind in ("joint", "linear"):
        with pytest.raises(MotionRefusedError, match="unreachable.*did not move"):
            robot.move(_offset(s0.T_base_flange, [3.0, 0.0, 0.0]), kind=kind)
    assert ctrl.num_moves == moves
    assert pose_distance(robot.state().T_base_flange, s0.T_base_flange)[0] < 1e-9
    assert pose_distance(robot.move(_offset(s0.T_base_flange, [0.02, 0, 0])).T_base_flange,
                         _offset(s0.T_base_flange, [0.02, 0, 0]))[0] < 1e-4  # fmt: skip


def test_stops_and_an_arm_that_cannot_move_are_device_errors_that_say_what_to_do(ur):
    srv, robot, ctrl = ur
    T = _offset(robot.state().T_base_flange, [0.2, -0.2, 0.0])
    # a protective stop during a move (1 s of motion at time_scale 1)
    ctrl.time_scale = 1.0
    out: dict = {}
    moves = ctrl.num_moves

    def run():
        try:
            robot.move(T)
        except Exception as e:  # noqa: BLE001 - inspected below
            out["e"] = e

    th = threading.Thread(target=run)
    th.start()
    deadline = time.monotonic() + 10
    while ctrl.num_moves == moves and time.monotonic() < deadline:
        time.sleep(0.005)
    time.sleep(0.1)
    srv.protective_stop()
    th.join(20)
    err = out.get("e")
    assert isinstance(err, DeviceError), err
    assert "protective stop" in str(err) and "Unlock" in str(err) and err.exit_code == 4
    with pytest.raises(DeviceError, match="protective stop.*Unlock"):
        robot.move(T)  # refused before anything is sent
    srv.unlock()
    ctrl.time_scale = 0.0
    # RTDE packages sent before the unlock may still be queued on a loaded machine: the first moves may still be
    # refused as stopped, and a move must go through within a few seconds
    deadline = time.monotonic() + 10.0
    while True:
        try:
            moved = robot.move(T)
            break
        except DeviceError as e:
            if "protective stop" not in str(e) or time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    assert pose_distance(moved.T_base_flange, T)[0] < 1e-4
    srv.emergency_stop()
    with pytest.raises(DeviceError, match="emergency stop button"):
        robot.move(_offset(T, [0.01, 0, 0]))
    srv.unlock()
    srv.robot_mode = 3  # POWER_OFF
    with pytest.raises(DeviceError, match="POWER_OFF.*power it on"):
        robot.move(_offset(T, [0.01, 0, 0]))
    srv.robot_mode = 7
    srv.remote_control = False  # an e-Series in Local mode ignores the program
    with pytest.raises(DeviceError, match="Remote Control"):
        robot.move(_offset(T, [0.01, 0, 0]))
    srv.remote_control = True
    assert pose_distance(robot.move(_offset(T, [0.01, 0, 0])).T_base_flange, _offset(T, [0.01, 0, 0]))[0] < 1e-4


def test_capture_stops_at_a_protective_stop_with_exit_4_and_resumes_after_unlock(ur, tmp_path):
    from jcalib.acquisition import CaptureInterrupted, capture
    from jcalib.acquisition.cameras import SimulatedCamera
    from jcalib.io.plan import make_plan
    from jcalib.io.session import read_session

    srv, robot, ctrl = ur
    T0 = robot.state().T_base_flange
    plan = make_plan([_offset(T0, [0.05 * i, -0.05 * i, 0.0]) for i in range(3)])
    cam = {"cam0": SimulatedCamera(lambda r: np.full((r.height, r.width), 90, np.uint8), name="cam0", sensor_size=(32, 24))}

    def listener(event, sid, detail):
        if event == "start" and sid == "s001":
            srv.protective_stop()  # the arm tripped before (or as) the move to s001 starts

    with pytest.raises(CaptureInterrupted, match=r"(?s)protective stop.*Unlock.*resume") as info:
        capture(plan, robot, cam, tmp_path / "s", progress=False, listener=listener)
    assert info.value.exit_code == 4
    assert [s["id"] for s in read_session(tmp_path / "s")[1]] == ["s000"]
    srv.unlock()
    capture(plan, robot, cam, tmp_path / "s", resume=True, progress=False)
    assert [s["id"] for s in read_session(tmp_path / "s")[1]] == ["s000", "s001", "s002"]


def _send_script(port: int, text: str) -> None:
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.sendall(text.encode())
        time.sleep(0.05)


def test_a_foreign_program_is_not_replaced_and_an_earlier_clients_move_is_waited_for(ur):
    srv, robot, ctrl = ur
    ctrl.time_scale = 1.0
    T0 = robot.state().T_base_flange
    _send_script(srv.script_port, "def someone_elses():\n  sleep(1.0)\nend\n")
    with pytest.raises(DeviceError, match="program jcalib did not start.*stop it at the teach pendant"):
        robot.move(_offset(T0, [0.01, 0, 0]))
    while srv.runtime_state != rtde.RUNTIME_STOPPED:
        time.sleep(0.02)
    # a killed client's move program still running: the next move waits for it, then goes
    T1 = _offset(T0, [0.15, 0.0, -0.1])
    _send_script(srv.script_port, move_program(777, T1, "joint", speed=1.0, acceleration=1.0))
    T2 = _offset(T0, [0.0, 0.05, 0.0])
    s = robot.move(T2)
    assert pose_distance(s.T_base_flange, T2)[0] < 1e-4 and srv.errors == []


_PROGRAM = move_program(12, pose_from_ur([0.4, -0.1, 0.3, 0.0, 3.1, 0.0]), "joint", speed=1.0, acceleration=1.4)


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=400) | st.builds(lambda i, j, c: _PROGRAM[:i] + c + _PROGRAM[j:], st.integers(0, 400),
                                         st.integers(0, 400), st.text(max_size=12)))
def test_urscript_parser_accepts_or_refuses_but_never_fails(text):
    try:
        program = parse_program(text)
        assert isinstance(program, list)
    except ScriptError:
        pass
    try:
        split_program(text.encode("utf-8"))
    except ScriptError:
        pass


def test_urscript_subset_and_stream_splitting():
    program = parse_program(_PROGRAM)
    assert [s.kind for s in program] == ["register", "set_tcp", "if_no_ik", "move", "register"]
    assert [s.kind for s in program[2].body] == ["register", "halt"]
    stream = ("  \n" + _PROGRAM + "stopj(2)\nmovej([0, -1.5, 1.5, 0, 1, 0])\n").encode()
    first, n = split_program(stream)
    assert first.strip() == _PROGRAM.strip()
    second, m = split_program(stream[n:])
    assert second == "stopj(2)" and split_program(stream[n + m :])[0] == "movej([0, -1.5, 1.5, 0, 1, 0])"
    assert split_program(_PROGRAM[:-5].encode()) == (None, 0)  # incomplete: wait for more
    for bad in ("movej(p[1, 2, 3, 4, 5, 1e999])", "set_tcp(p[0, 0, 0])", "write_output_integer_register(48, 1)",
                "def f():\n  movej(q)\nend", "if not get_inverse_kin_has_solution(p[0,0,0,0,0,0]):\n  halt",
                "import os", "movel([0, 0, 0, 0, 0, 0])"):  # fmt: skip
        with pytest.raises(ScriptError):
            parse_program(bad)
    with pytest.raises(ScriptError):
        split_program(b"movej(\xff)\n")


def _rtde_junk(rng: np.random.Generator) -> bytes:
    kind = rng.integers(0, 5)
    if kind == 0:
        return rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8).tobytes()
    command = int(rng.choice(list(b"VvOISPUMx")))
    if kind == 1:  # a setup with odd frequencies and names
        names = ",".join(rng.choice(["actual_q", "timestamp", "output_int_register_99", "", "x" * 300, "robot_mode"],
                                    int(rng.integers(0, 6))))  # fmt: skip
        freq = float(rng.choice([125.0, 0.0, -1.0, np.nan, np.inf, 1e9]))
        payload = struct.pack(">d", freq) + names.encode() if command == ord("O") else names.encode()
    elif kind == 2:  # a data package for a recipe that does or does not exist
        payload = bytes([int(rng.integers(0, 4))]) + rng.integers(0, 256, int(rng.integers(0, 40)), dtype=np.uint8).tobytes()
    else:
        payload = rng.integers(0, 256, int(rng.integers(0, 30)), dtype=np.uint8).tobytes()
    return rtde.encode_package(command, payload)


def _script_junk(rng: np.random.Generator) -> bytes:
    text = _PROGRAM
    for _ in range(int(rng.integers(1, 4))):
        i = int(rng.integers(0, len(text)))
        op = rng.integers(0, 4)
        if op == 0:
            text = text[:i] + text[i + int(rng.integers(1, 20)) :]
        elif op == 1:
            text = text[:i] + str(rng.choice(["nan", "1e999", "end\n", "def g():\n", "(", "]", "#", '"'])) + text[i:]
        elif op == 2:
            text = text[:i] + text[i:].replace("\n", "\n\n", 1)
        else:
            return rng.integers(0, 256, int(rng.integers(1, 200)), dtype=np.uint8).tobytes()
    return text.encode()


def test_fuzzed_rtde_and_urscript_input_never_crashes_the_simulator(ur):
    srv, robot, ctrl = ur
    rng = np.random.default_rng(7)
    for i in range(40):  # connections, each with a stream of junk: the client may be dropped, never the server
        with socket.create_connection(("127.0.0.1", srv.port), timeout=5) as s:
            if i % 2:  # a valid start, so that junk also hits a negotiated connection
                s.sendall(rtde.encode_package(rtde.REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2)))
            try:
                for _ in range(10):
                    s.sendall(_rtde_junk(rng))
            except OSError:
                pass
    for _ in range(60):
        with socket.create_connection(("127.0.0.1", srv.script_port), timeout=5) as s:
            try:
                s.sendall(_script_junk(rng))
            except OSError:
                pass
    time.sleep(0.3)
    assert srv._thread.is_alive() and srv.secondary._thread.is_alive()
    assert any("compile error" in e for e in srv.errors)
    while srv.runtime_state != rtde.RUNTIME_STOPPED:
        time.sleep(0.02)
    # the simulator serves: the driver's connection, and a new one
    for r in (robot, UrRobot("127.0.0.1", rtde_port=srv.port, script_port=srv.script_port, start_timeout_s=1.0)):
        T = _offset(r.state().T_base_flange, [0.01, 0.0, 0.0])
        assert pose_distance(r.move(T).T_base_flange, T)[0] < 1e-4
    r.close()


def test_ur_urls_and_options_are_checked():
    from jcalib.app.simulate import run_simulate
    from jcalib.workflow.devices import check_urls, open_robot

    check_urls("ur://10.0.0.5", {})
    check_urls("ur://127.0.0.1:40004:40002", {})
    for url in ("ur://10.0.0.5:30004", "ur://:1:2", "ur://h:a:b", "ur://h:0:30002"):
        with pytest.raises(BadInputError, match="--robot"):
            open_robot(url)
    with pytest.raises(DeviceError, match="RTDE"):  # nothing listens there
        UrRobot("127.0.0.1", rtde_port=1, script_port=2, timeout_s=0.5)
    with pytest.raises(BadInputError, match="--robot-port"):
        run_simulate("cell.yaml", robot_protocol="kuka", robot_port=None, camera_addresses={"cam0": "127.0.0.1"})
    with pytest.raises(BadInputError, match="loopback"):
        UrSimServer(host="0.0.0.0", port=0)
