"""Sections of the HTML report that read the result: warnings, summary tables, per-view RMS, task-space
uncertainty (transforms, TCPs, projection maps) and provenance."""

from __future__ import annotations

import datetime as _dt
import json
from collections.abc import Mapping
from typing import Any

import numpy as np

from jcalib.io.result import ResultFile
from jcalib.report.markup import esc, figure, fmt, note, table, vec

__all__ = ["INCLUDES", "intrinsics", "points", "projection_maps", "provenance", "statistics", "task_space",
           "tcps", "transforms", "view_rms", "warnings"]

_PIXEL_PARAMS = {"fx", "fy", "cx", "cy", "skew"}

INCLUDES = note(
    "<b>Includes</b>: the sampling noise of the observations (pixel noise, tool-tip and contact noise; robot "
    "pose noise as stated when the robot pose model was on), each kind scaled by its own a-posteriori noise "
    "level (variance component) as the solve estimated it, propagated to first order. <b>Excludes</b>: model "
    "error (a too-simple lens model, unmodelled robot error), a wrong local minimum, nonlinearity beyond "
    "first order.")


def warnings(items: list) -> str:
    """Warnings, most severe first (:func:`jcalib.report.advice.analysis_warnings`); advice that several of
    them share is said once, after the list (:func:`jcalib.report.advice.stated_once`)."""
    from jcalib.report.advice import stated_once

    if not items:
        return '<div class="ok">No warnings.</div>'
    lines, hints = stated_once(items)
    lis = "".join(f"<li>{esc(line)}</li>" for line in lines)
    after = "".join(f'<p class="hint">{esc(h)}</p>' for h in hints)
    return (f'<div class="warn" id="warnings"><h2>Warnings</h2><p class="note">Most severe first.</p>'
            f"<ol>{lis}</ol>{after}</div>")


def statistics(stats: Mapping[str, Any]) -> str:
    labels = [("rms_px", "reprojection RMS per point (error norms, as OpenCV)", "px"),
              ("rms_px_per_coordinate", "reprojection RMS per coordinate (x and y errors, as mrcal)", "px"),
              ("sigma_px", "a-posteriori σ per coordinate", "px"),
              ("tip_rms_px", "tool-tip RMS per point", "px"),
              ("tip_rms_px_per_coordinate", "tool-tip RMS per coordinate", "px"), ("axis_rms_px", "tool-axis RMS", "px"),
              ("contact_rms_m", "contact RMS", "m"), ("num_residuals", "residuals", ""),
              ("num_outliers", "outliers rejected", ""), ("iterations", "iterations", ""),
              ("status", "solver status", "")]
    rows = []
    for key, label, unit in labels:
        if key in stats:
            v = stats[key]
            rows.append([esc(label), fmt(v, 4) if isinstance(v, float) else esc(v), esc(unit)])
    for kind, factor in (stats.get("variance_components") or {}).items():
        rows.append([esc(f"variance component: {kind}"), fmt(float(factor), 4), ""])
    if stats.get("reseeded_views"):
        rows.append([esc("re-seeded views"), esc(", ".join(map(str, stats["reseeded_views"]))), ""])
    if "view_rms_px" in stats:
        rows.append([esc("views"), esc(len(stats["view_rms_px"])), ""])
    views = stats.get("view_noise_factor") or {}
    if views:  # each view's σ relative to its kind's (jcalib.problems.refine, round 4)
        worst = max(views, key=views.get)
        rows.append([esc("view noise σ / kind σ (min – max, noisiest view)"),
                     esc(f"{min(views.values()) ** 0.5:.2f} – {views[worst] ** 0.5:.2f} ({worst})"), ""])
    from jcalib.report.console import robot_lines

    rows += [[esc(label), esc(text), ""] for label, text in robot_lines(stats)]
    return table(["statistic", "value", "unit"], rows, {1})


