"""A GigE Vision camera for tests and simulation: Aravis' own GigE fake camera serving our frames.

``libaravis-0.8.so.0`` contains a complete GigE Vision device (GVCP control on UDP 3956, GVSP
streaming) behind ``arv_gv_fake_camera_new``. We drive it through ``ctypes`` and install a fill callback
(``arv_fake_camera_set_fill_pattern``) that copies the image a :data:`FrameSource` renders into each
outgoing buffer, so clients receive our frames over real GigE Vision packets (bit-identical).
PyGObject's ``FakeCamera.set_fill_pattern`` cannot be used: in Aravis 0.8.26 the binding frees the
callback and the process crashes (fixed in 0.9.1).

Packet loss is injected with the device's ``gvsp-lost-ratio`` property (a fraction of the stream
packets is dropped); the fake has no packet resend, so the client sees incomplete frames.

The fake trusts what it receives (a single out-of-range READMEM crashes libaravis) and binds Aravis'
discovery socket on ``255.255.255.255:3956``: :class:`jcalib.acquisition.cameras.gvcp_guard.GvcpGuard`
takes over its sockets as soon as it starts, so only checked GVCP packets reach it and every socket
is bound to ``address`` (loopback), nothing to a broadcast address.
The fake binds to the network interface that owns ``address``: 127.0.0.1 always works; another
loopback address (127.0.0.2) must be assigned to ``lo`` first (e.g. inside ``unshare -n``).
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import tempfile
import threading
import time
import traceback

import numpy as np

from jcalib.acquisition.cameras.base import FrameRequest, FrameSource, to_pixels
from jcalib.acquisition.cameras.gvcp_guard import Check, GvcpGuard, udp_sockets, xml_size_of
from jcalib.errors import BadInputError, DeviceError

_FILL = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint32)

# Registers of the fake camera (arv-fake-camera.xml): sensor size and region.
_REG_SENSOR_HEIGHT = 0x118
_REG_SENSOR_WIDTH = 0x11C
_REG_WIDTH = 0x100
_REG_HEIGHT = 0x104

#: Lens features this module adds to the fake's GenICam description (``lens_features=True``): name ->
#: (register, default, maximum). A motorised zoom and focus in motor steps (GenICam ``Zoom``, ``Focus``);
#: the registers are free in the fake's device register block (0x100-0x1ff).
LENS_FEATURES = {"Zoom": (0x140, 500, 1000), "Focus": (0x144, 500, 1000)}


def lens_genicam_xml(base_xml: str) -> str:
    """The fake camera's GenICam XML with the :data:`LENS_FEATURES` added (a ``LensControl`` category)."""
    nodes = []
    for name, (reg, _, top) in LENS_FEATURES.items():
        nodes.append(f"""
	<Integer Name="{name}" NameSpace="Standard">
		<Description>Lens {name.lower()} motor position (steps).</Description>
		<pValue>{name}Register</pValue>
		<Min>0</Min>
		<Max>{top}</Max>
	</Integer>

	<IntReg Name="{name}Register" NameSpace="Custom">
		<Address>{reg:#x}</Address>
		<Length>4</Length>
		<AccessMode>RW</AccessMode>
		<pPort>Device</pPort>
		<Sign>Unsigned</Sign>
		<Endianess>BigEndian</Endianess>
	</IntReg>
""")
    category = ("\n\t<Category Name=\"LensControl\" NameSpace=\"Standard\">\n"
                + "".join(f"\t\t<pFeature>{n}</pFeature>\n" for n in LENS_FEATURES) + "\t</Category>\n")
    root = '<Category Name="Root" NameSpace="Standard">'
    end = "</RegisterDescription>"
    if root not in base_xml or end not in base_xml:
        raise DeviceError("the fake camera's GenICam XML has an unexpected layout; cannot add lens features")
    xml = base_xml.replace(root, root + "\n\t\t<pFeature>LensControl</pFeature>", 1)
    return xml.replace(end, category + "".join(nodes) + "\n" + end, 1)


# GenICam PFNC codes of the formats the fake offers.
PIXEL_FORMATS = {
    0x01080001: "Mono8",
    0x01100007: "Mono16",
    0x02180014: "RGB8",
    0x01080008: "BayerGR8",
    0x01080009: "BayerRG8",
    0x0108000A: "BayerGB8",
    0x0108000B: "BayerBG8",
}

_lib = None


