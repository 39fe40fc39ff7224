"""Hand-eye stations: checked poses, the motion analysis before a closed form, the fit after it.

Before a hand-eye closed form (:mod:`jcalib.init.handeye`, :mod:`jcalib.init.robot_world`) runs,
:func:`analyse_motion` looks at the relative rotations of the robot stations and
:func:`check_observable` raises :class:`jcalib.errors.NotObservableError` naming what the data cannot
determine (too few stations, pure translations, rotations small against the stated noise, one common
rotation axis, planar SCARA-like motion); :func:`checked_stations` does both on validated poses.
After it, :func:`solution_diagnostics` says how well the solution fits the stations.

Relative motions pair the stations ``i < j`` (``"all"``, as ``cv2.calibrateHandEye``) or ``j = i + 1``
(``"consecutive"``). Units: translations in the unit of the inputs (metres in jcalib), angles in the
names' unit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.se3 import check_poses, rotvec

__all__ = [
    "HandEyeDiagnostics",
    "Mount",
    "MotionDiagnostics",
    "Pairs",
    "analyse_motion",
    "check_mount",
    "check_observable",
    "checked_stations",
    "fmt_axis",
    "pair_indices",
    "solution_diagnostics",
]

Mount = Literal["flange", "base"]
Pairs = Literal["all", "consecutive"]


def check_mount(mount: str) -> None:
    """Refuse a mount other than ``"flange"`` (eye-in-hand) or ``"base"`` (eye-to-hand)."""
    if mount not in ("flange", "base"):
        raise BadInputError(
            f"mount: expected 'flange' (camera on the flange, eye-in-hand) or 'base' (camera fixed, "
            f"eye-to-hand), got {mount!r}"
        )


def pair_indices(n: int, pairs: str) -> tuple[np.ndarray, np.ndarray]:
    """Station indices ``(i, j)`` of the relative motions: every ``i < j`` (``"all"``) or ``j = i + 1``."""
    if pairs == "all":
        i, j = np.triu_indices(n, k=1)
    elif pairs == "consecutive":
        i = np.arange(n - 1)
        j = i + 1
    else:
        raise BadInputError(f"pairs: expected 'all' or 'consecutive', got {pairs!r}")
    return i.astype(np.int64), j.astype(np.int64)


def _rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (deg) of ``Ra^T Rb`` (batched), accurate for small angles."""
    return np.degrees(np.linalg.norm(rotvec(np.swapaxes(Ra, -1, -2) @ Rb), axis=-1))


# ---------------------------------------------------------------------------------------------
# degeneracy analysis
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MotionDiagnostics:
    """How well a set of robot stations determines a hand-eye transform.

    Attributes:
        axes: (K, 3) unit rotation axis of each relative motion, in ``frame`` (sign: largest
            component positive; zero for motions without rotation).
        axes_base: (K, 3) the same axes in the base frame.
        angles_deg: (K,) rotation angle of each relative motion, degrees, in [0, 180].
        pairs: (K, 2) station indices ``(i, j)`` of each motion.
        singular_values_deg: (3,) singular values of the stacked rotation vectors (K, 3), degrees:
            how strongly each direction of the rotation axes is excited.
        axis_spread_deg: largest angle between the axis of a motion that rotates significantly
            (above the noise threshold) and the dominant axis, degrees (0 for one-axis motion).
        dominant_axis: (3,) the dominant rotation axis in ``frame`` (largest component positive).
        rank: number of rotation-axis directions excited above the noise threshold (0..3); a
            hand-eye rotation needs >= 2.
        threshold_deg: the singular-value threshold used for ``rank``, degrees.
        planar: True when every rotation is about the base z axis (SCARA-like motion).
        num_stations: N.
        frame: ``"flange"`` (eye-in-hand) or ``"base"`` (eye-to-hand): the frame of ``axes``.
        warnings: human-readable remarks about weak (but not degenerate) motion.
    """

    axes: np.ndarray
    axes_base: np.ndarray
    angles_deg: np.ndarray
    pairs: np.ndarray
    singular_values_deg: np.ndarray
    axis_spread_deg: float
    dominant_axis: np.ndarray
    rank: int
    threshold_deg: float
    planar: bool
    num_stations: int
    frame: str
    warnings: tuple[str, ...]


