"""Universal Robots (CB3, e-Series) controllers: state over RTDE, motion by URScript on the secondary interface.

``ur://HOST`` is the controller: RTDE on TCP 30004, the secondary client interface on TCP 30002 (the ports are
fixed on a real controller; ``ur://HOST:RTDE_PORT:SCRIPT_PORT`` names others, e.g. a simulator on free ports).

**State** (:meth:`UrRobot.state`): an RTDE connection (protocol version 2, :mod:`~jcalib.acquisition.robots.rtde`)
with one output recipe at 125 Hz (e-Series up to 500 Hz): ``timestamp``, ``actual_q``, ``actual_qd``,
``actual_TCP_pose``, ``tcp_offset``, ``robot_mode``, ``safety_mode``, ``runtime_state`` and two general-purpose
output registers (24 and 25, the range UR reserves for external clients). A reader thread keeps the newest
package; :meth:`UrRobot.state` waits for one that arrived after the call. The flange pose is
``actual_TCP_pose · tcp_offset⁻¹`` (UR poses are metres + rotation vector in the base frame), so it is the flange
whatever TCP the installation has active; joints are ``actual_q`` in degrees.

**Motion** (:meth:`UrRobot.move`): one small URScript program per move, sent on the secondary interface::

    def jcalib_move():
      write_output_integer_register(24, SEQ)          # started
      set_tcp(p[0, 0, 0, 0, 0, 0])                     # the target is the flange's
      jcalib_target = p[x, y, z, rx, ry, rz]
      if not get_inverse_kin_has_solution(jcalib_target):
        write_output_integer_register(25, -SEQ)       # refused: the robot did not move
        halt
      end
      movej(jcalib_target, a=..., v=...)              # or movel
      write_output_integer_register(25, SEQ)          # done
    end

The driver numbers its programs (``SEQ``, continuing from what register 24 holds at connection) and watches the
registers and ``runtime_state`` over RTDE: register 25 = SEQ is a finished move, -SEQ an unreachable target
(:class:`~jcalib.acquisition.robots.base.MotionRefusedError`), a program that started and stopped without either
failed on its path (a runtime error such as a singularity on a ``movel``: also refused). A protective stop, an
emergency stop, a robot that is not powered on and running, or a program that does not start (an e-Series not in
*Remote Control* mode ignores scripts on port 30002) is a :class:`~jcalib.errors.DeviceError` saying what to do
at the teach pendant. A program of an earlier, killed jcalib client still moving is waited for; a program
jcalib did not start is not replaced.

**Stop** (:meth:`UrRobot.stop`): ``stopj(a)`` (after a ``movej``) or ``stopl(a)`` (after a ``movel``) sent on the
same secondary-interface connection as the move. A program sent to the secondary interface replaces the running
one, so the move program ends and the stop program ramps the arm down on its path at the given deceleration;
sending it on the move's own connection keeps the two in order (a stop can never reach the controller before
the move it is meant to stop, which separate connections would allow). This needs nothing installed on the
controller, unlike a resident program driven through RTDE input registers, and it works whichever program
started the motion. The blocked move raises :class:`~jcalib.acquisition.robots.base.MotionStoppedError` once the
arm stands. The driver drains what the controller streams on the secondary interface (robot state at 10 Hz) and
ignores it.
"""

from __future__ import annotations

import socket
import struct
import threading
import time

import numpy as np

from jcalib.acquisition.robots import rtde
from jcalib.acquisition.robots.base import MotionRefusedError, MotionStoppedError, Robot, RobotState
from jcalib.errors import BadInputError, DeviceError
from jcalib.geometry.se3 import invert, pose_from_ur, pose_to_ur

#: Output registers of the move programs: started SEQ, finished SEQ (or -SEQ: refused).
STARTED_REGISTER, RESULT_REGISTER = 24, 25
_REQUIRED = ("timestamp", "actual_q", "actual_qd", "actual_TCP_pose", "robot_mode", "safety_mode", "runtime_state",
             f"output_int_register_{STARTED_REGISTER}", f"output_int_register_{RESULT_REGISTER}")  # fmt: skip
