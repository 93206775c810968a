# Names the rules use: roots from the config and the nights found under raw_root.
from borescan import pipeline

RAW = config["raw_root"]
RES = config["results_root"]
NIGHTS = pipeline.nights(RAW)


def stage_table(table):
    """Paths of one stage table for every night."""
    return expand(f"{RES}/stage/{table}/night={{night}}.parquet", night=NIGHTS)


def raw_files_of_night(wildcards):
    return pipeline.night_raw_files(RAW, wildcards.night)


def duplicate_ids_of_night(wildcards):
    return pipeline.earlier_duplicate_ids(RAW, wildcards.night)


def calibrations_up_to_night(wildcards):
    """Calibration tables of this and every earlier night (a measurement uses the latest valid one)."""
    return [f"{RES}/stage/calibrations/night={n}.parquet" for n in NIGHTS if n <= wildcards.night]


def verifications_before_night(wildcards):
    """Verification tables of earlier nights (a calibration that failed one is refused)."""
    return [f"{RES}/stage/verifications/night={n}.parquet" for n in NIGHTS if n < wildcards.night]
