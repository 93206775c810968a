"""Issue 21: the catalog and the report grow night by night; the result equals a full rebuild."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import duckdb
import polars as pl
import pytest
from test_catalog import make_history

from borescan import catalog
from borescan.report.pages import update_report
from borescan.synthetic import history as sh
from borescan.cli import main as cli_main


def _snapshot(path: Path) -> dict:
    """Every catalog table in key order, its columns, and every saved query's rows."""
    con = duckdb.connect(str(path), read_only=True)
    try:
        tables = {t: catalog.table_rows(con, t) for t in catalog.SCHEMA}
        cols = {t: [r[0] for r in con.execute(f"DESCRIBE {t}").fetchall()] for t in catalog.SCHEMA}
        views = {
            q: sorted(con.execute(f"SELECT * FROM {q}").fetchall(), key=repr) for q in catalog.saved_queries()
        }
    finally:
        con.close()
    return {"tables": tables, "columns": cols, "views": views}


def _rebuilt(res: Path, tmp: Path) -> dict:
    """Return the catalog a full rebuild gives from the same stage files (built in a copy of the folder)."""
    copy = tmp / f"rebuild-{time.monotonic_ns()}"
    shutil.copytree(
        res, copy, copy_function=os.link, ignore=shutil.ignore_patterns("catalog.duckdb*", "report*")
    )
    update = catalog.rebuild_catalog(copy)
    assert update.mode == "full"
    return _snapshot(copy / "catalog.duckdb")


# --------------------------------------------------------------------------- constructed nights

NIGHT_OF_OCTOBER = {"2026-11-20": "2026-10-30"}  # the first night moved to another month


def _write_stage(
    res: Path, tables: dict[str, pl.DataFrame], nights: list[str], remap: dict[str, str]
) -> None:
    """Write the constructed history as the stage files of ``nights``, each night's rows in its own file
    (nights renamed by ``remap``; rows without a night follow their scan, artifacts the first night).
    """
    moved = pl.col("night").replace(remap)
    scans = tables["scans"].with_columns(
        pl.coalesce(
            [
                pl.when(pl.col("night") == old).then(pl.col("started_at").str.replace(old, new))
                for old, new in remap.items()
            ]
            + [pl.col("started_at")]
        ).alias("started_at"),
        moved,
    )
    night_of = dict(zip(scans["scan_id"], scans["night"], strict=True))
    cal_night = {
        r["calibration_id"]: night_of[r["scan_id"]] for r in tables["calibrations"].iter_rows(named=True)
    }
    of_scan = pl.col("scan_id").replace_strict(night_of).alias("_n")
    by_table = {
        "scans": scans.with_columns(pl.col("night").alias("_n")),
        "scan_files": tables["scan_files"].with_columns(moved).with_columns(pl.col("night").alias("_n")),
        "quarantine/stage=ingest": tables["quarantine"]
        .with_columns(moved)
        .with_columns(pl.col("night").alias("_n")),
        "calibration_scans": tables["calibration_scans"].with_columns(
            pl.col("calibration_id").replace_strict(cal_night).alias("_n")
        ),
        "artifacts": tables["artifacts"].with_columns(pl.lit(min(night_of.values())).alias("_n")),
    }
    for name in ("calibrations", "diameters", "verifications", "findings"):
        by_table[name] = tables[name].with_columns(of_scan)  # the stages leave the night out of these
    for name, df in by_table.items():
        for night in nights:
            out = res / "stage" / name / f"night={night}.parquet"
            out.parent.mkdir(parents=True, exist_ok=True)
            df.filter(pl.col("_n") == night).drop("_n").write_parquet(out)


@pytest.fixture()
def staged(tmp_path):
    res = tmp_path / "results"
    tables = make_history(res)
    return res, tables


