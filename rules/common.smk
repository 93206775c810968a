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
