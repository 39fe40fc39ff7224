"""Uncertain pose chains: products of poses with their joint covariance, and points moved along them.

:func:`compose_pose_chains` multiplies poses that each carry a right-perturbation covariance
(``T_true = T . Exp(d)``, ``d = (rx, ry, rz, tx, ty, tz)``, rad and m) and keeps the correlations
between products that share a factor: the ``pose_covariance`` that
:func:`jcalib.init.triangulation.triangulate_points` needs when views share a hand-eye transform or a
robot pose.

**RoboCalib's chain** (:func:`point_in_frame`): a point triangulated in a camera frame, moved into
the target frame (RoboCalib's *Phys3D*, via ``T_cam_target``), the flange frame (*Hand3D*, via
``T_flange_cam``) or the robot base (via ``T_base_flange @ T_flange_cam``), each transform with an
optional covariance, propagated with JAX Jacobians. Linear propagation: fine while the errors are
small against the geometry.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.lie import se3_exp, se3_to_matrix
from jcalib.geometry.se3 import adjoint, as_pose_matrices, invert
from jcalib.init.triangulation import TriangulatedPoint

__all__ = ["CHAIN_FRAMES", "PointInFrame", "compose_pose_chains", "point_in_frame"]

#: Frames :func:`point_in_frame` can express a camera-frame point in (RoboCalib: Phys3D = target,
#: Hand3D = flange).
CHAIN_FRAMES = ("cam", "target", "flange", "base")


def compose_pose_chains(
    sources: Mapping[str, tuple[np.ndarray, np.ndarray | None]],
    chains: Sequence[Sequence[str]],
) -> tuple[np.ndarray, np.ndarray]:
    """Products of uncertain poses and the joint covariance of the products.

    Each chain is a list of source names multiplied left to right; a leading ``~`` takes the
    inverse, e.g. ``["T_base_flange@s0", "T_flange_cam0"]`` gives ``T_base_cam0`` at station s0
    and ``["~T_base_board", "T_base_cam1"]`` gives ``T_board_cam1``. Every source has a
    right-perturbation covariance (``T_true = T . Exp(d)``, ``d = (rx, ry, rz, tx, ty, tz)``, rad
    and m; None = exact); sources are independent of each other. A source used in several chains
    makes them correlated, which the joint covariance keeps (what
    :func:`jcalib.init.triangulation.triangulate_point` needs as
    ``pose_covariance`` when views share a hand-eye transform or a robot pose).

    Linear propagation through adjoints: perturbing factor ``F_j`` of ``F_1 ... F_n`` on the right
    by ``e`` perturbs the product on the right by ``Ad((F_{j+1} ... F_n)^-1) e``; an inverted source
    ``A^-1`` is perturbed by ``-Ad(A) d``.

    Args:
        sources: name -> ``((4, 4) pose, (6, 6) covariance or None)``, metres.
        chains: K chains of names (``~name`` for an inverse). An empty chain is the identity.

    Returns:
        ``(T (K, 4, 4), covariance (6K, 6K))`` over the products' right-perturbation tangents.

    Raises:
        BadInputError: an unknown source name, a malformed pose or covariance.
    """
    mats: dict[str, np.ndarray] = {}
    covs: dict[str, np.ndarray | None] = {}
    for name, value in sources.items():
        try:
            T, C = value
        except (TypeError, ValueError):
            raise BadInputError(f"sources[{name!r}]: expected (pose (4, 4), covariance (6, 6) or None)") from None
        mats[name] = as_pose_matrices(np.asarray(T, np.float64)[None], f"sources[{name!r}]")[0]
        if C is not None:
            C = np.asarray(C, np.float64)
            if C.shape != (6, 6) or not np.isfinite(C).all():
                raise BadInputError(f"sources[{name!r}]: expected a finite (6, 6) covariance, got shape {C.shape}")
        covs[name] = C
    uncertain = [s for s in mats if covs[s] is not None]
    col = {s: 6 * i for i, s in enumerate(uncertain)}
    K = len(chains)
    Ts = np.zeros((K, 4, 4))
    J = np.zeros((6 * K, 6 * len(uncertain)))
    for k, chain in enumerate(chains):
        factors = []
        for item in chain:
            inv = item.startswith("~")
            name = item[1:] if inv else item
            if name not in mats:
                raise BadInputError(f"chains[{k}]: unknown pose {name!r}; have {', '.join(mats) or 'none'}")
            factors.append((name, inv, invert(mats[name]) if inv else mats[name]))
        T = np.eye(4)
        for *_, F in factors:
            T = T @ F
        Ts[k] = T
        suffix = np.eye(4)
        for name, inv, F in reversed(factors):
            if covs[name] is not None:
                A = adjoint(invert(suffix))
                if inv:
                    A = -A @ adjoint(mats[name])
                J[6 * k : 6 * k + 6, col[name] : col[name] + 6] += A
            suffix = F @ suffix
    C_src = np.zeros((6 * len(uncertain),) * 2)
    for s in uncertain:
        C_src[col[s] : col[s] + 6, col[s] : col[s] + 6] = covs[s]
    cov = J @ C_src @ J.T
    return Ts, 0.5 * (cov + cov.T)


@dataclass(frozen=True)
class PointInFrame:
    """A point moved along RoboCalib's chain, with its covariance.

    Attributes:
        position: ``(3,)`` metres, in ``frame``.
        covariance: ``(3, 3)`` m^2: the point's own covariance and those of the transforms used,
            propagated linearly (taken as independent of each other).
        frame: ``"cam"``, ``"target"`` (Phys3D), ``"flange"`` (Hand3D) or ``"base"``.
    """

    position: np.ndarray
    covariance: np.ndarray
    frame: str

    @property
    def std(self) -> np.ndarray:
        """``(3,)`` standard deviations along the frame's axes, m."""
        return np.sqrt(np.diag(self.covariance))