def test_nightly_updates_equal_a_rebuild_and_read_only_new_nights(staged, tmp_path):
    res, tables = staged
    nights = ["2026-10-30", "2026-11-21", "2026-11-22"]
    _write_stage(res, tables, nights[:1], NIGHT_OF_OCTOBER)
    first = catalog.update_catalog(res)
    assert first.mode == "full" and first.reason == "no catalog to extend"
    _write_stage(res, tables, nights[1:2], NIGHT_OF_OCTOBER)
    second = catalog.update_catalog(res)
    assert (second.mode, second.added, second.removed) == ("append", ("2026-11-21",), ())
    assert _snapshot(res / "catalog.duckdb") == _rebuilt(res, tmp_path)
    _write_stage(res, tables, nights[2:], NIGHT_OF_OCTOBER)
    third = catalog.update_catalog(res)
    assert third.added == ("2026-11-22",)
    snap = _snapshot(res / "catalog.duckdb")
    assert snap == _rebuilt(res, tmp_path)
    # the derived columns were filled within each night
    con = catalog.open_catalog(res)
    assert con.execute(
        "SELECT night::VARCHAR, raw_sha256 IS NOT NULL FROM diameters WHERE scan_id = 'PART-8'"
    ).fetchone() == ("2026-11-22", True)
    assert con.execute("SELECT count(*) FROM build.sources WHERE night = '2026-11-22'").fetchone()[0] == 9
    con.close()
    assert catalog.update_catalog(res).mode == "unchanged"
    assert _snapshot(res / "catalog.duckdb") == snap


def test_replacing_or_removing_the_newest_night_equals_a_rebuild(staged, tmp_path):
    res, tables = staged
    nights = ["2026-10-30", "2026-11-21", "2026-11-22"]
    _write_stage(res, tables, nights, NIGHT_OF_OCTOBER)
    catalog.update_catalog(res)
    # the newest night re-run with another result: its rows are replaced
    f = res / "stage" / "artifacts" / "night=2026-11-22.parquet"
    pl.DataFrame(
        {"artifact_id": ["RG-275"], "type": ["ring_gauge"], "certified_diameter_mm": [275.031]}
    ).write_parquet(f)
    redo = catalog.update_catalog(res)
    assert (redo.mode, redo.added, redo.removed) == ("append", ("2026-11-22",), ("2026-11-22",))
    assert _snapshot(res / "catalog.duckdb") == _rebuilt(res, tmp_path)
    con = catalog.open_catalog(res)
    assert con.execute(
        "SELECT certified_diameter_mm FROM artifacts WHERE artifact_id='RG-275'"
    ).fetchone() == (275.031,)
    con.close()
    # the newest night gone: the artifact falls back to its earlier record, links of the night go
    for g in res.glob("stage/**/night=2026-11-22.parquet"):
        g.unlink()
    gone = catalog.update_catalog(res)
    assert (gone.mode, gone.added, gone.removed) == ("append", (), ("2026-11-22",))
    snap = _snapshot(res / "catalog.duckdb")
    assert snap == _rebuilt(res, tmp_path)
    assert not [r for r in snap["tables"]["calibration_scans"] if r[0] == "CAL-B"]
    assert [r[4] for r in snap["tables"]["artifacts"]] == [275.029]


def test_an_older_night_changed_rebuilds_everything(staged, tmp_path):
    res, tables = staged
    _write_stage(res, tables, ["2026-10-30", "2026-11-21", "2026-11-22"], NIGHT_OF_OCTOBER)
    catalog.update_catalog(res)
    f = res / "stage" / "findings" / "night=2026-10-30.parquet"
    df = pl.read_parquet(f).with_columns(pl.col("gap_before_mm") * 2)
    df.write_parquet(f)
    update = catalog.update_catalog(res)
    assert update.mode == "full"
    assert "night 2026-10-30 changed" in update.reason and "2026-11-22" in update.reason
    assert _snapshot(res / "catalog.duckdb") == _rebuilt(res, tmp_path)
    con = catalog.open_catalog(res)
    assert con.execute("SELECT gap_before_mm FROM findings WHERE scan_id='PART-7'").fetchone()[
        0
    ] == pytest.approx(0.0122)
    con.close()


