"""Rich console tables of a result: every unknown with its value, σ and unit."""

from __future__ import annotations

import numpy as np
from rich.console import Console
from rich.table import Table

from jcalib.io.result import KinematicsResult, ResultFile
from jcalib.report.error_model import error_model_line

_PIXEL_PARAMS = {"fx", "fy", "cx", "cy", "skew"}


def intrinsics_table(result: ResultFile, truth: dict[str, dict[str, float]] | None = None) -> Table:
    """One row per intrinsic of every camera: value, σ (and truth, error/σ when ``truth`` is given)."""
    table = Table(title="Camera intrinsics", show_lines=False)
    for col in ("camera", "parameter", "estimate", "σ", "unit"):
        table.add_column(col, justify="right" if col in ("estimate", "σ") else "left")
    if truth is not None:
        table.add_column("truth", justify="right")
        table.add_column("error / σ", justify="right")
    for name, cam in result.cameras.items():
        names, values = list(cam.param_names), list(cam.params)
        if cam.model == "splined":  # 416 spline values: the core, the extent and one summary row
            spline = np.asarray(values[5:])
            stds = np.asarray([cam.std.get(n, np.nan) for n in names[5:]])
            table.add_row(name, "spline", f"{len(spline)} values, max |·| {np.max(np.abs(spline)):.3g}",
                          f"{np.nanmin(stds):.2g}–{np.nanmax(stds):.2g}" if np.any(np.isfinite(stds)) else "–", "")
            names, values = names[:5], values[:5]
        for pname, value in zip(names, values):
            std = cam.std.get(pname)
            unit = "px" if pname in _PIXEL_PARAMS else ""
            fixed = std is not None and std == 0.0
            row = [name, pname, f"{value:.6g}", "fixed" if fixed else (f"{std:.2g}" if std is not None else "–"), unit]
            if truth is not None:
                t = truth.get(name, {}).get(pname)
                if t is None:
                    row += ["", ""]
                else:
                    z = (value - t) / std if std else float("nan")
                    row += [f"{t:.6g}", "" if fixed or not np.isfinite(z) else f"{z:+.2f}"]
            table.add_row(*row)
    return table


def transforms_table(result: ResultFile) -> Table | None:
    """One row per transform: translation (mm) and rotation vector (deg) with their σ."""
    if not result.transforms:
        return None
    from jcalib.geometry.conversions import matrix_to_rvec

    table = Table(title="Transforms (T_a_b: pose of b in a)")
    for col in ("transform", "t [mm]", "σ t [mm]", "rvec [deg]", "σ r [deg]"):
        table.add_column(col)
    for name, tr in result.transforms.items():
        T = np.asarray(tr.matrix)
        rvec = np.degrees(matrix_to_rvec(T[:3, :3]))
        std = tr.std
        table.add_row(
            name,
            " ".join(f"{v:.3f}" for v in T[:3, 3] * 1e3),
            "–" if std is None else " ".join(f"{v:.3f}" for v in std[3:] * 1e3),
            " ".join(f"{v:.4f}" for v in rvec),
            "–" if std is None else " ".join(f"{v:.4f}" for v in np.degrees(std[:3])),
        )
    return table


def points_table(result: ResultFile) -> Table | None:
    """One row per estimated point: position (mm) in its frame with σ."""
    if not result.points:
        return None
    table = Table(title="Points")
    for col in ("point", "frame", "position [mm]", "σ [mm]"):
        table.add_column(col)
    for name, pt in result.points.items():
        cov = pt.covariance
        std = "–" if cov is None else " ".join(f"{v:.3f}" for v in np.sqrt(np.maximum(np.diag(cov), 0.0)) * 1e3)
        table.add_row(name, pt.frame, " ".join(f"{v:.3f}" for v in np.asarray(pt.position) * 1e3), std)
    return table


def targets_table(result: ResultFile) -> Table | None:
    """One row per target whose warp was estimated: ``c0, c1`` (mm) with σ."""
    if not result.targets:
        return None
    table = Table(title="Target warp (z = c0 (1 − xr²) + c1 (1 − yr²))")
    for col in ("target", "c0, c1 [mm]", "σ [mm]"):
        table.add_column(col)
    for name, target in result.targets.items():
        std = target.warp_std_m
        table.add_row(name, " ".join(f"{v:.4f}" for v in target.warp_m * 1e3),
                      "–" if std is None else " ".join(f"{v:.4f}" for v in std * 1e3))
    return table


def kinematics_table(robot: str, k: KinematicsResult) -> Table:
    """The "Robot kinematics" table of one robot: every calibrated parameter with nominal, calibrated,
    change and σ (mm / deg)."""
    from jcalib.report.kinematics import parameter_rows

    table = Table(title=f"Robot kinematics: {robot} ({k.convention})")
    for col in ("parameter", "nominal", "calibrated", "change", "σ", "unit"):
        table.add_column(col, justify="left" if col in ("parameter", "unit") else "right")
    for p in parameter_rows(k):
        table.add_row(p.name, f"{p.nominal:.5f}", f"{p.calibrated:.5f}", f"{p.change:+.4g}",
                      "–" if p.std is None else f"{p.std:.3g}", p.unit)
    return table