#: Optional fields: dropped from the recipe on a controller that does not know them (then the installation's TCP
#: must be the flange for :meth:`UrRobot.state` to report the flange).
_OPTIONAL = ("tcp_offset",)
#: A move program that has not started after this long did not run, s.
START_TIMEOUT_S = 5.0
#: Joint speed below which a stopped arm counts as standing, rad/s.
STANDING_RAD_S = 1e-3


def _what_to_do(robot_mode: int, safety_mode: int) -> str | None:
    """Why the controller cannot move, with what to do at the teach pendant; None when it can."""
    if safety_mode == rtde.SAFETY_PROTECTIVE_STOP:
        return ("it is in a protective stop (safety mode PROTECTIVE_STOP): find what the arm hit or what tripped it, "
                "clear it with Unlock on the teach pendant, then resume the capture (--resume)")
    if safety_mode in rtde.SAFETY_EMERGENCY_STOPS:
        return (f"it is emergency-stopped (safety mode {rtde.SAFETY_MODES[safety_mode]}): release the emergency stop "
                "button, then power the arm on and release the brakes at the teach pendant, then resume the capture")
    if safety_mode not in (rtde.SAFETY_NORMAL, rtde.SAFETY_REDUCED):
        name = rtde.SAFETY_MODES.get(safety_mode, str(safety_mode))
        return f"its safety system holds it (safety mode {name}): clear that at the teach pendant, then retry"
    if robot_mode != rtde.ROBOT_MODE_RUNNING:
        name = rtde.ROBOT_MODES.get(robot_mode, str(robot_mode))
        return (f"the arm is not running (robot mode {name}): power it on and release the brakes at the teach "
                "pendant (robot mode RUNNING), then retry")
    return None


def move_program(seq: int, T_base_flange: np.ndarray, kind: str, *, speed: float, acceleration: float) -> str:
    """The URScript program of one move (module docstring); ``speed`` / ``acceleration`` in rad/s, rad/s² (joint)
    or m/s, m/s² (linear)."""
    pose = ", ".join(f"{v:.10f}" for v in pose_to_ur(T_base_flange))
    command = "movej" if kind == "joint" else "movel"
    return (
        "def jcalib_move():\n"
        f"  write_output_integer_register({STARTED_REGISTER}, {seq})\n"
        "  set_tcp(p[0.0, 0.0, 0.0, 0.0, 0.0, 0.0])\n"
        f"  jcalib_target = p[{pose}]\n"
        "  if not get_inverse_kin_has_solution(jcalib_target):\n"
        f"    write_output_integer_register({RESULT_REGISTER}, {-seq})\n"
        "    halt\n"
        "  end\n"
        f"  {command}(jcalib_target, a={acceleration:.6g}, v={speed:.6g})\n"
        f"  write_output_integer_register({RESULT_REGISTER}, {seq})\n"
        "end\n"
    )