def load_libraries():
    """Load libaravis / libgobject once and declare the C signatures we use."""
    global _lib
    if _lib is not None:
        return _lib
    try:
        arv = ctypes.CDLL("libaravis-0.8.so.0")
        gobj = ctypes.CDLL("libgobject-2.0.so.0")
    except OSError as e:
        raise DeviceError(
            "the fake GigE camera needs libaravis-0.8.so.0 (Debian: apt-get install libaravis-0.8-0 "
            f"gir1.2-aravis-0.8; listed in scripts/apt-packages.txt): {e}"
        ) from e
    arv.arv_gv_fake_camera_new.restype = ctypes.c_void_p
    arv.arv_gv_fake_camera_new.argtypes = [ctypes.c_char_p, ctypes.c_char_p]
    arv.arv_gv_fake_camera_new_full.restype = ctypes.c_void_p
    arv.arv_gv_fake_camera_new_full.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p]
    arv.arv_fake_camera_new.restype = ctypes.c_void_p
    arv.arv_fake_camera_new.argtypes = [ctypes.c_char_p]
    arv.arv_fake_camera_get_genicam_xml.restype = ctypes.c_void_p
    arv.arv_fake_camera_get_genicam_xml.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_size_t)]
    arv.arv_fake_camera_read_register.restype = ctypes.c_int
    arv.arv_fake_camera_read_register.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.POINTER(ctypes.c_uint32)]
    arv.arv_gv_fake_camera_is_running.restype = ctypes.c_int
    arv.arv_gv_fake_camera_is_running.argtypes = [ctypes.c_void_p]
    arv.arv_gv_fake_camera_get_fake_camera.restype = ctypes.c_void_p
    arv.arv_gv_fake_camera_get_fake_camera.argtypes = [ctypes.c_void_p]
    arv.arv_fake_camera_set_fill_pattern.restype = None
    arv.arv_fake_camera_set_fill_pattern.argtypes = [ctypes.c_void_p, _FILL, ctypes.c_void_p]
    arv.arv_fake_camera_set_trigger_frequency.restype = None
    arv.arv_fake_camera_set_trigger_frequency.argtypes = [ctypes.c_void_p, ctypes.c_double]
    arv.arv_fake_camera_write_register.restype = ctypes.c_int
    arv.arv_fake_camera_write_register.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32]
    arv.arv_fake_camera_read_memory.restype = ctypes.c_int
    arv.arv_fake_camera_read_memory.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_void_p]
    arv.arv_buffer_get_data.restype = ctypes.c_void_p
    arv.arv_buffer_get_data.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_size_t)]
    for fn in ("arv_buffer_get_image_width", "arv_buffer_get_image_height", "arv_buffer_get_image_x",
               "arv_buffer_get_image_y"):  # fmt: skip
        getattr(arv, fn).restype = ctypes.c_int
        getattr(arv, fn).argtypes = [ctypes.c_void_p]
    gobj.g_object_unref.restype = None
    gobj.g_object_unref.argtypes = [ctypes.c_void_p]
    gobj.g_object_set.restype = None
    gobj.g_object_set.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_double, ctypes.c_void_p]
    _lib = (arv, gobj)
    return _lib


