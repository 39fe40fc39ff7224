"""Reprojection residuals: target corners, tool tips and tool axes seen by a camera through a pose chain.

One function object per configuration (lens model class, image size, skew, chain), cached, so
problems built from new data share one traced and compiled solver.

Observations carry ``aspect = (flag, ratio)``: with flag 1 the model's ``fy`` is replaced by
``fx / ratio`` (OpenCV's ``CALIB_FIX_ASPECT_RATIO``), the same tie in every residual of that camera.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from jcalib.geometry.cameras import zoom
from jcalib.residuals.chain import Chain, chain_apply, chain_jacobian


def recipe(kind: str, *args) -> str:
    """A residual function's process-independent name (``fn.__jcalib_key__``): its factory and arguments,
    classes by module and qualified name (:mod:`jcalib.solve.traced` keys compiled solves by it)."""
    return repr((kind,) + tuple(f"{a.__module__}.{a.__qualname__}" if isinstance(a, type) else a for a in args))


def _model(model_cls: type, image_size: tuple[int, int], skew: bool, intrinsics, aspect):
    fy = jnp.where(aspect[0] > 0.5, intrinsics[0] / aspect[1], intrinsics[1])
    return model_cls.from_params(image_size, intrinsics.at[1].set(fy), skew=skew)


@functools.cache
def reprojection(model_cls: type, image_size: tuple[int, int], skew: bool, chain: Chain):
    """``(fn, jacobian)`` of a point reprojection: ``project(chain · p) − pixel`` (pixels, (2,)).

    ``fn(intrinsics, *poses, obs)`` with ``obs = (p (3,), pixel (2,), aspect (2,))``: ``p`` in the
    chain's input frame (a target corner, or ``0`` for the origin of a tool frame: its tip).
    ``jacobian`` is the engine's hand-derived linearisation (``FactorGroup.jacobian``): autodiff
    through the lens model only, the poses by :func:`jcalib.residuals.chain.chain_jacobian`.
    """

    def fn(intrinsics, *rest):
        *poses, obs = rest
        p, pixel, aspect = obs
        model = _model(model_cls, image_size, skew, intrinsics, aspect)
        return model.project(chain_apply(poses, chain, p)) - pixel

    def project(p_cam, intrinsics, obs):
        _, pixel, aspect = obs
        r = _model(model_cls, image_size, skew, intrinsics, aspect).project(p_cam) - pixel
        return r, r

    def jacobian(intrinsics, *rest):
        *poses, obs = rest
        p_cam, blocks, _ = chain_jacobian(poses, chain, obs[0])
        (J_cam, J_intr), r = jax.jacrev(project, argnums=(0, 1), has_aux=True)(p_cam, intrinsics, obs)
        return r, (J_intr, *[J_cam @ b for b in blocks])

    fn.__jcalib_key__ = jacobian.__jcalib_key__ = recipe("reprojection", model_cls, image_size, skew, chain)
    return fn, jacobian


@functools.cache
def warped_reprojection(model_cls: type, image_size: tuple[int, int], skew: bool, chain: Chain):
    """``(fn, jacobian)`` of a target corner's reprojection on a warped (non-flat) board.

    The board's warp (mrcal's parabolic definition, ``calobject_warp``) moves each corner along the
    target's z: ``z = c0 (1 − xr²) + c1 (1 − yr²)``, ``xr, yr`` the corner's position normalised to
    ``[−1, 1]`` over the extent of the target's points. ``fn(intrinsics, *poses, warp, obs)`` with
    ``warp = (c0, c1)`` metres and ``obs = (p (3,), pixel (2,), aspect (2,), bow (2,))``,
    ``bow = (1 − xr², 1 − yr²)`` precomputed per corner. ``jacobian`` as :func:`reprojection`'s,
    with ``∂/∂warp = J_cam · L e_z · bowᵀ`` (``L`` the chain's rotation).
    """

    def warped(p, warp, bow):
        return p.at[2].add(jnp.dot(warp, bow))

    def fn(intrinsics, *rest):
        *poses, warp, obs = rest
        p, pixel, aspect, bow = obs
        model = _model(model_cls, image_size, skew, intrinsics, aspect)
        return model.project(chain_apply(poses, chain, warped(p, warp, bow))) - pixel

    def project(p_cam, intrinsics, obs):
        _, pixel, aspect, _ = obs
        r = _model(model_cls, image_size, skew, intrinsics, aspect).project(p_cam) - pixel
        return r, r

    def jacobian(intrinsics, *rest):
        *poses, warp, obs = rest
        bow = obs[3]
        p_cam, blocks, left = chain_jacobian(poses, chain, warped(obs[0], warp, bow))
        (J_cam, J_intr), r = jax.jacrev(project, argnums=(0, 1), has_aux=True)(p_cam, intrinsics, obs)
        J_warp = (J_cam @ left[:, 2])[:, None] * bow[None, :]
        return r, (J_intr, *[J_cam @ b for b in blocks], J_warp)

    fn.__jcalib_key__ = jacobian.__jcalib_key__ = recipe("warped_reprojection", model_cls, image_size, skew, chain)
    return fn, jacobian


def _axis_foot(model, poses, chain: Chain, point, length):
    """Foot of ``point`` on the image of the tool's z axis: ``(s, u, e, ok)``, ``u`` the image of the axis
    point at ``s`` metres from the tip, ``e = du/ds`` and ``ok`` whether the chord was not degenerate."""
    zero = jnp.zeros_like(length)
    # the chain is affine in its input point: the axis in the camera frame is tip + s · z
    tip = chain_apply(poses, chain, jnp.stack([zero, zero, zero]))
    z = chain_apply(poses, chain, jnp.stack([zero, zero, jnp.ones_like(length)])) - tip

    def tangent(s):
        return jax.jvp(lambda t: model.project(tip + t * z), (s,), (jnp.ones_like(s),))

    a, b = model.project(tip - length * z), model.project(tip + length * z)
    chord = b - a
    c2 = jnp.sum(chord * chord)
    ok = c2 > 1e-12
    t = jnp.sum((point - a) * chord) / jnp.where(ok, c2, 1.0)
    s = jnp.where(ok, (2.0 * t - 1.0) * length, zero)

    def step(_, s):
        u, e = tangent(s)
        e2 = jnp.sum(e * e)
        return s - jnp.where(e2 > 1e-12, jnp.sum((u - point) * e) / jnp.where(e2 > 1e-12, e2, 1.0), zero)

    s = jax.lax.fori_loop(0, 3, step, s)
    u, e = tangent(s)
    return s, u, e, ok


def _axis_distance(point, u, e, ok):
    """``(r, n)``: the signed distance ``r = n · (point − u)`` and its unit direction ``n`` (the curve's
    normal at the foot; along ``point − u`` in the degenerate branch)."""
    n2 = jnp.sum(e * e)
    good = ok & (n2 > 1e-12)
    inv_n = 1.0 / jnp.sqrt(jnp.where(good, n2, 1.0))
    d = point - u
    far = jnp.sqrt(jnp.sum(d * d) + 1e-12)
    normal = jnp.stack([-e[1], e[0]]) * inv_n
    n = jnp.where(good, normal, d / far)
    return jnp.where(good, jnp.dot(normal, d), far), n


@functools.cache
def tool_axis(model_cls: type, image_size: tuple[int, int], skew: bool, chain: Chain):
    """``(fn, jacobian)`` of the signed distance (pixels, (1,)) of an observed point of the imaged tool axis
    from the image of the tool's z axis (the line through the tool frame's origin, its tip, along its z),
    lens distortion included: the image of a 3D line is curved, so the distance is taken to the foot
    point on the projected curve (three Gauss–Newton steps along the line from the foot on the chord
    between the images of the points ``±length`` metres from the tip).

    ``fn(intrinsics, *poses, obs)`` with ``obs = (pixel (2,), length (), aspect (2,))``; the chain ends
    with the tool's pose on its holder. A degenerate line (the axis along the viewing ray) gives a
    finite residual with finite derivatives (safe branch).

    ``jacobian`` is the envelope theorem's: at the foot the distance is stationary along the curve and
    its normal turns orthogonally to itself, so ``∂r/∂θ = −n · ∂u/∂θ`` at a fixed foot ``s``: one point
    reprojection's derivative (autodiff through the lens model, the poses by
    :func:`jcalib.residuals.chain.chain_jacobian`) instead of autodiff through the foot's iterations,
    which made this factor three quarters of a whole cell's compiled program. It equals autodiff of
    ``fn`` up to the foot's convergence (tested).
    """

    def fn(intrinsics, *rest):
        *poses, obs = rest
        point, length, aspect = obs
        model = _model(model_cls, image_size, skew, intrinsics, aspect)
        _, u, e, ok = _axis_foot(model, poses, chain, point, length)
        return _axis_distance(point, u, e, ok)[0][None]

    def jacobian(intrinsics, *rest):
        *poses, obs = rest
        point, length, aspect = obs
        s, u, e, ok = _axis_foot(_model(model_cls, image_size, skew, intrinsics, aspect), poses, chain, point, length)
        r, n = _axis_distance(point, u, e, ok)
        p_cam, blocks, _ = chain_jacobian(poses, chain, jnp.stack([jnp.zeros_like(s), jnp.zeros_like(s), s]))

        def along_n(p, k):
            return jnp.dot(n, _model(model_cls, image_size, skew, k, aspect).project(p))

        g_cam, g_intr = jax.grad(along_n, argnums=(0, 1))(p_cam, intrinsics)
        return r[None], (-g_intr[None], *[-(g_cam @ b)[None] for b in blocks])

    fn.__jcalib_key__ = jacobian.__jcalib_key__ = recipe("tool_axis", model_cls, image_size, skew, chain)
    return fn, jacobian


@functools.cache
def zoom_reprojection(model_cls: type, image_size: tuple[int, int], skew: bool, chain: Chain):
    """``(fn, jacobian)`` of a target corner's reprojection by a camera with a zoom (focus) lens
    (:mod:`jcalib.geometry.cameras.zoom`): the intrinsics and the camera frame's axial shift ``d`` are
    B-spline functions of the lens setting, ``p_cam(u) = chain · p − d(u) e_z``.

    ``fn(intrinsics, *poses, lens, obs)`` with ``obs = (p (3,), pixel (2,), aspect (2,), basis (nb,))``:
    ``intrinsics`` the camera at the lowest calibrated setting, ``lens`` the other control points and
    ``basis`` the spline basis at the observation's setting. ``jacobian`` as :func:`reprojection`'s (the
    shift does not depend on the poses), with ``∂/∂lens`` by autodiff through the lens functions.
    """

    def project(p_cam, intrinsics, lens, obs):
        _, pixel, aspect, b = obs
        params, shift = zoom.lens_at(intrinsics, lens, b)
        model = _model(model_cls, image_size, skew, params, aspect)
        r = model.project(p_cam - jnp.stack([jnp.zeros_like(shift), jnp.zeros_like(shift), shift])) - pixel
        return r, r

    def fn(intrinsics, *rest):
        *poses, lens, obs = rest
        return project(chain_apply(poses, chain, obs[0]), intrinsics, lens, obs)[0]

    def jacobian(intrinsics, *rest):
        *poses, lens, obs = rest
        p_cam, blocks, _ = chain_jacobian(poses, chain, obs[0])
        (J_cam, J_intr, J_lens), r = jax.jacrev(project, argnums=(0, 1, 2), has_aux=True)(p_cam, intrinsics, lens, obs)
        return r, (J_intr, *[J_cam @ b for b in blocks], J_lens)

    fn.__jcalib_key__ = jacobian.__jcalib_key__ = recipe("zoom_reprojection", model_cls, image_size, skew, chain)
    return fn, jacobian
