"""A simulated Universal Robots controller: the RTDE interface (30004) and the secondary interface (30002, URScript).

Behind both sits one :class:`~jcalib.acquisition.robots.simulated.SimulatedController` (``jcalib simulate`` gives
it the ``ur5e`` preset). What a client sees:

- **RTDE** (:mod:`~jcalib.acquisition.robots.rtde`, protocol version 2 only): controller version 5.15.0 (an
  e-Series), every output field of :data:`~jcalib.acquisition.robots.rtde.OUTPUTS` and the numbered registers
  (fields the simulation has no value for read 0), input recipes writing the input registers (``IN_USE`` when
  another client has one), streaming at the requested frequency (1..500 Hz; packages are skipped, not queued,
  when the simulator falls behind, as a controller does). ``actual_q``, ``actual_qd``, ``actual_TCP_pose`` (the
  active TCP in the base frame, UR's ``[x, y, z, rx, ry, rz]``), ``tcp_offset``, ``robot_mode`` (7 RUNNING),
  ``safety_mode``, ``runtime_state`` and the output registers are the simulated controller's. A package whose
  size field is below the header's drops that client; anything else malformed (a wrong payload, an unknown
  command or field) is answered with an error text message or a refused setup, and the connection stays.
  Clients that have not started streaming time out after ``idle_timeout_s``.
- **Secondary interface**: URScript programs (the subset of :mod:`~jcalib.acquisition.robots.urscript`) run in a
  program thread, ``runtime_state`` PLAYING meanwhile. A program that arrives while another runs replaces it:
  the running one is aborted (the arm brakes on its path) and the new one starts, as on a controller. A program
  that does not compile, or arrives during a protective or emergency stop, is not run (:attr:`UrSimServer.errors`
  says why). ``movej`` / ``movel`` to an unreachable pose or along an unfollowable path is a runtime error that
  ends the program (the arm did not move, or brakes where the path failed). Bytes that are not ASCII text drop
  that client. The robot state a controller streams on this port at 10 Hz is not simulated.
- **Faults on request**: :meth:`UrSimServer.protective_stop` (also URScript ``protective_stop()``),
  :meth:`UrSimServer.emergency_stop`, :meth:`UrSimServer.unlock` (the pendant's Unlock / reset), and
  :attr:`UrSimServer.robot_mode` (set it to 3, POWER_OFF, for an arm that is not running),
  :attr:`UrSimServer.remote_control` (False: an e-Series in Local mode, which ignores scripts on port 30002).

Everything listens on loopback unless ``allow_non_loopback``. Ports are UR's (30004, 30002) unless given; port 0
picks a free one (:attr:`UrSimServer.url` names both).
"""

from __future__ import annotations

import socket
import struct
import threading
import time

import numpy as np

from jcalib.acquisition.robots import rtde
from jcalib.acquisition.robots._server import ThreadedTcpServer
from jcalib.acquisition.robots.base import MotionStoppedError
from jcalib.acquisition.robots.simulated import SimulatedController, UnreachableError
from jcalib.acquisition.robots.urscript import ScriptError, Statement, parse_program, split_program
from jcalib.errors import BadInputError
from jcalib.geometry.se3 import invert, pose_from_ur, pose_to_ur

#: What the simulator reports as its controller version (an e-Series, 5.15.0).
VERSION = (5, 15, 0, 0)
_ZERO = {"BOOL": False, "UINT8": 0, "UINT32": 0, "UINT64": 0, "INT32": 0, "DOUBLE": 0.0, "VECTOR3D": (0.0,) * 3,
         "VECTOR6D": (0.0,) * 6, "VECTOR6INT32": (0,) * 6, "VECTOR6UINT32": (0,) * 6}  # fmt: skip
_SAFETY_BITS = {1: 0, 2: 1, 3: 2, 4: 3, 5: 4, 6: 5, 7: 6, 8: 8, 9: 9}


class _Abort(Exception):
    """The running program ends: replaced, stopped, halted, or a runtime error (the message)."""


class _SecondaryInterface(ThreadedTcpServer):
    """Port 30002: splits each client's stream into programs and hands them to the controller."""

    name = "ur-sim-secondary"

    def __init__(self, owner: "UrSimServer", host: str, port: int, **kw):
        super().__init__(host, port, **kw)
        self.owner = owner

    def serve_connection(self, conn: socket.socket) -> None:
        conn.settimeout(0.5)  # no idle timeout: a driver keeps this connection open between moves
        buf = bytearray()
        while not self._stop.is_set():
            try:
                chunk = conn.recv(4096)
            except socket.timeout:
                continue
            if not chunk:
                return
            buf += chunk
            while True:
                try:
                    program, used = split_program(bytes(buf))
                except ScriptError as e:
                    self.owner.record_error(f"secondary interface: {e}; client dropped")
                    self.num_dropped += 1
                    return
                if program is None:
                    break
                del buf[:used]
                if program.strip():
                    self.owner.run_script(program)


