"""A simulated KUKA controller: a KUKAVARPROXY server plus the ``JCALIB_MOVE`` KRL program's logic.

Reads of ``$POS_ACT`` / ``$AXIS_ACT`` come from a :class:`SimulatedController`; the program loop runs in
its own thread and acts on ``JC_FLAG`` like the KRL program in ``krl/JCALIB_MOVE.src`` (including
``INVERSE``-style rejection of unreachable targets with ``JC_ERR = 1``). Unknown variables and writes to
system variables fail the way KUKAVARPROXY reports failures (last trailer byte 0).

``JC_STOP`` behaves like the program's ``INTERRUPT ... WHEN JC_STOP == TRUE``: the interrupt is on only while
a motion command runs, and fires on the FALSE -> TRUE edge; it halts the controller (``BRAKE``), abandons
the motion (``RESUME``) and ends the command with ``JC_STOP = FALSE``, ``JC_ERR = 5``. A motion command that
starts while ``JC_STOP`` is TRUE does not move (``JC_ERR = 5``).

Values are checked the way the KRL types check them: the INT variables take integer literals in the
32-bit range, ``JC_STOP`` the BOOL literals ``TRUE`` / ``FALSE``, ``JC_POS`` a FRAME whose six components
are finite REALs; anything else (``"nan"``, ``1e999``) is a failed write and leaves the variable as it was.
The program loop survives whatever a command leads to (it reports ``JC_ERR = 4`` and clears ``JC_FLAG``).
A request that is not KUKAVARPROXY framing closes that client's connection; idle clients time out
(``idle_timeout_s``).

Start it in-process with ``KukaSimServer(...).start()`` or as a subprocess with
``python -m jcalib.acquisition.robots.serve --protocol kuka``.
"""

from __future__ import annotations

import math
import re
import socket
import struct
import threading

import numpy as np

from jcalib.acquisition.robots._server import ThreadedTcpServer
from jcalib.acquisition.robots.base import MotionStoppedError
from jcalib.acquisition.robots.base import recv_exact
from jcalib.acquisition.robots.kuka import HEADER, encode_reply, parse_krl_struct
from jcalib.geometry.se3 import pose_from_kuka, pose_to_kuka
from jcalib.acquisition.robots.simulated import SimulatedController, UnreachableError
from jcalib.errors import BadInputError

_INT = re.compile(r"^[+-]?\d{1,10}$")
_INT_VARS = ("JC_FLAG", "JC_ERR", "JC_TOOL", "JC_BASE", "JC_VEL", "$OV_PRO")
_REAL_MAX = 3.4e38  # KRL REAL is IEEE single precision
_MAX_VALUE_BYTES = 512


def valid_value(name: str, value: str) -> bool:
    """Whether KRL would accept ``value`` for the simulated variable ``name`` (module docstring)."""
    if len(value) > _MAX_VALUE_BYTES or not value.isascii():
        return False
    text = value.strip()
    if name in _INT_VARS:
        return bool(_INT.match(text)) and -(2**31) <= int(text) < 2**31
    if name == "JC_STOP":
        return text.upper() in ("TRUE", "FALSE")
    if name == "JC_POS":
        try:
            v = parse_krl_struct(text)
        except ValueError:
            return False
        return all(k in v and math.isfinite(v[k]) and abs(v[k]) <= _REAL_MAX for k in "XYZABC")
    return False


_USER_VARS = {
    "JC_POS": "{FRAME: X 0.0, Y 0.0, Z 0.0, A 0.0, B 0.0, C 0.0}",
    "JC_FLAG": "0",
    "JC_ERR": "0",
    "JC_STOP": "FALSE",
    "JC_TOOL": "0",
    "JC_BASE": "0",
    "JC_VEL": "20",
    "$OV_PRO": "100",
}


