"""Synthetic test problems for the engine (inline pinhole + k1, k2; no dependency on geometry/)."""

from __future__ import annotations

import jax.numpy as jnp
import jaxlie
import numpy as np

from jcalib.solve import SE3, Euclidean, FactorGroup, Problem, Variable
from jcalib.solve.manifolds import quat_rotate

INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2")
TRUE_INTRINSICS = np.array([800.0, 790.0, 640.0, 480.0, -0.2, 0.05])


def project(K, T_cam_target, obs):
    """Pinhole with radial k1, k2. ``K (6,)``, ``T_cam_target (7,) wxyz_xyz``, obs = (p (3,) m, uv (2,) px)."""
    p_target, uv = obs
    p = quat_rotate(T_cam_target[:4], p_target) + T_cam_target[4:]
    z = jnp.where(p[2] > 1e-6, p[2], 1.0)
    x, y = p[0] / z, p[1] / z
    r2 = x * x + y * y
    f = 1.0 + K[4] * r2 + K[5] * r2 * r2
    return jnp.stack([K[0] * x * f + K[2], K[1] * y * f + K[3]]) - uv


def board_points(cols=9, rows=6, square=0.03):
    g = np.stack(np.meshgrid(np.arange(cols), np.arange(rows), indexing="xy"), -1).reshape(-1, 2) * square
    g = g - g.mean(0)
    return np.concatenate([g, np.zeros((g.shape[0], 1))], 1)


def random_poses(num_views, rng):
    poses = []
    for _ in range(num_views):
        w = rng.uniform(-0.5, 0.5, 3)
        t = np.array([rng.uniform(-0.12, 0.12), rng.uniform(-0.08, 0.08), rng.uniform(0.45, 0.75)])
        T = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.exp(jnp.asarray(w)), jnp.asarray(t))
        poses.append(np.asarray(T.wxyz_xyz))
    return np.stack(poses)


def pixels(K, poses, pts):
    out = []
    for T in poses:
        for p in pts:
            out.append(np.asarray(project(jnp.asarray(K), jnp.asarray(T), (jnp.asarray(p), jnp.zeros(2)))))
    return np.stack(out)


def calibration_data(num_views=6, noise_px=0.1, seed=0, cols=9, rows=6):
    """Ground truth and noisy observations of a mini camera calibration."""
    rng = np.random.default_rng(seed)
    pts = board_points(cols, rows)
    poses = random_poses(num_views, rng)
    import jax

    proj = jax.jit(jax.vmap(project, in_axes=(None, 0, 0)))
    view_index = np.repeat(np.arange(num_views), len(pts))
    p_all = np.tile(pts, (num_views, 1))
    uv = np.asarray(proj(jnp.asarray(TRUE_INTRINSICS), jnp.asarray(poses[view_index]),
                         (jnp.asarray(p_all), jnp.zeros((len(p_all), 2)))))
    uv_noisy = uv + noise_px * rng.standard_normal(uv.shape)
    return dict(K=TRUE_INTRINSICS.copy(), poses=poses, points=p_all, view_index=view_index, uv=uv_noisy,
                uv_clean=uv, rng=rng)


def perturbed_start(data, rng, k_scale=1.0, pose_rot=0.03, pose_trans=0.01):
    K0 = data["K"] * np.array([1.03, 0.97, 1.0, 1.0, 0.0, 0.0]) + np.array([0, 0, 8.0, -6.0, 0, 0]) * k_scale
    P0 = []
    for T in data["poses"]:
        d = np.concatenate([rng.normal(0, pose_rot, 3), rng.normal(0, pose_trans, 3)])
        P0.append(np.asarray(SE3().retract(jnp.asarray(T), jnp.asarray(d))))
    return K0, np.stack(P0)


def calibration_problem(data, K0, P0, noise_px=0.1, K_fixed=False, sqrt_weight=None, loss=None,
                        eliminate=True, pose_fixed=False):
    K = Variable("intrinsics", Euclidean(6), K0, fixed=K_fixed, coord_names=INTRINSIC_NAMES)
    poses = Variable("T_cam_target", SE3(), P0, fixed=pose_fixed, eliminate=eliminate, entry_label="view {i} pose")
    f = FactorGroup(
        "reprojection", project, ("intrinsics", "T_cam_target"),
        (np.zeros(len(data["view_index"]), np.int32), data["view_index"]),
        (data["points"], data["uv"]), sigma=noise_px, sqrt_weight=sqrt_weight, loss=loss,
    )
    return Problem([K, poses], [f])


def exp_curve(theta, obs):
    """y = a·exp(b·t) + c; theta = (a, b, c); obs = (t, y)."""
    t, y = obs
    return jnp.atleast_1d(theta[0] * jnp.exp(theta[1] * t) + theta[2] - y)