class FakeGigECamera:
    """A GigE Vision device on ``address`` whose frames come from ``frame_source``.

    Args:
        frame_source: renders the current view, ``source(FrameRequest) -> image`` (full sensor or ROI).
        address: IPv4 address of a local interface to serve on (loopback by default).
        sensor_size: ``(width, height)`` of the sensor in pixels (also the initial region);
            the fake supports up to 2048 x 2048 comfortably.
        serial: device serial number, 1..15 bytes.
        loss_ratio: fraction of stream packets dropped (0..1).
        warm_up: render one frame in :meth:`start` before serving. The fill callback runs in the fake's
            only thread, which also answers GVCP: a callback that blocks for seconds (a JAX renderer
            compiling on its first call) misses the client's heartbeats, the fake drops the client's
            control channel and stops streaming. Every frame must render well within ~1 s.
        trigger_poll_hz: how often the fake checks for a software trigger (Aravis' default, 25 Hz,
            adds up to 40 ms of latency to every triggered frame).
        lock_timeout_s: how long :meth:`start` waits for another fake on the same address (in this
            network namespace, any process: parallel test workers) to finish.
        lens_features: the device also has a motorised lens: integer features ``Zoom`` and ``Focus``
            (:data:`LENS_FEATURES`, motor steps 0..1000), whose current values every
            :class:`FrameRequest` carries in ``lens`` (the frame source renders through the lens there).

    Use as a context manager, or call :meth:`start` / :meth:`stop`. Several fakes can live in one
    process (one per address); the GigE client can live in the same process.
    """

    def __init__(
        self,
        frame_source: FrameSource,
        address: str = "127.0.0.1",
        *,
        sensor_size: tuple[int, int] = (640, 480),
        serial: str = "JCALIB-FAKE-0",
        loss_ratio: float = 0.0,
        warm_up: bool = True,
        trigger_poll_hz: float = 500.0,
        lock_timeout_s: float = 120.0,
        lens_features: bool = False,
    ) -> None:
        w, h = (int(v) for v in sensor_size)
        if not (8 <= w <= 16384 and 8 <= h <= 16384):
            raise BadInputError(f"sensor_size: expected (width, height) in 8..16384, got {sensor_size}")
        self.frame_source = frame_source
        self.address = address
        self.sensor_size = (w, h)
        if not serial or len(serial.encode()) >= 16:  # ARV_GVBS_SERIAL_NUMBER_SIZE, NUL included
            raise BadInputError(
                f"serial: got {serial!r} ({len(serial.encode())} bytes), expected 1..15 bytes "
                "(GigE Vision's bootstrap register holds 16 bytes with the terminating NUL)"
            )
        self.serial = serial
        self._loss_ratio = float(loss_ratio)
        self._gv: int | None = None
        self._callback = _FILL(self._fill)  # must outlive the device
        self._lock = threading.Lock()
        self.frames_served = 0
        self.source_errors: list[str] = []
        self.lock_timeout_s = float(lock_timeout_s)
        self.trigger_poll_hz = float(trigger_poll_hz)
        self.warm_up = bool(warm_up)
        self._lock_fd = -1
        self.guard: GvcpGuard | None = None
        self.lens_features = bool(lens_features)
        self._fake: int | None = None
        self._xml_path: str | None = None

    def _acquire_address(self) -> None:
        """Only one GigE device can own UDP port 3956 on an address: serialise users across processes."""
        try:
            netns = os.stat("/proc/self/ns/net").st_ino
        except OSError:
            netns = 0
        path = os.path.join(tempfile.gettempdir(), f"jcalib-fake-gige-{netns}-{self.address}.lock")
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        deadline = time.monotonic() + self.lock_timeout_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                self._lock_fd = fd
                return
            except BlockingIOError:
                if time.monotonic() > deadline:
                    os.close(fd)
                    raise DeviceError(
                        f"another fake GigE camera has held {self.address} for {self.lock_timeout_s} s ({path})"
                    ) from None
                time.sleep(0.05)

    def _release_address(self) -> None:
        if self._lock_fd >= 0:
            os.close(self._lock_fd)
            self._lock_fd = -1

    # The callback runs in Aravis' streaming thread; ctypes takes the GIL for it.
    def _fill(self, buf, _data, exposure_us, gain, pixel_format) -> None:
        arv, _ = load_libraries()
        try:
            w, h = arv.arv_buffer_get_image_width(buf), arv.arv_buffer_get_image_height(buf)
            x, y = arv.arv_buffer_get_image_x(buf), arv.arv_buffer_get_image_y(buf)
            fmt = PIXEL_FORMATS.get(int(pixel_format), "Mono8")
            req = FrameRequest(w, h, x, y, fmt, float(exposure_us), float(gain), self.frames_served, self.lens())
            img = np.asarray(self.frame_source(req))
            if img.shape[:2] != (h, w):
                sw, sh = self.sensor_size
                if img.shape[:2] != (sh, sw):
                    raise ValueError(
                        f"frame source returned shape {img.shape}, expected ({h}, {w}) or the sensor ({sh}, {sw})"
                    )
                region = np.zeros((h, w) + img.shape[2:], img.dtype)  # a region past the sensor edge: black
                part = img[y : y + h, x : x + w]
                region[: part.shape[0], : part.shape[1]] = part
                img = region
            px = np.ascontiguousarray(to_pixels(img, fmt))
            bpp = (int(pixel_format) >> 16) & 0xFF
            nbytes = w * h * bpp // 8
            if px.nbytes != nbytes:
                raise ValueError(f"{fmt} frame of {px.nbytes} bytes, buffer expects {nbytes}")
            # (the fake calls us only when its buffer holds width x height of the current format)
            ptr = arv.arv_buffer_get_data(buf, None)
            ctypes.memmove(ptr, px.ctypes.data, nbytes)
            self.frames_served += 1
        except Exception:  # never let an exception cross into C
            self.source_errors.append(traceback.format_exc(limit=3))

    def start(self) -> "FakeGigECamera":
        """Create the device and start serving."""
        arv, _ = load_libraries()
        if self._gv is not None:
            return self
        if self.warm_up:  # compile / cache whatever the source needs before the device must answer
            w, h = self.sensor_size
            self.frame_source(FrameRequest(w, h, 0, 0, "Mono8", 10000.0, 0.0, 0))
        self._acquire_address()
        before = udp_sockets()
        if self.lens_features:
            gv = arv.arv_gv_fake_camera_new_full(self.address.encode(), self.serial.encode(), self._lens_xml().encode())
        else:
            gv = arv.arv_gv_fake_camera_new(self.address.encode(), self.serial.encode())
        if not gv or not arv.arv_gv_fake_camera_is_running(gv):
            if gv:
                load_libraries()[1].g_object_unref(gv)
            self._release_address()
            raise DeviceError(
                f"the fake GigE camera could not start on {self.address}: no local interface has that "
                "address, or UDP port 3956 is taken there (another fake camera?)"
            )
        fake = arv.arv_gv_fake_camera_get_fake_camera(gv)
        w, h = self.sensor_size
        for reg, val in ((_REG_SENSOR_WIDTH, w), (_REG_SENSOR_HEIGHT, h), (_REG_WIDTH, w), (_REG_HEIGHT, h)):
            arv.arv_fake_camera_write_register(fake, reg, val)
        self._fake = fake
        for reg, default, _ in (LENS_FEATURES.values() if self.lens_features else ()):
            arv.arv_fake_camera_write_register(fake, reg, default)
        arv.arv_fake_camera_set_fill_pattern(fake, self._callback, None)
        arv.arv_fake_camera_set_trigger_frequency(fake, self.trigger_poll_hz)
        self._gv = gv
        try:
            self.guard = self._guard(fake, {fd: a for fd, a in udp_sockets().items() if before.get(fd) != a})
        except OSError as e:
            self.stop()
            raise DeviceError(f"the fake GigE camera on {self.address} could not be guarded: {e}") from e
        self.set_loss_ratio(self._loss_ratio)
        return self

    def _lens_xml(self) -> str:
        """Write the GenICam XML with the lens features to a temporary file (once); its path."""
        if self._xml_path is None:
            arv, gobj = load_libraries()
            probe = arv.arv_fake_camera_new(b"JCALIB-XML")
            size = ctypes.c_size_t()
            data = arv.arv_fake_camera_get_genicam_xml(probe, ctypes.byref(size))
            base = ctypes.string_at(data, size.value).decode("utf-8").rstrip("\x00")
            gobj.g_object_unref(probe)
            fd, path = tempfile.mkstemp(prefix="jcalib-fake-lens-", suffix=".xml")
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(lens_genicam_xml(base))
            self._xml_path = path
        return self._xml_path

    def lens(self) -> dict[str, float]:
        """The lens features' current values (empty without ``lens_features``)."""
        if not self.lens_features or self._fake is None:
            return {}
        arv, _ = load_libraries()
        out = {}
        for name, (reg, _, _) in LENS_FEATURES.items():
            value = ctypes.c_uint32()
            arv.arv_fake_camera_read_register(self._fake, reg, ctypes.byref(value))
            out[name] = float(value.value)
        return out

    def _guard(self, fake: int, fds: dict[int, tuple[str, int]]) -> GvcpGuard:
        """Put :class:`GvcpGuard` in front of the fake's GVCP port (see the module docstring)."""
        arv, _ = load_libraries()

        def read_memory(address: int, size: int) -> bytes:
            buf = ctypes.create_string_buffer(size)
            arv.arv_fake_camera_read_memory(fake, address, size, buf)
            return buf.raw

        check = Check(self.sensor_size, xml_size_of(read_memory), set(PIXEL_FORMATS))
        timeout_ms = int.from_bytes(read_memory(0x0938, 4), "big") or 3000
        return GvcpGuard(self.address, fds, check, heartbeat_timeout_s=timeout_ms / 1000.0).start()

    def set_loss_ratio(self, ratio: float) -> None:
        """Drop this fraction (0..1) of the stream packets from now on."""
        if not 0.0 <= ratio <= 1.0:
            raise BadInputError(f"loss_ratio: expected a fraction in [0, 1], got {ratio}")
        self._loss_ratio = float(ratio)
        if self._gv is not None:
            load_libraries()[1].g_object_set(self._gv, b"gvsp-lost-ratio", ctypes.c_double(self._loss_ratio), None)

    def stop(self) -> None:
        """Stop serving and free the device (its threads are joined)."""
        guard, self.guard = self.guard, None
        if guard is not None:
            guard.stop()
        if self._gv is not None:
            gv, self._gv = self._gv, None
            self._fake = None
            load_libraries()[1].g_object_unref(gv)
        if self._xml_path is not None:
            path, self._xml_path = self._xml_path, None
            with contextlib.suppress(OSError):
                os.unlink(path)
        if guard is not None:
            guard.close_inner()
        self._release_address()

    def __enter__(self) -> "FakeGigECamera":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
