"""Calibrate & inspect: calibrate the session in the app's process, summarise the result, exclusions.

The calibration is the command line's, step for step: ``jcalib detect --session`` (:func:`jcalib.pipeline.
session.detect_session_to_file`, detections cached per image so a re-solve does not detect again), then
:func:`jcalib.calibrate` on the cell file and ``SESSION/observations.json`` (the session's exclusions
honoured the same way), so ``jcalib calibrate CELL SESSION/observations.json`` gives the same numbers. The
solve stays compiled in this process: after the first solve, a re-solve (a view excluded) costs the solve.
The full report (every section: it has the in-memory result) is written in the background after each solve.
"""

from __future__ import annotations

import shutil
import time
from typing import Any

import numpy as np

from jcalib.errors import BadInputError, JcalibError

__all__ = ["start_calibrate", "set_exclusion", "result_summary", "view_residuals", "export_formats", "export"]


def _calibrate(state, report, what: str) -> dict:
    from jcalib.pipeline.session import detect_session_to_file
    from jcalib.problems.api import calibrate

    cfg = state.config
    if not state.capture_started() or not state.session_records():
        raise BadInputError(f"the session {cfg.session_dir} has no captured station yet: capture first")
    report(0.1, "detecting (new images only)")
    detect_session_to_file(cfg.session_dir, cfg.cell_path, cfg.observations_path, progress=False,
                           cache=state.detection_cache)  # fmt: skip
    state.refresh_session()
    report(0.4, "solving")
    t0 = time.perf_counter()
    result = calibrate(cfg.cell_path, cfg.observations_path)
    solve_s = time.perf_counter() - t0
    cfg.app_dir.mkdir(parents=True, exist_ok=True)
    if cfg.result_path.is_file():
        shutil.copyfile(cfg.result_path, cfg.previous_path)
    result.to_json(cfg.result_path)
    with state.lock:
        state.previous = state.result if state.result is not None else _load_previous(cfg)
        state.result, state.solve_s = result, solve_s
        state.warnings = ["(computing the report's warnings …)"]
    state.spawn(_write_report, "report", state, result)
    s = result.file.stats
    return {"summary": f"{what}: RMS {float(s.get('rms_px', float('nan'))):.4g} px per point, solved in "
                       f"{solve_s:.2f} s" + (f"; left out {', '.join(s['excluded'])}" if s.get("excluded") else ""),
            "solve_s": solve_s}  # fmt: skip


def _load_previous(cfg):
    from jcalib.io.result import load_result
    from jcalib.problems.calibrate import Result

    if cfg.previous_path.is_file():
        try:
            return Result(load_result(cfg.previous_path))
        except JcalibError:
            return None
    return None


def _write_report(state, result) -> None:
    """The full HTML report of the in-memory result (every section) and the warnings the page lists."""
    from jcalib.report.html import write_report

    cfg = state.config
    try:
        write_report(result, cfg.report_path, observations=cfg.observations_path, cell=cfg.cell_path)
        warnings = _warnings(result)
    except JcalibError as e:
        warnings = [f"the report could not be written: {e}"]
    except Exception as e:  # a report bug must not take the app down
        warnings = [f"the report could not be written (a bug, please report it): {type(e).__name__}: {e}"]
    with state.lock:
        if state.result is result:
            state.warnings = warnings
    state.bus.publish({"type": "report", "path": str(cfg.report_path)})


def _warnings(result) -> list[str]:
    from jcalib.report.advice import analysis_warnings
    from jcalib.report.diagnostics import residual_diagnostics
    from jcalib.report.model import linear_model

    cal = result.details
    return [w.message for w in analysis_warnings(result.file, linear_model(cal), residual_diagnostics(cal))]


def start_calibrate(state):
    state.cell_spec()
    return state.jobs.start("calibrate", "calibrate", lambda job, report: _calibrate(state, report, "calibrated"))