def prediction(stats: Mapping[str, Any]) -> str:
    """``stats.prediction`` (:mod:`jcalib.problems.prediction`): the held-out error and each station's, worst
    first; a note for a cell without a robot or a calibration run without it."""
    pred = stats.get("prediction")
    head = "<h2>Prediction from the robot's poses</h2>"
    if not pred:
        return head + note(esc("Not computed: " + ("the calibration ran with --no-prediction." if "robot_pose_model"
                                                     in stats else "a cell without a robot has no robot poses to "
                                                     "predict from.")))
    if "skipped" in pred:
        return head + note(esc(f"Not computed: {pred['skipped']}."))
    models = ", ".join(f"{r}: {m}" for r, m in (pred.get("model") or {}).items())
    text = (f"Each of {pred['stations']} stations held out in turn ({pred['method']}, {pred['folds']} solves): the "
            "cell calibrated without it predicts its corners from the station's recorded robot pose alone. "
            f"Held-out error {fmt(pred['rms_px'], 3)} px RMS per point (median {fmt(pred['median_px'], 3)} px), "
            f"{fmt(pred['rms_mm'], 3)} mm at the target; robot error model {models}."
            + (f" {pred['failed_folds']} fold(s) could not be solved." if pred.get("failed_folds") else ""))
    rows = [[esc(sid), fmt(v["rms_px"], 3), fmt(v["rms_mm"], 3), esc(v["points"])]
            for sid, v in sorted(pred["per_station"].items(), key=lambda kv: -kv[1]["rms_px"])]
    return head + note(esc(text)) + table(["station", "held-out RMS (px)", "at the target (mm)", "points"], rows, {1, 2, 3})


def intrinsics(file: ResultFile) -> str:
    out = []
    for name, cam in file.cameras.items():
        rows = []
        names, values = list(cam.param_names), list(cam.params)
        if cam.model == "splined":  # the core and the extent, then the spline's 416 values in one row
            spline = np.asarray(values[5:])
            stds = np.asarray([cam.std.get(n, np.nan) for n in names[5:]])
            names, values = names[:5], values[:5]
        for pname, value in zip(names, values):
            std = cam.std.get(pname)
            s = "–" if std is None else ("fixed" if std == 0.0 else fmt(std, 3))
            rows.append([esc(pname), fmt(value, 8), s, "px" if pname in _PIXEL_PARAMS else "–"])
        if cam.model == "splined":
            rows.append(["spline", f"{len(spline)} values (stereographic units), max |·| {fmt(np.max(np.abs(spline)), 3)}",
                         f"{fmt(np.nanmin(stds), 3)}–{fmt(np.nanmax(stds), 3)}" if np.any(np.isfinite(stds)) else "–",
                         "–"])
        w, h = cam.image_size
        out.append(f"<h3>Camera <code>{esc(name)}</code>: model <code>{esc(cam.model)}</code>, image {w} x {h} px</h3>"
                   + table(["parameter", "value", "σ", "unit"], rows, {1, 2}))
    return "".join(out) or note("No cameras in this result.")


def transforms(file: ResultFile) -> str:
    if not file.transforms:
        return ""
    from jcalib.geometry.conversions import matrix_to_rvec

    rows = []
    for name, tr in file.transforms.items():
        T = np.asarray(tr.matrix)
        rvec = np.degrees(np.asarray(matrix_to_rvec(T[:3, :3])))
        std = tr.std
        angle = float(np.linalg.norm(rvec))
        what = []
        if tr.extra.get("calibrated") is not None:
            what.append("estimated: " + (", ".join(tr.extra["calibrated"]) or "nothing (held)"))
        if tr.extra.get("orientation") is not None:
            what.append(f"orientation {tr.extra['orientation']}")
        rows.append([f"<code>{esc(name)}</code>" + (f"<br><span class=note>{esc('; '.join(what))}</span>"
                                                     if what else ""),
                     vec(T[:3, 3] * 1e3, ".3f"), "–" if std is None else vec(std[3:] * 1e3, ".3f"),
                     vec(rvec, ".4f") + f"<br><span class=note>|r| = {angle:.4f}°</span>",
                     "–" if std is None else vec(np.degrees(std[:3]), ".4f")])
    return ("<h3>Transforms</h3>"
            + note("<code>T_a_b</code> is the pose of frame b in frame a (maps b → a). Rotation as a rotation "
                   "vector in degrees; σ over the right-perturbation tangent (rx, ry, rz, tx, ty, tz), expressed "
                   "in frame b.")
            + table(["transform", "translation [mm]", "σ t [mm]", "rotation vector [deg]", "σ r [deg]"], rows,
                    {1, 2, 3, 4}))


