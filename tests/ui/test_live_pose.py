"""The live page's board pose (distance and tilt shown while aiming a camera) against a pose it did not make."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from jcalib.ui.live import board_pose


@pytest.mark.parametrize("dist", [np.zeros(5), np.array([-0.21, 0.09, 0.001, -0.0005, -0.02])])
def test_board_pose_recovers_a_projected_board(dist):
    rng = np.random.default_rng(4)
    cols, rows, square = 9, 6, 0.025
    grid = np.stack(np.meshgrid(np.arange(cols), np.arange(rows)), -1).reshape(-1, 2) * square
    obj = np.column_stack([grid, np.zeros(len(grid))])
    K = np.array([[820.0, 0.0, 318.0], [0.0, 815.0, 244.0], [0.0, 0.0, 1.0]])
    tilt_deg = 35.0
    axis = np.array([np.cos(0.7), np.sin(0.7), 0.0])
    rvec = axis * np.radians(tilt_deg)
    tvec = np.array([-0.08, -0.05, 0.62])
    pixels = cv2.projectPoints(obj, rvec, tvec, K, dist)[0].reshape(-1, 2) + 0.05 * rng.standard_normal((len(obj), 2))
    pose = board_pose(obj, pixels, K, dist)
    assert pose is not None
    assert abs(pose["distance_m"] - np.linalg.norm(tvec)) < 2e-3
    assert abs(pose["tilt_deg"] - tilt_deg) < 0.5
    np.testing.assert_allclose(pose["t_m"], tvec, atol=3e-3)
    assert pose["rms_px"] < 0.1
    assert board_pose(obj[:3], pixels[:3], K, dist) is None  # too few points: no pose, no error
