"""ABB IRC5 / OmniCore robots through the jcalib RAPID socket server (``robot/abb/JcalibServer.mod``).

The line protocol is specified in ``robot/abb/PROTOCOL.md``; in short: TCP (port 5515), ASCII, one
request line then one reply line, each terminated by LF and at most 80 bytes including the LF (RAPID
strings hold 80 characters, so no message is ever split). Positions in mm (3 decimals), orientation as
ABB quaternion ``q1..q4`` = ``wxyz`` (6 decimals), joints in degrees.

=============================  =====================================================================
request                        reply
=============================  =====================================================================
``PING``                       ``OK JCALIB 2 <stop port>`` (protocol version, port of the stop task)
``GETP``                       ``POSE x y z q1 q2 q3 q4`` active tool in the active work object
``GETJ``                       ``JNT j1 j2 j3 j4 j5 j6``
``MOVJ x y z q1 q2 q3 q4``     ``OK`` once stopped at the fine point and ``SETTLE`` seconds later
``MOVL x y z q1 q2 q3 q4``     same, straight line
``TOOL n`` / ``WOBJ n``        ``OK`` (0 = tool0 / wobj0, 1..4 = the module's jc_tools / jc_wobjs)
``SPEED v``                    ``OK``; TCP speed in mm/s (1..2000), joint moves scaled accordingly
``SETTLE s``                   ``OK``; dwell after every move, s (0..10)
``BYE``                        ``OK``, then the server closes the connection
=============================  =====================================================================

Errors: ``ERR <code> <WORD>``: 1 SYNTAX, 2 UNREACHABLE (checked with ``CalcJointT`` before moving:
the robot did not move), 3 RANGE (argument out of range), 4 MOTION (failed while moving),
5 UNKNOWN (command), 6 STOPPED (a ``STOP`` ended the move: the robot stands where it braked).

``STOP`` goes to the stop port (``jc_stop_port``, 5516 by default), served by a second RAPID task
(``JcalibStop.mod``) while the motion task waits for a move: one request per connection, answered ``OK
STOPPED`` (a move was in progress) or ``OK IDLE``, then the task closes it. :meth:`AbbRobot.stop` sends it
and, while its own move has no reply yet and the answer was ``OK IDLE`` (the request overtook the move on
its way to the controller), sends it again every 10 ms. A version-1 server (no stop task) still moves the
robot; :meth:`AbbRobot.stop` then refuses with the update to make.
"""

from __future__ import annotations

import socket
import threading
import time

import numpy as np

from jcalib.acquisition.robots.base import MotionRefusedError, MotionStoppedError, Robot, RobotState
from jcalib.geometry.se3 import pose_from_mm_quat, pose_to_mm_quat
from jcalib.errors import DeviceError

DEFAULT_PORT = 5515
MAX_LINE = 80  # bytes per message including the terminating LF
PROTOCOL_VERSION = 2
ERRORS = {1: "SYNTAX", 2: "UNREACHABLE", 3: "RANGE", 4: "MOTION", 5: "UNKNOWN", 6: "STOPPED"}
#: How long :meth:`AbbRobot.stop` keeps repeating ``STOP`` while its move is in flight and the stop task
#: answers ``OK IDLE``, s.
STOP_RETRY_S = 1.0
_ERROR_TEXT = {
    1: "malformed request",
    2: "target unreachable (outside reach or joint limits); the robot did not move",
    3: "argument out of range",
    4: "motion failed while moving",
    5: "unknown command",
    6: "stopped by a STOP request; the robot stands where it braked",
}


def format_pose_args(T: np.ndarray) -> str:
    """(4, 4) pose in m -> ``"x y z q1 q2 q3 q4"`` (mm with 3 decimals, quaternion with 6)."""
    p, q = pose_to_mm_quat(T)
    return " ".join([f"{v:.3f}" for v in p] + [f"{v:.6f}" for v in q])


