# Names the rules use: roots from the config and the nights found under raw_root.
import sys

from borescan import night_config, rawio, validation
from borescan.catalog import set_aside_damaged
from borescan.effects import device_model_effects
from borescan.parallel import set_job_environment
from borescan.resources import shipped
from borescan.raw_index import night_index_paths
from borescan.workflow_log import is_dry_run, release_stale_locks

set_job_environment()  # glibc malloc settings every job inherits (borescan.parallel.JOB_MALLOC_ENVIRONMENT)

RAW = str(validation.require_raw_root(config["raw_root"]))
#: threads of a night job (ingest, signal, calibrate, measure, discrepancy, pooled): the processes it
#: spreads its scans (calibrate, pooled: its devices) over (borescan.parallel). Snakemake caps them at
#: --cores; `--set-threads measure_night=8` (or `set-threads:` in a profile) sets one rule's.
NIGHT_JOB_THREADS = 2
DRY_RUN = is_dry_run(workflow)  # snakemake -n: nothing below writes under the results root
RES = config["results_root"]
NIGHTS = rawio.nights(RAW)
#: the papers' transcribed tables, shipped with borescan (data/papers/ links to them)
PAPER_TRANSCRIPTIONS = [str(shipped("papers", f"yang2017_table{i}.csv")) for i in (1, 2, 3)]
# each night's manifest (its scan folders, files, sizes, times) rewritten when it changed: an input
# of ingest_night, so the raw root decides what runs whatever the files' times and the checkout
# (a dry run writes nothing under the results root: its changed manifests go to a temporary folder)
RAW_INDEX = night_index_paths(RAW, RES, NIGHTS, dry_run=DRY_RUN)
# the locks a run killed with SIGKILL left behind (its process is gone) are released; others stay
for _pid in release_stale_locks(".snakemake"):
    print(f"borescan: released the lock of run {_pid}, which was killed before it finished; its jobs rerun",
          file=sys.stderr)
# a catalog cut off (a full disk, a copy interrupted) is set aside: build_catalog rebuilds it, the report follows
_damaged = set_aside_damaged(RES, dry_run=DRY_RUN)
if _damaged:
    print(f"borescan: {_damaged}", file=sys.stderr)
# the settings each night is processed with: its record (borescan.night_config), else the current
# config (recorded now); an edit of the config applies to nights not yet in the history
NIGHT_SETTINGS, _differ = night_config.settle(RES, NIGHTS, config, record=not DRY_RUN)
if _differ:
    _keys = sorted({k for n in _differ for k in night_config.changed_keys(NIGHT_SETTINGS[n], night_config.night_settings(config))})
    print(f"borescan: the config differs from the one nights {_differ[0]}..{_differ[-1]} ({len(_differ)}) were "
          f"processed with ({', '.join(_keys[:6])}{' ...' if len(_keys) > 6 else ''}); it applies to nights not yet in "
          f"the history. To recompute earlier nights with it: borescan recompute --from NIGHT --results {RES}",
          file=sys.stderr)
for _device in config["devices"] or {}:  # a mistyped device-model entry stops the run here, named
    device_model_effects(config["devices"], _device)


def night_setting(*keys):
    """The setting ``keys`` (e.g. "verification") of the job's night (NIGHT_SETTINGS), for a rule's params;
    None where the night's record has no such key (recorded before the setting existed)."""

    def of_night(wildcards):
        value = NIGHT_SETTINGS[wildcards.night]
        for k in keys:
            value = value.get(k) if isinstance(value, dict) else None
        return value

    return of_night


def results_root_for(wildcards):
    """results_root for scripts that also write beside their declared outputs.

    Quarantine records (quarantine/<scan_id>.json) depend on what the data holds and lie in no
    per-night folder, so they are not declared; they go under results_root, which must be on a
    shared filesystem on a cluster. Certificates (calibration/night=<night>/, linked as
    calibration/<device_id>/<calibration_id>/), findings and gap plots (discrepancy/night=<night>/,
    linked as discrepancy/<scan_id>/), pooled findings and the report's month pages are declared
    as folders (`snakemake --report` lists their files by pattern).
    """
    return RES


def stage_table(table):
    """Paths of one stage table for every night."""
    return expand(f"{RES}/stage/{table}/night={{night}}.parquet", night=NIGHTS)


