rule write_report:
    message:
        "Writing the browsable report {output.html}"
    input:
        catalog=f"{RES}/catalog.duckdb",
    output:
        html=f"{RES}/report.html",
    params:
        results_root=RES,
    log:
        f"{RES}/logs/write_report.log",
    script:
        "../workflow/scripts/write_report.py"


rule report:
    input:
        rules.write_report.output,
