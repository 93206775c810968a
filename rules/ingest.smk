rule ingest_night:
    message:
        "Validating and registering the scans of night {wildcards.night}"
    input:
        raw=raw_files_of_night,
        raw_index=raw_index_of_night,  # rewritten when the night's scans change (rules/common.smk)
        earlier_scans=scans_before_night,
    output:
        scans=f"{RES}/stage/scans/night={{night}}.parquet",
        files=f"{RES}/stage/scan_files/night={{night}}.parquet",
        quarantine=f"{RES}/stage/quarantine/stage=ingest/night={{night}}.parquet",
        # the night's valid scans as ingest read them (borescan.rawio.store): what every later stage reads
        readings=directory(f"{RES}/stage/readings/night={{night}}"),
    params:
        raw_root=RAW,
        results_root=results_root_for,
        duplicates=duplicate_ids_of_night,
        on_conflict=night_setting("artifacts", "on_conflict"),
        plausibility=night_setting("plausibility"),  # None for a night recorded before it existed
    threads: NIGHT_JOB_THREADS
    log:
        f"{RES}/logs/ingest_night/{{night}}.log",
    benchmark:
        f"{RES}/benchmarks/ingest_night/{{night}}.tsv"
    conda:
        "../workflow/envs/borescan.yaml"
    script:
        "../workflow/scripts/ingest_night.py"
