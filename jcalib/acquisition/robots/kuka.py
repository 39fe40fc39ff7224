"""KUKA KRC robots through KUKAVARPROXY (a TCP server on the controller that reads/writes KRL variables).

Wire format (big-endian), one request then one reply on a TCP connection (port 7000 by default):

- request: ``u16 msg_id``, ``u16 len`` (bytes that follow), ``u8 mode`` (0 read, 1 write),
  ``u16 name_len`` + ASCII variable name, and for writes ``u16 value_len`` + ASCII KRL value;
- reply: ``u16 msg_id`` (echo), ``u16 len``, ``u8 mode``, ``u16 value_len`` + value, then three bytes
  ``00 01 01`` whose last byte is 1 on success.

:class:`KukaVarProxyClient` frames exactly that (reads the 4-byte header, then ``len`` bytes) with a
timeout on every socket operation; it never guesses a message boundary from a single ``recv``.

Motion uses the shared-variable ("flag / pos") method with the KRL program shipped in
``jcalib/acquisition/robots/krl/`` (``JCALIB_MOVE.src`` + ``.dat``, to be started on the controller):

========================  ============================================================================
``JC_POS``  (FRAME)        target ``{X, Y, Z, A, B, C}`` of the active tool in the active base (mm, deg)
``JC_FLAG`` (INT)          client writes 1 = PTP, 2 = LIN, 3 = apply JC_TOOL/JC_BASE only;
                           the program sets it back to 0 after the robot stopped (advance run stopped)
``JC_ERR``  (INT)          result of the last command: 0 ok, 1 target unreachable (``INVERSE`` failed,
                           the robot did not move), 2 motion failed on the path, 3 bad tool/base index,
                           4 unknown JC_FLAG value, 5 stopped by the client (``JC_STOP``: the robot
                           braked on its path and stands there)
``JC_STOP`` (BOOL)         client writes TRUE to stop the motion in progress: an ``INTERRUPT`` on it
                           brakes (``BRAKE``, a ramp-down stop on the path), abandons the motion
                           (``RESUME``) and sets JC_STOP back to FALSE, JC_ERR = 5, JC_FLAG = 0. TRUE
                           when a motion command starts: the robot does not move (JC_ERR = 5)
``JC_TOOL``, ``JC_BASE``   tool / base index (0 = ``$NULLFRAME``, i.e. the flange / world frame)
``JC_VEL`` (INT)           speed in percent (1..100) of ``$VEL_AXIS`` (PTP) and of 0.5 m/s (LIN)
========================  ============================================================================

The pose is read from ``$POS_ACT`` and the joints from ``$AXIS_ACT``. PTP moves keep the current
posture (``S``/``T`` of ``$POS_ACT``), so the arm never flips configuration between stations.

:meth:`KukaRobot.stop` writes ``JC_STOP = TRUE`` through the same connection (the client's lock is held
per transaction, so the write slips in between the polls of a blocked move); a move that starts clears a
``JC_STOP`` left TRUE by an earlier stop before it writes ``JC_FLAG``. A KRL program older than
``JC_STOP`` still moves the robot, but :meth:`KukaRobot.stop` then refuses with the update to make.
"""

from __future__ import annotations

import re
import socket
import struct
import threading
import time

import numpy as np

from jcalib.acquisition.robots.base import MotionRefusedError, MotionStoppedError, Robot, RobotState, recv_exact
from jcalib.geometry.se3 import pose_from_kuka, pose_to_kuka
from jcalib.errors import DeviceError

HEADER = struct.Struct("!HH")
DEFAULT_PORT = 7000

JC_ERRORS = {
    1: "target unreachable (outside reach or joint limits); the robot did not move",
    2: "motion failed on the way (path leaves the workspace or crosses a singularity)",
    3: "tool or base index out of range",
    4: "unknown JC_FLAG command",
    5: "stopped by the client (JC_STOP): the robot braked and stands where it stopped",
}
#: JC_ERR of a motion ended by JC_STOP.
JC_STOPPED = 5

_FIELD = re.compile(r"([A-Za-z][A-Za-z0-9_]*)\s+([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)")


def encode_request(msg_id: int, name: str, value: str | None = None) -> bytes:
    """One KUKAVARPROXY request: read when ``value`` is None, else write."""
    name_b = name.encode("ascii")
    body = struct.pack("!BH", 0 if value is None else 1, len(name_b)) + name_b
    if value is not None:
        value_b = value.encode("ascii")
        body += struct.pack("!H", len(value_b)) + value_b
    if len(body) > 0xFFFF:
        raise DeviceError(f"KUKAVARPROXY request for {name!r} is too long ({len(body)} bytes)")
    return HEADER.pack(msg_id & 0xFFFF, len(body)) + body