def _sign_normalise_axes(v: np.ndarray) -> np.ndarray:
    idx = np.argmax(np.abs(v), axis=-1)
    s = np.take_along_axis(v, idx[..., None], axis=-1)
    return np.where(s < 0.0, -v, v)


def fmt_axis(a: np.ndarray) -> str:
    """A unit axis for messages: ``[0.707, 0, -0.707]``."""
    vals = []
    for x in a:
        r = round(float(x), 3)
        r = 0.0 if r == 0.0 else r
        vals.append(f"{r:g}")
    return "[" + ", ".join(vals) + "]"


def analyse_motion(
    T_base_flange,
    *,
    frame: Mount = "flange",
    pairs: Pairs = "all",
    rotation_noise_deg: float = 0.02,
) -> MotionDiagnostics:
    """Analyse the relative rotations of a set of robot stations for hand-eye observability.

    The rotation vectors ``r_k`` (axis * angle) of the relative motions are stacked into a (K, 3)
    matrix; its singular values say how many axis directions the motion excites. A direction
    counts when its singular value exceeds ``3 * sqrt(2) * sigma * sqrt(K)`` with ``sigma`` the
    stated per-pose rotation noise (a relative motion combines two poses): below that, what looks
    like a second axis can be noise. ``rank`` 0 means no usable rotation (pure translation, or
    rotations small against the noise); 1 means all axes parallel (one-axis motion).

    Args:
        T_base_flange: (N, 4, 4) flange poses in the base frame, metres.
        frame: ``"flange"`` for eye-in-hand (axes of ``T_base_flange_j^-1 T_base_flange_i``, in the
            flange frame) or ``"base"`` for eye-to-hand (axes of ``T_base_flange_j T_base_flange_i^-1``,
            in the base frame).
        pairs: which station pairs make the motions: ``"all"`` (i < j, as OpenCV) or ``"consecutive"``.
        rotation_noise_deg: 1-sigma rotation noise of one pose (robot and camera combined), degrees,
            per axis. Zero leaves only a numerical floor (1e-9 rad).

    Returns:
        :class:`MotionDiagnostics`.
    """
    if not np.isfinite(rotation_noise_deg) or rotation_noise_deg < 0.0:
        raise BadInputError(f"rotation_noise_deg: expected a finite value >= 0, got {rotation_noise_deg!r}")
    if frame not in ("flange", "base"):
        raise BadInputError(f"frame: expected 'flange' or 'base', got {frame!r}")
    T = check_poses(T_base_flange, "T_base_flange")
    n = len(T)
    i, j = pair_indices(n, pairs)
    R = T[:, :3, :3]
    R_flange = np.swapaxes(R[j], -1, -2) @ R[i]  # rotation of T_base_flange_j^-1 T_base_flange_i
    r_flange = rotvec(R_flange)
    r_base = np.einsum("kab,kb->ka", R[j], r_flange)  # same axis expressed in the base frame
    r = r_flange if frame == "flange" else r_base
    K = len(r)
    angles = np.linalg.norm(r, axis=-1)

    def unit(v: np.ndarray) -> np.ndarray:
        nrm = np.linalg.norm(v, axis=-1, keepdims=True)
        return _sign_normalise_axes(np.where(nrm > 0.0, v / np.where(nrm > 0.0, nrm, 1.0), 0.0))

    sigma_rel = max(np.sqrt(2.0) * np.radians(rotation_noise_deg), 1e-9)
    threshold = 3.0 * sigma_rel * np.sqrt(max(K, 1))
    if K:
        _, sv, vt = np.linalg.svd(r, full_matrices=False)
        sv = np.concatenate([sv, np.zeros(3 - len(sv))])
        dominant = _sign_normalise_axes(vt[0])
    else:
        sv = np.zeros(3)
        dominant = np.zeros(3)
    rank = int((sv > threshold).sum())
    significant = angles > 3.0 * sigma_rel
    if significant.any():
        u = unit(r[significant])
        spread = float(np.degrees(np.arccos(np.clip(np.abs(u @ dominant), 0.0, 1.0))).max())
    else:
        spread = 0.0

    # planar (SCARA-like): rotations only about the base z axis
    planar = False
    if K and significant.any():
        _, sv_b, vt_b = np.linalg.svd(r_base, full_matrices=False)
        sv_b = np.concatenate([sv_b, np.zeros(3 - len(sv_b))])
        planar = bool(sv_b[1] <= threshold and abs(vt_b[0][2]) > np.cos(np.radians(1.0)))

    warnings: list[str] = []
    if K and rank >= 2:
        max_angle = float(np.degrees(angles.max()))
        if max_angle < 10.0:
            warnings.append(
                f"the largest relative rotation is only {max_angle:.3g} deg: closed-form hand-eye "
                "estimates amplify noise; rotate by 30 deg or more between stations"
            )
        if spread < 15.0:
            warnings.append(
                f"rotation axes are within {spread:.3g} deg of one direction: the rotation about and "
                "the translation along that axis are weakly determined; vary the rotation axis"
            )
        if sv[1] < 10.0 * threshold:
            warnings.append(
                f"the second rotation direction is excited only {sv[1] / threshold:.3g}x above the "
                "noise threshold: expect a poorly conditioned hand-eye rotation"
            )
    return MotionDiagnostics(
        axes=unit(r),
        axes_base=unit(r_base),
        angles_deg=np.degrees(angles),
        pairs=np.stack([i, j], axis=-1),
        singular_values_deg=np.degrees(sv),
        axis_spread_deg=spread,
        dominant_axis=dominant,
        rank=rank,
        threshold_deg=float(np.degrees(threshold)),
        planar=planar,
        num_stations=n,
        frame=frame,
        warnings=tuple(warnings),
    )


