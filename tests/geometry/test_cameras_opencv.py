"""Camera models against OpenCV: ``project`` vs ``cv2.projectPoints`` / ``cv2.fisheye.projectPoints``
and ``unproject`` vs ``cv2.undistortPointsIter`` / ``cv2.fisheye.undistortPoints``.

OpenCV is the independent reference: jcalib's models must mean exactly what OpenCV's parameters
mean. Each model variant is jit-compiled once (same shapes for every example).
"""

from __future__ import annotations

import cv2
import equinox as eqx
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jcalib.geometry.cameras import AbstractCameraModel
from jcalib.geometry.cameras.sampling import random_camera

MODELS = ("pinhole", "opencv4", "opencv5", "opencv8", "opencv12", "opencv14", "fisheye")
VARIANTS = [(name, skew) for name in MODELS for skew in (False, True)]
IDS = [f"{name}{'-skew' if skew else ''}" for name, skew in VARIANTS]
IMAGE_SIZE = (1280, 960)
NUM_POINTS = 200
ZERO3 = np.zeros(3)

seeds = st.integers(min_value=0, max_value=2**32 - 1)


@eqx.filter_jit
def _project(model: AbstractCameraModel, p):
    return model.project_valid(p)


@eqx.filter_jit
def _unproject(model: AbstractCameraModel, px):
    return model.unproject_valid(px)


def _points(
    model: AbstractCameraModel, rng: np.random.Generator, in_front_only: bool
) -> np.ndarray:
    """Points (NUM_POINTS, 3) in metres spread over and beyond the field of view."""
    if model.name == "fisheye":
        # cv2.fisheye is defined for Z > 0 only (it mirrors Z < 0): angles up to 89°.
        theta = np.radians(rng.uniform(0.0, 89.0, NUM_POINTS))
        phi = rng.uniform(0.0, 2.0 * np.pi, NUM_POINTS)
        dirs = np.stack(
            [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)],
            -1,
        )
        return dirs * rng.uniform(0.2, 10.0, (NUM_POINTS, 1))
    fx = float(model.params[0])
    half = 1.2 * IMAGE_SIZE[0] / 2.0 / fx
    xy = rng.uniform(-half, half, (NUM_POINTS, 2))
    z = rng.uniform(0.2, 10.0, NUM_POINTS)
    if not in_front_only:  # OpenCV projects points behind the camera too (mirrored)
        z = z * np.where(rng.uniform(size=NUM_POINTS) < 0.2, -1.0, 1.0)
    return np.concatenate([xy * z[:, None], z[:, None]], axis=1)


def _cv2_project(model: AbstractCameraModel, p: np.ndarray) -> np.ndarray:
    """OpenCV's projection of ``p`` (N, 3) with the model's (K, dist)."""
    K, dist = model.to_opencv()
    if model.name == "fisheye":
        alpha = K[0, 1] / K[0, 0]
        K0 = K.copy()
        K0[0, 1] = 0.0
        out, _ = cv2.fisheye.projectPoints(p[None], ZERO3, ZERO3, K0, dist, alpha=alpha)
        return out[0]
    if K[0, 1] == 0.0:
        out, _ = cv2.projectPoints(p, ZERO3, ZERO3, K, dist)
        return out[:, 0]
    # cv2.projectPoints ignores K[0][1]: project with K = I (distorted, tilted normalised
    # coordinates), then apply the full K.
    normalised, _ = cv2.projectPoints(p, ZERO3, ZERO3, np.eye(3), dist)
    return normalised[:, 0] @ K[:2, :2].T + K[:2, 2]


def _cv2_unproject(model: AbstractCameraModel, px: np.ndarray):
    """OpenCV's undistortion of pixels: unit rays (N, 3), and where OpenCV converged.

    OpenCV ignores K[0][1] when undistorting: the skew is removed from the pixels first
    (an exact identity: u' = u - K01 (v - cy) / fy). OpenCV "converged" where its answer
    reprojects (with OpenCV) onto the input within 1e-8 px.
    """
    K, dist = model.to_opencv()
    K0 = K.copy()
    K0[0, 1] = 0.0
    px0 = px.copy()
    px0[:, 0] -= K[0, 1] * (px[:, 1] - K[1, 2]) / K[1, 1]
    crit = (cv2.TERM_CRITERIA_COUNT, 1000, 0.0)
    if model.name == "fisheye":
        xy = cv2.fisheye.undistortPoints(px0[:, None, :], K0, dist, criteria=crit)[:, 0]
    else:
        xy = cv2.undistortPointsIter(px0[:, None, :], K0, dist, None, None, crit)[:, 0]
    p = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    rays = p / np.linalg.norm(p, axis=1, keepdims=True)
    if model.name == "fisheye":
        back, _ = cv2.fisheye.projectPoints(p[None], ZERO3, ZERO3, K0, dist)
        back = back[0]
    else:
        back, _ = cv2.projectPoints(p, ZERO3, ZERO3, K0, dist)
        back = back[:, 0]
    ok = np.all(np.isfinite(xy), axis=1) & (np.linalg.norm(back - px0, axis=1) < 1e-8)
    return rays, ok


@pytest.mark.parametrize(("name", "skew"), VARIANTS, ids=IDS)
@given(seed=seeds)
def test_project_matches_opencv(name, skew, seed):
    rng = np.random.default_rng(seed)
    model = random_camera(name, rng, IMAGE_SIZE, skew=skew)
    p = _points(model, rng, in_front_only=False)
    pixels, _ = _project(model, p)
    pixels = np.asarray(pixels)
    assert pixels.dtype == np.float64
    # 1e-9 px: the same float64 formula evaluated in another order (pixels ~1e3, eps ~1e-16).
    np.testing.assert_allclose(pixels, _cv2_project(model, p), rtol=0.0, atol=1e-9)


@pytest.mark.parametrize(("name", "skew"), VARIANTS, ids=IDS)
@given(seed=seeds)
def test_unproject_matches_opencv(name, skew, seed):
    rng = np.random.default_rng(seed)
    model = random_camera(name, rng, IMAGE_SIZE, skew=skew)
    px = np.stack(
        [
            rng.uniform(-0.5, IMAGE_SIZE[0] - 0.5, NUM_POINTS),
            rng.uniform(-0.5, IMAGE_SIZE[1] - 0.5, NUM_POINTS),
        ],
        axis=1,
    )
    rays, valid = (np.asarray(a) for a in _unproject(model, px))
    assert np.all(np.isfinite(rays))
    ref, cv_ok = _cv2_unproject(model, px)
    both = valid & cv_ok
    # The test must not pass vacuously: most of the image is inside every sampled model's
    # valid region and OpenCV's fixed-point iteration converges there.
    assert both.sum() >= NUM_POINTS // 4
    # OpenCV converged to within 1e-8 px, i.e. ~1e-11 rad at f >= 300 px: rays agree to 1e-10.
    np.testing.assert_allclose(rays[both], ref[both], rtol=0.0, atol=1e-10)
    # Where OpenCV found a pre-image inside jcalib's valid region, jcalib must have found it too.
    _, ref_in_region = _project(model, ref)
    assert np.all(valid[cv_ok & np.asarray(ref_in_region)])
