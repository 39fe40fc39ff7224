"""The body of ``jcalib study SCENARIO --trials N [--scheduler ADDR] -o TABLE``.

Register it in :mod:`jcalib.app.cli` with ``app.command("study")(study_command)`` (typer reads the
annotations below).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def study_command(
    scenario: Annotated[Path, typer.Argument(help="Study scenario (jcalib.study/1 YAML or JSON).")],
    trials: Annotated[int, typer.Option("--trials", "-n", help="Number of simulated trials.")] = 100,
    scheduler: Annotated[
        str | None,
        typer.Option("--scheduler", help="Dask scheduler address tcp://HOST:PORT (default: run here)."),
    ] = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Table to write (.csv, or .parquet with pyarrow).")] = Path(
        "study.csv"
    ),
    seed: Annotated[int, typer.Option(help="Study seed: trial i uses SeedSequence(seed).spawn(...)[i].")] = 0,
) -> None:
    """Run a strategy study (every estimator on every simulated trial) and write its table."""
    from jcalib.solve.cache import enable_compilation_cache
    from jcalib.study.run import run_study

    enable_compilation_cache()

    backend = "dask" if scheduler else "local"
    table = run_study(scenario, trials, seed, backend=backend, scheduler=scheduler, out=out)
    n = len(table)
    typer.echo(f"wrote {out} ({n} rows)")