def check_observable(motion: MotionDiagnostics, unknown: str = "T_flange_cam") -> None:
    """Raise :class:`NotObservableError` when ``motion`` cannot determine the hand-eye transform.

    Args:
        motion: from :func:`analyse_motion`.
        unknown: the name of the hand-eye transform in messages (``T_flange_cam``, ``T_base_cam``...).

    Raises:
        NotObservableError: with ``unknowns`` naming, in words, what is undetermined:
            fewer than 3 stations; no rotation (pure translation); rotations too small against the
            stated noise; all rotation axes parallel (one-axis or planar SCARA-like motion).
    """
    where = f"in the {motion.frame} frame"
    n = motion.num_stations
    if n < 3:
        if n == 2 and motion.rank >= 1:
            ax = fmt_axis(motion.dominant_axis)
            unknowns = [
                f"rotation of {unknown} about the rotation axis of the single motion (axis = {ax} {where})",
                f"translation of {unknown} along the rotation axis of the single motion "
                f"(axis = {ax} {where})",
            ]
        else:
            unknowns = [f"rotation of {unknown}", f"translation of {unknown}"]
        raise NotObservableError(
            f"hand-eye needs at least 3 stations (2 motions with rotations about non-parallel axes); "
            f"got {n} station(s). Undetermined: " + "; ".join(unknowns) + ".",
            unknowns=unknowns,
        )
    max_angle = float(motion.angles_deg.max()) if len(motion.angles_deg) else 0.0
    if motion.rank == 0:
        unknowns = [
            f"rotation of {unknown} (closed forms take it from the rotations, and there are none)",
            f"translation of {unknown} (all 3 components: without rotation it cancels out)",
        ]
        if max_angle < 1e-6:
            why = "the robot only translates (pure translations: no relative rotation between stations)"
        else:
            why = (
                f"the relative rotations are too small relative to the stated noise (largest "
                f"{max_angle:.3g} deg; excitation {motion.singular_values_deg[0]:.3g} deg below the "
                f"noise threshold {motion.threshold_deg:.3g} deg)"
            )
        raise NotObservableError(
            f"{unknown} is not observable: {why}. Undetermined: " + "; ".join(unknowns)
            + ". Rotate the flange about at least two different axes between stations.",
            unknowns=unknowns,
        )
    if motion.rank == 1:
        ax = fmt_axis(motion.dominant_axis)
        unknowns = [
            f"rotation of {unknown} about the common rotation axis (axis = {ax} {where})",
            f"translation of {unknown} along the common rotation axis (axis = {ax} {where})",
        ]
        if motion.planar:
            why = (
                "planar motion (SCARA-like): every rotation is about the base z axis, so all rotation "
                "axes are parallel"
            )
        else:
            why = (
                f"all rotation axes are parallel (spread {motion.axis_spread_deg:.3g} deg, within the "
                "stated noise): one-axis rotations"
            )
        raise NotObservableError(
            f"{unknown} is not observable: {why}. Undetermined: " + "; ".join(unknowns)
            + ". The translation along the axis cannot be determined by any method from these stations; "
            "the rotation about it is not determined by the rotations alone. Add stations rotating about "
            "another axis.",
            unknowns=unknowns,
        )


