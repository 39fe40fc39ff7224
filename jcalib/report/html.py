"""The one-page HTML report of a result: tables, warnings, plots and provenance in one file.

The page is self-contained (inline CSS, PNG figures embedded as base64 ``data:`` URIs, no script,
no external resource), so it can be mailed, archived next to ``result.json`` and opened offline.
It fits a laptop screen (max width 1100 px; tables wrap instead of scrolling sideways).
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.atomic import write_text_atomic
from jcalib.io.result import ResultFile, load_result

__all__ = ["POSES_KEY", "render_report", "write_report"]

#: Optional top-level key of a result file holding the per-view target poses that the residual
#: plots need: ``{station id: {camera id: 4x4 T_cam_target (m)}}``. The solver's
#: :class:`~jcalib.problems.camera.CameraCalibration` has them as ``T_cam_target``.
POSES_KEY = "T_cam_target"

_PIXEL_PARAMS = {"fx", "fy", "cx", "cy", "skew"}

_CSS = """
*{box-sizing:border-box}
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,"DejaVu Sans",Arial,sans-serif;
 margin:0;background:#f4f5f7;color:#1d232a;line-height:1.45}
main{max-width:1100px;margin:0 auto;padding:16px 24px 40px;background:#fff;min-height:100vh}
h1{font-size:1.5em;margin:0.3em 0}
h2{font-size:1.2em;border-bottom:2px solid #d5dae0;padding-bottom:3px;margin-top:1.6em}
h3{font-size:1.02em;margin:1.1em 0 0.4em}
table{border-collapse:collapse;margin:0.4em 0 1em;max-width:100%;font-size:0.92em}
th,td{border:1px solid #d5dae0;padding:3px 8px;text-align:left;vertical-align:top;
 overflow-wrap:anywhere;word-break:break-word}
th{background:#eef1f4}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.warn{background:#fff4e5;border:2px solid #e67e22;border-radius:6px;padding:8px 14px;margin:12px 0}
.warn h2{border:none;margin:0.2em 0;color:#a04000}
.warn li{margin:0.3em 0}
.ok{background:#eafaf1;border:1px solid #58d68d;border-radius:6px;padding:6px 14px;margin:12px 0}
.note{color:#4a5560;font-size:0.9em}
figure{margin:0.6em 0 1.2em}
figure img{max-width:100%;height:auto;display:block}
figcaption{color:#4a5560;font-size:0.88em;margin-top:4px}
table.kv td:first-child{white-space:nowrap;font-weight:600}
code{font-size:0.92em;background:#f0f2f4;padding:0 3px;border-radius:3px;overflow-wrap:anywhere}
"""


# ------------------------------------------------------------------------------ helpers


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _img(png: bytes, alt: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return f'<img alt="{_e(alt)}" src="data:image/png;base64,{data}">'


def _figure(png: bytes, alt: str, caption: str) -> str:
    return f"<figure>{_img(png, alt)}<figcaption>{caption}</figcaption></figure>"


def _table(
    header: list[str], rows: list[list[str]], num_cols: set[int] = frozenset(), cls: str = ""
) -> str:
    """An HTML table; ``rows`` hold already-escaped cell HTML."""
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join(
        "<tr>"
        + "".join(f'<td class="num">{c}</td>' if i in num_cols else f"<td>{c}</td>" for i, c in enumerate(r))
        + "</tr>"
        for r in rows
    )
    attr = f' class="{cls}"' if cls else ""
    return f"<table{attr}><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _fmt(x: float, digits: int = 6) -> str:
    return _e(f"{x:.{digits}g}")


def _vec(v, fmt: str) -> str:
    return _e(" ".join(format(float(x), fmt) for x in v))


# ------------------------------------------------------------------------------ sections


def _warnings_section(warnings: list) -> str:
    """Warnings, most severe first (:func:`jcalib.report.analysis.analysis_warnings`)."""
    if not warnings:
        return '<div class="ok">No warnings.</div>'
    items = "".join(f"<li>{_e(w.message)}</li>" for w in warnings)
    return (f'<div class="warn" id="warnings"><h2>Warnings</h2><p class="note">Most severe first.</p>'
            f"<ol>{items}</ol></div>")


def _intrinsics_section(result: ResultFile) -> str:
    out = []
    for name, cam in result.cameras.items():
        rows = []
        for pname, value in zip(cam.param_names, cam.params):
            std = cam.std.get(pname)
            if std is None:
                s = "–"
            elif std == 0.0:
                s = "fixed"
            else:
                s = _fmt(std, 3)
            rows.append([_e(pname), _fmt(value, 8), s, "px" if pname in _PIXEL_PARAMS else "–"])
        w, h = cam.image_size
        out.append(
            f"<h3>Camera <code>{_e(name)}</code>: model <code>{_e(cam.model)}</code>, "
            f"image {w} x {h} px</h3>"
            + _table(["parameter", "value", "σ", "unit"], rows, {1, 2})
        )
    return "".join(out) or '<p class="note">No cameras in this result.</p>'


def _transforms_section(result: ResultFile) -> str:
    if not result.transforms:
        return ""
    from jcalib.geometry.conversions import matrix_to_rvec

    rows = []
    for name, tr in result.transforms.items():
        T = np.asarray(tr.matrix)
        rvec = np.degrees(np.asarray(matrix_to_rvec(T[:3, :3])))
        std = tr.std
        angle = float(np.linalg.norm(rvec))
        rows.append([
            f"<code>{_e(name)}</code>",
            _vec(T[:3, 3] * 1e3, ".3f"),
            "–" if std is None else _vec(std[3:] * 1e3, ".3f"),
            _vec(rvec, ".4f") + f"<br><span class=note>|r| = {angle:.4f}°</span>",
            "–" if std is None else _vec(np.degrees(std[:3]), ".4f"),
        ])
    return (
        "<h3>Transforms</h3>"
        '<p class="note"><code>T_a_b</code> is the pose of frame b in frame a (maps b → a). '
        "Rotation as a rotation vector in degrees; σ over the right-perturbation tangent "
        "(rx, ry, rz, tx, ty, tz), expressed in frame b.</p>"
        + _table(["transform", "translation [mm]", "σ t [mm]", "rotation vector [deg]", "σ r [deg]"],
                 rows, {1, 2, 3, 4})
    )


def _points_section(result: ResultFile) -> str:
    if not result.points:
        return ""
    rows = []
    for name, pt in result.points.items():
        std = None if pt.covariance is None else np.sqrt(np.diag(pt.covariance))
        rows.append([
            f"<code>{_e(name)}</code>", _e(pt.frame), _vec(pt.position * 1e3, ".3f"),
            "–" if std is None else _vec(std * 1e3, ".3f"),
        ])
    return "<h3>Points</h3>" + _table(["point", "frame", "position [mm]", "σ [mm]"], rows, {2, 3})


def _stats_section(stats: Mapping[str, Any]) -> str:
    labels = [
        ("rms_px", "reprojection RMS", "px"),
        ("sigma_px", "a-posteriori σ", "px"),
        ("num_residuals", "residuals", ""),
        ("num_outliers", "outliers rejected", ""),
        ("iterations", "iterations", ""),
        ("status", "solver status", ""),
    ]
    rows = []
    for key, label, unit in labels:
        if key in stats:
            v = stats[key]
            rows.append([_e(label), _fmt(v, 4) if isinstance(v, float) else _e(v), _e(unit)])
    if stats.get("reseeded_views"):
        rows.append([_e("re-seeded views"), _e(", ".join(map(str, stats["reseeded_views"]))), ""])
    if "view_rms_px" in stats:
        rows.append([_e("views"), _e(len(stats["view_rms_px"])), ""])
    return _table(["statistic", "value", "unit"], rows, {1})


def _provenance_section(result: ResultFile, source: str | None) -> str:
    p = result.provenance
    rows = []
    if source:
        rows.append(["result file", f"<code>{_e(source)}</code>"])
    if p is None:
        rows.append(["provenance", "not recorded in the result"])
    else:
        rows += [
            ["input hash", f"<code>{_e(p.input_hash or '–')}</code>"],
            ["jcalib version", _e(p.jcalib_version or "–")],
            ["created", _e(p.created or "–")],
            ["options", f"<code>{_e(json.dumps(dict(p.options), sort_keys=True))}</code>"],
        ]
    from jcalib import __version__

    now = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z")
    rows.append(["report", _e(f"written {now} by jcalib {__version__}")])
    return _table(["field", "value"], rows, cls="kv")


def _uncertainty_section(result: ResultFile) -> str:
    from jcalib.report import plots

    out = [
        (
            '<p class="note">σ (pixels, worst direction) of the projection of a point at each place in '
        "the image, by linear propagation of the intrinsics covariance with a JAX Jacobian of the "
        "lens model's <code>project</code> w.r.t. the intrinsics. <b>Includes</b> the intrinsics "
        "uncertainty caused by pixel noise (as the solver reported it). <b>Excludes</b> model error "
        "(a too-simple lens model) and the uncertainty of the camera and target poses. The lens "
        "models are central, so the value is the same at every depth along a pixel's ray.</p>"
        )
    ]
    for name, cam in result.cameras.items():
        if cam.covariance is None:
            out.append(f"<p><code>{_e(name)}</code>: no intrinsics covariance in the result; no map.</p>")
            continue
        if not np.any(np.diag(np.asarray(cam.covariance)) > 0.0):
            out.append(f"<p><code>{_e(name)}</code>: intrinsics held fixed (known): they add no projection "
                       "uncertainty.</p>")
            continue
        png, summary = plots.projection_sigma_png(name, cam)
        out.append(_figure(
            png, f"projection uncertainty of {name}",
            f"<code>{_e(name)}</code>: σ = {summary['centre_px']:.3g} px at the image centre, "
            f"{summary['max_px']:.3g} px at most (image corners are usually worst: extrapolation "
            "beyond the observed corners grows it).",
        ))
    return "".join(out)


def _poses_from(result: Any, file: ResultFile) -> dict[str, dict[str, np.ndarray]] | None:
    details = getattr(result, "details", None)
    poses = getattr(details, "T_cam_target", None)
    if poses is None:
        poses = file.extra.get(POSES_KEY)
    if poses is None:
        return None
    if not isinstance(poses, Mapping):
        raise BadInputError(
            f"{POSES_KEY}: expected a mapping station id -> {{camera id: 4x4}}, got {type(poses).__name__}"
        )
    out: dict[str, dict[str, np.ndarray]] = {}
    for sid, per_cam in poses.items():
        if not isinstance(per_cam, Mapping):
            raise BadInputError(f"{POSES_KEY}.{sid}: expected a mapping camera id -> 4x4, got {per_cam!r}")
        for cam, T in per_cam.items():
            T = np.asarray(T, dtype=np.float64)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise BadInputError(
                    f"{POSES_KEY}.{sid}.{cam}: expected a finite 4x4 matrix, got shape {T.shape}"
                )
            out.setdefault(str(sid), {})[str(cam)] = T
    return out


def _project(cam, p_cam: np.ndarray) -> np.ndarray:
    """Pixels ``(n, 2)`` of camera-frame points ``(n, 3)`` (m) with the result's model."""
    from jcalib.report.analysis import _project as project

    return project(cam, p_cam)


def _residual_section(result: ResultFile, observations, poses) -> str:
    from jcalib.io.observations import load_observations
    from jcalib.report import plots

    obs = load_observations(observations)
    out = []
    if poses is None:
        out.append(
            '<p class="note">The result holds no per-view target poses '
            f"(<code>{_e(POSES_KEY)}</code>), so residuals cannot be re-projected; the plots show "
            "where corners were detected instead. Gaps at the edges and corners of the image leave "
            "the distortion there extrapolated (see the uncertainty map).</p>"
        )
    for name, cam in result.cameras.items():
        per_view_pix, obs_pix, p_cam = [], [], []
        for station in obs.stations:
            for det in station.detections:
                if det.camera != name or det.target is None or det.target not in obs.targets:
                    continue
                per_view_pix.append(np.asarray(det.pixels))
                T = None if poses is None else poses.get(station.id, {}).get(name)
                if T is None:
                    continue
                pts = obs.targets[det.target][det.point_index]
                obs_pix.append(np.asarray(det.pixels))
                p_cam.append(pts @ T[:3, :3].T + T[:3, 3][None, :])
        if not per_view_pix:
            out.append(f"<p><code>{_e(name)}</code>: no detections in the observations.</p>")
            continue
        if poses is None or not obs_pix:
            png = plots.coverage_png(name, cam.image_size, per_view_pix)
            n = sum(len(p) for p in per_view_pix)
            out.append(_figure(png, f"corner coverage of {name}",
                               f"<code>{_e(name)}</code>: {n} detected corners in {len(per_view_pix)} views."))
            continue
        pix = np.concatenate(obs_pix)
        res = pix - _project(cam, np.concatenate(p_cam))
        png, scale = plots.residual_vectors_png(name, cam.image_size, pix, res)
        rms = float(np.sqrt(np.mean(np.sum(res**2, axis=-1)) / 2.0))
        out.append(_figure(
            png, f"residual vectors of {name}",
            f"<code>{_e(name)}</code>: {len(pix)} corners of {len(obs_pix)} views with poses, "
            f"arrows magnified {scale:.0f}x, RMS {rms:.3g} px (per coordinate; rejected outliers "
            "included). Noise looks random; a pattern (swirls, radial flow) is model error.",
        ))
        png = plots.radial_residuals_png(name, pix, res, np.array([cam.K[0, 2], cam.K[1, 2]]))
        out.append(_figure(
            png, f"radial residuals of {name}",
            "Radial component of each residual (positive: observed farther from the principal point "
            "than predicted) against the distance from the principal point.",
        ))
    return "".join(out)


# ------------------------------------------------------------------------------ analysis sections

_INCLUDES = (
    '<p class="note"><b>Includes</b>: the sampling noise of the observations (pixel noise; robot '
    "pose noise as stated when the robot pose model was on) propagated to first order, scaled by the "
    "a-posteriori noise level when the solver did so. <b>Excludes</b>: model error (a too-simple lens "
    "model, unmodelled robot error), a wrong local minimum, nonlinearity beyond first order.</p>"
)


def _task_space_section(file: ResultFile) -> str:
    from jcalib.report import analysis
    from jcalib.report.tcp import is_tcp

    rows = []
    cameras = set(file.cameras)
    for name, tr in file.transforms.items():
        ts = analysis.transform_sigma(tr)
        if ts is None:
            continue
        child = name.split("_", 2)[-1] if name.count("_") >= 2 else name
        what = ("hand-eye" if child in cameras and name.startswith(("T_flange_", "T_base_")) else
                "TCP" if is_tcp(name, file) else "pose")
        rows.append([f"<code>{_e(name)}</code>", _e(what), _vec(ts["rotation_deg"], ".4f"),
                     _fmt(ts["rotation_total_deg"], 3), _vec(ts["translation_mm"], ".3f"),
                     _fmt(ts["translation_total_mm"], 3)])
    if not rows:
        return ""
    return ("<h3>Transforms (hand-eye, TCP, poses)</h3>"
            + _table(["transform", "kind", "σ rotation x y z [deg]", "total [deg]", "σ translation x y z [mm]",
                      "total [mm]"], rows, {2, 3, 4, 5})
            + '<p class="note">Per axis of the right-perturbation tangent, in the child frame; total = '
            "sqrt of the trace of the 3x3 block.</p>")


def _tcp_section(file: ResultFile) -> str:
    """σ of every TCP per flange axis and of the tool tip / a gripped point in the base frame (mm)."""
    from jcalib.report import tcp as T

    names = [n for n, tr in file.transforms.items() if T.is_tcp(n, file) and tr.covariance is not None]
    if not names:
        return ""
    ref = file.extra.get(T.GRIP_REFERENCE_KEY)
    B = np.eye(4) if ref is None else np.asarray(ref, np.float64)
    robot = T.robot_covariance(file)
    out = []
    rows = []
    for name in names:
        tr = file.transforms[name]
        s = T.tcp_std_mm(tr)
        Cr = np.asarray(tr.covariance)[:3, :3]
        tilt = float(np.degrees(np.sqrt(max(Cr[0, 0] + Cr[1, 1], 0.0))))
        rows.append([f"<code>{_e(name)}</code>", _vec(np.asarray(tr.matrix)[:3, 3] * 1e3, ".3f"), _vec(s, ".4f"),
                     _fmt(float(np.sqrt(np.sum(s**2))), 3),
                     _fmt(tilt, 3) if tilt > 0.0 else "not estimated (held)"])
    out.append(_table(["TCP", "position x y z [mm] (flange)", "σ x y z [mm] (flange)", "total σ [mm]",
                       "σ tool-axis tilt [deg]"], rows, {1, 2, 3, 4}))
    grip = np.asarray(T.DEFAULT_GRIPPED_POINT_M)
    rows = []
    for name in names:
        tr = file.transforms[name]
        rot_known = bool(np.any(np.diag(np.asarray(tr.covariance))[:3] > 0.0))
        points = [("tool tip", np.zeros(3)), (f"gripped point {1e3 * grip[2]:.0f} mm along the tool z", grip)]
        for label, p in points:
            for with_robot in ((False, True) if robot is not None else (False,)):
                C = T.gripped_point_covariance(tr, B, p, robot if with_robot else None)
                s = 1e3 * np.sqrt(np.maximum(np.diag(C), 0.0))
                what = label + (" + robot repeatability" if with_robot else "")
                if not rot_known and p.any():
                    what += " (orientation error of the TCP not included: not estimated)"
                rows.append([f"<code>{_e(name)}</code>", _e(what), _vec(s, ".4f"), _fmt(float(np.sqrt(np.sum(s**2))), 3)])
    out.append("<h3>Tool tip and gripped point in the base frame</h3>"
               + _table(["TCP", "point", "σ x y z [mm] (base)", "total σ [mm]"], rows, {2, 3}))
    where = ("at the flange pose <code>" + T.GRIP_REFERENCE_KEY + "</code> of the result" if ref is not None
             else "with the flange axes parallel to the base axes (the result names no reference pose)")
    out.append(f'<p class="note">σ per base axis {where}; the total does not depend on the flange orientation. '
               "Includes the TCP's calibration uncertainty (and, where named, the robot's stated repeatability at "
               "that pose); excludes model error (tip-detection bias, robot absolute-accuracy error).</p>")
    return "<h3>TCP</h3>" + "".join(out)


def _correlation_section(file: ResultFile, models: dict) -> str:
    from jcalib.report import analysis, plots

    sources = []
    joint = analysis.joint_covariance(file)
    if joint is not None:
        sources.append(("joint covariance of the result", [u.label for u in joint[0]], joint[1]))
    else:
        for name, m in models.items():
            sources.append((name, [u.label for u in m.unknowns], m.covariance()))
        if not models:
            for name, cam in file.cameras.items():
                if cam.covariance is not None:
                    free = [i for i, n in enumerate(cam.param_names) if cam.std.get(n, 1.0) != 0.0]
                    sources.append((name, [f"{name} {cam.param_names[i]}" for i in free],
                                    np.asarray(cam.covariance)[np.ix_(free, free)]))
    out = []
    for title, labels, C in sources:
        if len(labels) < 2:  # nothing to correlate (e.g. all intrinsics held)
            continue
        rho, pairs = analysis.correlations(C, labels, top=8, minimum=0.5)
        out.append(_figure(plots.correlation_png(labels, rho, f"correlations: {title}"),
                           f"correlation matrix {title}",
                           "Correlation between the unknowns (−1 blue … +1 red). Strongly correlated "
                           "unknowns trade off against each other: the data fix their combination, not each."))
        if pairs:
            out.append(_table(["unknown", "unknown", "correlation"],
                              [[_e(a), _e(b), f"{r:+.3f}"] for a, b, r in pairs], {2}))
    return "".join(out)


def _weak_section(models: dict, tolerances) -> str:
    from jcalib.report import analysis

    out = []
    for name, m in models.items():
        dirs = analysis.weak_directions(m, 3, tolerances)
        rows = [[str(k + 1), _fmt(d.ratio, 3), _e(d.describe())] for k, d in enumerate(dirs)]
        out.append(f"<h3><code>{_e(name)}</code></h3>" + _table(["#", "σ / tolerance", "direction (weights)"], rows, {1}))
    if out:
        tol = {**analysis.DEFAULT_TOLERANCES, **(tolerances or {})}
        out.insert(0, '<p class="note">Eigen-directions of the covariance with every unknown divided by '
                   f"its tolerance (transforms {tol['rotation_deg']:g}° and {tol['translation_mm']:g} mm; an "
                   f"intrinsic: the change that moves some image point by {tol['edge_px']:g} px). The first "
                   "is the combination the data determine worst; a ratio above 1 is worse than the tolerance.</p>")
    return "".join(out)


def _help_section(models: dict, tolerances) -> str:
    from jcalib.report import analysis

    out = []
    for name, m in models.items():
        sigma = m.sigma()
        ratio = sigma / analysis.unknown_tolerances(m, tolerances)
        order = [i for i in np.argsort(-ratio)][:3]
        labels = [m.unknowns[i].label for i in order]
        units = [m.unknowns[i].unit for i in order]
        sugg = analysis.what_would_help(m, labels)
        rows = [[_e(s.description)] + [
            f"{s.sigma_after[lab]:.3g} ({100 * (1 - s.sigma_after[lab] / s.sigma_before[lab]):.0f} % less)"
            for lab in labels] for s in sugg]
        head = ["one more station"] + [f"σ {lab} [{u}] now {sigma[i]:.3g}" for lab, u, i in zip(labels, units, order)]
        out.append(f"<h3><code>{_e(name)}</code></h3>" + _table(head, rows, set(range(1, len(head)))))
    if out:
        out.insert(0, '<p class="note">Predicted σ of the worst-determined unknowns (largest σ / tolerance) '
                   "if one more station of each kind were added: its Jacobian at the current estimate adds "
                   "its information (its own pose eliminated), best kind first.</p>")
    return "".join(out)


def _diagnostics_table(diags: dict) -> str:
    rows = []
    for name, d in diags.items():
        worst = max(d.view_rms_px.items(), key=lambda kv: kv[1]) if d.view_rms_px else ("–", 0.0)
        rows.append([f"<code>{_e(name)}</code>", _fmt(d.rms_px, 3), f"{_e(worst[0])}: {worst[1]:.3g}",
                     _e(len(d.outliers)), f"{d.radial.correlation:+.3f}", f"{d.radial.p_value:.2g}",
                     _fmt(d.radial.amplitude_px, 3), "yes" if d.radial.flagged else "no"])
    if not rows:
        return ""
    return (_table(["camera", "RMS [px]", "worst view RMS [px]", "outliers (> 5σ̂)", "corr(radial, r)",
                    "radial trend p", "trend amplitude [px]", "model too simple?"], rows, {1, 3, 4, 5, 6})
            + '<p class="note">Radial test: a cubic in the radius fitted to the radial residuals; p is the '
            "F-test p-value against no trend. A significant trend larger than half the noise hints at a "
            "too-simple lens model.</p>")


def _cross_validation_section(cell, observations, options) -> str:
    from jcalib.errors import BadInputError, NotObservableError
    from jcalib.report import analysis, plots

    try:
        cv = analysis.cross_validate(cell, observations, options)
    except (BadInputError, NotObservableError) as err:
        return f'<p class="note">Cross-validation not possible: {_e(err)}</p>'
    out = [(f'<p class="note">Calibrated separately on the even ({len(cv.stations[0])}) and odd '
           f"({len(cv.stations[1])}) stations. Each pixel's ray from half A is projected by half B after the "
           "best-fit common rotation (a camera-frame rotation is not a lens difference). A difference much "
           "larger than expected means the σ are too small (model error); comparable means they are honest.</p>")]
    for name, (u, v, diff, expected) in cv.maps.items():
        cam = cv.results[0].file.cameras[name]
        png = plots.cross_validation_png(name, u, v, diff, expected, cam.image_size)
        ratio = float(np.nanmedian(diff) / np.nanmedian(expected)) if np.any(np.isfinite(expected)) else float("nan")
        out.append(_figure(png, f"cross-validation of {name}",
                           f"<code>{_e(name)}</code>: difference median {np.nanmedian(diff):.3g} px, max "
                           f"{np.nanmax(diff):.3g} px; expected median {np.nanmedian(expected):.3g} px "
                           f"(ratio {ratio:.2f})."))
    rows = [[f"<code>{_e(n)}</code>", _fmt(t["rotation_deg"], 3), _fmt(t.get("rotation_sigma_deg", float("nan")), 3),
             _fmt(t["translation_mm"], 3), _fmt(t.get("translation_sigma_mm", float("nan")), 3)]
            for n, t in cv.transforms.items()]
    if rows:
        out.append(_table(["transform", "Δ rotation [deg]", "expected σ [deg]", "Δ translation [mm]",
                           "expected σ [mm]"], rows, {1, 2, 3, 4}))
    return "".join(out)


# ------------------------------------------------------------------------------ public API


def render_report(
    result: Any,
    observations: str | os.PathLike | Mapping | Any | None = None,
    title: str | None = None,
    cell: str | os.PathLike | Mapping | Any | None = None,
    tolerances: Mapping[str, float] | None = None,
    options: Any = None,
) -> str:
    """The HTML text of the one-page report of a result.

    Args:
        result: a :class:`jcalib.Result` (its ``details`` give the per-view poses, estimated flange
            poses and rejected corners), a :class:`~jcalib.io.result.ResultFile`, or a path to
            ``result.json``.
        observations: the ``jcalib.observations/1`` data the result was computed from (path, dict
            or :class:`~jcalib.io.observations.Observations`), or None. With them the report adds the
            weakest directions, "what would help", correlations across all shared unknowns, residual
            vectors, residual diagnostics (per-view RMS, outliers, radial test) when the result has
            per-view poses (``details.T_cam_target``, the file key :data:`POSES_KEY`, or hand-eye
            transforms), else the detected-corner coverage of each image.
        title: page title (default: "jcalib calibration report").
        cell: the cell spec (path, dict or ``CellSpec``): with ``observations``, adds the
            cross-validation (calibrations on the two halves of the stations; two more solves).
        tolerances: overrides of :data:`jcalib.report.analysis.DEFAULT_TOLERANCES`.
        options: calibration options for the cross-validation solves (default: the defaults).

    Returns:
        The HTML document (UTF-8 text, self-contained).

    Raises:
        BadInputError: unreadable or invalid result or observations.
    """
    from jcalib.report import analysis, plots

    source = None
    if isinstance(result, (str, os.PathLike)):
        source = str(result)
    file = result.file if hasattr(result, "file") and isinstance(result.file, ResultFile) else None
    file = file or load_result(result)
    models, diags = {}, {}
    if observations is not None:
        from jcalib.io.observations import load_observations

        observations = load_observations(observations)
        models = analysis.linear_models(result, observations)
        diags = analysis.residual_diagnostics(result, observations)
    warnings = analysis.analysis_warnings(file, models, diags, tolerances)

    stats = file.stats
    title = title or "jcalib calibration report"
    parts = [
        f"<h1>{_e(title)}</h1>",
        (
            f'<p class="note">{len(file.cameras)} camera(s), {len(file.transforms)} transform(s), '
        f"{len(file.points)} point(s). Uncertainties (σ) are sampling noise of the observations "
        "propagated to the estimate, not model error.</p>"
        ),
        _warnings_section(warnings),
        "<h2>Summary</h2>",
        _stats_section(stats),
        _intrinsics_section(file),
        _transforms_section(file),
        _points_section(file),
    ]
    if stats.get("view_rms_px"):
        parts += [
            "<h2>Per-view reprojection error</h2>",
            _figure(plots.view_rms_png(stats["view_rms_px"], stats.get("sigma_px")),
                    "per-view RMS", "RMS of the reprojection residuals of every view "
                    "(<code>camera/station</code>). A view far above the rest is a bad detection "
                    "or a wrong pose start."),
        ]
    parts += ["<h2>Task-space uncertainty</h2>", _INCLUDES, _task_space_section(file), _tcp_section(file),
              "<h3>Projection uncertainty</h3>", _uncertainty_section(file)]
    parts += ["<h2>Correlations</h2>", _correlation_section(file, models)]
    if models:
        parts += ["<h2>Weakest directions</h2>", _weak_section(models, tolerances),
                  "<h2>What would help</h2>", _help_section(models, tolerances)]
    if observations is not None:
        parts += ["<h2>Residuals</h2>", _diagnostics_table(diags),
                  _residual_section(file, observations,
                                    _poses_from(result, file) or analysis._camera_poses(result, file, observations))]
        if cell is not None:
            parts += ["<h2>Cross-validation</h2>", _cross_validation_section(cell, observations, options)]
    parts += ["<h2>Provenance</h2>", _provenance_section(file, source)]
    body = "\n".join(parts)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{_e(title)}</title><style>{_CSS}</style></head>"
        f"<body><main>\n{body}\n</main></body></html>\n"
    )


def write_report(
    result: Any,
    out: str | os.PathLike,
    observations: str | os.PathLike | Mapping | Any | None = None,
    title: str | None = None,
    cell: str | os.PathLike | Mapping | Any | None = None,
    tolerances: Mapping[str, float] | None = None,
    options: Any = None,
) -> Path:
    """Write :func:`render_report` to ``out`` atomically; returns the path.

    Raises:
        BadInputError: unreadable or invalid result or observations.
    """
    return write_text_atomic(out, render_report(result, observations, title, cell, tolerances, options))