class RtdeClient:
    """An RTDE connection streaming one output recipe; a reader thread keeps the newest data package.

    Args:
        host, port: the controller's RTDE interface.
        names: output fields to stream (:data:`_REQUIRED`); ``optional`` ones are dropped when the controller
            does not know them.
        frequency_hz: requested rate (capped at 125 Hz on a CB3, 500 Hz on an e-Series).
        timeout_s: connect and reply timeout, and the longest silence of the stream, s.

    Raises:
        DeviceError: cannot connect, version or recipe refused, a required field unknown.
    """

    def __init__(self, host: str, port: int, names, optional=(), *, frequency_hz: float = 125.0,
                 timeout_s: float = 2.0, address: str = "") -> None:  # fmt: skip
        self.address = address or f"{host}:{port}"
        self.timeout_s = float(timeout_s)
        self.messages: list[str] = []  # text messages the controller sent (newest last)
        self._cond = threading.Condition()
        self._latest: dict | None = None
        self._count = 0
        self._error: str | None = None
        try:
            self._sock: socket.socket | None = socket.create_connection((host, int(port)), timeout=self.timeout_s)
        except OSError as e:
            raise DeviceError(f"cannot connect to the RTDE interface of {self.address} ({host}:{port}): {e}. Check that "
                              "the controller is on and reachable (RTDE listens on TCP 30004)") from e
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            ok = self._request(rtde.REQUEST_PROTOCOL_VERSION, struct.pack(">H", rtde.PROTOCOL_VERSION))
            if ok != b"\x01":
                raise DeviceError(f"{self.address} refused RTDE protocol version {rtde.PROTOCOL_VERSION} "
                                  "(a controller older than CB3 3.3?)")
            v = self._request(rtde.GET_URCONTROL_VERSION)
            if len(v) != 16:
                raise DeviceError(f"{self.address} sent a malformed controller version ({len(v)} bytes)")
            self.version = struct.unpack(">IIII", v)
            freq = min(float(frequency_hz), 500.0 if self.version[0] >= 5 else 125.0)
            names = list(names) + list(optional)
            recipe = self._setup(freq, names)
            unknown = [n for n, t in zip(recipe.names, recipe.types) if t not in rtde.TYPE_FORMATS]
            if unknown and set(unknown) <= set(optional):
                names = [n for n in names if n not in unknown]
                recipe = self._setup(freq, names)
                unknown = [n for n, t in zip(recipe.names, recipe.types) if t not in rtde.TYPE_FORMATS]
            if unknown or recipe.id == 0:
                raise DeviceError(f"{self.address} does not stream the RTDE outputs {', '.join(unknown) or names} "
                                  f"(controller {'.'.join(map(str, self.version))}); jcalib needs CB3 3.4 / e-Series 5.0 "
                                  "or later")
            self.recipe = recipe
            if self._request(rtde.START) != b"\x01":
                raise DeviceError(f"{self.address} refused to start RTDE synchronisation")
        except DeviceError:
            self.close()
            raise
        self._sock.settimeout(self.timeout_s)
        self._thread = threading.Thread(target=self._read, name="ur-rtde-reader", daemon=True)
        self._thread.start()

    def _setup(self, frequency_hz: float, names: list[str]) -> rtde.Recipe:
        reply = self._request(rtde.SETUP_OUTPUTS, struct.pack(">d", frequency_hz) + ",".join(names).encode("ascii"))
        if not reply:
            raise DeviceError(f"{self.address} sent an empty reply to the RTDE output setup")
        types = reply[1:].decode("ascii", "replace").split(",")
        if len(types) != len(names):
            raise DeviceError(f"{self.address} answered the RTDE output setup of {len(names)} fields with "
                              f"{len(types)} types")
        return rtde.Recipe(reply[0], tuple(names), tuple(types))

    def _request(self, command: int, payload: bytes = b"") -> bytes:
        """Send one control package and return the payload of the reply with the same command (text messages
        in between are kept in :attr:`messages`)."""
        assert self._sock is not None
        deadline = time.monotonic() + self.timeout_s
        try:
            self._sock.sendall(rtde.encode_package(command, payload))
            while True:
                self._sock.settimeout(max(0.01, deadline - time.monotonic()))
                cmd, body = rtde.read_package(self._sock)
                if cmd == command:
                    return body
                if cmd == rtde.TEXT_MESSAGE:
                    self._keep_message(body)
                if time.monotonic() > deadline:
                    raise socket.timeout()
        except socket.timeout as e:
            raise DeviceError(f"the RTDE interface of {self.address} did not answer within {self.timeout_s} s") from e
        except (OSError, ConnectionError, ValueError) as e:
            raise DeviceError(f"lost the RTDE connection to {self.address}: {e}") from e

    def _keep_message(self, body: bytes) -> None:
        try:
            message, source, level = rtde.decode_text_message(body)
        except ValueError:
            return
        self.messages = (self.messages + [f"{source}: {message}"])[-10:]

    def _read(self) -> None:
        try:
            while True:
                sock = self._sock
                if sock is None:
                    return
                cmd, body = rtde.read_package(sock)
                if cmd == rtde.DATA_PACKAGE:
                    values = self.recipe.unpack(body)
                    with self._cond:
                        self._latest, self._count = values, self._count + 1
                        self._cond.notify_all()
                elif cmd == rtde.TEXT_MESSAGE:
                    self._keep_message(body)
        except socket.timeout:
            error = f"the RTDE stream of {self.address} stopped (no data for {self.timeout_s} s)"
        except (OSError, ConnectionError, ValueError) as e:
            error = f"lost the RTDE connection to {self.address}: {e}"
        with self._cond:
            self._error = error if self._sock is not None else f"the RTDE connection to {self.address} is closed"
            self._cond.notify_all()

    def fresh(self) -> dict:
        """The first data package that arrives after this call.

        Raises:
            DeviceError: the stream stopped or the connection is lost.
        """
        deadline = time.monotonic() + self.timeout_s
        with self._cond:
            seen = self._count
            while self._count == seen:
                if self._error is not None:
                    raise DeviceError(self._error)
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise DeviceError(f"no RTDE data from {self.address} within {self.timeout_s} s")
                self._cond.wait(remaining)
            assert self._latest is not None
            return self._latest

    def close(self) -> None:
        """Pause the stream and close the connection (idempotent)."""
        sock, self._sock = self._sock, None
        if sock is None:
            return
        try:
            sock.settimeout(0.2)
            sock.sendall(rtde.encode_package(rtde.PAUSE))
        except OSError:
            pass
        try:
            sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        sock.close()