def points(file: ResultFile) -> str:
    if not file.points:
        return ""
    rows = []
    for name, pt in file.points.items():
        std = None if pt.covariance is None else np.sqrt(np.maximum(np.diag(pt.covariance), 0.0))
        rows.append([f"<code>{esc(name)}</code>", esc(pt.frame), vec(pt.position * 1e3, ".3f"),
                     "–" if std is None else vec(std * 1e3, ".3f")])
    return "<h3>Points</h3>" + table(["point", "frame", "position [mm]", "σ [mm]"], rows, {2, 3})


def targets(file: ResultFile) -> str:
    """Board warps (non-flatness) estimated for targets with ``warp: true``."""
    if not file.targets:
        return ""
    rows = []
    for name, target in file.targets.items():
        std = target.warp_std_m
        c = target.warp_m
        rows.append([f"<code>{esc(name)}</code>", vec(c * 1e3, ".4f"), "–" if std is None else vec(std * 1e3, ".4f"),
                     f"{(c[0] + c[1]) * 1e3:.4f}"])
    return ("<h3>Target warp</h3>"
            + note("Board non-flatness, mrcal's parabolic definition: z = c0 (1 − xr²) + c1 (1 − yr²) in the target "
                   "frame, xr and yr in [−1, 1] over the extent of its points (x along its columns); the centre "
                   "moves by c0 + c1, the corners not at all.")
            + table(["target", "c0, c1 [mm]", "σ [mm]", "centre [mm]"], rows, {1, 2, 3}))


def lenses(file: ResultFile, heldout: Mapping[str, Mapping] | None = None) -> str:
    """Zoom lenses: each intrinsic and the axial shift against the setting with σ bands (``lenses.<cam>``),
    the held-out settings (``heldout``: camera -> :func:`jcalib.problems.lens_heldout.heldout_settings`, or
    the entry's own ``heldout``) marked with their prediction RMS."""
    from jcalib.problems.lens import lens_function
    from jcalib.report import plots

    entries = file.extra.get("lenses") or {}
    if not entries:
        return ""
    out = ["<h3>Zoom lenses</h3>", note("The camera's intrinsics and the shift of its frame along the optical axis "
                                         "as functions of the lens setting (sampling σ, not the error of the "
                                         "spline between calibrated settings: the held-out settings test that).")]
    for name, entry in entries.items():
        mount = entry.get("mount")
        lens = lens_function(entry, file.transforms[mount].matrix if mount in file.transforms else None)
        held = ((heldout or {}).get(name) or entry.get("heldout") or {}).get("settings") or {}
        columns = [n for n in lens.param_names if n not in ("p1", "p2")] + ["shift_m"]
        png = plots.lens_functions_png(name, lens, columns, entry.get("settings_used", []), held)
        out.append(figure(png, f"lens functions of {name}", f"{name}: intrinsics and axial shift against "
                                                            f"{esc(lens.setting)}"))
    return "".join(out)


def view_rms(stats: Mapping[str, Any]) -> str:
    from jcalib.report import plots

    if not stats.get("view_rms_px"):
        return note("The result has no per-view reprojection errors (no target corners).")
    return figure(plots.view_rms_png(stats["view_rms_px"], stats.get("sigma_px")), "per-view RMS",
                  "RMS per point (of the residual norms) of every view (<code>camera/station</code>); per coordinate "
                  "it is the same divided by about √2 (<code>stats.view_rms_px_per_coordinate</code>). A view far "
                  "above the rest is a bad detection or a wrong pose start.")


