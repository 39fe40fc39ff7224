"""Parse-time checks of the commands' numeric options: typer callbacks that refuse a value out of range
with a usage error (exit status 2) naming the option, before any file is read or any work is done.

Use as ``typer.Option(callback=SEED)`` or ``typer.Option(callback=count(1, 500))``. ``None`` (an option
left out) always passes: the command's default applies. Only ``typer`` is imported (``--help`` stays instant).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import typer

__all__ = ["MAX_SEED", "SEED", "count", "grid", "number", "seed"]

#: The largest random seed any command takes (NumPy and JAX take every seed in 0..2**32 - 1 alike).
MAX_SEED = 2**32 - 1

def seed(value: int | None) -> int | None:
    """A random seed: an integer in 0..:data:`MAX_SEED` (``None`` passes)."""
    if value is not None and not 0 <= value <= MAX_SEED:
        raise typer.BadParameter(f"expected a seed in 0..{MAX_SEED}, got {value}")
    return value


#: The callback of every ``--seed``.
SEED = seed


def count(lo: int, hi: int | None = None, what: str = "") -> Callable[[int | None], int | None]:
    """A callback that accepts an integer count in ``lo..hi`` (``hi`` None: no upper bound)."""
    span = f"{lo}..{hi}" if hi is not None else f">= {lo}"
    noun = f" {what}" if what else ""

    def check(value: int | None) -> int | None:
        if value is not None and not (lo <= value and (hi is None or value <= hi)):
            default = " (0 does not mean the default: leave the option out for that)" if value == 0 else ""
            raise typer.BadParameter(f"expected {span}{noun}, got {value}{default}")
        return value

    return check


def number(lo: float, hi: float, unit: str, *, lo_open: bool = True, hi_open: bool = False,
           allow_inf: bool = False) -> Callable[[float | None], float | None]:
    """A callback that accepts a number in ``(lo, hi]`` (``lo_open``, ``hi_open`` say which ends are open);
    NaN is refused, and infinity unless ``allow_inf``."""
    left, right = "(" if lo_open else "[", ")" if hi_open else "]"

    def check(value: float | None) -> float | None:
        if value is None or (allow_inf and value == math.inf and hi == math.inf):
            return value
        above = value > lo if lo_open else value >= lo
        below = value < hi if hi_open else value <= hi
        if not (math.isfinite(value) and above and below):
            if allow_inf and hi == math.inf:
                raise typer.BadParameter(f"expected a number {'>' if lo_open else '>='} {lo:g} {unit} (inf: "
                                         f"infinity), got {value}")
            raise typer.BadParameter(f"expected a finite number in {left}{lo:g}, {hi:g}{right} {unit}, got {value}")
        return value

    return check


def grid(lo: int = 2, hi: int = 500) -> Callable[[str | None], str | None]:
    """A callback that accepts ``WxH`` grid sizes with ``lo..hi`` points per side (the text is kept)."""

    def check(value: str | None) -> str | None:
        if value is None:
            return value
        w, sep, h = value.lower().partition("x")
        if not sep or not w.strip().isdigit() or not h.strip().isdigit():
            raise typer.BadParameter(f"expected WxH such as 24x18 (grid points across and down), got {value!r}")
        if not (lo <= int(w) <= hi and lo <= int(h) <= hi):
            raise typer.BadParameter(f"expected {lo}..{hi} grid points per side, got {value!r}")
        return value

    return check