class ScriptClient:
    """A connection to the secondary client interface: sends URScript, drains what the controller streams."""

    def __init__(self, host: str, port: int, *, timeout_s: float = 2.0, address: str = "") -> None:
        self.host, self.port, self.timeout_s = host, int(port), float(timeout_s)
        self.address = address or f"{host}:{port}"
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        self._connect()

    def _connect(self) -> None:
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except OSError as e:
            raise DeviceError(f"cannot connect to the secondary interface of {self.address} ({self.host}:{self.port}, "
                              f"which runs URScript): {e}. Check that the controller is reachable and port 30002 is "
                              "open") from e
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        threading.Thread(target=self._drain, args=(sock,), name="ur-secondary-drain", daemon=True).start()

    def _drain(self, sock: socket.socket) -> None:
        try:
            sock.settimeout(None)
            while sock.recv(65536):
                pass
        except OSError:
            pass

    def send(self, script: str) -> None:
        """Send one program; reconnects once when the connection was lost.

        Raises:
            DeviceError: it cannot be delivered.
        """
        data = script.encode("ascii")
        with self._lock:
            for attempt in (0, 1):
                try:
                    if self._sock is None:
                        self._connect()
                    assert self._sock is not None
                    self._sock.sendall(data)
                    return
                except OSError as e:
                    self._close_locked()
                    if attempt:
                        raise DeviceError(f"cannot send URScript to {self.address}: {e}") from e

    def _close_locked(self) -> None:
        if self._sock is not None:
            try:
                self._sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self._sock.close()
            self._sock = None

    def close(self) -> None:
        with self._lock:
            self._close_locked()


