"""The papers' page headline: printed | ours | why, with "ours" read from the reproductions in ``papers/``.

The "ours" column is computed from the CSV files the ``reproduce_papers`` rule wrote into this
results folder (never copied from the documentation); "why" says what explains a difference
(``docs/papers.md`` gives the arguments). A row whose file is missing or unreadable is left out.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import polars as pl


@dataclass(frozen=True)
class PaperRow:
    """One statement of a paper beside what the reproduction in ``papers/`` gives."""

    paper: str
    printed: str
    ours: str
    why: str
    source: str  # the file under papers/ the row is read from


def _rms(values: pl.Series) -> float:
    v = values.drop_nulls().cast(pl.Float64).to_numpy()
    return math.sqrt(float((v**2).mean())) if v.size else float("nan")


def _yang_table1(df: pl.DataFrame) -> list[PaperRow]:
    src = "yang2017_table1.csv"
    oe = df["oe_from_printed_d_b_mm"].drop_nulls()
    d_b = df["diff_d_b_oe_printed_um"].abs().max()
    r = ", ".join(f"{v:+.0f}" for v in df["diff_r_oe_printed_um"].to_list())
    cond = df["dr_dd_min"].abs()
    rounding = df["r_round_bound_um"] / 1e3
    return [
        PaperRow(
            "Yang 2017",
            "Eq. 9: oe = 2.3222 mm",
            f"the printed d_b imply oe = {oe.min():.6f}-{oe.max():.6f} mm",
            "the printed d_b agree with each other; Eq. 9 with the printed P1, P0 differs in the 4th decimal",
            src,
        ),
        PaperRow("Yang 2017", "Table 1 d_b", f"within {d_b:.1f} µm (with the printed oe)", "reproduced", src),
        PaperRow(
            "Yang 2017",
            "Table 1 r",
            f"{r} µm from the printed r",
            f"r is badly conditioned: dr/dd_min = {cond.min():.0f}-{cond.max():.0f} mm/mm, so rounding the "
            f"printed readings by half a digit moves r by {rounding.min():.2f}-{rounding.max():.1f} mm",
            src,
        ),
    ]


def _yang_table2(df: pl.DataFrame) -> list[PaperRow]:
    row = df.filter((pl.col("quantity") == "samples_per_rev") & pl.col("channel").is_null()).row(
        0, named=True
    )
    return [
        PaperRow(
            "Yang 2017",
            f"§3.2: {float(row['printed']):.0f} samples per revolution",
            f"{float(row['computed']):.2f} ± {float(row['u_computed']):.2f} from Table 2's own sample "
            "numbers",
            "θ_t (Eq. 15) with the printed value is several degrees too large",
            "yang2017_table2.csv",
        )
    ]


def _yang_table3(df: pl.DataFrame, alternatives: pl.DataFrame) -> list[PaperRow]:
    best = alternatives.sort("rms_um").row(0, named=True)
    theta_c = "no θ_c" if best["theta_c"] == "none" else f"θ_c {best['theta_c']}"
    return [
        PaperRow(
            "Yang 2017",
            "Table 3 diameters",
            f"reproduced to {best['rms_um']:.2f} µm RMS only with θ = θ_t, {theta_c} and N = {best['N']:.0f} "
            f"(best of {alternatives.height} readings); Eq. 14 as written misses by "
            f"{_rms(df['literal_eq14_diff_um']):.0f} µm RMS",
            "the printed table was not computed as the text says",
            "yang_table3.csv",
        )
    ]


def _wang(df: pl.DataFrame) -> list[PaperRow]:
    return [
        PaperRow(
            "Wang 2017", f"{r['item']}: {r['paper']}", r["reproduced"], r["note"] or "", "wang_statements.csv"
        )
        for r in df.iter_rows(named=True)
    ]


#: The reproductions the table reads: files under papers/ -> the rows they give.
_SOURCES: tuple[tuple[tuple[str, ...], Callable[..., list[PaperRow]]], ...] = (
    (("yang2017_table1.csv",), _yang_table1),
    (("yang2017_table2.csv",), _yang_table2),
    (("yang_table3.csv", "yang_table3_alternatives.csv"), _yang_table3),
    (("wang_statements.csv",), _wang),
)


def papers_rows(papers_dir: Path) -> list[PaperRow]:
    """Return the printed | ours | why rows of the reproductions found in ``papers_dir``."""
    rows: list[PaperRow] = []
    for files, make in _SOURCES:
        paths = [papers_dir / f for f in files]
        if not all(p.is_file() for p in paths):
            continue
        try:
            rows += make(*(pl.read_csv(p) for p in paths))
        except (pl.exceptions.PolarsError, KeyError, ValueError, IndexError, TypeError):
            continue  # a reproduction of another shape (an older results folder): its CSV is listed below
    return rows
