rule measure_night:
    message:
        "Verifying calibrations and measuring parts of night {wildcards.night}"
    input:
        scans=f"{RES}/stage/scans/night={{night}}.parquet",
        calibrations=calibrations_up_to_night,
        verifications_before=verifications_before_night,
        readings=f"{RES}/stage/readings/night={{night}}",  # ingest's validated scans: raw is read once, by ingest
    output:
        diameters=f"{RES}/stage/diameters/night={{night}}.parquet",
        verifications=f"{RES}/stage/verifications/night={{night}}.parquet",
        artifacts=f"{RES}/stage/artifacts/night={{night}}.parquet",
        quarantine=f"{RES}/stage/quarantine/stage=measure/night={{night}}.parquet",
    params:
        raw_root=RAW,
        results_root=results_root_for,
        verification=night_setting("verification"),
        measurement=night_setting("measurement"),
        calibration=night_setting("calibration"),
        uncertainty=night_setting("uncertainty"),
        laboratory=night_setting("laboratory"),
        signal=night_setting("signal"),
    threads: NIGHT_JOB_THREADS
    log:
        f"{RES}/logs/measure_night/{{night}}.log",
    benchmark:
        f"{RES}/benchmarks/measure_night/{{night}}.tsv"
    conda:
        "../workflow/envs/borescan.yaml"
    script:
        "../workflow/scripts/measure_night.py"


rule measure:
    input:
        stage_table("diameters"),
        stage_table("verifications"),
