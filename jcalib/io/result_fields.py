"""Field checks of the ``jcalib.result/1`` format (:mod:`jcalib.io.result`): every error names the key,
the value received and what was expected."""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from jcalib.errors import BadInputError

#: A rotation block is accepted when ``max |R^T R - I| <= ORTHONORMAL_TOL`` (a float64 solver
#: output is orthonormal to ~1e-15; a matrix printed to 7 decimals still passes).
ORTHONORMAL_TOL = 1e-6
#: Covariances must be symmetric to this relative tolerance (of their largest diagonal entry) and
#: have no eigenvalue below ``-COV_TOL * largest eigenvalue`` (rounding of a float64 inverse).
COV_TOL = 1e-8


# ----------------------------------------------------------------------------------------------
# Validation helpers: every error names the key, the value received and what was expected.
# ----------------------------------------------------------------------------------------------


class FieldError(BadInputError):
    """A validation error at key path ``key`` ("" = the value itself); prefixes compose."""

    def __init__(self, key: str, msg: str):
        super().__init__(f"{key}: {msg}" if key else msg)
        self.key, self.msg = key, msg

    def under(self, prefix: str) -> FieldError:
        return FieldError(f"{prefix}.{self.key}" if self.key else prefix, self.msg)


def field_fail(where: str, msg: str) -> FieldError:
    return FieldError(where, msg)


def short_repr(value: Any, limit: int = 120) -> str:
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def field_array(
    value: Any, shape: tuple[int, ...] | None, where: str, ndim: int | None = None
) -> np.ndarray:
    """A read-only float64 copy of ``value`` with the given shape, all finite."""
    if isinstance(value, (str, bytes, Mapping)) or isinstance(value, bool):
        raise field_fail(
            where, f"expected a numeric array of shape {shape or ('n',)}, got {short_repr(value)}"
        )
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise field_fail(
            where, f"expected a numeric array of shape {shape or ('n',)}, got {short_repr(value)}"
        ) from None
    if arr.dtype == object:  # pragma: no cover - np.array(dtype=float64) never gives object
        raise field_fail(where, f"expected numbers, got {short_repr(value)}")
    if shape is not None and arr.shape != shape:
        raise field_fail(where, f"expected shape {shape}, got shape {arr.shape}: {short_repr(value)}")
    if ndim is not None and arr.ndim != ndim:
        raise field_fail(where, f"expected a {ndim}-d array, got shape {arr.shape}: {short_repr(value)}")
    if not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise field_fail(where, f"expected finite numbers, got {arr[bad]} at index {list(bad)}")
    arr.setflags(write=False)
    return arr


def field_float(value: Any, where: str, minimum: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise field_fail(where, f"expected a number, got {short_repr(value)}")
    x = float(value)
    if not math.isfinite(x):
        raise field_fail(where, f"expected a finite number, got {x} (NaN or infinity)")
    if minimum is not None and x < minimum:
        raise field_fail(where, f"expected a number >= {minimum:g}, got {x}")
    return x


def field_count(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        if isinstance(value, (float, np.floating)) and float(value).is_integer() and value >= 0:
            return int(value)
        raise field_fail(where, f"expected a non-negative integer, got {short_repr(value)}")
    if value < 0:
        raise field_fail(where, f"expected a non-negative integer, got {value}")
    return int(value)


def field_name(value: Any, where: str) -> str:
    from jcalib.io.schema.base import check_name

    if not isinstance(value, str) or not value or value != value.strip():
        raise field_fail(
            where, f"expected a non-empty name without surrounding spaces, got {short_repr(value)}"
        )
    try:
        return check_name(value)
    except ValueError as err:
        raise field_fail(where, str(err)) from None


def field_json(value: Any, where: str) -> Any:
    """A deep copy of a JSON value (dict with str keys, list, str, finite number, bool, None)."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return field_float(value, where)
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "iu" or (value.dtype.kind == "f" and np.all(np.isfinite(value))):
            return value.tolist()  # numbers, all finite: nothing to check one by one
        return field_json(value.tolist(), where)
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise field_fail(where, f"expected string keys, got {short_repr(k)}")
            out[k] = field_json(v, f"{where}.{k}")
        return out
    if isinstance(value, (list, tuple)):
        if set(map(type, value)) <= {float} and all(map(math.isfinite, value)):
            return list(value)  # the common leaf: finite floats
        if value and set(map(type, value)) <= {list, tuple}:  # rows of finite floats (matrices)
            flat = list(itertools.chain.from_iterable(value))
            if set(map(type, flat)) <= {float} and all(map(math.isfinite, flat)):
                return [list(row) for row in value]
        return [field_json(v, f"{where}[{i}]") for i, v in enumerate(value)]
    raise field_fail(
        where, f"expected a JSON value (number, string, bool, list, mapping), got {short_repr(value)}"
    )


def field_covariance(value: Any, n: int, where: str) -> np.ndarray:
    cov = field_array(value, (n, n), where)
    scale = float(np.max(np.abs(np.diag(cov)))) if n else 0.0
    asym = float(np.max(np.abs(cov - cov.T))) if n else 0.0
    if asym > COV_TOL * scale:
        raise field_fail(where, f"expected a symmetric matrix, got max |C - C^T| = {asym:.3g}")
    if n and np.min(np.diag(cov)) < 0.0:
        raise field_fail(
            where, f"expected non-negative variances on the diagonal, got {np.diag(cov).tolist()}"
        )
    if n:
        eig = np.linalg.eigvalsh(0.5 * (cov + cov.T))
        if eig[0] < -COV_TOL * max(float(eig[-1]), 0.0) or (eig[-1] <= 0.0 and eig[0] < 0.0):
            raise field_fail(
                where,
                f"expected a positive semi-definite matrix, got smallest eigenvalue {eig[0]:.3g} "
                f"(largest {eig[-1]:.3g})",
            )
    return cov


def field_transform(value: Any, where: str) -> np.ndarray:
    T = field_array(value, (4, 4), where)
    if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise field_fail(where, f"expected the last row [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    with np.errstate(over="ignore", invalid="ignore"):  # huge finite entries: err = inf, refused below
        err = float(np.max(np.abs(R.T @ R - np.eye(3))))
        det = float(np.linalg.det(R))
    if not err <= ORTHONORMAL_TOL or not det > 0.0:
        raise field_fail(
            where,
            f"expected a proper rotation in the 3x3 block (orthonormal, det +1), got "
            f"max|R^T R - I| = {err:.3g} (tolerance {ORTHONORMAL_TOL:g}) and det = {det:.6g}",
        )
    return T


def check_entry_keys(entry: Any, required: tuple[str, ...]) -> None:
    if not isinstance(entry, Mapping):
        raise field_fail("", f"expected a mapping, got {short_repr(entry)}")
    for key in required:
        if key not in entry:
            raise field_fail(key, f"missing (the entry has: {', '.join(map(str, entry)) or 'no keys'})")


def extra_keys(entry: Mapping, known: tuple[str, ...]) -> dict[str, Any]:
    return {k: field_json(v, k) for k, v in entry.items() if k not in known}


def float_list(arr: np.ndarray) -> Any:
    return np.asarray(arr, dtype=np.float64).tolist()