def test_a_stage_column_first_seen_in_a_later_night_is_added(staged, tmp_path):
    res, tables = staged
    _write_stage(res, tables, ["2026-10-30", "2026-11-21"], NIGHT_OF_OCTOBER)
    catalog.update_catalog(res)
    _write_stage(res, tables, ["2026-11-22"], NIGHT_OF_OCTOBER)
    f = res / "stage" / "verifications" / "night=2026-11-22.parquet"
    pl.read_parquet(f).with_columns(pl.lit(0.0004).alias("u_gauge_extra_mm")).write_parquet(f)
    assert catalog.update_catalog(res).mode == "append"
    snap = _snapshot(res / "catalog.duckdb")
    assert snap == _rebuilt(res, tmp_path)
    assert snap["columns"]["verifications"][-1] == "u_gauge_extra_mm"


def test_a_row_of_another_night_in_a_stage_file_is_refused(staged):
    res, tables = staged
    _write_stage(res, tables, ["2026-10-30"], NIGHT_OF_OCTOBER)
    f = res / "stage" / "scans" / "night=2026-10-30.parquet"
    pl.read_parquet(f).with_columns(pl.lit("2026-10-29").alias("night")).write_parquet(f)
    with pytest.raises(ValueError, match=r"night=2026-10-30\.parquet: rows of night 2026-10-29"):
        catalog.update_catalog(res)
    assert not (res / "catalog.duckdb").exists() and not (res / "catalog.duckdb.tmp").exists()


def test_catalog_from_given_tables_is_rebuilt_by_the_next_update(staged):
    res, tables = staged
    catalog.build_catalog(res, tables)
    _write_stage(res, tables, ["2026-10-30"], NIGHT_OF_OCTOBER)
    update = catalog.update_catalog(res)
    assert update.mode == "full" and "given tables" in update.reason
    assert update.rows["scans"] == 4


def test_rebuild_catalog_command(staged, capsys):
    res, tables = staged
    _write_stage(res, tables, ["2026-10-30", "2026-11-21"], NIGHT_OF_OCTOBER)
    assert cli_main(["rebuild-catalog", "--results", str(res)]) == 0
    out = capsys.readouterr().out
    assert "full rebuild" in out and "2 night(s)" in out and "scans: 8 rows" in out
    assert cli_main(["rebuild-catalog", "--results", str(res / "nothing-here")]) == 1
    assert "no stage tables" in capsys.readouterr().err


def test_a_failed_verification_updates_the_earlier_month_page(staged):
    """PART-7 (October) used CAL-A; CAL-A fails its verification in November: October's page is
    rendered again and lists PART-7 as in doubt, without drawing October's plots again.
    """
    res, tables = staged
    _write_stage(res, tables, ["2026-10-30"], NIGHT_OF_OCTOBER)
    catalog.update_catalog(res)
    first = update_report(res)
    assert first.rendered == ("2026-10",)
    october = res / "report" / "2026-10" / "index.html"
    doubt = october.read_text().split("Measurements put in doubt")[1].split("</section>")[0]
    assert "PART-7" not in doubt
    plots_before = {p.name: p.stat().st_mtime_ns for p in october.parent.glob("*.png")}
    _write_stage(res, tables, ["2026-11-21"], NIGHT_OF_OCTOBER)
    catalog.update_catalog(res)
    second = update_report(res)
    assert second.rendered == ("2026-10", "2026-11")
    doubt = october.read_text().split("Measurements put in doubt")[1].split("</section>")[0]
    assert "PART-7" in doubt and "VER-21" in doubt
    assert {p.name: p.stat().st_mtime_ns for p in october.parent.glob("*.png")} == plots_before
    # the summary shows the latest month and links every month's page
    summary = (res / "report.html").read_text()
    assert "Calibration · 2026-11" in summary and 'href="report/2026-10/index.html"' in summary
    third = update_report(res)
    assert (third.rendered, third.plots_drawn) == ((), 0)


# --------------------------------------------------------------------------- the demo plus added nights


