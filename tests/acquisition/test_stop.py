"""Stopping the robot and controlling a capture: Robot.stop() on every driver (KUKA, ABB, UR) over its real protocol on
127.0.0.1 (realistic motion times, time_scale=1), and CaptureControl's pause / resume / abort / STOP.

Timing (stop -> standstill within 0.2 s) is measured by ``benchmarks/bench_stop.py``, not asserted here."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from jcalib.acquisition import CaptureControl, CaptureInterrupted, capture
from jcalib.acquisition.cameras import SimulatedCamera
from jcalib.acquisition.robots import (
    AbbRobot,
    AbbSimServer,
    KukaRobot,
    KukaSimServer,
    KukaVarProxyClient,
    MotionStoppedError,
    SimulatedController,
    SimulatedRobot,
    UrRobot,
    UrSimServer,
)
from jcalib.errors import DeviceError
from jcalib.geometry.se3 import pose_distance
from jcalib.io.plan import make_plan, save_plan
from jcalib.io.session import read_session

ROOT = Path(__file__).resolve().parents[2]


def _connect(protocol: str, ctrl: SimulatedController):
    if protocol == "kuka":
        srv = KukaSimServer(ctrl).start()
        return srv, KukaRobot("127.0.0.1", srv.port, motion_timeout_s=20.0)
    if protocol == "abb":
        srv = AbbSimServer(ctrl).start()
        return srv, AbbRobot("127.0.0.1", srv.port, motion_timeout_s=20.0)
    if protocol == "ur":
        srv = UrSimServer(ctrl, port=0).start()
        return srv, UrRobot("127.0.0.1", rtde_port=srv.port, script_port=srv.script_port, motion_timeout_s=20.0)
    return None, SimulatedRobot(ctrl)


@pytest.fixture(params=["sim", "kuka", "abb", "ur"])
def cell(request):
    ctrl = SimulatedController(time_scale=1.0, seed=5)
    srv, robot = _connect(request.param, ctrl)
    yield request.param, robot, ctrl
    robot.close()
    if srv is not None:
        srv.stop()


def _offset(T, d):
    T = T.copy()
    T[:3, 3] += d
    return T


def _move_in_thread(robot, T, kind):
    out: dict = {}

    def run():
        try:
            out["state"] = robot.move(T, kind=kind)
        except Exception as e:  # noqa: BLE001 - the test inspects it
            out["error"] = e

    th = threading.Thread(target=run)
    th.start()
    return th, out


def _stop_mid_move(robot, ctrl, T, kind):
    """Start a move, stop it once the controller is on its way (about 40% of it); returns the error raised."""
    moves = ctrl.num_moves
    th, out = _move_in_thread(robot, T, kind)
    deadline = time.monotonic() + 10.0
    while ctrl.num_moves == moves and time.monotonic() < deadline:
        time.sleep(0.002)
    duration = ctrl.motion_time_s  # the simulated motion time of this move
    time.sleep(0.4 * duration)
    robot.stop()
    th.join(20.0)
    assert not th.is_alive()
    return out.get("error")


def test_stop_during_a_joint_move_stands_on_the_path_and_the_next_move_works(cell):
    protocol, robot, ctrl = cell
    s0 = robot.state()
    q0 = np.radians(s0.joints_deg)
    T = _offset(s0.T_base_flange, [0.35, -0.35, -0.2])
    err = _stop_mid_move(robot, ctrl, T, "joint")
    assert isinstance(err, MotionStoppedError), (protocol, err)
    # it stands: consecutive readings agree (the move raised only once the robot stood)
    a = robot.state()
    time.sleep(0.05)
    b = robot.state()
    dt, dr = pose_distance(a.T_base_flange, b.T_base_flange)
    assert dt < 1e-6 and dr < 1e-5, (dt, dr)
    # the next move is accepted and reaches the target; the stop lies on the joint-space segment to it
    s1 = robot.move(T)
    assert pose_distance(s1.T_base_flange, T)[0] < 1e-4
    q1, qs = np.radians(s1.joints_deg), np.radians(a.joints_deg)
    f = float(np.dot(qs - q0, q1 - q0) / np.dot(q1 - q0, q1 - q0))
    assert 0.05 < f < 0.95, f  # stopped on the way, not at either end
    off = np.linalg.norm(qs - (q0 + f * (q1 - q0)))
    assert off < 1e-4, off  # on the segment (joint readings have 1e-3 deg resolution over ABB)


def test_stop_during_a_linear_move_stands_on_the_line(cell):
    protocol, robot, ctrl = cell
    s0 = robot.state()
    T = _offset(s0.T_base_flange, [0.0, 0.4, -0.1])
    err = _stop_mid_move(robot, ctrl, T, "linear")
    assert isinstance(err, MotionStoppedError), (protocol, err)
    p0, p1, ps = s0.T_base_flange[:3, 3], T[:3, 3], robot.state().T_base_flange[:3, 3]
    f = float(np.dot(ps - p0, p1 - p0) / np.dot(p1 - p0, p1 - p0))
    assert 0.05 < f < 0.95, f
    # on the straight line: the braking follows the path (the controller interpolates it in 1 cm steps)
    assert np.linalg.norm(ps - (p0 + f * (p1 - p0))) < 2e-4


def test_stop_when_idle_is_harmless_and_a_stop_before_a_guarded_move_refuses_it(cell):
    protocol, robot, ctrl = cell
    before = robot.state()
    robot.stop()
    robot.stop()  # idempotent
    assert ctrl.num_moves == 0
    assert pose_distance(robot.state().T_base_flange, before.T_base_flange)[0] < 1e-6
    T = _offset(before.T_base_flange, [0.02, 0.0, 0.0])
    seen = robot.num_stops
    robot.stop()  # between the caller's decision to move and the move: the move must not start
    with robot.stop_guard(seen), pytest.raises(MotionStoppedError, match="stop was requested"):
        robot.move(T)
    assert ctrl.num_moves == 0
    ctrl.time_scale = 0.0
    assert pose_distance(robot.move(T).T_base_flange, T)[0] < 1e-4  # accepted normally afterwards


def test_kuka_program_semantics_of_jc_stop():
    ctrl = SimulatedController(time_scale=0.0)
    with KukaSimServer(ctrl) as srv:
        client = KukaVarProxyClient("127.0.0.1", srv.port)
        for bad in ("1", "yes", "TRUE FALSE", ""):
            with pytest.raises(DeviceError, match="failed"):
                client.write("JC_STOP", bad)
        robot = KukaRobot("127.0.0.1", srv.port)
        client.write("JC_STOP", "TRUE")  # left TRUE (e.g. by a client killed after its stop) ...
        client.write("JC_POS", client.read("$POS_ACT").replace("E6POS", "FRAME"))
        client.write("JC_FLAG", "1")
        while client.read("JC_FLAG") != "0":
            time.sleep(0.005)
        assert client.read("JC_ERR") == "5" and client.read("JC_STOP") == "FALSE"  # ... a command does not move
        assert ctrl.num_moves == 0
        client.write("JC_STOP", "TRUE")
        robot2 = KukaRobot("127.0.0.1", srv.port)  # a new client clears it before its first move
        T = _offset(robot2.state().T_base_flange, [0.0, 0.02, 0.0])
        assert pose_distance(robot2.move(T).T_base_flange, T)[0] < 1e-4
        # a KRL program older than JC_STOP: moves work, stop() refuses and says what to do
        del srv.vars["JC_STOP"]
        old = KukaRobot("127.0.0.1", srv.port)
        assert not old.can_stop
        with pytest.raises(DeviceError, match="no JC_STOP .*teach pendant"):
            old.stop()
        assert pose_distance(old.move(_offset(T, [0.01, 0, 0])).T_base_flange, _offset(T, [0.01, 0, 0]))[0] < 1e-4
        for r in (robot, robot2, old):
            r.close()
        client.close()
        assert srv.program_errors == []


def test_abb_stop_port_survives_junk_and_a_version_1_server_cannot_stop():
    import socket

    ctrl = SimulatedController(time_scale=0.0)
    with AbbSimServer(ctrl) as srv:
        robot = AbbRobot("127.0.0.1", srv.port)
        assert robot.stop_port == srv.stop_port
        rng = np.random.default_rng(1)
        for junk in [b"", b"STOP", b"x" * 300 + b"\n", b"\xff\xfe\n", b"PING\n"] + [
            rng.integers(0, 256, int(rng.integers(1, 200)), dtype=np.uint8).tobytes() for _ in range(30)
        ]:
            with socket.create_connection(("127.0.0.1", srv.stop_port), timeout=2) as s:
                try:
                    s.sendall(junk)
                    s.shutdown(socket.SHUT_WR)
                    reply = s.recv(100)
                except OSError:  # the task answered a bad line and closed first
                    reply = b""
                assert len(reply) <= 80
        robot.stop()  # still served
        T = _offset(robot.state().T_base_flange, [0.01, 0.0, 0.0])
        assert pose_distance(robot.move(T).T_base_flange, T)[0] < 1e-4
        robot.close()
        srv.handle = lambda line: ("OK JCALIB 1", True) if line == "PING" else AbbSimServer.handle(srv, line)
        old = AbbRobot("127.0.0.1", srv.port)
        assert not old.can_stop and robot.can_stop
        with pytest.raises(DeviceError, match="protocol 1 .*FlexPendant"):
            old.stop()
        old.close()


# --- capture control ------------------------------------------------------------------------------------
def _camera():
    return SimulatedCamera(lambda r: np.full((r.height, r.width), 90, np.uint8), name="cam0", sensor_size=(32, 24))


def _plan(T0, n=4):
    return make_plan([_offset(T0, [0.12 * (i % 2), -0.1 * i, 0.05 * (i % 3)]) for i in range(n)])


def _check_complete(session: Path, plan) -> None:
    _, stations = read_session(session)
    assert sorted(s["id"] for s in stations) == [s.id for s in plan.stations]  # each exactly once
    for s in stations:
        assert s["status"] == "ok" and cv2.imread(str(session / s["images"]["cam0"])) is not None
    assert not list(session.rglob("*.tmp"))


def test_capture_stop_during_a_move_then_resume(cell, tmp_path):
    protocol, robot, ctrl = cell
    plan = _plan(robot.state().T_base_flange)
    control = CaptureControl()
    events = []

    def listener(event, sid, detail):
        events.append((event, sid))
        if event == "start" and sid == "s002":  # the move starts right after this event
            moves = ctrl.num_moves

            def press():
                while ctrl.num_moves == moves:
                    time.sleep(0.002)
                time.sleep(0.3 * ctrl.motion_time_s)
                control.stop()  # the capture's own robot

            threading.Thread(target=press, daemon=True).start()

    with pytest.raises(CaptureInterrupted, match=r"(?s)stopped by the operator.*s002 was not recorded.*resume"):
        capture(plan, robot, {"cam0": _camera()}, tmp_path / "s", progress=False, control=control,
                listener=listener)  # fmt: skip
    assert control.state == "stopped" and ("stopped", "s002") in events
    _, stations = read_session(tmp_path / "s")
    assert [s["id"] for s in stations] == ["s000", "s001"]
    assert not (tmp_path / "s" / "images" / "cam0" / "s002.png").exists()
    stood = robot.state().T_base_flange  # braked on the way: not at s002
    assert pose_distance(stood, plan.stations[2].T_base_flange)[0] > 1e-3
    res = capture(plan, robot, {"cam0": _camera()}, tmp_path / "s", resume=True, progress=False,
                  control=CaptureControl())  # fmt: skip
    assert res.captured == ["s002", "s003"] and not res.aborted
    _check_complete(tmp_path / "s", plan)


def test_capture_stop_between_moves_prevents_the_next_move(tmp_path):
    ctrl = SimulatedController(time_scale=0.0)
    robot = SimulatedRobot(ctrl)
    plan = _plan(robot.state().T_base_flange)
    control = CaptureControl()

    def listener(event, sid, detail):
        if event == "done" and sid == "s001":
            control.stop()  # the robot stands: the stop is for the capture

    with pytest.raises(CaptureInterrupted, match="stopped by the operator.*s002"):
        capture(plan, robot, {"cam0": _camera()}, tmp_path / "s", progress=False, control=control, listener=listener)
    assert ctrl.num_moves == 2  # s000, s001; no move towards s002
    assert [s["id"] for s in read_session(tmp_path / "s")[1]] == ["s000", "s001"]


def test_capture_pause_resume_and_abort(tmp_path):
    ctrl = SimulatedController(time_scale=0.0)
    robot = SimulatedRobot(ctrl)
    plan = _plan(robot.state().T_base_flange, 5)
    control = CaptureControl()
    control.keepalive_s = 0.02
    events, moves_while_paused, states = [], [], []

    def resume_later():
        n = ctrl.num_moves
        time.sleep(0.2)
        moves_while_paused.append(ctrl.num_moves - n)
        states.append(control.state)
        control.resume()

    def listener(event, sid, detail):
        events.append((event, sid))
        if event == "done" and sid == "s000":
            control.pause()
            states.append(control.state)
        if event == "paused":
            threading.Thread(target=resume_later, daemon=True).start()
        if event == "done" and sid == "s002":
            control.abort()
            states.append(control.state)

    res = capture(plan, robot, {"cam0": _camera()}, tmp_path / "s", progress=False, control=control, listener=listener)
    assert ("paused", "s001") in events and ("resumed", "s001") in events and ("aborted", "s003") in events
    assert moves_while_paused == [0]
    assert states == ["paused", "paused", "aborting"] and control.state == "done" and control.abort_requested
    assert res.aborted and res.captured == ["s000", "s001", "s002"]
    res = capture(plan, robot, {"cam0": _camera()}, tmp_path / "s", resume=True, progress=False)
    assert res.captured == ["s003", "s004"] and res.already_done == 3
    _check_complete(tmp_path / "s", plan)


def test_cli_capture_ctrl_c_stops_the_robot_exit_4_then_resume(tmp_path):
    """The first Ctrl-C of `jcalib capture` is the STOP button: exit status 4, the resume hint, no traceback."""
    ctrl = SimulatedController(time_scale=1.0, seed=2)
    with KukaSimServer(ctrl) as srv:
        T0 = SimulatedRobot(SimulatedController()).state().T_base_flange
        plan = _plan(T0, 4)
        save_plan(plan, tmp_path / "plan.json")
        (tmp_path / "img").mkdir()
        for i in range(4):
            cv2.imwrite(str(tmp_path / "img" / f"{i}.png"), np.full((24, 32), 60 + i, np.uint8))
        cmd = [sys.executable, "-c", "from jcalib.app.cli import main; main()", "capture", "--robot",
               f"kuka://127.0.0.1:{srv.port}", "--camera", f"cam0=replay://{tmp_path / 'img'}", "--plan",
               str(tmp_path / "plan.json"), "--out", str(tmp_path / "s")]  # fmt: skip
        env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60
        while ctrl.num_moves < 2 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.005)
        time.sleep(0.3 * ctrl.motion_time_s)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 4, err
        assert "stopped by the operator" in err and "session can be resumed" in err and "--resume" in err, err
        assert "Traceback" not in err
        assert [s["id"] for s in read_session(tmp_path / "s")[1]] == ["s000"]
        with KukaRobot("127.0.0.1", srv.port) as r:  # braked on the way to s001
            assert pose_distance(r.state().T_base_flange, plan.stations[1].T_base_flange)[0] > 1e-3
        ctrl.time_scale = 0.0
        done = subprocess.run(cmd + ["--resume"], env=env, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
    _check_complete(tmp_path / "s", plan)


def test_adaptive_capture_pauses_aborts_and_stops_through_the_same_control(tmp_path, monkeypatch):
    """``capture --goal`` runs one capture per station: one CaptureControl covers them all. The station choice
    (run_adaptive, tested in tests/planning) is replaced by a fixed sequence of stations here."""
    import yaml

    import jcalib.planning.adaptive as adaptive
    from jcalib.workflow.adaptive import run_adaptive_capture
    from jcalib.io.goals import parse_goals

    T0 = SimulatedRobot(SimulatedController(time_scale=0.0)).state().T_base_flange

    def fixed_stations(layout, goals, *, acquire, calibrate, max_stations, captured=(), **kw):
        got = [acquire(j, _offset(T0, [0.02 * j, -0.01 * j, 0.0]), ("cam0", "board")) for j in range(4)]
        return adaptive.AdaptiveOutcome(list(captured) + [g for g in got if g], [], [], False, None, "all tried")

    monkeypatch.setattr(adaptive, "run_adaptive", fixed_stations)
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
            "targets": {"board": {"type": "checkerboard", "cols": 8, "rows": 5, "square": 0.02, "mount": "base"}}}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    (tmp_path / "img").mkdir()
    for i in range(8):  # blank frames: nothing is detected (each station "choosing another")
        cv2.imwrite(str(tmp_path / "img" / f"{i}.png"), np.full((240, 320), 100, np.uint8))
    ctrl = SimulatedController(time_scale=0.0)
    with KukaSimServer(ctrl) as srv:
        kw = dict(robot_url=f"kuka://127.0.0.1:{srv.port}", camera_urls={"cam0": f"replay://{tmp_path / 'img'}"},
                  cell=tmp_path / "cell.yaml", goals=parse_goals(["T_flange_cam0:translation_mm<=1"]), max_stations=6,
                  out=tmp_path / "s", image_size=(320, 240), echo=lambda line: None)  # fmt: skip
        control, events = CaptureControl(), []

        def listener(event, sid, detail):
            events.append((event, sid))
            if event == "done" and sid == "s000":
                control.pause()  # held across the detection of s000 and the choice of the next station
            if event == "paused":
                threading.Timer(0.1, control.resume).start()
            if event == "start" and sid == "s001":
                control.abort()  # s001 is finished, then the run ends

        out = run_adaptive_capture(**kw, control=control, listener=listener)
        assert events[4:6] == [("paused", "s001"), ("resumed", "s001")], events
        assert events[-1] == ("aborted", "s002"), events
        assert out.message.startswith("aborted by the operator after 0 station(s)") and "--resume" in out.message
        assert control.state == "done" and control.abort_requested and ctrl.num_moves == 2
        assert [s["id"] for s in read_session(tmp_path / "s")[1]] == ["s000", "s001"]

        control = CaptureControl()

        def press_stop(event, sid, detail):
            if event == "start":
                control.stop()

        with pytest.raises(CaptureInterrupted, match="stopped by the operator .*s002"):
            run_adaptive_capture(**kw, resume=True, control=control, listener=press_stop)
        assert control.state == "stopped" and ctrl.num_moves == 2
