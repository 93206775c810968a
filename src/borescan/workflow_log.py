"""Logging for workflow scripts: messages go to the rule's log file and to stderr (progress)."""

from __future__ import annotations

import contextlib
import json
import os
import re
import resource
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator


@contextlib.contextmanager
def log_to(path: str | Path) -> Iterator[Callable[[str], None]]:
    """Yield a ``log(msg)`` function writing timestamped-by-elapsed-time lines to ``path`` and stderr.

    When the block ends without an error, the job's workers (``parallel.start_job_workers``) are
    stopped and its last line is the job's CPU time (:func:`job_cpu_line`).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    before_s = time.process_time()  # this process's start and imports
    with path.open("w") as fh:

        def log(msg: str) -> None:
            line = f"[{time.perf_counter() - t0:7.2f} s] {msg}"
            fh.write(line + "\n")
            fh.flush()
            print(line, file=sys.stderr, flush=True)

        yield log
        from borescan.parallel import stop_job_workers

        stop_job_workers()
        log(job_cpu_line(job_cpu(before_s)))


def rule_job(namespace: dict, script: str | Path, argv: list[str] | None = None):
    """Return the job a workflow script runs, from Snakemake or built from the Snakefile.

    Snakemake's ``snakemake`` object when Snakemake runs the script, else the same job built from
    the Snakefile, so a person can run (and debug) one stage of one night by hand::

        python workflow/scripts/calibrate_night.py night=2026-11-20 [raw_root=DIR results_root=DIR]

    ``key=value`` arguments are the rule's wildcards, or config overrides (as ``--config``) when
    the key is a top-level config key. The rule is the script's name; paths are relative to the
    project root (the working directory is changed to it, as Snakemake does).
    """
    if "snakemake" in namespace:
        return namespace["snakemake"]
    import os
    import sys as _sys

    import yaml
    from snakemake.api import SnakemakeApi
    from snakemake.dag import DAG
    from snakemake.jobs import Job
    from snakemake.script import Snakemake
    from snakemake.settings.types import ConfigSettings, DAGSettings, ResourceSettings

    script = Path(script).resolve()
    root = script.parents[2]
    rule_name = script.stem
    args = dict(a.split("=", 1) for a in (_sys.argv[1:] if argv is None else argv))
    config_keys = set(yaml.safe_load((root / "config" / "config.yaml").read_text()) or {})
    overrides = {k: v for k, v in args.items() if k in config_keys}
    wildcards = {k: v for k, v in args.items() if k not in config_keys}
    os.chdir(root)
    with SnakemakeApi() as api:
        wf = api.workflow(
            resource_settings=ResourceSettings(cores=1),
            config_settings=ConfigSettings(config=overrides),
            snakefile=root / "Snakefile",
            workdir=root,
        )
        wf.dag(DAGSettings())
        workflow = wf._workflow
        rule = workflow.get_rule(rule_name)
        missing = set(rule.wildcard_names) - set(wildcards)
        if missing:
            raise SystemExit(
                f"{script.name}: rule {rule_name} needs the wildcard(s) {sorted(missing)} "
                f"as key=value arguments, e.g. night=2026-11-20"
            )
        job = Job(rule, DAG(workflow, rules=[rule]), wildcards_dict=wildcards)
        for f in list(job.output) + list(job.log):
            Path(f).parent.mkdir(parents=True, exist_ok=True)
        return Snakemake(
            job.input,
            job.output,
            job.params,
            job.wildcards,
            1,
            job.resources,
            job.log,
            workflow.config,
            rule_name,
            None,
            scriptdir=str(script.parent),
        )


def restore_stale_backups(snakemake_dir: str | Path, folders, log=print) -> list[Path]:
    """Put back the copies Snakemake keeps of ``update()`` folders while their job runs.

    Before a job that updates a folder in place (``update(directory(...))``), Snakemake copies it
    to ``.snakemake/backups/<absolute path>`` and restores it if the job fails. A run killed hard
    (power cut, ``kill -9``) leaves the copy behind, and the next run's copy then fails with
    FileExistsError. Called when a run starts (it holds the lock, so no job of another run is
    writing): the folder goes back to its state before the killed job, which is then rerun.
    Returns the folders restored.
    """
    restored = []
    root = Path(snakemake_dir) / "backups"
    for folder in folders:
        folder = Path(folder)
        # where Snakemake keeps it: the output path as the rule names it, an absolute one without its root
        backup = root / (folder.relative_to(folder.parents[-1]) if folder.is_absolute() else folder)
        if not backup.is_dir():
            continue
        import shutil

        shutil.rmtree(folder, ignore_errors=True)
        shutil.move(str(backup), str(folder))
        log(f"{folder}: restored from the copy a killed run left in {backup}")
        restored.append(folder)
    return restored


def cancel_idle_timers() -> int:
    """Cancel the timer threads still waiting in this process once a Snakemake run is over.

    After each round Snakemake's scheduler arms a ``threading.Timer`` to look at the job queue
    again (its job-rate limit, ``--max-jobs-per-timespan``, 1 s by default). The interpreter
    waits for the last one before it exits, which added about a second to every run. Called by
    the Snakefile's ``onsuccess`` and ``onerror``, when the scheduler is done. Returns the number
    of timers cancelled.
    """
    timers = [t for t in threading.enumerate() if isinstance(t, threading.Timer) and t.is_alive()]
    for t in timers:
        t.cancel()
    return len(timers)


#: a job's log line of one item's compute time (:func:`compute_line`); ``python -m bench contract_night``
#: reads them
COMPUTE_RE = re.compile(r"compute (?P<item>\S+) (?P<seconds>[0-9.]+) s$")


def compute_line(item: str, seconds: float) -> str:
    """Return the log line of one item's (a scan's, a device's) CPU seconds in a stage.

    Timings go to the log only: never into a stage table, the catalog or a certificate (reruns stay
    byte-identical).
    """
    return f"compute {item} {seconds:.3f} s"


@dataclass(frozen=True)
class JobCpu:
    """CPU seconds (user + system) of a job: its own process and the child processes it has waited for."""

    user_s: float
    sys_s: float
    #: this process, from its start (the interpreter, the script's imports included)
    own_s: float
    #: of ``own_s``, before the stage began (the process's start and imports, up to :func:`log_to`)
    before_stage_s: float
    #: its worker processes (spawned interpreters, their imports included) that have exited
    workers_s: float

    @property
    def total_s(self) -> float:
        """User plus system seconds of the process and its exited children."""
        return self.user_s + self.sys_s


def job_cpu(before_stage_s: float = 0.0) -> JobCpu:
    """Return the CPU time of this process and of its child processes that have ended and been waited for.

    ``getrusage``: exact, unlike a sampled figure (Snakemake's ``benchmark:`` files take ``cpu_time``
    from samples of the job's process tree every 0.5 s for its first 15 s, every 30 s after, so a
    worker's last seconds and a long job's tail are missed). Far less stretched by other programs'
    load than the wall time, but not immune: with 20-27 runnable processes on 2 cores the same work
    took 2-4 times the CPU seconds it takes at a load of 10 (caches shared, cores switched every few
    ms), so compare figures taken at a similar load.
    """
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return JobCpu(
        user_s=me.ru_utime + kids.ru_utime,
        sys_s=me.ru_stime + kids.ru_stime,
        own_s=me.ru_utime + me.ru_stime,
        before_stage_s=before_stage_s,
        workers_s=kids.ru_utime + kids.ru_stime,
    )


#: a job's last log line (:func:`job_cpu_line`); ``python -m bench contract_night`` and ``pipeline`` read it
JOB_CPU_RE = re.compile(
    r"job cpu (?P<total>[0-9.]+) s \(user (?P<user>[0-9.]+) s, sys (?P<sys>[0-9.]+) s; "
    r"this process (?P<own>[0-9.]+) s, (?P<before>[0-9.]+) s of it before the stage; "
    r"worker processes (?P<workers>[0-9.]+) s\)$"
)


def job_cpu_line(cpu: JobCpu) -> str:
    """Return the log line of a job's CPU seconds (the log only, like :func:`compute_line`)."""
    return (
        f"job cpu {cpu.total_s:.3f} s (user {cpu.user_s:.3f} s, sys {cpu.sys_s:.3f} s; "
        f"this process {cpu.own_s:.3f} s, {cpu.before_stage_s:.3f} s of it before the stage; "
        f"worker processes {cpu.workers_s:.3f} s)"
    )