class KukaSimServer(ThreadedTcpServer):
    """KUKAVARPROXY on loopback backed by a simulated controller.

    Args:
        controller: the simulated arm (a default :class:`SimulatedController` when None).
        host, port: listening address (loopback only unless ``allow_non_loopback``); port 0 = any free.
        reply_delay_s: added latency per reply, s (a real KRC answers in ~2-10 ms).
    """

    name = "kuka-sim"

    def __init__(
        self,
        controller: SimulatedController | None = None,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        reply_delay_s: float = 0.0,
        allow_non_loopback: bool = False,
        idle_timeout_s: float = 30.0,
    ):
        super().__init__(host, port, allow_non_loopback=allow_non_loopback, idle_timeout_s=idle_timeout_s)
        self.controller = controller if controller is not None else SimulatedController()
        self.reply_delay_s = float(reply_delay_s)
        self.program_errors: list[str] = []
        self.vars = dict(_USER_VARS)
        self._cond = threading.Condition()
        self._interrupt_on = False  # INTERRUPT 20 (JC_STOP) is on while a motion command runs
        self._interrupted = False  # ... and fired during the current one
        self.num_requests = 0
        self._program = threading.Thread(target=self._program_loop, name="kuka-sim-krl", daemon=True)

    def start(self) -> "KukaSimServer":
        super().start()
        self._program.start()
        return self

    def stop(self) -> None:
        with self._cond:
            self._stop.set()
            self._cond.notify_all()
        super().stop()

    # --- KUKAVARPROXY ----------------------------------------------------------------------------
    def _read_var(self, name: str) -> tuple[str, bool]:
        c = self.controller
        if name == "$POS_ACT":
            x, y, z, a, b, cc = pose_to_kuka(c.T_base_tool())
            return (
                f"{{E6POS: X {x:.6f}, Y {y:.6f}, Z {z:.6f}, A {a:.7f}, B {b:.7f}, C {cc:.7f}, "
                "S 2, T 10, E1 0.0, E2 0.0, E3 0.0, E4 0.0, E5 0.0, E6 0.0}"
            ), True
        if name == "$AXIS_ACT":
            q = np.degrees(c.joints_rad())
            axes = ", ".join(f"A{i + 1} {v:.7f}" for i, v in enumerate(q))
            return f"{{E6AXIS: {axes}, E1 0.0, E2 0.0, E3 0.0, E4 0.0, E5 0.0, E6 0.0}}", True
        with self._cond:
            if name in self.vars:
                return self.vars[name], True
        return "", False

    def _write_var(self, name: str, value: str) -> tuple[str, bool]:
        with self._cond:
            if name not in self.vars or not valid_value(name, value):
                return "", False
            old = self.vars[name]
            self.vars[name] = value.strip().upper() if name == "JC_STOP" else value.strip()
            if name == "JC_STOP" and self._interrupt_on and old == "FALSE" and self.vars[name] == "TRUE":
                self._interrupted = True  # the interrupt routine: BRAKE (the rest happens in _execute)
                self.controller.halt()
            self._cond.notify_all()
            return self.vars[name], True

    def serve_connection(self, conn: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                msg_id, length = HEADER.unpack(recv_exact(conn, HEADER.size))
                body = recv_exact(conn, length)
            except ConnectionError:
                return
            request = parse_request(body)
            if request is None:  # not KUKAVARPROXY framing: drop this client
                self.num_dropped += 1
                return
            mode, name, written = request
            if mode == 0:
                value, ok = self._read_var(name)
            else:
                value, ok = self._write_var(name, written)
            self.num_requests += 1
            if self.reply_delay_s:
                self._stop.wait(self.reply_delay_s)
            conn.sendall(encode_reply(msg_id, mode, value, ok))

    # --- the KRL program ---------------------------------------------------------------------------
    def _set(self, **kw: str) -> None:
        with self._cond:
            self.vars.update(kw)

    def _program_loop(self) -> None:
        while True:
            with self._cond:
                while not self._stop.is_set() and int(self.vars["JC_FLAG"]) == 0:
                    self._cond.wait(0.5)
                if self._stop.is_set():
                    return
                snapshot = dict(self.vars)
                self.vars["JC_ERR"] = "0"
            try:
                err = self._execute(snapshot)
            except Exception as e:  # noqa: BLE001 - the program keeps running whatever a command does
                self.program_errors = (self.program_errors + [f"{type(e).__name__}: {e}"])[-20:]
                err = 4
            self._set(JC_ERR=str(err), JC_FLAG="0")

    def _execute(self, v: dict[str, str]) -> int:
        """One command of JCALIB_MOVE.src; returns JC_ERR."""
        cmd, tool, base = int(v["JC_FLAG"]), int(v["JC_TOOL"]), int(v["JC_BASE"])
        if not (0 <= tool <= 16 and 0 <= base <= 32):
            return 3
        try:
            self.controller.select_tool(tool)
            self.controller.select_base(base)
        except BadInputError:
            return 3
        if cmd == 3:
            return 0
        if cmd not in (1, 2):
            return 4
        pos = parse_krl_struct(v["JC_POS"])
        try:
            T = pose_from_kuka(np.array([pos[k] for k in "XYZABC"]))
        except BadInputError:  # not a pose (components far outside any workspace): INVERSE fails
            return 1
        with self._cond:  # JC_MOTION: INTERRUPT ON 20; IF JC_STOP == TRUE THEN (do not move)
            self._interrupt_on, self._interrupted = True, self.vars.get("JC_STOP") == "TRUE"
        try:
            if self._interrupted:
                return 5
            try:
                self.controller.start_move(T, "joint" if cmd == 1 else "linear")
            except UnreachableError as e:
                return 2 if e.on_path else 1
            except BadInputError:
                return 1
            with self._cond:  # the interrupt fired between the check and the motion start: RESUME skips it
                if self._interrupted:
                    self.controller.halt()
            try:
                self.controller.wait_motion()
            except MotionStoppedError:
                return 5
            return 5 if self._interrupted else 0
        finally:
            with self._cond:  # INTERRUPT OFF 20; a stop acknowledges JC_STOP
                self._interrupt_on = False
                if self._interrupted and "JC_STOP" in self.vars:
                    self.vars["JC_STOP"] = "FALSE"


def parse_request(body: bytes) -> tuple[int, str, str] | None:
    """``(mode, NAME, written value)`` of a KUKAVARPROXY request body, or None when it is malformed."""
    if len(body) < 3 or body[0] not in (0, 1):
        return None
    (nlen,) = struct.unpack("!H", body[1:3])
    name_b = body[3 : 3 + nlen]
    if nlen == 0 or len(name_b) != nlen or not name_b.isascii():
        return None
    rest = body[3 + nlen :]
    if body[0] == 0:
        return (0, name_b.decode("ascii").upper(), "") if not rest else None
    if len(rest) < 2:
        return None
    (vlen,) = struct.unpack("!H", rest[:2])
    if len(rest) != 2 + vlen:
        return None
    return 1, name_b.decode("ascii").upper(), rest[2:].decode("ascii", "replace")