class UrRobot(Robot):
    """A Universal Robots controller (module docstring).

    Args:
        host: the controller's address.
        rtde_port, script_port: its RTDE and secondary-interface ports (fixed on a real controller).
        timeout_s: connect and reply timeout, s.
        motion_timeout_s: longest a single move may take before a DeviceError, s.
        frequency_hz: RTDE output rate requested (125..500 Hz).
        joint_speed_rad_s, joint_acceleration_rad_s2: ``movej``'s ``v`` and ``a``.
        linear_speed_m_s, linear_acceleration_m_s2: ``movel``'s ``v`` and ``a``.
        stop_joint_rad_s2, stop_linear_m_s2: decelerations of ``stopj`` / ``stopl``.
        start_timeout_s: a move program that has not started after this long did not run, s.

    Raises:
        DeviceError: cannot connect, or the RTDE setup is refused.
    """

    def __init__(
        self,
        host: str,
        *,
        rtde_port: int = rtde.RTDE_PORT,
        script_port: int = rtde.SCRIPT_PORT,
        timeout_s: float = 2.0,
        motion_timeout_s: float = 120.0,
        frequency_hz: float = 125.0,
        joint_speed_rad_s: float = 1.05,
        joint_acceleration_rad_s2: float = 1.4,
        linear_speed_m_s: float = 0.25,
        linear_acceleration_m_s2: float = 1.2,
        stop_joint_rad_s2: float = 3.0,
        stop_linear_m_s2: float = 1.5,
        start_timeout_s: float = START_TIMEOUT_S,
    ) -> None:
        super().__init__()
        values = {"frequency_hz": (frequency_hz, 1.0, 500.0), "joint_speed_rad_s": (joint_speed_rad_s, 0.01, 3.15),
                  "joint_acceleration_rad_s2": (joint_acceleration_rad_s2, 0.01, 40.0),
                  "linear_speed_m_s": (linear_speed_m_s, 0.001, 3.0),
                  "linear_acceleration_m_s2": (linear_acceleration_m_s2, 0.01, 15.0),
                  "stop_joint_rad_s2": (stop_joint_rad_s2, 0.1, 40.0), "stop_linear_m_s2": (stop_linear_m_s2, 0.1, 15.0)}
        for name, (v, lo, hi) in values.items():
            if not (isinstance(v, (int, float)) and lo <= float(v) <= hi):
                raise BadInputError(f"{name}: expected a number in [{lo}, {hi}], got {v!r}")
        self.host, self.rtde_port, self.script_port = host, int(rtde_port), int(script_port)
        default = (self.rtde_port, self.script_port) == (rtde.RTDE_PORT, rtde.SCRIPT_PORT)
        self.address = f"ur://{host}" if default else f"ur://{host}:{self.rtde_port}:{self.script_port}"
        self.timeout_s, self.motion_timeout_s = float(timeout_s), float(motion_timeout_s)
        self.start_timeout_s = float(start_timeout_s)
        self._speeds = {"joint": (float(joint_speed_rad_s), float(joint_acceleration_rad_s2)),
                        "linear": (float(linear_speed_m_s), float(linear_acceleration_m_s2))}
        self._stop_decel = {"joint": float(stop_joint_rad_s2), "linear": float(stop_linear_m_s2)}
        self._kind = "joint"
        self._stop_sent = -1e9  # time of the last stop program sent (it runs briefly, also on a standing arm)
        self._rtde = RtdeClient(host, self.rtde_port, _REQUIRED, _OPTIONAL, frequency_hz=frequency_hz,
                                timeout_s=timeout_s, address=self.address)
        try:
            self._script = ScriptClient(host, self.script_port, timeout_s=timeout_s, address=self.address)
            p = self._rtde.fresh()
        except DeviceError:
            self._rtde.close()
            raise
        self._seq = max(abs(int(p[f"output_int_register_{STARTED_REGISTER}"])),
                        abs(int(p[f"output_int_register_{RESULT_REGISTER}"])))  # fmt: skip

    @property
    def controller_version(self) -> tuple[int, int, int, int]:
        """``(major, minor, bugfix, build)`` as the controller reports it over RTDE."""
        return self._rtde.version

    def state(self) -> RobotState:
        p = self._rtde.fresh()
        return RobotState(self._flange(p), np.degrees(np.asarray(p["actual_q"], dtype=np.float64)))

    def _flange(self, p: dict) -> np.ndarray:
        try:
            T = pose_from_ur(p["actual_TCP_pose"])
            if "tcp_offset" in p:
                T = T @ invert(pose_from_ur(p["tcp_offset"]))
        except (ValueError, FloatingPointError) as e:
            raise DeviceError(f"robot at {self.address}: malformed pose {p['actual_TCP_pose']}: {e}") from e
        if not np.all(np.isfinite(T)):
            raise DeviceError(f"robot at {self.address} reports a non-finite pose {p['actual_TCP_pose']}")
        return T

    @staticmethod
    def _registers(p: dict) -> tuple[int, int]:
        return int(p[f"output_int_register_{STARTED_REGISTER}"]), int(p[f"output_int_register_{RESULT_REGISTER}"])

    def _wait_ready(self, what: str) -> None:
        """Refuse a move the controller cannot make (what to do in the message); wait for a move program of an
        earlier jcalib client that is still running."""
        deadline = time.monotonic() + self.motion_timeout_s
        while True:
            p = self._rtde.fresh()
            why = _what_to_do(int(p["robot_mode"]), int(p["safety_mode"]))
            if why is not None:
                raise DeviceError(f"robot at {self.address} cannot {what}: {why}")
            runtime = int(p["runtime_state"])
            if runtime == rtde.RUNTIME_STOPPED:
                return
            started, result = self._registers(p)
            ours = started != abs(result) or time.monotonic() - self._stop_sent < self.start_timeout_s
            if runtime != rtde.RUNTIME_PLAYING or not ours:
                state = rtde.RUNTIME_STATES.get(runtime, str(runtime))
                raise DeviceError(
                    f"robot at {self.address} cannot {what}: a program jcalib did not start is {state.lower()} on the "
                    "controller (runtime state " + state + "); stop it at the teach pendant first (a program sent "
                    "to port 30002 would replace it)")
            if time.monotonic() > deadline:
                raise DeviceError(f"robot at {self.address}: jcalib's motion program {started} of an earlier client is "
                                  f"still running after {self.motion_timeout_s} s, so the {what} cannot start")

    def _move(self, T_base_flange: np.ndarray, kind: str) -> None:
        what = "movej" if kind == "joint" else "movel"
        self._wait_ready(what)
        stops = self.num_stops
        speed, acceleration = self._speeds[kind]
        with self._starting(what):
            self._seq = self._seq + 1 if self._seq < 2**31 - 2 else 1
            seq = self._seq
            self._kind = kind
            self._script.send(move_program(seq, T_base_flange, kind, speed=speed, acceleration=acceleration))
        self._wait_move(seq, what, stops)

    def _wait_move(self, seq: int, what: str, stops: int) -> None:
        t0 = time.monotonic()
        started = False
        while True:
            p = self._rtde.fresh()
            now = time.monotonic()
            reg_started, reg_result = self._registers(p)
            runtime = int(p["runtime_state"])
            if reg_result == seq:
                self._wait_program_end(what)
                return
            why = _what_to_do(int(p["robot_mode"]), int(p["safety_mode"]))
            if why is not None:
                raise DeviceError(f"robot at {self.address}: the {what} did not finish: {why}")
            if reg_result == -seq:
                raise MotionRefusedError(f"robot at {self.address} refused the {what}: target unreachable (outside "
                                         "reach or joint limits, get_inverse_kin_has_solution false); the robot did not "
                                         "move")
            started = started or reg_started == seq
            stopped = self.num_stops != stops
            standing = float(np.max(np.abs(p["actual_qd"]))) < STANDING_RAD_S
            if stopped and runtime != rtde.RUNTIME_PLAYING and standing:
                raise MotionStoppedError(f"robot at {self.address}: the {what} was stopped (stopj / stopl); the robot "
                                         "stands where it braked")
            if started and not stopped and runtime == rtde.RUNTIME_STOPPED:
                notes = f" (controller: {self._rtde.messages[-1]})" if self._rtde.messages else ""
                raise MotionRefusedError(f"robot at {self.address}: the {what} program ended before the motion "
                                         f"finished: a runtime error on the way (a path through a singularity or a "
                                         f"joint limit, a linear move that cannot be followed){notes}")
            if not started and not stopped and now - t0 > self.start_timeout_s:
                raise DeviceError(f"robot at {self.address} did not run the motion program sent to its secondary "
                                  f"interface (port {self.script_port}) within {self.start_timeout_s} s: an e-Series must "
                                  "be in Remote Control mode (teach pendant, top right) for it to run scripts; check "
                                  "also that no popup waits on the teach pendant")
            if now - t0 > self.motion_timeout_s:
                raise DeviceError(f"robot at {self.address}: the {what} did not finish within {self.motion_timeout_s} s "
                                  "(speed slider at 0 %, a paused program?)")

    def _wait_program_end(self, what: str) -> None:
        """After the done register, wait for the program to end (it has one statement left)."""
        deadline = time.monotonic() + max(2.0, self.timeout_s)
        while int(self._rtde.fresh()["runtime_state"]) == rtde.RUNTIME_PLAYING:
            if time.monotonic() > deadline:
                raise DeviceError(f"robot at {self.address}: the {what} program reported its move done but did not end")

    def _stop(self) -> None:
        kind = self._kind
        command = "stopj" if kind == "joint" else "stopl"
        self._stop_sent = time.monotonic()
        try:
            self._script.send(f"def jcalib_stop():\n  {command}({self._stop_decel[kind]:.6g})\nend\n")
        except DeviceError as e:
            raise DeviceError(f"{e}: stop the robot at the teach pendant") from e

    def close(self) -> None:
        self._script.close()
        self._rtde.close()