@pytest.mark.slow
def test_demo_plus_added_nights_incremental_equals_rebuild(pipeline_run, tmp_path):
    """The demo nights and the bad-input night processed by Snakemake, then six synthetic nights
    across a month boundary: night-by-night catalog and report equal a full rebuild and a full
    re-render, and a new December night leaves November's page and plots alone.
    """
    src_res = pipeline_run["results"]
    assert pipeline_run["proc"].returncode == 0
    res = tmp_path / "results"
    for sub in ("calibration", "discrepancy", "quarantine", "papers"):
        if (src_res / sub).is_dir():
            shutil.copytree(src_res / sub, res / sub, copy_function=os.link)
    demo_nights = sorted(catalog.stage_files(src_res))
    for night in demo_nights:
        for f in src_res.glob(f"stage/**/night={night}.parquet"):
            if f.parts[-2] in ("extrema", "signal_summary"):
                continue
            target = res / f.relative_to(src_res)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.link(f, target)
        update = catalog.update_catalog(res)
        assert update.added == (night,)
        update_report(res)
    src = sh.read_source(src_res)
    pool = tmp_path / "pool"
    added = sh.copy_nights(src, res, "2026-11-28", range(6), stage_root=pool)
    assert added[-1] == "2026-12-03"
    updates = []
    for night in added:
        for f in pool.glob(f"stage/**/night={night}.parquet"):
            target = res / f.relative_to(pool)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(f, target)
        assert catalog.update_catalog(res).mode == "append"
        updates.append(update_report(res))
    assert updates[-1].rendered == ("2026-12",)
    november = {p.name: p.stat().st_mtime_ns for p in (res / "report" / "2026-11").iterdir()}
    # the newest night re-run: replaced in the catalog, December's page only
    for f in res.glob(f"stage/**/night={added[-1]}.parquet"):
        f.touch()
    redo = catalog.update_catalog(res)
    assert (redo.added, redo.removed) == ((added[-1],), (added[-1],))
    assert update_report(res).rendered == ()  # the same rows: nothing to draw
    assert {p.name: p.stat().st_mtime_ns for p in (res / "report" / "2026-11").iterdir()} == november

    snap = _snapshot(res / "catalog.duckdb")
    assert snap == _rebuilt(res, tmp_path)
    n_scans = len(snap["tables"]["scans"])
    assert n_scans == sum(pl.read_parquet(f).height for f in res.glob("stage/scans/night=*.parquet"))
    # the report drawn night by night equals one drawn from scratch
    pages = {
        p.relative_to(res).as_posix(): p.read_bytes()
        for p in [res / "report.html", *sorted((res / "report").rglob("*"))]
        if p.is_file()
    }
    update_report(res, full=True)
    again = {
        p.relative_to(res).as_posix(): p.read_bytes()
        for p in [res / "report.html", *sorted((res / "report").rglob("*"))]
        if p.is_file()
    }
    assert pages == again
    assert {"report/2026-11/index.html", "report/2026-12/index.html"} <= set(pages)


@pytest.mark.slow
def test_the_workflow_extends_the_catalog_it_keeps(pipeline_run, tmp_path):
    """build_catalog's output is update()-flagged: Snakemake does not delete the catalog before
    the job, so a forced rerun finds it and has nothing to add (a deleted one is rebuilt in full).
    """
    from conftest import run_snakemake

    res = tmp_path / "results"
    shutil.copytree(
        pipeline_run["results"], res, copy_function=os.link, ignore=shutil.ignore_patterns("catalog.duckdb*")
    )
    shutil.copyfile(pipeline_run["results"] / "catalog.duckdb", res / "catalog.duckdb")
    before = _snapshot(res / "catalog.duckdb")
    proc = run_snakemake(pipeline_run["raw"], res, "--forcerun", "build_catalog", "--until", "build_catalog")
    assert proc.returncode == 0, proc.stderr[-3000:]
    log = (res / "logs" / "build_catalog.log").read_text()
    assert "unchanged: no stage file changed" in log, log
    assert _snapshot(res / "catalog.duckdb") == before


