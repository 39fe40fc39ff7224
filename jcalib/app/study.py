"""The body of ``jcalib study SCENARIO --trials N [--scheduler ADDR] -o TABLE``.

Registered in :mod:`jcalib.app.cli` with ``app.command("study")(study_command)`` (typer reads the
annotations below).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def study_command(
    scenario: Annotated[Path, typer.Argument(help="Study scenario (jcalib.study/1 YAML or JSON): a cell spec, its "
                                                  "truth, noise, station strategies and estimators.")],
    trials: Annotated[int, typer.Option("--trials", "-n", help="Number of simulated trials.")] = 100,
    scheduler: Annotated[
        str | None,
        typer.Option("--scheduler", help="Dask scheduler address tcp://HOST:PORT (default: run here)."),
    ] = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Table to write (.csv, or .parquet with pyarrow).")] = Path(
        "study.csv"
    ),
    seed: Annotated[int, typer.Option(help="Study seed: trial i uses SeedSequence(seed).spawn(...)[i].")] = 0,
    batch_size: Annotated[int, typer.Option("--batch-size", help="Trials per batch (one vmapped solve per "
                                                                 "estimator; one Dask task).")] = 8,
) -> None:
    """Run a strategy study (every estimator on every simulated trial) and write its table."""
    from jcalib.io.outputs import check_outputs

    check_outputs({"-o": out}, [scenario])
    from jcalib.solve.cache import enable_compilation_cache
    from jcalib.study.run import run_study
    from jcalib.study.scenario import load_scenario

    sc = load_scenario(scenario)  # bad input fails here, before anything heavy
    enable_compilation_cache()
    backend = "dask" if scheduler else "local"
    table = run_study(sc, trials, seed, backend=backend, scheduler=scheduler, batch_size=batch_size, out=out)
    typer.echo(f"wrote {out} ({len(table)} rows)")
