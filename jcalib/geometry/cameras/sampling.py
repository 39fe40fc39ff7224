"""Random, physically plausible camera models: for simulations, Monte Carlo studies and tests."""

from __future__ import annotations

import numpy as np

from jcalib.geometry.cameras.base import AbstractCameraModel, check_image_size
from jcalib.geometry.cameras.factory import CAMERA_MODELS, camera_model_from_name

# Uniform ranges of the distortion coefficients (OpenCV order), typical of industrial lenses.
_OPENCV_RANGES = (
    (-0.3, 0.1),  # k1
    (-0.02, 0.1),  # k2
    (-2e-3, 2e-3),  # p1
    (-2e-3, 2e-3),  # p2
    (-0.01, 0.01),  # k3
    (-0.1, 0.2),  # k4
    (-0.02, 0.02),  # k5
    (-0.005, 0.005),  # k6
    (-2e-3, 2e-3),  # s1
    (-2e-3, 2e-3),  # s2
    (-2e-3, 2e-3),  # s3
    (-2e-3, 2e-3),  # s4
    (-0.02, 0.02),  # tx (rad)
    (-0.02, 0.02),  # ty (rad)
)
_FISHEYE_RANGES = ((-0.05, 0.05), (-0.02, 0.02), (-5e-3, 5e-3), (-1e-3, 1e-3))


def random_camera(
    name: str,
    rng: np.random.Generator | int,
    image_size: tuple[int, int] = (1280, 960),
    skew: bool = False,
) -> AbstractCameraModel:
    """A camera model with random, plausible intrinsics.

    Perspective models: ``fx`` gives a 45°–95° horizontal field of view, ``fy = fx·(1 ± 3 %)``,
    the principal point within 3 % of the image size from the centre, ``|skew| < 2 px``, and
    distortion coefficients uniform in ranges typical of industrial lenses. Fisheye: ``fx`` for a
    150°–190° field of view across the image width, ``|alpha| < 1e-3``, small ``k1..k4``.
    The draws are not filtered: with a wide field of view and strong barrel distortion (about
    10 % of the draws) the image corners lie beyond the fold and do not unproject (``valid`` False).

    Args:
        name: model name (see :data:`~jcalib.geometry.cameras.factory.CAMERA_MODELS`).
        rng: NumPy generator or seed.
        image_size: ``(width, height)``, pixels.
        skew: give the model a skew parameter.
    """
    rng = np.random.default_rng(rng)
    size = check_image_size(image_size)
    cls = CAMERA_MODELS.get(name)
    width, height = size
    if name == "fisheye":
        half_fov = np.radians(rng.uniform(75.0, 95.0))
        fx = (width / 2.0) / half_fov
        dist = [rng.uniform(lo, hi) for lo, hi in _FISHEYE_RANGES]
        skew_value = rng.uniform(-1e-3, 1e-3)
    else:
        half_fov = np.radians(rng.uniform(22.5, 47.5))
        fx = (width / 2.0) / np.tan(half_fov)
        n = 0 if cls is None else getattr(cls, "num_coeffs", 0)
        dist = [rng.uniform(lo, hi) for lo, hi in _OPENCV_RANGES[:n]]
        skew_value = rng.uniform(-2.0, 2.0)
    fy = fx * rng.uniform(0.97, 1.03)
    cx = (width - 1) / 2.0 + rng.uniform(-0.03, 0.03) * width
    cy = (height - 1) / 2.0 + rng.uniform(-0.03, 0.03) * height
    params = np.array(
        [fx, fy, cx, cy] + ([skew_value] if skew else []) + dist, dtype=np.float64
    )
    return camera_model_from_name(name, size, params, skew=skew)
