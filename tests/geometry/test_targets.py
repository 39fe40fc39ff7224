"""Target geometry against OpenCV's own board objects and the conventions of its samples."""

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jcalib.errors import BadInputError
from jcalib.geometry.targets import Charuco, Checkerboard, CircleGrid, target_from_spec

# OpenCV stores board geometry as float32: agreement to float32 resolution of ~0.5 m coordinates.
F32_TOL = 1e-7


def _cv_charuco(t: Charuco) -> cv2.aruco.CharucoBoard:
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, t.dictionary))
    b = cv2.aruco.CharucoBoard((t.squares_x, t.squares_y), t.square, t.marker, d)
    b.setLegacyPattern(t.legacy)
    return b


@given(
    sx=st.integers(3, 12),
    sy=st.integers(3, 12),
    square=st.floats(0.005, 0.1),
    ratio=st.floats(0.3, 0.9),
    legacy=st.booleans(),
)
def test_charuco_matches_opencv_board(sx, sy, square, ratio, legacy):
    t = Charuco(sx, sy, square, ratio * square, "DICT_6X6_250", legacy)
    b = _cv_charuco(t)
    np.testing.assert_allclose(t.points, b.getChessboardCorners(), atol=F32_TOL * 10)
    np.testing.assert_allclose(t.marker_corners, np.array(b.getObjPoints()), atol=F32_TOL * 10)
    np.testing.assert_array_equal(t.marker_ids, b.getIds().ravel())
    assert t.points.dtype == np.float64 and t.points.shape == (t.num_points, 3)
    np.testing.assert_array_equal(t.ids, np.arange(t.num_points))


def test_checkerboard_is_opencv_chessboard_grid():
    # OpenCV's chessboard corners of a (cols+1)x(rows+1)-square board, shifted so the first is the origin.
    t = Checkerboard(9, 6, 0.03)
    b = _cv_charuco(Charuco(10, 7, 0.03, 0.02))
    np.testing.assert_allclose(t.points, b.getChessboardCorners() - [0.03, 0.03, 0.0], atol=1e-8)
    # OpenCV's calibration sample: object point k = (j, i) * square for k = i * cols + j.
    ref = np.array([[j * 0.03, i * 0.03, 0.0] for i in range(6) for j in range(9)])
    np.testing.assert_allclose(t.points, ref, atol=1e-15)


def test_circle_grids_follow_opencv_sample():
    # samples/cpp/calibration.cpp calcChessboardCorners for (ASYMMETRIC_)CIRCLES_GRID.
    sym = CircleGrid(7, 5, 0.02)
    ref = [[j * 0.02, i * 0.02, 0.0] for i in range(5) for j in range(7)]
    np.testing.assert_allclose(sym.points, ref, atol=1e-15)
    asym = CircleGrid(4, 11, 0.02, asymmetric=True)
    ref = [[(2 * j + i % 2) * 0.02, i * 0.02, 0.0] for i in range(11) for j in range(4)]
    np.testing.assert_allclose(asym.points, ref, atol=1e-15)
    assert asym.points.dtype == np.float64


@given(
    spec=st.one_of(
        st.fixed_dictionaries(
            {"type": st.just("checkerboard"), "cols": st.integers(2, 20), "rows": st.integers(2, 20),
             "square": st.floats(1e-3, 1.0)}
        ),
        st.fixed_dictionaries(
            {"type": st.just("charuco"), "squares_x": st.integers(3, 10), "squares_y": st.integers(3, 10),
             "square": st.just(0.04), "marker": st.floats(0.01, 0.035),
             "dictionary": st.sampled_from(["DICT_4X4_100", "DICT_5X5_100", "DICT_APRILTAG_36h11"]),
             "legacy": st.booleans()}
        ),
        st.fixed_dictionaries(
            {"type": st.just("circles"), "cols": st.integers(2, 10), "rows": st.integers(1, 6).map(lambda r: 2 * r + 1),
             "spacing": st.floats(0.005, 0.1), "asymmetric": st.booleans()}
        ),
    )
)
def test_spec_round_trip(spec):
    t = target_from_spec(spec)
    assert t.type == spec["type"]
    again = target_from_spec(t.to_spec())
    assert again == t
    for k, v in spec.items():
        assert t.to_spec()[k] == v


def test_spec_ignores_mount_and_pose():
    t = target_from_spec({"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025, "mount": "base"})
    assert t == Checkerboard(9, 6, 0.025)


@pytest.mark.parametrize(
    "spec, key",
    [
        ({"type": "hexagons", "cols": 3}, "type"),
        ({"cols": 3}, "type"),
        ({"type": "checkerboard", "cols": 9, "square": 0.02}, "rows"),
        ({"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.0}, "square"),
        ({"type": "checkerboard", "cols": 9, "rows": 6, "square": -0.02}, "square"),
        ({"type": "checkerboard", "cols": 0, "rows": 6, "square": 0.02}, "cols"),
        ({"type": "checkerboard", "cols": 9.5, "rows": 6, "square": 0.02}, "cols"),
        ({"type": "checkerboard", "cols": 9, "rows": 6, "square": "big"}, "square"),
        ({"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.02, "colour": "red"}, "colour"),
        ({"type": "charuco", "squares_x": 5, "squares_y": 7, "square": 0.04}, "marker"),
        ({"type": "charuco", "squares_x": 5, "squares_y": 7, "square": 0.04, "marker": 0.05}, "marker"),
        ({"type": "charuco", "squares_x": 5, "squares_y": 7, "square": 0.04, "marker": 0.03, "dictionary": "DICT_9X9"}, "dictionary"),
        ({"type": "charuco", "squares_x": 20, "squares_y": 20, "square": 0.04, "marker": 0.03, "dictionary": "DICT_4X4_50"}, "dictionary"),
        ({"type": "circles", "cols": 4, "rows": 11, "spacing": float("nan")}, "spacing"),
        ({"type": "circles", "cols": 4, "rows": 10, "spacing": 0.02, "asymmetric": True}, "rows"),
        ({"type": "circles", "cols": 4, "rows": 11, "spacing": 0.02, "diameter": 0.03}, "diameter"),
    ],
)
def test_bad_spec_names_the_key(spec, key):
    with pytest.raises(BadInputError, match=f"'{key}'"):
        target_from_spec(spec)


def test_targets_are_hashable_and_immutable():
    t = Charuco(5, 7, 0.04, 0.03)
    assert hash(t) == hash(Charuco(5, 7, 0.04, 0.03))
    with pytest.raises(Exception):
        t.square = 0.05  # type: ignore[misc]
