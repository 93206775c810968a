"""The Parts section: diameters with U, nominal, tolerance and verdict."""

from __future__ import annotations


import polars as pl

from borescan.report.data import group_fingerprints
from borescan.report.page import Page, _EMPTY
from borescan.report.plots import plot_diameters
from borescan.report.text import _e, _mm, _table, _temperature, _um, _verdict_cell


def part_rows(page: Page) -> pl.DataFrame:
    """Return the month's diameter rows with nominal, tolerance and verdict.

    Return the month's diameter rows with ``nominal_mm`` (the row's ``nominal_diameter_mm``, else the
    part's from ``artifacts``), ``tolerance_mm`` (the row's, when the measure stage records one),
    ``deviation_mm`` (at 20 °C where known, else as measured, minus the nominal) and
    ``in_tolerance`` (|deviation| <= tolerance; null without a tolerance).
    """
    dia = page.t["diameters"]
    cols = set(dia.columns)
    nominal = [
        pl.col(c).cast(pl.Float64) for c in ("nominal_diameter_mm", "artifact_nominal_mm") if c in cols
    ]
    value = pl.col("diameter_mm").cast(pl.Float64)
    if "diameter_20_mm" in cols:
        value = pl.coalesce(pl.col("diameter_20_mm").cast(pl.Float64), value)
    dia = dia.with_columns(
        (pl.coalesce(nominal) if nominal else pl.lit(None, dtype=pl.Float64)).alias("nominal_mm"),
        (
            pl.col("tolerance_mm").cast(pl.Float64)
            if "tolerance_mm" in cols
            else pl.lit(None, dtype=pl.Float64)
        ).alias("tolerance_mm"),
        value.alias("_value_mm"),
    )
    return dia.with_columns((pl.col("_value_mm") - pl.col("nominal_mm")).alias("deviation_mm")).with_columns(
        (pl.col("deviation_mm").abs() <= pl.col("tolerance_mm")).alias("in_tolerance")
    )


def _parts_table(df: pl.DataFrame) -> str:
    rows, classes = [], []
    for r in df.iter_rows(named=True):
        big_u, k = r.get("expanded_u_diameter_20_mm"), r.get("k")
        if big_u is None and r.get("u_diameter_mm") is not None:
            big_u, k = 2.0 * r["u_diameter_mm"], 2.0
        ok = r.get("in_tolerance")
        verdict, verdict_class = _verdict_cell(r.get("conformity"), ok, ("in tolerance", "OUT OF TOLERANCE"))
        rows.append(
            [
                _e(r.get("night")),
                _e(r.get("scan_id")),
                _e(r["artifact_id"]),
                _e(r.get("feature")),
                _mm(r.get("diameter_mm")),
                _temperature(r.get("temperature_c"), r.get("temperature_assumed")),
                _mm(r.get("diameter_20_mm")),
                _um(big_u, 2),
                "" if k is None else f"{k:.2f}",
                "" if r.get("coverage_probability") is None else f"{r['coverage_probability']:.4f}",
                _mm(r.get("nominal_mm")),
                _um(r.get("deviation_mm")),
                _um(r.get("tolerance_mm")),
                verdict,
                _e(r.get("calibration_id")),
            ]
        )
        classes.append(verdict_class or ("warn" if r.get("temperature_assumed") else ""))
    return _table(
        [
            "night",
            "scan",
            "part",
            "feature",
            "diameter at T [mm]",
            "T [°C]",
            "diameter at 20 °C [mm]",
            "U [µm]",
            "k",
            "coverage",
            "nominal [mm]",
            "deviation [µm]",
            "tolerance ± [µm]",
            "verdict",
            "calibration",
        ],
        rows,
        classes,
        num_cols={4, 5, 6, 7, 8, 9, 10, 11, 12},
    )


def _part_statistics_and_rows(sub: pl.DataFrame) -> str:
    """Return a part's statistics per feature (n, mean, sd, min, max) and its rows (HTML)."""
    stats = (
        sub.group_by("feature")
        .agg(
            pl.len().alias("n"),
            pl.col("_value_mm").mean().alias("mean"),
            pl.col("_value_mm").std().alias("sd"),
            pl.col("_value_mm").min().alias("min"),
            pl.col("_value_mm").max().alias("max"),
        )
        .sort("feature")
    )
    rows = [
        [_e(r["feature"]), str(r["n"]), _mm(r["mean"]), _um(r["sd"], 2), _mm(r["min"]), _mm(r["max"])]
        for r in stats.iter_rows(named=True)
    ]
    return _table(
        ["feature", "n", "mean [mm]", "sd [µm]", "min [mm]", "max [mm]"], rows, num_cols={1, 2, 3, 4, 5}
    ) + _parts_table(sub)


def diameters(page: Page) -> str:
    """Return the Parts section: diameters at T and at 20 °C with U, nominal, tolerance and verdict."""
    dia = page.t["diameters"]
    if dia.height == 0:
        return _EMPTY["diameters"]
    dia = part_rows(page).with_columns(pl.col("artifact_id").fill_null("?"))
    out = [
        '<p class="note">Diameters as measured at the temperature T and brought to 20 °C (ISO 1); '
        "U is the "
        "expanded uncertainty of the diameter at 20 °C with its coverage factor k and coverage "
        "probability "
        '(U = 2u, k = 2 where the catalog has no budget). "(assumed)": no temperature was recorded, '
        "20 °C assumed. Deviation = diameter at 20 °C − nominal; the verdict needs a part tolerance.</p>"
    ]
    if dia["nominal_mm"].drop_nulls().len() == 0:
        out.append(
            '<p class="note">No nominal diameter in the catalog for these parts (feature nominals of '
            "scan.json are not recorded in the diameters table).</p>"
        )
    counts = dia.group_by("artifact_id", "feature").len().group_by("artifact_id").agg(pl.col("len").max())
    once = set(counts.filter(pl.col("len") < 2)["artifact_id"].to_list())
    if once:  # a single value per feature has no distribution: one table for all such parts
        single = dia.filter(pl.col("artifact_id").is_in(sorted(once))).sort(
            "artifact_id", "feature", "scan_id"
        )
        out.append(f"<h3>Parts measured once ({len(once)})</h3>")
        out.append(_parts_table(single))
    keys = group_fingerprints(dia, "artifact_id")  # a part's tables: rendered again when its rows change
    for part in sorted(set(dia["artifact_id"].unique().to_list()) - once):
        sub = dia.filter(pl.col("artifact_id") == part)
        out.append(f"<h3>Part {_e(part)}</h3>")
        out.append(page.figure(plot_diameters, sub, part, f"diameters_{part}", f"diameters of {part}"))
        out.append(
            page.piece(
                "part tables", f"{part} {keys.get(part)}", lambda sub=sub: _part_statistics_and_rows(sub)
            )
        )
    return "".join(out)
