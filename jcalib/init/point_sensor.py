"""Closed-form start of a fixed 3-D point sensor and a tool tip on a flange (a laser tracker and its reflector).

At station ``i`` the sensor measures the tip ``p_s_i = R (R_i p + t_i) + t`` where ``[R | t] = T_sensor_base``
(unknown), ``[R_i | t_i] = T_base_flange_i`` (known) and ``p`` the tip in the flange frame (unknown). With
``K[k, a, b] = R[k, a] p[b]`` each coordinate ``k`` is linear in 13 unknowns,
``p_s_i[k] = <K[k], R_i> + <R[k, :], t_i> + t[k]``: three independent least-squares problems. ``R`` is then
projected onto the nearest rotation and ``p = Σ_k R[k, a] K[k, a, :]`` (averaged over ``a``; the columns
of ``R`` are unit vectors). The joint solve refines the result.
"""

from __future__ import annotations

import numpy as np

from jcalib.errors import NotObservableError

__all__ = ["point_sensor_start"]

#: Fewest stations: 13 unknowns per coordinate.
MIN_STATIONS = 13


def point_sensor_start(T_base_flange: np.ndarray, p_sensor: np.ndarray, what: str = "the point sensor"
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``(T_base_sensor (4, 4), p_flange_tip (3,))`` from flange poses and measured tip positions (m).

    Args:
        T_base_flange: ``(N, 4, 4)`` flange poses, m.
        p_sensor: ``(N, 3)`` the tip measured in the sensor frame, m.
        what: names the sensor and tool in errors.

    Raises:
        NotObservableError: fewer than :data:`MIN_STATIONS` stations, or flange rotations too alike to
            separate the tip from the sensor's pose (rank-deficient system).
    """
    F = np.asarray(T_base_flange, np.float64)
    P = np.asarray(p_sensor, np.float64)
    n = F.shape[0]
    if n < MIN_STATIONS:
        raise NotObservableError(f"{what}: {n} stations; a point sensor's pose and the tip's position start from at "
                                 f"least {MIN_STATIONS} stations with varied flange orientations", [what])
    A = np.concatenate([F[:, :3, :3].reshape(n, 9), F[:, :3, 3], np.ones((n, 1))], axis=1)  # (N, 13)
    s = np.linalg.svd(A, compute_uv=False)
    if s[-1] < 1e-9 * s[0]:
        raise NotObservableError(f"{what}: the flange orientations do not vary enough to separate the tip from the "
                                 "sensor's pose; rotate the flange about at least two axes between stations", [what])
    X = np.linalg.lstsq(A, P, rcond=None)[0]  # (13, 3): column k holds K[k] (9), R[k, :] (3), t[k]
    K = X[:9].T.reshape(3, 3, 3)
    U, _, Vt = np.linalg.svd(X[9:12].T)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    t = X[12]
    p = np.einsum("ka,kab->b", R, K) / 3.0
    T_sensor_base = np.eye(4)
    T_sensor_base[:3, :3], T_sensor_base[:3, 3] = R, t
    return np.linalg.inv(T_sensor_base), p
