rule calibrate_night:
    message:
        "Calibrating the devices scanned in ring gauges on night {wildcards.night}"
    input:
        scans=f"{RES}/stage/scans/night={{night}}.parquet",
        summary=f"{RES}/stage/signal_summary/night={{night}}.parquet",
        readings=f"{RES}/stage/readings/night={{night}}",  # ingest's validated scans: raw is read once, by ingest
        pooled=pooled_findings_before_night,
    output:
        calibrations=f"{RES}/stage/calibrations/night={{night}}.parquet",
        calibration_scans=f"{RES}/stage/calibration_scans/night={{night}}.parquet",
        quarantine=f"{RES}/stage/quarantine/stage=calibrate/night={{night}}.parquet",
        # one row per certificate written: its digests and content, from which `borescan certificate` reissues it
        certificate_issues=f"{RES}/stage/certificate_issues/night={{night}}.parquet",
        # <device_id>/<calibration_id>/certificate.{pdf,json,dcc.xml} (+ residuals.png) per calibration made (the
        # set is the data's); read as calibration/<device_id>/<calibration_id>/, a link into this folder
        certificates=report(directory(f"{RES}/calibration/night={{night}}"),
                            caption="../workflow/report/certificate.rst",
                            category="Calibration", subcategory="{night}",
                            labels={"device": "{device_id}", "calibration": "{calibration_id}", "file": "{file}"},
                            patterns=[r"{device_id,[^/]+}/{calibration_id,[^/]+}/"
                                      r"{file,certificate\.pdf|certificate\.json|certificate\.dcc\.xml|residuals\.png}"]),
    params:
        raw_root=RAW,
        results_root=results_root_for,
        calibration=night_setting("calibration"),
        uncertainty=night_setting("uncertainty"),
        laboratory=night_setting("laboratory"),
        verification=night_setting("verification"),
        devices=night_setting("devices"),
        device_model_auto_nights=night_setting("discrepancy", "device_model_auto_nights"),
        signal=night_setting("signal"),
    threads: NIGHT_JOB_THREADS
    log:
        f"{RES}/logs/calibrate_night/{{night}}.log",
    benchmark:
        f"{RES}/benchmarks/calibrate_night/{{night}}.tsv"
    conda:
        "../workflow/envs/borescan.yaml"
    script:
        "../workflow/scripts/calibrate_night.py"


rule calibrate:
    input:
        stage_table("calibrations"),
