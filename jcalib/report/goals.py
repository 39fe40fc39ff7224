"""The goals tables: the console table of ``jcalib report --plan`` and the report's "Goals" subsection,
drawn from the rows of :func:`jcalib.problems.goals.goal_rows`."""

from __future__ import annotations

from jcalib.problems.goals import GoalRow

__all__ = ["goals_html", "goals_table"]


def _num(x: float | None) -> str:
    return "–" if x is None else f"{x:.3g}"


def goals_table(rows: list[GoalRow]):
    """The rich console table of :func:`~jcalib.problems.goals.goal_rows`."""
    from rich.table import Table

    table = Table(title="Goals (worst-direction σ)")
    for col in ("goal", "limit", "predicted σ", "achieved σ", "unit", "met"):
        table.add_column(col, justify="right" if col in ("limit", "predicted σ", "achieved σ") else "left",
                         overflow="fold" if col == "goal" else "ellipsis")  # wraps after the colon, else folds
    for r in rows:
        table.add_row(r.goal.text.replace(":", ": ", 1), f"{r.goal.limit:g}", _num(r.predicted), _num(r.achieved), r.goal.unit,
                      "[green]yes[/]" if r.met else "[bold red]no[/]")
    return table


def goals_html(rows: list[GoalRow]) -> str:
    """The report's "Goals" subsection (HTML) of :func:`~jcalib.problems.goals.goal_rows`."""
    from jcalib.report.markup import esc, note, table

    body = [[esc(r.goal.text), esc(f"{r.goal.limit:g}"), esc(_num(r.predicted)), esc(_num(r.achieved)),
             esc(r.goal.unit), "yes" if r.met else "<b>no</b>"] for r in rows]
    met = sum(r.met for r in rows)
    return ("<h3>Goals</h3>" + note(
        f"{met} of {len(rows)} goal(s) met. σ is the worst-direction standard deviation (largest over directions "
        "and, for a projection, over the image); predicted: what the plan expected at the stated noise and the "
        "nominal cell; achieved: from this result's covariance.")
        + table(["goal", "limit", "predicted σ", "achieved σ", "unit", "met"], body, num_cols={1, 2, 3}))
