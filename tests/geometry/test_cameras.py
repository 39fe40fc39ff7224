"""Camera models: round trips, Jacobians, invalid points, the valid region, construction.

References are independent of the code under test: finite differences, NumPy polynomial roots,
closed-form identities, and the models' own definitions evaluated in NumPy.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jcalib.errors import BadInputError
from jcalib.geometry.cameras import (
    CAMERA_MODELS,
    AbstractCameraModel,
    Fisheye,
    OpenCV5,
    OpenCV8,
    OpenCV14,
    Pinhole,
    camera_from_opencv,
    camera_model_from_name,
)
from jcalib.geometry.cameras.sampling import random_camera

MODELS = ("pinhole", "opencv4", "opencv5", "opencv8", "opencv12", "opencv14", "fisheye")
VARIANTS = [(name, skew) for name in MODELS for skew in (False, True)]
IDS = [f"{name}{'-skew' if skew else ''}" for name, skew in VARIANTS]
IMAGE_SIZE = (1280, 960)
NUM_POINTS = 64

seeds = st.integers(min_value=0, max_value=2**32 - 1)


@eqx.filter_jit
def _project(model: AbstractCameraModel, p):
    return model.project_valid(p)


@eqx.filter_jit
def _unproject(model: AbstractCameraModel, px):
    return model.unproject_valid(px)


def _pad(x: np.ndarray) -> np.ndarray:
    """Repeat the last row up to NUM_POINTS rows, so every call reuses one compiled shape."""
    return np.concatenate([x, np.repeat(x[-1:], NUM_POINTS - len(x), axis=0)], axis=0)


def _pixels(rng, n=NUM_POINTS):
    """Pixels uniform over the image (OpenCV convention: centres from 0 to size - 1)."""
    return np.stack(
        [
            rng.uniform(-0.5, IMAGE_SIZE[0] - 0.5, n),
            rng.uniform(-0.5, IMAGE_SIZE[1] - 0.5, n),
        ],
        axis=1,
    )


# ------------------------------------------------------------------------ round trips


@pytest.mark.parametrize(("name", "skew"), VARIANTS, ids=IDS)
@settings(max_examples=30)  # x 14 variants x 64 points and pixels each
@given(seed=seeds)
def test_unproject_inverts_project(name, skew, seed):
    rng = np.random.default_rng(seed)
    model = random_camera(name, rng, IMAGE_SIZE, skew=skew)
    # Directions spread over the whole sphere of the field of view, not only the image.
    p = rng.normal(size=(NUM_POINTS, 3)) + np.array([0.0, 0.0, 1.5])
    px = _pixels(rng)
    pixels, ok_p = _project(model, p)
    rays, ok_r = (np.asarray(a) for a in _unproject(model, pixels))
    ok = np.asarray(ok_p) & ok_r
    rays_px, ok_px = (np.asarray(a) for a in _unproject(model, px))
    back, ok_back = (np.asarray(a) for a in _project(model, rays_px))
    ok_px = ok_px & ok_back
    # Must not pass vacuously: most points / image pixels are inside the valid region.
    assert ok.sum() >= NUM_POINTS // 4 and ok_px.sum() >= NUM_POINTS // 3
    # unproject(project(p)) ∥ p: unit vector, parallel and same direction (1e-12: float64
    # round-off of a converged Newton solve).
    unit = p / np.linalg.norm(p, axis=1, keepdims=True)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(rays[ok], unit[ok], rtol=0.0, atol=1e-12)
    # project(unproject(px)) == px to 1e-9 px.
    np.testing.assert_allclose(back[ok_px], px[ok_px], rtol=0.0, atol=1e-9)


# ------------------------------------------------------------------------ Jacobians


@eqx.filter_jit
def _jacobians(model: AbstractCameraModel, p, px):
    """Jacobians of project / unproject w.r.t. the point / pixel and the params vector, by
    forward and reverse mode."""
    theta = model.params

    def proj(t, q):
        return model.with_params(t).project(q)

    def unproj(t, x):
        return model.with_params(t).unproject(x)

    out = []
    for jac in (jax.jacfwd, jax.jacrev):
        d_proj = jax.vmap(jac(proj, argnums=(1, 0)), in_axes=(None, 0))(theta, p)
        d_unproj = jax.vmap(jac(unproj, argnums=(1, 0)), in_axes=(None, 0))(theta, px)
        out += [*d_proj, *d_unproj]
    return out


def _central_differences(fn, x: np.ndarray, batch_shape) -> np.ndarray:
    """d fn / d x by central differences, step 1e-7·max(1, |x_i|) per coordinate.

    ``x`` is either one vector shared by the batch (params) or one row per batch element (points,
    pixels); ``fn`` maps it to ``(batch..., m)``. Returns ``(batch..., m, n)``.
    """
    columns = []
    n = x.shape[-1]
    for i in range(n):
        h = 1e-7 * np.maximum(1.0, np.abs(x[..., i]))
        dx = np.zeros_like(x)
        dx[..., i] = h
        hb = h if np.ndim(h) == 0 else h[:, None]
        columns.append((np.asarray(fn(x + dx)) - np.asarray(fn(x - dx))) / (2.0 * hb))
    return np.stack(columns, axis=-1)


# Every model, skew on every other one (the skew enters linearly; compiling both variants of all
# seven models would double this test's compile time).
JACOBIAN_VARIANTS = [(name, i % 2 == 0) for i, name in enumerate(MODELS)] + [
    ("fisheye", False)
]


@pytest.mark.parametrize(
    ("name", "skew"),
    JACOBIAN_VARIANTS,
    ids=[f"{n}{'-skew' if s else ''}" for n, s in JACOBIAN_VARIANTS],
)
def test_jacobians_forward_reverse_finite_differences(name, skew):
    rng = np.random.default_rng(7)
    model = random_camera(name, rng, IMAGE_SIZE, skew=skew)
    px = _pixels(rng)
    rays, valid = (np.asarray(a) for a in _unproject(model, px))
    px = _pad(px[valid])
    p = _pad(rays[valid] * rng.uniform(0.3, 8.0, (valid.sum(), 1)))
    theta = np.asarray(model.params)
    fwd_pp, fwd_pt, fwd_xp, fwd_xt, rev_pp, rev_pt, rev_xp, rev_xt = (
        np.asarray(j) for j in _jacobians(model, p, px)
    )

    # Forward and reverse mode differentiate the same program: equal to float64 round-off.
    for fwd, rev in (
        (fwd_pp, rev_pp),
        (fwd_pt, rev_pt),
        (fwd_xp, rev_xp),
        (fwd_xt, rev_xt),
    ):
        np.testing.assert_allclose(fwd, rev, rtol=1e-9, atol=1e-12)

    # Central differences, h = 1e-7 relative: truncation h²/6 f''' (~1e-15 f''', and f''' reaches
    # ~1e8 for k4 at wide angles), round-off ~ eps |f| / h ~ 1e-6 for |f| ~ 1e3 px, 1e-9 for rays.
    fd_pp = _central_differences(lambda q: _project(model, q)[0], p, len(p))
    fd_pt = _central_differences(
        lambda t: _project(model.with_params(t), p)[0], theta, len(p)
    )
    fd_xp = _central_differences(lambda x: _unproject(model, x)[0], px, len(px))
    fd_xt = _central_differences(
        lambda t: _unproject(model.with_params(t), px)[0], theta, len(px)
    )
    np.testing.assert_allclose(fwd_pp, fd_pp, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(fwd_pt, fd_pt, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(fwd_xp, fd_xp, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(fwd_xt, fd_xt, rtol=1e-6, atol=1e-8)
    assert fwd_pt.shape == (len(p), 2, len(model.param_names))


# ------------------------------------------------------------------------ invalid points


def _fold_model(name: str) -> AbstractCameraModel:
    """A model whose valid region ends inside its field of view (strong barrel distortion)."""
    K = np.array([[600.0, 0.0, 639.5], [0.0, 600.0, 479.5], [0.0, 0.0, 1.0]])
    if name == "fisheye":
        return camera_from_opencv(K, [0.0, -0.05, 0.0, 0.0], IMAGE_SIZE, fisheye=True)
    dist = np.zeros(CAMERA_MODELS[name].num_coeffs)
    if dist.size:
        dist[:2] = (-0.4, 0.02)
    return camera_from_opencv(K, dist, IMAGE_SIZE)


@eqx.filter_jit
def _grads(model, p, px):
    """Gradients of the sums of project(p) and of unproject(px) w.r.t. params, points, pixels."""

    def total_project(t, q):
        return jnp.sum(model.with_params(t).project(q))

    def total_unproject(t, x):
        return jnp.sum(model.with_params(t).unproject(x))

    return (
        *jax.grad(total_project, argnums=(0, 1))(model.params, p),
        *jax.grad(total_unproject, argnums=(0, 1))(model.params, px),
    )


@pytest.mark.parametrize("name", MODELS)
def test_invalid_points_are_flagged_and_finite(name):
    model = _fold_model(name)
    bad = [
        [0.0, 0.0, 0.0],  # the camera centre
        [1e-12, -1e-12, 1e-13],  # next to it
        [0.3, -0.2, 0.0],  # in the plane z = 0
    ]
    if name == "fisheye":
        bad += [[0.0, 0.0, -2.0], [1e-10, 0.0, -2.0]]  # straight behind: θ = π
        # θ = 1.5 rad, beyond θ_max = √2 (slope 1 - 0.25 θ⁴).
        bad += [[np.tan(1.5), 0.0, 1.0]]
    else:
        bad += [[0.1, 0.2, -1.0], [0.0, 0.0, -1e-12]]  # behind the camera
    if name != "pinhole" and name != "fisheye":
        # r² = 1.69, beyond the fold at r² ≈ 0.90 (k1 = -0.4, k2 = 0.02).
        bad += [[1.3, 0.0, 1.0]]
    p = _pad(np.array(bad))
    pixels, valid = _project(model, p)
    assert not np.any(np.asarray(valid))
    assert np.all(np.isfinite(np.asarray(pixels)))
    for g in _grads(model, p, np.asarray(pixels)):
        assert np.all(np.isfinite(np.asarray(g)))


@pytest.mark.parametrize("name", MODELS)
def test_unproject_outside_valid_region_is_flagged_and_finite(name):
    model = _fold_model(name)
    # The image centre is valid; far-away pixels have no pre-image for a folding model.
    px = _pad(np.array([[639.5, 479.5], [1e6, 1e6], [-5e4, 479.5], [639.5, 3e3]]))
    rays, valid = (np.asarray(a) for a in _unproject(model, px))
    assert np.all(np.isfinite(rays))
    np.testing.assert_allclose(rays[0], [0.0, 0.0, 1.0], atol=1e-15)
    expected = [True] + [name == "pinhole"] * 3
    assert list(valid[:4]) == expected
    for g in _grads(model, _pad(rays[:4] * 2.0), px):
        assert np.all(np.isfinite(np.asarray(g)))


def test_fisheye_beyond_90_degrees_is_valid():
    """θ is the true angle (atan2), so a >180° lens sees points with Z < 0 (cv2 mirrors them)."""
    K = np.array([[400.0, 0.0, 639.5], [0.0, 400.0, 479.5], [0.0, 0.0, 1.0]])
    model = camera_from_opencv(K, [0.0, 0.0, 0.0, 0.0], IMAGE_SIZE, fisheye=True)
    theta = np.radians(100.0)
    p = _pad(np.array([[np.sin(theta), 0.0, np.cos(theta)]]))
    pixels, valid = _project(model, p)
    assert bool(valid[0])
    # Equidistant: u = cx + fx θ (closed form, k = 0).
    np.testing.assert_allclose(
        np.asarray(pixels)[0], [639.5 + 400.0 * theta, 479.5], atol=1e-9
    )
    rays, ok = _unproject(model, pixels)
    assert bool(ok[0])
    np.testing.assert_allclose(np.asarray(rays)[0], p[0], atol=1e-12)


# ------------------------------------------------------------------------ the valid region


def _first_positive_root(coeffs_low_to_high) -> float:
    """Smallest positive real root of a polynomial (NumPy, ascending coefficients), or inf."""
    coeffs = np.polynomial.polynomial.polytrim(
        np.asarray(coeffs_low_to_high, dtype=np.float64)
    )
    roots = np.polynomial.polynomial.polyroots(coeffs)
    real = roots[(np.abs(roots.imag) < 1e-12) & (roots.real > 0.0)].real
    return float(real.min()) if real.size else np.inf


def _fold_u_reference(k) -> float:
    """r²_max of OpenCV's radial map from NumPy roots: the first positive root of the slope
    numerator P(u) = N D + 2u (N' D - N D') or of the denominator D(u), u = r²."""
    k1, k2, k3, k4, k5, k6 = k
    P = np.polynomial.polynomial
    N, D = np.array([1.0, k1, k2, k3]), np.array([1.0, k4, k5, k6])
    slope = P.polyadd(
        P.polymul(N, D),
        P.polymul(
            [0.0, 2.0],
            P.polysub(P.polymul(P.polyder(N), D), P.polymul(N, P.polyder(D))),
        ),
    )
    return min(_first_positive_root(slope), _first_positive_root(D))


def _coefficient(lo: float, hi: float):
    """Floats rounded to 1e-6 (no subnormal leading coefficients for the NumPy root finder)."""
    return st.floats(lo, hi).map(lambda v: round(v, 6))


@settings(max_examples=40)
@given(
    k=st.tuples(
        _coefficient(-1.0, 0.2), _coefficient(-0.3, 0.3), _coefficient(-0.1, 0.1),
        _coefficient(-0.5, 0.5), _coefficient(-0.2, 0.2), _coefficient(-0.05, 0.05),
    )
)  # fmt: skip
def test_fold_radius_matches_polynomial_roots(k):
    u_max = _fold_u_reference(k)
    if not np.isfinite(u_max) or u_max > np.tan(np.radians(89.0)) ** 2:
        return  # no fold in the searched range of view angles
    # A dip narrower than the sampling (two roots very close) is documented as missable.
    model = OpenCV8(
        IMAGE_SIZE,
        (600.0, 600.0),
        (639.5, 479.5),
        distortion=np.r_[k[:2], 0.0, 0.0, k[2:]],
    )
    r_max = np.sqrt(u_max)
    p = _pad(
        np.array(
            [
                [0.999 * r_max, 0.0, 1.0],
                [1.001 * r_max, 0.0, 1.0],
                [0.0, 0.5 * r_max, 1.0],
            ]
        )
    )
    _, valid = _project(model, p)
    assert list(np.asarray(valid)[:3]) == [True, False, True]


def test_fold_is_a_real_fold():
    """Beyond r_max the radial map decreases: points farther out land closer to the centre."""
    model = _fold_model("opencv5")  # k1 = -0.4, k2 = 0.02: slope 1 - 1.2 u + 0.1 u²
    u_max = _first_positive_root([1.0, -1.2, 0.1])
    r = np.sqrt(u_max) * np.array([0.9, 0.99, 1.01, 1.1])
    p = _pad(np.stack([r, np.zeros(4), np.ones(4)], axis=1))
    pixels, valid = _project(model, p)
    u = np.asarray(pixels)[:4, 0]
    assert list(np.asarray(valid)[:4]) == [True, True, False, False]
    assert u[0] < u[1] and u[1] > u[2] > u[3]


def test_fisheye_max_theta_matches_polynomial_roots():
    k = np.array([0.02, -0.03, 0.004, -0.002])
    # dθd/dθ = 1 + 3k1 v + 5k2 v² + 7k3 v³ + 9k4 v⁴, v = θ².
    theta_max = np.sqrt(
        _first_positive_root([1.0, 3 * k[0], 5 * k[1], 7 * k[2], 9 * k[3]])
    )
    K = np.array([[300.0, 0.0, 639.5], [0.0, 300.0, 479.5], [0.0, 0.0, 1.0]])
    model = camera_from_opencv(K, k, IMAGE_SIZE, fisheye=True)
    th = theta_max * np.array([0.999, 1.001])
    p = _pad(np.stack([np.sin(th), np.zeros(2), np.cos(th)], axis=1))
    _, valid = _project(model, p)
    assert list(np.asarray(valid)[:2]) == [True, False]


# ------------------------------------------------------------------------ construction


@pytest.mark.parametrize(("name", "skew"), VARIANTS, ids=IDS)
def test_opencv_round_trip(name, skew):
    model = random_camera(name, 3, IMAGE_SIZE, skew=skew)
    K, dist = model.to_opencv()
    assert K.dtype == np.float64 and K.shape == (3, 3) and dist.dtype == np.float64
    assert dist.shape == (
        (4,) if name == "fisheye" else (CAMERA_MODELS[name].num_coeffs,)
    )
    assert (K[0, 1] != 0.0) == skew
    again = camera_from_opencv(K, dist, model.image_size, fisheye=name == "fisheye")
    assert type(again) is type(model) and again.name == name and again.has_skew == skew
    assert again.image_size == IMAGE_SIZE
    # Exact copy except alpha = (alpha fx) / fx: one rounding.
    np.testing.assert_allclose(
        np.asarray(again.params), np.asarray(model.params), rtol=1e-15, atol=0
    )
    # OpenCV's (1, n) row vectors are accepted too.
    again = camera_from_opencv(
        K, dist[None, :], model.image_size, fisheye=name == "fisheye"
    )
    np.testing.assert_allclose(
        np.asarray(again.params), np.asarray(model.params), rtol=1e-15, atol=0
    )


@pytest.mark.parametrize(("name", "skew"), VARIANTS, ids=IDS)
def test_params_round_trip_and_names(name, skew):
    model = random_camera(name, 4, IMAGE_SIZE, skew=skew)
    names = model.param_names
    theta = model.params
    assert theta.dtype == jnp.float64 and theta.shape == (len(names),)
    K, dist = model.to_opencv()
    by_name = dict(zip(names, np.asarray(theta), strict=True))
    assert (by_name["fx"], by_name["fy"], by_name["cx"], by_name["cy"]) == (
        K[0, 0],
        K[1, 1],
        K[0, 2],
        K[1, 2],
    )
    dist_names = names[5:] if skew else names[4:]
    assert [by_name[n] for n in dist_names] == list(dist)
    expected = ("k1", "k2", "k3", "k4") if name == "fisheye" else (
        "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty"
    )[: len(dist)]  # fmt: skip
    assert dist_names == expected
    if skew:
        assert names[4] == ("alpha" if name == "fisheye" else "skew")
    rebuilt = camera_model_from_name(name, IMAGE_SIZE, theta, skew=skew)
    assert type(rebuilt) is type(model)
    assert np.array_equal(np.asarray(rebuilt.params), np.asarray(theta))
    assert np.array_equal(
        np.asarray(model.with_params(theta).params), np.asarray(theta)
    )


@pytest.mark.parametrize(("name", "skew"), VARIANTS, ids=IDS)
def test_with_params_many_equals_with_params_one_by_one(name, skew):
    """The batched builder (results of batched calibrations) gives the models ``with_params`` gives:
    same class, configuration, field shapes and dtypes, parameters and projections."""
    model = random_camera(name, 7, IMAGE_SIZE, skew=skew)
    thetas = np.stack([np.asarray(random_camera(name, s, IMAGE_SIZE, skew=skew).params) for s in (1, 2, 3)])
    many = model.with_params_many(thetas)
    assert len(many) == 3
    p = _pad(np.array([[0.1, 0.2, 1.0], [-0.3, 0.1, 2.0]]))
    for got, theta in zip(many, thetas):
        one = model.with_params(theta)
        assert type(got) is type(one) and got.image_size == one.image_size and got.has_skew == skew
        assert jax.tree.structure(got) == jax.tree.structure(one)
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(one)):
            assert a.shape == b.shape and a.dtype == b.dtype == jnp.float64
        assert np.array_equal(np.asarray(got.params), theta)
        np.testing.assert_array_equal(np.asarray(_project(got, p)[0]), np.asarray(_project(one, p)[0]))
    with pytest.raises(BadInputError, match="shape"):
        model.with_params_many(thetas[:, :-1])


def test_default_model_from_name():
    model = camera_model_from_name("opencv5", (1600, 1200))
    K, dist = model.to_opencv()
    np.testing.assert_array_equal(
        K, [[1600.0, 0.0, 799.5], [0.0, 1600.0, 599.5], [0.0, 0.0, 1.0]]
    )
    np.testing.assert_array_equal(dist, np.zeros(5))
    assert (
        camera_model_from_name("fisheye", (640, 480), skew=True).param_names[4]
        == "alpha"
    )


def test_skew_convention():
    """``u = fx x + skew y + cx`` (K multiplies the normalised point)."""
    model = Pinhole((640, 480), (500.0, 400.0), (320.0, 240.0), skew=3.0)
    pixels = np.asarray(model.project(jnp.array([0.2, -0.1, 2.0])))
    K = np.array([[500.0, 3.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]])
    expected = K @ np.array([0.1, -0.05, 1.0])
    np.testing.assert_allclose(pixels, expected[:2], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(model.K), K)


def test_vmap_over_parameter_vectors():
    """A batch of cameras (one params vector each) projects in one vmapped call."""
    model = random_camera("opencv14", 5, IMAGE_SIZE)
    thetas = jnp.stack([model.params, model.params.at[4].set(0.0)])
    p = _pad(np.array([[0.1, 0.2, 1.0], [0.3, -0.1, 2.0]]))
    out = eqx.filter_jit(
        lambda m, t, p: jax.vmap(lambda t: m.with_params(t).project(p))(t)
    )(model, thetas, p)
    assert out.shape == (2, NUM_POINTS, 2) and out.dtype == jnp.float64
    # Batched and unbatched XLA kernels may round differently: 1e-12 relative.
    np.testing.assert_allclose(
        np.asarray(out[0]), np.asarray(_project(model, p)[0]), rtol=1e-12
    )


def test_batch_shapes():
    model = random_camera("fisheye", 6, IMAGE_SIZE)
    p = jnp.ones((2, 3, 3))
    pixels, valid = _project(model, p)
    assert (
        pixels.shape == (2, 3, 2) and valid.shape == (2, 3) and valid.dtype == jnp.bool_
    )
    rays, valid = _unproject(model, pixels)
    assert rays.shape == (2, 3, 3) and valid.shape == (2, 3)
    pixels, valid = _project(model, jnp.array([0.0, 0.0, 1.0]))
    assert pixels.shape == (2,) and valid.shape == ()


K_GOOD = [[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]]


@pytest.mark.parametrize(
    ("call", "words"),
    [
        (lambda: camera_from_opencv(K_GOOD, np.zeros(3), (640, 480)), ["3 coefficients", "0, 4, 5, 8, 12 or 14"]),
        (lambda: camera_from_opencv(K_GOOD, np.zeros(6), (640, 480)), ["6 coefficients"]),
        (lambda: camera_from_opencv(K_GOOD, np.zeros(5), (640, 480), fisheye=True), ["fisheye", "4"]),
        (lambda: camera_from_opencv(K_GOOD, [np.nan, 0, 0, 0, 0], (640, 480)), ["dist", "finite"]),
        (lambda: camera_from_opencv(np.eye(2), np.zeros(5), (640, 480)), ["K", "(3, 3)"]),
        (lambda: camera_from_opencv([[800, 0, 320], [1, 800, 240], [0, 0, 1]], [], (640, 480)), ["upper-triangular"]),
        (lambda: camera_from_opencv([[800, 0, 320], [0, 800, 240], [0, 0, 2]], [], (640, 480)), ["K[2][2] = 1"]),
        (lambda: camera_from_opencv([[-800, 0, 320], [0, 800, 240], [0, 0, 1]], [], (640, 480)), ["positive", "fx = -800"]),
        (lambda: camera_from_opencv([[800, 0, np.inf], [0, 800, 240], [0, 0, 1]], [], (640, 480)), ["finite"]),
        (lambda: camera_from_opencv(K_GOOD, [], (640, 0)), ["image_size", "(640, 0)"]),
        (lambda: camera_from_opencv(K_GOOD, [], (640.0, 480.0)), ["image_size", "integers"]),
        (lambda: camera_from_opencv(K_GOOD, [], (640,)), ["image_size"]),
        (lambda: camera_model_from_name("opencv6", (640, 480)), ["opencv6", "pinhole", "fisheye"]),
        (lambda: camera_model_from_name("opencv5", (640, 480), np.zeros(8)), ["shape (9,)", "got shape (8,)"]),
        (lambda: camera_model_from_name("opencv5", (640, 480), np.zeros(9), skew=True), ["shape (10,)"]),
        (lambda: camera_model_from_name("pinhole", (640, 480), [0.0, 500.0, 320.0, 240.0]), ["positive", "fx = 0"]),
        (lambda: camera_model_from_name("pinhole", (640, 480), [500.0, 500.0, np.nan, 240.0]), ["finite"]),
        (lambda: OpenCV5((640, 480), (500.0, 500.0), (320.0, 240.0), distortion=np.zeros(4)), ["distortion", "(5,)"]),
        (lambda: Fisheye((640, 480), (500.0,), (320.0, 240.0), np.zeros(4)), ["focal", "(2,)"]),
        (lambda: Pinhole((640, 480), (500.0, 500.0), (320.0, 240.0)).project(jnp.ones((4, 2))), ["p_cam", "(..., 3)"]),
        (lambda: Pinhole((640, 480), (500.0, 500.0), (320.0, 240.0)).unproject(jnp.ones((4, 3))), ["pixels", "(..., 2)"]),
    ],
)  # fmt: skip
def test_bad_input_raises(call, words):
    with pytest.raises(BadInputError) as info:
        call()
    for word in words:
        assert word in str(info.value)


def test_opencv14_tilt_is_used():
    """The tilt terms change the projection (guards against silently ignoring tx, ty)."""
    model = random_camera("opencv14", 8, IMAGE_SIZE)
    flat = OpenCV14(
        IMAGE_SIZE,
        model.focal,
        model.principal_point,
        model.distortion.at[12:].set(0.0),
    )
    p = _pad(np.array([[0.2, 0.1, 1.0]]))
    assert float(jnp.max(jnp.abs(_project(model, p)[0] - _project(flat, p)[0]))) > 1e-3


def test_valid_region_excludes_tangential_folds():
    """With tangential terms the map can fold inside the radial fold radius; valid points must
    keep a positive Jacobian determinant of the distortion (checked with OpenCV by central
    differences, independent of jcalib)."""
    import cv2

    # Radial slope 1 - 0.636 u + 0.0725 u² (fold at u ≈ 2.05), plus tangential terms.
    dist = np.array([-0.212, 0.0145, 4.8e-4, 1.7e-3])
    model = camera_from_opencv(
        np.diag([1000.0, 1000.0, 1.0])
        + np.array([[0, 0, 639.5], [0, 0, 479.5], [0, 0, 0]]),
        dist,
        IMAGE_SIZE,
    )
    rng = np.random.default_rng(11)
    n = 64 * NUM_POINTS
    r = np.sqrt(rng.uniform(0.0, 2.3, n))
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    xy = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
    p = np.concatenate([xy, np.ones((n, 1))], axis=1)
    valid = np.concatenate(
        [np.asarray(_project(model, chunk)[1]) for chunk in np.split(p, 64)]
    )

    def distort(q):
        p = np.concatenate([q, np.ones((len(q), 1))], axis=1)
        return cv2.projectPoints(p, np.zeros(3), np.zeros(3), np.eye(3), dist)[0][:, 0]

    h = 1e-6
    jx = (distort(xy + [h, 0.0]) - distort(xy - [h, 0.0])) / (2 * h)
    jy = (distort(xy + [0.0, h]) - distort(xy - [0.0, h])) / (2 * h)
    det = jx[:, 0] * jy[:, 1] - jx[:, 1] * jy[:, 0]
    assert np.any(det <= 0.0)  # the lens really folds inside the sampled disc
    assert np.all(det[valid] > 0.0)
    # The radial-only fold radius (NumPy root) is an upper bound of the valid radius.
    u_radial = _first_positive_root([1.0, 3 * dist[0], 5 * dist[1]])
    assert r[valid].max() < np.sqrt(u_radial) and valid.mean() > 0.5
