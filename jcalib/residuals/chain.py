"""Pose chains: a point carried through a sequence of (possibly inverted) rigid transforms.

Every geometric residual of a cell is a chain: a target corner seen by a flange camera is
``p_cam = T_flange_cam⁻¹ · T_base_flange_i⁻¹ · T_base_board · p``, a tool tip seen by a fixed camera
``p_cam = T_base_cam⁻¹ · T_base_flange_i · T_flange_tool · 0``, a contact ``T_base_flange_i ·
T_flange_tool · 0``. A chain is a static tuple of ``(argument, inverted)``: ``argument`` is the
position of a pose among the residual's pose arguments (``wxyz_xyz`` rows), ``inverted`` whether it
enters inverted. The first element is the one nearest the output frame.

:func:`chain_jacobian` is the chain rule of a chain in closed form, for the engine's right
perturbation ``A · Exp(ω, v)`` of every pose; residuals then differentiate only what follows the
chain (the lens model) by autodiff. With reverse-mode autodiff of the whole chain (quaternion
rotations included) a camera calibration's jitted solve takes ~20 % longer
(``benchmarks/bench_linearize_floor.py``).
"""

from __future__ import annotations

import jax.numpy as jnp

from jcalib.geometry import lie

Chain = tuple[tuple[int, bool], ...]


def skew(p):
    """``[p]×`` of ``p (3,)``: ``[p]× q = p × q``."""
    zero = jnp.zeros((), p.dtype)
    return jnp.stack([zero, -p[2], p[1], p[2], zero, -p[0], -p[1], p[0], zero]).reshape(3, 3)


def chain_apply(poses, chain: Chain, p):
    """``A_1 · A_2 ⋯ A_n · p``: ``poses`` the pose rows (7,), ``p (3,)`` -> ``(3,)``."""
    for a, inverted in reversed(chain):
        T = lie.se3_inverse(poses[a]) if inverted else poses[a]
        p = lie.se3_apply(T, p)
    return p


def chain_pose(poses, chain: Chain):
    """The composed transform ``A_1 · A_2 ⋯ A_n`` as a ``(7,)`` pose row."""
    out = None
    for a, inverted in chain:
        T = lie.se3_inverse(poses[a]) if inverted else poses[a]
        out = T if out is None else lie.se3_compose(out, T)
    return out


def chain_jacobian(poses, chain: Chain, p):
    """``(p_out (3,), blocks)``: the chained point and ``∂p_out/∂δ_a (3, 6)`` for every pose argument.

    With the right perturbation ``A_j · Exp(ω, v)`` of pose ``A_j``, ``q_j`` the point on its input
    side, ``u_j = A_j q_j`` and ``L_j`` the rotation of ``A_1 ⋯ A_{j-1}``:
    ``∂p_out/∂(ω, v)_j = L_j R_j [−[q_j]×, I]``, or ``L_j [[u_j]×, −I]`` when ``A_j`` is inverted.
    ``blocks`` is a list with one ``(3, 6)`` array per entry of ``poses`` (zero for poses the chain
    does not use; a pose used twice sums its blocks). Also returns ``∂p_out/∂p = L_{n+1} (3, 3)``.
    """
    q = p
    local = []  # (pose index, rotation of A_j, 3x6 block in the frame of A_j's output)
    for a, inverted in reversed(chain):
        R, t = lie.so3_to_matrix(poses[a][:4]), poses[a][4:]
        if inverted:
            u = R.T @ (q - t)
            local.append((a, R.T, jnp.concatenate([skew(u), -jnp.eye(3, dtype=u.dtype)], axis=1)))
        else:
            u = R @ q + t
            local.append((a, R, R @ jnp.concatenate([-skew(q), jnp.eye(3, dtype=q.dtype)], axis=1)))
        q = u
    blocks = [jnp.zeros((3, 6), q.dtype) for _ in poses]
    left = jnp.eye(3, dtype=q.dtype)
    for a, R_a, block in reversed(local):  # output side first
        blocks[a] = blocks[a] + left @ block
        left = left @ R_a
    return q, blocks, left
