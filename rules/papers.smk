rule reproduce_papers:
    message:
        "Reproducing Yang 2017 Tables 1-3 and Wang 2017 Eq. 7, Eq. 15, Figs. 9 and 11"
    input:
        transcriptions=PAPER_TRANSCRIPTIONS,
    output:
        # every file the reproduction writes; the ones a person reads go into `snakemake --report`
        index=f"{RES}/papers/index.csv",
        index_parquet=f"{RES}/papers/index.parquet",
        yang_table1=report(f"{RES}/papers/yang2017_table1.csv", caption="../workflow/report/yang2017_table1.rst",
                           category="Papers", subcategory="Yang 2017 Table 1"),
        yang_table1_png=report(f"{RES}/papers/yang2017_table1.png", caption="../workflow/report/yang2017_table1.rst",
                               category="Papers", subcategory="Yang 2017 Table 1"),
        yang_table2=report(f"{RES}/papers/yang2017_table2.csv", caption="../workflow/report/yang2017_table2.rst",
                           category="Papers", subcategory="Yang 2017 Table 2"),
        yang_table2_png=report(f"{RES}/papers/yang2017_table2.png", caption="../workflow/report/yang2017_table2.rst",
                               category="Papers", subcategory="Yang 2017 Table 2"),
        yang_table2_findings=f"{RES}/papers/yang2017_table2_findings.json",
        yang_table3=report(f"{RES}/papers/yang_table3.csv", caption="../workflow/report/yang_table3.rst",
                           category="Papers", subcategory="Yang 2017 Table 3"),
        yang_table3_alternatives=f"{RES}/papers/yang_table3_alternatives.csv",
        yang_table3_png=report(f"{RES}/papers/yang_table3.png", caption="../workflow/report/yang_table3.rst",
                               category="Papers", subcategory="Yang 2017 Table 3"),
        wang_statements=report(f"{RES}/papers/wang_statements.csv", caption="../workflow/report/wang2017.rst",
                               category="Papers", subcategory="Wang 2017"),
        wang_fig9=f"{RES}/papers/wang_fig9.csv",
        wang_fig11=f"{RES}/papers/wang_fig11.csv",
        wang_png=report(f"{RES}/papers/wang.png", caption="../workflow/report/wang2017.rst",
                        category="Papers", subcategory="Wang 2017"),
    # independent of the scans: let the night's stages go first and fill a core left idle by the
    # one-process calibration, instead of holding one that a two-process stage is waiting for
    priority: -10
    log:
        f"{RES}/logs/reproduce_papers.log",
    benchmark:
        f"{RES}/benchmarks/reproduce_papers.tsv"
    conda:
        "../workflow/envs/borescan.yaml"
    script:
        "../workflow/scripts/reproduce_papers.py"


rule papers:
    input:
        rules.reproduce_papers.output,
