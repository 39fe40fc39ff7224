"""Accuracy goals: what must be accurate, in task units (the cell spec's ``goals:``, ``jcalib plan --goal``,
``jcalib capture --goal``).

A goal is ``NAME:QUANTITY<=VALUE``:

- ``T_<a>_<b>:translation_mm<=0.05``: a transform's translation (a hand-eye ``T_flange_cam0``, a fixed
  camera ``T_base_cam1``, a fixed target or work object ``T_base_board``, a TCP ``T_flange_torch``);
  ``position_mm`` is the same quantity (the usual word for a TCP);
- ``T_<a>_<b>:rotation_deg<=0.01``: its rotation;
- ``<point>:position_mm<=0.05``: a cell point (a divot touched by a tool);
- ``<camera>:projection_px<=0.1``: where the camera's intrinsics put a fixed ray in the image, anywhere
  in the image (mrcal's projection uncertainty, from the intrinsics alone).

**What σ means.** The *worst-direction* standard deviation: the square root of the largest eigenvalue of
the quantity's covariance (3 x 3 for a translation, a rotation's tangent or a point; 2 x 2 per pixel for a
projection, the largest over a 9 x 7 grid of the image). A goal is met when that σ is at most its value.
Covariances are the solve's (tangent ``(rx, ry, rz, tx, ty, tz)``, rad and m, right perturbation; the
eigenvalues are the same in the parent frame). Lengths in metres internally, the goal in its unit.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from jcalib.errors import BadInputError

__all__ = ["QUANTITIES", "Goal", "parse_goal", "parse_goals", "projection_grid", "sigma_from_covariance"]

#: Quantity -> (what it measures, unit, factor from the internal unit to the goal's unit).
QUANTITIES = {
    "translation_mm": ("translation", "mm", 1e3),
    "position_mm": ("translation", "mm", 1e3),
    "rotation_deg": ("rotation", "deg", 180.0 / math.pi),
    "projection_px": ("projection", "px", 1.0),
}
_FORM = re.compile(r"^\s*([A-Za-z0-9_.\-]+)\s*:\s*([A-Za-z_]+)\s*<=\s*(\S+)\s*$")
#: Image grid (columns, rows) over which a projection goal takes its worst σ.
PROJECTION_GRID = (9, 7)


@dataclass(frozen=True)
class Goal:
    """One accuracy goal.

    Attributes:
        name: what it is about: a transform (``T_flange_cam0``), a cell point or a camera.
        quantity: a key of :data:`QUANTITIES`.  limit: the largest σ allowed, in :attr:`unit`.
        text: the goal as written.
    """

    name: str
    quantity: str
    limit: float
    text: str

    @property
    def measures(self) -> str:
        """``translation``, ``rotation`` or ``projection``."""
        return QUANTITIES[self.quantity][0]

    @property
    def unit(self) -> str:
        return QUANTITIES[self.quantity][1]

    @property
    def scale(self) -> float:
        """Factor from the internal unit (m, rad, px) to :attr:`unit`."""
        return QUANTITIES[self.quantity][2]

    @property
    def is_transform(self) -> bool:
        return self.name.startswith("T_")

    def label(self) -> str:
        return f"{self.name} {self.quantity.rsplit('_', 1)[0]} σ ({self.unit})"


def parse_goal(text: object, where: str = "--goal") -> Goal:
    """A goal from ``NAME:QUANTITY<=VALUE``.

    Raises:
        BadInputError: not of that form, an unknown quantity, a quantity that does not fit the name
            (``projection_px`` of a transform, ``rotation_deg`` of a point or a camera) or a limit that is
            not a positive number.
    """
    if not isinstance(text, str):
        raise BadInputError(f"{where}: expected a goal like 'T_flange_cam0:translation_mm<=0.05', got {text!r}")
    m = _FORM.match(text)
    if m is None:
        raise BadInputError(f"{where}: {text!r} is not a goal; write NAME:QUANTITY<=VALUE, e.g. "
                            "'T_flange_cam0:translation_mm<=0.05', 'T_flange_cam0:rotation_deg<=0.01', "
                            "'T_flange_torch:position_mm<=0.02' or 'cam0:projection_px<=0.1'")
    name, quantity, value = m.groups()
    if quantity not in QUANTITIES:
        raise BadInputError(f"{where}: {text!r}: unknown quantity {quantity!r}; use one of {', '.join(QUANTITIES)}")
    try:
        limit = float(value)
    except ValueError:
        limit = float("nan")
    if not (math.isfinite(limit) and limit > 0.0):
        raise BadInputError(f"{where}: {text!r}: the limit must be a positive number (the largest σ allowed, "
                            f"in {QUANTITIES[quantity][1]}), got {value!r}")
    transform = name.startswith("T_")
    what = QUANTITIES[quantity][0]
    if transform and what == "projection":
        raise BadInputError(f"{where}: {text!r}: projection_px is a camera's goal (e.g. cam0:projection_px<=0.1); a "
                            "transform takes translation_mm / position_mm or rotation_deg")
    if not transform and what == "rotation":
        raise BadInputError(f"{where}: {text!r}: rotation_deg is a transform's goal (e.g. "
                            "T_flange_cam0:rotation_deg<=0.01); a camera takes projection_px, a point position_mm")
    return Goal(name, quantity, limit, text.strip())


def parse_goals(texts: Iterable[object], where: str = "--goal") -> tuple[Goal, ...]:
    """Goals from their texts; the same name and quantity twice is refused (which limit would hold?)."""
    out: list[Goal] = []
    seen: dict[tuple[str, str], str] = {}
    for i, t in enumerate(texts):
        g = parse_goal(t, f"{where}[{i}]" if where != "--goal" else where)
        key = (g.name, g.measures)
        if key in seen:
            raise BadInputError(f"{where}: {g.text!r} and {seen[key]!r} set two limits on one quantity; keep one")
        seen[key] = g.text
        out.append(g)
    return tuple(out)


def projection_grid(image_size: Sequence[int], shape: tuple[int, int] = PROJECTION_GRID) -> np.ndarray:
    """``(cols * rows, 2)`` pixels spread over the image, corners included, px."""
    w, h = (int(s) for s in image_size)
    u, v = np.meshgrid(np.linspace(0.0, w - 1.0, shape[0]), np.linspace(0.0, h - 1.0, shape[1]))
    return np.stack([u.ravel(), v.ravel()], axis=-1)


def _worst(cov: np.ndarray) -> np.ndarray:
    """Largest eigenvalue of ``(..., k, k)`` symmetric matrices (negative round-off clipped to 0)."""
    return np.maximum(np.linalg.eigvalsh(0.5 * (cov + np.swapaxes(cov, -1, -2)))[..., -1], 0.0)


def sigma_from_covariance(goal: Goal, cov: np.ndarray, projection_jacobian: np.ndarray | None = None) -> np.ndarray:
    """The goal's σ (in its unit) from covariances, batched over leading axes.

    Args:
        goal: the goal.
        cov: ``(..., 6, 6)`` tangent covariance of a transform (``translation``/``rotation``), ``(..., 3, 3)``
            of a point, or ``(..., p, p)`` of a camera's intrinsics (``projection``).
        projection_jacobian: ``projection`` goals only: ``(g, 2, p)`` how each grid pixel's projection moves
            with the intrinsics (rays held fixed).
    Returns:
        ``(...)`` σ.
    """
    cov = np.asarray(cov, np.float64)
    if goal.measures == "projection":
        if projection_jacobian is None:
            raise ValueError("a projection goal needs the projection Jacobian")
        J = np.asarray(projection_jacobian, np.float64)
        g, _, p = J.shape
        JC = np.matmul(J.reshape(2 * g, p), cov).reshape(cov.shape[:-2] + (g, 2, p))
        per_pixel = np.matmul(JC, np.swapaxes(J, -1, -2))  # (..., g, 2, 2)
        a, b, d = per_pixel[..., 0, 0], 0.5 * (per_pixel[..., 0, 1] + per_pixel[..., 1, 0]), per_pixel[..., 1, 1]
        worst = 0.5 * (a + d) + np.sqrt(0.25 * (a - d) ** 2 + b**2)  # the larger eigenvalue of each 2 x 2
        return np.sqrt(np.maximum(worst, 0.0).max(axis=-1)) * goal.scale
    if cov.shape[-1] == 6:
        cov = cov[..., 3:, 3:] if goal.measures == "translation" else cov[..., :3, :3]
    return np.sqrt(_worst(cov)) * goal.scale
