rule build_catalog:
    message:
        "Adding the new nights to the history catalog {output.catalog}"
    input:
        scans=stage_table("scans"),
        scan_files=stage_table("scan_files"),
        quarantine=stage_table("quarantine/stage=ingest"),
        signal_summary=stage_table("signal_summary"),
        signal_quarantine=stage_table("quarantine/stage=signal"),
        calibrations=stage_table("calibrations"),
        calibration_scans=stage_table("calibration_scans"),
        calibrate_quarantine=stage_table("quarantine/stage=calibrate"),
        diameters=stage_table("diameters"),
        verifications=stage_table("verifications"),
        artifacts=stage_table("artifacts"),
        measure_quarantine=stage_table("quarantine/stage=measure"),
        findings=stage_table("findings"),
        discrepancy_quarantine=stage_table("quarantine/stage=discrepancy"),
        pooled_findings=stage_table("pooled_findings"),
        calibration_drift=stage_table("calibration_drift"),
    output:
        # update(): Snakemake must not delete the catalog before the job, which extends it by
        # the new nights (borescan.catalog.update_catalog); a failed job restores the old one
        catalog=update(f"{RES}/catalog.duckdb"),
    params:
        results_root=results_root_for,
        raw_root=RAW,  # the history is checked against it: every scan in, or the job fails naming it
    log:
        f"{RES}/logs/build_catalog.log",
    benchmark:
        f"{RES}/benchmarks/build_catalog.tsv"
    conda:
        "../workflow/envs/borescan.yaml"
    script:
        "../workflow/scripts/build_catalog.py"


rule catalog:
    input:
        rules.build_catalog.output,
        # every night's stage tables as well: Snakemake (9.27) does not run a job whose input is
        # missing unless a target needs that file, and it tells a changed set of inputs only from
        # .snakemake/metadata, which another checkout, or a copied results root, does not have.
        # Without these a night added to the raw root would be "Nothing to be done" from such a
        # checkout (the catalog exists, the new night's tables are not asked for); with them a
        # missing table of any night of the raw root is asked for, and the catalog is rebuilt after it.
        rules.build_catalog.input,
