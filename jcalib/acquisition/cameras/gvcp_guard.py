"""A validating GVCP front for Aravis' fake GigE camera: only well-formed, in-range packets reach libaravis.

Aravis 0.8's fake camera (:class:`jcalib.acquisition.cameras.FakeGigECamera`) answers GVCP itself, and
trusts what it receives: one READMEM beyond its GenICam data makes ``memcpy`` run off the end
(a 16-byte packet segfaults the whole process), a WRITEREG can set a packet size below the protocol
overhead or a stream destination off the host, and it also binds Aravis' discovery socket on
``255.255.255.255:3956``, which receives broadcasts from every interface.

:class:`GvcpGuard` takes over the fake's sockets right after it starts (the file descriptors of its
GLib sockets are replaced with ``dup2``, so the fake's thread keeps polling what it thinks are its own
sockets):

- the public GVCP socket (``ADDRESS:3956``) is ours; each packet is parsed and checked (command known,
  lengths consistent, addresses aligned and inside the device's register space or GenICam data,
  values of the registers the fake streams from within their ranges, stream destination on loopback);
  a refused packet gets a GVCP NACK (``status`` = the GigE Vision error code) when the client asked for
  an acknowledge, a packet that is not GVCP is dropped;
- accepted packets are relayed to the fake's GVCP handler, now an ephemeral port on the same address,
  from one relay socket per client (so the fake's control-channel logic still tells clients apart); a
  socket filter on that port admits datagrams from the relay sockets only, so nothing bypasses the
  checks; the answers go back to the client from ``ADDRESS:3956``;
- the discovery sockets and the fake's stream-source socket get a filter that drops everything
  (the stream socket only sends), and the discovery socket is rebound to ``ADDRESS`` (no broadcast
  address stays bound).

Stream packets (GVSP) go from the fake straight to the stream destination the client wrote.
"""

from __future__ import annotations

import ctypes
import os
import selectors
import socket
import struct
import threading
import time
from dataclasses import dataclass, field

# GVCP (GigE Vision 2.x, section 15): command header key, command codes, status codes.
_KEY = 0x42
_FLAG_ACK_REQUIRED = 0x01
CMD_DISCOVERY, CMD_READREG, CMD_WRITEREG, CMD_READMEM, CMD_WRITEMEM = 0x0002, 0x0080, 0x0082, 0x0084, 0x0086
STATUS_NOT_IMPLEMENTED, STATUS_INVALID_PARAMETER, STATUS_INVALID_ADDRESS = 0x8001, 0x8002, 0x8003
STATUS_WRITE_PROTECT, STATUS_BAD_ALIGNMENT, STATUS_ACCESS_DENIED = 0x8004, 0x8005, 0x8006
_MAX_MEM_BYTES = 512  # GVCP READMEM / WRITEMEM data per packet (Aravis uses 512)

#: The fake's register space (ARV_FAKE_CAMERA_MEMORY_SIZE); its GenICam XML follows it.
MEMORY_SIZE = 0x10000
#: Writable address ranges: the fake's device registers (0x100-0x1ff, triggers 0x300-0x3ff) and the
#: bootstrap registers from 0x900 (control channel, heartbeat, stream channels); device information,
#: XML URLs and network set-up are read-only here.
_WRITABLE = ((0x0100, 0x0200), (0x0300, 0x0400), (0x0900, 0x10000))
# Registers the fake's streaming thread reads (arvfakecamera.h, GigE Vision bootstrap map).
REG_WIDTH, REG_HEIGHT, REG_BINNING_H, REG_BINNING_V = 0x100, 0x104, 0x108, 0x10C
REG_GAIN, REG_SENSOR_HEIGHT, REG_SENSOR_WIDTH, REG_EXPOSURE_US = 0x110, 0x118, 0x11C, 0x120
REG_PIXEL_FORMAT, REG_OFFSET_X, REG_OFFSET_Y, REG_FRAME_PERIOD_US = 0x128, 0x130, 0x134, 0x138
REG_HEARTBEAT_TIMEOUT_MS, REG_CCP = 0x0938, 0x0A00
REG_SC0_PORT, REG_SC0_PACKET_SIZE, REG_SC0_DEST = 0x0D00, 0x0D04, 0x0D18
_XML_URL = 0x0200

_SO_ATTACH_FILTER = 26