# ---------------------------------------------------------------------------------------------
# stations in, diagnostics out
# ---------------------------------------------------------------------------------------------


def checked_stations(T_base_flange, T_cam_target, mount: str, pairs: str, rotation_noise_deg: float):
    """Validated station poses and their motion analysis, raising on degenerate motion.

    Returns:
        ``(T_base_flange (N, 4, 4), T_cam_target (N, 4, 4), MotionDiagnostics)``.

    Raises:
        BadInputError: malformed poses or mismatched counts.
        NotObservableError: degenerate motion, naming the undetermined part of the hand-eye unknown.
    """
    T_bf = check_poses(T_base_flange, "T_base_flange")
    T_ct = check_poses(T_cam_target, "T_cam_target")
    if len(T_bf) != len(T_ct):
        raise BadInputError(
            f"T_cam_target: expected one pose per robot pose ({len(T_bf)} stations), got {len(T_ct)}"
        )
    if len(T_bf) == 0:
        raise BadInputError("T_base_flange: expected at least 3 stations, got none")
    unknown = "T_flange_cam" if mount == "flange" else "T_base_cam"
    motion = analyse_motion(T_bf, frame=mount, pairs=pairs, rotation_noise_deg=rotation_noise_deg)
    check_observable(motion, unknown)
    return T_bf, T_ct, motion


@dataclass(frozen=True)
class HandEyeDiagnostics:
    """Consistency of a closed-form hand-eye solution with the data.

    Attributes:
        motion: the :class:`MotionDiagnostics` the solve was checked with.
        other_rotation_rms_deg: RMS angle between the per-station estimates of ``T_other``
            (``T_base_flange_i X T_cam_target_i`` or its eye-to-hand analogue) and their mean, degrees.
        other_translation_rms: RMS distance of the per-station ``T_other`` translations from
            their mean, input unit (m).
        motion_rotation_rms_deg: RMS rotation angle of ``(A_k X)^-1 X B_k`` over the motions, degrees.
        motion_translation_rms: RMS translation of ``A_k X - X B_k``, input unit (m).
    """

    motion: MotionDiagnostics
    other_rotation_rms_deg: float
    other_translation_rms: float
    motion_rotation_rms_deg: float
    motion_translation_rms: float


def solution_diagnostics(
    motion: MotionDiagnostics, per_station: np.ndarray, T_other: np.ndarray, lhs: np.ndarray, rhs: np.ndarray
) -> HandEyeDiagnostics:
    """How well a closed-form solution fits the stations.

    Args:
        motion: the motion analysis of the stations.
        per_station: (N, 4, 4) the other transform implied by the solution at each station.
        T_other: (4, 4) their average.
        lhs, rhs: (M, 4, 4) the two sides of the solved equation (``AX`` and ``XB``, or ``AX`` and ``ZB``).
    """
    R_other = np.broadcast_to(T_other[:3, :3], per_station[:, :3, :3].shape)
    rot_other = _rotation_angle_deg(R_other, per_station[:, :3, :3])
    tr_other = np.linalg.norm(per_station[:, :3, 3] - T_other[:3, 3], axis=-1)
    rot_m = _rotation_angle_deg(lhs[:, :3, :3], rhs[:, :3, :3])
    tr_m = np.linalg.norm(lhs[:, :3, 3] - rhs[:, :3, 3], axis=-1)

    def rms(v):
        return float(np.sqrt(np.mean(np.square(v))))

    return HandEyeDiagnostics(
        motion=motion,
        other_rotation_rms_deg=rms(rot_other),
        other_translation_rms=rms(tr_other),
        motion_rotation_rms_deg=rms(rot_m),
        motion_translation_rms=rms(tr_m),
    )
