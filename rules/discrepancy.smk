rule discrepancy_night:
    message:
        "Looking for missing physical effects in the scans of night {wildcards.night}"
    input:
        scans=f"{RES}/stage/scans/night={{night}}.parquet",
        calibrations=calibrations_up_to_night,
        readings=f"{RES}/stage/readings/night={{night}}",  # ingest's validated scans: raw is read once, by ingest
        findings_before=findings_before_night,  # what earlier nights' calibration scans were found to carry
    output:
        findings=f"{RES}/stage/findings/night={{night}}.parquet",
        quarantine=f"{RES}/stage/quarantine/stage=discrepancy/night={{night}}.parquet",
        # <scan_id>/findings.json and gap.png per scan examined (the set is the data's); read as
        # discrepancy/<scan_id>/, a link into this folder (borescan.stages.discrepancy)
        scans=report(directory(f"{RES}/discrepancy/night={{night}}"),
                     caption="../workflow/report/discrepancy_scan.rst",
                     category="Discrepancy", subcategory="{night}",
                     labels={"scan or device": "{scan_id}", "file": "{file}"},
                     patterns=[r"{scan_id,[^/]+}/{file,findings\.json|gap\.png}"]),
    params:
        raw_root=RAW,
        results_root=results_root_for,
        discrepancy=night_setting("discrepancy"),
    threads: NIGHT_JOB_THREADS
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
        stage_table("pooled_findings"),
        stage_table("calibration_drift"),



rule pooled_night:
    message:
        "Examining each device's spindle scans up to night {wildcards.night} together; calibration drift"
    input:
        scans=scans_of_pooled_window,
        calibrations=calibrations_up_to_night,
        readings=readings_of_pooled_window,  # the window's nights' readings stores (ingest)
    output:
        pooled_findings=f"{RES}/stage/pooled_findings/night={{night}}.parquet",
        calibration_drift=f"{RES}/stage/calibration_drift/night={{night}}.parquet",
        # one <device_id>.json per device with two or more spindle scans (the set is the data's)
        json=report(directory(f"{RES}/discrepancy/pooled/night={{night}}"),
                    caption="../workflow/report/discrepancy_pooled.rst",
                    category="Discrepancy", subcategory="{night}",
                    labels={"scan or device": "{device} (pooled)", "file": "{device}.json"},
                    patterns=[r"{device,[^/]+}.json"]),
    params:
        raw_root=RAW,
        results_root=results_root_for,
        discrepancy=night_setting("discrepancy"),
        devices=night_setting("devices"),
    threads: NIGHT_JOB_THREADS
    log:
        f"{RES}/logs/pooled_night/{{night}}.log",
    benchmark:
        f"{RES}/benchmarks/pooled_night/{{night}}.tsv"
    conda:
        "../workflow/envs/borescan.yaml"
    script:
        "../workflow/scripts/pooled_night.py"
