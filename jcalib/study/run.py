"""``run_study``: simulate many trials of a scenario, run its estimators, return a tidy table."""

from __future__ import annotations

import csv
import functools
import math
import os
from pathlib import Path

from jcalib.errors import BadInputError
from jcalib.solve.cache import enable_compilation_cache
from jcalib.study.backends import batches, run_dask, run_local
from jcalib.study.estimators import run_estimator
from jcalib.study.metrics import columns, error_row, row
from jcalib.study.scenario import Scenario, load_scenario
from jcalib.study.simulate import simulate_trial

__all__ = ["DEFAULT_BATCH_SIZE", "run_study", "run_trials", "write_table"]

#: Trials per batch (one Dask task, one vmapped solve per builder estimator).
DEFAULT_BATCH_SIZE = 8


def run_trials(scenario: Scenario, seed: int, trials: list[int]) -> list[dict]:
    """Simulate and estimate the given trials (one batch); rows ordered by trial, then estimator.

    Each builder estimator solves the batch's trials with one :func:`jcalib.calibrate_batch` call; the
    closed forms loop over the trials. A trial the scenario cannot simulate gives one failed row per
    estimator.
    """
    cols = columns(scenario)
    trials = [int(k) for k in trials]
    data, failed = {}, {}
    for k in trials:
        try:
            data[k] = simulate_trial(scenario, seed, k)
        except Exception as err:  # noqa: BLE001  (a failed trial is a row, not a crash)
            failed[k] = err
    live = [k for k in trials if k in data]
    results = {e.name: dict(zip(live, run_estimator(scenario, e, [data[k] for k in live])))
               for e in scenario.estimators}
    rows = []
    for k in trials:
        for e in scenario.estimators:
            if k in failed:
                rows.append(error_row(cols, k, e.name, failed[k]))
                continue
            res = results[e.name][k]
            if isinstance(res, Exception):
                rows.append(error_row(cols, k, e.name, res, len(data[k].kept)))
            else:
                rows.append(row(scenario, cols, k, e.name, res, data[k].truth))
    return rows


def _run_batch(scenario_data: dict, seed: int, trials: list[int]) -> list[dict]:
    """One batch, from plain data (what a Dask worker receives). Module level, so it pickles."""
    import jcalib  # noqa: F401  (float64 in a fresh worker process)

    return run_trials(load_scenario(scenario_data), seed, trials)


def _run_batch_worker(scenario_data: dict, seed: int, trials: list[int]) -> list[dict]:
    """:func:`_run_batch` in a Dask worker, with the persistent compilation cache on."""
    enable_compilation_cache()
    return _run_batch(scenario_data, seed, trials)


def _check_int(value, name: str, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < lo:
        raise BadInputError(f"{name}: got {value!r}, expected an integer >= {lo}")
    return value


def _as_table(rows: list[dict], cols: list[str]):
    try:
        import pandas as pd
    except ImportError:
        return rows
    return pd.DataFrame(rows, columns=cols)


def write_table(rows: list[dict], cols: list[str], path: str | os.PathLike) -> Path:
    """Write the rows as CSV (``.csv``, numbers in full precision: ``repr`` of the float) or Parquet
    (``.parquet``, needs pyarrow). Returns the path."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    if p.suffix.lower() == ".parquet":
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError:
            raise BadInputError(f"out: got {str(p)!r}, but Parquet needs pyarrow (pip install pyarrow); "
                                "or write .csv") from None
        pq.write_table(pa.table({c: [r[c] for r in rows] for c in cols}), p)
        return p
    tmp = p.with_name(p.name + ".tmp")
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in rows:
            w.writerow(["" if isinstance(r[c], float) and math.isnan(r[c]) else
                        repr(r[c]) if isinstance(r[c], float) else r[c] for c in cols])
    os.replace(tmp, p)
    return p


def run_study(
    scenario: str | os.PathLike | dict | Scenario,
    trials: int,
    seed: int = 0,
    backend: str = "local",
    scheduler: str | None = None,
    batch_size: int = DEFAULT_BATCH_SIZE,
    *,
    out: str | os.PathLike | None = None,
    n_workers: int = 2,
    client=None,
    progress: bool = True,
):
    """Run a strategy study: ``trials`` simulated trials of ``scenario``, every estimator on each.

    Trial ``i`` draws all its randomness from ``SeedSequence(seed).spawn(trials)[i]``
    (:func:`jcalib.study.simulate.trial_rng`), and trials are grouped into the same contiguous
    batches on every backend, so the same ``(scenario, trials, seed, batch_size)`` gives the same
    table (every column but ``runtime_s``) on the local backend and on any Dask cluster.

    Args:
        scenario: a scenario (dict, :class:`Scenario` or YAML/JSON path), see :mod:`jcalib.study.scenario`.
        trials: number of trials, >= 1.
        seed: the study's seed.
        backend: ``"local"`` (this process; one vmapped solve per builder estimator and batch) or ``"dask"``
            (one task per batch on a ``dask.distributed`` cluster).
        scheduler: Dask scheduler address (``tcp://HOST:PORT``); ``None`` starts a loopback
            ``LocalCluster`` of ``n_workers`` single-threaded workers. Setting it implies ``"dask"``.
        batch_size: trials per batch / task.
        out: write the table there too (``.csv``, or ``.parquet`` with pyarrow).
        n_workers: workers of the local Dask cluster.
        client: an existing ``dask.distributed.Client`` (backend ``"dask"``), left open.
        progress: show a rich progress bar.

    Returns:
        The tidy table, one row per trial × estimator (columns: :func:`jcalib.study.metrics.columns`):
        a ``pandas.DataFrame`` when pandas is installed, else a list of dicts (column -> value).

    Raises:
        BadInputError: invalid scenario (naming the key), arguments or backend.
    """
    sc = load_scenario(scenario)
    trials = _check_int(trials, "trials", 1)
    seed = _check_int(seed, "seed", 0)
    batch_size = _check_int(batch_size, "batch_size", 1)
    if scheduler is not None and backend == "local":
        backend = "dask"
    if backend not in ("local", "dask"):
        raise BadInputError(f"backend: got {backend!r}, expected 'local' or 'dask'")
    parts = batches(trials, batch_size)
    data = sc.to_dict()
    if backend == "local":
        results = run_local(functools.partial(_run_batch, data, seed), parts, progress=progress)
    else:
        fn = functools.partial(_run_batch_worker, data, seed)
        results = run_dask(fn, parts, scheduler=scheduler, n_workers=n_workers, client=client, progress=progress)
    rows = [r for part in results for r in part]
    cols = columns(sc)
    if out is not None:
        write_table(rows, cols, out)
    return _as_table(rows, cols)
