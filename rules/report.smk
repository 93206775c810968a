# The landing page of `snakemake --report <file>.zip`: what the record holds and where to start
report: "../workflow/report/workflow.rst"

rule write_report:
    message:
        "Writing the browsable report {output.html}"
    input:
        catalog=f"{RES}/catalog.duckdb",
        papers=f"{RES}/papers/index.csv",
    output:
        # update(): the page and its month pages (report/<YYYY-MM>/) are brought up to date in
        # place; a month whose rows did not change keeps its page and plots
        html=report(update(f"{RES}/report.html"), caption="../workflow/report/report_page.rst",
                    category="Diameters", subcategory="Report pages",
                    labels={"page": "report.html (every month; start here)"}),
        # the month pages and plots and the papers' page; the set of months is the data's. While the
        # job runs Snakemake keeps a copy in .snakemake/backups/ (restored if the job fails); a run
        # killed hard leaves it behind and the next write_report stops with FileExistsError naming
        # that copy: delete it and rerun (Snakemake 9.27 copies folders with shutil.copytree)
        pages=report(update(directory(f"{RES}/report")), caption="../workflow/report/report_pages.rst",
                     category=report_page_category, subcategory=report_page_subcategory,
                     labels=report_page_labels,
                     patterns=[
                         r"{month,\d{4}-\d{2}|undated}/{kind,calibration|control|diameters|devicemodel}_{subject,[^/]+}.png",
                         r"{month,\d{4}-\d{2}|undated}/{page,index}.html",
                         r"{page,papers}.html",
                     ]),
    params:
        results_root=results_root_for,
    threads: NIGHT_JOB_THREADS  # the month's changed plots are drawn on the job's processes
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
