rule reproduce_papers:
    message:
        "Reproducing Yang 2017 Tables 1-3 and Wang 2017 Eq. 7, Eq. 15, Figs. 9 and 11"
    input:
        transcriptions=[
            "data/papers/yang2017_table1.csv",
            "data/papers/yang2017_table2.csv",
            "data/papers/yang2017_table3.csv",
        ],
    output:
        index=f"{RES}/papers/index.csv",
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
