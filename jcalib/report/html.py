"""The one-page HTML report of a result: tables, warnings, plots and provenance in one file.

Every cell gets the same sections: warnings (most severe first), summary, per-view reprojection error,
task-space uncertainty (transforms, TCPs, projection maps), correlations, weakest directions, what would
help, residuals, cross-validation and provenance. Everything that needs the calibration's linear model
comes from its solve (:mod:`jcalib.report.model`): the in-memory result's, or one restored from
``result.json`` with its observations and cell spec. With the result file alone the sections that need
the solve say so.

The page is self-contained (inline CSS, PNG figures embedded as base64 ``data:`` URIs, no script,
no external resource), so it can be mailed, archived next to ``result.json`` and opened offline.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from jcalib.io.atomic import write_text_atomic
from jcalib.report import budget, findings, kinematics, sections
from jcalib.report.error_model import error_model_section
from jcalib.report.goals import goals_html
from jcalib.report.markup import CSS, esc, note

__all__ = ["SECTIONS", "render_report", "write_report"]

#: The page's sections (``<h2>``), in order; every report has all of them.
SECTIONS = ("Warnings", "Summary", "Prediction from the robot's poses", "What limits this result",
            "Per-view reprojection error",
            "Task-space uncertainty", "Correlations", "Weakest directions", "What would help", "Residuals",
            "Cross-validation", "Provenance")


def _options(options, file):
    from jcalib.problems.options import CalibrationOptions
    from jcalib.report.model import options_of

    if options is None:
        return options_of(file)
    if isinstance(options, Mapping):
        return CalibrationOptions().replace(**options)
    return options


def _tool_references(cal) -> tuple[dict, dict]:
    """Tool transform -> a flange pose of its robot at the estimate, and -> the robot's name."""
    if cal is None or cal.graph is None:
        return {}, {}
    g = cal.graph
    reference, robot_of = {}, {}
    for tool, spec in g.cell.tools.items():
        r = g.holder(spec)
        poses = cal.flange_poses.get(r)
        if poses is not None and len(poses["estimated"]):
            reference[f"T_flange_{tool}"] = poses["estimated"][0]
            robot_of[f"T_flange_{tool}"] = r
    return reference, robot_of


def _cell_goal_rows(cal, cell, file) -> list:
    """Rows of the cell spec's goals against the result (the calibration's cell, else ``cell``); a goal the
    result cannot answer (its quantity not calibrated) is left out."""
    from jcalib.errors import BadInputError
    from jcalib.problems.goals import goal_rows

    spec = getattr(getattr(cal, "graph", None), "cell", None)
    if spec is None and cell is not None:
        from jcalib.io.cell import load_cell

        spec = load_cell(cell)
    rows = []
    for g in getattr(spec, "goals", ()) or ():
        try:
            rows += goal_rows([g], file)
        except BadInputError:
            continue
    return rows