def encode_reply(msg_id: int, mode: int, value: str, ok: bool) -> bytes:
    """One KUKAVARPROXY reply (used by the simulator)."""
    value_b = value.encode("ascii")
    body = struct.pack("!BH", mode, len(value_b)) + value_b + bytes([0, 1, 1 if ok else 0])
    return HEADER.pack(msg_id & 0xFFFF, len(body)) + body


def parse_krl_struct(text: str) -> dict[str, float]:
    """``"{E6POS: X 1.5, Y -2, ..., S 6, T 27}"`` -> ``{"X": 1.5, "Y": -2.0, ..., "S": 6.0, "T": 27.0}``."""
    body = text.strip()
    if not (body.startswith("{") and body.endswith("}")):
        raise ValueError(f"not a KRL structure: {text!r}")
    body = body[1:-1]
    if ":" in body:
        body = body.split(":", 1)[1]
    return {k.upper(): float(v) for k, v in _FIELD.findall(body)}


def format_frame(xyzabc: np.ndarray) -> str:
    """``[X, Y, Z, A, B, C]`` (mm, deg) -> KRL FRAME aggregate (32-bit REAL precision is plenty)."""
    x, y, z, a, b, c = (float(v) for v in xyzabc)
    return f"{{FRAME: X {x:.4f}, Y {y:.4f}, Z {z:.4f}, A {a:.5f}, B {b:.5f}, C {c:.5f}}}"