class UrSimServer(ThreadedTcpServer):
    """A UR controller's RTDE and secondary interfaces on loopback, backed by a simulated controller.

    Args:
        controller: the simulated arm (a default :class:`SimulatedController` when None).
        host: listening address (loopback only unless ``allow_non_loopback``).
        port: RTDE port (30004 by default; 0 = any free port).
        script_port: secondary-interface port (None: 30002 with the default RTDE port, else any free port).
        idle_timeout_s: an RTDE client that sends nothing before starting its stream is dropped after this long.
    """

    name = "ur-sim-rtde"

    def __init__(
        self,
        controller: SimulatedController | None = None,
        host: str = "127.0.0.1",
        port: int = rtde.RTDE_PORT,
        *,
        script_port: int | None = None,
        allow_non_loopback: bool = False,
        idle_timeout_s: float = 30.0,
    ) -> None:
        super().__init__(host, port, allow_non_loopback=allow_non_loopback, idle_timeout_s=idle_timeout_s)
        self.controller = controller if controller is not None else SimulatedController()
        if script_port is None:
            script_port = rtde.SCRIPT_PORT if port == rtde.RTDE_PORT else 0
        try:
            self.secondary = _SecondaryInterface(self, host, script_port, allow_non_loopback=allow_non_loopback,
                                                 idle_timeout_s=idle_timeout_s)
        except BaseException:
            self._sock.close()
            raise
        self.script_port = self.secondary.port
        #: 7 = RUNNING; set 3 (POWER_OFF) etc. to simulate an arm that cannot move.
        self.robot_mode = rtde.ROBOT_MODE_RUNNING
        #: False: an e-Series in Local mode, which ignores programs sent to the secondary interface.
        self.remote_control = True
        self.safety_mode = rtde.SAFETY_NORMAL
        self.runtime_state = rtde.RUNTIME_STOPPED
        self.errors: list[str] = []  # why programs were refused or ended early (newest last, 50 kept)
        self.num_programs = 0  # programs started
        self.num_requests = 0  # RTDE control packages served
        self._out_int = [0] * 48
        self._out_double = [0.0] * 48
        self._in_int = [0] * 48
        self._in_double = [0.0] * 48
        self._in_bits = [False] * 128
        self._lock = threading.RLock()
        self._program: tuple[threading.Thread, threading.Event] | None = None
        self._program_lock = threading.Lock()  # one program switch at a time
        self._input_owners: dict[str, int] = {}
        self._t0 = time.monotonic()
        self._snapshot: tuple[float, dict] = (-1.0, {})

    @property
    def url(self) -> str:
        """``ur://HOST`` on UR's ports, else ``ur://HOST:RTDE_PORT:SCRIPT_PORT``."""
        if (self.port, self.script_port) == (rtde.RTDE_PORT, rtde.SCRIPT_PORT):
            return f"ur://{self.host}"
        return f"ur://{self.host}:{self.port}:{self.script_port}"

    def start(self) -> "UrSimServer":
        super().start()
        self.secondary.start()
        return self

    def stop(self) -> None:
        self._abort_program("the simulator stops")
        self.secondary.stop()
        super().stop()

    def record_error(self, message: str) -> None:
        with self._lock:
            self.errors = (self.errors + [message])[-50:]

    # --- faults ----------------------------------------------------------------------------------
    def protective_stop(self) -> None:
        """Trip a protective stop: the arm halts, the running program ends, programs are refused until :meth:`unlock`."""
        with self._lock:
            self.safety_mode = rtde.SAFETY_PROTECTIVE_STOP
        self.controller.halt()
        self._abort_program("protective stop", join=threading.current_thread() is not self._program_thread())

    def emergency_stop(self) -> None:
        """Press the robot's emergency stop (safety mode ROBOT_EMERGENCY_STOP): as a protective stop."""
        with self._lock:
            self.safety_mode = 7
        self.controller.halt()
        self._abort_program("emergency stop")

    def unlock(self) -> None:
        """Clear a protective or emergency stop (the pendant's Unlock, or releasing the button and powering on)."""
        with self._lock:
            self.safety_mode = rtde.SAFETY_NORMAL

    # --- programs --------------------------------------------------------------------------------
    def _program_thread(self) -> threading.Thread | None:
        current = self._program
        return current[0] if current is not None else None

    def _abort_program(self, why: str, join: bool = True) -> None:
        current = self._program
        if current is None:
            return
        thread, abort = current
        if thread.is_alive() and not abort.is_set():
            abort.set()
            self.controller.halt()
        if join and thread is not threading.current_thread():
            thread.join(10.0)

    def run_script(self, text: str) -> bool:
        """Compile and start one program, replacing a running one; False (and :attr:`errors` says why) when refused."""
        try:
            program = parse_program(text)
        except ScriptError as e:
            self.record_error(f"compile error: {e}")
            return False
        with self._program_lock:
            self._abort_program("replaced by a new program")
            with self._lock:
                if not self.remote_control:
                    self.record_error("program ignored: the controller is not in Remote Control mode")
                    return False
                if self.safety_mode not in (rtde.SAFETY_NORMAL, rtde.SAFETY_REDUCED) or \
                        self.robot_mode != rtde.ROBOT_MODE_RUNNING:
                    self.record_error(f"program not started: safety mode {self.safety_mode}, robot mode "
                                      f"{self.robot_mode}")
                    return False
                abort = threading.Event()
                thread = threading.Thread(target=self._execute, args=(program, abort), name="ur-sim-program",
                                          daemon=True)  # fmt: skip
                self._program = (thread, abort)
                self.runtime_state = rtde.RUNTIME_PLAYING
                self.num_programs += 1
            thread.start()
        return True

    def _execute(self, program: list[Statement], abort: threading.Event) -> None:
        try:
            self._run(program, abort)
        except _Abort as e:
            if str(e):
                self.record_error(str(e))
        except Exception as e:  # noqa: BLE001 - a program error never takes the controller down
            self.record_error(f"runtime error: {type(e).__name__}: {e}")
        finally:
            with self._lock:
                if self._program is not None and self._program[1] is abort:
                    self.runtime_state = rtde.RUNTIME_STOPPED

    def _run(self, program: list[Statement], abort: threading.Event) -> None:
        c = self.controller
        for st in program:
            if abort.is_set():
                raise _Abort("")
            if st.kind == "register":
                with self._lock:
                    self._out_int[st.args[0]] = st.args[1]
            elif st.kind == "set_tcp":
                T = pose_from_ur(st.args[0])
                if np.allclose(T, np.eye(4), atol=1e-12):
                    c.select_tool(0)
                else:
                    c.set_tool(1, T)
            elif st.kind == "if_no_ik":
                T_flange = pose_from_ur(st.args[0]) @ invert(c.tools[c.tool])
                if not c.model.inverse(T_flange, c.joints_rad()).ok:
                    self._run(st.body, abort)
            elif st.kind == "move":
                self._move(st.args, abort)
            elif st.kind == "stop":
                c.halt()
                try:
                    c.wait_motion()
                except MotionStoppedError:
                    pass
            elif st.kind == "halt":
                raise _Abort("")
            elif st.kind == "protective_stop":
                self.protective_stop()
                raise _Abort("protective stop requested by the program")
            elif st.kind == "sleep":
                if abort.wait(st.args[0] * max(c.time_scale, 0.0)):
                    raise _Abort("")

    def _move(self, args: tuple, abort: threading.Event) -> None:
        command, what, values, opts = args
        c = self.controller
        kind = "joint" if command == "movej" else "linear"
        v = opts.get("v")
        if v:
            if kind == "linear":
                c.linear_speed_m_s = float(v)
            else:
                c.speed_fraction = float(np.clip(v / float(np.max(c.model.joint_speed_rad_s)), 0.01, 1.0))
        if what == "joints":
            T = c.model.forward(np.asarray(values, dtype=np.float64)) @ c.tools[c.tool]
        else:
            T = pose_from_ur(values)
        try:
            c.start_move(T, kind)
        except (UnreachableError, BadInputError) as e:
            raise _Abort(f"runtime error: {command}: {e}") from None
        if abort.is_set():
            c.halt()
        try:
            c.wait_motion()
        except MotionStoppedError:
            raise _Abort("") from None

    # --- RTDE --------------------------------------------------------------------------------------
    def _state(self) -> dict:
        """The controller's values, shared by all clients (recomputed at most every millisecond)."""
        now = time.monotonic()
        with self._lock:
            t, snap = self._snapshot
            if now - t < 1e-3:
                return snap
            q, qd, T, T_tool = self.controller.snapshot()
            pose, offset = tuple(pose_to_ur(T)), tuple(pose_to_ur(T_tool))
            running = self.runtime_state == rtde.RUNTIME_PLAYING
            bits = 1 << _SAFETY_BITS.get(self.safety_mode, 10)
            snap = {"timestamp": now - self._t0, "actual_q": tuple(q), "target_q": tuple(q), "actual_qd": tuple(qd),
                    "target_qd": tuple(qd), "actual_TCP_pose": pose, "target_TCP_pose": pose, "tcp_offset": offset,
                    "robot_mode": self.robot_mode, "safety_mode": self.safety_mode, "safety_status": self.safety_mode,
                    "runtime_state": self.runtime_state, "joint_mode": (253,) * 6, "speed_scaling": 1.0,
                    "target_speed_fraction": 1.0, "robot_status_bits": 1 | (2 if running else 0),
                    "safety_status_bits": bits, "actual_main_voltage": 48.0, "actual_robot_voltage": 48.0,
                    "joint_temperatures": (30.0,) * 6, "actual_execution_time": 0.5}  # fmt: skip
            for i in range(48):
                snap[f"output_int_register_{i}"] = self._out_int[i]
                snap[f"output_double_register_{i}"] = self._out_double[i]
                snap[f"input_int_register_{i}"] = self._in_int[i]
                snap[f"input_double_register_{i}"] = self._in_double[i]
            self._snapshot = (now, snap)
            return snap

    def _values(self, recipe: rtde.Recipe) -> dict:
        snap = self._state()
        out = {}
        for name, t in zip(recipe.names, recipe.types):
            if name in snap:
                out[name] = snap[name]
            elif name.startswith("input_bit_register_"):
                out[name] = self._in_bits[int(name.rsplit("_", 1)[1])]
            else:
                out[name] = _ZERO[t]
        return out

    def serve_connection(self, conn: socket.socket) -> None:
        _RtdeSession(self, conn).serve()