def render_report(
    result: Any,
    observations: str | os.PathLike | Mapping | Any | None = None,
    title: str | None = None,
    cell: str | os.PathLike | Mapping | Any | None = None,
    tolerances: Mapping[str, float] | None = None,
    options: Any = None,
    cross_validation: bool | None = None,
    goals: Any = None,
) -> str:
    """The HTML text of the one-page report of a result.

    Args:
        result: a :class:`jcalib.Result` (its ``details`` hold the solve), a
            :class:`~jcalib.io.result.ResultFile`, or a path to ``result.json``.
        observations: the ``jcalib.observations/1`` data the result was computed from (path, dict or
            :class:`~jcalib.io.observations.Observations`), or None.
        title: page title (default: "jcalib calibration report").
        cell: the cell spec (path, dict or ``CellSpec``) the result was computed from. With
            ``observations`` and a result file, the calibration is restored (rebuilt by the one builder
            and re-solved from the file's values) so that every section has the solve's linear model.
        tolerances: overrides of :data:`jcalib.report.advice.DEFAULT_TOLERANCES`.
        options: the calibration options (``CalibrationOptions`` or a dict; default: the file's provenance).
        cross_validation: calibrate the two halves of the stations again and compare (two more solves);
            default: when ``cell`` and ``observations`` are given.
        goals: rows of :func:`jcalib.problems.goals.goal_rows` (a goal-driven plan's goals against this
            result): a "Goals" table in the summary. Default: the cell spec's ``goals:`` (no prediction),
            when the report has the cell. The goals are also the tolerances of the unknowns they name
            (:func:`jcalib.report.advice.goal_tolerances`; ``tolerances`` still overrides the defaults).

    Returns:
        The HTML document (UTF-8 text, self-contained).

    Raises:
        BadInputError: unreadable or invalid result, observations or cell, or ones that do not belong
            together.
    """
    from jcalib.report import advice, diagnostics
    from jcalib.report.model import calibration_of, linear_model, model_from_file, result_file

    source = str(result) if isinstance(result, (str, os.PathLike)) else None
    file = result_file(result)
    obs = None
    if observations is not None:
        from jcalib.io.observations import load_observations

        obs = load_observations(observations)
    opts = _options(options, file)
    cal = calibration_of(result, obs, cell, opts)
    if goals is None:
        goals = _cell_goal_rows(cal, cell, file)
    if goals:  # the goals are the tolerances of what they name
        tolerances = {**advice.goal_tolerances([r.goal for r in goals]), **(tolerances or {})}
    model = linear_model(cal, opts) if cal is not None else model_from_file(file)
    diags = diagnostics.residual_diagnostics(cal) if cal is not None else {}
    groups = diagnostics.group_statistics(cal) if cal is not None else []
    warnings = advice.analysis_warnings(file, model, diags, tolerances)
    cameras = cal.cameras if cal is not None else file.cameras
    covariances = {c: model.camera_covariance(c) for c in cameras} if model is not None else {}
    reference, robot_of = _tool_references(cal)
    if cross_validation is None:
        cross_validation = cell is not None and obs is not None

    title = title or "jcalib calibration report"
    parts = [
        f"<h1>{esc(title)}</h1>",
        note(f"{len(file.cameras)} camera(s), {len(file.transforms)} transform(s), {len(file.points)} point(s). "
             "Uncertainties (σ) are sampling noise of the observations propagated to the estimate, not model error."
             + ("" if cal is not None else " Sections that need the calibration's solve " + findings.MISSING_SOLVE
                + ".")),
        sections.warnings(warnings),
        "<h2>Summary</h2>", sections.statistics(file.stats), sections.intrinsics(file), sections.transforms(file),
        sections.points(file),
        sections.targets(file), sections.lenses(file), kinematics.section(file), goals_html(goals) if goals else "",
        sections.prediction(file.stats), error_model_section(file.stats), budget.section(file),
        "<h2>Per-view reprojection error</h2>", sections.view_rms(file.stats),
        "<h2>Task-space uncertainty</h2>", sections.INCLUDES, sections.task_space(file),
        sections.tcps(file, reference, robot_of), "<h3>Projection uncertainty</h3>",
        sections.projection_maps(file, {c: C for c, C in covariances.items() if C is not None}),
        "<h2>Correlations</h2>", findings.correlation_section(file, model),
        "<h2>Weakest directions</h2>", findings.weak_section(model, tolerances, cameras),
        "<h2>What would help</h2>", findings.help_section(model, tolerances),
        "<h2>Residuals</h2>", findings.residual_section(file, cal, diags, groups, obs),
        "<h2>Cross-validation</h2>", findings.cross_validation_section(cell, obs, opts, bool(cross_validation)),
        "<h2>Provenance</h2>", sections.provenance(file, source),
    ]
    if not warnings:  # the warnings box has its heading only when there is something to say
        parts.insert(2, "<h2>Warnings</h2>")
    body = "\n".join(parts)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{esc(title)}</title><style>{CSS}</style></head>"
            f"<body><main>\n{body}\n</main></body></html>\n")


def write_report(
    result: Any,
    out: str | os.PathLike,
    observations: str | os.PathLike | Mapping | Any | None = None,
    title: str | None = None,
    cell: str | os.PathLike | Mapping | Any | None = None,
    tolerances: Mapping[str, float] | None = None,
    options: Any = None,
    cross_validation: bool | None = None,
    goals: Any = None,
) -> Path:
    """Write :func:`render_report` to ``out`` atomically; returns the path.

    Raises:
        BadInputError: unreadable or invalid result, observations or cell.
    """
    return write_text_atomic(out, render_report(result, observations, title, cell, tolerances, options,
                                                cross_validation, goals))
