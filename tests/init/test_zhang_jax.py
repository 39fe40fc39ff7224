"""Zhang's closed form inside the jit: same answer as the numpy closed form, padding-blind, flags bad data."""

import functools
from unittest import mock

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jcalib.geometry import conversions
from jcalib.init import zhang as zhang_module
from jcalib.init.zhang import zhang_init
from jcalib.init.zhang_jax import zhang_start

from .test_zhang import GRID, _camera, _views

SIZE = (640, 480)


@functools.cache
def _start(skew=False, aspect_ratio=None, principal_point=None):
    return jax.jit(functools.partial(zhang_start, image_size=SIZE, skew=skew, aspect_ratio=aspect_ratio,
                                     principal_point=principal_point))


def _padded(pixels, views=16, corners=56):
    """(V, 54, 2) views -> the camera problem's padded (views, corners) layout and weights."""
    V, n = pixels.shape[:2]
    P, U, W = np.zeros((views, corners, 2)), np.zeros((views, corners, 2)), np.zeros((views, corners))
    P[:V, :n], U[:V, :n], W[:V, :n] = GRID, pixels, 1.0
    return P, U, W


@settings(max_examples=20)
@given(st.integers(0, 2**32 - 1), st.booleans(), st.integers(3, 12))
def test_noise_free_recovers_K_and_poses(seed, skew, num_views):
    rng = np.random.default_rng(seed)
    K = _camera(rng, skew=rng.uniform(-2.0, 2.0) if skew else 0.0)
    R, t, pixels = _views(rng, K, num_views)
    K_est, pose, ok, spread = _start(skew)(*_padded(pixels))
    assert bool(ok)
    # noiseless data: exact up to float64 rounding (1e-6 relative, STYLE.md)
    np.testing.assert_allclose(np.asarray(K_est), K, rtol=1e-6, atol=1e-6 * K[0, 0])
    T = conversions.pose_to_matrix(np.asarray(pose[:num_views]))
    np.testing.assert_allclose(T[:, :3, :3], R, atol=1e-8)
    np.testing.assert_allclose(T[:, :3, 3], t, atol=1e-8)
    assert float(spread) < 1e-6  # no noise, no spread
    assert np.all(np.isfinite(np.asarray(pose)))  # padded views too


@settings(max_examples=10)
@given(st.integers(0, 2**32 - 1))
def test_noisy_views_match_the_numpy_closed_form(seed):
    """The homogeneous (numpy) and h33 = 1 (JAX) DLTs differ by O(noise²): K within 1e-3 relative."""
    rng = np.random.default_rng(seed)
    K = _camera(rng)
    _, _, pixels = _views(rng, K, 10, noise_px=0.3)
    # all 16 Monte-Carlo draws of the numpy check (its 4-draw screening value is too noisy to compare)
    with mock.patch.object(zhang_module, "_MC_SCREEN_DRAWS", 16):
        z = zhang_init(GRID, pixels, image_size=SIZE, estimate_distortion=False, refine_homographies=False)
    K_est, pose, ok, spread = _start()(*_padded(pixels))
    assert bool(ok)
    np.testing.assert_allclose(np.asarray(K_est), z.K, rtol=1e-3, atol=1e-3)
    T = conversions.pose_to_matrix(np.asarray(pose[:10]))
    np.testing.assert_allclose(T[:, :3, 3], z.t, rtol=1e-2, atol=1e-4)
    # first-order spread vs the numpy Monte-Carlo spread (16 draws: ~18 % sampling error)
    assert 0.4 < float(spread) / z.focal_rel_std < 2.5


def test_padding_and_dropped_corners_do_not_change_the_answer():
    rng = np.random.default_rng(3)
    K = _camera(rng)
    _, _, pixels = _views(rng, K, 8, noise_px=0.2)
    drop = list(range(10, 20))
    P, U, W = _padded(pixels, views=16, corners=64)
    W[2, drop] = 0.0  # view 2 lost ten corners
    U[2, drop] = 1e6  # whatever a dropped corner holds must not matter
    K_a, pose_a, ok_a, _ = _start()(P, U, W)
    # the same data without padding slots
    P2, U2, W2 = _padded(pixels, views=8, corners=54)
    W2[2, drop] = 0.0
    K_b, pose_b, ok_b, _ = _start()(P2, U2, W2)
    assert bool(ok_a) and bool(ok_b)
    np.testing.assert_allclose(np.asarray(K_a), np.asarray(K_b), rtol=1e-10)
    np.testing.assert_allclose(np.asarray(pose_a[:8]), np.asarray(pose_b), atol=1e-10)
    ref = zhang_init([GRID, GRID, np.delete(GRID, drop, axis=0)] + [GRID] * 5,
                     [pixels[0], pixels[1], np.delete(pixels[2], drop, axis=0), *pixels[3:]],
                     image_size=SIZE, estimate_distortion=False, refine_homographies=False)
    np.testing.assert_allclose(np.asarray(K_a), ref.K, rtol=1e-3)


@pytest.mark.parametrize("case", ["fronto", "one_axis_tilt_small", "collinear", "two_views_with_skew"])
def test_bad_data_is_flagged_for_the_numpy_path(case):
    rng = np.random.default_rng(5)
    K = _camera(rng)
    tilt = (0.0, 0.0) if case == "fronto" else (0.5, 1.0) if case == "one_axis_tilt_small" else (20.0, 40.0)
    _, _, pixels = _views(rng, K, 2 if case == "two_views_with_skew" else 8, tilt_deg=tilt, noise_px=0.2)
    P, U, W = _padded(pixels)
    if case == "collinear":
        W[3] = 0.0
        W[3, :9] = 1.0  # one view keeps only the first row of the board
    _, _, ok, _ = _start(skew=case == "two_views_with_skew")(P, U, W)
    assert not bool(ok)


def test_fixed_aspect_and_principal_point():
    rng = np.random.default_rng(11)
    K = _camera(rng, pp=((SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2))
    K[1, 1] = K[0, 0]
    _, _, pixels = _views(rng, K, 6)
    K_est, _, ok, _ = _start(aspect_ratio=1.0, principal_point=((SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2))(
        *_padded(pixels))
    assert bool(ok)
    np.testing.assert_allclose(np.asarray(K_est), K, rtol=1e-6)
