"""A simulated ABB controller running the jcalib line protocol (``robot/abb/PROTOCOL.md``).

It answers exactly like ``robot/abb/JcalibServer.mod``: one client at a time is served (RAPID has one
socket server task), every reply is one line of at most 80 bytes, unreachable targets are refused with
``ERR 2 UNREACHABLE`` before the robot moves. A client that sends nothing for ``idle_timeout_s`` is
disconnected, so an idle (or dead) client cannot hold the one server task; a request the parser
cannot make sense of (non-finite numbers included) is ``ERR 1 SYNTAX``. Start it in-process with ``AbbSimServer(...).start()`` or
as a subprocess with ``python -m jcalib.acquisition.robots.serve --protocol abb``.

The stop port is a second listener, as the RAPID stop task is a second task: ``STOP`` (one request per
connection) bumps a stop counter and halts a motion in progress; a move compares the counter with its
value when the request arrived, right after the motion starts and when it ends, as ``DoMove`` does with
``jc_stop_seq``, and answers ``ERR 6 STOPPED``.
"""

from __future__ import annotations

import socket
import threading
import time

import numpy as np

from jcalib.acquisition.robots._server import ThreadedTcpServer
from jcalib.acquisition.robots.base import MotionStoppedError
from jcalib.acquisition.robots.abb import MAX_LINE, PROTOCOL_VERSION, LineSocket, encode_line, format_pose_args, parse_pose_args
from jcalib.acquisition.robots.simulated import SimulatedController, UnreachableError
from jcalib.errors import BadInputError


class _StopTask(ThreadedTcpServer):
    """The ``JcalibStop`` task: one request per connection on the stop port."""

    name = "abb-sim-stop"

    def __init__(self, owner: "AbbSimServer", host: str, port: int, **kw):
        super().__init__(host, port, **kw)
        self.owner = owner

    def serve_connection(self, conn: socket.socket) -> None:
        try:
            line = LineSocket(conn).readline().strip().upper()
        except ValueError:
            line = ""
        except ConnectionError:
            return
        if line == "STOP":
            reply = "OK STOPPED" if self.owner.request_stop() else "OK IDLE"
        elif line == "PING":
            reply = f"OK JCALIB {PROTOCOL_VERSION}"
        else:
            reply = "ERR 5 UNKNOWN" if line else "ERR 1 SYNTAX"
        conn.sendall(encode_line(reply))


