"""Normalised DLT homographies: exact on noise-free views, as good as OpenCV's refined fit with noise."""

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jcalib.errors import BadInputError
from jcalib.init.homography import (
    estimate_homographies,
    estimate_homography,
    homography_residuals,
    refine_homographies,
)

GRID = np.stack(np.meshgrid(np.arange(9), np.arange(6)), axis=-1).reshape(-1, 2) * 0.025  # m


def _canonical(H):
    H = H / np.linalg.norm(H)
    return H * np.sign(H[2, 2])


def _random_view(rng):
    """(K, R, t, H_true, pixels) for a tilted 9x6 board 0.4-1.2 m in front of the camera."""
    f = rng.uniform(400.0, 2000.0)
    K = np.array(
        [
            [f, rng.uniform(-1.0, 1.0), rng.uniform(300, 500)],
            [0.0, f * rng.uniform(0.95, 1.05), rng.uniform(200, 400)],
            [0.0, 0.0, 1.0],
        ]
    )
    axis = rng.normal(size=3)
    axis[2] *= 0.3
    rvec = axis / np.linalg.norm(axis) * rng.uniform(0.0, 1.0)
    R, _ = cv2.Rodrigues(rvec)
    t = np.array([-0.1, -0.06, rng.uniform(0.4, 1.2)])
    H = K @ np.column_stack([R[:, 0], R[:, 1], t])
    ph = np.column_stack([GRID, np.ones(len(GRID))]) @ H.T
    return K, R, t, H, ph[:, :2] / ph[:, 2:]


@given(st.integers(0, 2**32 - 1))
def test_noise_free_homography_is_exact(seed):
    rng = np.random.default_rng(seed)
    _, _, _, H_true, pixels = _random_view(rng)
    for refine in (False, True):
        H = estimate_homography(GRID, pixels, refine=refine)
        # float64 identity through a normalised 9x9 SVD: exact up to ~1e-12 relative
        np.testing.assert_allclose(H, _canonical(H_true), atol=1e-9, rtol=0)
        assert np.abs(homography_residuals(H, GRID, pixels)).max() < 1e-7  # pixels
        assert H.dtype == np.float64


def test_batched_equals_single_and_ragged():
    rng = np.random.default_rng(1)
    views = [_random_view(rng) for _ in range(4)]
    pixels = np.stack([v[4] for v in views])
    H_batch = estimate_homographies(GRID, pixels)
    assert H_batch.shape == (4, 3, 3)
    H_3d = estimate_homographies(np.column_stack([GRID, np.zeros(len(GRID))]), pixels)
    for i, v in enumerate(views):
        np.testing.assert_allclose(H_batch[i], _canonical(v[3]), atol=1e-9)
    np.testing.assert_allclose(H_3d, H_batch, atol=1e-12)
    # ragged: views seeing different subsets of the board
    subsets = [np.arange(54), np.arange(10, 54), np.arange(0, 40, 2), np.arange(54)]
    H_ragged = estimate_homographies(
        [GRID[s] for s in subsets], [pixels[i][s] for i, s in enumerate(subsets)]
    )
    for i, v in enumerate(views):
        np.testing.assert_allclose(H_ragged[i], _canonical(v[3]), atol=1e-9)


def test_noisy_refinement_matches_opencv():
    """With 0.5 px noise the refined fit reaches OpenCV's LM-refined homography (same objective)."""
    rng = np.random.default_rng(2)
    views = [_random_view(rng) for _ in range(5)]
    noisy = np.stack([v[4] for v in views]) + rng.normal(scale=0.5, size=(5, len(GRID), 2))
    H_dlt = estimate_homographies(GRID, noisy, refine=False)
    H_ref = estimate_homographies(GRID, noisy, refine=True)
    H_again = refine_homographies(H_dlt, GRID, noisy)
    for i in range(5):
        H_cv, _ = cv2.findHomography(GRID, noisy[i], 0)
        rms = lambda H: np.sqrt(np.mean(homography_residuals(H, GRID, noisy[i]) ** 2))  # noqa: E731
        assert rms(H_ref[i]) <= rms(H_dlt[i]) + 1e-12
        # both minimise the same transfer error: equal optimum to well below the noise
        assert rms(H_ref[i]) <= rms(H_cv) * (1 + 1e-6)
        np.testing.assert_allclose(H_again[i], H_ref[i], atol=1e-8)
        # sane: noise 0.5 px, 54 points, 8 dof -> RMS ~ 0.5 * sqrt(1 - 8/108)
        assert 0.3 < rms(H_ref[i]) < 0.7


def test_degenerate_views_name_the_view():
    rng = np.random.default_rng(3)
    pixels = np.stack([_random_view(rng)[4] for _ in range(3)])
    with pytest.raises(BadInputError, match="view 'cam0/s002'.*at least 4 points"):
        estimate_homographies(
            [GRID, GRID, GRID[:3]], [pixels[0], pixels[1], pixels[2][:3]], view_names=["a", "b", "cam0/s002"]
        )
    bad = pixels.copy()
    bad[1, 7, 0] = np.nan
    with pytest.raises(BadInputError, match=r"view 1: pixels contain NaN.*\[7\]"):
        estimate_homographies(GRID, bad)
    row = GRID[:9]  # one row of the board: collinear
    with pytest.raises(BadInputError, match="view 0: the target points are collinear"):
        estimate_homography(row, pixels[0][:9])
    four = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [0.0, 1.0]])  # 3 of 4 collinear
    with pytest.raises(BadInputError, match="view 'v': degenerate point configuration"):
        estimate_homography(four, four * 100.0 + 5.0, view_name="v")
    with pytest.raises(BadInputError, match="z = 0"):
        estimate_homography(np.column_stack([GRID, np.full(len(GRID), 0.01)]), pixels[0])
    with pytest.raises(BadInputError, match="54 target points but 53 pixels"):
        estimate_homography(GRID, pixels[0][:53])
