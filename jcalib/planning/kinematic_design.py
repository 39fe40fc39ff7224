"""Optimal experiment design for kinematic calibration: which joint configurations determine a robot's
kinematic parameters best.

The calibration (:mod:`jcalib.problems.kinematics`) estimates a *minimal identifiable set* of the
parameters the cell names in ``calibrate_kinematics``, together with an unknown pose on each side of
the robot (what is fixed in the base: a board, a fixed camera; what the flange carries: a hand-eye
camera, a target). Each station measures the flange pose ``T_base_flange(q, params)`` through a camera
(or a pose sensor), with the robot's repeatability on top. Linearised about the nominal parameters,
station ``m`` contributes the rows ``B_m = L_m^T A_m`` to the whitened Jacobian, with

    A_m = [ Ad(T_m^-1) | I_6 | dT/dparams ]   (6, 12 + F): base-side pose, flange-side pose, the F free parameters
    L_m L_m^T = (Σ_view,m + Σ_repeat)^-1      the flange pose's information at that station

(right-perturbation tangents ``(rx, ry, rz, tx, ty, tz)`` of the flange, rad and m; ``Exp(e) T =
T Exp(Ad(T^-1) e)`` turns the base-side pose into flange-frame columns). ``Σ_view,m`` is the
covariance of the flange pose from the corners of a target seen at station m (pinhole projection of
the nominal intrinsics, ``σ_px`` per coordinate, intrinsics taken as known; :func:`view_information`);
without a camera model the flange pose is taken as measured exactly and only the repeatability counts.
The information of a set of stations is ``Σ B_m^T B_m``; the plan maximises the log determinant of
its Schur complement onto the kinematic parameters (**Ds-optimal**, the D-optimal design for the
parameters of interest with the two poses as nuisance unknowns: the kinematics' joint confidence
ellipsoid, whatever the hand-eye and target poses' precision; :func:`d_optimal`: greedy selection from
a candidate set, then Fedorov exchanges). It is invariant to the parameters' units.

The structural scan of :func:`identifiable` repeats the builder's (:mod:`jcalib.problems.kinematics`:
same generic configurations, whitening and tolerance; the tests hold the two to the same answer). It was
written when the planners lived in acquisition, which may not import the builder; planning may.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry import kinematic_models, kinematic_tables, lie
from jcalib.geometry.kinematic_identifiability import (GAUGE_COLUMNS, INDEPENDENCE_TOLERANCE, flange_jacobians,
                                                       gauge_columns, repeatability_sqrt_info, structural_scan)
from jcalib.geometry.kinematics import DHRobot, forward_kinematics
from jcalib.geometry.se3 import skew

__all__ = [
    "GAUGE_COLUMNS", "DesignRows", "d_optimal", "design_rows", "flange_jacobians", "identifiable", "ik_robot",
    "joint_margin", "joint_space_candidates", "log_det", "null_parameters", "prediction", "repeatability_covariance",
    "view_information",
]

#: Ridge (relative to one station's normalised information) that starts the greedy selection.
RIDGE = 1e-6


def _window(model) -> tuple[np.ndarray, np.ndarray]:
    """Joint limits with revolute ranges over one turn cut to the turn centred on the middle (rad, m)."""
    lo, hi = np.asarray(model.lower, np.float64), np.asarray(model.upper, np.float64)
    revolute = np.array([t == "revolute" for t in model.joint_types])
    mid = 0.5 * (lo + hi)
    wide = revolute & (hi - lo > 2.0 * math.pi)
    return np.where(wide, mid - math.pi, lo), np.where(wide, mid + math.pi, hi)


def joint_margin(model) -> np.ndarray:
    """``(n,)`` distance kept from every joint limit: 1 deg (revolute) or 5 mm (prismatic), at most 5 %
    of the joint's range (rad, m)."""
    lo, hi = np.asarray(model.lower, np.float64), np.asarray(model.upper, np.float64)
    revolute = np.array([t == "revolute" for t in model.joint_types])
    return np.minimum(np.where(revolute, math.radians(1.0), 5e-3), 0.05 * (hi - lo))


def joint_space_candidates(model, count: int, rng: np.random.Generator) -> np.ndarray:
    """``(count, n)`` joint values spread uniformly over the limits less :func:`joint_margin` (revolute
    ranges over one turn cut to one turn about their middle), rad and m."""
    lo, hi = _window(model)
    margin = joint_margin(model)
    return rng.uniform(lo + margin, hi - margin, size=(count, lo.size))


