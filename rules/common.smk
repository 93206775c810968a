# Names the rules use: roots from the config and the nights found under raw_root.
from borescan import rawio, validation

RAW = str(validation.require_raw_root(config["raw_root"]))
RES = config["results_root"]
NIGHTS = rawio.nights(RAW)


def results_root_for(wildcards):
    """results_root for scripts that also write beside their declared outputs.

    Quarantine records (quarantine/<scan_id>.json), certificates (calibration/...), findings and
    gap plots (discrepancy/...) depend on what the data holds, so they cannot be declared
    up front; they go under results_root, which must be on a shared filesystem on a cluster.
    """
    return RES


def stage_table(table):
    """Paths of one stage table for every night."""
    return expand(f"{RES}/stage/{table}/night={{night}}.parquet", night=NIGHTS)


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


def verifications_before_night(wildcards):
    """Verification tables of earlier nights (a calibration that failed one is refused)."""
    return [f"{RES}/stage/verifications/night={n}.parquet" for n in NIGHTS if n < wildcards.night]


def scans_of_pooled_window(wildcards):
    """Scans tables of the night and of the discrepancy.pooled_window_nights - 1 nights before it."""
    upto = [n for n in NIGHTS if n <= wildcards.night]
    window = upto[-int(config["discrepancy"]["pooled_window_nights"]):]
    return [f"{RES}/stage/scans/night={n}.parquet" for n in window]
