"""Figures of the HTML report, each returned as PNG bytes (matplotlib, Agg backend, no display).

The numbers come from :mod:`jcalib.report.analysis` (e.g. :func:`projection_sigma_map` of
:mod:`jcalib.problems.taskspace`, re-exported here); this module only draws.
"""

from __future__ import annotations

import io
from collections.abc import Mapping

import numpy as np

from jcalib.io.result import CameraResult
from jcalib.problems.taskspace import projection_sigma_map

__all__ = [
    "correlation_png",
    "coverage_png",
    "cross_validation_png",
    "lens_functions_png",
    "projection_sigma_map",
    "projection_sigma_png",
    "radial_residuals_png",
    "residual_vectors_png",
    "view_rms_png",
]

#: Figure width in inches at :data:`DPI`: 10.4 in x 100 dpi = 1040 px, inside the page's 1100 px.
FIG_WIDTH_IN = 10.4
DPI = 100


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _png(fig) -> bytes:
    plt = _pyplot()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


# ------------------------------------------------------------------------------ per-view RMS


def view_rms_png(view_rms_px: Mapping[str, float], sigma_px: float | None = None) -> bytes:
    """Bar chart of the RMS reprojection error of every view.

    Args:
        view_rms_px: ``"<camera>/<station>"`` -> RMS (pixels), as in ``stats["view_rms_px"]``.
        sigma_px: the a-posteriori noise σ (pixels), drawn as a reference line when given.
    """
    plt = _pyplot()
    names = list(view_rms_px)
    values = np.array([float(view_rms_px[n]) for n in names], dtype=np.float64)
    height = 3.2
    fig, ax = plt.subplots(figsize=(FIG_WIDTH_IN, height))
    x = np.arange(len(names))
    median = float(np.median(values)) if values.size else 0.0
    colors = ["#c0392b" if v > 2.0 * median and v > 0 else "#2e86c1" for v in values]
    ax.bar(x, values, color=colors)
    if sigma_px is not None:
        ax.axhline(sigma_px, color="#555", ls="--", lw=1, label=f"a-posteriori σ = {sigma_px:.3g} px")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_ylim(0.0, 1.3 * max(float(values.max()) if values.size else 0.0, sigma_px or 0.0, 1e-9))
    ax.set_ylabel("RMS per point [px]")
    ax.set_title("Reprojection RMS per view (red: over 2x the median)")
    step = max(1, len(names) // 40)
    ax.set_xticks(x[::step])
    ax.set_xticklabels(names[::step], rotation=60, ha="right", fontsize=7)
    ax.set_xlim(-0.6, max(len(names), 1) - 0.4)
    ax.grid(axis="y", alpha=0.3)
    return _png(fig)


# ------------------------------------------------------------------------------ uncertainty map



def projection_sigma_png(name: str, cam: CameraResult, covariance: np.ndarray | None = None
                         ) -> tuple[bytes, dict[str, float]]:
    """Map of :func:`projection_sigma_map` over the image (the camera's covariance, or ``covariance``);
    returns PNG bytes and summary numbers (``centre_px``, ``max_px``: σ at the image centre and its
    maximum over the image, pixels)."""
    plt = _pyplot()
    u, v, sigma = projection_sigma_map(cam, covariance=covariance)
    width, height = cam.image_size
    fig, ax = plt.subplots(figsize=(FIG_WIDTH_IN * 0.62, FIG_WIDTH_IN * 0.62 * height / width + 0.6))
    # geometric levels: σ grows by orders of magnitude towards unobserved image corners
    lo, hi = float(np.nanmin(sigma)), float(np.nanmax(sigma))
    levels = np.geomspace(max(lo, 1e-12), max(hi, lo * 1.01, 1e-12), 13)
    from matplotlib.colors import BoundaryNorm

    norm = BoundaryNorm(levels, ncolors=256)
    cs = ax.contourf(u, v, sigma, levels=levels, cmap="viridis", norm=norm)
    lines = ax.contour(u, v, sigma, levels=levels, colors="white", linewidths=0.5, alpha=0.8)
    ax.clabel(lines, levels[::2], fmt=lambda x: f"{x:.2g}", fontsize=7)
    cbar = fig.colorbar(cs, ax=ax, label="σ [px], worst direction")
    cbar.set_ticks(levels[::2])
    cbar.set_ticklabels([f"{x:.3g}" for x in levels[::2]])
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    ax.set_title(f"{name}: projection uncertainty from the intrinsics", fontsize=10)
    cy, cx = (sigma.shape[0] - 1) // 2, (sigma.shape[1] - 1) // 2
    summary = {"centre_px": float(sigma[cy, cx]), "max_px": float(np.nanmax(sigma))}
    return _png(fig), summary


# ------------------------------------------------------------------------------ residuals


def _frame(ax, image_size: tuple[int, int]) -> None:
    width, height = image_size
    ax.add_patch(
        _pyplot().Rectangle((-0.5, -0.5), width, height, fill=False, ec="#333", lw=1)
    )
    ax.set_xlim(-0.5 - 0.02 * width, width - 0.5 + 0.02 * width)
    ax.set_ylim(height - 0.5 + 0.02 * height, -0.5 - 0.02 * height)
    ax.set_aspect("equal")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")


def residual_vectors_png(
    name: str, image_size: tuple[int, int], pixels: np.ndarray, residuals: np.ndarray
) -> tuple[bytes, float]:
    """Residual vectors (observed − predicted) drawn at the observed corners, magnified.

    Args:
        pixels: ``(n, 2)`` observed corners, pixels.
        residuals: ``(n, 2)`` observed − predicted, pixels.

    Returns:
        PNG bytes and the magnification factor of the arrows.
    """
    plt = _pyplot()
    width, height = image_size
    norm = np.linalg.norm(residuals, axis=-1)
    typical = float(np.percentile(norm, 95)) if norm.size else 1.0
    # the 95th-percentile arrow is 4 % of the image width long
    scale = 0.04 * width / max(typical, 1e-12)
    fig, ax = plt.subplots(figsize=(FIG_WIDTH_IN * 0.62, FIG_WIDTH_IN * 0.62 * height / width + 0.6))
    ax.quiver(
        pixels[:, 0], pixels[:, 1], residuals[:, 0] * scale, residuals[:, 1] * scale,
        norm, angles="xy", scale_units="xy", scale=1.0, cmap="plasma", width=0.0025,
    )
    _frame(ax, image_size)
    ax.set_title(f"{name}: residuals (observed − predicted) x {scale:.0f}", fontsize=10)
    return _png(fig), scale


def radial_residuals_png(
    name: str, pixels: np.ndarray, residuals: np.ndarray, centre: np.ndarray
) -> bytes:
    """Radial residual component against distance from the principal point.

    A systematic trend (an S-curve, a drift at the edge) hints at a too-simple lens model;
    noise-only residuals scatter evenly about 0 at every radius.

    Args:
        pixels: ``(n, 2)`` observed corners, pixels.
        residuals: ``(n, 2)`` observed − predicted, pixels.
        centre: ``(2,)`` principal point ``(cx, cy)``, pixels.
    """
    plt = _pyplot()
    d = pixels - centre[None, :]
    r = np.linalg.norm(d, axis=-1)
    radial = np.sum(residuals * d, axis=-1) / np.maximum(r, 1e-9)
    fig, ax = plt.subplots(figsize=(FIG_WIDTH_IN, 3.2))
    ax.scatter(r, radial, s=3, alpha=0.35, color="#2e86c1", label="corners")
    if r.size > 20:
        edges = np.linspace(0.0, float(r.max()) + 1e-9, 16)
        idx = np.digitize(r, edges) - 1
        centres, medians = [], []
        for b in range(edges.size - 1):
            sel = idx == b
            if np.count_nonzero(sel) >= 5:
                centres.append(0.5 * (edges[b] + edges[b + 1]))
                medians.append(float(np.median(radial[sel])))
        ax.plot(centres, medians, color="#c0392b", lw=2, label="median per radius bin")
    ax.axhline(0.0, color="#333", lw=0.8)
    ax.set_xlabel("distance from the principal point [px]")
    ax.set_ylabel("radial residual [px]")
    ax.set_title(f"{name}: radial residuals (a trend hints at a too-simple lens model)", fontsize=10)
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    return _png(fig)


def coverage_png(name: str, image_size: tuple[int, int], pixels_per_view: list[np.ndarray]) -> bytes:
    """Detected corners of every view over the image frame (one colour per view).

    Args:
        pixels_per_view: one ``(n_i, 2)`` array of detected corners (pixels) per view.
    """
    plt = _pyplot()
    width, height = image_size
    fig, ax = plt.subplots(figsize=(FIG_WIDTH_IN * 0.62, FIG_WIDTH_IN * 0.62 * height / width + 0.6))
    cmap = plt.get_cmap("tab20")
    for i, pix in enumerate(pixels_per_view):
        ax.scatter(pix[:, 0], pix[:, 1], s=4, color=cmap(i % 20))
    _frame(ax, image_size)
    ax.set_title(f"{name}: detected corners ({len(pixels_per_view)} views)", fontsize=10)
    return _png(fig)


# ------------------------------------------------------------------------------ correlations


def correlation_png(labels: list[str], rho: np.ndarray, title: str) -> bytes:
    """Heat map of a correlation matrix ``rho (n, n)`` with ``labels`` on both axes (blue −1 … red +1)."""
    plt = _pyplot()
    n = len(labels)
    side = min(FIG_WIDTH_IN * 0.7, 2.2 + 0.32 * n)
    fig, ax = plt.subplots(figsize=(side + 1.2, side))
    im = ax.imshow(rho, cmap="RdBu_r", vmin=-1.0, vmax=1.0)
    ax.set_xticks(np.arange(n))
    ax.set_yticks(np.arange(n))
    ax.set_xticklabels(labels, rotation=70, ha="right", fontsize=7)
    ax.set_yticklabels(labels, fontsize=7)
    if n <= 16:
        for i in range(n):
            for j in range(n):
                if i != j and abs(rho[i, j]) >= 0.5:
                    ax.text(j, i, f"{rho[i, j]:.2f}", ha="center", va="center", fontsize=6,
                            color="white" if abs(rho[i, j]) > 0.8 else "black")
    fig.colorbar(im, ax=ax, label="correlation", fraction=0.046, pad=0.04)
    ax.set_title(title, fontsize=10)
    return _png(fig)


# ------------------------------------------------------------------------------ cross-validation


def cross_validation_png(name: str, u: np.ndarray, v: np.ndarray, diff: np.ndarray, expected: np.ndarray,
                         image_size: tuple[int, int]) -> bytes:
    """Two maps side by side: the two halves' projection difference and its expected size (px)."""
    plt = _pyplot()
    from matplotlib.colors import BoundaryNorm

    width, height = image_size
    fig, axes = plt.subplots(1, 2, figsize=(FIG_WIDTH_IN, FIG_WIDTH_IN * 0.5 * height / width + 0.9))
    finite = np.concatenate([diff[np.isfinite(diff)], expected[np.isfinite(expected)]])
    lo = max(float(finite.min()) if finite.size else 1e-3, 1e-3)
    hi = max(float(finite.max()) if finite.size else 1.0, lo * 1.01)
    levels = np.geomspace(lo, hi, 11)
    norm = BoundaryNorm(levels, ncolors=256)
    for ax, data, title in ((axes[0], diff, "difference between the halves"),
                            (axes[1], expected, "expected: sqrt(σ_A² + σ_B²)")):
        cs = ax.contourf(u, v, np.clip(data, lo, hi), levels=levels, cmap="magma", norm=norm)
        ax.set_xlim(-0.5, width - 0.5)
        ax.set_ylim(height - 0.5, -0.5)
        ax.set_aspect("equal")
        ax.set_xlabel("u [px]")
        ax.set_title(f"{name}: {title}", fontsize=9)
    axes[0].set_ylabel("v [px]")
    cbar = fig.colorbar(cs, ax=list(axes), label="[px]", fraction=0.03)
    cbar.set_ticks(levels[::2])
    cbar.set_ticklabels([f"{x:.3g}" for x in levels[::2]])
    return _png(fig)


# ------------------------------------------------------------------------------ zoom lenses


def lens_functions_png(name: str, lens, columns: list[str], captured, heldout: Mapping[float, dict] | None = None,
                       num: int = 61) -> bytes:
    """Each intrinsic and the axial shift of a zoom camera against the lens setting, with ±σ and ±3σ bands.

    Args:
        name: camera id; lens: its :class:`jcalib.geometry.cameras.zoom.LensFunction`.
        columns: the panels (intrinsic names and ``shift_m``); captured: the calibrated settings (ticks).
        heldout: setting -> ``{"rms_px": ...}`` of held-out settings (marked, their prediction RMS shown).
    """
    plt = _pyplot()
    lo, hi = lens.range_
    s = np.linspace(lo, hi, num)
    names = list(lens.param_names)
    values = {c: np.zeros(num) for c in columns}
    sigma = {c: np.zeros(num) for c in columns}
    for i, x in enumerate(s):
        at = lens.at(x)
        for c in columns:
            if c == "shift_m":
                values[c][i] = at["shift_m"] * 1e3
                sigma[c][i] = (at["shift_std_m"] or 0.0) * 1e3
            else:
                j = names.index(c)
                values[c][i] = at["params"][j]
                cov = at["params_covariance"]
                sigma[c][i] = 0.0 if cov is None else float(np.sqrt(max(cov[j, j], 0.0)))
    cols = 3
    rows = -(-len(columns) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(FIG_WIDTH_IN, 2.3 * rows), squeeze=False)
    for ax, c in zip(axes.ravel(), columns):
        v, sd = values[c], sigma[c]
        ax.fill_between(s, v - 3 * sd, v + 3 * sd, color="tab:blue", alpha=0.15, lw=0)
        ax.fill_between(s, v - sd, v + sd, color="tab:blue", alpha=0.35, lw=0)
        ax.plot(s, v, color="tab:blue", lw=1.2)
        for x in captured:
            ax.axvline(x, color="0.7", lw=0.6, zorder=0)
        for x in (heldout or {}):
            ax.axvline(float(x), color="tab:red", lw=1.0, ls="--", zorder=0)
        ax.set_title("shift along +z [mm]" if c == "shift_m" else c, fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[len(columns):]:
        ax.axis("off")
    held = ", ".join(f"{float(k):g}: {v.get('rms_px') or float('nan'):.3f} px" for k, v in (heldout or {}).items())
    fig.suptitle(f"{name}: lens functions of {lens.setting} (bands ±1σ, ±3σ; grey: calibrated settings"
                 + (f"; red: held out, prediction RMS {held})" if held else ")"), fontsize=9)
    fig.tight_layout()
    return _png(fig)
