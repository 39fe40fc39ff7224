"""Universal Robots' RTDE wire format (Real-Time Data Exchange, TCP port 30004), shared by the driver and the simulator.

Every package, both ways, is ``u16 size`` (bytes, header included) + ``u8 command`` + payload, big-endian.
Commands (protocol version 2, what UR's own client library and ``ur_rtde`` speak):

====  ==========================  ============================================  ===============================
code  command                     client sends                                  controller answers
====  ==========================  ============================================  ===============================
``V`` REQUEST_PROTOCOL_VERSION    ``u16 version``                               ``u8 accepted``
``v`` GET_URCONTROL_VERSION       (nothing)                                     ``u32 major, minor, bugfix, build``
``O`` CONTROL_PACKAGE_SETUP_OUTPUTS ``f64 frequency`` + names, comma-separated  ``u8 recipe id`` + types, comma-separated
``I`` CONTROL_PACKAGE_SETUP_INPUTS names, comma-separated                       ``u8 recipe id`` + types
``S`` CONTROL_PACKAGE_START       (nothing)                                     ``u8 accepted``
``P`` CONTROL_PACKAGE_PAUSE       (nothing)                                     ``u8 accepted``
``U`` DATA_PACKAGE                ``u8 input recipe id`` + values               (the controller streams ``u8 output
                                                                                recipe id`` + values at the frequency)
``M`` TEXT_MESSAGE                ``u8 len`` + message, ``u8 len`` + source, ``u8 level`` (either way)
====  ==========================  ============================================  ===============================

A name the controller does not know comes back as type ``NOT_FOUND``, an input another client already writes
as ``IN_USE``. Values are packed back to back in recipe order: ``BOOL`` ``?``, ``UINT8`` ``B``, ``UINT32``
``I``, ``UINT64`` ``Q``, ``INT32`` ``i``, ``DOUBLE`` ``d``, ``VECTOR3D`` ``3d``, ``VECTOR6D`` ``6d``,
``VECTOR6INT32`` ``6i``, ``VECTOR6UINT32`` ``6I``.

:data:`OUTPUTS` lists the controller's output fields (UR's RTDE guide, e-Series 5.x) with their types;
:func:`field_type` also resolves the numbered registers. Poses (``actual_TCP_pose``, ``tcp_offset``) are
``[x, y, z, rx, ry, rz]``: metres and a rotation vector (rad) in the robot's base frame.
"""

from __future__ import annotations

import re
import socket
import struct
from dataclasses import dataclass

from jcalib.acquisition.robots.base import recv_exact

RTDE_PORT = 30004
#: The secondary client interface, which runs URScript sent to it.
SCRIPT_PORT = 30002
PROTOCOL_VERSION = 2

HEADER = struct.Struct(">HB")
#: Largest package: the size field is 16 bits.
MAX_PACKAGE = 0xFFFF
#: UR's limit on the bytes of a recipe's variable names.
MAX_RECIPE_NAMES = 2048

REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

#: Text message levels.
EXCEPTION_MESSAGE, ERROR_MESSAGE, WARNING_MESSAGE, INFO_MESSAGE = 0, 1, 2, 3

TYPE_FORMATS = {"BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i", "DOUBLE": "d",
                "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I"}  # fmt: skip

