"""The one check of a solve's outcome, for every kind of cell (camera, hand-eye, TCP, pivot, pose pairs,
multi-robot, kinematic): a solve that stopped at its iteration limit, whose residuals are far beyond
the stated noise of their kind, or whose measurements are fewer than its free unknowns (priors alone hold
the rest: the fit absorbs the noise) is never reported silently.

:func:`outcome_warnings` is called by the one result assembler (:func:`jcalib.problems.assemble.assemble`),
so each preset's :class:`~jcalib.problems.assemble.Calibration` carries the warnings in ``warnings`` and the
result file in ``stats["warnings"]`` (which the console and the HTML report print by name).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["NOISE_RATIO", "outcome_warnings"]

#: Residuals whose RMS is over this many times their kind's stated σ are "far beyond the stated noise".
NOISE_RATIO = 5.0

#: kind -> (what it is, unit, factor from the residual's unit to the printed one).
_KIND_TEXT = {
    "corner": ("reprojection", "px", 1.0), "corner_mean": ("reprojection (mean of repeated images)", "px", 1.0),
    "tip": ("tool-tip", "px", 1.0), "axis": ("tool-axis", "px", 1.0), "contact": ("contact", "mm", 1e3),
    "pose_rotation": ("pose-measurement rotation", "deg", float(np.degrees(1.0))),
    "pose_translation": ("pose-measurement translation", "mm", 1e3),
    "position": ("point-sensor position", "mm", 1e3),
}

#: Why the residuals of a kind can be far beyond its noise, and what to try.
_CAUSES = {
    "corner": "the lens model is probably too simple for this lens (try a model with more distortion terms, or "
              "fisheye), detections are wrong, or the robot poses are worse than stated",
    "tip": "wrong tool-tip detections, a tool that moved on the flange, or robot poses worse than stated",
    "axis": "wrong tool-axis detections or a bent tool",
    "contact": "the tip did not touch the point at every station, or the robot poses are worse than stated",
    "pose_rotation": "the pose sensor or the robot is worse than stated, or the data mix frames or units",
    "pose_translation": "the pose sensor or the robot is worse than stated, or the data mix frames or units "
                        "(millimetres written as metres, joints in radians where degrees are expected)",
    "position": "the point sensor or the robot is worse than stated, the reflector moved on the flange, or the data "
                "mix frames or units (millimetres written as metres)",
}


def outcome_warnings(status: str, iterations: int, rms: Mapping[str, float], sigma: Mapping[str, float],
                     max_iterations: int | None = None, num_measurements: int | None = None,
                     num_free: int | None = None) -> list[str]:
    """The warnings a solve's outcome calls for.

    Args:
        status: the solver status in lower case (``converged``, ``max_iterations``, ...).
        iterations: iterations of the final solve.
        rms: residual kind -> RMS of its inlier residual vectors (the kind's unit: px, m, rad).
        sigma: residual kind -> stated σ per coordinate (same unit).
        max_iterations: the iteration limit, when known (for the message).
        num_measurements: residual components of the measurements (priors left out); num_free: the free
            tangent coordinates of the solve.

    Returns:
        One message per finding: the iteration limit (with what to do), then each kind whose RMS is over
        :data:`NOISE_RATIO` times its stated σ (naming the kind, both numbers and the likely causes), then
        measurements no more than the free unknowns.
    """
    out = []
    if status == "max_iterations":
        limit = f"{max_iterations}" if max_iterations is not None else f"{iterations} iterations"
        out.append(f"the solver stopped at its iteration limit ({limit}) before converging: the estimate and its "
                   "σ are unreliable; the data probably do not determine the unknowns well (too few views or "
                   "stations, a model with more unknowns than the data support) or the start is far off; "
                   "add data or raise --max-iterations")
    for kind, value in rms.items():
        stated = sigma.get(kind)
        if kind not in _KIND_TEXT or stated is None or not stated > 0 or not np.isfinite(value):
            continue
        if value > NOISE_RATIO * stated:
            what, unit, scale = _KIND_TEXT[kind]
            cause = _CAUSES.get(kind, _CAUSES["corner"])
            noun = "corner" if kind in ("corner", "corner_mean") else what
            out.append(f"{what} RMS {value * scale:.3g} {unit} is over {NOISE_RATIO:g}x the stated {noun} noise "
                       f"({stated * scale:g} {unit}): {cause}; the reported σ describe noise only, not this "
                       "model error")
    if num_measurements is not None and num_free is not None and 0 < num_measurements <= num_free:
        out.append(f"the measurements ({num_measurements} residuals) do not outnumber the free unknowns "
                   f"({num_free}): priors alone hold the rest, the fit absorbs the noise and the estimate (a focal "
                   "length, a spline, a kinematic parameter) can be far off while the residuals look small; add "
                   "views or stations, or a model with fewer unknowns")
    return out
