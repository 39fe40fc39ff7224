"""Universal Robots' per-robot kinematic calibration file (``calibration.conf``): read and written.

Every UR arm leaves the factory with a kinematic calibration, which its controller keeps in
``/root/.urcontrol/calibration.conf``, an INI file whose ``[mounting]`` section holds, per joint::

    delta_theta = [ 6 numbers ]   # rad
    delta_a = [ 6 numbers ]       # m
    delta_d = [ 6 numbers ]       # m
    delta_alpha = [ 6 numbers ]   # rad
    joint_checksum = [ ... ]      # the controller's own integrity data (not read)
    calibration_status = 2 # 0 == notInitialized / 1 == notLinearised / 2 == Linearised

The controller's kinematics is its type's nominal DH table (UR's published values, e.g. the ``ur5e`` preset)
plus these deltas, with ``theta_i = q_i + delta_theta_i`` (standard DH). Nearly parallel axes make the
calibrated ``d`` of joints 2 to 4 huge (hundreds of metres that cancel); that is the DH form, not an error.

:func:`read_ur_calibration` gives the deltas as a cell spec's ``delta_dh`` (``kinematics: {preset: ur5e,
delta_dh: ...}``), so a robot's own calibration is its nominal kinematics in jcalib; a cell spec may also name
the file, ``kinematics: {preset: ur5e, ur_calibration: calibration.conf}`` (relative to the cell file), which
:func:`jcalib.io.cell.load_cell` replaces by the deltas it holds. :func:`ur_calibration_text` writes deltas in
that form (``jcalib export --format ur-calibration``): what jcalib calibrated, for comparison and records. It
has no checksums and is not a file to copy onto a controller: a UR arm's calibration is changed only by UR's
own procedure.
"""

from __future__ import annotations

import configparser
import math
import os
from collections.abc import Sequence
from pathlib import Path

from jcalib.errors import BadInputError

__all__ = ["UR_CALIBRATION_KEYS", "parse_ur_calibration", "read_ur_calibration", "ur_calibration_text"]

#: The ``[mounting]`` keys read, and the ``delta_dh`` keys they become.
UR_CALIBRATION_KEYS = {"delta_theta": "theta", "delta_a": "a", "delta_d": "d", "delta_alpha": "alpha"}
_STATUS = {0: "notInitialized", 1: "notLinearised", 2: "Linearised"}
_MAX_BYTES = 1 << 20


def _numbers(text: str, key: str, where: str) -> list[float]:
    body = text.strip()
    if not (body.startswith("[") and body.endswith("]")):
        raise BadInputError(f"{where}: {key}: expected a list [n1, n2, ...], got {text.strip()[:80]!r}")
    try:
        values = [float(v) for v in body[1:-1].split(",") if v.strip()]
    except ValueError:
        raise BadInputError(f"{where}: {key}: expected numbers, got {text.strip()[:80]!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise BadInputError(f"{where}: {key}: expected finite numbers, got {values}")
    return values


def parse_ur_calibration(text: str, source: str = "<calibration.conf>") -> dict[str, list[float]]:
    """The deltas of a ``calibration.conf`` text as ``{"theta", "a", "d", "alpha": [n numbers]}`` (rad, m).

    Raises:
        BadInputError: not an INI text with a ``[mounting]`` section, a delta missing or malformed, lists of
            different lengths, or a ``calibration_status`` other than 2 (Linearised: only then are the deltas
            a DH table), each naming the file and the key.
    """
    parser = configparser.ConfigParser(strict=False, inline_comment_prefixes=("#", ";"), interpolation=None)
    try:
        parser.read_string(text, source=source)
    except configparser.Error as e:
        raise BadInputError(f"{source}: not a UR calibration file (INI with a [mounting] section): {e}") from None
    if not parser.has_section("mounting"):
        raise BadInputError(f"{source}: no [mounting] section; a UR controller's calibration.conf has one (it is in "
                            "/root/.urcontrol/ on the controller)")
    mounting = parser["mounting"]
    out: dict[str, list[float]] = {}
    for key, name in UR_CALIBRATION_KEYS.items():
        if key not in mounting:
            raise BadInputError(f"{source}: [mounting] has no {key}; expected {', '.join(UR_CALIBRATION_KEYS)}")
        out[name] = _numbers(mounting[key], key, source)
    lengths = {len(v) for v in out.values()}
    if len(lengths) != 1 or not lengths <= set(range(1, 33)):
        raise BadInputError(f"{source}: the delta lists have {sorted(len(v) for v in out.values())} entries; expected "
                            "one number per joint in each")
    if "calibration_status" in mounting:
        try:
            status = int(mounting["calibration_status"].split()[0])
        except (ValueError, IndexError):
            raise BadInputError(f"{source}: calibration_status: expected 0, 1 or 2, got "
                                f"{mounting['calibration_status']!r}") from None
        if status != 2:
            raise BadInputError(f"{source}: calibration_status is {status} ({_STATUS.get(status, 'unknown')}); only a "
                                "Linearised calibration (2) is a DH table. Read the file of a calibrated controller")
    return out


def read_ur_calibration(path: str | os.PathLike) -> dict[str, list[float]]:
    """:func:`parse_ur_calibration` of the file at ``path``.

    Raises:
        BadInputError: the file cannot be read, is larger than 1 MiB or not UTF-8, or as :func:`parse_ur_calibration`.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise BadInputError(f"UR calibration file {p}: cannot read it ({e.strerror or e})") from None
    if len(data) > _MAX_BYTES:
        raise BadInputError(f"UR calibration file {p}: {len(data)} bytes; a calibration.conf is a few hundred")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise BadInputError(f"UR calibration file {p}: not UTF-8 text") from None
    return parse_ur_calibration(text, str(p))


def _list(values: Sequence[float]) -> str:
    return "[ " + ", ".join(repr(float(v) + 0.0) for v in values) + "]"


def ur_calibration_text(delta: dict[str, Sequence[float]], comments: Sequence[str] = ()) -> str:
    """A ``calibration.conf``-form text of ``delta`` (``{theta, a, d, alpha}``, rad and m) after ``comments``
    (one ``#`` line each; the caller escapes them). Numbers are written exactly (shortest round-trip text).

    Raises:
        BadInputError: a key missing, lists of different lengths, or a non-finite number.
    """
    keys = {name: key for key, name in UR_CALIBRATION_KEYS.items()}
    if set(delta) != set(keys) or len({len(v) for v in delta.values()}) != 1:
        raise BadInputError(f"delta: expected {sorted(keys)} with one number per joint each, got {sorted(delta)}")
    if not all(math.isfinite(float(v)) for vs in delta.values() for v in vs):
        raise BadInputError("delta: non-finite number; nothing to export")
    lines = [f"# {c}" for c in comments] + ["[mounting]"]
    lines += [f"{keys[name]} = {_list(delta[name])}" for name in ("theta", "a", "d", "alpha")]
    return "\n".join(lines) + "\n"
