"""What to tell the user: tolerances, weakest directions and the ordered warnings.

Every number comes from the model of :mod:`jcalib.report.model` (the solve's covariance and
information), the predictions of :mod:`jcalib.report.candidates` and the solve's residuals
(:mod:`jcalib.report.diagnostics`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from jcalib.errors import JcalibError
from jcalib.io.result import ResultFile
from jcalib.report.candidates import candidates, station_information, what_would_help
from jcalib.report.diagnostics import ResidualDiagnostics
from jcalib.report.model import TANGENT, LinearModel, correlations, transform_unknown
from jcalib.problems.taskspace import image_grid, pixel_effect, projection_sigma_at, transform_sigma

__all__ = ["DEFAULT_TOLERANCES", "NO_SOLVE_HINT", "Warning", "WeakDirection", "analysis_warnings", "goal_tolerances",
           "projection_warning", "stated_once", "unknown_tolerances", "weak_directions"]

#: Tolerances a σ is compared with to call an unknown weak (each can be overridden):
#: ``edge_px``: the displacement of some image point (edges and corners included) caused by 1 σ of an
#: intrinsic; ``projection_px``: worst σ of the projection over the image, pixels;
#: ``rotation_deg`` / ``translation_mm``: 1 σ of any axis of a transform (hand-eye, TCP, target pose,
#: robot base) or of a cell point (mm).
DEFAULT_TOLERANCES = {"edge_px": 2.0, "projection_px": 1.0, "rotation_deg": 0.05, "translation_mm": 0.5}

#: A target pose is a nuisance unknown: at equal σ / tolerance the hand-eye (or TCP) is named first.
NUISANCE_WEIGHT = 0.9

#: Said once under the warnings when weak unknowns are judged without the solve (a result file alone).
NO_SOLVE_HINT = ("give the report the observations and the cell spec the result was computed from (or the "
                 "in-memory result of jcalib.calibrate) for a hint on which stations would help")


def goal_tolerances(goals) -> dict[str, float]:
    """Tolerances from accuracy goals (:class:`jcalib.io.goals.Goal` s): per transform, point or camera,
    overriding :data:`DEFAULT_TOLERANCES` for the unknowns a goal names.

    A transform's ``rotation_deg`` / ``translation_mm`` (``position_mm``) goal becomes the tolerance of its
    rotation / translation coordinates (key ``"T_flange_cam0.rotation_deg"``), a point's ``position_mm`` that of
    its coordinates (``"point divot.translation_mm"``), a camera's ``projection_px`` that of its projection
    (``"cam0.projection_px"``). A goal bounds the worst-direction σ, so a coordinate over its goal's limit means
    the goal is not met either.
    """
    out = {}
    for g in goals:
        if g.measures == "projection":
            out[f"{g.name}.projection_px"] = g.limit
        elif g.is_transform:
            out[f"{g.name}.{'rotation_deg' if g.measures == 'rotation' else 'translation_mm'}"] = g.limit
        else:
            out[f"point {g.name}.translation_mm"] = g.limit
    return out


def _tolerance(tol: Mapping[str, float], block: str, kind: str) -> tuple[float, bool]:
    """``(tolerance, from a goal)`` of ``block``'s ``kind`` (``rotation_deg``, ``translation_mm``, ``projection_px``)."""
    key = f"{block}.{kind}"
    return (float(tol[key]), True) if key in tol else (float(tol[kind]), False)


def unknown_tolerances(model: LinearModel, overrides: Mapping[str, float] | None = None,
                       cameras: Mapping | None = None) -> np.ndarray:
    """``(n,)`` tolerance of every unknown of ``model`` in display units.

    Intrinsics: the change that moves some image point by ``edge_px`` pixels (:func:`pixel_effect`);
    transform rotations ``rotation_deg``, translations and points ``translation_mm`` (per block where
    ``overrides`` has a key of :func:`goal_tolerances`).

    Args:
        cameras: camera id -> model or :class:`CameraResult` (default: the model's calibration's).
    """
    tol = {**DEFAULT_TOLERANCES, **(overrides or {})}
    if cameras is None:
        cameras = {} if model.calibration is None else model.calibration.cameras
    out = np.empty(len(model.unknowns))
    effects: dict[str, np.ndarray] = {}
    for i, u in enumerate(model.unknowns):
        if u.unit == "deg":
            out[i] = _tolerance(tol, u.block, "rotation_deg")[0]
        elif u.unit == "mm":
            out[i] = _tolerance(tol, u.block, "translation_mm")[0]
        elif u.block in cameras:
            if u.block not in effects:
                effects[u.block] = pixel_effect(cameras[u.block])
            j = model.param_names[u.block].index(u.coord)
            out[i] = tol["edge_px"] / max(float(effects[u.block][j]), 1e-300)
        else:
            out[i] = np.inf
    return out