def parse_pose_args(tokens: list[str]) -> np.ndarray:
    """``["x", "y", "z", "q1", "q2", "q3", "q4"]`` (mm, wxyz) -> (4, 4) pose in m."""
    if len(tokens) != 7:
        raise ValueError(f"expected 7 numbers, got {len(tokens)}")
    v = np.array([float(t) for t in tokens])
    if not np.all(np.isfinite(v)):
        raise ValueError("non-finite number")
    return pose_from_mm_quat(v[:3], v[3:])


def encode_line(text: str) -> bytes:
    """One protocol message; raises ValueError beyond :data:`MAX_LINE` bytes."""
    data = (text + "\n").encode("ascii")
    if len(data) > MAX_LINE:
        raise ValueError(f"message of {len(data)} bytes exceeds {MAX_LINE}: {text!r}")
    return data


class LineSocket:
    """Reads LF-terminated lines of at most :data:`MAX_LINE` bytes from a socket."""

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self._buf = bytearray()

    def readline(self) -> str:
        while b"\n" not in self._buf:
            if len(self._buf) > MAX_LINE:
                raise ValueError(f"line longer than {MAX_LINE} bytes")
            chunk = self.sock.recv(256)
            if not chunk:
                raise ConnectionError("connection closed by peer")
            self._buf += chunk
        i = self._buf.index(b"\n")
        line = bytes(self._buf[:i]).decode("ascii", errors="replace").rstrip("\r")
        del self._buf[: i + 1]
        return line