def _perturbed(T, d):
    """``T . Exp(d)`` as a 4x4 matrix (T (4, 4), d (6,) rad and m)."""
    return T @ se3_to_matrix(se3_exp(d))


@jax.jit
def _chain_point(p, T_cam_target, T_flange_cam, T_base_flange):
    """All four frames at once (one compilation): ``(4, 3)`` points and their Jacobians."""

    def f(p, d_ct, d_fc, d_bf):
        ph = jnp.concatenate([p, jnp.ones(1)])
        T = _perturbed(T_cam_target, d_ct)
        target = T[:3, :3].T @ (p - T[:3, 3])
        T_fc = _perturbed(T_flange_cam, d_fc)
        flange = (T_fc @ ph)[:3]
        base = (_perturbed(T_base_flange, d_bf) @ T_fc @ ph)[:3]
        return jnp.stack([p, target, flange, base])

    z = jnp.zeros(6)
    return f(p, z, z, z), jax.jacfwd(f, argnums=(0, 1, 2, 3))(p, z, z, z)


def point_in_frame(
    point,
    frame: str,
    *,
    T_cam_target=None,
    T_flange_cam=None,
    T_base_flange=None,
    T_cam_target_covariance=None,
    T_flange_cam_covariance=None,
    T_base_flange_covariance=None,
) -> PointInFrame:
    """Move a camera-frame point along RoboCalib's chain: camera, target (Phys3D), flange (Hand3D), base.

    ``p_target = T_cam_target^-1 p_cam``, ``p_flange = T_flange_cam p_cam``,
    ``p_base = T_base_flange T_flange_cam p_cam``. The covariance adds the point's own covariance
    and each used transform's right-perturbation covariance (``(rx, ry, rz, tx, ty, tz)``, rad and
    m), through JAX Jacobians; all are taken as independent. Do not give a transform's covariance
    here if it was already part of the point's covariance (e.g. the hand-eye transform was in the
    triangulation's ``pose_covariance``): that would count it twice.

    Args:
        point: a :class:`TriangulatedPoint` triangulated in the camera frame (its ``p_base``), or
            ``(p_cam (3,), covariance (3, 3) or None)``, metres.
        frame: one of :data:`CHAIN_FRAMES`.
        T_cam_target: ``(4, 4)`` the target (e.g. a calibration plate) in the camera; for "target".
        T_flange_cam: ``(4, 4)`` hand-eye transform; for "flange" and "base".
        T_base_flange: ``(4, 4)`` robot pose at the time of the images; for "base".
        T_cam_target_covariance, T_flange_cam_covariance, T_base_flange_covariance: ``(6, 6)`` or None.

    Returns:
        :class:`PointInFrame`.

    Raises:
        BadInputError: unknown frame, a transform the frame needs is missing, malformed input.
    """
    if frame not in CHAIN_FRAMES:
        raise BadInputError(f"frame: expected one of {', '.join(CHAIN_FRAMES)}, got {frame!r}")
    if isinstance(point, TriangulatedPoint):
        p, C = point.p_base, point.covariance
    else:
        try:
            p, C = point
        except (TypeError, ValueError):
            raise BadInputError(
                f"point: expected a TriangulatedPoint or (p_cam, covariance), got {type(point).__name__}"
            ) from None
    p = np.asarray(p, np.float64)
    C = np.zeros((3, 3)) if C is None else np.asarray(C, np.float64)
    if p.shape != (3,) or C.shape != (3, 3) or not (np.isfinite(p).all() and np.isfinite(C).all()):
        raise BadInputError(f"point: expected a finite p_cam (3,) and covariance (3, 3), got {p.shape}, {C.shape}")
    needed = {"cam": (), "target": ("T_cam_target",), "flange": ("T_flange_cam",),
              "base": ("T_flange_cam", "T_base_flange")}[frame]  # fmt: skip
    given = {"T_cam_target": T_cam_target, "T_flange_cam": T_flange_cam, "T_base_flange": T_base_flange}
    covs = {"T_cam_target": T_cam_target_covariance, "T_flange_cam": T_flange_cam_covariance,
            "T_base_flange": T_base_flange_covariance}  # fmt: skip
    mats = {}
    for name, T in given.items():
        if T is None:
            if name in needed:
                raise BadInputError(f"{name}: frame {frame!r} needs it (the chain is camera -> {frame}), got None")
            mats[name] = np.eye(4)
        else:
            mats[name] = as_pose_matrices(np.asarray(T, np.float64)[None], name)[0]
        c = covs[name]
        if c is not None:
            c = np.asarray(c, np.float64)
            if c.shape != (6, 6) or not np.isfinite(c).all():
                raise BadInputError(f"{name}_covariance: expected a finite (6, 6) covariance, got shape {c.shape}")
        covs[name] = c
    k = CHAIN_FRAMES.index(frame)
    out, (Jp, *Jd) = _chain_point(jnp.asarray(p), *(jnp.asarray(mats[n]) for n in given))
    Jp = np.asarray(Jp)[k]
    cov = Jp @ C @ Jp.T
    for name, J in zip(given, Jd, strict=True):
        if covs[name] is not None and name in needed:
            J = np.asarray(J)[k]
            cov = cov + J @ covs[name] @ J.T
    return PointInFrame(np.asarray(out)[k], 0.5 * (cov + cov.T), frame)
