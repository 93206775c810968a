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
    (32 MB mmap threshold, 256 MB trim threshold), and leaves a value the user has set alone.
    """
    from borescan.parallel import JOB_MALLOC_ENVIRONMENT, set_job_environment

    env = {"MALLOC_TRIM_THRESHOLD_": "131072", "PATH": "/bin"}
    got = set_job_environment(env)
    assert got == {"MALLOC_MMAP_THRESHOLD_": str(32 * 2**20), "MALLOC_TRIM_THRESHOLD_": "131072"}
    assert env["PATH"] == "/bin" and set(JOB_MALLOC_ENVIRONMENT) <= set(env)
    assert (
        set_job_environment({})
        == JOB_MALLOC_ENVIRONMENT
        == {"MALLOC_MMAP_THRESHOLD_": "33554432", "MALLOC_TRIM_THRESHOLD_": "268435456"}
    )


_JOB_SCRIPT = """
import os, sys, time
class _Job:
    threads = int(sys.argv[1])
if _Job.threads:
    snakemake = _Job()  # what Snakemake puts into a script job's namespace (none when run by hand)
from borescan.parallel import start_job_workers
started = start_job_workers(globals())
import numpy  # after: the BLAS threads of this process are fixed here
from borescan.parallel import map_in_order

def square_pid_threads(x):
    barrier = os.environ.get("JOB_TEST_BARRIER")  # a folder: each process that takes an item leaves its pid
    if barrier:
        open(os.path.join(barrier, str(os.getpid())), "w").close()
        deadline = time.monotonic() + 60.0
        while x == 0 and len(os.listdir(barrier)) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)  # item 0 waits until the other process has taken an item too
    return x * x, os.getpid(), os.environ.get("OPENBLAS_NUM_THREADS"), os.environ.get("POLARS_MAX_THREADS")

if __name__ == "__main__":
    out = list(map_in_order(square_pid_threads, range(40), workers=max(_Job.threads, 1)))  # smk.threads
    print(started, os.getpid(), repr(out))