@dataclass(frozen=True)
class WeakDirection:
    """A poorly determined combination of unknowns.

    Attributes:
        ratio: σ along the direction in tolerances: each unknown is divided by its tolerance and
            ``ratio²`` is an eigenvalue of the scaled covariance. Above 1: worse than the tolerance.
        components: ``[(label, weight)]`` of the unit eigenvector (scaled units), ``|weight| >= 0.2``,
            largest first, sign-normalised (the largest weight positive).
    """

    ratio: float
    components: tuple[tuple[str, float], ...]

    def describe(self) -> str:
        """E.g. ``T_flange_cam0 translation z (+0.93) + cam0 fy (-0.20)``."""
        return " + ".join(f"{n} ({w:+.2f})" for n, w in self.components)


def weak_directions(model: LinearModel, count: int = 3, overrides: Mapping[str, float] | None = None,
                    cameras: Mapping | None = None) -> list[WeakDirection]:
    """The ``count`` largest eigen-directions of the model's covariance scaled by the tolerances.

    Dividing every unknown by its tolerance makes the directions comparable across units (px,
    unitless, deg, mm): the first one is the combination the data determine worst relative to what
    matters (e.g. a hand-eye translation along the only rotation axis with the target pose).
    Unknowns without a tolerance (distortion of a camera the model has no lens for) are left out.
    """
    scale = np.array([u.scale for u in model.unknowns])
    t = unknown_tolerances(model, overrides, cameras) / scale
    ok = np.isfinite(t)
    C = model.covariance()[np.ix_(ok, ok)] / t[ok][:, None] / t[ok][None, :]
    labels = [u.label for u, keep in zip(model.unknowns, ok) if keep]
    lam, vec = np.linalg.eigh(0.5 * (C + C.T))
    out = []
    for k in range(len(lam) - 1, max(len(lam) - 1 - count, -1), -1):
        v = vec[:, k] * np.sign(vec[np.argmax(np.abs(vec[:, k])), k])
        order = np.argsort(-np.abs(v))
        comps = tuple((labels[i], float(v[i])) for i in order if abs(v[i]) >= 0.2)
        out.append(WeakDirection(float(np.sqrt(max(lam[k], 0.0))), comps))
    return out


@dataclass(frozen=True)
class Warning:
    """One report warning: ``severity`` orders them (largest first); > 1 means over tolerance.

    Attributes:
        severity: σ / tolerance for weak unknowns; fixed levels for other findings.
        message: the text shown (the finding and what is specific to it).
        unknown: label of the weak unknown it names, or None.
        fix: the key of the candidate station that helps most, or None.
        hint: advice that does not depend on this warning alone (e.g. what to give the report for a
            station hint): stated once for all the warnings that share it (:func:`stated_once`).
    """

    severity: float
    message: str
    unknown: str | None = None
    fix: str | None = None
    hint: str | None = None


def stated_once(warnings: list[Warning]) -> tuple[list[str], list[str]]:
    """``(lines, hints)``: each warning's text, and the hints stated once.

    A hint that only one warning carries ends that warning's line; one that several carry is left out of
    their lines and returned once in ``hints`` (in order of first use), to be shown after the list.
    """
    count: dict[str, int] = {}
    for w in warnings:
        if w.hint:
            count[w.hint] = count.get(w.hint, 0) + 1
    lines = []
    for w in warnings:
        if w.hint and count[w.hint] == 1:
            lines.append(f"{w.message.rstrip('.')}: {w.hint}.")
        else:
            lines.append(w.message)
    shared = [h for h in count if count[h] > 1]
    hints = [f"{h[0].upper()}{h[1:]} (said once for the {count[h]} warnings above that it applies to)." for h in shared]
    return lines, hints


def _fmt(x: float, unit: str) -> str:
    return f"{x:.3g} {unit}" if unit != "–" else f"{x:.3g}"


