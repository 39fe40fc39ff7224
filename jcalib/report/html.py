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


def _warnings_section(stats: Mapping[str, Any]) -> str:
    warnings = stats.get("warnings") or []
    status = stats.get("status")
    items = [f"<li>{_e(w)}</li>" for w in warnings]
    if status is not None and str(status) != "converged":
        items.insert(0, f"<li>solver status: <b>{_e(status)}</b> (not converged)</li>")
    if not items:
        return '<div class="ok">No warnings.</div>'
    return f'<div class="warn" id="warnings"><h2>Warnings</h2><ul>{"".join(items)}</ul></div>'


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
    import jax.numpy as jnp

    from jcalib.report.plots import _camera_model

    return np.asarray(_camera_model(cam).project(jnp.asarray(p_cam)))


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


# ------------------------------------------------------------------------------ public API


def render_report(
    result: Any,
    observations: str | os.PathLike | Mapping | Any | None = None,
    title: str | None = None,
) -> str:
    """The HTML text of the one-page report of a result.

    Args:
        result: a :class:`jcalib.Result` (its ``details`` give the per-view poses for the
            residual plots), a :class:`~jcalib.io.result.ResultFile`, or a path to ``result.json``.
        observations: the ``jcalib.observations/1`` data the result was computed from (path, dict
            or :class:`~jcalib.io.observations.Observations`), or None: adds the residual vectors
            over the image and the radial residual plot when the result has per-view poses
            (``details.T_cam_target`` or the file key :data:`POSES_KEY`), else the detected-corner
            coverage of each image.
        title: page title (default: "jcalib calibration report").

    Returns:
        The HTML document (UTF-8 text, self-contained).

    Raises:
        BadInputError: unreadable or invalid result or observations.
    """
    source = None
    if isinstance(result, (str, os.PathLike)):
        source = str(result)
    file = result.file if hasattr(result, "file") and isinstance(result.file, ResultFile) else None
    file = file or load_result(result)
    from jcalib.report import plots

    stats = file.stats
    title = title or "jcalib calibration report"
    parts = [
        f"<h1>{_e(title)}</h1>",
        (
            f'<p class="note">{len(file.cameras)} camera(s), {len(file.transforms)} transform(s), '
        f"{len(file.points)} point(s). Uncertainties (σ) are sampling noise of the observations "
        "propagated to the estimate, not model error.</p>"
        ),
        _warnings_section(stats),
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
    parts += ["<h2>Projection uncertainty</h2>", _uncertainty_section(file)]
    if observations is not None:
        parts += ["<h2>Residuals</h2>", _residual_section(file, observations, _poses_from(result, file))]
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
) -> Path:
    """Write :func:`render_report` to ``out`` atomically; returns the path.

    Raises:
        BadInputError: unreadable or invalid result or observations.
    """
    return write_text_atomic(out, render_report(result, observations, title))