def set_exclusion(state, station: str, camera: str | None, excluded: bool):
    """Exclude or include a view (``camera``) or a whole station in ``SESSION/exclusions.json``, then re-solve."""
    from jcalib.io.exclusions import load_exclusions, save_exclusions

    if not isinstance(station, str) or (camera is not None and not isinstance(camera, str)):
        raise BadInputError("station / camera: expected ids (text)")
    if not isinstance(excluded, bool):
        raise BadInputError("excluded: expected true or false")
    records = {r["id"]: r for r in state.session_records()}
    if station not in records:
        raise BadInputError(f"station {station!r} is not in the session")
    if camera is not None and camera not in (records[station].get("images") or {}):
        raise BadInputError(f"station {station!r} has no image of camera {camera!r}")
    with state.lock:
        excl = load_exclusions(state.config.session_dir)
        excl = excl.with_view(station, camera, excluded) if camera else excl.with_station(station, excluded)
        save_exclusions(state.config.session_dir, excl)
    what = f"{'excluded' if excluded else 'included'} {station}" + (f"/{camera}" if camera else "")
    return state.jobs.start("calibrate", f"re-solve ({what})", lambda job, report: _calibrate(state, report, what))


def result_summary(state) -> dict:
    """Everything the inspect page shows of the latest result."""
    from jcalib.geometry.conversions import matrix_to_rvec
    from jcalib.io.exclusions import load_exclusions
    from jcalib.problems.goals import achieved_sigmas

    result = state.result
    if result is None:
        return {"available": False, "message": "No result yet: press Calibrate."}
    f = result.file
    s = f.stats
    cams = []
    for name, c in f.cameras.items():
        params = []
        for p, v in zip(c.param_names, c.params):
            std = c.std.get(p)
            params.append({"name": p, "value": float(v), "std": None if std is None else float(std),
                           "fixed": std is None or std == 0.0, "unit": "px" if p in ("fx", "fy", "cx", "cy", "skew") else "–"})
        cams.append({"name": name, "model": c.model, "image_size": list(c.image_size), "params": params})
    transforms = []
    for name, t in f.transforms.items():
        T = np.asarray(t.matrix, dtype=np.float64)
        std = None if t.std is None else np.asarray(t.std, dtype=np.float64)
        transforms.append({
            "name": name, "t_mm": (T[:3, 3] * 1e3).tolist(), "r_deg": np.degrees(np.asarray(matrix_to_rvec(T[:3, :3]))).tolist(),
            "std_t_mm": None if std is None else (std[3:] * 1e3).tolist(),
            "std_r_deg": None if std is None else np.degrees(std[:3]).tolist(),
            "note": ", ".join(str(x) for x in ([t.extra["orientation"]] if t.extra.get("orientation") else []))})
    excl = load_exclusions(state.config.session_dir)
    views = _views(state, excl)
    goals = []
    spec_goals = state.cell_spec().goals
    if spec_goals:
        try:
            sig = achieved_sigmas(spec_goals, f)
            goals = [{"goal": g.text, "achieved": sig[g.text], "limit": g.limit, "met": sig[g.text] <= g.limit}
                     for g in spec_goals]  # fmt: skip
        except BadInputError as e:
            goals = [{"goal": g.text, "achieved": None, "limit": g.limit, "met": False, "error": str(e)} for g in spec_goals]
    robot = s.get("robot")
    compare = _compare(state)
    return {
        "available": True, "path": str(state.config.result_path), "solve_s": state.solve_s,
        "stats": {"rms_px": s.get("rms_px"), "sigma_px": s.get("sigma_px"), "status": s.get("status"),
                  "iterations": s.get("iterations"), "num_residuals": s.get("num_residuals"),
                  "outliers": s.get("num_outliers", s.get("outliers", 0))},
        "cameras": cams, "transforms": transforms, "views": views, "warnings": list(state.warnings), "goals": goals,
        "robot": _robot_text(robot), "excluded": list(s.get("excluded") or []), "compare": compare,
    }  # fmt: skip


def _robot_text(robot: Any) -> str | None:
    """The robot-accuracy estimate of a result (``stats.robot``: the a-posteriori flange-pose σ of the pose
    model, against the stated one), in one line."""
    if not isinstance(robot, dict) or "a_posteriori_sigma_translation_m" not in robot:
        return None
    t = 1e3 * float(np.max(robot["a_posteriori_sigma_translation_m"]))
    r = float(np.max(robot["a_posteriori_sigma_rotation_deg"]))
    t0 = 1e3 * float(np.max(robot.get("prior_sigma_translation_m", [np.nan])))
    r0 = float(np.max(robot.get("prior_sigma_rotation_deg", [np.nan])))
    return (f"flange pose σ {t:.3g} mm / {r:.3g} deg a posteriori (stated {t0:.3g} mm / {r0:.3g} deg; "
            f"redundancy {float(robot.get('redundancy', float('nan'))):.3g})")