class KukaVarProxyClient:
    """KUKAVARPROXY client with proper framing and timeouts.

    Args:
        host: controller address (IP or name).
        port: KUKAVARPROXY port (7000).
        timeout_s: connect and per-reply timeout, s.

    Raises:
        DeviceError: cannot connect; later, on a lost connection, a timeout, a mismatched reply or a
            read/write the proxy reports as failed (unknown or write-protected variable).
    """

    def __init__(self, host: str, port: int = DEFAULT_PORT, *, timeout_s: float = 2.0):
        self.host, self.port, self.timeout_s = host, int(port), float(timeout_s)
        self._msg_id = 0
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        try:
            self._sock = socket.create_connection((host, self.port), timeout=self.timeout_s)
        except OSError as e:
            raise DeviceError(
                f"cannot connect to KUKAVARPROXY at {host}:{self.port}: {e}. Check that the controller is "
                "on and reachable and that KUKAVARPROXY is running on it (port 7000 open in the firewall)."
            ) from e
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    @property
    def connected(self) -> bool:
        """False once the connection was closed (by :meth:`close`, or after a timeout or a lost link)."""
        return self._sock is not None

    def _transact(self, name: str, value: str | None) -> str:
        with self._lock:
            if self._sock is None:
                raise DeviceError(f"KUKAVARPROXY connection to {self.address} is closed")
            self._msg_id = (self._msg_id + 1) & 0xFFFF
            msg_id = self._msg_id
            what = f"{'write' if value is not None else 'read'} of {name!r}"
            try:
                self._sock.sendall(encode_request(msg_id, name, value))
                rid, length = HEADER.unpack(recv_exact(self._sock, HEADER.size))
                body = recv_exact(self._sock, length)
            except socket.timeout as e:
                self._close_locked()
                raise DeviceError(
                    f"KUKAVARPROXY at {self.address} did not answer the {what} within {self.timeout_s} s; "
                    "connection closed"
                ) from e
            except (OSError, ConnectionError) as e:
                self._close_locked()
                raise DeviceError(f"lost connection to KUKAVARPROXY at {self.address} during the {what}: {e}") from e
            if rid != msg_id or length < 6:
                self._close_locked()
                raise DeviceError(
                    f"KUKAVARPROXY at {self.address}: malformed reply to the {what} "
                    f"(msg_id {rid}, expected {msg_id}; {length} bytes)"
                )
            (vlen,) = struct.unpack("!H", body[1:3])
            if 3 + vlen + 3 != length:
                self._close_locked()
                raise DeviceError(
                    f"KUKAVARPROXY at {self.address}: reply to the {what} has value length {vlen} "
                    f"but {length} bytes"
                )
            text = body[3 : 3 + vlen].decode("ascii", errors="replace")
            if body[-1] != 1:
                raise DeviceError(
                    f"KUKAVARPROXY at {self.address} reports the {what} failed "
                    "(unknown variable, not declared PUBLIC/global, or write-protected)"
                )
            return text

    def read(self, name: str) -> str:
        """Value of KRL variable ``name`` as KRL text."""
        return self._transact(name, None)

    def write(self, name: str, value: str) -> str:
        """Write KRL text ``value`` to ``name``; returns the proxy's echo."""
        return self._transact(name, value)

    def _close_locked(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None

    def close(self) -> None:
        with self._lock:
            self._close_locked()


class KukaRobot(Robot):
    """A KUKA robot driven through KUKAVARPROXY and the ``JCALIB_MOVE`` KRL program.

    Args:
        host, port: KUKAVARPROXY address.
        timeout_s: per-request timeout, s.
        motion_timeout_s: longest a single motion may take before a DeviceError, s.
        poll_s: JC_FLAG polling period while moving, s.
        velocity_percent: written to ``JC_VEL`` at connection (None leaves it).

    Raises:
        DeviceError: cannot connect, or the first reads fail.
    """

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        timeout_s: float = 2.0,
        motion_timeout_s: float = 120.0,
        poll_s: float = 0.02,
        velocity_percent: int | None = None,
    ):
        super().__init__()
        self.client = KukaVarProxyClient(host, port, timeout_s=timeout_s)
        self.address = f"kuka://{host}:{port}"
        self.motion_timeout_s = float(motion_timeout_s)
        self.poll_s = float(poll_s)
        try:  # JCALIB_MOVE older than JC_STOP: moves work, stop() refuses
            self._stop_set = self.client.read("JC_STOP").strip().upper() != "FALSE"
            self.can_stop = True
        except DeviceError:
            if not self.client.connected:  # the connection itself failed, not the read
                raise
            self._stop_set, self.can_stop = False, False
        if velocity_percent is not None:
            self.client.write("JC_VEL", str(int(np.clip(velocity_percent, 1, 100))))

    def state(self) -> RobotState:
        pos = parse_krl_struct(self.client.read("$POS_ACT"))
        axis = parse_krl_struct(self.client.read("$AXIS_ACT"))
        try:
            T = pose_from_kuka(np.array([pos[k] for k in "XYZABC"]))
        except KeyError as e:
            raise DeviceError(f"robot at {self.address}: $POS_ACT lacks component {e}") from e
        joints = np.array([axis[f"A{i}"] for i in range(1, 7) if f"A{i}" in axis])
        return RobotState(T, joints)

    def _wait_idle(self, what: str) -> None:
        """Wait until JCALIB_MOVE has finished any command still running (JC_FLAG back at 0).

        A client killed mid-move leaves the program executing its last command; writing a new target
        before that clears JC_FLAG would be overwritten by the program's ``JC_FLAG = 0``.
        """
        deadline = time.monotonic() + self.motion_timeout_s
        while self.client.read("JC_FLAG").strip() != "0":
            if time.monotonic() > deadline:
                raise DeviceError(
                    f"robot at {self.address}: JCALIB_MOVE is still busy with an earlier command after "
                    f"{self.motion_timeout_s} s, so the {what} cannot start (is another program writing JC_FLAG?)"
                )
            time.sleep(self.poll_s)

    def _command(self, flag: int | None, what: str) -> None:
        """Write ``JC_FLAG = flag`` (None: already written), wait until the program clears it, map JC_ERR."""
        if flag is not None:
            self.client.write("JC_FLAG", str(flag))
        deadline = time.monotonic() + self.motion_timeout_s
        while True:
            if self.client.read("JC_FLAG").strip() == "0":
                break
            if time.monotonic() > deadline:
                raise DeviceError(
                    f"robot at {self.address}: {what} not finished after {self.motion_timeout_s} s "
                    "(is JCALIB_MOVE running in automatic mode, override > 0, no stop active?)"
                )
            time.sleep(self.poll_s)
        err = int(float(self.client.read("JC_ERR")))
        if err == JC_STOPPED:
            raise MotionStoppedError(f"robot at {self.address}: the {what} was stopped (JC_STOP); the robot stands "
                                     "where it braked")
        if err:
            raise (MotionRefusedError if err in (1, 2) else DeviceError)(
                f"robot at {self.address} refused the {what}: "
                f"{JC_ERRORS.get(err, f'controller error code {err}')} (JC_ERR={err})"
            )

    def _move(self, T_base_flange: np.ndarray, kind: str) -> None:
        what = "PTP" if kind == "joint" else "LIN"
        self._wait_idle(what)
        with self._starting(what):
            if self._stop_set:  # left TRUE by an earlier stop: this move would not start
                self.client.write("JC_STOP", "FALSE")
                self._stop_set = False
            self.client.write("JC_POS", format_frame(pose_to_kuka(T_base_flange)))
            self.client.write("JC_FLAG", str(1 if kind == "joint" else 2))
        self._command(None, what)

    def _stop(self) -> None:
        if not self.can_stop:
            raise DeviceError(
                f"robot at {self.address}: the KRL program JCALIB_MOVE on the controller has no JC_STOP variable "
                "(an older version), so jcalib cannot stop the robot: stop it at the teach pendant, then install "
                "krl/JCALIB_MOVE.src and .dat of this jcalib version"
            )
        self._stop_set = True
        self.client.write("JC_STOP", "TRUE")

    def select_tool(self, index: int) -> None:
        self._wait_idle(f"selection of tool {index}")
        self.client.write("JC_TOOL", str(int(index)))
        self._command(3, f"selection of tool {index}")

    def select_base(self, index: int) -> None:
        self._wait_idle(f"selection of base {index}")
        self.client.write("JC_BASE", str(int(index)))
        self._command(3, f"selection of base {index}")

    def close(self) -> None:
        self.client.close()
