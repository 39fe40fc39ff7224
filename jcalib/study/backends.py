"""Where the batches of a study run: this process (``local``) or a ``dask.distributed`` cluster.

Both run the same function on the same batches (:func:`batches`: contiguous runs of
``batch_size`` trial indices), so the table does not depend on the backend. Progress bars (rich)
count finished trials.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

from jcalib.errors import BadInputError

__all__ = ["batches", "run_dask", "run_local"]


def batches(trials: int, batch_size: int) -> list[list[int]]:
    """Trial indices ``0 .. trials-1`` in contiguous batches of ``batch_size`` (the last may be shorter)."""
    return [list(range(s, min(s + batch_size, trials))) for s in range(0, trials, batch_size)]


@contextlib.contextmanager
def _progress(total: int, label: str, enabled: bool) -> Iterator[Callable[[int], None]]:
    if not enabled:
        yield lambda n: None
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  TimeRemainingColumn(), transient=False) as progress:
        task = progress.add_task(label, total=total)
        yield lambda n: progress.advance(task, n)


def run_local(fn: Callable[[list[int]], list[dict]], parts: list[list[int]], progress: bool = True) -> list[list[dict]]:
    """Run ``fn`` on every batch in this process, in order."""
    out = []
    with _progress(sum(len(p) for p in parts), "study (local)", progress) as advance:
        for part in parts:
            out.append(fn(part))
            advance(len(part))
    return out


def _dask_client(scheduler: str | None, n_workers: int):
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise BadInputError(
            "backend: got 'dask', but dask.distributed is not installed; pip install 'jcalib[distributed]'"
        ) from None
    if scheduler:
        return Client(scheduler), None
    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, host="127.0.0.1", dashboard_address=None,
                           processes=True)
    return Client(cluster), cluster


def run_dask(
    fn: Callable[[list[int]], list[dict]],
    parts: list[list[int]],
    *,
    scheduler: str | None = None,
    n_workers: int = 2,
    client=None,
    progress: bool = True,
) -> list[list[dict]]:
    """Run ``fn`` on every batch as one Dask task each; results in batch order.

    Args:
        fn: a picklable function of a list of trial indices (e.g. a ``functools.partial`` of a
            module-level function).
        parts: the batches.
        scheduler: ``tcp://HOST:PORT`` of a running scheduler; ``None`` starts a
            ``LocalCluster(n_workers, threads_per_worker=1, host="127.0.0.1")`` for the study.
        n_workers: workers of that local cluster.
        client: an existing ``dask.distributed.Client`` to use instead (not closed here).
        progress: show a progress bar.
    """
    from dask.distributed import as_completed

    own = client is None
    cluster = None
    if own:
        client, cluster = _dask_client(scheduler, n_workers)
    try:
        futures = [client.submit(fn, part, key=f"jcalib-study-batch-{k}-{part[0]}", pure=False)
                   for k, part in enumerate(parts)]
        index = {f.key: k for k, f in enumerate(futures)}
        out: list = [None] * len(parts)
        with _progress(sum(len(p) for p in parts), "study (dask)", progress) as advance:
            for fut in as_completed(futures):
                k = index[fut.key]
                out[k] = fut.result()
                advance(len(parts[k]))
        return out
    finally:
        if own:
            client.close()
            if cluster is not None:
                cluster.close()
