"""The linear model of a calibration, read from its solve.

A :class:`LinearModel` holds the covariance and the information matrix of a calibration's *shared*
unknowns (every camera's free intrinsics, every transform's and cell point's free coordinates), with
the per-station unknowns (free target poses, flange-pose corrections) marginalised, exactly as the
solve computed them: the covariance is :meth:`jcalib.solve.Solution.joint_covariance`, the
information :meth:`jcalib.solve.Solution.information` (a test checks that one inverts the other). The
report never rebuilds Jacobians or normal equations of the calibration; adding the information a
hypothetical station would bring (:mod:`jcalib.report.candidates`, linearised by
:func:`jcalib.solve.information`) gives the covariance that station would leave.

Where the solve comes from (:func:`calibration_of`): the :class:`~jcalib.problems.assemble.Calibration`
of an in-memory :class:`jcalib.Result` (``result.details``), or, for a ``result.json`` with its
observations and cell spec, :func:`jcalib.problems.calibrate.restore`, which rebuilds the problem with
the one builder and re-solves it from the file's values (it stays at the file's optimum).

Units: the solve's (pixels for ``fx..cy``, unitless distortion, radians and metres for transform
tangents ``(rx, ry, rz, tx, ty, tz)``, right perturbation in the transform's child frame, metres for
points). Every :class:`Unknown` carries the factor to its display unit (px, –, deg, mm). Transforms
are in the result's basis (a tool whose orientation was calibrated is reported at the convention for
its roll: its tangent is rotated alike, as in the result file).

What every σ includes: the sampling noise of the observations (pixel noise, robot pose noise as stated
with the pose model, each kind's variance component as the solve estimated it), propagated to first
order. What it does not include: model error, a wrong local minimum, nonlinearity beyond first order.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg

from jcalib.errors import BadInputError
from jcalib.io.result import ResultFile, load_result

__all__ = [
    "JOINT_COVARIANCE_KEY",
    "TANGENT",
    "LinearModel",
    "Unknown",
    "calibration_of",
    "correlations",
    "intrinsic_unknown",
    "joint_covariance",
    "kinematic_unknown",
    "linear_model",
    "model_from_file",
    "options_of",
    "point_unknown",
    "result_file",
    "transform_unknown",
    "warp_unknown",
]

#: Optional top-level key of a result file with the joint covariance of the shared unknowns
#: (``{"names", "dims", "matrix"}``, written by :func:`jcalib.problems.calibrate.result_file`).
JOINT_COVARIANCE_KEY = "joint_covariance"

#: Tangent coordinates of a transform, in covariance order.
TANGENT = ("rx", "ry", "rz", "tx", "ty", "tz")
_WORDS = {"rx": "rotation x", "ry": "rotation y", "rz": "rotation z",
          "tx": "translation x", "ty": "translation y", "tz": "translation z"}
_PIXEL_PARAMS = ("fx", "fy", "cx", "cy", "skew")


# ------------------------------------------------------------------------------------ unknowns


@dataclass(frozen=True)
class Unknown:
    """One scalar unknown of a linear model.

    Attributes:
        block: the camera id (intrinsics), the transform name (``T_flange_cam0``) or ``point <name>``.
        coord: the intrinsic name (``fx``, ``k1``…), tangent coordinate (``rx``…``tz``) or ``x, y, z``.
        unit: display unit (``px``, ``–``, ``deg``, ``mm``).
        scale: display value per internal unit (1, 180/π, 1000).
        role: what the block is: ``intrinsics``, ``camera``, ``target``, ``tool``, ``robot``, ``point``
            or ``pose`` (anything else).
    """

    block: str
    coord: str
    unit: str
    scale: float
    role: str = "pose"

    @property
    def label(self) -> str:
        """Human name, e.g. ``cam0 fx`` or ``T_flange_cam0 translation z``."""
        return f"{self.block} {_WORDS.get(self.coord, self.coord)}"

    @property
    def key(self) -> str:
        """Machine name ``block.coord``."""
        return f"{self.block}.{self.coord}"


def intrinsic_unknown(camera: str, name: str) -> Unknown:
    return Unknown(camera, name, "px" if name in _PIXEL_PARAMS else "–", 1.0, "intrinsics")


def transform_unknown(transform: str, coord: str, role: str = "pose") -> Unknown:
    if coord.startswith("r"):
        return Unknown(transform, coord, "deg", 180.0 / math.pi, role)
    return Unknown(transform, coord, "mm", 1000.0, role)


def point_unknown(point: str, coord: str) -> Unknown:
    return Unknown(f"point {point}", coord, "mm", 1000.0, "point")


#: The coordinates of a board warp (``warp:<target>``), in covariance order.
WARP_COORDS = ("c0", "c1")


def warp_unknown(target: str, coord: str) -> Unknown:
    """A board warp coefficient (``c0`` along the target's x, ``c1`` along its y), displayed in mm."""
    return Unknown(f"warp:{target}", coord, "mm", 1000.0, "target")


def kinematic_unknown(robot: str, name: str) -> Unknown:
    """A kinematic parameter ``<joint>.<param>`` (or ``base.*``/``flange.*``) of a robot, in mm or deg."""
    if name.rsplit(".", 1)[-1] in ("a", "d", "tx", "ty", "tz"):
        return Unknown(f"kinematics:{robot}", name, "mm", 1000.0, "robot")
    return Unknown(f"kinematics:{robot}", name, "deg", 180.0 / math.pi, "robot")


# ------------------------------------------------------------------------------------ the model


@dataclass
class Block:
    """One variable of the solve as the model sees it.

    Attributes:
        variable: the solve's variable name (``intrinsics:cam0``, ``T_flange_cam0``, ``point:divot``).
        dim: its tangent dimension; ``basis``: ``(dim, dim)`` orthogonal map from the solve's tangent
            to the reported one; ``free``: ``(dim,)`` coordinates that are unknowns (reported basis).
    """

    variable: str
    dim: int
    basis: np.ndarray
    free: np.ndarray


@dataclass
class LinearModel:
    """The covariance and information of a calibration's shared unknowns at its estimate.

    Attributes:
        name: what the model covers (``"cell"``; ``"joint covariance"`` for one read from a file).
        kind: ``"camera"`` (no robot), ``"hand-eye"`` (a robot, no tools) or ``"cell"``.
        unknowns: the free shared unknowns, in matrix order.
        information: ``(n, n)`` information (inverse covariance), internal units.
        base_covariance: ``(n, n)`` the solve's covariance (``inv(information)`` up to rounding).
        blocks: the solve's variables behind the unknowns (to map a candidate station's information).
        param_names: camera id -> its intrinsic names (order of its covariance).
        calibration: the :class:`~jcalib.problems.assemble.Calibration` (None for a model from a file).
        options: the calibration's :class:`~jcalib.problems.options.CalibrationOptions`.
        variance_factor: what the solve's stated-noise information is divided by (σ̂² or 1).
        aspect: camera -> ``fx / fy`` of a camera whose aspect ratio is held (``fix: [aspect]``): its ``fy``
            follows ``fx`` and is no unknown of its own.
        predictions: candidate key -> the information it adds (filled by
            :func:`jcalib.report.candidates.station_information`).
    """

    name: str
    kind: str
    unknowns: tuple[Unknown, ...]
    information: np.ndarray
    base_covariance: np.ndarray
    blocks: list[Block] = field(default_factory=list, repr=False)
    param_names: dict[str, tuple[str, ...]] = field(default_factory=dict, repr=False)
    calibration: Any = field(default=None, repr=False)
    options: Any = field(default=None, repr=False)
    variance_factor: float = 1.0
    aspect: dict[str, float] = field(default_factory=dict, repr=False)
    predictions: dict = field(default_factory=dict, repr=False)

    @property
    def labels(self) -> list[str]:
        return [u.label for u in self.unknowns]

    def covariance(self, added: np.ndarray | None = None) -> np.ndarray:
        """``(n, n)`` covariance (internal units): the solve's, or after adding information ``added``.

        The update starts from the solve's covariance ``C`` (push-through identity,
        ``(H + A)⁻¹ = C − C A (I + C A)⁻¹ C``), not from inverting the information: a direction the solve
        holds by convention (a tool's rotation about its own axis, seen in another frame) has no
        information, so ``H + A`` may be singular while the update stays in what ``C`` spans.
        """
        if added is None:
            return self.base_covariance
        C, A = self.base_covariance, 0.5 * (added + added.T)
        d = np.sqrt(np.maximum(np.diag(C), 1e-300))  # unit σ: the update is well scaled whatever the units
        Cs, As = C / d[:, None] / d[None, :], A * d[:, None] * d[None, :]
        out = Cs - Cs @ As @ np.linalg.solve(np.eye(len(C)) + Cs @ As, Cs)
        return 0.5 * (out + out.T) * d[:, None] * d[None, :]

    def sigma(self, added: np.ndarray | None = None) -> np.ndarray:
        """``(n,)`` 1σ of every unknown in display units."""
        scale = np.array([u.scale for u in self.unknowns])
        return np.sqrt(np.maximum(np.diag(self.covariance(added)), 0.0)) * scale

    def index(self, block: str, coord: str) -> int:
        """Position of unknown ``block.coord``; BadInputError when it is not a free unknown."""
        for i, u in enumerate(self.unknowns):
            if u.block == block and u.coord == coord:
                return i
        raise BadInputError(f"unknown: got {block}.{coord}, expected one of {', '.join(u.key for u in self.unknowns)}")

    def camera_covariance(self, camera: str, added: np.ndarray | None = None) -> np.ndarray | None:
        """Full ``(p, p)`` intrinsics covariance of ``camera`` (zeros where held), or None without one."""
        names = self.param_names.get(camera)
        idx = [i for i, u in enumerate(self.unknowns) if u.block == camera and u.role == "intrinsics"]
        if names is None or not idx:
            return None
        C = self.covariance(added)
        out = np.zeros((len(names), len(names)))
        pos = [names.index(self.unknowns[i].coord) for i in idx]
        out[np.ix_(pos, pos)] = C[np.ix_(idx, idx)]
        ratio = self.aspect.get(camera)
        if ratio is not None and "fx" in names and "fy" in names:  # fy = fx / ratio
            fx, fy = names.index("fx"), names.index("fy")
            out[fy, :], out[:, fy] = out[fx, :] / ratio, out[:, fx] / ratio
            out[fy, fy] = out[fx, fx] / ratio**2
        return out

    def expand(self, names: Sequence[str], dims: Sequence[int], matrix: np.ndarray) -> np.ndarray:
        """``(n, n)`` over the model's unknowns from information over whole variables of the solve.

        Args:
            names, dims: variables of the solve and their tangent dimensions.
            matrix: ``(Σ dims, Σ dims)`` information over those variables (entry-major, the solve's
                basis), e.g. from :func:`jcalib.solve.information`. Variables the model lacks are
                dropped; model variables not in ``names`` get zeros.
        """
        M = np.asarray(matrix, np.float64)
        offsets = np.concatenate([[0], np.cumsum(dims)]).astype(int)
        where = {n: np.arange(offsets[k], offsets[k + 1]) for k, n in enumerate(names)}
        start = np.concatenate([[0], np.cumsum([b.dim for b in self.blocks])]).astype(int)
        full = np.zeros((int(start[-1]),) * 2)
        for a, ba in enumerate(self.blocks):
            for b, bb in enumerate(self.blocks):
                if ba.variable in where and bb.variable in where:
                    blk = ba.basis @ M[np.ix_(where[ba.variable], where[bb.variable])] @ bb.basis.T
                    full[start[a]:start[a + 1], start[b]:start[b + 1]] = blk
        keep = np.concatenate([b.free for b in self.blocks]) if self.blocks else np.zeros(0, bool)
        return full[np.ix_(keep, keep)]

    @property
    def variables(self) -> list[str]:
        """The solve's variables behind the unknowns, in order."""
        return [b.variable for b in self.blocks]


def _role(g, name: str) -> str:
    cell = g.cell
    for spec in cell.cameras.values():
        if g.mount_name(spec) == name:
            return "camera"
    for spec in cell.targets.values():
        if g.mount_name(spec) == name:
            return "target"
    if name.startswith("T_flange_") and name[9:] in cell.tools:
        return "tool"
    if name.startswith("T_world_") and name[8:] in g.robot_names:
        return "robot"
    return "pose"


def _kind(cal) -> str:
    g = cal.graph
    if not g.has_robot:
        return "camera"
    return "cell" if (g.cell.tools or g.cell.points or g.multi) else "hand-eye"


def linear_model(cal, options=None) -> LinearModel:
    """The :class:`LinearModel` of a calibration, from its solution.

    Args:
        cal: a :class:`~jcalib.problems.assemble.Calibration` with its ``solution``, ``graph`` and ``built``.
        options: the :class:`~jcalib.problems.options.CalibrationOptions` it was computed with (kept for
            the candidate stations of :mod:`jcalib.report.candidates`).
    """
    from jcalib.problems.build import se3_matrix

    sol, noise = cal.solution, cal.covariance_noise
    layout = sol.layout
    blocks, unknowns = [], []

    def shared(var: str) -> bool:
        return var in layout.names and not layout.eliminate[layout.kind(var)]

    def add(var: str, basis: np.ndarray, make) -> None:
        fixed = np.asarray(sol.problem.variable(var).fixed, bool)[0]
        free = (np.abs(basis) @ (~fixed).astype(float)) > 0.0
        if not free.any():
            return
        blocks.append(Block(var, basis.shape[0], basis, free))
        unknowns.extend(make(j) for j in np.flatnonzero(free))

    for c, model in cal.cameras.items():
        var = f"intrinsics:{c}"
        if shared(var):
            names = tuple(model.param_names)
            add(var, np.eye(len(names)), lambda j, c=c, names=names: intrinsic_unknown(c, names[j]))
    for name in cal.transforms:
        if shared(name):
            Q = cal.transforms[name][:3, :3].T @ se3_matrix(sol.values[name][0])[:3, :3]
            role = _role(cal.graph, name)
            add(name, np.kron(np.eye(2), Q), lambda j, n=name, r=role: transform_unknown(n, TANGENT[j], r))
    for p in cal.points:
        var = f"point:{p}"
        if shared(var):
            add(var, np.eye(3), lambda j, p=p: point_unknown(p, "xyz"[j]))
    for t in cal.warps:
        var = f"warp:{t}"
        if shared(var):
            add(var, np.eye(2), lambda j, t=t: warp_unknown(t, WARP_COORDS[j]))
    names = [b.variable for b in blocks]
    B = scipy.linalg.block_diag(*[b.basis for b in blocks]) if blocks else np.zeros((0, 0))
    keep = np.concatenate([b.free for b in blocks]) if blocks else np.zeros(0, bool)
    C = B @ sol.joint_covariance(names, noise=noise) @ B.T
    H = B @ sol.information(names, noise=noise) @ B.T
    C, H = C[np.ix_(keep, keep)], H[np.ix_(keep, keep)]
    aspect = {}
    for c, m in cal.cameras.items():
        spec = cal.graph.cell.cameras.get(c)
        if spec is not None and "aspect" in spec.fix:
            params = np.asarray(m.params)
            aspect[c] = float(params[0] / params[1])
    return LinearModel("cell", _kind(cal), tuple(unknowns), 0.5 * (H + H.T), 0.5 * (C + C.T), blocks,
                       {c: tuple(m.param_names) for c, m in cal.cameras.items()}, cal, options,
                       sol.variance_factor(noise), aspect)


# ------------------------------------------------------------------------------------ loading


def result_file(result: Any) -> ResultFile:
    """The :class:`ResultFile` of a :class:`jcalib.Result`, a ``ResultFile`` or a path."""
    file = getattr(result, "file", None)
    if isinstance(file, ResultFile):
        return file
    return load_result(result)


def options_of(file: ResultFile):
    """The calibration options a result file records (:func:`jcalib.problems.calibrate.options_of`)."""
    from jcalib.problems.calibrate import options_of as of

    return of(file)


def calibration_of(result: Any, observations: Any = None, cell: Any = None, options: Any = None):
    """The :class:`~jcalib.problems.assemble.Calibration` (with its solution) behind a result, or None.

    Args:
        result: a :class:`jcalib.Result` (its ``details``), a :class:`ResultFile` or a path.
        observations, cell: the observations and cell spec the result was computed from (path, dict or
            parsed): without ``details``, the calibration is restored from the file with both
            (:func:`jcalib.problems.calibrate.restore`); without either, None.
        options: the calibration options (default: the file's provenance).

    Raises:
        BadInputError: the result, observations and cell do not belong together.
    """
    details = getattr(result, "details", None)
    if details is not None and getattr(details, "solution", None) is not None:
        return details
    if observations is None or cell is None:
        return None
    from jcalib.io.cell import load_cell
    from jcalib.io.observations import load_observations
    from jcalib.problems.calibrate import restore

    file = result_file(result)
    missing = sorted(set(file.cameras) - set(load_cell(cell).cameras))
    if missing:
        raise BadInputError(f"cell: the result has camera(s) {missing} that the cell spec does not; give the cell "
                            "spec the result was computed from")
    cal = restore(load_cell(cell), load_observations(observations), file, options)
    _check_restored(cal, file)
    return cal


#: The restored solve must stay within this many σ of the file's estimate (it starts there).
RESTORE_TOLERANCE_SIGMA = 1e-3


def _check_restored(cal, file: ResultFile) -> None:
    """Raise when the restored solve left the file's estimate: the inputs are not the result's."""
    from jcalib.geometry.se3 import log_se3

    worst, where = 0.0, None
    for c, cam in file.cameras.items():
        if c in cal.cameras:
            std = np.sqrt(np.maximum(np.diag(cal.intrinsics_covariance[c]), 0.0))
            d = np.abs(np.asarray(cal.cameras[c].params) - np.asarray(cam.params))
            z = np.where(std > 0, d / np.where(std > 0, std, 1.0), np.where(d > 1e-9 * (1 + np.abs(cam.params)), np.inf, 0))
            if z.max() > worst:
                worst, where = float(z.max()), f"{c} {cam.param_names[int(np.argmax(z))]}"
    for n, tr in file.transforms.items():
        if n in cal.transforms:
            std = np.sqrt(np.maximum(np.diag(cal.transform_covariance[n]), 0.0))
            d = np.abs(np.asarray(log_se3(np.linalg.inv(tr.matrix) @ cal.transforms[n])))
            z = np.where(std > 0, d / np.where(std > 0, std, 1.0), np.where(d > 1e-9, np.inf, 0))
            if z.max() > worst:
                worst, where = float(z.max()), f"{n} {TANGENT[int(np.argmax(z))]}"
    for t, target in file.targets.items():
        if t in cal.warps:
            std = np.sqrt(np.maximum(np.diag(cal.warp_covariance[t]), 0.0))
            d = np.abs(cal.warps[t] - target.warp_m)
            z = np.where(std > 0, d / np.where(std > 0, std, 1.0), np.where(d > 1e-12, np.inf, 0))
            if z.max() > worst:
                worst, where = float(z.max()), f"{t} warp {WARP_COORDS[int(np.argmax(z))]}"
    for r, k in file.kinematics.items():
        if r in cal.kinematics:
            mine = cal.kinematics[r]
            if tuple(mine["model"].param_names) != tuple(k.names):
                raise BadInputError(f"cell: the kinematics of robot '{r}' has other parameters than the result's; give "
                                    "the cell spec the result was computed from")
            std = np.sqrt(np.maximum(np.diag(np.asarray(mine["covariance"])), 0.0))
            d = np.abs(np.asarray(mine["params"]) - k.values)
            z = np.where(std > 0, d / np.where(std > 0, std, 1.0), np.where(d > 1e-12, np.inf, 0))
            if z.max() > worst:
                worst, where = float(z.max()), f"kinematics of {r} {k.names[int(np.argmax(z))]}"
    if worst > RESTORE_TOLERANCE_SIGMA:
        raise BadInputError(
            f"observations, cell: re-solving the result with them moves {where} by {worst:.3g} σ from the result's "
            "value; give the observations and cell spec the result was computed from")


def model_from_file(file: ResultFile) -> LinearModel | None:
    """A model from the file's joint covariance (:data:`JOINT_COVARIANCE_KEY`), or None without one.

    It has the solve's covariance, not its solution: enough for correlations and weak directions, not
    for predicting stations (``calibration`` is None).
    """
    joint = joint_covariance(file)
    if joint is None:
        return None
    unknowns, C = joint
    keep = []  # unknowns with a variance of their own (not held, not tied to an earlier one, e.g. fy to fx)
    d = np.sqrt(np.maximum(np.diag(C), 0.0))
    for i in np.flatnonzero(d > 0.0):
        if all(abs(C[i, j]) < (1.0 - 1e-9) * d[i] * d[j] for j in keep):
            keep.append(int(i))
    C = C[np.ix_(keep, keep)]
    H = np.linalg.inv(C)
    return LinearModel("joint covariance", "cell", tuple(unknowns[i] for i in keep), 0.5 * (H + H.T), C,
                       param_names={c: tuple(cam.param_names) for c, cam in file.cameras.items()})


def joint_covariance(file: ResultFile) -> tuple[tuple[Unknown, ...], np.ndarray] | None:
    """The file's :data:`JOINT_COVARIANCE_KEY` as ``(unknowns, covariance)``, or None."""
    data = file.extra.get(JOINT_COVARIANCE_KEY)
    if data is None:
        return None
    try:
        names = [str(n) for n in data["names"]]
        C = np.asarray(data["matrix"], np.float64)
        pairs = [tuple(n.rpartition(".")[::2]) for n in names]  # (block, coord)
        if "dims" in data:  # block form: one name per block (a camera's intrinsics or a transform), its dimension
            pairs = []
            for n, d in zip(names, data["dims"], strict=True):
                if n.startswith("kinematics:") and n[11:] not in file.kinematics:
                    raise ValueError(f"block {n!r} names a robot without a kinematics entry in the result")
                coords = (file.cameras[n].param_names if n in file.cameras
                          else file.kinematics[n[11:]].names if n.startswith("kinematics:")
                          else WARP_COORDS if n.startswith("warp:") else TANGENT)
                if len(coords) != int(d):
                    raise ValueError(f"block {n!r} has {d} coordinates, expected {len(coords)}")
                pairs += [(n, c) for c in coords]
    except (KeyError, TypeError, ValueError) as err:
        raise BadInputError(f"{JOINT_COVARIANCE_KEY}: expected {{names: [...], matrix: n x n}}, got {err}") from None
    if C.shape != (len(pairs), len(pairs)) or not np.all(np.isfinite(C)):
        raise BadInputError(
            f"{JOINT_COVARIANCE_KEY}.matrix: expected a finite {len(pairs)}x{len(pairs)} matrix, got shape {C.shape}")
    unknowns = []
    for block, coord in pairs:
        if block.startswith("warp:") and coord in WARP_COORDS:
            unknowns.append(warp_unknown(block[5:], coord))
        elif block.startswith("kinematics:"):
            unknowns.append(kinematic_unknown(block[11:], coord))
        else:
            unknowns.append(transform_unknown(block, coord) if coord in TANGENT else intrinsic_unknown(block, coord))
    return tuple(unknowns), C


def correlations(covariance: np.ndarray, labels: Sequence[str], top: int = 8, minimum: float = 0.5
                 ) -> tuple[np.ndarray, list[tuple[str, str, float]]]:
    """Correlation matrix and the strongest pairs.

    Args:
        covariance: ``(n, n)``; labels: ``n`` names.
        top: at most this many pairs; minimum: only pairs with ``|ρ| >= minimum``.

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
