rule write_report:
    message:
        "Writing the browsable report {output.html}"
    input:
        catalog=f"{RES}/catalog.duckdb",
        papers=f"{RES}/papers/index.csv",
    output:
        # update(): the page and its month pages (report/<YYYY-MM>/) are brought up to date in
        # place; a month whose rows did not change keeps its page and plots
        html=update(f"{RES}/report.html"),
    params:
        results_root=results_root_for,
    log:
        f"{RES}/logs/write_report.log",
    benchmark:
        f"{RES}/benchmarks/write_report.tsv"
    conda:
        "../workflow/envs/borescan.yaml"
    script:
        "../workflow/scripts/write_report.py"


rule report:
    input:
        rules.write_report.output,
