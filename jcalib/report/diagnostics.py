"""Residual diagnostics from the solve: per-camera corner residuals, per-view RMS, rejected
measurements, a test for radial structure (a too-simple lens model), and statistics per factor group.

Every residual is the solve's own (``Calibration.residuals``: each factor group's residuals at the
estimate, rejected measurements included), never re-projected here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jcalib.problems.build import CORNER_KINDS

__all__ = ["GroupStatistics", "RadialTest", "ResidualDiagnostics", "group_statistics", "radial_structure",
           "residual_diagnostics"]

#: Display unit and scale of each residual kind (the solve's units: px, m, rad).
_UNITS = {"corner": ("px", 1.0), "corner_mean": ("px", 1.0), "tip": ("px", 1.0), "axis": ("px", 1.0),
          "contact": ("mm", 1e3),
          "pose_rotation": ("deg", float(np.degrees(1.0))), "pose_translation": ("mm", 1e3), "position": ("mm", 1e3)}


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
    """The corner residuals of one camera at the estimate (all its targets).

    Attributes:
        camera: camera id.
        pixels, residuals: ``(n, 2)`` observed corners and observed − predicted, px.
        view: ``(n,)`` station id of every corner; point_index: ``(n,)`` its target point.
        inlier: ``(n,)`` bool, False where the solve rejected the corner.
        view_rms_px: station id -> RMS of its inlier corners' residual norms (OpenCV's RMS), px.
        rms_px: RMS of the inlier residual norms (OpenCV's RMS), px.
        outliers: ``[(station id, point index, |r| px)]`` the solve rejected, largest first.
        radial: :class:`RadialTest` of the inliers.
    """

    camera: str
    pixels: np.ndarray
    residuals: np.ndarray
    view: np.ndarray
    point_index: np.ndarray
    inlier: np.ndarray
    view_rms_px: dict[str, float]
    rms_px: float
    outliers: list[tuple[str, int, float]]
    radial: RadialTest


def residual_diagnostics(cal) -> dict[str, ResidualDiagnostics]:
    """Per-camera corner diagnostics of a :class:`~jcalib.problems.assemble.Calibration`.

    Residuals are the solve's at the estimate (``cal.residuals``, negated to observed − predicted);
    a static pair (camera and target on one holder) counts once, at its mean pixels, as the solve did.
    """
    g, built = cal.graph, cal.built
    sigma = cal.sigma_px if cal.sigma_px == cal.sigma_px else None
    parts: dict[str, list] = {}
    for gr in built.groups:
        if gr.kind not in CORNER_KINDS:
            continue
        c, _ = gr.key
        pair = g.pairs[gr.key]
        pix = np.concatenate([np.asarray(x, np.float64) for x in pair.pixels])
        ids = np.asarray([g.station_ids[int(k)] for k in gr.stations])
        parts.setdefault(c, []).append((pix, -np.asarray(cal.residuals[gr.name], np.float64), ids,
                                        np.asarray(gr.index), np.asarray(cal.weights[gr.name]) > 0))
    out = {}
    for c, items in parts.items():
        pix, res, view, index, inlier = (np.concatenate([it[j] for it in items]) for j in range(5))
        sq = np.sum(res**2, axis=-1)
        view_rms = {}
        for sid in dict.fromkeys(view.tolist()):
            sel = (view == sid) & inlier
            view_rms[sid] = float(np.sqrt(np.mean(sq[sel]))) if sel.any() else float("nan")
        rms = float(np.sqrt(np.mean(sq[inlier]))) if inlier.any() else float("nan")
        norm = np.sqrt(sq)
        outliers = sorted(((str(view[j]), int(index[j]), float(norm[j])) for j in np.flatnonzero(~inlier)),
                          key=lambda o: -o[2])
        s = sigma if sigma is not None else rms / np.sqrt(2.0)
        K = np.asarray(cal.cameras[c].K)
        radial = radial_structure(pix[inlier], res[inlier], np.array([K[0, 2], K[1, 2]]), s)
        out[c] = ResidualDiagnostics(c, pix, res, view, index, inlier, view_rms, rms, outliers, radial)
    return out


@dataclass(frozen=True)
class GroupStatistics:
    """Residual statistics of one factor group of the solve.

    Attributes:
        name, kind: the group (``corners:cam0/board``...) and its residual kind; unit: display unit.
        count: measurements; rejected: how many the solve rejected.
        rms, max: RMS and largest norm of the inlier residuals, display unit.
        sigma: the a-posteriori σ per coordinate of the kind (stated σ times the square root of its
            variance component), display unit, or NaN.
    """

    name: str
    kind: str
    unit: str
    count: int
    rejected: int
    rms: float
    max: float
    sigma: float


def group_statistics(cal, options=None) -> list[GroupStatistics]:
    """:class:`GroupStatistics` of every measurement group of a calibration (corners, tips, axis points,
    contacts, pose measurements)."""
    out = []
    for gr in cal.built.groups:
        unit, scale = _UNITS.get(gr.kind, ("", 1.0))
        r = np.asarray(cal.residuals[gr.name], np.float64)
        w = np.asarray(cal.weights[gr.name]) > 0
        norm = np.linalg.norm(r, axis=-1)[w] * scale
        factor = cal.variance_components.get(gr.kind)
        if factor is None:
            factor = cal.sigma2 if cal.covariance_noise == "a_posteriori" else 1.0
        sigma = float(cal.built.sigma[gr.kind] * np.sqrt(factor) * scale) if factor == factor else float("nan")
        out.append(GroupStatistics(gr.name, gr.kind, unit, int(w.size), int(np.count_nonzero(~w)),
                                   float(np.sqrt(np.mean(norm**2))) if norm.size else float("nan"),
                                   float(norm.max()) if norm.size else float("nan"), sigma))
    return out