def attach_port_filter(sock: socket.socket, allowed_source_ports: list[int]) -> ctypes.Array:
    """Attach a classic BPF filter: accept UDP datagrams whose source port is listed, drop the rest.

    The program reads the UDP header's source port (offset 0 of a UDP socket's packet). Returns the
    program buffer, which must stay alive while the filter is being attached (the kernel copies it).
    """
    ports = list(allowed_source_ports)[:200]
    prog = [(0x28, 0, 0, 0)]  # ldh [0]: UDP source port
    for i, p in enumerate(ports):
        prog.append((0x15, len(ports) - i, 0, int(p)))  # jeq #p -> accept
    prog += [(0x06, 0, 0, 0), (0x06, 0, 0, 0x40000)]  # drop; accept
    buf = ctypes.create_string_buffer(b"".join(struct.pack("HBBI", *ins) for ins in prog))
    sock.setsockopt(socket.SOL_SOCKET, _SO_ATTACH_FILTER, struct.pack("HL", len(prog), ctypes.addressof(buf)))
    return buf


def udp_sockets() -> dict[int, tuple[str, int]]:
    """This process's UDP/IPv4 sockets: file descriptor -> bound (address, port)."""
    out = {}
    for name in os.listdir("/proc/self/fd"):
        fd = int(name)
        try:
            if not os.readlink(f"/proc/self/fd/{fd}").startswith("socket:"):
                continue
            s = socket.socket(fileno=os.dup(fd))
        except OSError:
            continue
        try:
            if s.family == socket.AF_INET and s.type == socket.SOCK_DGRAM:
                out[fd] = s.getsockname()[:2]
        except OSError:
            pass
        finally:
            s.close()
    return out


@dataclass
class GuardStats:
    """Counters of the guard: packets relayed, refused (with the reason of the last few), dropped."""

    relayed: int = 0
    refused: int = 0
    dropped: int = 0
    reasons: list[str] = field(default_factory=list)


class Check:
    """What the guard accepts, for a fake camera of a given sensor and GenICam data size."""

    def __init__(self, sensor_size: tuple[int, int], xml_size: int, pixel_formats: set[int]):
        self.sensor_w, self.sensor_h = sensor_size
        self.xml_size = int(xml_size)
        self.pixel_formats = set(pixel_formats)

    def readable(self, address: int, size: int) -> bool:
        if address % 4 or size <= 0 or size % 4 or size > _MAX_MEM_BYTES:
            return False
        if address + size <= MEMORY_SIZE:
            return True
        return MEMORY_SIZE <= address < MEMORY_SIZE + self.xml_size

    def register_value(self, address: int, value: int) -> str | None:
        """None when writing ``value`` to the register at ``address`` is safe, else why not."""
        w, h = self.sensor_w, self.sensor_h
        ranges = {
            REG_WIDTH: (1, w), REG_HEIGHT: (1, h), REG_OFFSET_X: (0, w - 1), REG_OFFSET_Y: (0, h - 1),
            REG_BINNING_H: (1, 16), REG_BINNING_V: (1, 16), REG_GAIN: (0, 1000),
            REG_EXPOSURE_US: (1, 10_000_000), REG_FRAME_PERIOD_US: (1000, 10_000_000),
            REG_HEARTBEAT_TIMEOUT_MS: (100, 600_000),
        }  # fmt: skip
        if address in (REG_SENSOR_WIDTH, REG_SENSOR_HEIGHT):
            return "the sensor size is read-only"
        if address in ranges:
            lo, hi = ranges[address]
            return None if lo <= value <= hi else f"value {value} outside {lo}..{hi}"
        if address == REG_PIXEL_FORMAT:
            return None if value in self.pixel_formats else f"unknown pixel format 0x{value:08x}"
        if address == REG_SC0_PACKET_SIZE:
            size = value & 0xFFFF
            return None if 220 <= size <= 16404 else f"packet size {size} outside 220..16404"
        if address == REG_SC0_DEST:
            return None if (value >> 24) == 127 else "stream destination must be a loopback address (127.x.y.z)"
        return None

    def writable(self, address: int) -> str | None:
        if address % 4:
            return "unaligned"
        if not any(lo <= address <= hi - 4 for lo, hi in _WRITABLE):
            return "outside the writable registers"
        return None

    def __call__(self, packet: bytes) -> tuple[int, int, int | None, str]:
        """``(command, request id, status, reason)``: status None accepts the packet, else the NACK code.

        Raises:
            ValueError: not a GVCP command packet (drop it without an answer).
        """
        if len(packet) < 8 or packet[0] != _KEY:
            raise ValueError("not a GVCP command")
        _, _, command, length, req_id = struct.unpack("!BBHHH", packet[:8])
        body = packet[8:]
        if length != len(body):
            return command, req_id, STATUS_INVALID_PARAMETER, f"length field {length} != {len(body)} bytes"
        if command == CMD_DISCOVERY:
            return (command, req_id, None, "") if not body else (command, req_id, STATUS_INVALID_PARAMETER, "body")
        if command == CMD_READREG:
            if len(body) != 4:  # the fake answers one register per packet
                return command, req_id, STATUS_INVALID_PARAMETER, "READREG: one register per packet"
            (addr,) = struct.unpack("!I", body)
            ok = self.readable(addr, 4)
            return command, req_id, None if ok else STATUS_INVALID_ADDRESS, "" if ok else f"READREG 0x{addr:x}"
        if command == CMD_WRITEREG:
            if len(body) != 8:
                return command, req_id, STATUS_INVALID_PARAMETER, "WRITEREG: one register per packet"
            addr, value = struct.unpack("!II", body)
            why = self.writable(addr)
            if why:
                return command, req_id, STATUS_WRITE_PROTECT, f"WRITEREG 0x{addr:x}: {why}"
            why = self.register_value(addr, value)
            return command, req_id, None if why is None else STATUS_INVALID_PARAMETER, why or ""
        if command == CMD_READMEM:
            if len(body) != 8:
                return command, req_id, STATUS_INVALID_PARAMETER, "READMEM: 8-byte body expected"
            addr, _, count = struct.unpack("!IHH", body)
            ok = self.readable(addr, count)
            return command, req_id, None if ok else STATUS_INVALID_ADDRESS, "" if ok else f"READMEM 0x{addr:x}+{count}"
        if command == CMD_WRITEMEM:
            if len(body) < 8 or (len(body) - 4) % 4 or len(body) - 4 > _MAX_MEM_BYTES:
                return command, req_id, STATUS_INVALID_PARAMETER, "WRITEMEM: 4..512 data bytes, whole words"
            (addr,) = struct.unpack("!I", body[:4])
            for k in range(0, len(body) - 4, 4):
                why = self.writable(addr + k)
                if why:
                    return command, req_id, STATUS_WRITE_PROTECT, f"WRITEMEM 0x{addr + k:x}: {why}"
                why = self.register_value(addr + k, struct.unpack("!I", body[4 + k : 8 + k])[0])
                if why:
                    return command, req_id, STATUS_INVALID_PARAMETER, why
            return command, req_id, None, ""
        return command, req_id, STATUS_NOT_IMPLEMENTED, f"command 0x{command:04x}"


