"""What an estimator found in one trial, in one form for the builder and the closed forms."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Estimate", "from_calibration"]


@dataclass
class Estimate:
    """What an estimator found in one trial (metres, radians, pixels); empty where it estimates nothing.

    Attributes:
        cameras: camera id -> parameters (``param_names`` order); ``camera_covariance``: ``(p, p)``.
        transforms: name -> ``(4, 4)``; ``calibrated``: name -> estimated tangent coordinates
            (``rx`` .. ``tz``); ``transform_covariance``: name -> ``(6, 6)`` right perturbation.
        tool_orientation: tool -> ``"calibrated"``, ``"given"`` or ``"not calibrated"``.
        points, point_covariance: cell point -> ``(3,)`` / ``(3, 3)``.
        joint: the builder's joint covariance ``{"names", "dims", "matrix"}`` (intrinsics, transforms).
        rms_px: corner reprojection RMS; num_stations: stations used; runtime_s: see the module docstring.
    """

    cameras: dict = field(default_factory=dict)
    camera_covariance: dict = field(default_factory=dict)
    transforms: dict = field(default_factory=dict)
    calibrated: dict = field(default_factory=dict)
    transform_covariance: dict = field(default_factory=dict)
    tool_orientation: dict = field(default_factory=dict)
    points: dict = field(default_factory=dict)
    point_covariance: dict = field(default_factory=dict)
    joint: dict | None = None
    rms_px: float = math.nan
    num_stations: int = 0
    runtime_s: float = math.nan


def from_calibration(cal) -> Estimate:
    """An :class:`Estimate` of a builder result (:class:`jcalib.problems.assemble.Calibration`)."""
    return Estimate(
        cameras={c: np.asarray(m.params, np.float64) for c, m in cal.cameras.items()},
        camera_covariance={c: np.asarray(v, np.float64) for c, v in cal.intrinsics_covariance.items()},
        transforms={n: np.asarray(T, np.float64) for n, T in cal.transforms.items()},
        calibrated={n: list(v) for n, v in cal.calibrated.items()},
        transform_covariance={n: np.asarray(v, np.float64) for n, v in cal.transform_covariance.items()},
        tool_orientation=dict(cal.tool_orientation),
        points={n: np.asarray(p, np.float64) for n, p in cal.points.items()},
        point_covariance={n: np.asarray(v, np.float64) for n, v in cal.point_covariance.items()},
        joint=cal.joint_covariance, rms_px=float(cal.rms_px), num_stations=len(cal.station_ids))
