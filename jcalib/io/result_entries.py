"""Entries of the result file besides cameras: transforms, points, calibrated kinematics and target warps
(:mod:`jcalib.io.result` holds the file, its conventions and its units; it re-exports these classes).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jcalib.io.result_fields import check_entry_keys, extra_keys, field_array, field_covariance, field_fail, field_json, field_name, field_transform, float_list

__all__ = ["WARP_DEFINITION", "KinematicsResult", "PointResult", "TargetResult", "TransformResult"]


@dataclass(frozen=True, eq=False)
class TransformResult:
    """One rigid transform ``T_a_b`` (maps points of *b* into *a*).

    Attributes:
        matrix: ``(4, 4)``, metres.
        covariance: optional ``(6, 6)`` over the right-perturbation tangent ``(rx, ry, rz, tx, ty,
            tz)`` (rad, m) in frame *b*: ``T_true = T . Exp(delta)``.
        extra: further JSON keys, kept as they are.
    """

    matrix: np.ndarray
    covariance: np.ndarray | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "matrix", field_transform(self.matrix, "matrix"))
        if self.covariance is not None:
            object.__setattr__(
                self,
                "covariance",
                field_covariance(self.covariance, 6, "covariance (rx, ry, rz, tx, ty, tz)"),
            )
        object.__setattr__(self, "extra", field_json(dict(self.extra), "extra"))

    @property
    def std(self) -> np.ndarray | None:
        """Standard deviations ``(6,)`` in tangent order (rad, rad, rad, m, m, m), or None."""
        return None if self.covariance is None else np.sqrt(np.diag(self.covariance))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"matrix": float_list(self.matrix)}
        if self.covariance is not None:
            out["covariance"] = float_list(self.covariance)
        out.update(self.extra)
        return out

    @classmethod
    def from_dict(cls, data: Any) -> TransformResult:
        check_entry_keys(data, ("matrix",))
        return cls(
            matrix=data["matrix"],
            covariance=data.get("covariance"),
            extra=extra_keys(data, ("matrix", "covariance")),
        )


@dataclass(frozen=True, eq=False)
class PointResult:
    """One estimated point.

    Attributes:
        position: ``(3,)``, metres, in ``frame``.
        frame: the frame name, e.g. ``"base"``.
        covariance: optional ``(3, 3)``, m².
        extra: further JSON keys, kept as they are.
    """

    position: np.ndarray
    frame: str = "base"
    covariance: np.ndarray | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", field_array(self.position, (3,), "position"))
        field_name(self.frame, "frame")
        if self.covariance is not None:
            object.__setattr__(self, "covariance", field_covariance(self.covariance, 3, "covariance"))
        object.__setattr__(self, "extra", field_json(dict(self.extra), "extra"))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"position": float_list(self.position), "frame": self.frame}
        if self.covariance is not None:
            out["covariance"] = float_list(self.covariance)
        out.update(self.extra)
        return out

    @classmethod
    def from_dict(cls, data: Any) -> PointResult:
        check_entry_keys(data, ("position", "frame"))
        return cls(
            position=data["position"],
            frame=data["frame"],
            covariance=data.get("covariance"),
            extra=extra_keys(data, ("position", "frame", "covariance")),
        )


@dataclass(frozen=True, eq=False)
class KinematicsResult:
    """A robot's calibrated kinematic model.

    Attributes:
        convention: ``"dh"``, ``"mdh"`` or ``"poe"`` (:mod:`jcalib.geometry.kinematic_models`).
        names: ``(P,)`` parameter names (``<joint>.<parameter>``, ``base.*``, ``flange.*``).
        values, nominal: ``(P,)`` calibrated and nominal parameters (m, rad).
        calibrated: the estimated parameter names (the others are held at their nominal value).
        covariance: ``(p, p)`` over ``calibrated`` in that order (m², rad², m·rad), or None.
        extra: further JSON keys, kept as they are (``held``: name -> why, ``controller_offsets``,
            ``table``, ``correction_rms_*``, ``repeatability``).
    """

    convention: str
    names: tuple[str, ...]
    values: np.ndarray
    nominal: np.ndarray
    calibrated: tuple[str, ...] = ()
    covariance: np.ndarray | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        field_name(self.convention, "convention")
        names = tuple(field_name(n, f"names[{i}]") for i, n in enumerate(self.names))
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "values", field_array(self.values, (len(names),), "values"))
        object.__setattr__(self, "nominal", field_array(self.nominal, (len(names),), "nominal"))
        bad = [n for n in self.calibrated if n not in names]
        if bad:
            raise field_fail("calibrated", f"names {bad} are not among the parameter names")
        object.__setattr__(self, "calibrated", tuple(self.calibrated))
        if self.covariance is not None:
            object.__setattr__(self, "covariance", field_covariance(self.covariance, len(self.calibrated), "covariance"))
        object.__setattr__(self, "extra", field_json(dict(self.extra), "extra"))

    @property
    def std(self) -> dict[str, float]:
        """Calibrated name -> one standard deviation (m or rad); empty without a covariance."""
        if self.covariance is None:
            return {}
        return {n: float(np.sqrt(max(v, 0.0))) for n, v in zip(self.calibrated, np.diag(self.covariance))}

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"convention": self.convention,
                               "parameters": {n: float(v) for n, v in zip(self.names, self.values)},
                               "nominal": {n: float(v) for n, v in zip(self.names, self.nominal)},
                               "calibrated": list(self.calibrated)}
        if self.covariance is not None:
            out["std"] = self.std
            out["covariance"] = float_list(self.covariance)
        out["units"] = "lengths m, angles rad; covariance over 'calibrated' in that order"
        out.update(self.extra)
        return out

    @classmethod
    def from_dict(cls, data: Any) -> KinematicsResult:
        check_entry_keys(data, ("convention", "parameters", "nominal"))
        params, nominal = data["parameters"], data["nominal"]
        if not isinstance(params, Mapping) or not isinstance(nominal, Mapping) or list(params) != list(nominal):
            raise field_fail("parameters", "expected name -> value mappings with the same names as 'nominal'")
        return cls(convention=data["convention"], names=tuple(params), values=list(params.values()),
                   nominal=list(nominal.values()), calibrated=tuple(data.get("calibrated") or ()),
                   covariance=data.get("covariance"),
                   extra=extra_keys(data, ("convention", "parameters", "nominal", "calibrated", "std", "covariance",
                                           "units")))


#: How a warp is defined (written next to it, so the file is readable without this code).
WARP_DEFINITION = ("z = c0 (1 - xr^2) + c1 (1 - yr^2) in the target frame, xr and yr in [-1, 1] over the "
                   "extent of the target's points (x along its columns, y along its rows); mrcal's calobject_warp")


@dataclass(frozen=True, eq=False)
class TargetResult:
    """What was estimated about a target itself: its warp (board non-flatness).

    Attributes:
        warp_m: ``(2,)`` ``(c0, c1)``, metres (:data:`WARP_DEFINITION`).
        warp_covariance: optional ``(2, 2)``, m².
        extra: further JSON keys, kept as they are.
    """

    warp_m: np.ndarray
    warp_covariance: np.ndarray | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "warp_m", field_array(self.warp_m, (2,), "warp_m"))
        if self.warp_covariance is not None:
            object.__setattr__(self, "warp_covariance", field_covariance(self.warp_covariance, 2, "warp_covariance"))
        object.__setattr__(self, "extra", field_json(dict(self.extra), "extra"))

    @property
    def warp_std_m(self) -> np.ndarray | None:
        """``(2,)`` standard deviations of ``warp_m``, or None without a covariance."""
        if self.warp_covariance is None:
            return None
        return np.sqrt(np.maximum(np.diag(self.warp_covariance), 0.0))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"warp_m": float_list(self.warp_m)}
        if self.warp_covariance is not None:
            out["warp_std_m"] = float_list(self.warp_std_m)
            out["warp_covariance"] = float_list(self.warp_covariance)
        out["warp_definition"] = WARP_DEFINITION
        out.update(self.extra)
        return out

    @classmethod
    def from_dict(cls, data: Any) -> TargetResult:
        check_entry_keys(data, ("warp_m",))
        return cls(
            warp_m=data["warp_m"],
            warp_covariance=data.get("warp_covariance"),
            extra=extra_keys(data, ("warp_m", "warp_std_m", "warp_covariance", "warp_definition")),
        )
