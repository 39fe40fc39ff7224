"""The body of ``jcalib sensitivity RESULT --wrt board.square``: the derivative of every unknown with respect
to a stated input, read from the result's ``sensitivities`` (no re-solve).

Registered in :mod:`jcalib.app.cli` with ``app.command("sensitivity")(sensitivity_command)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def _scale(unit: str) -> tuple[float, str]:
    return {"rad": (57.29577951308232, "deg"), "m": (1e3, "mm")}.get(unit, (1.0, unit))


def sensitivity_command(
    result: Annotated[Path, typer.Argument(help="A result (jcalib.result/1 JSON) computed with its error budget.")],
    wrt: Annotated[str, typer.Option("--wrt", help="The stated input, as the result's stats.assumptions name it "
                                                   "(e.g. board.square, cam1.intrinsics, T_base_cam1.pose).")],
    of: Annotated[str | None, typer.Option("--of", help="Only this unknown (e.g. T_flange_cam0).")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """Print the derivative of every unknown with respect to a stated input (first order, at the estimate).

    Columns are the input's coordinates (a target's scale: relative; held intrinsics: per px or unit;
    a held transform: rx..tz in rad and m); rows are the unknowns' coordinates in display units (mm, deg, px).
    Multiply by a change of the input to see what it does without re-solving.
    """
    import json

    from rich.console import Console
    from rich.table import Table

    from jcalib.io.result import load_result
    from jcalib.report.budget import sensitivity_rows

    file = load_result(result)
    rows = sensitivity_rows(file, wrt, of)
    sens = dict(file.extra)["sensitivities"][wrt]
    columns = [f"d/d {c}" + (f" [{u}]" if u else "") for c, u in zip(sens["columns"], sens["units"])]
    if json_out:
        print(json.dumps({"wrt": wrt, "columns": sens["columns"], "column_units": sens["units"],
                          "rows": [{"unknown": n, "coord": c, "unit": u, "derivative": d} for n, c, u, d in rows]}))
        return
    table = Table(title=f"Sensitivity to {wrt} ({sens['what']})")
    for col in ["unknown", "coordinate", "unit", *columns]:
        table.add_column(col, justify="right" if col.startswith("d/d") else "left")
    for name, coord, unit, d in rows:
        k, shown = _scale(unit)
        table.add_row(name, coord, shown, *[f"{v * k:.4g}" for v in d])
    Console().print(table)
