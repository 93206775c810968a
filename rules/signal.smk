rule signal_night:
    message:
        "Filtering readings, finding revolutions and extrema for night {wildcards.night}"
    input:
        scans=f"{RES}/stage/scans/night={{night}}.parquet",
        readings=f"{RES}/stage/readings/night={{night}}",  # ingest's validated scans: raw is read once, by ingest
    output:
        extrema=f"{RES}/stage/extrema/night={{night}}.parquet",
        summary=f"{RES}/stage/signal_summary/night={{night}}.parquet",
        quarantine=f"{RES}/stage/quarantine/stage=signal/night={{night}}.parquet",
    params:
        raw_root=RAW,
        results_root=results_root_for,
        signal=night_setting("signal"),
    threads: NIGHT_JOB_THREADS
    log:
        f"{RES}/logs/signal_night/{{night}}.log",
    benchmark:
        f"{RES}/benchmarks/signal_night/{{night}}.tsv"
    conda:
        "../workflow/envs/borescan.yaml"
    script:
        "../workflow/scripts/signal_night.py"
