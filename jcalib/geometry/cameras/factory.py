"""Build camera models from OpenCV's ``(K, dist)`` or from a model name and a parameter vector."""

from __future__ import annotations

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.cameras.base import (
    AbstractCameraModel,
    check_image_size,
    is_concrete,
)
from jcalib.geometry.cameras.fisheye import Fisheye
from jcalib.geometry.cameras.opencv import OpenCV4, OpenCV5, OpenCV8, OpenCV12, OpenCV14
from jcalib.geometry.cameras.pinhole import Pinhole
from jcalib.geometry.cameras.splined import SPLINED_DIST_NAMES, SplinedStereographic, fov_covering

#: Model classes by name (the ``model`` key of the cell spec and result files).
CAMERA_MODELS: dict[str, type[AbstractCameraModel]] = {
    cls.name: cls
    for cls in (Pinhole, OpenCV4, OpenCV5, OpenCV8, OpenCV12, OpenCV14, Fisheye, SplinedStereographic)
}

#: OpenCV ``dist`` lengths and the perspective model each one selects.
_BY_DIST_LENGTH = {
    0: Pinhole,
    4: OpenCV4,
    5: OpenCV5,
    8: OpenCV8,
    12: OpenCV12,
    14: OpenCV14,
}


def _check_K(K) -> np.ndarray:
    try:
        K = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise BadInputError(
            f"K must be a 3x3 array of numbers; got {K!r} ({err})"
        ) from None
    if K.shape != (3, 3):
        raise BadInputError(f"K must have shape (3, 3), got shape {K.shape}")
    if not np.all(np.isfinite(K)):
        raise BadInputError(f"K must be finite, got {K.tolist()}")
    if K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0 or K[2, 2] != 1.0:
        raise BadInputError(
            "K must be upper-triangular with K[2][2] = 1 ([[fx, skew, cx], [0, fy, cy], [0, 0, 1]]); "
            f"got {K.tolist()}"
        )
    if K[0, 0] <= 0.0 or K[1, 1] <= 0.0:
        raise BadInputError(
            f"K must have positive focal lengths fx = K[0][0], fy = K[1][1]; got fx = {K[0, 0]}, "
            f"fy = {K[1, 1]}"
        )
    return K


