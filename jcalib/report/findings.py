"""Sections of the HTML report that read the solve's linear model and residuals: correlations, weakest
directions, what would help, residual diagnostics and cross-validation."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.io.result import ResultFile
from jcalib.report.markup import esc, figure, fmt, note, table
from jcalib.problems.taskspace import image_grid, projection_sigma_at

__all__ = ["MISSING_SOLVE", "correlation_section", "cross_validation_section", "help_section", "residual_section",
           "weak_section"]

#: Said where a section needs the solve and the report has only a result file.
MISSING_SOLVE = ("needs the calibration's solve: pass the in-memory result of <code>jcalib.calibrate</code>, or the "
                 "observations and the cell spec the result was computed from (<code>jcalib report RESULT "
                 "--observations OBS --cell CELL</code>)")


def correlation_section(file: ResultFile, model) -> str:
    """Correlation heat map and strongest pairs over the model's unknowns (else the file's cameras)."""
    from jcalib.report import plots
    from jcalib.report.model import correlations

    sources = []
    if model is not None:
        title = "every shared unknown of the solve" if model.calibration is not None else "joint covariance of the result"
        sources.append((title, model.labels, model.covariance()))
    else:
        for name, cam in file.cameras.items():
            if cam.covariance is not None:
                free = [i for i, n in enumerate(cam.param_names) if cam.std.get(n, 1.0) != 0.0]
                sources.append((name, [f"{name} {cam.param_names[i]}" for i in free],
                                np.asarray(cam.covariance)[np.ix_(free, free)]))
    out = []
    for title, labels, C in sources:
        if len(labels) < 2:  # nothing to correlate (e.g. all intrinsics held)
            continue
        rho, pairs = correlations(C, labels, top=8, minimum=0.5)
        out.append(figure(plots.correlation_png(labels, rho, f"correlations: {title}"), f"correlation matrix {title}",
                          "Correlation between the unknowns (−1 blue … +1 red). Strongly correlated unknowns trade "
                          "off against each other: the data fix their combination, not each."))
        if pairs:
            out.append(table(["unknown", "unknown", "correlation"], [[esc(a), esc(b), f"{r:+.3f}"] for a, b, r in pairs],
                             {2}))
    return "".join(out) or note("Fewer than two unknowns with a covariance: nothing to correlate.")


def weak_section(model, tolerances, cameras=None) -> str:
    from jcalib.report import advice

    if model is None:
        return note("The weakest directions " + MISSING_SOLVE + ".")
    dirs = advice.weak_directions(model, 3, tolerances, cameras)
    rows = [[str(k + 1), fmt(d.ratio, 3), esc(d.describe())] for k, d in enumerate(dirs)]
    tol = {**advice.DEFAULT_TOLERANCES, **(tolerances or {})}
    by_goal = any("." in k for k in tol)
    return (note("Eigen-directions of the covariance with every unknown divided by its tolerance (transforms and "
                 f"points {tol['rotation_deg']:g}° and {tol['translation_mm']:g} mm"
                 + (", or the limit of a goal that names them" if by_goal else "") + "; an intrinsic: the change "
                 f"that moves some image point by {tol['edge_px']:g} px). The first is the combination the data "
                 "determine worst; a ratio above 1 is worse than the tolerance.")
            + table(["#", "σ / tolerance", "direction (weights)"], rows, {1}))


def help_section(model, tolerances) -> str:
    from jcalib.report import advice, candidates

    if model is None or model.calibration is None:
        return note("The prediction of what one more station would do " + MISSING_SOLVE + ".")
    sigma = model.sigma()
    ratio = sigma / advice.unknown_tolerances(model, tolerances)
    judged = np.array([u.unit in ("deg", "mm") or u.coord in ("fx", "fy", "cx", "cy") for u in model.unknowns])
    order = [int(i) for i in np.argsort(-np.where(judged, ratio, -np.inf)) if judged[i]][:3]
    labels = [model.unknowns[i].label for i in order]
    sugg = candidates.what_would_help(model, labels)
    if not sugg:
        return note("No candidate station could be built for this cell.")
    worst = _worst_projection(model)
    head = ["one more station"] + [f"σ {model.unknowns[i].label} [{model.unknowns[i].unit}] now {sigma[i]:.3g}"
                                   for i in order]
    head += [f"projection σ of {c} at ({px[0]:.0f}, {px[1]:.0f}) [px] now {s0:.3g}" for c, (px, s0) in worst.items()]
    rows = []
    for s in sugg:
        row = [esc(s.description)] + [_less(s.sigma_after[lab], s.sigma_before[lab]) for lab in labels]
        added = model.predictions.get(s.kind)
        for c, (px, s0) in worst.items():
            cam = model.calibration.cameras[c]
            after = projection_sigma_at(cam, px[None], model.camera_covariance(c, added))[0]
            row.append(_less(float(after), s0))
        rows.append(row)
    return (note("Predicted σ of the worst-determined unknowns (largest σ / tolerance; distortion terms are judged "
                 "by the projection σ where it is worst) if one more station of each kind were added at the current "
                 "estimate: the station is built by the calibration's own problem builder and linearised by the "
                 "solver (its own pose unknowns marginalised), and its information is added to the solve's. Best "
                 "first for the first column.")
            + table(head, rows, set(range(1, len(head)))))


def _less(after: float, before: float) -> str:
    return f"{after:.3g} ({100 * (1 - after / max(before, 1e-300)):.0f} % less)"


def _worst_projection(model) -> dict:
    """Camera -> (pixel (2,), σ px) where its projection σ is worst (cameras with free intrinsics)."""
    out = {}
    for c, cam in model.calibration.cameras.items():
        cov = model.camera_covariance(c)
        if cov is None:
            continue
        u, v = image_grid(cam.image_size, (9, 7))
        grid = np.stack([u.ravel(), v.ravel()], -1)
        s = projection_sigma_at(cam, grid, cov)
        if np.any(np.isfinite(s)):
            k = int(np.nanargmax(s))
            out[c] = (grid[k], float(s[k]))
    return out


def residual_section(file: ResultFile, cal, diags: Mapping, groups: list, observations) -> str:
    """Diagnostics table, per-group statistics, residual vectors and radial plots (from the solve), or the
    detected-corner coverage when the report has observations but no solve."""
    from jcalib.report import plots

    out = []
    if cal is None:
        if observations is None:
            return note("The residuals " + MISSING_SOLVE + ".")
        out.append(note("Without the calibration's solve the residuals are not shown (" + MISSING_SOLVE + "); the plots "
                        "show where corners were detected. Gaps at the edges and corners of the image leave the "
                        "distortion there extrapolated (see the uncertainty map)."))
        for name, cam in file.cameras.items():
            per_view = [np.asarray(d.pixels) for st in observations.stations for d in st.detections
                        if d.camera == name and d.target is not None]
            if not per_view:
                out.append(f"<p><code>{esc(name)}</code>: no target detections in the observations.</p>")
                continue
            n = sum(len(p) for p in per_view)
            out.append(figure(plots.coverage_png(name, cam.image_size, per_view), f"corner coverage of {name}",
                              f"<code>{esc(name)}</code>: {n} detected corners in {len(per_view)} views."))
        return "".join(out)
    rows = []
    for name, d in diags.items():
        worst = max(d.view_rms_px.items(), key=lambda kv: kv[1]) if d.view_rms_px else ("–", 0.0)
        inl = d.residuals[d.inlier]
        per_coordinate = float(np.sqrt(np.mean(inl**2))) if inl.size else float("nan")
        rows.append([f"<code>{esc(name)}</code>", fmt(d.rms_px, 3), fmt(per_coordinate, 3),
                     f"{esc(worst[0])}: {worst[1]:.3g}",
                     esc(len(d.outliers)), f"{d.radial.correlation:+.3f}", f"{d.radial.p_value:.2g}",
                     fmt(d.radial.amplitude_px, 3), "yes" if d.radial.flagged else "no"])
    if rows:
        out.append(table(["camera", "RMS per point [px]", "RMS per coordinate [px]", "worst view RMS [px]", "rejected",
                          "corr(radial, r)", "radial trend p", "trend amplitude [px]", "model too simple?"], rows,
                         {1, 2, 4, 5, 6, 7})
                   + note("RMS per point: of the residual norms per corner (OpenCV's RMS); per coordinate: of their x "
                          "and y components (mrcal's RMS); rejected corners left out. Radial test: "
                          "a cubic in the radius fitted to the radial residuals; p is the F-test p-value against no "
                          "trend. A significant trend larger than half the noise hints at a too-simple lens model."))
    grows = [[f"<code>{esc(s.name)}</code>", esc(s.kind), esc(s.count), esc(s.rejected), fmt(s.rms, 3), fmt(s.max, 3),
              fmt(s.sigma, 3), esc(s.unit)] for s in groups]
    if grows:
        out.append("<h3>Every measurement group of the solve</h3>"
                   + table(["group", "kind", "measurements", "rejected", "RMS", "max", "a-posteriori σ", "unit"], grows,
                           {2, 3, 4, 5, 6})
                   + note("Residual norms of the inliers at the estimate; σ per coordinate, the stated σ times the "
                          "square root of the kind's variance component."))
    for name, d in diags.items():
        cam = file.cameras.get(name)
        if cam is None:
            continue
        png, scale = plots.residual_vectors_png(name, cam.image_size, d.pixels, d.residuals)
        out.append(figure(png, f"residual vectors of {name}",
                          f"<code>{esc(name)}</code>: {len(d.pixels)} corners of {len(d.view_rms_px)} views, arrows "
                          f"magnified {scale:.0f}x, RMS {d.rms_px:.3g} px per point (rejected corners left out of the RMS, drawn "
                          "too). Noise looks random; a pattern (swirls, radial flow) is model error."))
        K = np.asarray(cam.K)
        png = plots.radial_residuals_png(name, d.pixels[d.inlier], d.residuals[d.inlier], np.array([K[0, 2], K[1, 2]]))
        out.append(figure(png, f"radial residuals of {name}",
                          "Radial component of each residual (positive: observed farther from the principal point "
                          "than predicted) against the distance from the principal point."))
    return "".join(out) or note("No residuals.")


def cross_validation_section(cell, observations, options, enabled: bool) -> str:
    from jcalib.report import crossval, plots

    if not enabled or cell is None or observations is None:
        return note("Not run: cross-validation calibrates the two halves of the stations again; it needs the "
                    "observations and the cell spec (<code>jcalib report RESULT --observations OBS --cell CELL</code>, "
                    "or <code>render_report(..., cell=..., cross_validation=True)</code>).")
    try:
        cv = crossval.cross_validate(cell, observations, options)
    except (BadInputError, NotObservableError) as err:
        return note(f"Cross-validation not possible: {esc(err)}")
    out = [note(f"Calibrated separately on the even ({len(cv.stations[0])}) and odd ({len(cv.stations[1])}) stations. "
                "Each pixel's ray from half A is projected by half B after the rotation that best aligns their camera "
                "frames (a camera-frame rotation is not a lens difference), and the difference is tested against the "
                "one the two halves' covariances predict (χ² per point and over the image). A difference much larger "
                "than predicted means the σ are too small (model error, a camera that changed); comparable means they "
                "are honest.")]
    for name, (u, v, diff, expected) in cv.maps.items():
        c = cv.comparisons[name]
        cam = cv.results[0].file.cameras[name]
        png = plots.cross_validation_png(name, u, v, diff, expected, cam.image_size)
        out.append(figure(png, f"cross-validation of {name}",
                          f"<code>{esc(name)}</code>: {esc(c.message)}"))
    rows = [[f"<code>{esc(n)}</code>", fmt(t["rotation_deg"], 3), fmt(t.get("rotation_sigma_deg", float("nan")), 3),
             fmt(t["translation_mm"], 3), fmt(t.get("translation_sigma_mm", float("nan")), 3)]
            for n, t in cv.transforms.items()]
    if rows:
        out.append(table(["transform", "Δ rotation [deg]", "expected σ [deg]", "Δ translation [mm]", "expected σ [mm]"],
                         rows, {1, 2, 3, 4}))
    return "".join(out)
