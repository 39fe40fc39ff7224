"""Planar PnP (our IPPE, both candidates) and general PnP (SQPnP) against ground truth and OpenCV."""

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jcalib.errors import BadInputError
from jcalib.init.pnp import planar_pnp, planar_pnp_views, solve_pnp

GRID = np.stack(np.meshgrid(np.arange(9), np.arange(6)), axis=-1).reshape(-1, 2) * 0.025  # m
GRID3 = np.column_stack([GRID, np.zeros(len(GRID))])
K = np.array([[900.0, 0.0, 330.0], [0.0, 905.0, 245.0], [0.0, 0.0, 1.0]])


def _rotation_deg(Ra, Rb):
    return np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1.0) / 2.0, -1.0, 1.0)))


def _project(P, R, t, dist=None):
    uv, _ = cv2.projectPoints(P.reshape(-1, 1, 3), cv2.Rodrigues(R)[0], t, K, dist)
    return uv.reshape(-1, 2)


def _random_pose(rng, max_angle=1.0):
    rvec = rng.normal(size=3)
    R, _ = cv2.Rodrigues(rvec / np.linalg.norm(rvec) * rng.uniform(0.0, max_angle))
    t = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(0.4, 1.5)]) - R @ np.array(
        [0.1, 0.0625, 0.0]
    )
    return R, t


@given(st.integers(0, 2**32 - 1), st.booleans())
def test_planar_candidates_include_truth(seed, distorted):
    rng = np.random.default_rng(seed)
    R, t = _random_pose(rng)
    dist = np.array([-0.2, 0.08, 0.001, -0.0005, 0.0]) if distorted else None
    pixels = _project(GRID3, R, t, dist)
    res = planar_pnp(GRID, pixels, K, dist)
    assert res.R.shape == (2, 3, 3) and res.t.shape == (2, 3) and res.rms_px.shape == (2,)
    assert res.rms_px[0] <= res.rms_px[1]
    # noise-free: the best candidate is the true pose (float64 closed form; the iterative
    # undistortion of OpenCV converges to ~1e-15 in normalised coordinates)
    np.testing.assert_allclose(res.R[0], R, atol=1e-9)
    np.testing.assert_allclose(res.t[0], t, atol=1e-9)
    assert res.rms_px[0] < 1e-7
    for R_c in res.R:
        np.testing.assert_allclose(R_c @ R_c.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R_c) > 0


def test_same_candidates_as_opencv_ippe():
    rng = np.random.default_rng(1)
    dist = np.array([-0.1, 0.02, 0.0, 0.0, 0.0])
    for _ in range(5):
        R, t = _random_pose(rng)
        pixels = _project(GRID3, R, t, dist) + rng.normal(scale=0.3, size=(len(GRID), 2))
        ours = planar_pnp(GRID, pixels, K, dist)
        n, rvecs, tvecs, errs = cv2.solvePnPGeneric(GRID3, pixels, K, dist, flags=cv2.SOLVEPNP_IPPE)
        assert n == 2
        for i in range(2):  # OpenCV sorts by reprojection error too
            # both are IPPE on a homography fit of the same points: equal up to the fit's details
            assert _rotation_deg(cv2.Rodrigues(rvecs[i])[0], ours.R[i]) < 0.05
            np.testing.assert_allclose(tvecs[i].ravel(), ours.t[i], atol=1e-3 * np.linalg.norm(t))
            assert abs(errs[i, 0] - ours.rms_px[i]) < 0.01


def test_far_fronto_parallel_view_returns_both_poses():
    """A small, far, nearly fronto-parallel board: two poses explain the pixels about equally well."""
    rng = np.random.default_rng(2)
    R, _ = cv2.Rodrigues(np.array([0.05, -0.04, 0.3]))
    t = np.array([0.35, 0.25, 4.0])  # 4 m away, off-centre: the board spans ~50 px
    pixels = _project(GRID3, R, t) + rng.normal(scale=0.2, size=(len(GRID), 2))
    res = planar_pnp(GRID, pixels, K, refine=True)
    flip = _rotation_deg(res.R[0], res.R[1])
    assert flip > 5.0  # two distinct poses, tilted opposite ways
    assert res.ambiguity_ratio < 1.5  # both fit the pixels about equally well
    assert res.rms_px[1] < 0.5  # the second candidate is plausible given 0.2 px noise
    assert min(_rotation_deg(R_c, R) for R_c in res.R) < 0.6 * flip  # truth near one of them
    # the two candidates mirror each other about the line of sight: their normals differ,
    # their board centres almost coincide
    centre = np.array([0.1, 0.0625, 0.0])
    c0, c1 = (res.R[i] @ centre + res.t[i] for i in range(2))
    assert np.linalg.norm(c0 - c1) < 0.02 * np.linalg.norm(c0)