_V6D, _V3D, _D = "VECTOR6D", "VECTOR3D", "DOUBLE"
#: The controller's output fields (besides the numbered registers) and their types.
OUTPUTS: dict[str, str] = {
    "timestamp": _D, "target_q": _V6D, "target_qd": _V6D, "target_qdd": _V6D, "target_current": _V6D,
    "target_moment": _V6D, "actual_q": _V6D, "actual_qd": _V6D, "actual_current": _V6D,
    "actual_current_window": _V6D, "joint_control_output": _V6D, "actual_TCP_pose": _V6D,
    "actual_TCP_speed": _V6D, "actual_TCP_force": _V6D, "target_TCP_pose": _V6D, "target_TCP_speed": _V6D,
    "actual_digital_input_bits": "UINT64", "joint_temperatures": _V6D, "actual_execution_time": _D,
    "robot_mode": "INT32", "joint_mode": "VECTOR6INT32", "safety_mode": "INT32", "safety_status": "INT32",
    "actual_tool_accelerometer": _V3D, "speed_scaling": _D, "target_speed_fraction": _D, "actual_momentum": _D,
    "actual_main_voltage": _D, "actual_robot_voltage": _D, "actual_robot_current": _D,
    "actual_joint_voltage": _V6D, "actual_digital_output_bits": "UINT64", "runtime_state": "UINT32",
    "elbow_position": _V3D, "elbow_velocity": _V3D, "robot_status_bits": "UINT32", "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32", "standard_analog_input0": _D, "standard_analog_input1": _D,
    "standard_analog_output0": _D, "standard_analog_output1": _D, "io_current": _D,
    "euromap67_input_bits": "UINT32", "euromap67_output_bits": "UINT32", "euromap67_24V_voltage": _D,
    "euromap67_24V_current": _D, "tool_mode": "UINT32", "tool_analog_input_types": "UINT32",
    "tool_analog_input0": _D, "tool_analog_input1": _D, "tool_output_voltage": "INT32", "tool_output_current": _D,
    "tool_temperature": _D, "tcp_force_scalar": _D, "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32", "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32", "tool_output_mode": "UINT8", "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8", "payload": _D, "payload_cog": _V3D, "payload_inertia": _V6D,
    "script_control_line": "UINT32", "ft_raw_wrench": _V6D, "joint_position_deviation_ratio": _V6D,
    "collision_detection_ratio": _D, "time_scale_source": "UINT32", "tcp_offset": _V6D,
    "actual_current_as_torque": _V6D,
}  # fmt: skip
#: The input fields a client may write (besides the numbered input registers).
INPUTS: dict[str, str] = {
    "speed_slider_mask": "UINT32", "speed_slider_fraction": _D, "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8", "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8", "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8", "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": _D, "standard_analog_output_1": _D, "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32", "external_force_torque": _V6D,
}  # fmt: skip
_REGISTER = re.compile(r"^(input|output)_(int|double|bit)_register_(\d{1,3})$")
_REGISTER_TYPES = {"int": "INT32", "double": _D, "bit": "BOOL"}

#: ``robot_mode`` values.
ROBOT_MODES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
               4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE"}  # fmt: skip
ROBOT_MODE_RUNNING = 7
#: ``safety_mode`` values.
SAFETY_MODES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
                6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
                10: "VALIDATE_JOINT_ID", 11: "UNDEFINED_SAFETY_MODE", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
                13: "SYSTEM_THREE_POSITION_ENABLING_STOP"}  # fmt: skip
SAFETY_NORMAL, SAFETY_REDUCED, SAFETY_PROTECTIVE_STOP = 1, 2, 3
SAFETY_EMERGENCY_STOPS = (6, 7)
#: ``runtime_state`` values.
RUNTIME_STATES = {0: "STOPPING", 1: "STOPPED", 2: "PLAYING", 3: "PAUSING", 4: "PAUSED", 5: "RESUMING"}
RUNTIME_STOPPED, RUNTIME_PLAYING, RUNTIME_PAUSED = 1, 2, 4


def field_type(name: str, inputs: bool = False) -> str | None:
    """The RTDE type of output (or, with ``inputs``, input) field ``name``; None when the controller has no such field.

    Numbered registers: ``output_int_register_N`` / ``output_double_register_N`` (N = 0..47),
    ``output_bit_register_N`` (N = 64..127), and the same ``input_*`` ones (outputs may read inputs too).
    """
    m = _REGISTER.match(name)
    if m:
        n = int(m.group(3))
        ok = 64 <= n <= 127 if m.group(2) == "bit" else 0 <= n <= 47
        if not ok or (inputs and m.group(1) == "output"):
            return None
        return _REGISTER_TYPES[m.group(2)]
    return INPUTS.get(name) if inputs else OUTPUTS.get(name)


