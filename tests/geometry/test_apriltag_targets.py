"""AprilTag targets: Kalibr's AprilGrid layout, the single tag, the printed tags (texture) and the spec."""

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jcalib.errors import BadInputError
from jcalib.geometry.apriltags import APRILTAG_FAMILIES, AprilGrid, AprilTag
from jcalib.geometry.targets import target_from_spec
from jcalib.sim.textures import apriltag_image, target_texture

#: Published tag36h11 codes (the AprilTag family as Kalibr's kalibr_create_target_pdf and the original
#: AprilTags library list it) of ids 0, 1, 2, 31: bit 35 - k is cell k of the printed tag, row-major from
#: the top left, white where the bit is 1.
TAG36H11_CODES = {0: 0xD5D628584, 1: 0xD97F18B49, 2: 0xDD280910E, 31: 0x2DDE6A3DA}


def _kalibr_points(cols, rows, size, spacing):
    """Kalibr's createGridPoints: a (2 rows) x (2 cols) grid of corners, y up, row-major (r * 2cols + c)."""
    out = np.zeros((2 * rows, 2 * cols, 3))
    for r in range(2 * rows):
        for c in range(2 * cols):
            out[r, c] = [(c // 2) * (1 + spacing) * size + (c % 2) * size, (r // 2) * (1 + spacing) * size + (r % 2) * size, 0]
    return out.reshape(-1, 3)


@given(cols=st.integers(1, 8), rows=st.integers(1, 8), size=st.floats(0.01, 0.2), spacing=st.floats(0.05, 1.0))
def test_aprilgrid_points_are_kalibrs_turned_about_x(cols, rows, size, spacing):
    g = AprilGrid(cols, rows, size, spacing)
    kalibr = _kalibr_points(cols, rows, size, spacing)
    # Kalibr's corners of tag t: base = (t // cols) * 4 cols + (t % cols) * 2, then +0, +1, +2cols+1, +2cols
    t = np.arange(cols * rows)
    base = (t // cols) * 4 * cols + (t % cols) * 2
    idx = np.stack([base, base + 1, base + 2 * cols + 1, base + 2 * cols], axis=1).reshape(-1)
    expected = kalibr[idx] * [1.0, -1.0, -1.0]  # Kalibr's (x, y, z) = jcalib's (x, -y, -z)
    np.testing.assert_allclose(g.points, expected, atol=1e-12)
    assert g.points.shape == (4 * cols * rows, 3) and g.points.dtype == np.float64
    np.testing.assert_array_equal(g.ids, np.arange(g.num_points))


def test_aprilgrid_corner_order_and_extent():
    g = AprilGrid(3, 2, 0.05, 0.2)
    c = g.tag_corners[4]  # tag 4: column 1, row 1 (the top row, up along -y)
    x0, y0 = 1.2 * 0.05, -1.2 * 0.05
    np.testing.assert_allclose(c[:, :2], [[x0, y0], [x0 + 0.05, y0], [x0 + 0.05, y0 - 0.05], [x0, y0 - 0.05]])
    gap = 0.01
    np.testing.assert_allclose(g.extent_m, (-gap, -(2 * 0.05 + gap) - gap, 3 * 0.05 + 2 * gap + gap, gap))
    # proper order on the printed face (x right, y down): bottom left -> bottom right -> top right turns
    # counter-clockwise as seen, i.e. negative signed area in x-right / y-down coordinates
    x, y = c[:, 0], c[:, 1]
    assert np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0


def test_single_tag_points_centre_origin():
    t = AprilTag(id=10, size=0.048)
    h = 0.024
    np.testing.assert_allclose(t.points, [[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]])
    assert t.extent_m == (-h, -h, h, h)
    assert target_from_spec(t.to_spec()) == t


def test_spec_round_trip_and_errors():
    g = target_from_spec({"type": "aprilgrid", "cols": 6, "rows": 6, "tag_size": 0.088, "tag_spacing": 0.3})
    assert g == AprilGrid(6, 6, 0.088, 0.3, "tag36h11") and target_from_spec(g.to_spec()) == g
    for bad, word in [
        ({"type": "aprilgrid", "cols": 6, "rows": 6, "tag_size": 0.088, "tag_spacing": 1.5}, "tag_spacing"),
        ({"type": "aprilgrid", "cols": 6, "rows": 6, "tag_size": 0.088, "tag_spacing": 0.0}, "tag_spacing"),
        ({"type": "aprilgrid", "cols": 6, "rows": 6, "tag_size": -1, "tag_spacing": 0.3}, "tag_size"),
        ({"type": "aprilgrid", "cols": 6, "rows": 6, "tag_size": 0.088, "tag_spacing": 0.3, "family": "tag16h5"},
         "tag16h5 has 30 tags"),
        ({"type": "aprilgrid", "cols": 6, "rows": 6, "tag_size": 0.088, "tag_spacing": 0.3, "family": "t36h11"},
         "family"),
        ({"type": "apriltag", "id": 587, "size": 0.05}, "ids 0..586"),
        ({"type": "apriltag", "id": 3, "size": 0.05, "border_bits": 3}, "border_bits"),
        ({"type": "apriltag", "size": 0.05}, "missing key 'id'"),
    ]:
        with pytest.raises(BadInputError, match=word):
            target_from_spec(bad)


@pytest.mark.parametrize("tag_id", sorted(TAG36H11_CODES))
def test_printed_tags_are_the_published_codes(tag_id):
    """The texture's tags read as the published tag36h11 codes: Kalibr's print (and the official images),
    i.e. OpenCV 4.x's marker images turned by 180° — a test that fails if OpenCV changes its dictionary."""
    code = TAG36H11_CODES[tag_id]
    white = np.array([(code >> (35 - k)) & 1 for k in range(36)], bool).reshape(6, 6)
    cells = apriltag_image("tag36h11", tag_id, border_bits=2)
    assert cells.shape == (10, 10) and cells[:2].all() and cells[-2:].all() and cells[:, :2].all()
    np.testing.assert_array_equal(~cells[2:-2, 2:-2], white)
    # and the texture of a grid draws it there: tag 0 at the bottom left (y down on the print)
    g = AprilGrid(8, 4, 0.05, 0.3)
    bit = 0.005
    tex = target_texture(g, bit / 4, margin_m=0.0)
    x0, y0 = g.tag_corners[tag_id][:, 0].min(), g.tag_corners[tag_id][:, 1].min()  # top left of the tag
    centres = np.array([[x0 + (j + 2.5) * bit, y0 + (i + 2.5) * bit] for i in range(6) for j in range(6)])
    uv = np.round((centres - tex.origin_m) / tex.metres_per_pixel).astype(int)
    np.testing.assert_array_equal(tex.image[uv[:, 1], uv[:, 0]].reshape(6, 6) > 0.5, white)


def test_grid_texture_has_crossing_squares_and_opencv_reads_it():
    g = AprilGrid(3, 2, 0.04, 0.25)
    mpp = 0.0005
    tex = target_texture(g, mpp)
    ink = 1.0 - tex.image
    n_cross = (g.cols + 1) * (g.rows + 1)
    tag_ink = sum((apriltag_image(g.family, t, 2)).sum() for t in g.tag_ids) * (g.tag_size / 10) ** 2
    np.testing.assert_allclose(ink.sum() * mpp**2, tag_ink + n_cross * g.gap**2, rtol=1e-9)
    # every tag corner is an X-junction: the crossing square diagonally opposite the tag is black
    for c, (dx, dy) in zip(range(4), [(-1, 1), (1, 1), (1, -1), (-1, -1)]):
        p = g.tag_corners[:, c, :2] + 0.5 * g.gap * np.array([dx, dy])
        uv = np.round((p - tex.origin_m) / mpp).astype(int)
        assert np.all(tex.image[uv[:, 1], uv[:, 0]] < 0.01)
    # OpenCV finds the tags with their ids where the geometry puts them (OpenCV's corner 0 = point corner 1)
    img = np.pad((255 * tex.image).astype(np.uint8), 20, constant_values=255)
    params = cv2.aruco.DetectorParameters()
    params.markerBorderBits = 2
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    corners, ids, _ = cv2.aruco.ArucoDetector(d, params).detectMarkers(cv2.dilate(img, np.ones((3, 3), np.uint8)))
    assert ids is not None and sorted(ids.ravel()) == list(range(g.num_tags))
    for c, i in zip(corners, ids.ravel()):
        expect = (g.tag_corners[i][[1, 0, 3, 2], :2] - tex.origin_m) / mpp + 20
        assert np.max(np.abs(c.reshape(4, 2) - expect)) < 3.0


def test_families_are_opencvs():
    for name, (dictionary, bits, count) in APRILTAG_FAMILIES.items():
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
        assert d.markerSize == bits and d.bytesList.shape[0] == count, name
