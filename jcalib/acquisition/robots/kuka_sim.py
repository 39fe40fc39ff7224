"""A simulated KUKA controller: a KUKAVARPROXY server plus the ``JCALIB_MOVE`` KRL program's logic.

Reads of ``$POS_ACT`` / ``$AXIS_ACT`` come from a :class:`SimulatedController`; the program loop runs in
its own thread and acts on ``JC_FLAG`` like the KRL program in ``krl/JCALIB_MOVE.src`` (including
``INVERSE``-style rejection of unreachable targets with ``JC_ERR = 1``). Unknown variables and writes to
system variables fail the way KUKAVARPROXY reports failures (last trailer byte 0).

Start it in-process with ``KukaSimServer(...).start()`` or as a subprocess with
``python -m jcalib.acquisition.robots.serve --protocol kuka``.
"""

from __future__ import annotations

import socket
import struct
import threading

import numpy as np

from jcalib.acquisition.robots._server import ThreadedTcpServer
from jcalib.acquisition.robots.kuka import HEADER, encode_reply, parse_krl_struct, recv_exact
from jcalib.geometry.se3 import pose_from_kuka, pose_to_kuka
from jcalib.acquisition.robots.simulated import SimulatedController, UnreachableError
from jcalib.errors import BadInputError

_USER_VARS = {
    "JC_POS": "{FRAME: X 0.0, Y 0.0, Z 0.0, A 0.0, B 0.0, C 0.0}",
    "JC_FLAG": "0",
    "JC_ERR": "0",
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
    ):
        super().__init__(host, port, allow_non_loopback=allow_non_loopback)
        self.controller = controller if controller is not None else SimulatedController()
        self.reply_delay_s = float(reply_delay_s)
        self.vars = dict(_USER_VARS)
        self._cond = threading.Condition()
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
            if name not in self.vars:
                return "", False
            try:
                if name == "JC_POS":
                    v = parse_krl_struct(value)
                    if not all(k in v for k in "XYZABC"):
                        return "", False
                else:
                    float(value)
            except ValueError:
                return "", False
            self.vars[name] = value.strip()
            self._cond.notify_all()
            return self.vars[name], True

    def serve_connection(self, conn: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                msg_id, length = HEADER.unpack(recv_exact(conn, HEADER.size))
                body = recv_exact(conn, length)
            except ConnectionError:
                return
            mode = body[0]
            (nlen,) = struct.unpack("!H", body[1:3])
            name = body[3 : 3 + nlen].decode("ascii", errors="replace").upper()
            if mode == 0:
                value, ok = self._read_var(name)
            elif mode == 1:
                (vlen,) = struct.unpack("!H", body[3 + nlen : 5 + nlen])
                value, ok = self._write_var(name, body[5 + nlen : 5 + nlen + vlen].decode("ascii", "replace"))
            else:
                value, ok = "", False
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
                while not self._stop.is_set() and self.vars["JC_FLAG"] in ("0", "0.0"):
                    self._cond.wait(0.5)
                if self._stop.is_set():
                    return
                cmd = int(float(self.vars["JC_FLAG"]))
                tool, base = int(float(self.vars["JC_TOOL"])), int(float(self.vars["JC_BASE"]))
                pos = parse_krl_struct(self.vars["JC_POS"])
                self.vars["JC_ERR"] = "0"
            err = 0
            try:
                self.controller.select_tool(tool)
                self.controller.select_base(base)
            except BadInputError:
                err = 3
            if err == 0:
                if cmd in (1, 2):
                    T = pose_from_kuka(np.array([pos[k] for k in "XYZABC"]))
                    try:
                        self.controller.move(T, "joint" if cmd == 1 else "linear")
                    except UnreachableError as e:
                        err = 2 if e.on_path else 1
                elif cmd != 3:
                    err = 4
            self._set(JC_ERR=str(err), JC_FLAG="0")
