"""Pivot calibration: the tool tip rests in one fixed point while the flange (or a tracked marker) turns.

This is what a robot's "XYZ 4-point" (KUKA) or "TCP 4-point" (ABB) method does, and what a tracked
pointer's pivot calibration does: ``N`` poses ``T_base_flange_i = (R_i, t_i)`` are recorded with the
tip touching the same point, so for every ``i``::

    R_i p_flange_tip + t_i = p_base_pivot                        (3 equations per pose)

Stacked, ``[R_i, -I] [p_flange_tip; p_base_pivot] = -t_i`` is a linear least-squares problem in the six
unknowns, solved here in closed form (:func:`pivot_calibration`). It needs **at least 3 poses whose
rotations do not all share one axis**: two poses (one relative rotation about one axis) never
determine the tip component along that axis, whatever the angle; three poses with two different
relative rotation axes give 9 equations of rank 6. The robot methods ask for 4 poses (KUKA, ABB) to
have one pose of redundancy; more poses average the noise. When all rotations are about one common
axis ``a`` (in the flange frame) the tip position along ``a`` is not observable and
:class:`jcalib.errors.NotObservableError` names that direction; when the poses barely rotate at all no
component is.

:func:`pivot_sphere_fit` is the older alternative: the flange origins ``t_i`` lie on a sphere about
the pivot whose radius is ``|p_flange_tip|``, so an algebraic (Kasa) sphere fit to the ``t_i`` gives
``p_base_pivot`` and the radius; the tip in the flange frame is then the average of
``R_i^T (p_base_pivot - t_i)``. It ignores the rotations while fitting, weights the data differently
(radial distances instead of 3-D tip residuals) and is biased for small arcs; use the algebraic
solution unless comparing methods.

Units are the unit of the input translations (metres in jcalib; the tracker data in the tests is in
millimetres). Uncertainty: the covariance is ``sigma^2 (A^T A)^-1`` with ``sigma^2`` estimated from the
residuals, i.e. it describes **sampling noise only** (repeatability of the recorded poses, play of the
tip in the divot) under an isotropic, independent noise model; it does not include model error
(robot absolute-accuracy errors, a tip that slides, tracker bias). These closed forms start the joint
solve (``jcalib.problems``), which can treat the same data with a proper noise model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.se3 import as_pose_matrices, make_pose

__all__ = [
    "MIN_PIVOT_POSES",
    "PivotResult",
    "SphereFitResult",
    "as_pose_matrices",
    "pivot_calibration",
    "pivot_sphere_fit",
    "rotation_spread",
]

#: Fewest poses the pivot methods accept (3 poses, with two distinct relative rotation axes).
MIN_PIVOT_POSES = 3

#: Default smallest RMS rotation spread (degrees) about the weakest direction; below it the tip
#: component along that direction is reported as not observable. 0.5 deg amplifies pose noise into
#: the tip by ~115x along that direction; real 4-point procedures use 30-90 deg reorientations.
DEFAULT_MIN_ROTATION_DEG = 0.5


def rotation_spread(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How much a set of rotations moves each direction of the rotated (flange) frame.

    Args:
        R: ``(N, 3, 3)`` rotations ``R_base_flange_i``.

    Returns:
        ``(spread_rad, axes)``: ``spread_rad (3,)`` ascending, the RMS over poses of
        ``|R_i u - mean_j R_j u|`` for the unit flange-frame directions ``u = axes[:, k]`` (for small
        rotations this is the RMS rotation angle, in radians, about axes perpendicular to ``u``);
        ``axes (3, 3)`` their directions in the flange frame (columns). A spread near zero for
        ``axes[:, 0]`` means every rotation is about that one axis.
    """
    D = R - R.mean(axis=0)
    M = np.einsum("nji,njk->ik", D, D) / R.shape[0]
    evals, evecs = np.linalg.eigh(M)
    return np.sqrt(np.maximum(evals, 0.0)), evecs


def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{c:.4f}" for c in v) + "]"