def encode_package(command: int, payload: bytes = b"") -> bytes:
    """One package: header + payload.

    Raises:
        ValueError: the package would exceed :data:`MAX_PACKAGE` bytes.
    """
    size = HEADER.size + len(payload)
    if size > MAX_PACKAGE:
        raise ValueError(f"RTDE package of {size} bytes exceeds {MAX_PACKAGE}")
    return HEADER.pack(size, command & 0xFF) + payload


def read_package(sock: socket.socket) -> tuple[int, bytes]:
    """``(command, payload)`` of the next package on ``sock``.

    Raises:
        ConnectionError: the peer closed the connection.
        ValueError: a size field below the header's 3 bytes (not RTDE framing).
    """
    size, command = HEADER.unpack(recv_exact(sock, HEADER.size))
    if size < HEADER.size:
        raise ValueError(f"RTDE package size {size} is below the 3-byte header")
    return command, recv_exact(sock, size - HEADER.size)


def encode_text_message(message: str, source: str = "jcalib", level: int = INFO_MESSAGE) -> bytes:
    """A protocol-2 text message package (message and source cut to 255 bytes)."""
    m, s = message.encode("utf-8", "replace")[:255], source.encode("utf-8", "replace")[:255]
    return encode_package(TEXT_MESSAGE, bytes([len(m)]) + m + bytes([len(s)]) + s + bytes([level & 0xFF]))


def decode_text_message(payload: bytes) -> tuple[str, str, int]:
    """``(message, source, level)`` of a protocol-2 text message payload.

    Raises:
        ValueError: truncated.
    """
    if not payload:
        raise ValueError("empty text message")
    n = payload[0]
    message = payload[1 : 1 + n]
    rest = payload[1 + n :]
    if len(message) != n or not rest:
        raise ValueError("truncated text message")
    k = rest[0]
    source = rest[1 : 1 + k]
    if len(source) != k or len(rest) != 2 + k:
        raise ValueError("truncated text message")
    return message.decode("utf-8", "replace"), source.decode("utf-8", "replace"), rest[1 + k]


@dataclass(frozen=True)
class Recipe:
    """An agreed list of fields: its id, names and types, and the struct that packs a data package's values.

    Attributes:
        id: recipe id (1..255).
        names: field names in order.
        types: their RTDE types (every one in :data:`TYPE_FORMATS`).
    """

    id: int
    names: tuple[str, ...]
    types: tuple[str, ...]

    @property
    def struct(self) -> struct.Struct:
        return struct.Struct(">B" + "".join(TYPE_FORMATS[t] for t in self.types))

    def pack(self, values: dict) -> bytes:
        """A data package's payload: the recipe id then ``values[name]`` per field (vectors as sequences)."""
        flat: list = [self.id]
        for name, t in zip(self.names, self.types):
            v = values[name]
            if t.startswith("VECTOR"):
                flat.extend(v)
            else:
                flat.append(v)
        return self.struct.pack(*flat)

    def unpack(self, payload: bytes) -> dict:
        """``{name: value}`` of a data package's payload (vectors as tuples).

        Raises:
            ValueError: wrong size or recipe id.
        """
        st = self.struct
        if len(payload) != st.size:
            raise ValueError(f"data package of {len(payload)} bytes for recipe {self.id}, expected {st.size}")
        flat = st.unpack(payload)
        if flat[0] != self.id:
            raise ValueError(f"data package of recipe {flat[0]}, expected {self.id}")
        out, i = {}, 1
        for name, t in zip(self.names, self.types):
            n = 6 if t.startswith("VECTOR6") else 3 if t.startswith("VECTOR3") else 1
            out[name] = flat[i] if n == 1 else tuple(flat[i : i + n])
            i += n
        return out


def parse_names(text: bytes) -> list[str] | None:
    """The field names of a setup payload (comma-separated ASCII); None when it is not that."""
    if len(text) > MAX_RECIPE_NAMES or not text.isascii():
        return None
    names = [n.strip() for n in text.decode("ascii").split(",")]
    if names and names[-1] == "" and len(names) > 1:  # ur_rtde ends the list with a comma
        names.pop()
    if not names or any(not n or not n.isprintable() for n in names):
        return None
    return names
