"""``jcalib plan`` (and the app's Plan button): plan stations for a cell, check the options per kind, describe a plan."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jcalib.errors import BadInputError

__all__ = ["PLAN_OPTIONS", "check_plan_options", "check_sigma_px", "kinematic_plan_lines", "optimal_plan_lines",
           "run_plan"]


def run_plan(
    cell: str | Path,
    kind: str,
    out: str | Path,
    *,
    robot: str | None = None,
    num_stations: int | None = None,
    camera: str | None = None,
    target: str | None = None,
    tool: str | None = None,
    amplitude_deg: float | None = None,
    image_size: tuple[int, int] | None = None,
    num_candidates: int | None = None,
    seed: int = 0,
    sigma_px: float | None = None,
    goals: list[str] | None = None,
    max_stations: int | None = None,
):
    """``jcalib plan``: plan stations for the cell (:func:`jcalib.planning.stations.plan_cell`,
    :func:`~jcalib.planning.stations.plan_kinematics` for ``kinematics``, or
    :func:`jcalib.planning.optimal.plan_optimal` for ``optimal``), write them.

    Returns:
        The :class:`~jcalib.planning.stations.PlannedStations` written to ``out`` (``jcalib.plan/1``
        JSON with an extra ``planner`` key: kind, robot, camera / target / tool, dropped candidates;
        ``kinematics``: also the prediction and the joint spans).
    """
    from jcalib.planning.layout import cell_layout
    from jcalib.planning.stations import plan_cell, plan_kinematics
    from jcalib.io.atomic import write_json_atomic

    if kind == "kinematics":  # the layout is built only where a camera view is planned (not for external axes)
        planned = plan_kinematics(cell, robot=robot, image_size=image_size, num_stations=num_stations, camera=camera,
                                  target=target, amplitude_deg=amplitude_deg, num_candidates=num_candidates,
                                  seed=seed, sigma_px=sigma_px)  # fmt: skip
        write_json_atomic(out, planned.to_json())
        return planned
    layout = cell_layout(cell, robot=robot, image_size=image_size)
    if kind == "optimal":
        from jcalib.io.goals import parse_goals
        from jcalib.planning.optimal import DEFAULT_CANDIDATES, DEFAULT_MAX_STATIONS, plan_optimal
        from jcalib.problems.options import CalibrationOptions

        wanted = parse_goals(goals) if goals else layout.cell.goals
        options = CalibrationOptions() if sigma_px is None else CalibrationOptions(sigma_px=check_sigma_px(sigma_px))
        planned = plan_optimal(layout, wanted, DEFAULT_MAX_STATIONS if max_stations is None else max_stations,
                               options=options, seed=seed, amplitude_deg=amplitude_deg,
                               num_candidates=DEFAULT_CANDIDATES if num_candidates is None else num_candidates)
        write_json_atomic(out, planned.to_json(layout))
        return planned
    planned = plan_cell(layout, kind, num_stations=num_stations, camera=camera, target=target, tool=tool,
                        amplitude_deg=amplitude_deg)  # fmt: skip
    write_json_atomic(out, planned.to_json(layout))
    return planned


#: ``jcalib plan`` options and the kinds that use them (any other kind refuses them).
PLAN_OPTIONS = {
    "--stations": ("viewsets", "handeye", "tcp", "kinematics"),
    "--goal": ("optimal",),
    "--max-stations": ("optimal",),
    "--tool": ("tcp",),
    "--camera": ("viewsets", "handeye", "kinematics"),
    "--target": ("viewsets", "handeye", "kinematics"),
    "--candidates": ("kinematics", "optimal"),
    "--sigma-px": ("kinematics", "optimal"),
}


def check_plan_options(kind: str, **given) -> None:
    """Refuse a ``jcalib plan`` option that ``kind`` does not use (naming it and the kinds that do)."""
    from jcalib.planning.stations import KINDS

    if kind not in KINDS + ("optimal",):
        raise BadInputError(f"--kind: expected one of {', '.join(KINDS + ('optimal',))}, got {kind!r}")
    for name, value in given.items():
        opt = "--" + name.replace("_", "-")
        if value is not None and value != [] and kind not in PLAN_OPTIONS[opt]:
            hint = " (optimal plans take --max-stations)" if opt == "--stations" else ""
            raise BadInputError(f"{opt}: not used by --kind {kind}; it applies to --kind "
                                f"{' / '.join(PLAN_OPTIONS[opt])}{hint}")


def check_sigma_px(sigma_px: float) -> float:
    if not (np.isfinite(sigma_px) and 0.0 < sigma_px <= 10.0):
        raise BadInputError(f"--sigma-px: expected a corner noise in (0, 10] px, got {sigma_px}")
    return float(sigma_px)


def optimal_plan_lines(planned) -> list[str]:
    """The predicted σ of each goal after each planned station (the greedy order), then the verdict."""
    d = planned.details
    goals = d["goals"]
    lines = ["predicted σ after each station (greedy order; goal in brackets):"]
    limits = {g: float(g.rsplit("<=", 1)[1]) for g in goals}
    for k, row in enumerate(d["after_each_station"], 1):
        parts = [f"{g.split('<=')[0]} {row[g]:.4g} [{limits[g]:g}]" for g in goals]
        lines.append(f"  {k:3d}: " + ", ".join(parts))
    final = ", ".join(f"{g.split('<=')[0]} {d['predicted'][g]:.4g}" for g in goals)
    lines.append(f"after exchanges and refinement ({d['refined']} stations refined): {final}")
    if d["met"]:
        lines.append(f"every goal is met (predicted) with {len(planned.plan)} stations")
    else:
        lines.append(f"WARNING: the goals are not met (predicted) with {len(planned.plan)} stations: raise "
                     "--max-stations, relax the goals, or lower the noise (better detection, a larger target)")
    return lines


def kinematic_plan_lines(planned) -> list[str]:
    """Console lines of a ``kinematics`` plan: each joint's span, the predicted worst σ per parameter
    group and what the prediction assumes."""
    d = planned.details
    pred = d["prediction"]
    spans = ", ".join(f"{j} {v['value']:.0f} {v['unit']}" for j, v in d["joint_span"].items())
    lines = [f"joints move over: {spans}",
             f"{len(d['free_parameters'])} parameters estimated, from {d['usable']} usable of {d['candidates']} "
             f"candidates; condition {pred['condition']:.3g}"]
    if d["held_parameters"]:
        lines.append(f"held at nominal (not separable): {', '.join(d['held_parameters'])}")
    for group, w in pred["worst"].items():
        lines.append(f"predicted worst σ {group}: {w['value']:.3g} ({w['name']})")
    lines.append(f"assuming {pred['assumes']}")
    return lines