def repeatability_covariance(robot_spec) -> tuple[np.ndarray, str]:
    """``(Σ (6, 6), where it came from)``: the flange pose's repeatability (rad², m²) from the cell's
    ``pose_noise``, else the builder's default (:func:`~jcalib.geometry.kinematic_identifiability.repeatability_sqrt_info`)."""
    S, how = repeatability_sqrt_info(robot_spec)
    return np.diag(1.0 / np.diag(S) ** 2), how


def identifiable(model, requested, covariance: np.ndarray) -> tuple[np.ndarray, dict[str, str]]:
    """The builder's minimal identifiable subset of ``requested`` (names or groups) by structure
    (:func:`~jcalib.geometry.kinematic_identifiability.structural_scan`, whitened by the repeatability
    ``covariance (6, 6)``).

    Returns:
        ``(free (P,) bool, held: name -> why)``.
    """
    want = np.asarray(kinematic_models.select(model, list(requested)), bool)
    S = np.linalg.cholesky(np.linalg.inv(covariance)).T  # SᵀS = Σ⁻¹
    return structural_scan(model, want, S)


def view_information(T_cam_target: np.ndarray, T_cam_flange: np.ndarray, points: np.ndarray, K: np.ndarray,
                     sigma_px: float) -> np.ndarray:
    """``(M, 6, 6)`` information of the flange pose (right perturbation, rad and m) from a target's
    corners seen by a pinhole camera, ``σ_px`` per pixel coordinate; intrinsics known, distortion ignored.

    Args:
        T_cam_target: (M, 4, 4) target in the camera at each station, m.
        T_cam_flange: (M, 4, 4) flange in the camera (eye-in-hand: ``inv(T_flange_cam)``; eye-to-hand:
            ``inv(T_base_cam) T_base_flange``), m.
        points: (k, 3) target points in the target frame, m.  K: (3, 3) camera matrix, px.
    """
    R, t = T_cam_target[:, None, :3, :3], T_cam_target[:, None, :3, 3]
    p = np.einsum("mkij,kj->mki", np.broadcast_to(R, (R.shape[0], len(points), 3, 3)), points) + t  # (M, k, 3)
    Rf, tf = T_cam_flange[:, :3, :3], T_cam_flange[:, :3, 3]
    q_f = np.einsum("mji,mkj->mki", Rf, p - tf[:, None])  # the points in the flange frame
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    zero = np.zeros_like(z)
    Jproj = np.stack([np.stack([K[0, 0] / z, zero, -K[0, 0] * x / z**2], -1),
                      np.stack([zero, K[1, 1] / z, -K[1, 1] * y / z**2], -1)], -2)  # (M, k, 2, 3)
    # the camera-frame point moves by ±R_cam_flange [[q_f]x, -I] δ for a flange perturbation δ
    D = np.einsum("mij,mkjl->mkil", Rf, np.concatenate([skew(q_f), -np.broadcast_to(np.eye(3), q_f.shape + (3,))], -1))
    J = Jproj @ D  # (M, k, 2, 6)
    return np.einsum("mkai,mkaj->mij", J, J) / sigma_px**2


@dataclass
class DesignRows:
    """Whitened Jacobian rows of candidate stations (module docstring).

    Attributes:
        rows: ``(M, 6, 12 + F)`` rows ``B_m`` in physical units (columns: base-side pose, flange-side
            pose, then the free parameters ``names``); ``scale``: ``(12 + F,)`` RMS column norm per
            station (the D-optimal search works on ``rows / scale``).
        names: the F free parameter names.  groups: name -> its parameter group (``joint_offsets``, ...).
    """

    rows: np.ndarray
    scale: np.ndarray
    names: list[str]
    groups: dict[str, str] = field(default_factory=dict)

    @property
    def normalised(self) -> np.ndarray:
        return self.rows / self.scale


def design_rows(model, T: np.ndarray, J_params: np.ndarray, free: np.ndarray, covariance: np.ndarray) -> DesignRows:
    """Rows of candidate stations with flange poses ``T (M, 4, 4)``, parameter Jacobians ``J_params
    (M, 6, P)`` and flange-pose covariances ``covariance (M, 6, 6)`` (or one ``(6, 6)``)."""
    A = np.concatenate([gauge_columns(T), J_params[:, :, free]], axis=2)
    info = np.linalg.inv(np.broadcast_to(covariance, (T.shape[0], 6, 6)))
    L = np.linalg.cholesky(0.5 * (info + np.swapaxes(info, 1, 2)))
    B = np.swapaxes(L, 1, 2) @ A
    scale = np.sqrt(np.mean(np.sum(B**2, axis=1), axis=0))
    names = [n for n, f in zip(model.param_names, free) if f]
    group_of = {p: g for g, ps in kinematic_models.parameter_groups(model).items() if g != "all" for p in ps}
    return DesignRows(B, np.where(scale > 0, scale, 1.0), names, {n: group_of[n] for n in names})


