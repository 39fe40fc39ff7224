"""Validation helpers of the study's file forms: each error names the key, the value and what was expected."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError

__all__ = ["check_keys", "fail", "integer", "number", "numbers", "poses", "read_file", "relative"]



def fail(key: str, value: Any, expected: str) -> BadInputError:
    """``BadInputError('<key>: got <value>, expected <expected>')``."""
    return BadInputError(f"{key}: got {value!r}, expected {expected}")


def check_keys(data: dict, allowed, where: str) -> None:
    for k in data:
        if k not in allowed:
            raise BadInputError(f"{where}.{k}: unknown key; expected one of {sorted(allowed)}")


def number(value: Any, key: str, lo: float | None = None, hi: float | None = None, *, lo_open=False,
           hi_open=False) -> float:
    """A finite number within the bounds, else a BadInputError naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise fail(key, value, "a finite number")
    v = float(value)
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise fail(key, value, f"a number {'>' if lo_open else '>='} {lo:g}")
    if hi is not None and (v > hi or (hi_open and v == hi)):
        raise fail(key, value, f"a number {'<' if hi_open else '<='} {hi:g}")
    return v


def numbers(value: Any, key: str, n: int | None = None) -> list[float]:
    if not isinstance(value, (list, tuple)) or (n is not None and len(value) != n):
        raise fail(key, value, f"a list of {n if n is not None else 'some'} numbers")
    return [number(v, f"{key}[{i}]") for i, v in enumerate(value)]


def integer(value: Any, key: str, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < lo:
        raise fail(key, value, f"an integer >= {lo}")
    return int(value)


def poses(value: Any, key: str, minimum: int = 1) -> np.ndarray:
    """A list of rigid 4x4 transforms (m)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise fail(key, type(value).__name__, "a list of 4x4 poses (m)") from None
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != (4, 4) or len(arr) < minimum or not np.all(np.isfinite(arr)):
        raise fail(key, f"array of shape {arr.shape}", f"at least {minimum} finite 4x4 pose(s) (m)")
    R = arr[:, :3, :3]
    if np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max() > 1e-6 or np.any(np.linalg.det(R) < 0):
        raise fail(key, "a matrix that is not a rigid transform", "4x4 poses with orthonormal rotations")
    return arr


def read_file(path: str | os.PathLike, key: str = "scenario") -> Any:
    """A scenario (or a file it names) within jcalib's input limits: size, UTF-8, JSON / YAML depth and
    aliases (:func:`jcalib.io.schema.reading.read_document`); errors name ``key``."""
    from jcalib.io.schema.reading import read_document

    try:
        return read_document(path, f"{key}: file")
    except BadInputError as err:
        msg = str(err)
        raise BadInputError(msg if msg.startswith(key) else f"{key}: {msg}") from None


def relative(path: Any, base: Path | None, key: str) -> Path:
    """``path`` from the folder ``base`` (the scenario's) unless absolute."""
    if not isinstance(path, (str, os.PathLike)):
        raise fail(key, path, "a file path")
    p = Path(path)
    return base / p if not p.is_absolute() and base is not None else p
