"""Scan-level parallelism inside one batch job: the night's scans spread over worker processes.

A night is one Snakemake job per stage (per-job overhead would otherwise dominate), so the job
itself spreads its scans over the cores Snakemake gave it (``threads:``). Results come back in
input order, so outputs do not depend on the number of workers.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import Any, TypeVar

__all__ = ["map_in_order", "workers_for", "MIN_ITEMS_PER_WORKER", "JOB_MALLOC_ENVIRONMENT", "set_job_environment"]

T = TypeVar("T")

#: fewer items than this per worker run in the job's own process: a spawned worker costs
#: about a second of imports (numpy, scipy, polars), more than a handful of scans take
MIN_ITEMS_PER_WORKER = 4


#: glibc malloc settings for every job of the workflow and its worker processes (set by
#: rules/common.smk before any job starts; glibc reads them when a process starts, other C
#: libraries ignore them). By default glibc hands memory at the top of its heap back to the
#: system as soon as 128 KB-32 MB of it are free, and a scan's numpy temporaries are that size:
#: each new array was then faulted in again page by page. With arrays below 32 MB served from
#: the heap and up to 256 MB kept there, the measurement of the reference night (one process,
#: 116 scans) took 25.9-26.2 s instead of 32.1-32.8 s (sys time 6.2-6.7 -> 0.4-0.5 s, page
#: faults 2.9 M -> 66 000; peak memory 366 -> 378 MB). A variable the user has set is kept.
JOB_MALLOC_ENVIRONMENT = {"MALLOC_MMAP_THRESHOLD_": str(32 << 20), "MALLOC_TRIM_THRESHOLD_": str(256 << 20)}


def set_job_environment(environ=os.environ) -> dict[str, str]:
    """Put :data:`JOB_MALLOC_ENVIRONMENT` into ``environ`` (this process's environment, which the
    jobs it starts inherit), keeping any value already set; returns the values in effect."""
    for k, v in JOB_MALLOC_ENVIRONMENT.items():
        environ.setdefault(k, v)
    return {k: environ[k] for k in JOB_MALLOC_ENVIRONMENT}


def workers_for(n_items: int, workers: int) -> int:
    """Processes :func:`map_in_order` uses for ``n_items`` items with ``workers`` allowed."""
    return max(1, min(int(workers), n_items // MIN_ITEMS_PER_WORKER))


def map_in_order(fn: Callable[[Any], T], items: Iterable[Any], workers: int = 1) -> Iterator[T]:
    """``fn(item)`` for every item, in order, on up to ``workers`` processes.

    ``fn`` must be a module-level function and items picklable. Workers are spawned, not forked
    (polars and BLAS keep thread pools that a fork would copy in an unknown state); a spawned
    worker imports the parent's main script as ``__mp_main__``, so scripts that call this keep
    their work under ``if __name__ == "__main__":``.
    """
    items = list(items)
    workers = workers_for(len(items), workers)
    if workers <= 1:
        for it in items:
            yield fn(it)
        return
    ctx = multiprocessing.get_context("spawn")
    saved = {k: os.environ.get(k) for k in _ONE_THREAD}
    os.environ.update(_ONE_THREAD)  # each worker one BLAS thread: the workers already fill the cores
    try:
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            results = pool.map(fn, items, chunksize=1)  # submits every item (spawns the workers) now
            _restore(saved)
            yield from results
    finally:
        _restore(saved)


_ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "POLARS_MAX_THREADS": "1"}


def _restore(saved: dict[str, str | None]) -> None:
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