def _gains(rows: np.ndarray, Minv: np.ndarray) -> np.ndarray:
    """``log det(I + B_m M^-1 B_m^T)`` per candidate: the log-det increase of adding station m."""
    G = (rows @ Minv) @ np.swapaxes(rows, 1, 2)
    return np.linalg.slogdet(np.eye(rows.shape[1]) + G)[1]


def _criterion_gains(rows: np.ndarray, info: np.ndarray, nuisance: int) -> np.ndarray:
    """Increase of ``log det(info) - log det(info[:nuisance, :nuisance])`` (the log det of the Schur
    complement: the information of the other columns with the first ``nuisance`` unknown) per candidate."""
    g = _gains(rows, np.linalg.inv(info))
    if nuisance:
        g = g - _gains(rows[:, :, :nuisance], np.linalg.inv(info[:nuisance, :nuisance]))
    return g


def d_optimal(rows: np.ndarray, n: int, *, nuisance: int = 0, passes: int = 4) -> np.ndarray:
    """Indices of ``n`` distinct candidates maximising the log determinant of the information
    ``Σ B_m^T B_m`` of normalised ``rows (M, 6, K)``, or with ``nuisance > 0`` of its Schur complement
    onto the last ``K - nuisance`` columns (Ds-optimal: the first columns are unknowns whose own
    precision does not matter, such as the poses on either side of a robot).

    Greedy: from a small ridge (:data:`RIDGE`), add the candidate with the largest gain; then Fedorov
    exchanges: swap a chosen station for the candidate that raises the criterion most, until a pass
    changes nothing (at most ``passes``).
    """
    M, _, K = rows.shape
    if n > M:
        raise BadInputError(f"d_optimal: {n} stations requested from {M} candidates")
    info = RIDGE * np.eye(K)
    outer = np.einsum("mai,maj->mij", rows, rows)
    chosen: list[int] = []
    taken = np.zeros(M, bool)
    for _ in range(n):
        j = int(np.argmax(np.where(taken, -np.inf, _criterion_gains(rows, info, nuisance))))
        chosen.append(j)
        taken[j] = True
        info = info + outer[j]
    for _ in range(passes):
        changed = False
        for pos in range(n):
            i = chosen[pos]
            rest = info - outer[i]
            g = _criterion_gains(rows, rest, nuisance)
            j = int(np.argmax(np.where(taken, -np.inf, g)))
            if g[j] > g[i] + 1e-9:
                chosen[pos] = j
                taken[i], taken[j] = False, True
                info = rest + outer[j]
                changed = True
        if not changed:
            break
    return np.asarray(chosen)


def log_det(rows: np.ndarray, index, nuisance: int = 0) -> float:
    """``log det`` of the information of the stations ``index`` (rows as given), or of its Schur
    complement with the first ``nuisance`` columns unknown (the criterion of :func:`d_optimal`)."""
    B = rows[np.asarray(index)]
    info = np.einsum("mai,maj->ij", B, B)
    if nuisance:
        info = info[nuisance:, nuisance:] - info[nuisance:, :nuisance] @ np.linalg.solve(
            info[:nuisance, :nuisance], info[:nuisance, nuisance:])
    return float(np.linalg.slogdet(info)[1])


def _unit_of(name: str, group: str, prismatic_joints: set[str]) -> tuple[str, float]:
    """``(unit, factor)`` of a parameter's σ: deg for angles, mm for lengths (factor from rad or m)."""
    deg, mm = ("deg", 180.0 / math.pi), ("mm", 1e3)
    if group == "joint_offsets":
        return mm if name.split(".")[0] in prismatic_joints else deg
    if group in ("link_lengths", "twists"):
        return mm if group == "link_lengths" else deg
    return deg if name.rsplit(".", 1)[-1].startswith("r") else mm  # base.* / flange.* tangents


