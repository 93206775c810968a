"""Scan-level parallelism: results in input order, the same as one process, on several processes."""

import os

from borescan.parallel import MIN_ITEMS_PER_WORKER, map_in_order


def _square_and_pid(x: int) -> tuple[int, int]:
    return x * x, os.getpid()


def test_map_in_order_spreads_over_workers_and_keeps_order():
    items = list(range(2 * MIN_ITEMS_PER_WORKER + 3))
    env_before = {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "POLARS_MAX_THREADS")}
    out = list(map_in_order(_square_and_pid, items, workers=2))
    assert [v for v, _ in out] == [x * x for x in items]
    pids = {p for _, p in out}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2
    # the one-thread setting is for the workers only; the calling process gets its own back
    assert {k: os.environ.get(k) for k in env_before} == env_before


def test_few_items_run_in_the_calling_process():
    out = list(map_in_order(_square_and_pid, range(MIN_ITEMS_PER_WORKER + 1), workers=2))
    assert {p for _, p in out} == {os.getpid()}


def test_job_environment_sets_the_malloc_settings_and_keeps_the_users():
    """set_job_environment puts glibc's heap settings into the environment the jobs inherit
    (32 MB mmap threshold, 256 MB trim threshold), and leaves a value the user has set alone."""
    from borescan.parallel import JOB_MALLOC_ENVIRONMENT, set_job_environment

    env = {"MALLOC_TRIM_THRESHOLD_": "131072", "PATH": "/bin"}
    got = set_job_environment(env)
    assert got == {"MALLOC_MMAP_THRESHOLD_": str(32 * 2**20), "MALLOC_TRIM_THRESHOLD_": "131072"}
    assert env["PATH"] == "/bin" and set(JOB_MALLOC_ENVIRONMENT) <= set(env)
    assert set_job_environment({}) == JOB_MALLOC_ENVIRONMENT == {
        "MALLOC_MMAP_THRESHOLD_": "33554432", "MALLOC_TRIM_THRESHOLD_": "268435456"}