def kinematics_lines(k: KinematicsResult) -> list[str]:
    """The lines under a robot's kinematics table: the held parameters, the stations' flange correction
    RMS against the stated repeatability, and the held-out prediction error."""
    from jcalib.report.kinematics import fit_lines

    held = list(k.extra.get("held") or {})
    return [f"held at nominal: {', '.join(held) if held else 'none'}", *fit_lines(k)]


def print_result(result: ResultFile, console: Console | None = None, truth=None) -> None:
    """Print the result's tables and fit statistics."""
    console = console or Console()
    if result.cameras:
        console.print(intrinsics_table(result, truth))
    for t in (transforms_table(result), points_table(result), targets_table(result)):
        if t is not None:
            console.print(t)
    for robot, k in result.kinematics.items():
        console.print(kinematics_table(robot, k))
        for line in kinematics_lines(k):
            console.print(line, highlight=False)
    s = result.stats
    parts = []
    if "rms_px" in s:
        parts.append(f"{rms_text(s)} · a-posteriori σ {s.get('sigma_px', float('nan')):.4f} px per coordinate")
    if "contact_rms_m" in s:
        parts.append(f"contact RMS {s['contact_rms_m'] * 1e3:.4f} mm")
    parts.append(f"{s.get('num_residuals', 0)} residuals · {s.get('iterations', '?')} iterations · "
                 f"status {s.get('status', '?')} · {s.get('num_outliers', 0)} outliers rejected")
    console.print(" · ".join(parts), highlight=False)
    for label, text in robot_lines(s):
        console.print(f"{label}: {text}", highlight=False)
    for line in (prediction_line(s.get("prediction")), error_model_line(s)):
        if line:
            console.print(line, highlight=False)
    for note in s.get("notes", []):
        console.print(f"note: {note}", highlight=False)
    for warning in s.get("warnings", []):
        console.print(f"[bold yellow]warning:[/] {warning}", highlight=False)
    from jcalib.report.budget import console_lines

    for line in console_lines(result):
        console.print(line, highlight=False, markup=False)


def rms_text(stats: dict, key: str = "rms_px") -> str:
    """``"RMS 0.2828 px per point (0.2000 px per coordinate)"``: ``stats[key]`` is the RMS of the error norms
    (per point, as OpenCV prints), ``stats[key + "_per_coordinate"]`` that of the x and y errors (as mrcal
    prints), when the result holds it."""
    text = f"RMS {stats[key]:.4f} px per point"
    per = stats.get(f"{key}_per_coordinate")
    return text + (f" ({per:.4f} px per coordinate)" if per is not None else "")


def prediction_line(pred: dict | None) -> str | None:
    """One sentence for ``stats.prediction`` (:mod:`jcalib.problems.prediction`), or None without one."""
    if not pred:
        return None
    if "skipped" in pred:
        return f"prediction from the robot's poses: not computed ({pred['skipped']})"
    mm = pred.get("rms_mm", float("nan"))
    at_board = f", {mm:.2f} mm at the target" if mm == mm else ""
    return (f"predicted from the robot's pose, a held-out station's corners land within {pred['rms_px']:.2f} px RMS "
            f"per point{at_board} ({pred['method']}, {pred['stations']} stations)")


def robot_lines(stats: dict) -> list[tuple[str, str]]:
    """``(label, text)`` per robot of ``stats.robot`` (:func:`jcalib.problems.assemble.robot_statistics`): the
    flange-pose σ the calibration estimated (a posteriori, from the stations' flange corrections) beside the
    one the cell stated (``pose_noise``); empty without robot statistics."""
    robots = stats.get("robot") or {}
    if "prior_sigma_translation_m" in robots:
        robots = {"": robots}

    def triple(values, scale: float, digits: str) -> str:
        return " ".join(format(float(v) * scale, digits) for v in np.atleast_1d(np.asarray(values, np.float64)))

    out = []
    for name, r in robots.items():
        if not isinstance(r, dict) or "prior_sigma_translation_m" not in r:
            continue
        t, rot = r.get("a_posteriori_sigma_translation_m"), r.get("a_posteriori_sigma_rotation_deg")
        if t is not None and np.all(np.isfinite(np.asarray(t, np.float64))):
            est = f"x y z {triple(t, 1e3, '.4f')} mm, {triple(rot, 1.0, '.5f')} deg"
        else:
            est = "not estimated (no redundancy)"
        stated = (f"{triple(r['prior_sigma_translation_m'], 1e3, '.4f')} mm, "
                  f"{triple(r.get('prior_sigma_rotation_deg', [0.0]), 1.0, '.5f')} deg")
        text = (f"flange-pose σ estimated {est} (a posteriori, from the stations' flange corrections); stated "
                f"(pose_noise) {stated}")
        out.append((f"robot accuracy{f' ({name})' if name else ''}", text))
    return out
