"""The result file (``result.json``, schema ``jcalib.result/1``): what a calibration found.

A pure data layer (NumPy only, no JAX): the solver fills a :class:`ResultFile`, the report and the
exports (:mod:`jcalib.io.export`) read one. See docs/design.md, "File formats and entry points".

Units and conventions (the file states them, readers rely on them):

- cameras: OpenCV's ``K`` (pixels, ``K[0][1]`` = skew, or ``alpha * fx`` for the fisheye) and
  ``dist`` in OpenCV's order, so ``cv2`` takes them unchanged; ``std`` maps intrinsic names
  (``fx, fy, cx, cy, skew|alpha, k1, k2, p1, p2, k3, ...``) to one standard deviation (pixels for
  ``fx..cy`` and ``skew``, unitless for ``alpha`` and distortion); the optional ``covariance`` is
  over the model's intrinsic vector in the order of :attr:`CameraResult.param_names`.
- transforms: ``T_a_b`` maps points of frame *b* into frame *a*; ``matrix`` is 4x4 in metres;
  the optional ``covariance`` (6x6) is over the right-perturbation tangent
  ``T_true = T . Exp(delta)``, ``delta = (rx, ry, rz, tx, ty, tz)`` in radians and metres,
  expressed in frame *b* (:mod:`jcalib.geometry.lie`).
- points: ``position`` (3,) in metres in the named ``frame``; ``covariance`` 3x3 in m².
- targets: ``warp_m`` (2,) ``(c0, c1)``, a board's estimated non-flatness in metres, mrcal's parabolic
  definition ``z = c0 (1 − xr²) + c1 (1 − yr²)`` (``xr, yr`` in ``[−1, 1]`` over the extent of the target's
  points, x along its columns); ``warp_std_m`` (2,) and ``warp_covariance`` 2x2 in m². Only targets
  whose warp was estimated (``warp: true``) are listed.
- kinematics: robot -> its calibrated kinematic model: ``convention``, ``parameters`` and ``nominal``
  (name -> value, m and rad), ``calibrated`` (the estimated names), ``std`` and ``covariance`` over
  them, ``held`` (name -> why it was held), ``controller_offsets`` (joint -> zero offset in the
  controller's units), ``table`` (the model in the cell spec's table form). Only robots whose
  kinematics was calibrated are listed.
- stats: ``rms_px`` (per point: RMS of the corners' error norms, as OpenCV prints), ``rms_px_per_coordinate``
  (RMS of the x and y errors, as mrcal prints), ``num_residuals``, ``sigma_px`` and any further finite JSON values.
- provenance: ``input_hash``, ``jcalib_version``, ``options``, ``created`` (ISO 8601).

Uncertainties are what the solver reports: sampling noise of the observations propagated to the
estimate (scaled by the a-posteriori noise level when the solver says so), not model error.

Every number in the file is finite (a NaN or infinity is a :class:`~jcalib.errors.BadInputError`,
never written). Files are JSON, never pickle, written atomically. Keys this version does not know
are kept (``extra``) and written back, so a newer file survives a round trip through older code.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.atomic import write_text_atomic
from jcalib.io.result_fields import (
    FieldError,
    check_entry_keys,
    extra_keys,
    field_array,
    field_count,
    field_covariance,
    field_fail,
    field_float,
    field_json,
    field_name,
    float_list,
    short_repr,
)
from jcalib.io.result_entries import KinematicsResult, PointResult, TargetResult, TransformResult
from jcalib.io.schema.lens import LENS_DIST_NAMES, dist_problem

__all__ = [
    "CAMERA_MODEL_DIST_NAMES",
    "SCHEMA",
    "TRANSFORM_TANGENT_ORDER",
    "CameraResult",
    "KinematicsResult",
    "PointResult",
    "Provenance",
    "ResultFile",
    "TargetResult",
    "TransformResult",
    "hash_inputs",
    "load_result",
]

SCHEMA = "jcalib.result/1"

#: Order (and units: rad, m) of the tangent vector a transform covariance is expressed in.
TRANSFORM_TANGENT_ORDER = ("rx", "ry", "rz", "tx", "ty", "tz")

#: Distortion coefficient names of each camera model, in OpenCV's order (``len`` = ``len(dist)``).
CAMERA_MODEL_DIST_NAMES: dict[str, tuple[str, ...]] = LENS_DIST_NAMES

# ----------------------------------------------------------------------------------------------
# Entries
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class CameraResult:
    """One calibrated camera, in OpenCV's form.

    Attributes:
        model: lens model name (a key of :data:`CAMERA_MODEL_DIST_NAMES`).
        image_size: ``(width, height)``, pixels.
        K: ``(3, 3)`` camera matrix, pixels: ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``.
        dist: ``(n,)`` distortion coefficients in OpenCV's order (``n`` fixed by ``model``;
            the 4 ``D`` of ``cv2.fisheye`` for ``fisheye``).
        std: intrinsic name -> one standard deviation (names from :attr:`param_names`; any subset).
        covariance: optional ``(p, p)`` covariance of the intrinsic vector, order
            :attr:`param_names` (pixels² for ``fx..cy``, ``skew``).
        skew: whether the model has a skew parameter (``K[0][1]``); None = ``K[0][1] != 0``.
        extra: further JSON keys, kept as they are.
    """

    model: str
    image_size: tuple[int, int]
    K: np.ndarray  # noqa: N815 (OpenCV's name)
    dist: np.ndarray
    std: Mapping[str, float] = field(default_factory=dict)
    covariance: np.ndarray | None = None
    skew: bool | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if not isinstance(self.model, str) or self.model not in CAMERA_MODEL_DIST_NAMES:
            raise field_fail(
                "model",
                f"unknown camera model {self.model!r}; expected one of "
                f"{', '.join(CAMERA_MODEL_DIST_NAMES)}",
            )
        size = self.image_size
        if (
            not isinstance(size, (list, tuple, np.ndarray))
            or len(size) != 2
            or any(
                isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s <= 0 for s in size
            )
        ):
            raise field_fail(
                "image_size",
                f"expected [width, height] as two positive integers, got {short_repr(size)}",
            )
        set_(self, "image_size", (int(size[0]), int(size[1])))
        K = field_array(self.K, (3, 3), "K")
        if (
            K[1, 0] != 0.0
            or K[2, 0] != 0.0
            or K[2, 1] != 0.0
            or K[2, 2] != 1.0
            or K[0, 0] <= 0
            or K[1, 1] <= 0
        ):
            raise field_fail(
                "K",
                f"expected [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K.tolist()}",
            )
        set_(self, "K", K)
        n_dist = len(CAMERA_MODEL_DIST_NAMES[self.model])
        set_(self, "dist", field_array(self.dist, (n_dist,), f"dist (model {self.model!r})"))
        why = dist_problem(self.model, self.dist)
        if why:
            raise field_fail("dist", why)
        if self.skew is None:
            set_(self, "skew", bool(K[0, 1] != 0.0))
        elif not isinstance(self.skew, bool):
            raise field_fail("skew", f"expected true or false, got {short_repr(self.skew)}")
        elif not self.skew and K[0, 1] != 0.0:
            raise field_fail("skew", f"is false but K[0][1] = {K[0, 1]} (the skew) is not 0")
        names = self.param_names
        if not isinstance(self.std, Mapping):
            raise field_fail(
                "std",
                f"expected a mapping of intrinsic name -> standard deviation, got {short_repr(self.std)}",
            )
        std = {}
        for key, value in self.std.items():
            if key not in names:
                raise field_fail(
                    "std",
                    f"unknown intrinsic {key!r} for model {self.model!r}; expected names from {list(names)}",
                )
            std[key] = field_float(value, f"std.{key}", minimum=0.0)
        set_(self, "std", std)
        if self.covariance is not None:
            set_(
                self,
                "covariance",
                field_covariance(self.covariance, len(names), f"covariance (order {list(names)})"),
            )
        set_(self, "extra", field_json(dict(self.extra), "extra"))

    @property
    def param_names(self) -> tuple[str, ...]:
        """Intrinsic names in the order of the intrinsic vector (and of :attr:`covariance`)."""
        skew_name = ("alpha",) if self.model == "fisheye" else ("skew",)
        return (
            ("fx", "fy", "cx", "cy")
            + (skew_name if self.skew else ())
            + CAMERA_MODEL_DIST_NAMES[self.model]
        )

    @property
    def params(self) -> np.ndarray:
        """The intrinsic vector ``(p,)`` in the order of :attr:`param_names`."""
        K = self.K
        s = (K[0, 1] / K[0, 0] if self.model == "fisheye" else K[0, 1],) if self.skew else ()
        return np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], s, self.dist])

    @classmethod
    def from_model(
        cls, model: Any, covariance: Any = None, std: Mapping[str, float] | None = None
    ) -> CameraResult:
        """The entry of a :mod:`jcalib.geometry.cameras` model (duck-typed: ``name``, ``image_size``,
        ``has_skew``, ``to_opencv()``); ``std`` defaults to the square roots of ``covariance``'s
        diagonal (order ``model.param_names``)."""
        K, dist = model.to_opencv()
        entry_std = dict(std or {})
        if covariance is not None and std is None:
            cov = np.asarray(covariance, dtype=np.float64)
            names = tuple(model.param_names)
            if cov.shape != (len(names), len(names)):
                raise field_fail(
                    "covariance", f"expected shape {(len(names), len(names))}, got {cov.shape}"
                )
            entry_std = {n: float(np.sqrt(max(cov[i, i], 0.0))) for i, n in enumerate(names)}
        return cls(
            model.name,
            tuple(model.image_size),
            K,
            dist,
            entry_std,
            covariance,
            bool(model.has_skew),
        )

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "model": self.model,
            "image_size": list(self.image_size),
            "K": float_list(self.K),
            "dist": float_list(self.dist),
        }
        if self.skew:
            out["skew"] = True
        if self.std:
            out["std"] = {k: self.std[k] for k in self.param_names if k in self.std}
        if self.covariance is not None:
            out["covariance"] = float_list(self.covariance)
        out.update(self.extra)
        return out

    @classmethod
    def from_dict(cls, data: Any) -> CameraResult:
        check_entry_keys(data, ("model", "image_size", "K", "dist"))
        known = ("model", "image_size", "K", "dist", "std", "covariance", "skew")
        return cls(
            model=data["model"],
            image_size=data["image_size"],
            K=data["K"],
            dist=data["dist"],
            std=data.get("std", {}),
            covariance=data.get("covariance"),
            skew=data.get("skew"),
            extra=extra_keys(data, known),
        )


@dataclass(frozen=True, eq=False)
class Provenance:
    """Where a result came from.

    Attributes:
        input_hash: e.g. ``"sha256:<hex>"`` of the inputs (:func:`hash_inputs`), or None.
        jcalib_version: the version that computed the result, or None.
        options: the solve options (JSON values).
        created: creation time, ISO 8601 (e.g. ``"2026-11-21T10:00:00Z"``), or None.
        extra: further JSON keys, kept as they are.
    """

    input_hash: str | None = None
    jcalib_version: str | None = None
    options: Mapping[str, Any] = field(default_factory=dict)
    created: str | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key in ("input_hash", "jcalib_version", "created"):
            value = getattr(self, key)
            if value is not None and (not isinstance(value, str) or not value):
                raise field_fail(key, f"expected a non-empty string or null, got {short_repr(value)}")
        if self.created is not None:
            try:
                _dt.datetime.fromisoformat(self.created)
            except ValueError:
                raise field_fail(
                    "created",
                    f"expected an ISO 8601 time like '2026-11-21T10:00:00Z', got {self.created!r}",
                ) from None
        if not isinstance(self.options, Mapping):
            raise field_fail("options", f"expected a mapping, got {short_repr(self.options)}")
        object.__setattr__(self, "options", field_json(dict(self.options), "options"))
        object.__setattr__(self, "extra", field_json(dict(self.extra), "extra"))

    @classmethod
    def now(
        cls, input_hash: str | None = None, options: Mapping[str, Any] | None = None
    ) -> Provenance:
        """Provenance stamped with this jcalib's version and the current UTC time (seconds)."""
        from jcalib import __version__

        created = (
            _dt.datetime.now(_dt.timezone.utc)
            .replace(microsecond=0)
            .isoformat()
            .replace("+00:00", "Z")
        )
        return cls(
            input_hash=input_hash,
            jcalib_version=__version__,
            options=dict(options or {}),
            created=created,
        )

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "input_hash": self.input_hash,
            "jcalib_version": self.jcalib_version,
            "options": dict(self.options),
            "created": self.created,
        }
        out.update(self.extra)
        return out

    @classmethod
    def from_dict(cls, data: Any) -> Provenance:
        check_entry_keys(data, ())
        known = ("input_hash", "jcalib_version", "options", "created")
        return cls(
            input_hash=data.get("input_hash"),
            jcalib_version=data.get("jcalib_version"),
            options=data.get("options", {}),
            created=data.get("created"),
            extra=extra_keys(data, known),
        )


