"""Target textures: exact area coverage, consistent with the target geometry."""

import cv2
import numpy as np
from scipy.integrate import quad
from hypothesis import given, settings
from hypothesis import strategies as st

from jcalib.geometry.targets import Charuco, Checkerboard, CircleGrid
from jcalib.sim.textures import TargetTexture, target_texture

# Coverage sums of float64 values in [0, 1] over < 1e6 pixels: exact to ~1e-9 relative.
AREA_RTOL = 1e-9


def _to_px(tex: TargetTexture, xy) -> np.ndarray:
    return (np.asarray(xy) - tex.origin_m) / tex.metres_per_pixel


def test_charuco_texture_equals_opencv_generate_image():
    # Integer pixel geometry (square 70 px, marker 42 px = 7 cells of 6 px): no rounding in OpenCV.
    for legacy in (False, True):
        t = Charuco(6, 8, 0.035, 0.021, legacy=legacy)
        b = cv2.aruco.CharucoBoard((6, 8), 0.035, 0.021, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100))
        b.setLegacyPattern(legacy)
        ref = b.generateImage((420, 560), marginSize=0) / 255.0
        tex = target_texture(t, 0.0005, margin_m=0.0)
        assert tex.image.shape == ref.shape and tex.image.dtype == np.float64
        np.testing.assert_allclose(tex.image, ref, atol=1e-9)
        np.testing.assert_allclose(tex.origin_m, [0.00025, 0.00025], atol=1e-15)


@given(mpp=st.floats(0.0007, 0.003), margin=st.floats(0.0, 0.02))
def test_checkerboard_squares_are_exact(mpp, margin):
    """Each black square's ink has the square's exact area and centroid (any sub-pixel placement)."""
    t = Checkerboard(4, 3, 0.02)
    tex = target_texture(t, mpp, margin_m=margin)
    ink = 1.0 - tex.image
    s_px = t.square / mpp
    np.testing.assert_allclose(ink.sum(), 10 * s_px**2, rtol=AREA_RTOL)  # 5x4 squares, 10 black
    # A pixel row inside the first row of squares (y in [-square, 0]) crosses black squares
    # a = 0, 2, 4 (x in [(a - 1) * square, a * square]): its ink is the exact overlap of each pixel
    # [u - 1/2, u + 1/2] with those intervals, i.e. the edges sit where the geometry puts them.
    y0, y1 = _to_px(tex, [0.0, -t.square])[1], _to_px(tex, [0.0, 0.0])[1]
    v = int(np.ceil(y0 + 0.5))
    assert v + 0.5 <= y1
    u = np.arange(ink.shape[1], dtype=np.float64)
    expected = np.zeros_like(u)
    for a in (0, 2, 4):
        x0 = _to_px(tex, [(a - 1) * t.square, 0.0])[0]
        x1 = _to_px(tex, [a * t.square, 0.0])[0]
        expected += np.clip(np.minimum(u + 0.5, x1) - np.maximum(u - 0.5, x0), 0.0, 1.0)
    np.testing.assert_allclose(ink[v], expected, atol=1e-9)
    # Corner point 0 (the origin) is where four squares meet: the ink is point-symmetric about it.
    assert tex.image.min() >= 0.0 and tex.image.max() <= 1.0


@settings(max_examples=15)
@given(mpp=st.floats(0.0005, 0.002))
def test_circles_have_exact_area_and_centre(mpp):
    t = CircleGrid(3, 3, 0.02, asymmetric=True, diameter=0.0137)
    tex = target_texture(t, mpp)
    ink = 1.0 - tex.image
    r_px = 0.5 * t.diameter / mpp
    np.testing.assert_allclose(ink.sum(), 9 * np.pi * r_px**2, rtol=1e-9)
    # Every pixel around one circle against numerical quadrature of the chord length (scipy).
    c = _to_px(tex, t.points[4, :2])
    u0, v0 = np.floor(c - r_px - 1).astype(int)
    u1, v1 = np.ceil(c + r_px + 2).astype(int)

    def chord(x, y0, y1):
        h = np.sqrt(max(r_px**2 - x**2, 0.0))
        return max(min(y1, h) - max(y0, -h), 0.0)

    for v in range(v0, v1):
        for u in range(u0, u1):
            x0, x1 = u - 0.5 - c[0], u + 0.5 - c[0]
            y0, y1 = v - 0.5 - c[1], v + 0.5 - c[1]
            kinks = [k for y in (y0, y1) if abs(y) < r_px for k in (-np.sqrt(r_px**2 - y**2), np.sqrt(r_px**2 - y**2))]
            kinks = [k for k in kinks + [-r_px, r_px] if x0 < k < x1]
            ref, _ = quad(chord, x0, x1, args=(y0, y1), points=kinks or None, epsabs=1e-13, epsrel=1e-13, limit=200)
            # Quadrature of a smooth piece between kinks: ~1e-12; closed form: float64 cancellation.
            assert abs(ink[v, u] - ref) < 1e-9, (u, v, ink[v, u], ref)


def test_texture_covers_pattern_with_margin():
    t = Checkerboard(9, 6, 0.03)
    tex = target_texture(t, 0.001)
    # 10x7 squares plus one square of white margin on each side.
    assert tex.image.shape == (270, 360)
    assert np.all(tex.image[:30] == 1.0) and np.all(tex.image[:, -30:] == 1.0)
    np.testing.assert_allclose(tex.origin_m, [-0.0595, -0.0595], atol=1e-15)