def _check_dist(dist) -> np.ndarray:
    if dist is None:
        return np.zeros(0, dtype=np.float64)
    try:
        d = np.asarray(dist, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise BadInputError(
            f"dist must be a vector of numbers; got {dist!r} ({err})"
        ) from None
    # OpenCV hands out (1, n) and (n, 1) arrays as often as (n,).
    if d.ndim > 2 or (d.ndim == 2 and 1 not in d.shape):
        raise BadInputError(
            f"dist must be a vector (n,), (1, n) or (n, 1); got shape {d.shape}"
        )
    d = d.reshape(-1)
    if not np.all(np.isfinite(d)):
        raise BadInputError(f"dist must be finite, got {d.tolist()}")
    return d


def camera_from_opencv(
    K, dist, image_size, fisheye: bool = False
) -> AbstractCameraModel:
    """The camera model that reproduces OpenCV's ``(K, dist)`` exactly.

    The model is picked by the length of ``dist``: 0 (or None) → ``pinhole``, 4, 5, 8, 12, 14 →
    ``opencv4`` … ``opencv14``; with ``fisheye=True`` ``dist`` is cv2.fisheye's ``D`` (4 values)
    and the model is ``fisheye``. A ``dist`` of a result file's ``splined`` camera (``fov_x_deg`` and
    the spline values, :data:`~jcalib.geometry.cameras.splined.SPLINED_DIST_NAMES`) gives that model.
    A nonzero ``K[0][1]`` gives a model with a skew parameter
    (``skew = K[0][1]`` in pixels; fisheye: ``alpha = K[0][1] / fx``).

    Args:
        K: ``(3, 3)`` camera matrix, pixels; upper-triangular, ``K[2][2] = 1``, ``fx, fy > 0``.
        dist: distortion coefficients in OpenCV's order, shape ``(n,)``, ``(1, n)`` or ``(n, 1)``.
        image_size: ``(width, height)``, pixels.
        fisheye: interpret ``dist`` as cv2.fisheye's ``D``.

    Raises:
        BadInputError: malformed ``K``, ``dist`` (length not allowed, non-finite) or image size.
    """
    size = check_image_size(image_size)
    K = _check_K(K)
    d = _check_dist(dist)
    focal, pp = (K[0, 0], K[1, 1]), (K[0, 2], K[1, 2])
    has_skew = K[0, 1] != 0.0
    if fisheye:
        if d.size != 4:
            raise BadInputError(
                f"dist for a fisheye camera must have 4 coefficients (k1, k2, k3, k4); got "
                f"{d.size}: {d.tolist()}"
            )
        alpha = K[0, 1] / K[0, 0] if has_skew else None
        return Fisheye(size, focal, pp, d, alpha=alpha)
    if d.size == len(SPLINED_DIST_NAMES):
        if has_skew:
            raise BadInputError("a splined camera has no skew: K[0][1] must be 0")
        return SplinedStereographic.from_params(size, np.concatenate([[focal[0], focal[1], pp[0], pp[1]], d]))
    cls = _BY_DIST_LENGTH.get(d.size)
    if cls is None:
        raise BadInputError(
            f"dist has {d.size} coefficients; OpenCV's models have 0, 4, 5, 8, 12 or 14 "
            f"(for a fisheye pass fisheye=True with 4)"
        )
    return cls(
        size,
        focal,
        pp,
        distortion=d if d.size else None,
        skew=K[0, 1] if has_skew else None,
    )


def camera_model_from_name(name: str, image_size, params=None, skew: bool = False):
    """A camera model by name, from a flat parameter vector or with default values.

    Args:
        name: ``pinhole``, ``opencv4``, ``opencv5``, ``opencv8``, ``opencv12``, ``opencv14``,
            ``fisheye`` or ``splined``.
        image_size: ``(width, height)``, pixels.
        params: shape ``(n,)`` in the order of the model's ``param_names`` (may be traced; values
            are checked only when concrete), or None for defaults: ``fx = fy = max(width,
            height)`` (about 53° horizontal field of view for a landscape sensor), the principal
            point at the image centre ``((width - 1)/2, (height - 1)/2)``, zero skew and
            distortion.
        skew: whether the model has a skew parameter (``skew``; fisheye ``alpha``).

    Raises:
        BadInputError: unknown name, bad image size, ``params`` of the wrong length or with
            non-finite values or non-positive focal lengths.
    """
    cls = CAMERA_MODELS.get(name) if isinstance(name, str) else None
    if cls is None:
        raise BadInputError(
            f"unknown camera model {name!r}; expected one of {', '.join(CAMERA_MODELS)}"
        )
    size = check_image_size(image_size)
    if params is None:
        f = float(max(size))
        core = [f, f, (size[0] - 1) / 2.0, (size[1] - 1) / 2.0]
        if cls is SplinedStereographic:
            spline = [fov_covering(core[:2], core[2:], size)] + [0.0] * (len(SPLINED_DIST_NAMES) - 1)
            params = np.concatenate([core, spline])
        else:
            n_dist = 4 if cls is Fisheye else cls.num_coeffs
            params = np.concatenate([core, [0.0] * int(skew), [0.0] * n_dist])
    model = cls.from_params(size, params, skew=bool(skew))
    if is_concrete(params):
        values = np.asarray(model.params)
        if not np.all(np.isfinite(values)):
            raise BadInputError(
                f"params for model {name!r} must be finite, got {values.tolist()}"
            )
        if values[0] <= 0.0 or values[1] <= 0.0:
            raise BadInputError(
                f"params for model {name!r} must have positive fx, fy; got fx = {values[0]}, "
                f"fy = {values[1]}"
            )
    return model
