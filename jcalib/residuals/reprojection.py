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


@functools.cache
def tool_axis(model_cls: type, image_size: tuple[int, int], skew: bool, chain: Chain):
    """Signed distance (pixels, (1,)) of an observed point of the imaged tool axis from the image of the
    tool's z axis (the line through the tool frame's origin, its tip, along its z), lens distortion
    included: the image of a 3D line is curved, so the distance is taken to the foot point on the
    projected curve (three Gauss–Newton steps along the line from the foot on the chord between the
    images of the points ``±length`` metres from the tip).

    ``fn(intrinsics, *poses, obs)`` with ``obs = (pixel (2,), length (), aspect (2,))``; the chain ends
    with the tool's pose on its holder. A degenerate line (the axis along the viewing ray) gives a
    finite residual with finite derivatives (safe branch).
    """

    def fn(intrinsics, *rest):
        *poses, obs = rest
        point, length, aspect = obs
        model = _model(model_cls, image_size, skew, intrinsics, aspect)
        zero = jnp.zeros_like(length)

        def image(s):
            return model.project(chain_apply(poses, chain, jnp.stack([zero, zero, s])))

        def tangent(s):
            return jax.jvp(image, (s,), (jnp.ones_like(s),))

        a, b = image(-length), image(length)
        chord = b - a
        c2 = jnp.sum(chord * chord)
        ok = c2 > 1e-12
        t = jnp.sum((point - a) * chord) / jnp.where(ok, c2, 1.0)
        s = jnp.where(ok, (2.0 * t - 1.0) * length, zero)
        for _ in range(3):
            u, e = tangent(s)
            e2 = jnp.sum(e * e)
            s = s - jnp.where(e2 > 1e-12, jnp.sum((u - point) * e) / jnp.where(e2 > 1e-12, e2, 1.0), zero)
        u, e = tangent(s)
        n2 = jnp.sum(e * e)
        good = ok & (n2 > 1e-12)
        inv_n = 1.0 / jnp.sqrt(jnp.where(good, n2, 1.0))
        d = point - u
        cross = e[0] * d[1] - e[1] * d[0]
        return jnp.where(good, cross * inv_n, jnp.sqrt(jnp.sum(d * d) + 1e-12))[None]

    fn.__jcalib_key__ = recipe("tool_axis", model_cls, image_size, skew, chain)
    return fn
