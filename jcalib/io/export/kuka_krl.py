"""Export TCPs and bases as KUKA KRL ``TOOL_DATA`` / ``BASE_DATA`` lines as in ``$config.dat``.

::

    TOOL_DATA[1]={X 12.345, Y 0.000, Z 201.500, A 0.0000, B 90.0000, C 0.0000}
    TOOL_NAME[1,]="needle"
    BASE_DATA[1]={X 900.000, Y -120.000, Z 10.000, A 45.0000, B 0.0000, C 0.0000}
    BASE_NAME[1,]="board"

``TOOL_DATA[n]`` is ``T_flange_<tool>`` (the TCP in KUKA's ``$FLANGE`` frame); ``BASE_DATA[n]`` is
``T_base_<base>``, which KUKA reads in ``$WORLD``: equal to jcalib's ``base`` when the robot root
is at world (``$ROBROOT`` = 0, the default). ``X, Y, Z`` in mm (3 decimals, 0.001 mm); ``A, B, C``
in degrees (4 decimals, about 2e-6 rad; KRL ``REAL`` is single precision), intrinsic Z-Y'-X'':
``R = Rz(A) Ry(B) Rx(C)``, ``B`` in [-90, 90]; at ``B = +-90`` only ``A -+ C`` is defined and
``C = 0`` is written. Indices: ``TOOL_DATA`` 1..16, ``BASE_DATA`` 1..32; names at most 24
characters. Load data is not written (the calibration does not measure it).
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.atomic import write_text_atomic
from jcalib.io.export._common import checked_export, fixed, frame_selection, provenance_lines, tool_pose
from jcalib.io.result import ResultFile, load_result

__all__ = [
    "ANGLE_DECIMALS",
    "MM_DECIMALS",
    "kuka_config_lines",
    "kuka_frame_literal",
    "write_kuka_krl",
]

#: Decimals of positions (mm): 0.001 mm.
MM_DECIMALS = 3
#: Decimals of A, B, C (degrees): 1e-4 deg (about 2e-6 rad).
ANGLE_DECIMALS = 4
#: ``$config.dat`` sizes: ``TOOL_DATA[16]``, ``BASE_DATA[32]``, ``TOOL_NAME[16,24]``.
MAX_TOOLS, MAX_BASES, NAME_MAX = 16, 32, 24


def kuka_frame_literal(matrix) -> str:
    """The KRL ``FRAME`` literal ``{X .., Y .., Z .., A .., B .., C ..}`` of a 4x4 transform (m)."""
    from jcalib.geometry.conversions import matrix_to_kuka

    v = matrix_to_kuka(np.asarray(matrix, dtype=np.float64))
    parts = [f"{k} {fixed(x, MM_DECIMALS)}" for k, x in zip("XYZ", v[:3], strict=True)]
    parts += [f"{k} {fixed(x, ANGLE_DECIMALS)}" for k, x in zip("ABC", v[3:], strict=True)]
    return "{" + ", ".join(parts) + "}"


def _indices(chosen: dict[str, int | None], limit: int, what: str) -> dict[str, int]:
    taken = {i for i in chosen.values() if i is not None}
    free = (i for i in range(1, limit + 1) if i not in taken)
    out: dict[str, int] = {}
    for frame, index in chosen.items():
        if index is None:
            index = next(free, None)
            if index is None:
                raise BadInputError(
                    f"{what}: more than {limit} frames to export; name the ones to write"
                )
        elif (
            isinstance(index, bool)
            or not isinstance(index, (int, np.integer))
            or not 1 <= index <= limit
        ):
            raise BadInputError(
                f"{what}: the index for {frame!r} must be an integer 1..{limit}, got {index!r}"
            )
        if int(index) in out.values():
            raise BadInputError(f"{what}: index {index} is given to two frames")
        out[frame] = int(index)
    return out


def _krl_name(name: str, what: str) -> str:
    if len(name) > NAME_MAX or not re.fullmatch(r"[ -~]*", name) or '"' in name:
        raise BadInputError(
            f"{what}: {name!r} cannot be a KUKA name (at most {NAME_MAX} printable ASCII characters, no '\"')"
        )
    return name


def kuka_config_lines(
    result: ResultFile,
    tools: Mapping[str, int] | Sequence[str] | str | None = None,
    bases: Mapping[str, int] | Sequence[str] | str | None = None,
    orientations: Mapping[str, np.ndarray] | None = None,
) -> str:
    """``TOOL_DATA``/``TOOL_NAME`` and ``BASE_DATA``/``BASE_NAME`` lines for ``$config.dat``.

    Args:
        result: the calibration result.
        tools: tools (frames with ``T_flange_<tool>``): None = all of them (eye-in-hand cameras
            included), a name, a list, or a mapping tool -> ``TOOL_DATA`` index (1..16). Tools
            without an index take the lowest free ones in order. ``[]`` = none.
        bases: bases (frames with ``T_base_<base>``), likewise with ``BASE_DATA`` indices (1..32).
        orientations: tool -> ``(3, 3)`` orientation for tools whose orientation was not calibrated
            (refused without it, see :func:`jcalib.io.export._common.tool_pose`).

    Returns:
        The text: ``;`` comments with the provenance, then the lines to replace in ``$config.dat``.

    Raises:
        BadInputError: unknown frame, index out of range or used twice, a name KUKA cannot hold,
            nothing to export.
    """
    tool_idx = _indices(frame_selection(result, "flange", tools, "tools"), MAX_TOOLS, "tools")
    base_idx = _indices(frame_selection(result, "base", bases, "bases"), MAX_BASES, "bases")
    if not tool_idx and not base_idx:
        raise BadInputError(
            "tools/bases: nothing to export: the result has no T_flange_<tool> or T_base_<base> "
            f"transforms (it has: {', '.join(result.transforms) or 'none'})"
        )
    lines = ["; Written by jcalib from a calibration result."]
    lines += [f"; {line}" for line in provenance_lines(result, ascii_only=True)]
    lines.append("; Replace the lines with the same index in KRC:\\R1\\System\\$config.dat.")
    lines.append(
        "; X, Y, Z in mm; A, B, C in degrees (R = Rz(A) Ry(B) Rx(C)). Load data not included."
    )
    for tool, i in tool_idx.items():
        T, note = tool_pose(result, tool, orientations)
        lines.append(f"; TOOL_DATA[{i}] {tool}: {note}.")
        lines.append(f"TOOL_DATA[{i}]={kuka_frame_literal(T)}")
        lines.append(f'TOOL_NAME[{i},]="{_krl_name(tool, "tools")}"')
    for base, i in base_idx.items():
        T = result.transforms[f"T_base_{base}"].matrix
        lines.append(f"BASE_DATA[{i}]={kuka_frame_literal(T)}")
        lines.append(f'BASE_NAME[{i},]="{_krl_name(base, "bases")}"')
    return checked_export("\n".join(lines) + "\n", "krl", ascii_only=True)


def write_kuka_krl(
    result: ResultFile | str | os.PathLike,
    path: str | os.PathLike,
    tools: Mapping[str, int] | Sequence[str] | str | None = None,
    bases: Mapping[str, int] | Sequence[str] | str | None = None,
) -> Path:
    """Write :func:`kuka_config_lines` of ``result`` (a :class:`ResultFile` or a path) atomically."""
    return write_text_atomic(path, kuka_config_lines(load_result(result), tools, bases))
