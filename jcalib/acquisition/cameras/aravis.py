"""GigE Vision cameras through Aravis 0.8 (PyGObject), opened by IP address only.

Device discovery (Aravis' device-list update) broadcasts on every interface, so it is never used:
the device object is built directly from the camera's address and the local address that routes to
it (``Aravis.GvDevice.new``), which sends unicast GVCP to that camera only.

Needs Debian's ``gir1.2-aravis-0.8 libaravis-0.8-0`` and PyGObject (``pip install "jcalib[acquisition]"``;
``scripts/setup`` does both when run as root).
"""

from __future__ import annotations

import ipaddress
import socket
import time
from typing import Any

import numpy as np

from jcalib.acquisition.cameras.base import FEATURE_ALIASES, Camera, Frame
from jcalib.errors import BadInputError, DeviceError

INSTALL_HINT = (
    "GigE Vision cameras need Aravis 0.8 and PyGObject: as root, `apt-get install gir1.2-aravis-0.8 "
    "libaravis-0.8-0 libgirepository1.0-dev libcairo2-dev pkg-config gobject-introspection` "
    "(scripts/apt-packages.txt lists them; ./scripts/setup installs them), then "
    '`.venv/bin/pip install "PyGObject>=3.42,<3.51"`'
)

_aravis = None
_STREAM_LAYOUT = (
    "Width", "Height", "PixelFormat", "OffsetX", "OffsetY", "GevSCPSPacketSize",
    "BinningHorizontal", "BinningVertical", "DecimationHorizontal", "DecimationVertical",
)  # fmt: skip


def load_aravis():
    """Import ``gi.repository.Aravis`` 0.8 (cached). Raises DeviceError with install instructions."""
    global _aravis
    if _aravis is None:
        try:
            import gi

            gi.require_version("Aravis", "0.8")
            from gi.repository import Aravis, Gio, GLib
        except (ImportError, ValueError) as e:
            raise DeviceError(f"{INSTALL_HINT}. ({type(e).__name__}: {e})") from e
        _aravis = (Aravis, Gio, GLib)
    return _aravis


def aravis_available() -> bool:
    """True when Aravis 0.8 can be used from Python here."""
    try:
        load_aravis()
        return True
    except DeviceError:
        return False