def _views(state, excl) -> list[dict]:
    from jcalib.report.diagnostics import residual_diagnostics

    result = state.result
    diags = residual_diagnostics(result.details)
    rows = []
    seen = set()
    for cam, d in diags.items():
        for sid in dict.fromkeys(d.view.tolist()):
            sel = d.view == sid
            rows.append({"camera": cam, "station": str(sid), "rms_px": d.view_rms_px.get(sid),
                         "points": int(sel.sum()), "outliers": int((sel & ~d.inlier).sum()), "excluded": False,
                         "station_excluded": excl.excludes(str(sid))})  # fmt: skip
            seen.add((str(sid), cam))
    for r in state.session_records():  # excluded views stay listed, to take them back in
        for cam in r.get("images") or {}:
            if (r["id"], cam) not in seen and excl.excludes(r["id"], cam):
                rows.append({"camera": cam, "station": r["id"], "rms_px": None, "points": 0, "outliers": 0,
                             "excluded": True, "station_excluded": excl.excludes(r["id"])})  # fmt: skip
    return rows


def view_residuals(state, station: str, camera: str) -> dict:
    """Observed corners and their residuals (observed − predicted, px) of one view, outliers marked."""
    from jcalib.report.diagnostics import residual_diagnostics

    result = state.result
    if result is None:
        raise BadInputError("no result yet: calibrate first")
    d = residual_diagnostics(result.details).get(camera)
    if d is None:
        raise BadInputError(f"camera {camera!r} has no corner residuals in the result")
    sel = d.view == station
    if not sel.any():
        raise BadInputError(f"view {station}/{camera} is not in the result (excluded, or nothing detected)")
    px, res, inl = d.pixels[sel], d.residuals[sel], d.inlier[sel]
    points = [{"px": [float(p[0]), float(p[1])], "r": [float(r[0]), float(r[1])], "inlier": bool(i)}
              for p, r, i in zip(px, res, inl)]  # fmt: skip
    size = result.file.cameras[camera].image_size
    return {"station": station, "camera": camera, "image_size": list(size), "rms_px": d.view_rms_px.get(station),
            "sigma_px": result.file.stats.get("sigma_px"), "points": points}  # fmt: skip


def _compare(state) -> dict | None:
    from jcalib.report.compare import compare_results

    prev, cur = state.previous, state.result
    if prev is None or cur is None:
        return None
    try:
        comps = compare_results(prev.file, cur.file)
    except BadInputError as e:
        return {"note": str(e), "cameras": {}}
    return {"note": "what `jcalib compare PREVIOUS CURRENT` prints: the projection difference over the image, "
                    "tested against both covariances",
            "cameras": {n: {"rms_px": c.rms_px, "max_px": c.max_px, "verdict": c.message} for n, c in comps.items()}}


def export_formats(state) -> dict:
    from jcalib.io.export import EXPORT_FORMATS
    from jcalib.io.export.formats import FORMAT_DESCRIPTIONS, format_option_names

    formats = []
    for name in EXPORT_FORMATS:
        formats.append({"name": name, "description": FORMAT_DESCRIPTIONS.get(name, ""),
                        "options": [{"name": o, "list": o == "tool_orientation",
                                     "placeholder": "TOOL=flange; TOOL=X,Y,Z" if o == "tool_orientation" else ""}
                                    for o in format_option_names(name)]})  # fmt: skip
    return {"formats": formats, "result": state.config.result_path.is_file()}


def export(state, fmt: str, options: dict) -> tuple[str, str]:
    """``(file name, text)`` of the latest result in ``fmt``, as ``jcalib export`` writes it (same refusals)."""
    from jcalib.io.export import export_text
    from jcalib.io.export.formats import DEFAULT_FILE_NAMES, export_options

    if not state.config.result_path.is_file():
        raise BadInputError("no result yet: calibrate first (Calibrate & inspect)")
    if not isinstance(options, dict):
        raise BadInputError("options: expected {name: value}")
    names = export_options(fmt, **options)
    text = export_text(state.config.result_path, fmt, **names)
    return DEFAULT_FILE_NAMES.get(fmt, f"jcalib_{fmt}.txt"), text