def parse_job_cpu(line: str) -> JobCpu | None:
    """Return the :class:`JobCpu` of a :func:`job_cpu_line` (its log prefix allowed), else None."""
    m = JOB_CPU_RE.search(line)
    if m is None:
        return None
    return JobCpu(
        user_s=float(m["user"]),
        sys_s=float(m["sys"]),
        own_s=float(m["own"]),
        before_stage_s=float(m["before"]),
        workers_s=float(m["workers"]),
    )


# ------------------------------------------------------------------------ locks of a killed run


def _boot_id() -> str:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def record_lock_owner(snakemake_dir: str | Path, lock_files) -> Path:
    """At a run's start (it holds its locks): note which lock files are this process's, on this boot."""
    path = Path(snakemake_dir) / "locks" / f"borescan-owner-{os.getpid()}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        json.dumps({"pid": os.getpid(), "boot_id": _boot_id(), "locks": sorted(map(str, lock_files))})
    )
    return path


def release_stale_locks(snakemake_dir: str | Path) -> list[int]:
    """Remove the locks of runs on this machine whose process is gone; return their process ids.

    Killed with SIGKILL, or a crash. A lock whose owner is alive, on another boot, or unknown is left to
    Snakemake, which names it and the command that releases it (``snakemake --unlock``).
    """
    gone = []
    for owner in sorted((Path(snakemake_dir) / "locks").glob("borescan-owner-*.json")):
        try:
            rec = json.loads(owner.read_text())
        except (OSError, ValueError):
            continue
        if rec.get("boot_id") != _boot_id() or _alive(int(rec["pid"])):
            continue
        for lock in rec.get("locks", []):
            Path(lock).unlink(missing_ok=True)
        owner.unlink(missing_ok=True)
        gone.append(int(rec["pid"]))
    return gone


def is_dry_run(workflow=None, argv: list[str] | None = None) -> bool:
    """Return whether the Snakemake run that parses the Snakefile is a dry run (``-n``, ``--dry-run``).

    ``workflow.dryrun`` is known only once the executor is chosen, after the Snakefile is parsed (it is False
    while ``rules/common.smk`` runs, Snakemake 9.27), so the command line (``argv``, default ``sys.argv``) is
    read with Snakemake's own parser (combined flags such as ``-np`` included). An unreadable command line is
    not a dry run.
    """
    if workflow is not None and getattr(workflow, "dryrun", False):
        return True
    from snakemake.cli import get_argument_parser

    try:
        args, _ = get_argument_parser().parse_known_args(sys.argv[1:] if argv is None else argv)
    except (SystemExit, ValueError):  # argparse exits on what it cannot read
        return False
    return bool(getattr(args, "dryrun", False))
