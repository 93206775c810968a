# borescan: LDS bore scans -> calibrated devices, certified diameters, traceable history.
# Table of contents only; each stage lives in rules/<stage>.smk and calls src/borescan.
from snakemake.utils import min_version, validate

from borescan.config import SCHEMA_PATH, check_config

min_version("8.0")


configfile: "config/config.yaml"
configfile: "config/devices.yaml"  # the device model: a user's decisions per device


# a mistyped key or a wrong value: one line naming it (Snakemake's own message prints the schema)
check_config(config, "config (config/config.yaml, config/devices.yaml, --config)")
validate(config, str(SCHEMA_PATH))  # the schema borescan ships (workflow/schemas/ links to it)


include: "rules/common.smk"
include: "rules/ingest.smk"
include: "rules/signal.smk"
include: "rules/calibrate.smk"
include: "rules/measure.smk"
include: "rules/discrepancy.smk"
include: "rules/papers.smk"
include: "rules/catalog.smk"
include: "rules/report.smk"


rule all:
    default_target: True
    input:
        rules.catalog.input,
        rules.report.input,
        rules.papers.input,



onstart:
    # a run killed hard inside write_report leaves Snakemake's copy of results/report behind: put it back
    from borescan.workflow_log import record_lock_owner, restore_stale_backups

    restore_stale_backups(".snakemake", [f"{RES}/report"])
    # which lock files are this run's: a later run releases them if this process is killed (SIGKILL)
    record_lock_owner(".snakemake", getattr(workflow.persistence, "_lockfile", {}).values())


onsuccess:
    # the scheduler's last re-evaluation timer would hold the exit up by about a second
    from borescan.workflow_log import cancel_idle_timers

    cancel_idle_timers()


onerror:
    from borescan.workflow_log import cancel_idle_timers

    cancel_idle_timers()