def local_address_for(address: str, port: int = 3956) -> str:
    """The local IPv4 address the kernel routes ``address`` through (no packet is sent)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.connect((address, port))
        return s.getsockname()[0]


class GigECamera(Camera):
    """A GigE Vision camera at an IPv4 address, software-triggered.

    Args:
        address: the camera's IPv4 address (no names, no discovery).
        name: camera id in the cell (for messages and sessions).
        packet_size: GVSP packet size in bytes (``GevSCPSPacketSize``); None keeps the device's. Jumbo
            frames (8000+) need a NIC MTU to match; 1400 always fits a 1500-byte MTU.
        pixel_format: e.g. "Mono8"; None keeps the device's.
        max_retries: extra triggers after an incomplete frame or a timeout.
        num_buffers: stream buffers queued.
        local_address: the host's address facing the camera (default: the kernel's route to it).
        control_timeout_s: longest wait for the control channel, s. A controller that died (a capture
            killed with SIGKILL) holds it until the camera's heartbeat timeout (``GevHeartbeatTimeout``,
            3 s by default) runs out; the wait is that timeout plus a margin, at most this.

    A camera keeps streaming to whoever started an acquisition until it is stopped, even after that
    controller is gone: every stream start here stops the acquisition first and re-negotiates the
    stream channel (destination address and port, packet size), so a new process picks up a camera
    that a killed one left running. A grab that gets no frame checks that the control channel is
    still ours (a missed heartbeat loses it), takes it back and re-negotiates once before failing.
    """

    def __init__(
        self,
        address: str,
        *,
        name: str = "cam",
        packet_size: int | None = None,
        pixel_format: str | None = None,
        max_retries: int = 3,
        num_buffers: int = 4,
        local_address: str | None = None,
        control_timeout_s: float = 70.0,
    ) -> None:
        super().__init__()
        try:
            ipaddress.IPv4Address(address)
        except ValueError as e:
            raise BadInputError(
                f"camera {name}: address must be an IPv4 address such as 192.168.1.20 (GigE cameras are "
                f"opened by address, never by discovery), got {address!r}"
            ) from e
        Aravis, Gio, GLib = load_aravis()
        self._Aravis, self._GLib = Aravis, GLib
        self.name, self.address = name, address
        self.max_retries, self.num_buffers = int(max_retries), int(num_buffers)
        self._stream = None
        self._acquiring = False
        try:
            local = local_address or local_address_for(address)
            dev = Aravis.GvDevice.new(Gio.InetAddress.new_from_string(local), Gio.InetAddress.new_from_string(address))
            self._cam = Aravis.Camera.new_with_device(dev)
        except (GLib.Error, OSError, TypeError) as e:
            raise DeviceError(
                f"cannot open GigE camera {name} at {address}: {e}. Check power, cabling, that the camera's "
                "IP is in the host NIC's subnet, and that no other program holds its control channel."
            ) from e
        self._dev = self._cam.get_device()
        self._take_control(float(control_timeout_s))
        try:
            self._cam.set_range_check_policy(Aravis.RangeCheckPolicy.ENABLE)
        except (AttributeError, GLib.Error):
            pass
        self._features = self._list_features()
        if packet_size is not None:
            self.set("PacketSize", int(packet_size))
        if pixel_format is not None:
            self.set("PixelFormat", pixel_format)
        try:
            self._cam.set_acquisition_mode(Aravis.AcquisitionMode.CONTINUOUS)
            self._cam.set_trigger("Software")
        except GLib.Error as e:
            raise DeviceError(f"camera {name} at {address} has no software trigger: {e}") from e

    def _heartbeat_timeout_s(self) -> float:
        try:
            return max(0.1, float(self._dev.get_integer_feature_value("GevHeartbeatTimeout")) / 1000.0)
        except (self._GLib.Error, TypeError, ValueError):
            return 3.0

    def _take_control(self, limit_s: float) -> None:
        """Become the camera's controller, waiting out a dead controller's heartbeat timeout."""
        if self._dev.is_controller():
            return
        deadline = time.monotonic() + min(limit_s, self._heartbeat_timeout_s() + 2.0)
        while True:
            try:
                if self._dev.take_control():
                    return
            except self._GLib.Error:
                pass
            if time.monotonic() > deadline:
                raise DeviceError(
                    f"camera {self.name} at {self.address} is controlled by another application (its control "
                    f"channel stayed taken for {self._heartbeat_timeout_s() + 2.0:.1f} s, longer than the camera's "
                    "heartbeat timeout): close the other program (a viewer, another capture) and retry"
                )
            time.sleep(0.25)

    def _list_features(self) -> set[str]:
        names = set()
        for cand in sorted({c for v in FEATURE_ALIASES.values() for c in v}):
            try:
                if self._cam.is_feature_available(cand):
                    names.add(cand)
            except self._GLib.Error:
                pass
        return names

    def device_feature_names(self) -> list[str]:
        return sorted(self._features)

    def has(self, feature: str) -> bool:
        if super().has(feature):
            return True
        try:  # a device-specific name outside the alias table
            return bool(self._cam.is_feature_available(feature))
        except self._GLib.Error:
            return False

    def resolve(self, feature: str) -> str:
        if feature not in self._features and feature not in FEATURE_ALIASES:
            try:
                if self._cam.is_feature_available(feature):
                    self._features.add(feature)
            except self._GLib.Error:
                pass
        return super().resolve(feature)

    def _get(self, device_name: str) -> Any:
        Aravis = self._Aravis
        node = self._dev.get_feature(device_name)
        try:
            if isinstance(node, Aravis.GcEnumeration):
                return self._dev.get_string_feature_value(device_name)
            if isinstance(node, Aravis.GcInteger):
                return int(self._dev.get_integer_feature_value(device_name))
            if isinstance(node, Aravis.GcFloat):
                return float(self._dev.get_float_feature_value(device_name))
            return node.get_value_as_string()
        except self._GLib.Error as e:
            raise DeviceError(f"camera {self.name} at {self.address}: cannot read {device_name}: {e}") from e

    def _set(self, device_name: str, value: Any) -> None:
        Aravis = self._Aravis
        node = self._dev.get_feature(device_name)
        if device_name in _STREAM_LAYOUT:
            # The payload or the packet layout changes: the stream is re-made at the next grab. (A GvStream
            # keeps the packet size it was created with; changing it under a running stream yields
            # frames that say SUCCESS but hold misplaced data.)
            self._stop_stream()
        try:
            if isinstance(node, Aravis.GcEnumeration):
                self._dev.set_string_feature_value(device_name, str(value))
            elif isinstance(node, Aravis.GcInteger):
                lo, hi = node.get_min(), node.get_max()
                if not lo <= int(value) <= hi:
                    raise BadInputError(
                        f"camera {self.name}: {device_name} must be in {lo}..{hi}, got {value!r}"
                    )
                self._dev.set_integer_feature_value(device_name, int(value))
            elif isinstance(node, Aravis.GcFloat):
                self._dev.set_float_feature_value(device_name, float(value))
            else:
                node.set_value_from_string(str(value))
        except self._GLib.Error as e:
            raise DeviceError(
                f"camera {self.name} at {self.address} refused {device_name} = {value!r}: {e}"
            ) from e
        if device_name == "PixelFormat" and self._get(device_name) != str(value):
            raise DeviceError(f"camera {self.name}: PixelFormat {value!r} not available")

    # --- streaming ------------------------------------------------------------------------------------
    def _start_stream(self) -> None:
        if self._acquiring:
            return
        try:
            self._cam.stop_acquisition()  # end an acquisition a previous (perhaps dead) controller left running
        except self._GLib.Error:
            pass
        try:
            self._stream = self._cam.create_stream(None, None)
            payload = self._cam.get_payload()
            for _ in range(self.num_buffers):
                self._stream.push_buffer(self._Aravis.Buffer.new_allocate(payload))
            self._cam.start_acquisition()
        except self._GLib.Error as e:
            raise DeviceError(f"camera {self.name} at {self.address}: cannot start streaming: {e}") from e
        self._acquiring = True

    def _stop_stream(self) -> None:
        if self._acquiring:
            try:
                self._cam.stop_acquisition()
            except self._GLib.Error:
                pass
        self._acquiring = False
        self._stream = None

    def _missing_packets(self) -> int:
        try:
            return int(self._stream.get_statistics()[1])
        except Exception:
            return 0

    def grab(self, timeout_s: float = 2.0) -> Frame:
        """Software-trigger, wait up to ``timeout_s`` per attempt, return the first complete frame.

        Incomplete frames (missing packets, ``status != SUCCESS``) and timeouts are counted in
        :attr:`stats` and retried up to :attr:`max_retries` times.

        Raises:
            DeviceError: no complete frame after all attempts (the message says why).
        """
        try:
            return self._grab(timeout_s)
        except DeviceError:
            if self._dev.is_controller() and self.stats.frames == 0:
                raise
        # lost control (missed heartbeats) or never had a frame: take control again, re-negotiate the stream
        self._stop_stream()
        self._take_control(self._heartbeat_timeout_s() + 2.0)
        return self._grab(timeout_s)

    def _grab(self, timeout_s: float) -> Frame:
        Aravis = self._Aravis
        self._start_stream()
        stream = self._stream
        problems: list[str] = []
        for attempt in range(self.max_retries + 1):
            if attempt:
                self.stats.retries += 1
            while True:  # drop frames of earlier triggers (late arrivals after a timeout)
                stale = stream.try_pop_buffer()
                if stale is None:
                    break
                stream.push_buffer(stale)
            t_trigger_ns = time.time_ns()
            try:
                self._cam.software_trigger()
            except self._GLib.Error as e:
                raise DeviceError(f"camera {self.name} at {self.address}: software trigger failed: {e}") from e
            deadline = time.monotonic() + timeout_s
            buf = None
            while buf is None:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                buf = stream.timeout_pop_buffer(max(1, int(remaining * 1e6)))
                if buf is not None and buf.get_system_timestamp() < t_trigger_ns - 1_000_000:
                    stream.push_buffer(buf)  # an older frame that arrived late
                    buf = None
            if buf is None:
                self.stats.timeouts += 1
                problems.append("timeout")
                continue
            status = buf.get_status()
            if status != Aravis.BufferStatus.SUCCESS:
                self.stats.incomplete += 1
                self.stats.missing_packets = self._missing_packets()
                problems.append(status.value_nick)
                stream.push_buffer(buf)
                continue
            w, h = buf.get_image_width(), buf.get_image_height()
            fmt = self._cam.get_pixel_format_as_string()
            data = buf.get_data()
            try:
                img = _decode(data, w, h, fmt)
            except ValueError as e:
                self.stats.incomplete += 1
                problems.append(str(e))
                stream.push_buffer(buf)
                continue
            frame = Frame(img, int(buf.get_frame_id()), int(buf.get_system_timestamp()), fmt)
            stream.push_buffer(buf)
            self.stats.frames += 1
            return frame
        self.stats.history.append(", ".join(problems))
        raise DeviceError(
            f"camera {self.name} at {self.address}: no complete frame after {self.max_retries + 1} "
            f"triggers ({', '.join(problems)}). Check the link (packet loss: lower the packet size or "
            "add packet delay), the trigger settings, and the timeout."
        )

    def close(self) -> None:
        self._stop_stream()
        self._cam = None
        self._dev = None


def _decode(data: bytes, w: int, h: int, fmt: str) -> np.ndarray:
    """Buffer bytes -> image array (copy), checking the size."""
    if fmt == "RGB8":
        shape, dtype = (h, w, 3), np.uint8
    elif fmt in ("Mono16",) or fmt.endswith("16"):
        shape, dtype = (h, w), np.dtype("<u2")
    else:
        shape, dtype = (h, w), np.uint8
    n = int(np.prod(shape)) * np.dtype(dtype).itemsize
    if len(data) < n:
        raise ValueError(f"short buffer: {len(data)} bytes for a {w}x{h} {fmt} image")
    img = np.frombuffer(data, dtype=dtype, count=int(np.prod(shape))).reshape(shape)
    return img.astype(np.uint16) if img.dtype.itemsize == 2 else img.copy()