def provenance(file: ResultFile, source: str | None) -> str:
    p = file.provenance
    rows = []
    if source:
        rows.append(["result file", f"<code>{esc(source)}</code>"])
    if p is None:
        rows.append(["provenance", "not recorded in the result"])
    else:
        rows += [["input hash", f"<code>{esc(p.input_hash or '–')}</code>"],
                 ["jcalib version", esc(p.jcalib_version or "–")], ["created", esc(p.created or "–")],
                 ["options", f"<code>{esc(json.dumps(dict(p.options), sort_keys=True))}</code>"]]
    from jcalib import __version__

    now = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z")
    rows.append(["report", esc(f"written {now} by jcalib {__version__}")])
    return table(["field", "value"], rows, cls="kv")


# ------------------------------------------------------------------------------ task space


def task_space(file: ResultFile) -> str:
    """σ of every transform per axis and in total."""
    from jcalib.problems.taskspace import transform_sigma
    from jcalib.report.tcp import is_tcp

    rows = []
    cameras = set(file.cameras)
    for name, tr in file.transforms.items():
        ts = transform_sigma(tr)
        if ts is None:
            continue
        child = name.split("_", 2)[-1] if name.count("_") >= 2 else name
        what = ("camera pose" if child in cameras else "TCP" if is_tcp(name, file)
                else "robot base" if name.startswith("T_world_") and file.stats.get("robot") else "pose")
        rows.append([f"<code>{esc(name)}</code>", esc(what), vec(ts["rotation_deg"], ".4f"),
                     fmt(ts["rotation_total_deg"], 3), vec(ts["translation_mm"], ".3f"),
                     fmt(ts["translation_total_mm"], 3)])
    if not rows:
        return ""
    return ("<h3>Transforms (hand-eye, TCP, poses)</h3>"
            + table(["transform", "kind", "σ rotation x y z [deg]", "total [deg]", "σ translation x y z [mm]",
                     "total [mm]"], rows, {2, 3, 4, 5})
            + note("Per axis of the right-perturbation tangent, in the child frame; total = sqrt of the trace of "
                   "the 3x3 block."))