def check_rotations(R: np.ndarray, min_rotation_deg: float, what: str) -> None:
    """Raise NotObservableError when the rotations leave the tip (partly) undetermined."""
    n = R.shape[0]
    if n < MIN_PIVOT_POSES:
        raise NotObservableError(
            f"{what} needs at least {MIN_PIVOT_POSES} poses with two different rotation axes (4 are "
            f"usual, more average the noise); got {n}: two poses never determine the tip component "
            f"along their relative rotation axis",
            unknowns=["tip position (too few poses)"],
        )
    spread, axes = rotation_spread(R)
    limit = np.deg2rad(min_rotation_deg)
    weak = spread < limit
    if not weak.any():
        return
    R0 = R[0]
    if weak.all():
        raise NotObservableError(
            f"{what}: the poses barely rotate (largest RMS rotation spread "
            f"{np.rad2deg(spread[-1]):.3g} deg < {min_rotation_deg} deg), so no component of the tip "
            f"position is determined; reorient the flange by tens of degrees about two different axes",
            unknowns=["tip position (all components): the poses do not rotate"],
        )
    unknowns = []
    for k in np.flatnonzero(weak):
        a = axes[:, k] * (1.0 if axes[np.argmax(np.abs(axes[:, k])), k] > 0 else -1.0)
        unknowns.append(f"tip position along the common rotation axis {_fmt(a)} of the flange")
        unknowns.append(f"pivot position along {_fmt(R0 @ a)} in the base frame")
    raise NotObservableError(
        f"{what}: all rotations are (nearly) about one common axis (RMS rotation about other axes "
        f"{np.rad2deg(spread[0]):.3g} deg < {min_rotation_deg} deg): not observable: "
        + "; ".join(unknowns)
        + ". Add poses rotated about a second axis.",
        unknowns=unknowns,
    )


class PivotAccessors:
    """Derived views shared by pivot results: needs ``p_flange_tip``, ``covariance`` (6x6, tip
    then pivot) and ``residuals`` (one row per pose)."""

    @property
    def num_poses(self) -> int:
        """Number of poses used."""
        return int(self.residuals.shape[0])

    @property
    def tip_std(self) -> np.ndarray:
        """``(3,)`` standard deviations of ``p_flange_tip`` (input unit)."""
        return np.sqrt(np.diag(self.covariance)[:3])

    @property
    def pivot_std(self) -> np.ndarray:
        """``(3,)`` standard deviations of ``p_base_pivot`` (input unit)."""
        return np.sqrt(np.diag(self.covariance)[3:])

    @property
    def T_flange_tcp(self) -> np.ndarray:
        """``(4, 4)`` TCP with the flange's orientation and the tip as origin (a 3-DoF TCP)."""
        return make_pose(np.eye(3), self.p_flange_tip)


@dataclass(frozen=True)
class PivotResult(PivotAccessors):
    """Tip and pivot point from a pivot (4-point) calibration.

    Attributes:
        p_flange_tip: ``(3,)`` tool tip in the flange (or marker) frame, input length unit.
        p_base_pivot: ``(3,)`` the fixed point in the base (or tracker) frame, input length unit.
        covariance: ``(6, 6)`` covariance of ``(p_flange_tip, p_base_pivot)`` in that order,
            unit^2: ``sigma^2 (A^T A)^-1``. Sampling noise only (see the module docstring).
        residuals: ``(N, 3)`` ``R_i p_flange_tip + t_i - p_base_pivot`` in the base frame.
        rms: RMS of all residual coordinates, ``sqrt(mean(residuals**2))`` (scikit-surgery's
            "residual error"); the RMS 3-D tip distance is ``sqrt(3) * rms``.
        sigma: a-posteriori noise per coordinate, ``sqrt(sum(residuals**2) / (3 N - 6))``, or the
            ``sigma`` given to :func:`pivot_calibration`.
        rotation_spread_rad: ``(3,)`` ascending RMS rotation spread of the poses (see
            :func:`rotation_spread`); the first is the weakest direction.
    """

    p_flange_tip: np.ndarray
    p_base_pivot: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    rms: float
    sigma: float
    rotation_spread_rad: np.ndarray



