rule build_catalog:
    message:
        "Building the history catalog {output.catalog}"
    input:
        scans=stage_table("scans"),
        scan_files=stage_table("scan_files"),
        quarantine=stage_table("quarantine/stage=ingest"),
    output:
        catalog=f"{RES}/catalog.duckdb",
    params:
        results_root=RES,
    log:
        f"{RES}/logs/build_catalog.log",
    script:
        "../workflow/scripts/build_catalog.py"


rule catalog:
    input:
        rules.build_catalog.output,