def _limit_word(tol: Mapping[str, float], u) -> str:
    """``goal`` when the unknown's tolerance comes from an accuracy goal, else ``tolerance``."""
    kind = "rotation_deg" if u.unit == "deg" else "translation_mm"
    return "goal" if u.unit in ("deg", "mm") and _tolerance(tol, u.block, kind)[1] else "tolerance"


def _weak_unknowns(model: LinearModel, tol: dict) -> list[Warning]:
    sigma = model.sigma()
    tols = unknown_tolerances(model, tol)
    weak = []
    for i, u in enumerate(model.unknowns):
        # distortion terms trade off against each other: judged through the projection σ instead
        judged = u.unit in ("deg", "mm") or u.coord in ("fx", "fy", "cx", "cy")
        if judged and sigma[i] > tols[i]:
            demote = NUISANCE_WEIGHT if u.role == "target" else 1.0
            weak.append((demote * sigma[i] / tols[i], i, tols[i]))
    weak.sort(reverse=True)
    if not weak:
        return []
    rho, _ = correlations(model.covariance(), model.labels, top=0)
    helps = what_would_help(model, [model.unknowns[i].label for _, i, _ in weak])
    out = []
    for ratio, i, t in weak:
        u = model.unknowns[i]
        partners = [model.unknowns[j].label for j in np.argsort(-np.abs(rho[i]))
                    if j != i and abs(rho[i, j]) >= 0.7][:3]
        msg = (f"{u.label} is weakly determined: σ = {_fmt(sigma[i], u.unit)} ({_limit_word(tol, u)} "
               f"{_fmt(t, u.unit)})" + (f", correlated with {', '.join(partners)}" if partners else ""))
        fix = None
        if helps:
            best = max(helps, key=lambda s: s.gain(u.label))
            fix = best.kind
            msg += (f". Add {best.description}: predicted σ {_fmt(best.sigma_before[u.label], u.unit)} → "
                    f"{_fmt(best.sigma_after[u.label], u.unit)}.")
        else:
            msg += "."
        out.append(Warning(float(ratio), msg, u.label, fix))
    return out


def projection_warning(model: LinearModel, camera: str, tol: dict, weak: bool) -> Warning | None:
    """The warning for a camera whose worst projection σ over the image exceeds ``projection_px`` (or the
    camera's goal, :func:`goal_tolerances`), naming the candidate station that lowers it most there; None
    when within tolerance."""
    cov = model.camera_covariance(camera)
    cam = model.calibration.cameras.get(camera) if model.calibration is not None else None
    if cov is None or cam is None:
        return None
    u, v = image_grid(cam.image_size, (9, 7))
    grid = np.stack([u.ravel(), v.ravel()], -1)
    s = projection_sigma_at(cam, grid, cov)
    if not np.any(np.isfinite(s)):
        return None
    k = int(np.nanargmax(s))
    worst = float(s[k])
    limit, from_goal = _tolerance(tol, camera, "projection_px")
    if worst <= limit:
        return None
    best, best_after = None, worst
    for cand in candidates(model):
        if camera not in cand.pair:
            continue
        try:
            after = projection_sigma_at(cam, grid[k:k + 1], model.camera_covariance(camera,
                                                                                    station_information(model, cand)))
        except JcalibError:  # a candidate the builder refuses is not offered
            continue
        if float(after[0]) < best_after:
            best, best_after = cand, float(after[0])
    msg = (f"{camera}: projection σ reaches {worst:.3g} px at pixel ({grid[k, 0]:.0f}, {grid[k, 1]:.0f}) "
           f"({'goal' if from_goal else 'tolerance'} {limit:g} px): the distortion there is extrapolated")
    if best is not None:
        msg += f". Add {best.description}: predicted {worst:.3g} → {best_after:.3g} px."
    # with weak focal length / principal point, those warnings name the cause; this one follows
    severity = worst / limit if not weak else 1.05
    if weak:
        msg += " (mostly a consequence of the weak unknowns above)"
    return Warning(severity, msg, f"{camera} projection", None if best is None else best.key)