"""


def _run_job_script(tmp_path, threads: int, barrier: bool = False):
    """Run the job script; ``barrier``: its first item waits until a second process has taken an item.

    Without it, 40 items of microseconds may all be done by the job's own process before its worker
    has finished importing (a loaded machine): which process takes what is the queue's, not the test's.
    """
    import ast
    import subprocess
    import sys

    script = tmp_path / "job.py"
    script.write_text(_JOB_SCRIPT)
    env = dict(os.environ)
    if barrier:
        (tmp_path / "pids").mkdir(exist_ok=True)
        env["JOB_TEST_BARRIER"] = str(tmp_path / "pids")
    proc = subprocess.run(
        [sys.executable, str(script), str(threads)], capture_output=True, text=True, timeout=120, env=env
    )
    assert proc.returncode == 0, proc.stderr
    started, parent, out = proc.stdout.strip().split(" ", 2)
    return int(started), int(parent), ast.literal_eval(out)


def test_a_job_started_early_computes_in_its_own_process_and_one_worker(tmp_path):
    """start_job_workers at the top of a job's script (threads = 2): one worker is spawned at once,
    the job's process is the other; both run with one BLAS and polars thread (so a scan's result
    does not depend on the process that took it), and the results come back in order.
    """
    started, parent, out = _run_job_script(tmp_path, threads=2, barrier=True)
    assert started == 2
    assert [v for v, *_ in out] == [x * x for x in range(40)]
    pids = {p for _, p, _, _ in out}
    assert parent in pids and len(pids) == 2  # the caller took items too, and one spawned worker
    assert {(b, p) for _, _, b, p in out} == {("1", "1")}


def test_a_job_of_one_thread_or_by_hand_computes_alone_with_one_blas_thread(tmp_path):
    """threads = 1 (``--cores 1``) or no Snakemake (a person runs the script): no worker, and the
    same one BLAS and polars thread as a job of several processes, so results are the same.
    """
    for threads in (1, 0):
        started, parent, out = _run_job_script(tmp_path, threads=threads)
        assert started == 1
        assert [v for v, *_ in out] == [x * x for x in range(40)]
        assert {p for _, p, _, _ in out} == {parent}
        assert {(b, p) for _, _, b, p in out} == {("1", "1")}


def test_start_job_workers_does_nothing_in_a_worker_or_after_numpy():
    """Not in a worker (``__mp_main__``), and never once numpy is loaded in the process (its BLAS
    threads could no longer be set): nothing is started and the environment is left as it was.
    """
    from borescan.parallel import _JOB_POOL, start_job_workers

    class Job:
        threads = 2

    env_before = dict(os.environ)
    assert start_job_workers({"__name__": "__mp_main__", "snakemake": Job()}) == 1
    assert start_job_workers({"__name__": "__main__", "snakemake": Job()}) == 1  # pytest has numpy loaded
    assert dict(os.environ) == env_before and not _JOB_POOL


def test_every_job_of_several_processes_starts_its_workers_before_numpy():
    """A rule with ``threads:`` spreads its items over processes; its script calls
    start_job_workers before anything imports numpy (else the job's own process would keep its BLAS
    threads and could give other last digits than its workers for the same scan).
    """
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    checked = []
    for smk in sorted((root / "rules").glob("*.smk")):
        for block in re.split(r"\n(?=rule )", smk.read_text()):
            script = re.search(r'script:\s*\n\s*"\.\./(workflow/scripts/[\w.]+)"', block)
            if "threads:" not in block or script is None:
                continue
            lines = [
                ln
                for ln in (root / script.group(1)).read_text().splitlines()
                if ln.startswith(("import ", "from ", "start_job_workers("))
            ]
            assert lines[0] == "from borescan.parallel import start_job_workers", script.group(1)
            assert lines[1].startswith("start_job_workers(globals())"), script.group(1)
            checked.append(script.group(1))
    assert len(checked) >= 6, checked  # ingest, signal, calibrate, measure, discrepancy, pooled


def test_map_timed_keeps_order_and_gives_each_items_cpu_seconds():
    """The compute time of each item, as the log line the benchmark reads back."""
    import re

    from borescan.parallel import map_timed
    from borescan.workflow_log import COMPUTE_RE, compute_line

    items = list(range(2 * MIN_ITEMS_PER_WORKER + 3))
    out = list(map_timed(_square_and_pid, items, workers=2))
    assert [v for (v, _), _ in out] == [x * x for x in items]
    assert all(s >= 0.0 for _, s in out)
    m = COMPUTE_RE.search("[  1.00 s] " + compute_line("CT5-00001", 1.23456))
    assert m and m["item"] == "CT5-00001" and float(m["seconds"]) == 1.235
    assert re.fullmatch(r"compute \S+ [0-9.]+ s", compute_line("TRI-01", 0.5))


_SHARING_SCRIPT = """
import multiprocessing, os, sys, time
class _Job:
    threads = 2
snakemake = _Job()
from borescan.parallel import start_job_workers
start_job_workers(globals())
from borescan.parallel import map_in_order
PARENT = os.getpid()
_taken = []

def item(x):
    if multiprocessing.parent_process() is None:  # the job's own process (a worker has a parent)
        _taken.append(x)
        if len(_taken) == 1:
            time.sleep(3.0)  # the caller's first item is a long one
    else:
        time.sleep(0.01)
    return x, os.getpid()

if __name__ == "__main__":
    out = list(map_in_order(item, range(40), workers=2))
    print(PARENT, repr(out))
"""


def test_the_worker_goes_on_while_the_caller_computes_a_long_item(tmp_path):
    """The job's own process and its worker share one queue: while the caller spends 3 s on one item,
    the worker takes every other item (0.01 s each) instead of waiting with the one or two it was
    handed; the results still come back in order.
    """
    import ast
    import subprocess
    import sys

    script = tmp_path / "job.py"
    script.write_text(_SHARING_SCRIPT)
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    parent, out = proc.stdout.strip().split(" ", 1)
    out = ast.literal_eval(out)
    assert [x for x, _ in out] == list(range(40))
    by_caller = [x for x, p in out if p == int(parent)]
    # the caller takes an item only when it is free: its long one, and any taken before the worker had
    # finished importing (the worker needs 0.4 s for the rest, the caller's item lasts 3 s)
    assert 1 <= len(by_caller) <= 5, by_caller
