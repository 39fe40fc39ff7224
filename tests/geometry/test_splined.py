"""The splined stereographic lens model: an ideal stereographic lens without spline, exact reproduction
of polynomial corrections (the B-spline's defining property, which checks its indexing), projection /
unprojection round trips and derivatives, and its form in result files and exports."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jcalib.errors import BadInputError
from jcalib.geometry import camera_from_opencv
from jcalib.geometry.cameras import camera_model_from_name
from jcalib.geometry.cameras.splined import GRID, SPLINED_DIST_NAMES, SplinedStereographic, spline_extent
from jcalib.io.schema.lens import LENS_DIST_NAMES

SIZE = (1280, 960)


def _model(control=None, fov=190.0):
    return SplinedStereographic(SIZE, [330.0, 331.0], [641.0, 479.0], fov, control)


def _points(rng, n=400, max_angle_deg=80.0):
    theta = np.radians(rng.uniform(0.0, max_angle_deg, n))
    phi = rng.uniform(0.0, 2 * np.pi, n)
    d = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)
    return d * rng.uniform(0.2, 5.0, (n, 1))


def test_without_spline_it_is_an_ideal_stereographic_lens():
    rng = np.random.default_rng(0)
    p = _points(rng)
    pix, ok = _model().project_valid(jnp.asarray(p))
    r = np.linalg.norm(p, axis=1)
    theta = np.arccos(p[:, 2] / r)
    radius = 2.0 * np.tan(theta / 2.0)
    direction = p[:, :2] / np.linalg.norm(p[:, :2], axis=1, keepdims=True)
    expected = np.array([330.0, 331.0]) * radius[:, None] * direction + np.array([641.0, 479.0])
    assert np.all(np.asarray(ok))
    np.testing.assert_allclose(np.asarray(pix), expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_spline_reproduces_polynomials_up_to_cubic(degree):
    """Control values sampled from a polynomial of degree <= 3 at the control points' positions
    (uniform cubic B-spline: their Greville abscissae, spacing h, from −U − h) give exactly that polynomial
    inside the domain (up to the quasi-interpolation correction, which vanishes for degree <= 1; for
    degree 2 and 3 the control values need the h²/6 correction of the B-spline's second moment)."""
    nx, ny = GRID
    U, V, h = (float(v) for v in spline_extent(190.0))
    xs = -U - h + h * np.arange(nx)
    ys = -V - h + h * np.arange(ny)
    X, Y = np.meshgrid(xs, ys)
    a = np.array([0.03, -0.02, 0.01, 0.004, -0.003, 0.002, 0.001, -0.0005, 0.0007, 0.0003])

    def poly(x, y, d):
        terms = [np.ones_like(x), x, y, x * x, x * y, y * y, x**3, x * x * y, x * y * y, y**3]
        k = {1: 3, 2: 6, 3: 10}[d]
        return sum(c * t for c, t in zip(a[:k], terms[:k]))

    # B-spline quasi-interpolant of x^2: control = x_i^2 − h²/3 (and x^3: x_i^3 − x_i h²); build from that
    def control_of(d):
        x, y = X, Y
        terms = [np.ones_like(x), x, y, x * x - h * h / 3, x * y, y * y - h * h / 3, x**3 - x * h * h,
                 (x * x - h * h / 3) * y, x * (y * y - h * h / 3), y**3 - y * h * h]
        k = {1: 3, 2: 6, 3: 10}[d]
        return sum(c * t for c, t in zip(a[:k], terms[:k]))

    c = control_of(degree)
    model = _model(np.stack([c, -0.5 * c], axis=-1))
    rng = np.random.default_rng(degree)
    u = np.stack([rng.uniform(-U, U, 500), rng.uniform(-V, V, 500)], axis=1)
    d, inside = model.correction(jnp.asarray(u))
    truth = poly(u[:, 0], u[:, 1], degree)
    assert np.all(np.asarray(inside))
    np.testing.assert_allclose(np.asarray(d), np.stack([truth, -0.5 * truth], axis=1), atol=1e-12)


def test_projection_and_unprojection_round_trip():
    rng = np.random.default_rng(3)
    nx, ny = GRID
    model = _model(0.03 * rng.normal(size=(ny, nx, 2)))
    p = _points(rng)
    pix, ok = model.project_valid(jnp.asarray(p))
    ray, ok2 = model.unproject_valid(pix)
    ok, ok2 = np.asarray(ok), np.asarray(ok2)
    assert ok.mean() > 0.95 and np.all(ok2[ok])
    unit = p / np.linalg.norm(p, axis=1, keepdims=True)
    np.testing.assert_allclose(np.asarray(ray)[ok], unit[ok], atol=1e-12)
    # a pixel beyond the spline's domain is not valid (and finite)
    far, valid = model.unproject_valid(jnp.asarray([[-5000.0, 479.0]]))
    assert not bool(valid[0]) and np.all(np.isfinite(np.asarray(far)))


def test_unprojection_derivatives_are_the_implicit_ones():
    """∂ray/∂params of unproject against central differences (the Newton solve is not differentiated;
    one differentiable step on the solution gives the implicit-function derivatives)."""
    rng = np.random.default_rng(4)
    nx, ny = GRID
    model = _model(0.02 * rng.normal(size=(ny, nx, 2)))
    pixel = jnp.asarray([900.0, 650.0])
    params = np.asarray(model.params)

    def ray(prm):
        return SplinedStereographic.from_params(SIZE, prm).unproject(pixel)

    J = np.asarray(jax.jacfwd(ray)(jnp.asarray(params)))
    for j in (0, 2, 5 + 2 * (7 * nx + 8), 5 + 2 * (7 * nx + 8) + 1):  # fx, cx, a control value near the pixel
        h = 1e-6 * max(1.0, abs(params[j]))
        e = np.zeros_like(params)
        e[j] = h
        fd = (np.asarray(ray(jnp.asarray(params + e))) - np.asarray(ray(jnp.asarray(params - e)))) / (2 * h)
        np.testing.assert_allclose(J[:, j], fd, rtol=1e-5, atol=1e-9)
    assert np.abs(J[:, 5 + 2 * (7 * nx + 8)]).max() > 0.0


def test_result_form_round_trips_and_names_agree():
    """A result file stores a splined camera as K and dist = (fov_x_deg, spline values); reading it back
    gives the same model. The no-JAX name table (io) equals the model's."""
    assert LENS_DIST_NAMES["splined"] == SPLINED_DIST_NAMES
    rng = np.random.default_rng(5)
    nx, ny = GRID
    model = _model(0.01 * rng.normal(size=(ny, nx, 2)))
    K, dist = model.to_opencv()
    again = camera_from_opencv(K, dist, SIZE)
    assert isinstance(again, SplinedStereographic)
    np.testing.assert_array_equal(np.asarray(again.params), np.asarray(model.params))
    default = camera_model_from_name("splined", SIZE)
    w = SIZE[0] / 2 / default.params[0]
    assert default.params[4] > math.degrees(4 * math.atan(w / 2))  # its spline covers the image
    with pytest.raises(BadInputError, match="skew"):
        camera_from_opencv(np.array([[330.0, 1.0, 641.0], [0, 331.0, 479.0], [0, 0, 1]]), dist, SIZE)


def test_exports_refuse_a_splined_camera_and_say_how_to_convert(tmp_path):
    from jcalib.io.export import export_result
    from jcalib.io.result import CameraResult, ResultFile

    file = ResultFile(cameras={"cam0": CameraResult.from_model(_model())})
    path = tmp_path / "r.json"
    file.save(path)
    for fmt in ("opencv", "ros"):
        with pytest.raises(BadInputError, match="jcalib convert"):
            export_result(path, fmt, tmp_path / f"out.{fmt}")