def hash_inputs(*inputs: str | os.PathLike | bytes) -> str:
    """``"sha256:<hex>"`` over the given files' bytes (paths) or byte strings, in order.

    Each input is length-prefixed, so ``("ab", "c")`` and ``("a", "bc")`` hash differently.
    """
    h = hashlib.sha256()
    for item in inputs:
        if isinstance(item, bytes):
            data = item
        else:
            path = Path(item)
            if not path.is_file():
                raise BadInputError(f"hash_inputs: '{path}' is not a file")
            data = path.read_bytes()
        h.update(len(data).to_bytes(8, "little"))
        h.update(data)
    return "sha256:" + h.hexdigest()


# ----------------------------------------------------------------------------------------------
# The file
# ----------------------------------------------------------------------------------------------

_STAT_CHECKS = {
    "rms_px": lambda v, w: field_float(v, w, minimum=0.0),
    "rms_px_per_coordinate": lambda v, w: field_float(v, w, minimum=0.0),
    "sigma_px": lambda v, w: field_float(v, w, minimum=0.0),
    "num_residuals": field_count,
}

_TOP_KEYS = ("schema", "cameras", "transforms", "points", "targets", "kinematics", "stats", "provenance")


def _entries(value: Any, cls: type, where: str) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise field_fail(where, f"expected a mapping of name -> {cls.__name__}, got {short_repr(value)}")
    out = {}
    for key, entry in value.items():
        field_name(key, f"{where} (a key)")
        if not isinstance(entry, cls):
            raise field_fail(f"{where}.{key}", f"expected a {cls.__name__}, got {type(entry).__name__}")
        out[key] = entry
    return out