class AbbSimServer(ThreadedTcpServer):
    """The RAPID server's behaviour on loopback, backed by a simulated controller.

    Args:
        controller: the simulated arm (a default :class:`SimulatedController` when None).
        host, port: listening address (loopback only unless ``allow_non_loopback``); 0 = any free port.
        stop_port: port of the stop task; None: ``port + 1`` for a given port, any free one for ``port=0``.
    """

    name = "abb-sim"

    def __init__(
        self,
        controller: SimulatedController | None = None,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        allow_non_loopback: bool = False,
        idle_timeout_s: float = 30.0,
        stop_port: int | None = None,
    ):
        super().__init__(host, port, allow_non_loopback=allow_non_loopback, idle_timeout_s=idle_timeout_s)
        self.controller = controller if controller is not None else SimulatedController()
        self.settle_s = 0.0
        self._one_client = threading.Lock()  # RAPID serves one connection at a time
        self.num_requests = 0
        self._stop_seq = 0  # jc_stop_seq
        self._moving = False  # jc_moving
        self._stop_lock = threading.Lock()
        if stop_port is None:
            stop_port = 0 if port == 0 else self.port + 1
        try:
            self.stop_task = _StopTask(self, host, stop_port, allow_non_loopback=allow_non_loopback,
                                       idle_timeout_s=min(idle_timeout_s, 5.0))
        except BaseException:
            self._sock.close()
            raise
        self.stop_port = self.stop_task.port

    def start(self) -> "AbbSimServer":
        super().start()
        self.stop_task.start()
        return self

    def stop(self) -> None:
        self.stop_task.stop()
        super().stop()

    def request_stop(self) -> bool:
        """What the stop task does on ``STOP``: bump ``jc_stop_seq`` (the motion task's interrupt then brakes
        a motion in progress); True when a move request was being served (``jc_moving``)."""
        with self._stop_lock:
            self._stop_seq += 1
            moving = self._moving
        if moving:
            self.controller.halt()
        return moving

    def handle(self, line: str) -> tuple[str, bool]:
        """One request line -> (reply line, keep the connection open)."""
        try:
            return self._handle(line)
        except Exception:  # noqa: BLE001 - RAPID's ERROR handler answers a malformed request, it never stops
            return "ERR 1 SYNTAX", True

    def _handle(self, line: str) -> tuple[str, bool]:
        tok = line.split()
        if not tok:
            return "ERR 1 SYNTAX", True
        cmd, args = tok[0].upper(), tok[1:]
        c = self.controller
        try:
            if cmd == "PING" and not args:
                return f"OK JCALIB {PROTOCOL_VERSION} {self.stop_port}", True
            if cmd == "BYE":
                return "OK", False
            if cmd == "GETP" and not args:
                return "POSE " + format_pose_args(c.T_base_tool()), True
            if cmd == "GETJ" and not args:
                return "JNT " + " ".join(f"{v:.3f}" for v in np.degrees(c.joints_rad())), True
            if cmd in ("MOVJ", "MOVL"):
                try:
                    T = parse_pose_args(args)
                except (ValueError, BadInputError):
                    return "ERR 1 SYNTAX", True
                return self._move(T, "joint" if cmd == "MOVJ" else "linear"), True
            if cmd in ("TOOL", "WOBJ", "SPEED", "SETTLE"):
                if len(args) != 1:
                    return "ERR 1 SYNTAX", True
                try:
                    v = float(args[0])
                except ValueError:
                    return "ERR 1 SYNTAX", True
                if not np.isfinite(v):
                    return "ERR 1 SYNTAX", True
                if cmd in ("TOOL", "WOBJ"):
                    if v != int(v) or not 0 <= v <= 4:
                        return "ERR 3 RANGE", True
                    try:
                        (c.select_tool if cmd == "TOOL" else c.select_base)(int(v))
                    except BadInputError:
                        return "ERR 3 RANGE", True
                elif cmd == "SPEED":
                    if not 1.0 <= v <= 2000.0:
                        return "ERR 3 RANGE", True
                    c.linear_speed_m_s = v / 1000.0
                else:
                    if not 0.0 <= v <= 10.0:
                        return "ERR 3 RANGE", True
                    self.settle_s = v
                return "OK", True
            if cmd in ("PING", "GETP", "GETJ"):
                return "ERR 1 SYNTAX", True
            return "ERR 5 UNKNOWN", True
        finally:
            self.num_requests += 1

    def _move(self, T: np.ndarray, kind: str) -> str:
        """``DoMove``: reach check, ``MoveJ \\Conc``, a stop since the request stops it, ``WaitRob \\InPos``."""
        c = self.controller
        with self._stop_lock:
            seq0 = self._stop_seq
            self._moving = True
        try:
            try:
                c.start_move(T, kind)
            except UnreachableError as e:
                return "ERR 4 MOTION" if e.on_path else "ERR 2 UNREACHABLE"
            if self._stop_seq != seq0:  # a STOP came before the motion was on the path
                c.halt()
            try:
                c.wait_motion()
            except MotionStoppedError:
                return "ERR 6 STOPPED"
        finally:
            with self._stop_lock:
                self._moving = False
        if self._stop_seq != seq0:
            return "ERR 6 STOPPED"
        if self.settle_s > 0:
            time.sleep(self.settle_s * c.time_scale)
        return "OK"

    def serve_connection(self, conn: socket.socket) -> None:
        with self._one_client:
            lines = LineSocket(conn)
            while not self._stop.is_set():
                try:
                    line = lines.readline()
                except ValueError:  # longer than a RAPID string: what RAPID would see is garbage
                    conn.sendall(encode_line("ERR 1 SYNTAX"))
                    return
                except ConnectionError:
                    return
                reply, keep = self.handle(line)
                data = encode_line(reply)
                assert len(data) <= MAX_LINE
                conn.sendall(data)
                if not keep:
                    return