def test_refinement_lowers_error():
    rng = np.random.default_rng(3)
    R, t = _random_pose(rng)
    pixels = _project(GRID3, R, t) + rng.normal(scale=0.5, size=(len(GRID), 2))
    raw = planar_pnp(GRID, pixels, K)
    ref = planar_pnp(GRID, pixels, K, refine=True)
    assert ref.rms_px[0] <= raw.rms_px[0] + 1e-12
    rvec, tvec = cv2.solvePnPRefineLM(GRID3, pixels, K, None, cv2.Rodrigues(raw.R[0])[0], raw.t[0].copy())
    rms_cv = np.sqrt(np.mean((_project(GRID3, cv2.Rodrigues(rvec)[0], tvec.ravel()) - pixels) ** 2))
    assert ref.rms_px[0] < rms_cv + 1e-3  # same minimum as OpenCV's LM (ours in normalised coordinates)


def test_views_helper_matches_single_calls():
    rng = np.random.default_rng(4)
    poses = [_random_pose(rng) for _ in range(3)]
    pixels = np.stack([_project(GRID3, R, t) for R, t in poses])
    batch = planar_pnp_views(GRID, pixels, K)
    assert batch.R.shape == (3, 2, 3, 3) and batch.T_cam_target.shape == (3, 2, 4, 4)
    for i, (R, t) in enumerate(poses):
        single = planar_pnp(GRID, pixels[i], K)
        np.testing.assert_allclose(batch.R[i], single.R, atol=1e-12)
        np.testing.assert_allclose(batch.T_cam_target[i, 0, :3, 3], t, atol=1e-9)
    ragged = planar_pnp_views([GRID, GRID[5:]], [pixels[0], pixels[1][5:]], K)
    np.testing.assert_allclose(ragged.R[1, 0], poses[1][0], atol=1e-9)


def test_general_pnp_non_planar():
    rng = np.random.default_rng(5)
    P = rng.uniform([-0.2, -0.2, -0.1], [0.2, 0.2, 0.1], size=(30, 3))
    dist = np.array([-0.15, 0.05, 0.0, 0.0, 0.0])
    for _ in range(3):
        R, t = _random_pose(rng)
        t = t + np.array([0.0, 0.0, 0.5])
        res = solve_pnp(P, _project(P, R, t, dist), K, dist)
        np.testing.assert_allclose(res.R, R, atol=1e-9)
        np.testing.assert_allclose(res.t, t, atol=1e-9)
        assert res.rms_px < 1e-7 and res.T_cam_target.shape == (4, 4)


def test_bad_input():
    R, t = _random_pose(np.random.default_rng(6))
    pixels = _project(GRID3, R, t)
    with pytest.raises(BadInputError, match="view 's3'.*at least 4 points"):
        planar_pnp(GRID[:3], pixels[:3], K, view_name="s3")
    bad = pixels.copy()
    bad[2] = np.nan
    with pytest.raises(BadInputError, match="NaN"):
        planar_pnp(GRID, bad, K)
    with pytest.raises(BadInputError, match="view '1'.*collinear"):
        planar_pnp_views([GRID, GRID[:9]], [pixels, pixels[:9]], K)
    with pytest.raises(BadInputError, match="dist: expected an OpenCV distortion vector"):
        planar_pnp(GRID, pixels, K, [0.1, 0.2, 0.3])
    with pytest.raises(BadInputError, match="K: expected"):
        planar_pnp(GRID, pixels, np.eye(2))
    with pytest.raises(BadInputError, match="at least 3 points"):
        solve_pnp(GRID3[:2], pixels[:2], K)
