"""Shared helpers of the exporters: number formatting, name checks, picking entries of a result."""

from __future__ import annotations

import re
import unicodedata
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


#: Characters some reader takes as a line break (Python's ``str.splitlines``, YAML 1.1, C1 NEL).
_LINE_BREAKS = "\n\r\v\f\x1c\x1d\x1e\x85\u2028\u2029"


def _unsafe(c: str, ascii_only: bool) -> bool:
    return c in _LINE_BREAKS or unicodedata.category(c) in ("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp") or (
        ascii_only and ord(c) > 126)


def comment_text(text: Any, ascii_only: bool = False) -> str:
    """``text`` made safe for one comment line of an export: every control, format or line-break
    character (and, for controller files, every non-ASCII one) is written as a ``\\xNN`` /
    ``\\uNNNN`` escape, so no field copied from a result can start a new line.

    Args:
        text: the field (converted with ``str``).
        ascii_only: escape non-ASCII characters too (RAPID and KRL files are read as Latin-1 or ASCII
            by controllers, where UTF-8 bytes 0x80-0x9F are C1 control characters).
    """
    return "".join(c.encode("unicode_escape").decode("ascii") if _unsafe(c, ascii_only) else c for c in str(text))


def checked_export(text: str, fmt: str, ascii_only: bool = False) -> str:
    """``text`` after the last line of defence: no line of an export may hold a character that some
    reader takes as a line break or a control (and controller files only ASCII).

    Raises:
        BadInputError: such a character (a field that escaped :func:`comment_text` or a name check).
    """
    for n, line in enumerate(text.split("\n"), start=1):
        bad = next((c for c in line if c != "\t" and _unsafe(c, ascii_only)), None)
        if bad is not None:
            raise BadInputError(
                f"{fmt} export: line {n} would hold the character {bad!r} (a control, line-break or "
                f"{'non-ASCII ' if ascii_only else ''}character); nothing was written. A name or field of the "
                "result holds it: fix the result file"
            )
    return text


def _clip(text: str, limit: int = 100) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def provenance_lines(result: ResultFile, ascii_only: bool = False) -> list[str]:
    """Human-readable provenance lines (no comment marker) from the result's own provenance, so
    an export is a pure function of the result; every field escaped by :func:`comment_text`."""
    prov = result.provenance
    lines = []
    if prov is not None:
        parts = []
        if prov.jcalib_version:
            parts.append(f"jcalib {_clip(prov.jcalib_version)}")
        if prov.created:
            parts.append(f"created {_clip(prov.created)}")
        if prov.input_hash:
            parts.append(f"input {_clip(prov.input_hash)}")
        if parts:
            lines.append("result: " + comment_text(", ".join(parts), ascii_only))
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


def lens_setting_lines(result, camera: str) -> list[str]:
    """Comment lines (without ``#``) for a zoom camera exported at one lens setting (``jcalib export --at``):
    the setting and each intrinsic's σ; empty for any other camera."""
    values = (result.stats.get("lens_setting") or {}).get(camera)
    if not values or camera not in result.cameras:
        return []
    setting = ", ".join(f"{k}={v:g}" for k, v in values.items())
    std = ", ".join(f"{k}={v:.4g}" for k, v in result.cameras[camera].std.items())
    return [comment_text(f"{camera} at lens setting {setting}; std (1 sigma, sampling noise): {std}")]
