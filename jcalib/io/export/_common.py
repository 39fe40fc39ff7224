"""Shared helpers of the exporters: number formatting, name checks, picking entries of a result."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import rotation_z_to
from jcalib.io.result import ResultFile


def exact_float(x: float) -> str:
    """The shortest text that reads back as exactly ``x`` (Python ``repr``), always with a ``.``
    in the mantissa so YAML 1.1 readers (PyYAML) see a float: ``1e-05`` -> ``1.0e-05``."""
    x = float(x)
    if not np.isfinite(x):
        raise BadInputError(f"cannot export the non-finite number {x}")
    text = repr(x + 0.0)  # + 0.0 turns -0.0 into 0.0
    mantissa, _, exponent = text.partition("e")
    if "." not in mantissa:
        mantissa += ".0"
    return mantissa + ("e" + exponent if exponent else "")


def fixed(x: float, decimals: int) -> str:
    """``x`` with ``decimals`` digits after the point, never ``-0.000``."""
    text = f"{float(x):.{decimals}f}"
    if float(text) == 0.0:
        text = f"{0.0:.{decimals}f}"
    return text


def check_identifier(
    name: Any, what: str, max_len: int, pattern: str = r"[A-Za-z][A-Za-z0-9_]*"
) -> str:
    """``name`` if it is a controller identifier (letter first, then letters, digits, ``_``)."""
    if not isinstance(name, str) or not re.fullmatch(pattern, name) or len(name) > max_len:
        raise BadInputError(
            f"{what}: expected an identifier of at most {max_len} characters (a letter, then "
            f"letters, digits or '_'), got {name!r}"
        )
    return name


def pick_camera(result: ResultFile, camera: str | None) -> str:
    """``camera``, or the only camera of ``result``; :class:`BadInputError` otherwise."""
    if camera is not None:
        result.camera(camera)
        return camera
    if len(result.cameras) != 1:
        raise BadInputError(
            f"camera: the result has {len(result.cameras)} cameras "
            f"({', '.join(result.cameras) or 'none'}); name the one to export"
        )
    return next(iter(result.cameras))


def frame_selection(
    result: ResultFile,
    parent: str,
    selection: Mapping[str, Any] | Sequence[str] | str | None,
    what: str,
) -> dict[str, Any]:
    """Frames ``x`` of transforms ``T_<parent>_x`` to export, mapped to a user value (or None).

    ``selection`` is None (all such frames, sorted), one name, a list of names, or a mapping
    name -> value (a controller name or index).
    """
    available = result.frames_under(parent)
    if selection is None:
        return {x: None for x in available}
    if isinstance(selection, str):
        chosen: dict[str, Any] = {selection: None}
    elif isinstance(selection, Mapping):
        chosen = dict(selection)
    else:
        chosen = {x: None for x in selection}
    for x in chosen:
        if x not in available:
            raise BadInputError(
                f"{what}: the result has no transform T_{parent}_{x}; frames with a T_{parent}_<name> "
                f"transform: {', '.join(available) or 'none'}"
            )
    return chosen


def provenance_lines(result: ResultFile) -> list[str]:
    """Human-readable provenance lines (no comment marker) from the result's own provenance, so
    an export is a pure function of the result."""
    prov = result.provenance
    lines = []
    if prov is not None:
        parts = []
        if prov.jcalib_version:
            parts.append(f"jcalib {prov.jcalib_version}")
        if prov.created:
            parts.append(f"created {prov.created}")
        if prov.input_hash:
            parts.append(f"input {prov.input_hash}")
        if parts:
            lines.append("result: " + ", ".join(parts))
    stats = result.stats
    if "rms_px" in stats:
        lines.append(f"reprojection RMS: {stats['rms_px']:.4g} px")
    return lines


def parse_tool_orientation(text: str) -> tuple[str, np.ndarray]:
    """``TOOL=flange`` (the TCP axes parallel to the flange's) or ``TOOL=X,Y,Z`` (the tool's z axis in
    the flange frame; the rotation about it by the smallest-rotation convention) -> ``(tool, (3, 3))``."""
    tool, sep, value = str(text).partition("=")
    if not sep or not tool:
        raise BadInputError(f"--tool-orientation: expected TOOL=flange or TOOL=X,Y,Z (the tool axis in the flange "
                            f"frame), got {text!r}")
    if value.strip().lower() == "flange":
        return tool, np.eye(3)
    try:
        a = np.asarray([float(v) for v in value.split(",")], np.float64)
    except ValueError:
        a = np.zeros(0)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or not np.linalg.norm(a) > 0:
        raise BadInputError(f"--tool-orientation {tool}: expected 'flange' or three numbers X,Y,Z (a non-zero tool "
                            f"axis in the flange frame), got {value!r}")
    return tool, rotation_z_to(a / np.linalg.norm(a))


def tool_pose(result: ResultFile, tool: str, orientations: Mapping[str, np.ndarray] | None) -> tuple[np.ndarray, str]:
    """The pose ``T_flange_<tool>`` to write to a controller and a comment on its orientation.

    A tool whose orientation the calibration did not determine (``"orientation": "not calibrated"``:
    only its tip was observed) is refused unless ``orientations`` supplies one; a supplied orientation
    replaces the result's rotation (the tip is kept).

    Raises:
        BadInputError: an uncalibrated orientation with none supplied, naming the tool and the fix.
    """
    entry = result.transforms[f"T_flange_{tool}"]
    T = np.array(entry.matrix, dtype=np.float64)
    how = entry.extra.get("orientation", "calibrated") if isinstance(entry.extra, Mapping) else "calibrated"
    given = (orientations or {}).get(tool)
    if given is not None:
        T[:3, :3] = np.asarray(given, np.float64)
        return T, "orientation: supplied at export (not calibrated)"
    if how == "not calibrated":
        raise BadInputError(
            f"tool '{tool}': its orientation was not calibrated (only its tip was observed, no imaged tool axis), so "
            "the exported tool frame would carry a guessed rotation. Supply it: --tool-orientation "
            f"{tool}=flange (TCP axes parallel to the flange's) or {tool}=X,Y,Z (the tool axis in the flange frame), "
            f"or state tools.{tool}.orientation / axis in the cell spec and calibrate again")
    if how == "given":
        return T, "orientation: as stated in the cell spec (not calibrated)"
    if how == "calibrated" and "calibrated" in entry.extra and "rz" not in entry.extra["calibrated"]:
        return T, "orientation: tool axis calibrated; rotation about it by convention (smallest from the flange z)"
    return T, "orientation: calibrated"