def tcps(file: ResultFile, reference: Mapping[str, np.ndarray] | None = None,
         robot_of: Mapping[str, str] | None = None) -> str:
    """σ of every TCP per flange axis and of the tool tip / a gripped point in the base frame (mm).

    Args:
        reference: tool transform name -> ``(4, 4)`` flange pose (robot base) at which the base-frame σ
            is evaluated (default: the file's :data:`jcalib.report.tcp.GRIP_REFERENCE_KEY`, else
            flange axes parallel to the base axes).
        robot_of: tool transform name -> the robot holding it (whose repeatability is added; default:
            the file's only robot).
    """
    from jcalib.report import tcp as T

    names = [n for n, tr in file.transforms.items() if T.is_tcp(n, file) and tr.covariance is not None]
    if not names:
        return ""
    ref = file.extra.get(T.GRIP_REFERENCE_KEY)
    rows = []
    for name in names:
        tr = file.transforms[name]
        s = T.tcp_std_mm(tr)
        Cr = np.asarray(tr.covariance)[:3, :3]
        tilt = float(np.degrees(np.sqrt(max(Cr[0, 0] + Cr[1, 1], 0.0))))
        rows.append([f"<code>{esc(name)}</code>", vec(np.asarray(tr.matrix)[:3, 3] * 1e3, ".3f"), vec(s, ".4f"),
                     fmt(float(np.sqrt(np.sum(s**2))), 3), fmt(tilt, 3) if tilt > 0.0 else "not estimated (held)"])
    out = [table(["TCP", "position x y z [mm] (flange)", "σ x y z [mm] (flange)", "total σ [mm]",
                  "σ tool-axis tilt [deg]"], rows, {1, 2, 3, 4})]
    grip = np.asarray(T.DEFAULT_GRIPPED_POINT_M)
    rows = []
    for name in names:
        tr = file.transforms[name]
        robots = {"": None, " + robot repeatability (stated)": T.robot_covariance(file, (robot_of or {}).get(name)),
                  " + robot accuracy (a-posteriori estimate)": T.robot_covariance(file, (robot_of or {}).get(name),
                                                                                  estimate=True)}
        B = np.asarray((reference or {}).get(name, np.eye(4) if ref is None else ref), np.float64)
        rot_known = bool(np.any(np.diag(np.asarray(tr.covariance))[:3] > 0.0))
        for label, p in (("tool tip", np.zeros(3)), (f"gripped point {1e3 * grip[2]:.0f} mm along the tool z", grip)):
            for extra, robot in robots.items():
                if extra and robot is None:
                    continue
                C = T.gripped_point_covariance(tr, B, p, robot)
                s = 1e3 * np.sqrt(np.maximum(np.diag(C), 0.0))
                what = label + extra
                if not rot_known and p.any():
                    what += " (orientation error of the TCP not included: not estimated)"
                rows.append([f"<code>{esc(name)}</code>", esc(what), vec(s, ".4f"), fmt(float(np.sqrt(np.sum(s**2))), 3)])
    out.append("<h3>Tool tip and gripped point in the base frame</h3>"
               + table(["TCP", "point", "σ x y z [mm] (base)", "total σ [mm]"], rows, {2, 3}))
    where = ("at a flange pose of the calibration (the tool's first station)" if reference else
             "at the flange pose <code>" + T.GRIP_REFERENCE_KEY + "</code> of the result" if ref is not None
             else "with the flange axes parallel to the base axes (the result names no reference pose)")
    out.append(note(f"σ per base axis {where}; the total does not depend on the flange orientation. Includes the "
                    "TCP's calibration uncertainty (and, where named, the robot's flange-pose σ at that pose: as stated "
                    "in the cell, and as the calibration estimated it from the stations' flange corrections); "
                    "excludes model error (tip-detection bias, robot absolute-accuracy error)."))
    return "<h3>TCP</h3>" + "".join(out)


def projection_maps(file: ResultFile, covariances: Mapping[str, np.ndarray] | None = None) -> str:
    """Projection σ maps of every camera with free intrinsics.

    Args:
        covariances: camera id -> ``(p, p)`` intrinsics covariance from the solve's model (default: the
            file's, the same numbers when the file came from that solve).
    """
    from jcalib.report import plots

    out = [note(
        "σ (pixels, worst direction) of the projection of a point at each place in the image, by linear "
        "propagation of the intrinsics covariance through the lens model's <code>project</code> (its JAX "
        "Jacobian w.r.t. the intrinsics). <b>Includes</b> the intrinsics uncertainty caused by the measurement "
        "noise (as the solve reported it). <b>Excludes</b> model error (a too-simple lens model) and the "
        "uncertainty of the camera and target poses. The lens models are central, so the value is the same at "
        "every depth along a pixel's ray.")]
    for name, cam in file.cameras.items():
        cov = (covariances or {}).get(name, cam.covariance)
        if cov is None:
            out.append(f"<p><code>{esc(name)}</code>: no intrinsics covariance in the result; no map.</p>")
            continue
        if not np.any(np.diag(np.asarray(cov)) > 0.0):
            out.append(f"<p><code>{esc(name)}</code>: intrinsics held fixed (known): they add no projection "
                       "uncertainty.</p>")
            continue
        png, summary = plots.projection_sigma_png(name, cam, cov)
        out.append(figure(png, f"projection uncertainty of {name}",
                          f"<code>{esc(name)}</code>: σ = {summary['centre_px']:.3g} px at the image centre, "
                          f"{summary['max_px']:.3g} px at most (image corners are usually worst: extrapolation "
                          "beyond the observed corners grows it)."))
    return "".join(out)