class AbbRobot(Robot):
    """An ABB robot running ``JcalibServer.mod``.

    Args:
        host, port: address of the controller's socket server (``jc_ip`` / ``jc_port`` in the module).
        timeout_s: connect and reply timeout for non-motion requests, s.
        motion_timeout_s: longest a move may take before a DeviceError, s.
        speed_mm_s: sent with ``SPEED`` at connection (None leaves the module's default).
        settle_s: sent with ``SETTLE`` at connection (None leaves the module's default).
    """

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        timeout_s: float = 2.0,
        motion_timeout_s: float = 120.0,
        speed_mm_s: float | None = None,
        settle_s: float | None = None,
    ):
        super().__init__()
        self.host, self.port = host, int(port)
        self.address = f"abb://{host}:{self.port}"
        self.stop_port: int | None = None  # announced by PING (protocol 2); None: the server cannot stop
        self._in_motion = False
        self.timeout_s, self.motion_timeout_s = float(timeout_s), float(motion_timeout_s)
        self._lock = threading.Lock()
        try:
            self._sock: socket.socket | None = socket.create_connection((host, self.port), timeout=self.timeout_s)
        except OSError as e:
            raise DeviceError(
                f"cannot connect to the ABB jcalib server at {host}:{self.port}: {e}. Check that the "
                "controller is reachable and JcalibServer is running (RAPID main in auto, motors on)."
            ) from e
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._lines = LineSocket(self._sock)
        try:
            reply = self._request("PING")
        except DeviceError as e:
            raise DeviceError(
                f"{e}. The RAPID server serves one client at a time: another program (another capture?) may "
                "be connected to it; it is freed when that client disconnects or stays idle past the "
                "server's timeout"
            ) from e
        version = reply[2] if reply[:2] == ["OK", "JCALIB"] and len(reply) >= 3 else None
        if version == "2" and len(reply) == 4 and reply[3].isdigit() and 0 < int(reply[3]) < 65536:
            self.stop_port = int(reply[3])
        elif version == "1":
            self.can_stop = False
        else:
            self.close()
            raise DeviceError(
                f"{self.address} answered PING with {' '.join(reply)!r}, expected 'OK JCALIB "
                f"{PROTOCOL_VERSION} <stop port>' (or 'OK JCALIB 1'): not a jcalib server of these protocol versions"
            )
        if speed_mm_s is not None:
            self._request(f"SPEED {float(speed_mm_s):.1f}")
        if settle_s is not None:
            self._request(f"SETTLE {float(settle_s):.3f}")

    def _request(self, line: str, timeout_s: float | None = None, *, motion: str | None = None) -> list[str]:
        """Send ``line``, return the reply's tokens. ``motion`` (a move): sent inside :meth:`_starting`."""
        with self._lock:
            if self._sock is None:
                raise DeviceError(f"connection to {self.address} is closed")
            cmd = line.split(" ", 1)[0]
            try:
                self._sock.settimeout(timeout_s or self.timeout_s)
                if motion is None:
                    self._sock.sendall(encode_line(line))
                else:
                    with self._starting(motion):
                        self._sock.sendall(encode_line(line))
                        self._in_motion = True
                try:
                    reply = self._lines.readline()
                finally:
                    self._in_motion = False
            except socket.timeout as e:
                self._close_locked()
                raise DeviceError(
                    f"robot at {self.address} did not answer {cmd} within {timeout_s or self.timeout_s} s; "
                    "connection closed"
                ) from e
            except (OSError, ConnectionError, ValueError) as e:
                self._close_locked()
                raise DeviceError(f"lost connection to the robot at {self.address} during {cmd}: {e}") from e
        tokens = reply.split()
        if tokens and tokens[0] == "ERR":
            code = int(tokens[1]) if len(tokens) > 1 and tokens[1].isdigit() else 0
            if code == 6:
                raise MotionStoppedError(f"robot at {self.address}: {cmd} stopped by a STOP request; the robot "
                                         "stands where it braked")
            raise (MotionRefusedError if code in (2, 4) else DeviceError)(
                f"robot at {self.address} refused {line!r}: {_ERROR_TEXT.get(code, 'error')} "
                f"(reply {reply!r})"
            )
        if not tokens:
            raise DeviceError(f"robot at {self.address} sent an empty reply to {cmd}")
        return tokens

    def state(self) -> RobotState:
        pose = self._request("GETP")
        joints = self._request("GETJ")
        try:
            if pose[0] != "POSE" or joints[0] != "JNT":
                raise ValueError("unexpected reply keyword")
            T = parse_pose_args(pose[1:])
            q = np.array([float(v) for v in joints[1:]])
        except ValueError as e:
            raise DeviceError(
                f"robot at {self.address}: malformed reply {' '.join(pose)!r} / {' '.join(joints)!r}: {e}"
            ) from e
        return RobotState(T, q)

    def _move(self, T_base_flange: np.ndarray, kind: str) -> None:
        cmd = "MOVJ" if kind == "joint" else "MOVL"
        self._request(f"{cmd} {format_pose_args(T_base_flange)}", timeout_s=self.motion_timeout_s, motion=cmd)

    def _stop(self) -> None:
        if not self.can_stop:
            raise DeviceError(
                f"robot at {self.address}: its RAPID server speaks protocol 1 (no stop task), so jcalib cannot stop "
                "the robot: stop it at the FlexPendant, then install robot/abb/JcalibServer.mod and JcalibStop.mod "
                "of this jcalib version"
            )
        deadline = time.monotonic() + STOP_RETRY_S
        while True:
            answer = self._stop_request()
            if answer != "OK IDLE" or not self._in_motion or time.monotonic() > deadline:
                return
            time.sleep(0.01)

    def _stop_request(self) -> str:
        """One ``STOP`` on the stop port; the reply line."""
        where = f"{self.host}:{self.stop_port}"
        try:
            with socket.create_connection((self.host, self.stop_port), timeout=self.timeout_s) as s:
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                s.sendall(encode_line("STOP"))
                reply = LineSocket(s).readline()
        except (OSError, ConnectionError, ValueError) as e:
            raise DeviceError(
                f"robot at {self.address}: the STOP request to the stop task at {where} failed ({e}): stop the robot "
                "at the FlexPendant; check that the JcalibStop task runs"
            ) from e
        if reply not in ("OK STOPPED", "OK IDLE"):
            raise DeviceError(f"robot at {self.address}: the stop task at {where} answered STOP with {reply!r}")
        return reply

    def select_tool(self, index: int) -> None:
        self._request(f"TOOL {int(index)}")

    def select_base(self, index: int) -> None:
        self._request(f"WOBJ {int(index)}")

    def _close_locked(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None

    def close(self) -> None:
        with self._lock:
            if self._sock is not None:
                try:
                    self._sock.settimeout(0.5)
                    self._sock.sendall(encode_line("BYE"))
                except OSError:
                    pass
            self._close_locked()