def nack(command: int, req_id: int, status: int) -> bytes:
    """A GVCP acknowledge carrying an error status (answer = command + 1, no data)."""
    return struct.pack("!HHHH", status, (command + 1) & 0xFFFF, 0, req_id)


class GvcpGuard:
    """Own the public GVCP port of a started fake camera; relay checked packets to it (module docstring).

    Args:
        address: the fake's address (its GVCP port is 3956 there).
        fake_fds: the fake's UDP sockets as :func:`udp_sockets` lists them (created by the fake).
        check: the packet check (:class:`Check`).
        num_relays: relay sockets (concurrent clients).
        heartbeat_timeout_s: a relay idle this long (plus margin) may serve another client: the fake
            has expired that client's control by then.
    """

    def __init__(self, address: str, fake_fds: dict[int, tuple[str, int]], check: Check, *,
                 num_relays: int = 16, heartbeat_timeout_s: float = 3.0) -> None:  # fmt: skip
        self.address, self.check = address, check
        self.stats = GuardStats()
        self.idle_s = max(10.0, heartbeat_timeout_s + 2.0)
        self._keep: list = []
        self._stop = threading.Event()
        gvcp = [fd for fd, (a, p) in fake_fds.items() if p == 3956 and a == address]
        others = [fd for fd, (a, p) in fake_fds.items() if fd not in gvcp]
        if len(gvcp) != 1:
            raise OSError(f"the fake camera's GVCP socket on {address}:3956 was not found ({fake_fds})")
        self.relays = []
        for _ in range(num_relays):
            r = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            r.bind((address, 0))
            r.setblocking(False)
            self.relays.append(r)
        # the fake's handler moves to an ephemeral port that admits the relays only
        self.inner = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.inner.bind((address, 0))
        self.inner.setblocking(False)
        self._keep.append(attach_port_filter(self.inner, [r.getsockname()[1] for r in self.relays]))
        os.dup2(self.inner.fileno(), gvcp[0])
        for fd in others:  # discovery sockets: replaced by a deaf one; the stream source: made deaf
            a, p = fake_fds[fd]
            if p == 3956:
                deaf = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                deaf.bind((address, 0))
                deaf.setblocking(False)
                self._keep.append(attach_port_filter(deaf, []))
                os.dup2(deaf.fileno(), fd)
                deaf.close()
            else:
                s = socket.socket(fileno=os.dup(fd))
                self._keep.append(attach_port_filter(s, []))
                s.close()
        for r in self.relays:
            r.connect(self.inner.getsockname())  # a connected UDP socket hears the fake only
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.front.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        deadline = time.monotonic() + 2.0
        while True:  # the fake's thread may still be inside poll() on the old socket (<= 100 ms)
            try:
                self.front.bind((address, 3956))
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.01)
        self.front.setblocking(False)
        self._client_of: dict[int, tuple[str, int]] = {}  # relay index -> client
        self._relay_of: dict[tuple[str, int], int] = {}
        self._last: dict[int, float] = {}
        self._thread = threading.Thread(target=self._run, name=f"gvcp-guard-{address}", daemon=True)

    def start(self) -> "GvcpGuard":
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop relaying (call before the fake is freed); the public port is released."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.front.close()
        for r in self.relays:
            r.close()

    def close_inner(self) -> None:
        """Release our handle of the fake's handler socket (after the fake is freed)."""
        self.inner.close()

    def _relay_for(self, client: tuple[str, int]) -> int | None:
        now = time.monotonic()
        k = self._relay_of.get(client)
        if k is not None:
            return k
        for k in range(len(self.relays)):
            owner = self._client_of.get(k)
            if owner is None or now - self._last.get(k, 0.0) > self.idle_s:
                if owner is not None:
                    del self._relay_of[owner]
                self._client_of[k], self._relay_of[client] = client, k
                return k
        return None

    def _refuse(self, reason: str) -> None:
        self.stats.refused += 1
        self.stats.reasons = (self.stats.reasons + [reason])[-20:]

    def _from_client(self) -> None:
        try:
            data, client = self.front.recvfrom(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            return
        try:
            command, req_id, status, reason = self.check(data)
        except ValueError:
            self.stats.dropped += 1
            return
        if status is not None:
            self._refuse(reason)
            if data[1] & _FLAG_ACK_REQUIRED:
                self._send(nack(command, req_id, status), client)
            return
        k = self._relay_for(client)
        if k is None:  # every relay serves a live client: busy
            self._refuse("too many clients")
            if data[1] & _FLAG_ACK_REQUIRED:
                self._send(nack(command, req_id, STATUS_ACCESS_DENIED), client)
            return
        self._last[k] = time.monotonic()
        try:
            self.relays[k].send(data)
            self.stats.relayed += 1
        except OSError:
            self.stats.dropped += 1

    def _from_fake(self, k: int) -> None:
        try:
            data = self.relays[k].recv(65536)
        except OSError:
            return
        client = self._client_of.get(k)
        if client is not None:
            self._last[k] = time.monotonic()
            self._send(data, client)

    def _send(self, data: bytes, client: tuple[str, int]) -> None:
        try:
            self.front.sendto(data, client)
        except OSError:
            self.stats.dropped += 1

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self.front, selectors.EVENT_READ, -1)
        for k, r in enumerate(self.relays):
            sel.register(r, selectors.EVENT_READ, k)
        try:
            while not self._stop.is_set():
                try:
                    events = sel.select(timeout=0.1)
                except OSError:
                    break
                for key, _ in events:
                    try:
                        if key.data == -1:
                            self._from_client()
                        else:
                            self._from_fake(key.data)
                    except Exception as e:  # noqa: BLE001 - one bad packet must not end the guard
                        self._refuse(f"internal: {type(e).__name__}: {e}")
        finally:
            sel.close()


def xml_size_of(read_memory) -> int:
    """Size of the fake's GenICam data from its first XML URL (``Local:NAME;ADDRESS;SIZE``, hex)."""
    raw = read_memory(_XML_URL, 512).split(b"\0", 1)[0].decode("ascii", "replace")
    try:
        _, addr, size = raw.split(";")[-3:]
        if int(addr, 16) != MEMORY_SIZE:
            return 0
        return int(size, 16)
    except ValueError:
        return 0