def pivot_calibration(
    T_base_flange,
    sigma: float | None = None,
    min_rotation_deg: float = DEFAULT_MIN_ROTATION_DEG,
) -> PivotResult:
    """Tip in the flange frame and pivot point in the base frame from poses touching one point.

    Solves ``R_i p_flange_tip + t_i = p_base_pivot`` for all poses in the least-squares sense
    (closed form: the pivot is eliminated, ``p_flange_tip`` solves the centred 3x3 normal
    equations, then ``p_base_pivot`` is the mean tip position).

    Args:
        T_base_flange: ``(N, 4, 4)`` (or ``(N, 7)``) poses of the flange (or of a tracked marker) in
            the base (tracker) frame, ``N >= 3``, translations in any length unit.
        sigma: known noise per coordinate of the tip position (input unit), e.g. the robot's
            repeatability; ``None`` estimates it from the residuals.
        min_rotation_deg: smallest accepted RMS rotation spread about the weakest direction.

    Returns:
        :class:`PivotResult`.

    Raises:
        BadInputError: malformed poses or ``sigma``.
        NotObservableError: fewer than 3 poses, or rotations (nearly) about one axis or none.
    """
    T = as_pose_matrices(T_base_flange, "T_base_flange")
    if sigma is not None and not (np.isfinite(sigma) and sigma > 0):
        raise BadInputError(f"sigma: expected a positive noise level (input length unit) or None, got {sigma!r}")
    R, t = T[:, :3, :3], T[:, :3, 3]
    check_rotations(R, min_rotation_deg, "pivot calibration")
    n = R.shape[0]
    # Eliminate the pivot: (R_i - Rbar) x = -(t_i - tbar).
    D = R - R.mean(axis=0)
    e = t - t.mean(axis=0)
    M = np.einsum("nji,njk->ik", D, D)
    x = np.linalg.solve(M, -np.einsum("nji,nj->i", D, e))
    p_tip_base = np.einsum("nij,j->ni", R, x) + t
    p = p_tip_base.mean(axis=0)
    residuals = p_tip_base - p
    ssr = float(np.sum(residuals**2))
    rms = float(np.sqrt(ssr / (3 * n)))
    dof = 3 * n - 6
    s = float(sigma) if sigma is not None else float(np.sqrt(ssr / dof))
    # Covariance of (x, p): sigma^2 (A^T A)^-1 with A_i = [R_i, -I].
    AtA = np.zeros((6, 6))
    AtA[:3, :3] = np.einsum("nji,njk->ik", R, R)  # n I for exact rotations; data are rounded
    AtA[:3, 3:] = -R.sum(axis=0).T
    AtA[3:, :3] = -R.sum(axis=0)
    AtA[3:, 3:] = n * np.eye(3)
    cov = s**2 * np.linalg.inv(AtA)
    cov = 0.5 * (cov + cov.T)
    spread, _ = rotation_spread(R)
    return PivotResult(
        p_flange_tip=x,
        p_base_pivot=p,
        covariance=cov,
        residuals=residuals,
        rms=rms,
        sigma=s,
        rotation_spread_rad=spread,
    )


@dataclass(frozen=True)
class SphereFitResult:
    """Pivot point and tip from a sphere fitted to the flange origins.

    Attributes:
        p_base_pivot: ``(3,)`` sphere centre in the base frame (input unit).
        radius: sphere radius, the tip's distance from the flange origin (input unit).
        p_flange_tip: ``(3,)`` mean of ``R_i^T (p_base_pivot - t_i)`` (input unit).
        radial_residuals: ``(N,)`` ``|t_i - p_base_pivot| - radius`` (input unit).
        rms: RMS of ``radial_residuals``.
    """

    p_base_pivot: np.ndarray
    radius: float
    p_flange_tip: np.ndarray
    radial_residuals: np.ndarray
    rms: float


def pivot_sphere_fit(T_base_flange, min_rotation_deg: float = DEFAULT_MIN_ROTATION_DEG) -> SphereFitResult:
    """Pivot point and tip by fitting a sphere to the flange origins (the alternative method).

    Algebraic (Kasa) fit: ``|t_i - c|^2 = r^2`` is linear in ``(c, r^2 - |c|^2)``, solved by least
    squares on translations centred at their mean (for conditioning). The tip in the flange frame is
    the mean of ``R_i^T (c - t_i)``. Minimises an algebraic, not a geometric, error: biased when the
    poses cover a small arc; prefer :func:`pivot_calibration`.

    Args:
        T_base_flange: ``(N, 4, 4)`` (or ``(N, 7)``) flange poses, ``N >= 4`` for a sphere.
        min_rotation_deg: as for :func:`pivot_calibration` (the origins lie on a circle, not a
            sphere, when all rotations share one axis).

    Raises:
        NotObservableError: fewer than 4 poses, or degenerate rotations (see
            :func:`pivot_calibration`).
    """
    T = as_pose_matrices(T_base_flange, "T_base_flange")
    R, t = T[:, :3, :3], T[:, :3, 3]
    if R.shape[0] < 4:
        raise NotObservableError(
            f"pivot sphere fit needs at least 4 poses (a sphere has 4 parameters); got {R.shape[0]}",
            unknowns=["pivot position (too few poses)"],
        )
    check_rotations(R, min_rotation_deg, "pivot sphere fit")
    mean = t.mean(axis=0)
    tc = t - mean
    A = np.concatenate([2.0 * tc, np.ones((tc.shape[0], 1))], axis=1)
    b = np.sum(tc**2, axis=1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c_local = sol[:3]
    radius = float(np.sqrt(max(sol[3] + c_local @ c_local, 0.0)))
    c = c_local + mean
    tips = np.einsum("nji,nj->ni", R, c - t)
    radial = np.linalg.norm(t - c, axis=1) - radius
    return SphereFitResult(
        p_base_pivot=c,
        radius=radius,
        p_flange_tip=tips.mean(axis=0),
        radial_residuals=radial,
        rms=float(np.sqrt(np.mean(radial**2))),
    )