def test_synthetic_nights_move_a_calibrations_due_date_with_its_night(tmp_path):
    """A copied calibration falls due as long after its new night as the source's after its own (a due
    date left behind would make every synthetic calibration expire in the source's month).
    """
    src_root, dest = tmp_path / "src", tmp_path / "dest"
    for name, df in {
        "scans": pl.DataFrame({"scan_id": ["S-20261120"], "night": ["2026-11-20"], "device_id": ["D"]}),
        "calibrations": pl.DataFrame(
            {
                "calibration_id": ["D-20261120-x"],
                "night": ["2026-11-20"],
                "valid_from": ["2026-11-20"],
                "recalibration_due": ["2026-12-20"],
            }
        ),
    }.items():
        (src_root / "stage" / name).mkdir(parents=True)
        df.write_parquet(src_root / "stage" / name / "night=2026-11-20.parquet")
    nights = sh.copy_nights(sh.read_source(src_root), dest, "2027-03-01", [40])
    assert nights == ["2027-04-10"]
    cal = pl.read_parquet(dest / "stage" / "calibrations" / "night=2027-04-10.parquet")
    assert cal.row(0, named=True) == {
        "calibration_id": "D-20270410-x",
        "night": "2027-04-10",
        "valid_from": "2027-04-10",
        "recalibration_due": "2027-05-10",  # 30 days after, as 2026-12-20 is after 2026-11-20
    }


def test_a_calibrations_record_changed_alone_is_seen_by_its_digest(staged):
    """The catalog keeps each calibration record's SHA-256 beside it (``calibration_json_sha256``), and the
    report's month fingerprints hash the digest instead of the record: a record changed alone still renders
    its month again (and no other), and tables given without the digest (catalog.with_record_digest)
    fingerprint the months as the same tables with the catalog's digest.
    """
    import hashlib

    from borescan.report import data

    res, tables = staged
    nights = ["2026-10-30", "2026-11-21", "2026-11-22"]

    def with_records(tag: str) -> dict[str, pl.DataFrame]:
        record = pl.concat_str(
            pl.lit('{"calibration_id": "'), "calibration_id", pl.lit(f'", "note": "{tag}"}}')
        )
        cal = tables["calibrations"].with_columns(record.alias("calibration_json"))
        return {**tables, "calibrations": cal}

    _write_stage(res, with_records("first"), nights, NIGHT_OF_OCTOBER)
    catalog.update_catalog(res)
    assert update_report(res).rendered == ("2026-10", "2026-11")
    con = catalog.open_catalog(res)
    rows = con.execute(
        "SELECT calibration_json, calibration_json_sha256, sha256(calibration_json) FROM calibrations"
    ).fetchall()
    file_prints = data.month_fingerprints(con)
    con.close()
    assert len(rows) == tables["calibrations"].height == 7
    assert all(d == hashlib.sha256(j.encode()).hexdigest() == s for j, d, s in rows)
    assert set(file_prints) == {"2026-10", "2026-11"}
    loaded = data.load_tables(res)
    prints = []
    for given in (loaded, {**loaded, "calibrations": loaded["calibrations"].drop("calibration_json_sha256")}):
        mem = data._memory_catalog(given)
        prints.append(data.month_fingerprints(mem))
        mem.close()
    assert prints[0] == prints[1]
    # CAL-B (the newest night, November) gets another record, every other column the same
    changed = with_records("first")
    changed["calibrations"] = changed["calibrations"].with_columns(
        pl.when(pl.col("calibration_id") == "CAL-B")
        .then(pl.col("calibration_json").str.replace("first", "second"))
        .otherwise(pl.col("calibration_json"))
        .alias("calibration_json")
    )
    _write_stage(res, changed, nights[2:], NIGHT_OF_OCTOBER)
    update = catalog.update_catalog(res)
    assert (update.mode, update.removed, update.added) == ("append", ("2026-11-22",), ("2026-11-22",))
    assert update_report(res).rendered == ("2026-11",)
    assert update_report(res).rendered == ()
