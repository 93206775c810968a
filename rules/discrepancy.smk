rule discrepancy_night:
    message:
        "Looking for missing physical effects in the scans of night {wildcards.night}"
    input:
        scans=f"{RES}/stage/scans/night={{night}}.parquet",
        calibrations=calibrations_up_to_night,
        raw=raw_files_of_night,
    output:
        findings=f"{RES}/stage/findings/night={{night}}.parquet",
        quarantine=f"{RES}/stage/quarantine/stage=discrepancy/night={{night}}.parquet",
    params:
        raw_root=RAW,
        results_root=results_root_for,
        discrepancy=config["discrepancy"],
    threads: config["stage_workers"]
    log:
        f"{RES}/logs/discrepancy_night/{{night}}.log",
    benchmark:
        f"{RES}/benchmarks/discrepancy_night/{{night}}.tsv"
    conda:
        "../workflow/envs/borescan.yaml"
    script:
        "../workflow/scripts/discrepancy_night.py"


rule discrepancy:
    input:
        stage_table("findings"),