def _file_weak(file: ResultFile, tol: dict) -> list[Warning]:
    out = []
    for name, tr in file.transforms.items():
        ts = transform_sigma(tr)
        if ts is None:
            continue
        for k, c in enumerate(TANGENT):
            val, (t, _) = ((ts["rotation_deg"][k], _tolerance(tol, name, "rotation_deg")) if k < 3 else
                           (ts["translation_mm"][k - 3], _tolerance(tol, name, "translation_mm")))
            if val > t:
                u = transform_unknown(name, c)
                out.append(Warning(float(val / t), f"{u.label} is weakly determined: σ = {_fmt(val, u.unit)} "
                                   f"({_limit_word(tol, u)} {_fmt(t, u.unit)})", u.label, hint=NO_SOLVE_HINT))
    return out


def analysis_warnings(
    file: ResultFile,
    model: LinearModel | None = None,
    residuals: Mapping[str, ResidualDiagnostics] | None = None,
    tolerances: Mapping[str, float] | None = None,
) -> list[Warning]:
    """The report's warnings, most severe first.

    Weak unknowns (σ above :data:`DEFAULT_TOLERANCES`, severity σ / tolerance; a target pose counts
    :data:`NUISANCE_WEIGHT` x) name the candidate station that reduces their σ most and the predicted σ
    after it. Then: a camera's worst projection σ over the image above tolerance (severity worst /
    tolerance, or 1.05 after weak unknowns, which are then its cause), a solver status other than
    converged (severity 100), radial residual structure (severity 5 + amplitude / σ̂), rejected
    measurements (1.2) and the solver's own warnings (1.5). Advice that would repeat across warnings (what
    to give the report for a station hint without the solve, what radial structure or outliers mean) is
    each warning's :attr:`Warning.hint`, to be stated once (:func:`stated_once`).

    Args:
        file: the result file.
        model: the linear model (:func:`jcalib.report.model.linear_model`; without a calibration, e.g.
            from the file's joint covariance, no station is suggested); None: weak unknowns are judged
            from the file's σ alone.
        residuals: from :func:`jcalib.report.diagnostics.residual_diagnostics`.
        tolerances: overrides of :data:`DEFAULT_TOLERANCES`, and per-block ones from accuracy goals
            (:func:`goal_tolerances`).
    """
    tol = {**DEFAULT_TOLERANCES, **(tolerances or {})}
    out: list[Warning] = []
    status = file.stats.get("status")
    if status is not None and str(status) != "converged":
        out.append(Warning(100.0, f"solver status: {status} (not converged): the estimate and its σ are unreliable"))
    for w in file.stats.get("warnings") or []:
        out.append(Warning(1.5, f"solver: {w}"))
    if model is not None and model.calibration is not None:
        weak = _weak_unknowns(model, tol)
        out += weak
        labels = model.labels
        weak_blocks = {model.unknowns[labels.index(w.unknown)].block for w in weak}
        for camera in model.param_names:
            w = projection_warning(model, camera, tol, camera in weak_blocks)
            if w is not None:
                out.append(w)
    elif model is not None:
        sigma, tols = model.sigma(), unknown_tolerances(model, tol, file.cameras)
        for i, u in enumerate(model.unknowns):
            judged = u.unit in ("deg", "mm") or u.coord in ("fx", "fy", "cx", "cy")
            if judged and sigma[i] > tols[i]:
                out.append(Warning(float(sigma[i] / tols[i]), f"{u.label} is weakly determined: σ = "
                                   f"{_fmt(sigma[i], u.unit)} ({_limit_word(tol, u)} {_fmt(tols[i], u.unit)})",
                                   u.label, hint=NO_SOLVE_HINT))
    else:
        out += _file_weak(file, tol)
    for name, diag in (residuals or {}).items():
        sigma = float(file.stats.get("sigma_px", diag.rms_px))
        if diag.radial.flagged:
            out.append(Warning(
                5.0 + diag.radial.amplitude_px / max(sigma, 1e-9),
                f"{name}: the radial residuals follow the radius (fitted trend up to "
                f"{diag.radial.amplitude_px:.3g} px, p = {diag.radial.p_value:.1e})", hint=(
                    "the lens model is probably too simple (try one with more distortion terms); σ do not include "
                    "this model error")))
        if diag.outliers:
            worst = diag.outliers[0]
            out.append(Warning(1.2, f"{name}: {len(diag.outliers)} corner(s) rejected as outliers (worst "
                                    f"{worst[2]:.3g} px, station {worst[0]} corner {worst[1]})",
                               hint="check the detections"))
    out.sort(key=lambda w: -w.severity)
    return out