def prediction(model, design: DesignRows, index) -> dict:
    """Predicted precision of the stations ``index``: σ of every free parameter (deg or mm, linear
    propagation of the whitened Jacobian, base- and flange-side poses unknown), the worst per group,
    the condition number of the column-normalised Jacobian, and ``log_det``: the criterion of
    :func:`d_optimal` (normalised columns, the 12 poses as nuisance)."""
    B = design.rows[np.asarray(index)]
    info = np.einsum("mai,maj->ij", B, B)
    d = np.sqrt(np.diag(info))
    corr = info / np.outer(d, d)
    ev = np.linalg.eigvalsh(corr)
    full_rank = ev[0] > INDEPENDENCE_TOLERANCE**2 * ev[-1] * len(ev)
    cov = np.linalg.pinv(info, hermitian=True)
    prismatic = {j for j, t in zip(model.joint_names, model.joint_types) if t == "prismatic"}
    std: dict[str, dict] = {}
    worst: dict[str, dict] = {}
    for k, name in enumerate(design.names):
        group = design.groups[name]
        unit, factor = _unit_of(name, group, prismatic)
        s = float(np.sqrt(max(cov[GAUGE_COLUMNS + k, GAUGE_COLUMNS + k], 0.0)) * factor) if full_rank else math.inf
        std[name] = {"value": s, "unit": unit}
        key = f"{group} ({unit})"
        if key not in worst or s > worst[key]["value"]:
            worst[key] = {"name": name, "value": s, "unit": unit}
    return {
        "condition": float(np.sqrt(ev[-1] / ev[0])) if full_rank else math.inf,
        "log_det": log_det(design.normalised, index, nuisance=GAUGE_COLUMNS) if full_rank else -math.inf,
        "full_rank": bool(full_rank),
        "std": std,
        "worst": worst,
    }


def null_parameters(design: DesignRows, index) -> list[str]:
    """Free parameters in the (near) null space of the information of the stations ``index``."""
    B = design.normalised[np.asarray(index)]
    info = np.einsum("mai,maj->ij", B, B)
    d = np.sqrt(np.maximum(np.diag(info), 1e-300))
    w, V = np.linalg.eigh(info / np.outer(d, d))
    out: list[str] = []
    for k in np.flatnonzero(w < INDEPENDENCE_TOLERANCE**2 * w[-1] * len(w)):
        v = np.abs(V[GAUGE_COLUMNS:, k])
        for j in np.flatnonzero(v > 0.2 * max(v.max(), 1e-300)):
            if design.names[j] not in out:
                out.append(design.names[j])
    return out


def ik_robot(model, kinematics_spec=None) -> DHRobot:
    """The :class:`~jcalib.geometry.kinematics.DHRobot` with the nominal FK of ``model`` (for its inverse
    kinematics): the model itself when it is a dh chain of revolute joints, else the dh form of the
    preset its spec entry names.

    Raises:
        BadInputError: an mdh / poe table or a prismatic joint in an arm (no dh form to solve).
    """
    if model.convention != "dh" and isinstance(kinematics_spec, dict) and "preset" in kinematics_spec:
        entry = {k: v for k, v in kinematics_spec.items() if k != "convention"}
        model = kinematic_tables.from_spec(entry, model.name)
    if model.convention != "dh" or any(t != "revolute" for t in model.joint_types):
        raise BadInputError(
            f"plan --kind kinematics: the kinematics of {model.name} is a {model.convention} chain"
            f"{' with prismatic joints' if any(t != 'revolute' for t in model.joint_types) else ''}; planning "
            "camera views for an arm solves its inverse kinematics on a dh chain of revolute joints: name a "
            "preset (kinematics: {preset: ..., convention: ...}) or write the table with convention: dh"
        )
    p = np.asarray(model.nominal, np.float64)
    n = model.num_joints
    dh = p[: 4 * n].reshape(n, 4)  # theta, d, a, alpha
    tangents = p[4 * n :].reshape(2, 6)
    E = np.asarray(lie.se3_to_matrix(lie.se3_exp(jnp.asarray(tangents))))
    robot = DHRobot(a=dh[:, 2], alpha=dh[:, 3], d=dh[:, 1], theta_offset=dh[:, 0], joint_sign=model.joint_sign,
                    lower=model.lower, upper=model.upper, T_base_link0=np.asarray(model.T_base_link0) @ E[0],
                    T_link_flange=np.asarray(model.T_link_flange) @ E[1], name=model.name,
                    joint_names=model.joint_names)
    q = np.random.default_rng(0).uniform(-1.0, 1.0, size=(3, n))
    gap = np.max(np.abs(np.asarray(forward_kinematics(robot, q)) - np.asarray(kinematic_models.forward(model, p, q))))
    if gap > 1e-9:  # a dh model and its DHRobot are the same chain; anything else is a bug
        raise RuntimeError(f"ik_robot: the dh form of {model.name} differs from its model by {gap:.3g}")
    return robot