def raw_index_of_night(wildcards):
    return str(RAW_INDEX[wildcards.night])


def raw_files_of_night(wildcards):
    return rawio.night_raw_files(RAW, wildcards.night)


def duplicate_ids_of_night(wildcards):
    return rawio.earlier_duplicate_ids(RAW, wildcards.night)


def calibrations_up_to_night(wildcards):
    """Calibration tables of this and every earlier night (a measurement uses the latest valid one)."""
    return [f"{RES}/stage/calibrations/night={n}.parquet" for n in NIGHTS if n <= wildcards.night]


def scans_before_night(wildcards):
    """Scans tables of earlier nights (an artifact certificate must keep the value it was first recorded with)."""
    return [f"{RES}/stage/scans/night={n}.parquet" for n in NIGHTS if n < wildcards.night]


def findings_before_night(wildcards):
    """Findings tables of earlier nights (a scan read against an earlier calibration gets its scans' findings)."""
    return [f"{RES}/stage/findings/night={n}.parquet" for n in NIGHTS if n < wildcards.night]


def verifications_before_night(wildcards):
    """Verification tables of earlier nights (a calibration that failed one is refused)."""
    return [f"{RES}/stage/verifications/night={n}.parquet" for n in NIGHTS if n < wildcards.night]


def pooled_findings_before_night(wildcards):
    """Pooled findings of earlier nights when a device has a device model (config devices) or effects
    may enter one automatically (discrepancy.device_model_auto_nights): a night's calibration carries
    each at the latest earlier estimate; none otherwise."""
    cfg = NIGHT_SETTINGS[wildcards.night]
    listed = any((entry or {}).get("effects") for entry in (cfg.get("devices") or {}).values())
    if not listed and not int(cfg["discrepancy"]["device_model_auto_nights"]):
        return []
    return [f"{RES}/stage/pooled_findings/night={n}.parquet" for n in NIGHTS if n < wildcards.night]


def pooled_window_nights(wildcards):
    """The night and the discrepancy.pooled_window_nights - 1 nights before it."""
    upto = [n for n in NIGHTS if n <= wildcards.night]
    return upto[-int(NIGHT_SETTINGS[wildcards.night]["discrepancy"]["pooled_window_nights"]):]


def scans_of_pooled_window(wildcards):
    """Scans tables of the nights of pooled_window_nights."""
    return [f"{RES}/stage/scans/night={n}.parquet" for n in pooled_window_nights(wildcards)]


def readings_of_pooled_window(wildcards):
    """Readings stores (ingest's, borescan.rawio.store) of the nights of pooled_window_nights."""
    return [f"{RES}/stage/readings/night={n}" for n in pooled_window_nights(wildcards)]


#: month plots of results/report/<YYYY-MM>/ (named by borescan.report.pages) -> category of `snakemake --report`
MONTH_PLOT_CATEGORY = {"calibration": "Calibration", "control": "Verification", "diameters": "Diameters",
                       "devicemodel": "Calibration"}


def report_page_category(wildcards):
    """Category of a file of results/report/: a month plot by what it shows, the papers' page under
    Papers, a month page beside report.html (Diameters: the parts are what the pages are read for)."""
    if wildcards.get("kind"):
        return MONTH_PLOT_CATEGORY[wildcards.kind]
    return "Papers" if wildcards.get("page") == "papers" else "Diameters"


def report_page_subcategory(wildcards):
    """Subcategory: the month of a month plot; "Report pages" beside report.html; the papers' page
    on its own."""
    if wildcards.get("kind"):
        return wildcards.month
    return "All papers (page)" if wildcards.get("page") == "papers" else "Report pages"


def report_page_labels(wildcards):
    """Columns of the report's table: what a file shows and of which device, gauge or part."""
    if wildcards.get("kind"):
        return {"plot": {"calibration": "calibration history", "control": "control chart",
                         "diameters": "diameters", "devicemodel": "device model and gaps over the nights"}[wildcards.kind],
                "of": wildcards.subject}
    if wildcards.get("page") == "papers":
        return {"page": "papers.html (every reproduced table and figure)"}
    return {"page": f"month {wildcards.month} (report/{wildcards.month}/index.html)"}
