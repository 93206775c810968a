"""Scan-level parallelism inside one batch job: the night's scans spread over worker processes.

A night is one Snakemake job per stage (per-job overhead would otherwise dominate), so the job
itself spreads its scans over the cores Snakemake gave it (``threads:``). Results come back in
input order, so outputs do not depend on the number of workers. A job whose script calls
:func:`start_job_workers` first spawns its workers while it imports, and computes on its own
process too.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, wait
from functools import partial
from typing import Any, TypeVar

__all__ = [
    "map_in_order",
    "map_timed",
    "workers_for",
    "MIN_ITEMS_PER_WORKER",
    "JOB_MALLOC_ENVIRONMENT",
    "set_job_environment",
    "start_job_workers",
    "stop_job_workers",
]

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
    """Put the job malloc settings into ``environ``; return the values in effect.

    Put :data:`JOB_MALLOC_ENVIRONMENT` into ``environ`` (this process's environment, which the
    jobs it starts inherit), keeping any value already set; returns the values in effect.
    """
    for k, v in JOB_MALLOC_ENVIRONMENT.items():
        environ.setdefault(k, v)
    return {k: environ[k] for k in JOB_MALLOC_ENVIRONMENT}


def workers_for(n_items: int, workers: int) -> int:
    """Return the processes :func:`map_in_order` uses.

    Return the processes :func:`map_in_order` uses for ``n_items`` items with ``workers`` allowed (in a job
    whose workers :func:`start_job_workers` started, one item is enough for a worker).
    """
    per_worker = 1 if _JOB_POOL else MIN_ITEMS_PER_WORKER
    return max(1, min(int(workers), n_items // per_worker))


def map_timed(fn: Callable[[Any], T], items: Iterable[Any], workers: int = 1) -> Iterator[tuple[T, float]]:
    """Return :func:`map_in_order`'s results with each item's compute time.

    ``(fn(item), CPU seconds)`` of the process that computed it (a job's log line, never a result: see
    ``workflow_log.compute_line``).
    """
    yield from map_in_order(partial(_timed_call, fn), items, workers)


def _timed_call(fn: Callable[[Any], T], item: Any) -> tuple[T, float]:
    t0 = time.process_time()
    out = fn(item)
    return out, time.process_time() - t0


def map_in_order(fn: Callable[[Any], T], items: Iterable[Any], workers: int = 1) -> Iterator[T]:
    """``fn(item)`` for every item, in order, on up to ``workers`` processes.

    ``fn`` must be a module-level function and items picklable. Workers are spawned, not forked
    (polars and BLAS keep thread pools that a fork would copy in an unknown state); a spawned
    worker imports the parent's main script as ``__mp_main__``, so scripts that call this keep
    their work under ``if __name__ == "__main__":``.

    In a job that called :func:`start_job_workers` the calling process is one of the workers (it
    runs with one BLAS and polars thread, as they do, so an item's result does not depend on the
    process that computed it) and the others were spawned when the job started; otherwise
    ``workers`` processes are spawned now and the calling process waits for them.
    """
    items = list(items)
    workers = workers_for(len(items), workers)
    if workers <= 1:
        for it in items:
            yield fn(it)
        return
    if _JOB_POOL and _JOB_POOL["workers"] >= workers:
        yield from _map_with_caller(fn, items, _JOB_POOL["pool"])
        return
    saved = {k: os.environ.get(k) for k in _ONE_THREAD}
    os.environ.update(_ONE_THREAD)  # each worker one BLAS thread: the workers already fill the cores
    try:
        with _spawn_pool(workers) as pool:
            results = pool.map(fn, items, chunksize=1)  # submits every item (spawns the workers) now
            _restore(saved)
            yield from results
    finally:
        _restore(saved)


def _map_with_caller(fn, items: list, pool: ProcessPoolExecutor) -> Iterator:
    """Map in order on spawned workers and the calling process, sharing one queue.

    :func:`map_in_order` on the workers of ``pool`` and the calling process: every item
    is submitted at once, the workers take them in order, and the caller takes the first item no
    worker has started (its pending future cancelled) whenever it is free; results are yielded in
    input order as soon as they are complete from the first item on. Neither side waits for the
    other while an item is left: a scan of seconds on one side no longer leaves the other idle
    (a queue of a few items ahead did on a night of scans from 0.01 to 3 s: the discrepancy job's
    worker computed 16.5 CPU s to its caller's 23.7). At the end a worker holds at most one item
    queued beyond the one it computes (the pool's call queue).
    """
    futures = [pool.submit(fn, it) for it in items]
    mine: dict[int, Any] = {}
    take = first = 0
    try:
        while first < len(items):
            while take < len(items) and not futures[take].cancel():  # started (or done) by a worker
                take += 1
            if take < len(items):
                mine[take] = fn(items[take])
                take += 1
            else:
                wait([futures[first]])
            while first < len(items) and (first in mine or futures[first].done()):
                yield mine.pop(first) if first in mine else futures[first].result()
                first += 1
    finally:
        for fut in futures:
            fut.cancel()


def start_job_workers(namespace: dict) -> int:
    """Start a workflow job's worker processes at the top of its script, before numpy loads.

    ``namespace`` is the script's ``globals()``. In the script's own process (``__main__``: a
    Snakemake job, or a person running the script by hand) every process that will compute the
    stage's items gets one BLAS and one polars thread, so a scan's result does not depend on the
    process that took it, the job's ``threads`` or the machine's cores (OpenBLAS on two threads
    sums a dot product in another order). When Snakemake runs the script as a job of ``threads``
    >= 2 (its ``snakemake`` object is in ``namespace``), ``threads - 1`` workers are spawned now,
    so that their imports (about 0.7 s each) overlap this process's own, and this process becomes
    the last worker of :func:`map_in_order`. Nothing is done in a worker (which imports the script
    as ``__mp_main__``) or once numpy is loaded (its BLAS threads are fixed then). Returns the
    number of processes that will compute items, this one included.
    """
    if namespace.get("__name__") != "__main__" or _JOB_POOL or "numpy" in sys.modules:
        return 1
    os.environ.update(_ONE_THREAD)  # this process and its workers alike (read when numpy and polars load)
    smk = namespace.get("snakemake")
    workers = int(getattr(smk, "threads", 1) or 1) if smk is not None else 1
    if workers < 2:
        return 1
    pool = _spawn_pool(workers - 1)
    for _ in range(workers - 1):
        pool.submit(int)  # spawns a worker now: it imports the job's script while this process does
    _JOB_POOL.update(pool=pool, workers=workers)
    return workers


def stop_job_workers() -> int:
    """Shut down the workers :func:`start_job_workers` spawned and wait until they have exited.

    Once they have exited (and been waited for) their CPU time counts in this process's
    ``resource.getrusage(RUSAGE_CHILDREN)`` (``workflow_log.job_cpu``). Returns the number of
    workers stopped (0 where there were none); :func:`map_in_order` spawns its own afterwards.
    """
    pool = _JOB_POOL.get("pool")
    n = int(_JOB_POOL.get("workers", 1)) - 1 if pool is not None else 0
    _JOB_POOL.clear()
    if pool is not None:
        pool.shutdown(wait=True)
    return n


#: the job's pool from :func:`start_job_workers`: {"pool": ProcessPoolExecutor, "workers": int}
_JOB_POOL: dict[str, Any] = {}


def _spawn_pool(n: int) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context("spawn"))


_ONE_THREAD = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "POLARS_MAX_THREADS": "1",
}


def _restore(saved: dict[str, str | None]) -> None:
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