@dataclass(frozen=True, eq=False)
class ResultFile:
    """The contents of a ``jcalib.result/1`` file.

    Attributes:
        cameras: camera id -> :class:`CameraResult`.
        transforms: ``T_a_b`` name -> :class:`TransformResult` (a TCP is ``T_flange_<tool>``, a
            fixed camera ``T_base_<camera>``, a fixed target ``T_base_<target>``).
        points: point name -> :class:`PointResult`.
        targets: target id -> :class:`TargetResult` (targets whose warp was estimated).
        kinematics: robot name -> :class:`KinematicsResult` (robots whose kinematics was calibrated).
        stats: ``rms_px`` (pixels, per point), ``rms_px_per_coordinate`` (pixels), ``num_residuals``,
            ``sigma_px`` (a-posteriori noise per coordinate, pixels),
            and any further JSON values (all finite).
        provenance: :class:`Provenance`, or None when unknown.
        extra: further top-level JSON keys, kept as they are.
    """

    cameras: Mapping[str, CameraResult] = field(default_factory=dict)
    transforms: Mapping[str, TransformResult] = field(default_factory=dict)
    points: Mapping[str, PointResult] = field(default_factory=dict)
    targets: Mapping[str, TargetResult] = field(default_factory=dict)
    stats: Mapping[str, Any] = field(default_factory=dict)
    provenance: Provenance | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)
    kinematics: Mapping[str, KinematicsResult] = field(default_factory=dict)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "kinematics", _entries(self.kinematics, KinematicsResult, "kinematics"))
        set_(self, "cameras", _entries(self.cameras, CameraResult, "cameras"))
        set_(self, "transforms", _entries(self.transforms, TransformResult, "transforms"))
        set_(self, "points", _entries(self.points, PointResult, "points"))
        set_(self, "targets", _entries(self.targets, TargetResult, "targets"))
        if not isinstance(self.stats, Mapping):
            raise field_fail("stats", f"expected a mapping, got {short_repr(self.stats)}")
        stats = {}
        for key, value in self.stats.items():
            check = _STAT_CHECKS.get(key)
            stats[key] = (
                check(value, f"stats.{key}") if check else field_json(value, f"stats.{key}")
            )
        set_(self, "stats", stats)
        if self.provenance is not None and not isinstance(self.provenance, Provenance):
            raise field_fail(
                "provenance", f"expected a Provenance or None, got {type(self.provenance).__name__}"
            )
        extra = field_json(dict(self.extra), "extra")
        clash = sorted(set(extra) & set(_TOP_KEYS))
        if clash:
            raise field_fail("extra", f"keys {clash} are fields of the result, not extra keys")
        set_(self, "extra", extra)

    # ------------------------------------------------------------------ queries

    def camera(self, name: str) -> CameraResult:
        """The camera ``name``; :class:`BadInputError` listing the cameras if absent."""
        if name not in self.cameras:
            raise BadInputError(
                f"camera: no camera {name!r} in the result; it has: {', '.join(self.cameras) or 'none'}"
            )
        return self.cameras[name]

    def transform(self, name: str) -> TransformResult:
        """The transform ``name`` (e.g. ``"T_flange_needle"``); :class:`BadInputError` if absent."""
        if name not in self.transforms:
            raise BadInputError(
                f"transform: no transform {name!r} in the result; it has: "
                f"{', '.join(self.transforms) or 'none'}"
            )
        return self.transforms[name]

    def frames_under(self, parent: str) -> list[str]:
        """Names ``x`` with a transform ``T_<parent>_x``, sorted (e.g. ``frames_under("flange")``
        lists the tools and eye-in-hand cameras)."""
        prefix = f"T_{parent}_"
        return sorted(
            n[len(prefix) :]
            for n in self.transforms
            if n.startswith(prefix) and len(n) > len(prefix)
        )

    def transform_between(self, a: str, b: str) -> np.ndarray:
        """``T_a_b`` (4x4, m) from ``T_a_b``, the inverse of ``T_b_a``, or ``T_x_a^-1 T_x_b`` for
        a frame ``x`` holding both (the first such ``x`` in sorted order).

        Raises:
            BadInputError: no such transform can be formed from the result.
        """
        direct, inverse = f"T_{a}_{b}", f"T_{b}_{a}"
        if direct in self.transforms:
            return np.array(self.transforms[direct].matrix)
        if inverse in self.transforms:
            return _invert(self.transforms[inverse].matrix)
        suffix_a, suffix_b = f"_{a}", f"_{b}"
        parents_a = {
            n[2 : -len(suffix_a)]
            for n in self.transforms
            if n.startswith("T_") and n.endswith(suffix_a)
        }
        parents_b = {
            n[2 : -len(suffix_b)]
            for n in self.transforms
            if n.startswith("T_") and n.endswith(suffix_b)
        }
        common = sorted(p for p in parents_a & parents_b if p)
        if not common:
            raise BadInputError(
                f"transform_between: cannot form T_{a}_{b}: the result has neither {direct}, {inverse} "
                f"nor two transforms T_x_{a} and T_x_{b} from one frame x; it has: "
                f"{', '.join(self.transforms) or 'none'}"
            )
        x = common[0]
        return _invert(self.transforms[f"T_{x}_{a}"].matrix) @ self.transforms[f"T_{x}_{b}"].matrix

    # ------------------------------------------------------------------ (de)serialisation

    def to_dict(self) -> dict[str, Any]:
        """A plain JSON-ready dict (``schema`` first) that :meth:`from_dict` reads back exactly."""
        out: dict[str, Any] = {
            "schema": SCHEMA,
            "cameras": {n: c.to_dict() for n, c in self.cameras.items()},
            "transforms": {n: t.to_dict() for n, t in self.transforms.items()},
            "points": {n: p.to_dict() for n, p in self.points.items()},
        }
        if self.targets:
            out["targets"] = {n: t.to_dict() for n, t in self.targets.items()}
        if self.kinematics:
            out["kinematics"] = {n: k.to_dict() for n, k in self.kinematics.items()}
        out["stats"] = dict(self.stats)
        if self.provenance is not None:
            out["provenance"] = self.provenance.to_dict()
        out.update(self.extra)
        return out

    @classmethod
    def from_dict(cls, data: Any, source: str = "<dict>") -> ResultFile:
        """Validate a result given as a dict (e.g. parsed JSON).

        Raises:
            BadInputError: naming ``source`` and the key path, e.g.
                ``"result.json: cameras.cam0.K: expected shape (3, 3), got shape (2, 3)"``.
        """
        try:
            return cls._from_dict(data)
        except FieldError as err:
            raise BadInputError(f"{source}: {err}") from None

    @classmethod
    def _from_dict(cls, data: Any) -> ResultFile:
        if not isinstance(data, Mapping):
            raise field_fail(
                "", f'a result must be a JSON object with "schema": "{SCHEMA}", got {short_repr(data)}'
            )
        schema = data.get("schema")
        if schema != SCHEMA:
            raise field_fail("schema", f"expected {SCHEMA!r}, got {schema!r}")

        def section(key: str, entry_cls: type) -> dict[str, Any]:
            value = data.get(key, {})
            if not isinstance(value, Mapping):
                raise field_fail(key, f"expected a mapping of name -> entry, got {short_repr(value)}")
            out = {}
            for name, entry in value.items():
                field_name(name, f"{key} (a key)")
                try:
                    out[name] = entry_cls.from_dict(entry)
                except FieldError as err:
                    raise err.under(f"{key}.{name}") from None
            return out

        cameras = section("cameras", CameraResult)
        transforms = section("transforms", TransformResult)
        points = section("points", PointResult)
        targets = section("targets", TargetResult)
        kinematics = section("kinematics", KinematicsResult)
        provenance = None
        if data.get("provenance") is not None:
            try:
                provenance = Provenance.from_dict(data["provenance"])
            except FieldError as err:
                raise err.under("provenance") from None
        return cls(
            cameras=cameras,
            transforms=transforms,
            points=points,
            targets=targets,
            kinematics=kinematics,
            stats=data.get("stats", {}),
            provenance=provenance,
            extra={k: v for k, v in data.items() if k not in _TOP_KEYS},
        )

    def to_json(self) -> str:
        """The file's text: indented JSON, number arrays one row per line, exact float round trip."""
        return _dump(self.to_dict(), 0) + "\n"

    def save(self, path: str | os.PathLike) -> Path:
        """Write the result to ``path`` atomically (temporary file, fsync, rename)."""
        return write_text_atomic(path, self.to_json())

    @classmethod
    def load(cls, path: str | os.PathLike) -> ResultFile:
        """Read and validate a result file.

        Raises:
            BadInputError: missing file, invalid JSON (with line and column), NaN/Infinity, or any
                key that fails validation (named with its path).
        """
        from jcalib.io.schema.reading import read_document
        from jcalib.io.schema.result import validate_result_document

        path = Path(path)
        if not path.exists():
            raise BadInputError(
                f"result file '{path}' does not exist (expected a {SCHEMA} JSON file)"
            )
        data = read_document(path, "result file", fmt="json")  # size, UTF-8, depth limits
        if isinstance(data, Mapping):
            validate_result_document(data, str(path))  # names safe for consoles and exports
        return cls.from_dict(data, source=str(path))


def load_result(path: str | os.PathLike | ResultFile) -> ResultFile:
    """A :class:`ResultFile` from a path, or the one given."""
    return path if isinstance(path, ResultFile) else ResultFile.load(path)


def _invert(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _dump(value: Any, indent: int) -> str:
    """JSON like ``json.dumps(indent=2)`` but with lists of numbers on one line."""
    pad, inner = " " * indent, " " * (indent + 2)
    if isinstance(value, dict):
        if not value:
            return "{}"
        items = [f"{inner}{json.dumps(k)}: {_dump(v, indent + 2)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(value, list):
        if all(_is_number(v) for v in value):
            return "[" + ", ".join(json.dumps(v, allow_nan=False) for v in value) + "]"
        items = [f"{inner}{_dump(v, indent + 2)}" for v in value]
        return "[\n" + ",\n".join(items) + "\n" + pad + "]"
    return json.dumps(value, allow_nan=False)