class _RtdeSession:
    """One RTDE client: its negotiated version, recipes and stream."""

    def __init__(self, server: UrSimServer, conn: socket.socket) -> None:
        self.server, self.conn = server, conn
        self.version = 0
        self.outputs: rtde.Recipe | None = None
        self.frequency = 125.0
        self.inputs: dict[int, rtde.Recipe] = {}
        self.send_lock = threading.Lock()
        self.streaming: threading.Event | None = None

    def send(self, command: int, payload: bytes = b"") -> None:
        with self.send_lock:
            self.conn.sendall(rtde.encode_package(command, payload))

    def error(self, message: str) -> None:
        with self.send_lock:
            self.conn.sendall(rtde.encode_text_message(message, "RTDE", rtde.ERROR_MESSAGE))

    def serve(self) -> None:
        srv, conn = self.server, self.conn
        conn.settimeout(0.5)
        buf, idle = bytearray(), 0.0
        try:
            while not srv._stop.is_set():
                try:
                    chunk = conn.recv(65536)
                except socket.timeout:
                    idle = 0.0 if self.streaming is not None else idle + 0.5
                    if idle >= srv.idle_timeout_s:
                        return
                    continue
                if not chunk:
                    return
                idle = 0.0
                buf += chunk
                while len(buf) >= rtde.HEADER.size:
                    size, command = rtde.HEADER.unpack_from(buf)
                    if size < rtde.HEADER.size:
                        srv.num_dropped += 1  # not RTDE framing
                        return
                    if len(buf) < size:
                        break
                    payload = bytes(buf[rtde.HEADER.size : size])
                    del buf[:size]
                    self.handle(command, payload)
        finally:
            self.stop_stream()
            with srv._lock:
                for name in [n for n, owner in srv._input_owners.items() if owner == id(self)]:
                    del srv._input_owners[name]

    def handle(self, command: int, payload: bytes) -> None:
        srv = self.server
        srv.num_requests += 1
        if command == rtde.REQUEST_PROTOCOL_VERSION:
            ok = len(payload) == 2 and struct.unpack(">H", payload)[0] == rtde.PROTOCOL_VERSION
            if ok:
                self.version = rtde.PROTOCOL_VERSION
            self.send(command, b"\x01" if ok else b"\x00")
        elif command == rtde.GET_URCONTROL_VERSION:
            self.send(command, struct.pack(">IIII", *VERSION))
        elif command == rtde.SETUP_OUTPUTS:
            self.setup_outputs(payload)
        elif command == rtde.SETUP_INPUTS:
            self.setup_inputs(payload)
        elif command == rtde.START:
            self.send(command, b"\x01" if self.version == rtde.PROTOCOL_VERSION else b"\x00")
            if self.version == rtde.PROTOCOL_VERSION:
                self.start_stream()
        elif command == rtde.PAUSE:
            self.stop_stream()
            self.send(command, b"\x01")
        elif command == rtde.DATA_PACKAGE:
            self.write_inputs(payload)
        elif command == rtde.TEXT_MESSAGE:
            pass  # a client's message for the log
        else:
            self.error(f"unknown RTDE command {command}")

    def setup_outputs(self, payload: bytes) -> None:
        names = rtde.parse_names(payload[8:]) if len(payload) > 8 else None
        freq = struct.unpack(">d", payload[:8])[0] if len(payload) >= 8 else float("nan")
        if self.version != rtde.PROTOCOL_VERSION or self.streaming is not None or names is None \
                or not 0.0 < freq <= 500.0:  # (also refuses nan)
            self.error("output setup refused: negotiate protocol version 2 first, pause the stream, give a frequency "
                       "in (0, 500] Hz and comma-separated field names")
            self.send(rtde.SETUP_OUTPUTS, b"\x00")
            return
        types = tuple(rtde.field_type(n) or "NOT_FOUND" for n in names)
        ok = "NOT_FOUND" not in types
        self.send(rtde.SETUP_OUTPUTS, bytes([1 if ok else 0]) + ",".join(types).encode("ascii"))
        if ok:
            self.outputs, self.frequency = rtde.Recipe(1, tuple(names), types), float(freq)

    def setup_inputs(self, payload: bytes) -> None:
        srv = self.server
        names = rtde.parse_names(payload)
        if self.version != rtde.PROTOCOL_VERSION or self.streaming is not None or names is None \
                or len(self.inputs) >= 255:
            self.error("input setup refused: negotiate protocol version 2 first, pause the stream and give "
                       "comma-separated field names")
            self.send(rtde.SETUP_INPUTS, b"\x00")
            return
        with srv._lock:
            types = tuple(
                "IN_USE" if srv._input_owners.get(n, id(self)) != id(self) else (rtde.field_type(n, True) or "NOT_FOUND")
                for n in names)  # fmt: skip
            ok = all(t in rtde.TYPE_FORMATS for t in types)
            recipe_id = len(self.inputs) + 1 if ok else 0
            if ok:
                for n in names:
                    srv._input_owners[n] = id(self)
                self.inputs[recipe_id] = rtde.Recipe(recipe_id, tuple(names), types)
        self.send(rtde.SETUP_INPUTS, bytes([recipe_id]) + ",".join(types).encode("ascii"))

    def write_inputs(self, payload: bytes) -> None:
        recipe = self.inputs.get(payload[0]) if payload else None
        try:
            if recipe is None:
                raise ValueError("no input recipe with that id")
            values = recipe.unpack(payload)
        except ValueError as e:
            self.error(f"data package refused: {e}")
            return
        srv = self.server
        with srv._lock:
            for name, v in values.items():
                kind, _, index = name.rpartition("_")
                if name.startswith("input_int_register_"):
                    srv._in_int[int(index)] = int(v)
                elif name.startswith("input_double_register_"):
                    srv._in_double[int(index)] = float(v)
                elif name.startswith("input_bit_register_"):
                    srv._in_bits[int(index)] = bool(v)

    def start_stream(self) -> None:
        if self.streaming is not None or self.outputs is None:
            self.streaming = self.streaming or threading.Event()
            return
        stop = threading.Event()
        self.streaming = stop
        threading.Thread(target=self.stream, args=(self.outputs, self.frequency, stop), name="ur-sim-stream",
                         daemon=True).start()  # fmt: skip

    def stop_stream(self) -> None:
        if self.streaming is not None:
            self.streaming.set()
            self.streaming = None

    def stream(self, recipe: rtde.Recipe, frequency: float, stop: threading.Event) -> None:
        period = 1.0 / frequency
        deadline = time.monotonic()
        try:
            while not stop.is_set() and not self.server._stop.is_set():
                self.send(rtde.DATA_PACKAGE, recipe.pack(self.server._values(recipe)))
                deadline += period
                now = time.monotonic()
                if deadline < now - period:  # fallen behind: skip packages rather than queue them
                    deadline = now
                stop.wait(max(0.0, deadline - now))
        except (OSError, struct.error):
            stop.set()
