"""Stage ``reproduce_papers``: the papers' tables and figures reproduced beside the printed values."""

from __future__ import annotations

from pathlib import Path

import polars as pl

from borescan.atomic import atomic_write_json
from borescan.discrepancy.table2 import examine_table2
from borescan.papers import wang, yang_table1, yang_table2, yang_table3
from borescan.stages._common import write_table

__all__ = ["stage_papers"]


def stage_papers(out_dir: str | Path, log=print) -> pl.DataFrame:
    """Reproduce the papers' printed results beside them; returns (and writes) ``index.csv``.

    Yang 2017 Tables 1-3 (calibration inputs, extrema sample numbers, verification diameters),
    Wang 2017 Eq. 7, Eq. 15, Figs. 9 and 11, and the model-discrepancy finding on Table 2 (its
    sample numbers disagree with the stated 625 samples per revolution).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []

    def add(source: str, result) -> None:
        paths = result.values() if isinstance(result, dict) else result
        for p in paths:
            rows.append({"source": source, "file": Path(p).name})
        log(f"{source}: " + ", ".join(Path(p).name for p in paths))

    add("Yang 2017 Table 1", yang_table1.write_reproduction(out_dir))
    add("Yang 2017 Table 2", yang_table2.write_reproduction(out_dir))
    add("Yang 2017 Table 3", yang_table3.write_reproduction(out_dir))
    add("Wang 2017 Eq. 7, Eq. 15, Figs. 9 and 11", wang.write_reproduction(out_dir, progress=log))
    path = atomic_write_json(out_dir / "yang2017_table2_findings.json", examine_table2())
    add("Yang 2017 Table 2 model discrepancy", [path])
    index = pl.DataFrame(rows)
    write_table(index, out_dir / "index.parquet")
    index.write_csv(out_dir / "index.csv")
    return index
