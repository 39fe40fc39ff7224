"""What a result's uncertainty means: task-space σ, correlations, weak directions, what would help,
residual diagnostics, cross-validation and ordered warnings. Pure functions; the report shows them.

The central object is a :class:`LinearModel`: the Gauss–Newton information matrix of the *shared*
unknowns of a calibration (a camera's free intrinsics; for a hand-eye cell also the hand-eye and
target transforms), rebuilt from the result and its observations with JAX Jacobians at the
estimate. The per-view target poses (camera cells) or per-station flange-pose corrections
(hand-eye cells with the robot pose model) are eliminated by a Schur complement, exactly as the
solver does, so ``inv(information)`` is the reported covariance (a test checks it). Adding the
predicted information of one more station at the current estimate gives the covariance that
station would leave: the basis of the "what would help" hints.

Conventions: internal units are the solver's (pixels for ``fx..cy``, unitless distortion,
radians and metres for transform tangents ``(rx, ry, rz, tx, ty, tz)``, right perturbation,
expressed in the transform's child frame). Every :class:`Unknown` carries the factor to its display
unit (px, –, deg, mm).

What every σ here includes: the sampling noise of the observations (pixel noise and, with the robot
pose model, robot pose noise as stated), propagated to first order and scaled by the a-posteriori
variance factor when the solver did so. With the robot pose model the report scales only the pixel
information by the pixels' own factor and keeps the robot prior as stated (variance components, see
:func:`handeye_linear_model`): one factor for both, as the solver applies it, under-states the
robot-driven hand-eye translation by up to ``sqrt(σ̂²)`` when the corner σ was over-stated. What it does not include: model error (a too-simple lens
model, unmodelled robot error), a wrong local minimum, nonlinearity beyond first order.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.result import CameraResult, ResultFile, TransformResult, load_result

__all__ = [
    "DEFAULT_TOLERANCES",
    "JOINT_COVARIANCE_KEY",
    "POSES_KEY",
    "STATION_KINDS",
    "CrossValidation",
    "LinearModel",
    "RadialTest",
    "ResidualDiagnostics",
    "Suggestion",
    "Unknown",
    "Warning",
    "WeakDirection",
    "analysis_warnings",
    "camera_linear_model",
    "correlations",
    "cross_validate",
    "handeye_linear_model",
    "linear_models",
    "pixel_effect",
    "projection_sigma_map",
    "radial_structure",
    "residual_diagnostics",
    "result_file",
    "station_information",
    "transform_sigma",
    "unknown_tolerances",
    "weak_directions",
    "what_would_help",
]

#: Optional top-level key of a result file holding the per-view target poses:
#: ``{station id: {camera id: 4x4 T_cam_target (m)}}``.
POSES_KEY = "T_cam_target"

#: Optional top-level key of a result file with the joint covariance of the shared unknowns:
#: ``{"names": ["cam0.fx", ..., "T_flange_cam0.rx", ...], "matrix": n x n}`` in the solver's units
#: (px, unitless, rad, m). When present the correlation heat map spans intrinsics *and* transforms
#: without the observations.
JOINT_COVARIANCE_KEY = "joint_covariance"

_TANGENT = ("rx", "ry", "rz", "tx", "ty", "tz")
_TANGENT_WORDS = {
    "rx": "rotation x", "ry": "rotation y", "rz": "rotation z",
    "tx": "translation x", "ty": "translation y", "tz": "translation z",
}
_PIXEL_PARAMS = ("fx", "fy", "cx", "cy", "skew")

#: Tolerances a σ is compared with to call an unknown weak (each can be overridden):
#: ``edge_px``: the displacement of a point at the image edge caused by 1 σ of ``fx``/``fy``
#: (``σ_f · (w/2) / f``) or of ``cx``/``cy`` (``σ_c``), pixels; ``projection_px``: worst σ of the
#: projection over the image (intrinsics only), pixels; ``rotation_deg`` / ``translation_mm``:
#: 1 σ of any axis of a transform (hand-eye, TCP, target pose).
DEFAULT_TOLERANCES = {"edge_px": 2.0, "projection_px": 1.0, "rotation_deg": 0.05, "translation_mm": 0.5}


# ------------------------------------------------------------------------------------ unknowns


@dataclass(frozen=True)
class Unknown:
    """One scalar unknown of a linear model.

    Attributes:
        block: the camera id (intrinsics) or the transform name (``T_flange_cam0``).
        coord: the intrinsic name (``fx``, ``k1``…) or tangent coordinate (``rx``…``tz``).
        unit: display unit (``px``, ``–``, ``deg``, ``mm``).
        scale: display value per internal unit (1, 180/π, 1000).
    """

    block: str
    coord: str
    unit: str
    scale: float

    @property
    def label(self) -> str:
        """Human name, e.g. ``cam0 fx`` or ``T_flange_cam0 translation z``."""
        return f"{self.block} {_TANGENT_WORDS.get(self.coord, self.coord)}"

    @property
    def key(self) -> str:
        """Machine name ``block.coord`` (as in :data:`JOINT_COVARIANCE_KEY`)."""
        return f"{self.block}.{self.coord}"


def _intrinsic_unknown(camera: str, name: str) -> Unknown:
    return Unknown(camera, name, "px" if name in _PIXEL_PARAMS else "–", 1.0)


def _transform_unknown(transform: str, coord: str) -> Unknown:
    if coord.startswith("r"):
        return Unknown(transform, coord, "deg", 180.0 / math.pi)
    return Unknown(transform, coord, "mm", 1000.0)


# ------------------------------------------------------------------------------------ loading


def result_file(result: Any) -> ResultFile:
    """The :class:`ResultFile` of a :class:`jcalib.Result`, a ``ResultFile`` or a path."""
    file = getattr(result, "file", None)
    if isinstance(file, ResultFile):
        return file
    return load_result(result)


def _camera_model(cam: CameraResult):
    from jcalib.geometry.cameras import camera_from_opencv

    return camera_from_opencv(cam.K, cam.dist, cam.image_size, fisheye=cam.model == "fisheye")


def _se3(T: np.ndarray) -> np.ndarray:
    from jcalib.geometry import conversions

    return np.asarray(conversions.matrix_to_pose(np.asarray(T, np.float64)), np.float64)


def _variance_factor(file: ResultFile) -> tuple[float, float]:
    """``(stated σ px, variance factor)``: the covariance is ``factor · (information at stated σ)⁻¹``."""
    stats = file.stats
    options = {} if file.provenance is None else dict(file.provenance.options)
    sigma_post = float(stats.get("sigma_px", options.get("sigma_px", 1.0)))
    stated = float(options.get("sigma_px", sigma_post))
    if options.get("noise", "a_posteriori") == "stated":
        return stated, 1.0
    return stated, (sigma_post / stated) ** 2


# ------------------------------------------------------------------------------------ Jacobians


def _bucket(n: int) -> int:
    from jcalib.solve import bucket_size

    return bucket_size(max(int(n), 1))


def _pad(x: np.ndarray, n: int) -> np.ndarray:
    if x.shape[0] >= n:
        return x
    return np.concatenate([x, np.broadcast_to(x[:1], (n - x.shape[0],) + x.shape[1:])])


@functools.cache
def _camera_jacobian_fn(model_cls: type, image_size: tuple[int, int], skew: bool):
    """Jitted ``(params (p,), T_cam_target (N, 7), p_target (N, 3)) -> (pixels (N, 2), J_θ (N, 2, p),
    J_pose (N, 2, 6))``; the pose Jacobian is w.r.t. a right perturbation of ``T_cam_target``."""
    import jax
    import jax.numpy as jnp

    from jcalib.geometry import lie

    def one(params, pose, p):
        def f(theta, delta):
            T = lie.retract(pose, delta)
            return model_cls.from_params(image_size, theta, skew=skew).project(lie.se3_apply(T, p))

        zero = jnp.zeros(6, jnp.float64)
        Jt, Jp = jax.jacfwd(f, argnums=(0, 1))(params, zero)
        return f(params, zero), Jt, Jp

    return jax.jit(jax.vmap(one, in_axes=(None, 0, 0)))


@functools.cache
def _handeye_jacobian_fn(model_cls: type, image_size: tuple[int, int], skew: bool, mount: str):
    """Jitted ``(params, X (7,), Y (7,), B (N, 7), p (N, 3)) -> (pixels, J_θ, J_X, J_Y, J_B)``.

    ``mount="flange"``: ``p_cam = inv(X) · inv(B) · Y · p`` (X = T_flange_cam, Y = T_base_target);
    ``"base"``: ``p_cam = inv(X) · B · Y · p`` (X = T_base_cam, Y = T_flange_target). All pose
    Jacobians are w.r.t. right perturbations (the result file's tangent).
    """
    import jax
    import jax.numpy as jnp

    from jcalib.geometry import lie

    def one(params, X, Y, B, p):
        def f(theta, dX, dY, dB):
            Xp, Yp, Bp = lie.retract(X, dX), lie.retract(Y, dY), lie.retract(B, dB)
            Bm = lie.se3_inverse(Bp) if mount == "flange" else Bp
            T = lie.se3_compose(lie.se3_inverse(Xp), lie.se3_compose(Bm, Yp))
            return model_cls.from_params(image_size, theta, skew=skew).project(lie.se3_apply(T, p))

        zero = jnp.zeros(6, jnp.float64)
        J = jax.jacfwd(f, argnums=(0, 1, 2, 3))(params, zero, zero, zero)
        return (f(params, zero, zero, zero), *J)

    return jax.jit(jax.vmap(one, in_axes=(None, None, None, 0, 0)))


# ------------------------------------------------------------------------------------ linear model


@dataclass
class LinearModel:
    """The information matrix of a calibration's shared unknowns at its estimate.

    Attributes:
        kind: ``"camera"`` (one camera, free target poses) or ``"hand-eye"``.
        unknowns: the free shared unknowns, in matrix order.
        information: ``(n, n)`` information (inverse covariance) in internal units, with the
            per-view / per-station poses eliminated (Schur complement) and the a-posteriori
            variance factor applied: ``covariance() = inv(information)``.
        column_information: ``(n,)`` diagonal of ``JᵀJ`` (same scaling) *before* eliminating
            the poses: how strongly each unknown alone moves the data. Unit-free weak directions
            scale by it.
        context: what :func:`station_information` needs to predict a new station (camera model,
            estimate, target points, reference pose, Jacobian function).
    """

    kind: str
    unknowns: tuple[Unknown, ...]
    information: np.ndarray
    column_information: np.ndarray
    context: dict = field(default_factory=dict, repr=False)

    def covariance(self, added: np.ndarray | None = None) -> np.ndarray:
        """``(n, n)`` covariance (internal units), optionally after adding information ``added``."""
        H = self.information if added is None else self.information + added
        d = 1.0 / np.sqrt(np.maximum(np.diag(H), 1e-300))
        Hs = H * d[:, None] * d[None, :]
        return np.linalg.inv(0.5 * (Hs + Hs.T)) * d[:, None] * d[None, :]

    def sigma(self, added: np.ndarray | None = None) -> np.ndarray:
        """``(n,)`` 1σ of every unknown in display units."""
        scale = np.array([u.scale for u in self.unknowns])
        return np.sqrt(np.maximum(np.diag(self.covariance(added)), 0.0)) * scale

    def index(self, block: str, coord: str) -> int:
        """Position of unknown ``block.coord``; BadInputError when it is not a free unknown."""
        for i, u in enumerate(self.unknowns):
            if u.block == block and u.coord == coord:
                return i
        raise BadInputError(
            f"unknown: got {block}.{coord}, expected one of {', '.join(u.key for u in self.unknowns)}"
        )


def _assemble(J_shared: np.ndarray, J_elim: np.ndarray | None, group: np.ndarray | None,
              num_groups: int, prior_info: np.ndarray | None, weight: np.ndarray,
              whiten: float, blocks: bool = False):
    """Schur-reduced information ``A − Σ_g W_g V_g⁻¹ W_gᵀ`` and ``diag(A)``.

    Args:
        J_shared: ``(N, 2, n)`` Jacobians of the pixel residuals w.r.t. the shared unknowns.
        J_elim: ``(N, 2, 6)`` w.r.t. the eliminated pose of each corner's group, or None.
        group: ``(N,)`` group (view / station) index of each corner.
        prior_info: ``(6, 6)`` prior information added to every group's block, or None.
        weight: ``(N,)`` 0/1 corner weights (0: outlier).
        whiten: ``1/σ`` of a pixel coordinate.
        blocks: also return ``W (g, n, 6)`` and ``V (g, 6, 6)`` (prior included).
    """
    w = weight[:, None, None] * whiten
    Js = J_shared * w
    A = np.einsum("kin,kim->nm", Js, Js)
    diag = np.diag(A).copy()
    if J_elim is None:
        return (A, diag, None, None) if blocks else (A, diag)
    Je = J_elim * w
    n = Js.shape[-1]
    W = np.zeros((num_groups, n, 6))
    V = np.zeros((num_groups, 6, 6))
    np.add.at(W, group, np.einsum("kin,kie->kne", Js, Je))
    np.add.at(V, group, np.einsum("kid,kie->kde", Je, Je))
    if prior_info is not None:
        V = V + prior_info[None]
    Y = np.linalg.solve(V, np.swapaxes(W, 1, 2))  # (g, 6, n) = V⁻¹ Wᵀ
    S = A - np.einsum("gne,gem->nm", W, Y)
    if blocks:
        return 0.5 * (S + S.T), diag, W, V
    return 0.5 * (S + S.T), diag


def _free_intrinsics(cam: CameraResult) -> np.ndarray:
    """Indices of the free intrinsics (σ not exactly 0)."""
    return np.array([i for i, n in enumerate(cam.param_names) if cam.std.get(n, 1.0) != 0.0], dtype=np.int64)


def camera_linear_model(
    name: str,
    cam: CameraResult,
    points: Sequence[np.ndarray],
    pixels: Sequence[np.ndarray],
    T_cam_target: Sequence[np.ndarray],
    sigma_px: float,
    variance_factor: float = 1.0,
    outlier_px: float | None = None,
) -> LinearModel:
    """The :class:`LinearModel` of one camera's intrinsics from its views of a planar target.

    Args:
        name: camera id.
        cam: the calibrated camera (its free intrinsics: σ ≠ 0).
        points: per view ``(n_i, 3)`` target points, m (target frame).
        pixels: per view ``(n_i, 2)`` observed corners, px.
        T_cam_target: per view ``(4, 4)`` estimated target pose in the camera, m.
        sigma_px: the stated corner noise σ the solver whitened with, px.
        variance_factor: the solver's a-posteriori factor ``σ̂²`` (1 for stated noise).
        outlier_px: corners with a residual norm above this are left out (as the solver rejected
            them); None keeps all.

    Returns:
        The model; ``covariance()`` is the intrinsics covariance of the free intrinsics.
    """
    import jax.numpy as jnp

    model = _camera_model(cam)
    free = _free_intrinsics(cam)
    P = np.concatenate([np.asarray(p, np.float64) for p in points])
    X = np.concatenate([np.asarray(x, np.float64) for x in pixels])
    group = np.repeat(np.arange(len(points)), [len(p) for p in points])
    poses = np.stack([_se3(T) for T in T_cam_target])[group]
    N = P.shape[0]
    Np = _bucket(N)
    fn = _camera_jacobian_fn(type(model), tuple(int(s) for s in model.image_size), bool(model.has_skew))
    proj, Jt, Jp = (np.asarray(a)[:N] for a in fn(jnp.asarray(cam.params), jnp.asarray(_pad(poses, Np)),
                                                     jnp.asarray(_pad(P, Np))))
    res = X - proj
    weight = np.ones(N)
    if outlier_px is not None:
        weight = (np.linalg.norm(res, axis=-1) <= outlier_px).astype(np.float64)
    S, diag = _assemble(Jt[..., free], Jp, group, len(points), None, weight, 1.0 / sigma_px)
    unknowns = tuple(_intrinsic_unknown(name, cam.param_names[i]) for i in free)
    context = {"camera": name, "cam": cam, "free": free, "points": np.asarray(points[0], np.float64),
                   "T_cam_target": [np.asarray(T, np.float64) for T in T_cam_target], "whiten": 1.0 / sigma_px,
                   "variance_factor": variance_factor, "jacobian_fn": fn, "residuals": res, "pixels": X, "weight": weight,
                   "group": group}
    return LinearModel("camera", unknowns, S / variance_factor, diag / variance_factor, context)


def handeye_linear_model(
    camera: str,
    cam: CameraResult,
    hand_eye: tuple[str, TransformResult],
    target: tuple[str, TransformResult],
    mount: str,
    points: Sequence[np.ndarray],
    pixels: Sequence[np.ndarray],
    T_base_flange: Sequence[np.ndarray],
    sigma_px: float,
    variance_factor: float = 1.0,
    pose_sigma: tuple[np.ndarray, np.ndarray] | None = None,
    variance_components: bool = False,
) -> LinearModel:
    """The :class:`LinearModel` of a hand-eye cell: free intrinsics, hand-eye and target transform.

    Args:
        camera: camera id; ``cam`` its calibrated model.
        hand_eye: ``(name, transform)`` of ``T_flange_<camera>`` (``mount="flange"``) or
            ``T_base_<camera>`` (``mount="base"``).
        target: ``(name, transform)`` of ``T_base_<target>`` or ``T_flange_<target>``.
        points, pixels: per station ``(n_i, 3)`` target points (m) and ``(n_i, 2)`` corners (px).
        T_base_flange: per station ``(4, 4)`` flange pose, m (the estimated true poses when the robot
            pose model was on and they are known; the measured ones otherwise).
        sigma_px: stated corner noise, px; ``variance_factor`` the solver's σ̂².
        pose_sigma: ``(rotation σ (3,) rad, translation σ (3,) m)`` of the robot-pose prior (the
            robot pose model), or None (poses exact).
        variance_components: with the robot pose model, scale only the *pixel* information by
            the pixels' own a-posteriori factor ``χ²_px / r_px`` (the corner residuals' χ² at the
            stated σ over their redundancy ``r_px = 2N − n_shared − r_prior``, ``r_prior = 6S − Σ_i
            tr(C_ii P)`` the redundancy of the robot prior over S stations, ``C_ii`` station i's
            posterior covariance, ``P`` the prior information) and keep the robot prior at its stated σ, instead of scaling everything by
            the overall ``variance_factor``. One factor for both is right only when both noise
            levels are off by the same ratio; with the pixel σ mis-stated and the robot σ right it
            under- or over-states the robot-driven directions (hand-eye translation) by up to
            ``sqrt(variance_factor)``. Ignored without ``pose_sigma``.

    A transform whose covariance is zero (held fixed) is not an unknown.
    """
    import jax.numpy as jnp

    model = _camera_model(cam)
    free = _free_intrinsics(cam)
    P = np.concatenate([np.asarray(p, np.float64) for p in points])
    Xpix = np.concatenate([np.asarray(x, np.float64) for x in pixels])
    group = np.repeat(np.arange(len(points)), [len(p) for p in points])
    B = np.stack([_se3(T) for T in T_base_flange])
    N = P.shape[0]
    Np = _bucket(N)
    fn = _handeye_jacobian_fn(type(model), tuple(int(s) for s in model.image_size), bool(model.has_skew), mount)
    X7, Y7 = _se3(hand_eye[1].matrix), _se3(target[1].matrix)
    out = fn(jnp.asarray(cam.params), jnp.asarray(X7), jnp.asarray(Y7), jnp.asarray(_pad(B[group], Np)),
             jnp.asarray(_pad(P, Np)))
    proj, Jt, JX, JY, JB = (np.asarray(a)[:N] for a in out)
    blocks, unknowns = [Jt[..., free]], [_intrinsic_unknown(camera, cam.param_names[i]) for i in free]
    for (tname, tr), J in ((hand_eye, JX), (target, JY)):
        if tr.covariance is not None and not np.any(np.diag(tr.covariance) > 0.0):
            continue  # held fixed
        blocks.append(J)
        unknowns += [_transform_unknown(tname, c) for c in _TANGENT]
    Js = np.concatenate(blocks, axis=-1)
    prior = None  # whitened prior information of one flange-pose correction, diag(1/σ²)
    if pose_sigma is not None:
        prior = np.diag(1.0 / np.concatenate([pose_sigma[0], pose_sigma[1]]) ** 2)
    whiten = 1.0 / sigma_px
    S, diag, W, V = _assemble(Js, JB if prior is not None else None, group, len(points), prior, np.ones(N), whiten,
                              blocks=True)
    pixel_factor = r_prior = None
    if variance_components and prior is not None:
        # station i's posterior δ covariance (stated noise): V⁻¹ + V⁻¹ Wᵀ S⁻¹ W V⁻¹
        Vi = np.linalg.inv(V)
        G = np.einsum("gde,gne->gdn", Vi, W)  # V⁻¹ Wᵀ
        d = 1.0 / np.sqrt(np.maximum(np.diag(S), 1e-300))
        Cs = np.linalg.inv(S * d[:, None] * d[None, :]) * d[:, None] * d[None, :]
        Cii = Vi + np.einsum("gdn,nm,gem->gde", G, Cs, G)
        r_prior = 6.0 * len(points) - float(np.einsum("gde,ed->", Cii, prior))
        r_px = 2.0 * N - Js.shape[-1] - r_prior
        chi2_px = float(np.sum(((Xpix - proj) * whiten) ** 2))
        if r_px > 0.0 and chi2_px > 0.0:
            pixel_factor = chi2_px / r_px
            whiten = whiten / math.sqrt(pixel_factor)
            S, diag = _assemble(Js, JB, group, len(points), prior, np.ones(N), whiten)
            variance_factor = 1.0
    context = {"camera": camera, "cam": cam, "free": free, "points": np.asarray(points[0], np.float64), "mount": mount,
                   "X7": X7, "Y7": Y7, "T_base_flange": np.asarray(T_base_flange, np.float64),
                   "hand_eye": hand_eye[0], "target": target[0], "whiten": whiten, "pixel_factor": pixel_factor,
                   "prior_redundancy": r_prior,
                   "variance_factor": variance_factor, "jacobian_fn": fn, "pose_prior": prior,
                   "blocks": [u.block for u in unknowns], "residuals": Xpix - proj, "pixels": Xpix, "group": group,
                   "weight": np.ones(N)}
    return LinearModel("hand-eye", tuple(unknowns), S / variance_factor, diag / variance_factor, context)


def _detections(obs, camera: str, target: str):
    """Per station ``(station id, points (n, 3), pixels (n, 2), T_base_flange or None)``."""
    out = []
    for st in obs.stations:
        for det in st.detections:
            if det.camera == camera and det.target == target and target in obs.targets:
                pts = np.asarray(obs.targets[target], np.float64)[det.point_index]
                out.append((st.id, pts, np.asarray(det.pixels, np.float64), st.T_base_flange))
                break
    return out


def _hand_eye_layout(file: ResultFile):
    """``(camera, mount, hand-eye name, target name, target id)`` of a hand-eye result, or None."""
    for cam in file.cameras:
        for mount, other in (("flange", "base"), ("base", "flange")):
            he = f"T_{mount}_{cam}"
            if he not in file.transforms:
                continue
            targets = [n for n in file.transforms if n.startswith(f"T_{other}_") and n != he
                       and file.transforms[n].extra.get("kind") != "tcp"]  # a TCP is no target
            if len(targets) == 1:
                return cam, mount, he, targets[0], targets[0][len(f"T_{other}_"):]
    return None


def linear_models(result: Any, observations: Any, variance_components: bool = True) -> dict[str, LinearModel]:
    """Linear models of a result: one per camera (camera cells) or one for the hand-eye cell.

    Args:
        result: a :class:`jcalib.Result` (its ``details`` supply the per-view poses, the estimated
            flange poses and the rejected corners), a :class:`ResultFile` or a path.
        observations: the observations the result was computed from (path, dict or
            :class:`~jcalib.io.observations.Observations`).
        variance_components: hand-eye cells with the robot pose model and a-posteriori noise: scale
            the pixel information by the pixels' own variance factor and keep the robot prior as
            stated (see :func:`handeye_linear_model`); False: one factor for both, exactly as the
            solver's covariance.

    Returns:
        ``{camera id or hand-eye transform name: LinearModel}``; a camera without per-view poses in
        the result is left out. Cameras of a multi-camera rig are modelled one at a time (the rig
        coupling is ignored: their σ come out slightly larger than the joint solve's).
    """
    from jcalib.io.observations import load_observations

    file = result_file(result)
    obs = load_observations(observations)
    details = getattr(result, "details", None)
    stated, factor = _variance_factor(file)
    options = {} if file.provenance is None else dict(file.provenance.options)
    layout = _hand_eye_layout(file)
    if layout is not None:
        camera, mount, he, tg, target = layout
        dets = _detections(obs, camera, target)
        if not dets:
            return {}
        ids = [d[0] for d in dets]
        T_bf = [np.asarray(d[3], np.float64) for d in dets]
        if details is not None and getattr(details, "T_base_flange", None) is not None:
            est = dict(zip(details.station_ids, details.T_base_flange))
            T_bf = [est.get(i, T) for i, T in zip(ids, T_bf)]
        pose_sigma = None
        robot = file.stats.get("robot") or {}
        if robot.get("prior_sigma_translation_m") is not None:
            pose_sigma = (np.radians(np.asarray(robot["prior_sigma_rotation_deg"], np.float64)) * np.ones(3),
                          np.asarray(robot["prior_sigma_translation_m"], np.float64) * np.ones(3))
        m = handeye_linear_model(camera, file.cameras[camera], (he, file.transforms[he]), (tg, file.transforms[tg]),
                                 mount, [d[1] for d in dets], [d[2] for d in dets], T_bf, stated, factor, pose_sigma,
                                 variance_components=variance_components and options.get("noise") != "stated")
        return {he: m}
    poses = getattr(details, "T_cam_target", None) or file.extra.get(POSES_KEY)
    if not poses:
        return {}
    threshold = options.get("outlier_threshold")
    out = {}
    targets = list(obs.targets)
    for camera, cam in file.cameras.items():
        views = []
        for target in targets:
            views += [d for d in _detections(obs, camera, target) if camera in poses.get(d[0], {})]
        if not views:
            continue
        outlier_px = None
        if threshold is not None and "sigma_px" in file.stats:
            outlier_px = float(threshold) * float(file.stats["sigma_px"])
        out[camera] = camera_linear_model(
            camera, cam, [v[1] for v in views], [v[2] for v in views],
            [np.asarray(poses[v[0]][camera], np.float64) for v in views], stated, factor, outlier_px)
    return out


# ------------------------------------------------------------------------------------ task space


@functools.cache
def _sigma_fn(model_cls: type, image_size: tuple[int, int], skew: bool):
    """Jitted ``(params (p,), p_cam (n, 3), cov (p, p)) -> (n, 2, 2)`` pixel covariances."""
    import jax

    def one(params, p_cam, cov):
        def proj(q):
            return model_cls.from_params(image_size, q, skew=skew).project(p_cam)

        J = jax.jacfwd(proj)(params)  # (2, p)
        return J @ cov @ J.T

    @jax.jit
    def many(params, p_cam, cov):
        return jax.vmap(one, in_axes=(None, 0, None))(params, p_cam, cov)

    return many


def _grid(image_size, grid):
    width, height = image_size
    nx, ny = grid
    return np.meshgrid(np.linspace(0.0, width - 1.0, nx), np.linspace(0.0, height - 1.0, ny))


def projection_sigma_map(
    cam: CameraResult, grid: tuple[int, int] = (33, 25), covariance: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """σ (pixels) of the projection of points across the image due to the intrinsics covariance.

    For a grid of pixels, the estimated model unprojects each pixel to a point ``p_cam`` on its ray
    (held fixed); the Jacobian ``J (2, p)`` of ``project(p_cam)`` w.r.t. the intrinsic vector
    (order :attr:`CameraResult.param_names`, from JAX) propagates the covariance ``C``:
    ``Σ = J C Jᵀ (2, 2)``. The value is the worst-direction σ, ``sqrt(λ_max(Σ))`` (mrcal's
    "worstdirection-stdev").

    Includes: the intrinsics uncertainty caused by pixel noise (as the solver reported it).
    Excludes: model error (a too-simple lens model) and the uncertainty of the camera and target
    poses. The lens models are central, so the value is the same for a point at any working
    distance along the pixel's ray.

    Args:
        cam: a camera with a ``covariance`` (or pass ``covariance``).
        grid: ``(nx, ny)`` grid points across the image.
        covariance: ``(p, p)`` intrinsics covariance to use instead of the camera's (e.g. predicted).

    Returns:
        ``(u, v, sigma)``: pixel coordinates ``(ny, nx)`` each (OpenCV convention) and σ ``(ny, nx)``
        in pixels; NaN where the pixel has no valid ray (outside a fisheye's valid range).
    """
    import jax.numpy as jnp

    cov = cam.covariance if covariance is None else np.asarray(covariance, np.float64)
    if cov is None:
        raise BadInputError(
            f"cam: the camera ({cam.model}) has no intrinsics covariance; the projection "
            "uncertainty needs one"
        )
    u, v = _grid(cam.image_size, grid)
    pixels = np.stack([u.ravel(), v.ravel()], axis=-1)
    model = _camera_model(cam)
    rays, valid = _unproject(cam, pixels)
    valid = valid & (rays[:, 2] > 1e-6)
    fn = _sigma_fn(type(model), tuple(model.image_size), bool(model.has_skew))
    cov_px = np.asarray(fn(jnp.asarray(cam.params), jnp.asarray(rays), jnp.asarray(cov)))
    eig = np.linalg.eigvalsh(0.5 * (cov_px + np.swapaxes(cov_px, -1, -2)))
    sigma = np.sqrt(np.maximum(eig[:, -1], 0.0))
    sigma = np.where(valid, sigma, np.nan)
    return u, v, sigma.reshape(u.shape)


def transform_sigma(transform: TransformResult) -> dict[str, Any] | None:
    """1σ of a transform per axis and in total, in display units.

    Returns:
        ``{"rotation_deg": (3,), "translation_mm": (3,), "rotation_total_deg": float,
        "translation_total_mm": float}`` (per-axis σ of the right-perturbation tangent, in the
        child frame; totals ``sqrt(trace)`` of the 3x3 blocks), or None without a covariance.
    """
    if transform.covariance is None:
        return None
    C = np.asarray(transform.covariance, np.float64)
    d = np.sqrt(np.maximum(np.diag(C), 0.0))
    return {
        "rotation_deg": np.degrees(d[:3]),
        "translation_mm": 1e3 * d[3:],
        "rotation_total_deg": float(np.degrees(np.sqrt(max(np.trace(C[:3, :3]), 0.0)))),
        "translation_total_mm": float(1e3 * np.sqrt(max(np.trace(C[3:, 3:]), 0.0))),
    }


# ------------------------------------------------------------------------------------ correlations


def correlations(covariance: np.ndarray, labels: Sequence[str], top: int = 8, minimum: float = 0.5
                 ) -> tuple[np.ndarray, list[tuple[str, str, float]]]:
    """Correlation matrix and the strongest pairs.

    Args:
        covariance: ``(n, n)``.
        labels: ``n`` names.
        top: at most this many pairs.
        minimum: only pairs with ``|ρ| >= minimum``.

    Returns:
        ``(ρ (n, n), [(label a, label b, ρ), ...])`` pairs sorted by ``|ρ|``, strongest first.
    """
    C = np.asarray(covariance, np.float64)
    d = np.sqrt(np.maximum(np.diag(C), 0.0))
    safe = np.where(d > 0.0, d, 1.0)
    rho = np.where((d[:, None] > 0) & (d[None, :] > 0), C / safe[:, None] / safe[None, :], 0.0)
    np.fill_diagonal(rho, np.where(d > 0, 1.0, 0.0))
    i, j = np.triu_indices(len(d), 1)
    order = np.argsort(-np.abs(rho[i, j]), kind="stable")
    pairs = [(labels[i[k]], labels[j[k]], float(rho[i[k], j[k]])) for k in order
             if abs(rho[i[k], j[k]]) >= minimum][:top]
    return rho, pairs


_TANGENT_ORDER = _TANGENT


def joint_covariance(file: ResultFile) -> tuple[tuple[Unknown, ...], np.ndarray] | None:
    """The file's :data:`JOINT_COVARIANCE_KEY` as ``(unknowns, covariance)``, or None."""
    data = file.extra.get(JOINT_COVARIANCE_KEY)
    if data is None:
        return None
    try:
        names = [str(n) for n in data["names"]]
        C = np.asarray(data["matrix"], np.float64)
        if "dims" in data:  # block form (whole-cell results): one name per unknown block, its dimension
            full = []
            for n, d in zip(names, data["dims"], strict=True):
                coords = file.cameras[n].param_names if n in file.cameras else _TANGENT_ORDER
                if len(coords) != int(d):
                    raise ValueError(f"block {n!r} has {d} coordinates, expected {len(coords)}")
                full += [f"{n}.{c}" for c in coords]
            names = full
    except (KeyError, TypeError, ValueError) as err:
        raise BadInputError(f"{JOINT_COVARIANCE_KEY}: expected {{names: [...], matrix: n x n}}, got {err}") from None
    if C.shape != (len(names), len(names)) or not np.all(np.isfinite(C)):
        raise BadInputError(
            f"{JOINT_COVARIANCE_KEY}.matrix: expected a finite {len(names)}x{len(names)} matrix, got shape {C.shape}")
    unknowns = []
    for n in names:
        block, _, coord = n.rpartition(".")
        unknowns.append(_transform_unknown(block, coord) if coord in _TANGENT else _intrinsic_unknown(block, coord))
    return tuple(unknowns), C


# ------------------------------------------------------------------------------------ weak directions


@functools.cache
def _projection_jacobian_fn(model_cls: type, image_size: tuple[int, int], skew: bool):
    """Jitted ``(params (p,), p_cam (n, 3)) -> J (n, 2, p)``: pixels w.r.t. the intrinsics."""
    import jax

    def one(params, p):
        return jax.jacfwd(lambda q: model_cls.from_params(image_size, q, skew=skew).project(p))(params)

    return jax.jit(jax.vmap(one, in_axes=(None, 0)))


def pixel_effect(cam: CameraResult, grid: tuple[int, int] = (9, 7)) -> np.ndarray:
    """``(p,)`` largest pixel displacement per unit change of each intrinsic over the image.

    The norm of ``∂ project(ray) / ∂θ_j`` (px per unit of θ_j) at a grid of pixels including the
    image edges and corners, maximised over the grid: e.g. ``max |x/z|`` for ``fx``, 1 for ``cx``,
    ``f · r³``-like for ``k1``.
    """
    import jax.numpy as jnp

    u, v = _grid(cam.image_size, grid)
    rays, valid = _unproject(cam, np.stack([u.ravel(), v.ravel()], -1))
    ok = valid & (rays[:, 2] > 1e-6)
    m = _camera_model(cam)
    fn = _projection_jacobian_fn(type(m), tuple(int(s) for s in m.image_size), bool(m.has_skew))
    J = np.asarray(fn(jnp.asarray(cam.params), jnp.asarray(rays[ok])))
    return np.max(np.linalg.norm(J, axis=1), axis=0)


def unknown_tolerances(model: LinearModel, overrides: Mapping[str, float] | None = None) -> np.ndarray:
    """``(n,)`` tolerance of every unknown of ``model`` in display units.

    Intrinsics: the change that moves some image point (edges and corners included) by
    ``edge_px`` pixels (:func:`pixel_effect`); transform rotations ``rotation_deg``, translations
    ``translation_mm`` (:data:`DEFAULT_TOLERANCES`, with ``overrides``).
    """
    tol = {**DEFAULT_TOLERANCES, **(overrides or {})}
    out = np.empty(len(model.unknowns))
    effect = None
    cam = model.context.get("cam")
    for i, u in enumerate(model.unknowns):
        if u.unit == "deg":
            out[i] = tol["rotation_deg"]
        elif u.unit == "mm":
            out[i] = tol["translation_mm"]
        else:
            if effect is None:
                effect = pixel_effect(cam)
            out[i] = tol["edge_px"] / max(float(effect[cam.param_names.index(u.coord)]), 1e-300)
    return out


@dataclass(frozen=True)
class WeakDirection:
    """A poorly determined combination of unknowns.

    Attributes:
        ratio: σ along the direction in tolerances (:func:`unknown_tolerances`): each unknown is divided by
            its tolerance, and ``ratio² `` is an eigenvalue of the scaled covariance. Above 1: the
            combination is known worse than the tolerance.
        components: ``[(label, weight)]`` of the unit eigenvector (scaled units), ``|weight| >= 0.2``,
            largest first, sign-normalised (first weight positive).
    """

    ratio: float
    components: tuple[tuple[str, float], ...]

    def describe(self) -> str:
        """E.g. ``T_flange_cam0 translation z (+0.93) + cam0 fy (-0.20)``."""
        return " + ".join(f"{n} ({w:+.2f})" for n, w in self.components)


def weak_directions(model: LinearModel, count: int = 3, overrides: Mapping[str, float] | None = None
                    ) -> list[WeakDirection]:
    """The ``count`` largest eigen-directions of the covariance of ``model`` scaled by tolerances.

    Dividing every unknown by its tolerance makes the directions comparable across units (px,
    unitless, deg, mm): the first one is the combination of unknowns the data determine worst
    relative to what matters (e.g. hand-eye translation along the only rotation axis together with
    the target pose, or focal length with the view distances when all views are fronto-parallel).
    """
    scale = np.array([u.scale for u in model.unknowns])
    t = unknown_tolerances(model, overrides) / scale  # internal units
    C = model.covariance() / t[:, None] / t[None, :]
    lam, vec = np.linalg.eigh(0.5 * (C + C.T))
    out = []
    for k in range(len(lam) - 1, max(len(lam) - 1 - count, -1), -1):
        v = vec[:, k] * np.sign(vec[np.argmax(np.abs(vec[:, k])), k])
        order = np.argsort(-np.abs(v))
        comps = tuple((model.unknowns[i].label, float(v[i])) for i in order if abs(v[i]) >= 0.2)
        out.append(WeakDirection(float(np.sqrt(max(lam[k], 0.0))), comps))
    return out


# ------------------------------------------------------------------------------------ what would help


#: Station kinds :func:`what_would_help` predicts, by problem kind: key -> description.
STATION_KINDS = {
    "camera": {
        "tilt_x": "a view with the target tilted 40° about the camera X axis",
        "tilt_y": "a view with the target tilted 40° about the camera Y axis",
        "closer": "a closer view (target filling ~90 % of the image height, tilted 20°)",
        "corner": "a view with the target in the worst image corner (tilted 20°)",
    },
    "hand-eye": {
        "rot_x": "a station rotated 30° about the camera X axis (orbiting the target)",
        "rot_y": "a station rotated 30° about the camera Y axis (orbiting the target)",
        "rot_z": "a station rotated 30° about the camera Z (optical) axis",
    },
}


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


@functools.cache
def _project_jit(model_cls: type, image_size: tuple[int, int], skew: bool):
    """Jitted ``(params (p,), p_cam (n, 3)) -> pixels (n, 2)``."""
    import jax

    return jax.jit(lambda q, p: model_cls.from_params(image_size, q, skew=skew).project(p))


@functools.cache
def _unproject_jit(model_cls: type, image_size: tuple[int, int], skew: bool):
    """Jitted ``(params (p,), pixels (n, 2)) -> (rays (n, 3), valid (n,))``."""
    import jax

    return jax.jit(lambda q, x: model_cls.from_params(image_size, q, skew=skew).unproject_valid(x))


def _project(cam: CameraResult, p_cam: np.ndarray) -> np.ndarray:
    """Pixels ``(n, 2)`` of camera-frame points ``(n, 3)`` (m), one compiled function per shape bucket."""
    import jax.numpy as jnp

    m = _camera_model(cam)
    n = p_cam.shape[0]
    fn = _project_jit(type(m), tuple(int(s) for s in m.image_size), bool(m.has_skew))
    return np.asarray(fn(jnp.asarray(cam.params), jnp.asarray(_pad(p_cam, _bucket(n)))))[:n]


def _unproject(cam: CameraResult, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays ``(n, 3)`` and validity ``(n,)`` of pixels ``(n, 2)``."""
    import jax.numpy as jnp

    m = _camera_model(cam)
    n = pixels.shape[0]
    fn = _unproject_jit(type(m), tuple(int(s) for s in m.image_size), bool(m.has_skew))
    rays, valid = fn(jnp.asarray(cam.params), jnp.asarray(_pad(np.asarray(pixels, np.float64), _bucket(n))))
    return np.asarray(rays)[:n], np.asarray(valid)[:n]


def _fits(cam: CameraResult, p_cam: np.ndarray, margin: float = 10.0) -> bool:
    if np.any(p_cam[:, 2] <= 1e-3):
        return False
    pix = _project(cam, p_cam)
    w, h = cam.image_size
    return bool(np.all((pix >= margin) & (pix <= np.array([w - 1 - margin, h - 1 - margin]))))


def _camera_candidate(model: LinearModel, kind: str) -> np.ndarray:
    """``T_cam_target`` (4, 4) of a predicted view of ``kind`` (see :data:`STATION_KINDS`)."""
    ctx = model.context
    cam: CameraResult = ctx["cam"]
    pts = ctx["points"]
    centroid = pts.mean(axis=0)
    depth = float(np.median([(T[:3, :3] @ centroid + T[:3, 3])[2] for T in ctx["T_cam_target"]]))
    w, h = cam.image_size
    tilt = {"tilt_x": ([1.0, 0, 0], 40.0), "tilt_y": ([0, 1.0, 0], 40.0)}.get(kind, ([1.0, 1.0, 0], 20.0))
    R = _rot(tilt[0], math.radians(tilt[1]))
    aim = np.array([(w - 1) / 2, (h - 1) / 2])
    if kind == "corner":
        u, v, sigma = projection_sigma_map(cam, grid=(9, 7), covariance=_intrinsics_cov(model))
        k = int(np.nanargmax(sigma))
        corner = np.array([u.ravel()[k], v.ravel()[k]])
        aim = corner + 0.25 * (np.array([(w - 1) / 2, (h - 1) / 2]) - corner)
    ray = _unproject(cam, aim[None, :])[0][0]
    ray = ray / ray[2]
    radius = float(np.max(np.linalg.norm(pts - centroid, axis=1)))
    start = depth
    if kind == "closer":
        fy = float(cam.K[1, 1])
        start = 2.0 * radius * fy / (0.9 * h)  # the target's diameter spans ~90 % of the height
    # the farthest distance <= start at which the whole target is inside the image, else move back
    d = start
    for _ in range(60):
        T = _pose(R, d * ray - R @ centroid)
        if _fits(cam, pts @ T[:3, :3].T + T[:3, 3]):
            return T
        d *= 1.08 if kind != "corner" else 1.0
        if kind == "corner":
            aim = aim + 0.1 * (np.array([(w - 1) / 2, (h - 1) / 2]) - aim)
            ray = _unproject(cam, aim[None, :])[0][0]
            ray = ray / ray[2]
    return _pose(R, d * ray - R @ centroid)


def _intrinsics_cov(model: LinearModel, added: np.ndarray | None = None) -> np.ndarray:
    """Full ``(p, p)`` intrinsics covariance (zeros for fixed ones) from a model's covariance."""
    cam: CameraResult = model.context["cam"]
    free = model.context["free"]
    C = model.covariance(added)
    out = np.zeros((len(cam.param_names),) * 2)
    out[np.ix_(free, free)] = C[: len(free), : len(free)]
    return out


def _handeye_candidate(model: LinearModel, kind: str) -> np.ndarray:
    """Flange pose ``T_base_flange`` (4, 4) of a predicted hand-eye station of ``kind``."""
    from jcalib.geometry import conversions

    ctx = model.context
    X = conversions.pose_to_matrix(ctx["X7"])
    Y = conversions.pose_to_matrix(ctx["Y7"])
    B = ctx["T_base_flange"]
    inv = np.linalg.inv
    if ctx["mount"] == "flange":
        T_ct = [inv(X) @ inv(b) @ Y for b in B]
    else:
        T_ct = [inv(X) @ b @ Y for b in B]
    centroid = ctx["points"].mean(axis=0)
    centres = np.array([T[:3, :3] @ centroid + T[:3, 3] for T in T_ct])
    ref = int(np.argmin(np.linalg.norm(centres - np.median(centres, axis=0), axis=1)))
    L = centres[ref]
    axis = {"rot_x": [1.0, 0, 0], "rot_y": [0, 1.0, 0], "rot_z": [0, 0, 1.0]}[kind]
    R = _rot(axis, math.radians(30.0))
    M = _pose(R, L - R @ L)  # rotation about an axis through the target centre, camera frame
    if ctx["mount"] == "flange":
        # camera moves: T_camref_camnew = M; B_new = B_ref X M X⁻¹
        return B[ref] @ X @ M @ inv(X)
    # fixed camera, target moves: T_cam_target_new = M T_cam_target_ref; B_new = X T_ct_new Y⁻¹
    return X @ M @ T_ct[ref] @ inv(Y)


def station_information(model: LinearModel, kind: str) -> np.ndarray:
    """Predicted information ``(n, n)`` one more station of ``kind`` adds (same units as
    ``model.information``): its Jacobian at the current estimate, its own pose eliminated (camera
    views; hand-eye stations under the robot-pose prior when the model has one).

    Args:
        kind: a key of :data:`STATION_KINDS` for ``model.kind``.
    """
    import jax.numpy as jnp

    kinds = STATION_KINDS[model.kind]
    if kind not in kinds:
        raise BadInputError(f"kind: got {kind!r}, expected one of {', '.join(kinds)} for a {model.kind} model")
    ctx = model.context
    pts = ctx["points"]
    N = len(pts)
    Np = max(_bucket(N), _bucket(len(ctx["group"])))  # the model's padded size: no new compilation
    cam: CameraResult = ctx["cam"]
    free = ctx["free"]
    if model.kind == "camera":
        T = _camera_candidate(model, kind)
        _, Jt, Jp = (np.asarray(a)[:N] for a in ctx["jacobian_fn"](
            jnp.asarray(cam.params), jnp.asarray(_pad(np.broadcast_to(_se3(T), (N, 7)), Np)),
            jnp.asarray(_pad(pts, Np))))
        S, _ = _assemble(Jt[..., free], Jp, np.zeros(N, np.int64), 1, None, np.ones(N), ctx["whiten"])
    else:
        Bn = _handeye_candidate(model, kind)
        _, Jt, JX, JY, JB = (np.asarray(a)[:N] for a in ctx["jacobian_fn"](
            jnp.asarray(cam.params), jnp.asarray(ctx["X7"]), jnp.asarray(ctx["Y7"]),
            jnp.asarray(_pad(np.broadcast_to(_se3(Bn), (N, 7)), Np)), jnp.asarray(_pad(pts, Np))))
        blocks = [Jt[..., free]]
        if ctx["hand_eye"] in ctx["blocks"]:
            blocks.append(JX)
        if ctx["target"] in ctx["blocks"]:
            blocks.append(JY)
        prior = ctx["pose_prior"]
        S, _ = _assemble(np.concatenate(blocks, axis=-1), JB if prior is not None else None,
                         np.zeros(N, np.int64), 1, prior,
                         np.ones(N), ctx["whiten"])
    return S / ctx["variance_factor"]


@dataclass(frozen=True)
class Suggestion:
    """The predicted effect of one more station of a kind.

    Attributes:
        kind, description: the station kind (:data:`STATION_KINDS`).
        sigma_before, sigma_after: ``{unknown label: σ}`` in display units for the unknowns asked for.
    """

    kind: str
    description: str
    sigma_before: dict[str, float]
    sigma_after: dict[str, float]

    def gain(self, label: str) -> float:
        """σ before / after for one unknown (> 1: the station helps)."""
        return self.sigma_before[label] / max(self.sigma_after[label], 1e-300)


def what_would_help(model: LinearModel, labels: Sequence[str] | None = None) -> list[Suggestion]:
    """Predicted σ of the ``labels`` unknowns if one station of each kind were added.

    Args:
        model: a linear model.
        labels: unknown labels (:attr:`Unknown.label`) to report; default all.

    Returns:
        One :class:`Suggestion` per kind of :data:`STATION_KINDS` for ``model.kind``, best first
        (largest gain on the first label).
    """
    all_labels = [u.label for u in model.unknowns]
    labels = list(labels) if labels is not None else all_labels
    idx = [all_labels.index(lab) for lab in labels]
    before = model.sigma()
    out = []
    for kind, text in STATION_KINDS[model.kind].items():
        after = model.sigma(station_information(model, kind))
        out.append(Suggestion(kind, text, {labels[k]: float(before[i]) for k, i in enumerate(idx)},
                              {labels[k]: float(after[i]) for k, i in enumerate(idx)}))
    if labels:
        out.sort(key=lambda s: -s.gain(labels[0]))
    return out


# ------------------------------------------------------------------------------------ residuals


@dataclass(frozen=True)
class RadialTest:
    """Radial residual structure: is the radial residual a function of the radius?

    Attributes:
        correlation: Pearson correlation of the radial residual with the radius.
        p_value: F-test p-value of a cubic in ``r / r_max`` (with intercept) against zero.
        amplitude_px: largest absolute value of the fitted cubic over the observed radii, px.
        flagged: ``p_value < 1e-4`` and ``amplitude_px >`` max(0.05 px, 0.5 σ̂): a too-simple lens
            model (or a wrong one) is likely.
    """

    correlation: float
    p_value: float
    amplitude_px: float
    flagged: bool


def radial_structure(pixels: np.ndarray, residuals: np.ndarray, centre: np.ndarray, sigma_px: float) -> RadialTest:
    """Test residuals ``(n, 2)`` (observed − predicted, px) at ``pixels`` for radial structure
    about ``centre (2,)`` (the principal point), given the a-posteriori σ (px)."""
    from scipy import stats as st

    d = pixels - centre[None, :]
    r = np.linalg.norm(d, axis=-1)
    e = np.sum(residuals * d, axis=-1) / np.maximum(r, 1e-9)
    n = e.size
    if n < 10:
        return RadialTest(0.0, 1.0, 0.0, False)
    rho = r / max(float(r.max()), 1e-9)
    A = np.stack([np.ones(n), rho, rho**2, rho**3], axis=-1)
    coef, *_ = np.linalg.lstsq(A, e, rcond=None)
    fit = A @ coef
    rss1 = float(np.sum((e - fit) ** 2))
    rss0 = float(np.sum(e**2))
    k = A.shape[1]
    F = ((rss0 - rss1) / k) / max(rss1 / (n - k), 1e-300)
    p = float(st.f.sf(F, k, n - k))
    corr = float(np.corrcoef(r, e)[0, 1]) if np.std(r) > 0 and np.std(e) > 0 else 0.0
    grid = np.linspace(float(rho.min()), 1.0, 50)
    amp = float(np.max(np.abs(np.stack([np.ones(50), grid, grid**2, grid**3], -1) @ coef)))
    return RadialTest(corr, p, amp, bool(p < 1e-4 and amp > max(0.05, 0.5 * sigma_px)))


@dataclass
class ResidualDiagnostics:
    """Residuals of one camera re-projected with the result's estimate.

    Attributes:
        camera: camera id.
        pixels, residuals: ``(n, 2)`` observed corners and observed − predicted, px.
        view: ``(n,)`` station id of every corner.
        view_rms_px: station id -> RMS (per coordinate, px) of its corners.
        rms_px: RMS per coordinate over all corners, px.
        outliers: ``[(station id, index within the station's detection, |r| px)]`` with
            ``|r| > outlier_sigma · σ̂``, largest first.
        radial: :class:`RadialTest`.
    """

    camera: str
    pixels: np.ndarray
    residuals: np.ndarray
    view: np.ndarray
    view_rms_px: dict[str, float]
    rms_px: float
    outliers: list[tuple[str, int, float]]
    radial: RadialTest


def _camera_poses(result: Any, file: ResultFile, obs) -> dict[str, dict[str, np.ndarray]]:
    """station id -> camera id -> T_cam_target (4, 4) from the result (or derived for hand-eye)."""
    details = getattr(result, "details", None)
    poses = getattr(details, "T_cam_target", None) or file.extra.get(POSES_KEY)
    if poses:
        return {str(s): {str(c): np.asarray(T, np.float64) for c, T in per.items()} for s, per in poses.items()}
    layout = _hand_eye_layout(file)
    if layout is None:
        return {}
    camera, mount, he, tg, _ = layout
    X, Y = file.transforms[he].matrix, file.transforms[tg].matrix
    est = {}
    if details is not None and getattr(details, "T_base_flange", None) is not None:
        est = dict(zip(details.station_ids, details.T_base_flange))
    out = {}
    for st in obs.stations:
        B = est.get(st.id, st.T_base_flange)
        if B is None:
            continue
        B = np.asarray(B, np.float64)
        T = np.linalg.inv(X) @ (np.linalg.inv(B) if mount == "flange" else B) @ Y
        out[st.id] = {camera: T}
    return out


def residual_diagnostics(result: Any, observations: Any, outlier_sigma: float = 5.0
                         ) -> dict[str, ResidualDiagnostics]:
    """Per-camera residual diagnostics from the result's estimate and the observations.

    Residuals are re-projected with the result's intrinsics and per-view poses (camera cells: the
    result's ``T_cam_target``; hand-eye cells: from the hand-eye and target transforms and the flange
    poses, the estimated ones when ``result.details`` has them, else the measured ones).

    Args:
        result: a :class:`jcalib.Result`, a :class:`ResultFile` or a path.
        observations: the observations (path, dict or ``Observations``).
        outlier_sigma: corners with ``|r| >`` this many a-posteriori σ are flagged.

    Returns:
        ``{camera id: ResidualDiagnostics}`` for cameras with poses.
    """

    from jcalib.io.observations import load_observations

    file = result_file(result)
    obs = load_observations(observations)
    poses = _camera_poses(result, file, obs)
    sigma = float(file.stats.get("sigma_px", 0.0)) or None
    out = {}
    for name, cam in file.cameras.items():
        P, X, V, I = [], [], [], []
        for st in obs.stations:
            T = poses.get(st.id, {}).get(name)
            if T is None:
                continue
            for det in st.detections:
                if det.camera != name or det.target is None or det.target not in obs.targets:
                    continue
                pts = np.asarray(obs.targets[det.target], np.float64)[det.point_index]
                P.append(pts @ T[:3, :3].T + T[:3, 3][None, :])
                X.append(np.asarray(det.pixels, np.float64))
                V += [st.id] * len(pts)
                I += list(range(len(pts)))
        if not P:
            continue
        pix = np.concatenate(X)
        res = pix - _project(cam, np.concatenate(P))
        view = np.asarray(V)
        norm = np.linalg.norm(res, axis=-1)
        view_rms = {}
        for sid in dict.fromkeys(V):
            sel = view == sid
            view_rms[sid] = float(np.sqrt(np.mean(res[sel] ** 2)))
        s = sigma if sigma is not None else float(np.sqrt(np.mean(res**2)))
        bad = np.flatnonzero(norm > outlier_sigma * s)
        outliers = sorted(((V[k], I[k], float(norm[k])) for k in bad), key=lambda t: -t[2])
        radial = radial_structure(pix, res, np.array([cam.K[0, 2], cam.K[1, 2]]), s)
        out[name] = ResidualDiagnostics(name, pix, res, view, view_rms, float(np.sqrt(np.mean(res**2))),
                                        outliers, radial)
    return out


# ------------------------------------------------------------------------------------ cross-validation


@dataclass
class CrossValidation:
    """Two calibrations on the two halves of the stations (even / odd), compared.

    Attributes:
        stations: ``(ids of half A, ids of half B)``.
        maps: camera id -> ``(u, v, diff, expected)``: grid pixels ``(ny, nx)``, the distance between
            the two halves' projections of the same ray (px, after the best-fit common rotation), and
            the expected distance from their reported covariances (``sqrt(σ_A² + σ_B²)``, worst
            direction each, px).
        transforms: transform name -> ``{"rotation_deg", "translation_mm"}``: difference between the
            halves, and ``{"rotation_sigma_deg", "translation_sigma_mm"}``: its expected 1σ (totals).
        results: the two half results (:class:`jcalib.Result`).
    """

    stations: tuple[list[str], list[str]]
    maps: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
    transforms: dict[str, dict[str, float]]
    results: tuple[Any, Any]


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation ``R`` minimising ``Σ |R a_i − b_i|²`` (unit vectors ``(n, 3)``)."""
    U, _, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))])
    return U @ D @ Vt


def projection_difference(cam_a: CameraResult, cam_b: CameraResult, grid: tuple[int, int] = (33, 25),
                          fit_rotation: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance (px) between where two calibrations of one camera project the same point.

    Each grid pixel is unprojected by ``cam_a`` to a ray; ``cam_b`` projects that ray (after the
    rotation that best aligns the two models' rays over the grid, when ``fit_rotation``: a small
    rotation of the camera frame is not a difference in the lens, mrcal's "projection_diff" with
    points at infinity). Returns ``(u, v, diff)``, each ``(ny, nx)``; NaN where a ray is invalid.
    """

    u, v = _grid(cam_a.image_size, grid)
    pix = np.stack([u.ravel(), v.ravel()], -1)
    ra, va = _unproject(cam_a, pix)
    rb, vb = _unproject(cam_b, pix)
    ok = va & vb & (ra[:, 2] > 1e-6) & (rb[:, 2] > 1e-6)
    ra = ra / np.linalg.norm(ra, axis=-1, keepdims=True)
    rb = rb / np.linalg.norm(rb, axis=-1, keepdims=True)
    R = _kabsch(ra[ok], rb[ok]) if fit_rotation and np.count_nonzero(ok) >= 3 else np.eye(3)
    proj = _project(cam_b, ra @ R.T)
    diff = np.where(ok, np.linalg.norm(proj - pix, axis=-1), np.nan)
    return u, v, diff.reshape(u.shape)


def cross_validate(cell: Any, observations: Any, options: Any = None, grid: tuple[int, int] = (33, 25)
                   ) -> CrossValidation:
    """Calibrate on the even and the odd stations separately and compare (mrcal-style).

    The difference in projection across the image is evidence beyond the reprojection error: if it is
    much larger than the expected ``sqrt(σ_A² + σ_B²)``, the reported σ are too small (model error,
    unmodelled effects); if comparable, they are honest.

    Args:
        cell: the cell spec (path, dict or ``CellSpec``).
        observations: the observations (path, dict or ``Observations``).
        options: calibration options passed to :func:`jcalib.calibrate` for both halves.
        grid: ``(nx, ny)`` pixels of the maps.

    Raises:
        BadInputError: fewer than 4 stations.
        NotObservableError: a half cannot determine the unknowns (propagated from the solver).
    """
    from dataclasses import replace

    from jcalib.problems.api import calibrate
    from jcalib.io.observations import load_observations

    obs = load_observations(observations)
    stations = [s for s in obs.stations if s.detections]
    if len(stations) < 4:
        raise BadInputError(
            f"observations: got {len(stations)} stations with detections, cross-validation needs at least 4")
    halves = (stations[0::2], stations[1::2])
    results = []
    for half in halves:
        results.append(calibrate(cell, replace(obs, stations=tuple(half)), options))
    fa, fb = results[0].file, results[1].file
    maps = {}
    for name, ca in fa.cameras.items():
        cb = fb.cameras.get(name)
        if cb is None:
            continue
        u, v, diff = projection_difference(ca, cb, grid)
        if ca.covariance is not None and cb.covariance is not None:
            sa = projection_sigma_map(ca, grid)[2]
            sb = projection_sigma_map(cb, grid)[2]
            expected = np.sqrt(sa**2 + sb**2)
        else:
            expected = np.full_like(diff, np.nan)
        maps[name] = (u, v, diff, expected)
    transforms = {}
    for name, ta in fa.transforms.items():
        tb = fb.transforms.get(name)
        if tb is None:
            continue
        from jcalib.geometry.conversions import matrix_to_rvec

        D = np.linalg.inv(ta.matrix) @ tb.matrix
        entry = {"rotation_deg": float(np.degrees(np.linalg.norm(matrix_to_rvec(D[:3, :3])))),
                 "translation_mm": float(1e3 * np.linalg.norm(ta.matrix[:3, 3] - tb.matrix[:3, 3]))}
        if ta.covariance is not None and tb.covariance is not None:
            C = np.asarray(ta.covariance) + np.asarray(tb.covariance)
            entry["rotation_sigma_deg"] = float(np.degrees(np.sqrt(np.trace(C[:3, :3]))))
            entry["translation_sigma_mm"] = float(1e3 * np.sqrt(np.trace(C[3:, 3:])))
        transforms[name] = entry
    return CrossValidation(([s.id for s in halves[0]], [s.id for s in halves[1]]), maps, transforms,
                           (results[0], results[1]))


# ------------------------------------------------------------------------------------ warnings


@dataclass(frozen=True)
class Warning:
    """One report warning: ``severity`` orders them (largest first); > 1 means over tolerance.

    Attributes:
        severity: σ / tolerance for weak unknowns; fixed levels for other findings.
        message: the text shown.
        unknown: label of the weak unknown it names, or None.
        fix: the station kind that helps most (:data:`STATION_KINDS` key), or None.
    """

    severity: float
    message: str
    unknown: str | None = None
    fix: str | None = None


def _fmt(x: float, unit: str) -> str:
    return f"{x:.3g} {unit}" if unit != "–" else f"{x:.3g}"


def analysis_warnings(
    file: ResultFile,
    models: Mapping[str, LinearModel] | None = None,
    residuals: Mapping[str, ResidualDiagnostics] | None = None,
    tolerances: Mapping[str, float] | None = None,
) -> list[Warning]:
    """The report's warnings, most severe first.

    Weak unknowns (σ above :data:`DEFAULT_TOLERANCES`, severity σ / tolerance) name the station kind
    that reduces their σ most (:func:`what_would_help`) and the predicted σ after one such station.
    A target pose (a nuisance unknown) counts 0.9 x its ratio, so at equal σ the hand-eye is named
    first. Then: worst projection σ over the image above tolerance (severity worst / tolerance, or
    1.05 when the camera also has a weak focal length or principal point, which are then its cause),
    a solver status other than converged (severity 100), radial residual structure (severity
    5 + amplitude / σ̂), flagged outliers (1.2) and the solver's own warnings (1.5).

    Args:
        file: the result file.
        models: from :func:`linear_models` (weak unknowns with a "what would help" need them;
            without, weak unknowns are judged from the file's σ alone).
        residuals: from :func:`residual_diagnostics`.
        tolerances: overrides of :data:`DEFAULT_TOLERANCES`.
    """
    tol = {**DEFAULT_TOLERANCES, **(tolerances or {})}
    out: list[Warning] = []
    status = file.stats.get("status")
    if status is not None and str(status) != "converged":
        out.append(Warning(100.0, f"solver status: {status} (not converged): the estimate and its σ are unreliable"))
    for w in file.stats.get("warnings") or []:
        out.append(Warning(1.5, f"solver: {w}"))
    models = dict(models or {})
    for model in models.values():
        sigma = model.sigma()
        tols = unknown_tolerances(model, tol)
        weak = []
        for i, u in enumerate(model.unknowns):
            # distortion terms trade off against each other: judged through the projection σ instead
            judged = u.unit in ("deg", "mm") or u.coord in ("fx", "fy", "cx", "cy")
            if judged and sigma[i] > tols[i]:
                # the target pose is a nuisance unknown: at equal σ / tolerance the hand-eye comes first
                demote = 0.9 if model.kind == "hand-eye" and u.block == model.context["target"] else 1.0
                weak.append((demote * sigma[i] / tols[i], i, tols[i]))
        weak.sort(reverse=True)
        cov = model.covariance()
        rho, _ = correlations(cov, [u.label for u in model.unknowns], top=0)
        helps = what_would_help(model, [model.unknowns[i].label for _, i, _ in weak]) if weak else []
        for ratio, i, t in weak:
            u = model.unknowns[i]
            partners = [model.unknowns[j].label for j in np.argsort(-np.abs(rho[i])) if j != i and abs(rho[i, j]) >= 0.7][:3]
            best = max(helps, key=lambda s: s.gain(u.label))
            msg = (f"{u.label} is weakly determined: σ = {_fmt(sigma[i], u.unit)} (tolerance {_fmt(t, u.unit)})"
                   + (f", correlated with {', '.join(partners)}" if partners else "")
                   + f". Add {best.description}: predicted σ {_fmt(best.sigma_before[u.label], u.unit)} → "
                   f"{_fmt(best.sigma_after[u.label], u.unit)}.")
            out.append(Warning(float(ratio), msg, u.label, best.kind))
        if model.kind == "camera":
            cam = model.context["cam"]
            u, v, s = projection_sigma_map(cam, grid=(9, 7), covariance=_intrinsics_cov(model))
            worst = float(np.nanmax(s))
            if worst > tol["projection_px"]:
                k = int(np.nanargmax(s))
                where = (float(u.ravel()[k]), float(v.ravel()[k]))
                best, best_after = None, worst
                for kind, text in STATION_KINDS["camera"].items():
                    after = projection_sigma_map(cam, grid=(9, 7),
                                                 covariance=_intrinsics_cov(model, station_information(model, kind)))[2]
                    a = float(after.ravel()[k])
                    if a < best_after:
                        best, best_after = (kind, text), a
                msg = (f"{model.context['camera']}: projection σ reaches {worst:.3g} px at pixel "
                       f"({where[0]:.0f}, {where[1]:.0f}) (tolerance {tol['projection_px']:g} px): the distortion "
                       "there is extrapolated")
                if best is not None:
                    msg += f". Add {best[1]}: predicted {worst:.3g} → {best_after:.3g} px."
                # with weak focal length / principal point, those warnings name the cause; this one follows
                severity = worst / tol["projection_px"] if not weak else 1.05
                if weak:
                    msg += " (mostly a consequence of the weak unknowns above)"
                out.append(Warning(severity, msg, f"{model.context['camera']} projection",
                                   None if best is None else best[0]))
    if not models:
        for name, tr in file.transforms.items():
            ts = transform_sigma(tr)
            if ts is None:
                continue
            for k, c in enumerate(_TANGENT):
                val, t = ((ts["rotation_deg"][k], tol["rotation_deg"]) if k < 3 else
                          (ts["translation_mm"][k - 3], tol["translation_mm"]))
                if val > t:
                    u = _transform_unknown(name, c)
                    out.append(Warning(float(val / t), f"{u.label} is weakly determined: σ = {_fmt(val, u.unit)} "
                                       f"(tolerance {_fmt(t, u.unit)}); give the report the observations for a "
                                       "hint on which stations would help.", u.label))
    for name, diag in (residuals or {}).items():
        sigma = float(file.stats.get("sigma_px", diag.rms_px))
        if diag.radial.flagged:
            out.append(Warning(
                5.0 + diag.radial.amplitude_px / max(sigma, 1e-9),
                f"{name}: the radial residuals follow the radius (fitted trend up to "
                f"{diag.radial.amplitude_px:.3g} px, p = {diag.radial.p_value:.1e}): the lens model is probably "
                "too simple (try one with more distortion terms); σ do not include this model error."))
        if diag.outliers:
            worst = diag.outliers[0]
            out.append(Warning(1.2, f"{name}: {len(diag.outliers)} corner(s) with a residual over 5σ̂ (worst "
                                    f"{worst[2]:.3g} px, station {worst[0]} corner {worst[1]}): check the detections"))
    out.sort(key=lambda w: -w.severity)
    return out

