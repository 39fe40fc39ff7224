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
    from jcalib.io.outputs import check_outputs

    check_outputs({"-o": out}, [scenario, *_scenario_files(scenario)])
    from jcalib.solve.cache import enable_compilation_cache
    from jcalib.study.run import run_study
    from jcalib.study.scenario import load_scenario

    loaded = load_scenario(scenario)  # every key checked before the first trial
    enable_compilation_cache()

    backend = "dask" if scheduler else "local"
    table = run_study(loaded, trials, seed, backend=backend, scheduler=scheduler, out=out)
    n = len(table)
    typer.echo(f"wrote {out} ({n} rows)")


def _scenario_files(scenario: Path) -> list[Path]:
    """Read the scenario file (and the station file it names) within jcalib's input limits: size,
    UTF-8, JSON / YAML depth and aliases; returns the station file, if any."""
    from jcalib.errors import BadInputError
    from jcalib.io.schema.reading import read_document

    data = read_document(scenario, "scenario")
    if not isinstance(data, dict):
        raise BadInputError(f"{scenario}: a scenario is a mapping with 'schema: jcalib.study/1', got "
                            f"{type(data).__name__}")
    stations = data.get("stations")
    path = stations.get("path") if isinstance(stations, dict) and stations.get("strategy") == "file" else None
    if not isinstance(path, str) or "T_target_cam" in stations:
        return []
    p = Path(path)
    if not p.is_absolute():
        p = Path(scenario).resolve().parent / p
    read_document(p, "scenario stations file")
    return [p]
