"""Whole nights never crash, and the raw root decides what runs (issue 40), built from the demo nights.

The slow tests run the real workflow: on a raw root of the faults that once crashed whole nights
(``fault_roots.make_crash_root``: rod only, a refused first three-sensor calibration, an empty night,
``night=2026-02-30``, files written with umask 077 by another user), as the user nobody where the
machine allows it; and from a second checkout with no record of the results root, after a night
is added with its old file times (``cp -a``), and on a copied results root.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import duckdb
import polars as pl
import pyarrow as pa
import pytest

from conftest import ROOT, checksums
from fault_roots import (
    as_nobody,
    can_drop_to_nobody,
    checkout_copy,
    copy_scan,
    give_to_nobody,
    make_crash_root,
)

from borescan import raw_index, rawio, tables, validation
from borescan.synthetic import demo
from borescan.stages import _common
from borescan.stages.catalog import HistoryGapError, raw_coverage, stage_catalog
from borescan.stages.ingest import stage_ingest
from borescan.stages.pooled import stage_pooled


@pytest.fixture(scope="module")
def demo_raw(tmp_path_factory):
    base = tmp_path_factory.mktemp("demo")
    demo.make_demo(base)
    return base / "raw"


# ------------------------------------------------------------------------- fast: the stage functions


def test_conform_gives_every_column_of_the_table():
    rod_only = pl.DataFrame(
        {"calibration_id": ["R"], "channel": [1], "l0_mm": [80.0], "calibration_json": ["{}"]}
    )
    c = tables.conform("calibrations", rod_only)
    assert list(c.columns)[: len(tables.polars_schema("calibrations"))] == list(
        tables.polars_schema("calibrations")
    )
    assert c["beta_rad"].to_list() == [None] and c["l0_mm"].to_list() == [80.0]
    assert c.columns[-1] == "calibration_json"  # a stage's extra column kept, after the table's
    empty = tables.conform("scans", pl.DataFrame())
    assert empty.height == 0 and empty.schema == pl.Schema(tables.polars_schema("scans"))


def test_pooled_stage_with_rod_calibrations_only_and_with_an_empty_night(tmp_path):
    """Issue 40 items 5, 6: rod calibrations and no three-sensor one; a night without scans."""
    rod_cal = tmp_path / "cal.parquet"
    _common.write_table(
        pl.DataFrame(
            {
                "calibration_id": ["ROD-01-nominal"],
                "device_id": ["ROD-01"],
                "device_type": ["rod"],
                "channel": [1],
                "l0_mm": [80.0],
                "valid_from": ["2026-11-20"],
                "method": ["nominal"],
            }
        ),
        rod_cal,
    )
    empty_scans = tmp_path / "scans.parquet"
    _common.write_table(tables.frame("scans", []), empty_scans)
    findings, drift = stage_pooled(
        tmp_path / "raw", "2026-11-20", tmp_path, [empty_scans], [rod_cal], {}, log=lambda _: None
    )
    assert findings.height == 0 and drift.height == 0
    assert drift.schema == pl.Schema(tables.polars_schema("calibration_drift"))
    assert _common.ok_scans(pl.DataFrame()).height == 0  # no columns at all (a table of an empty night)


def test_nights_leave_out_an_impossible_date_and_name_it(tmp_path, demo_raw):
    raw = tmp_path / "raw"
    copy_scan(demo_raw / "night=2026-11-20" / "scan=N20261120-ROD01-MEAS-CYL2H", raw, "2026-02-30", "R1")
    copy_scan(demo_raw / "night=2026-11-20" / "scan=N20261120-ROD01-MEAS-CYL2H", raw, "2026-11-20", "R2")
    assert rawio.nights(raw) == ["2026-11-20"]
    report = validation.validate_tree(raw)
    assert [str(e) for e in report.problems] == [
        "-: night=2026-02-30: folder night is not a date YYYY-MM-DD; its scans are not processed"
    ]


def test_an_unreadable_raw_file_quarantines_its_scan_and_the_night_goes_on(tmp_path, demo_raw, monkeypatch):
    """Check that a scan whose file cannot be read is quarantined naming the file; the others pass.

    Issue 40 item 8 inside one process: reading or hashing a file raises PermissionError (as for a
    file another user wrote with umask 077).
    (The workflow as a user who cannot read the file: test_crash_root_workflow_as_a_user_who_is_not_root.)
    """
    raw, res = tmp_path / "raw", tmp_path / "res"
    src = demo_raw / "night=2026-11-20"
    for d in sorted(src.glob("scan=*ROD01*")):
        copy_scan(d, raw, "2026-11-20", d.name[5:])
    locked = raw / "night=2026-11-20" / "scan=N20261120-ROD01-MEAS-CYL2H" / "lds.parquet"
    real_hash, real_osfile = rawio.sha256_file, pa.OSFile

    def refused(path) -> bool:
        return Path(path) == locked

    def sha256_file(path):
        if refused(path):
            raise PermissionError(13, "Permission denied", str(path))
        return real_hash(path)

    def osfile(path, *a, **k):
        if refused(path):
            raise PermissionError(13, "Permission denied", str(path))
        return real_osfile(path, *a, **k)

    monkeypatch.setattr(rawio, "sha256_file", sha256_file)
    monkeypatch.setattr(pa, "OSFile", osfile)
    scans, files, bad = stage_ingest(raw, "2026-11-20", res)
    status = dict(zip(scans["scan_id"], scans["status"]))
    assert status == {
        "N20261120-ROD01-CAL-RGS150": "ok",
        "N20261120-ROD01-MEAS-CYL2H": "quarantined",
        "N20261120-ROD01-VER-RGS150": "ok",
    }
    assert [(q.scan_id, q.file, q.reason) for q in bad] == [
        ("N20261120-ROD01-MEAS-CYL2H", "lds.parquet", "unreadable: Permission denied")
    ]
    assert "lds.parquet" not in set(files.filter(pl.col("scan_id") == "N20261120-ROD01-MEAS-CYL2H")["file"])


def test_raw_index_changes_with_the_scans_not_with_a_rerun(tmp_path, demo_raw):
    """A scan added with its old times rewrites the night's manifest (now-dated); nothing else does."""
    raw, res = tmp_path / "raw", tmp_path / "res"
    src = demo_raw / "night=2026-11-20"
    shutil.copytree(
        src / "scan=N20261120-ROD01-CAL-RGS150", raw / "night=2026-11-20" / "scan=N20261120-ROD01-CAL-RGS150"
    )
    old_ns = 1_700_000_000 * 10**9
    for p in (raw / "night=2026-11-20").rglob("*"):
        os.utime(p, ns=(old_ns, old_ns))
    assert raw_index.refresh_raw_index(raw, res, ["2026-11-20"]) == []  # first manifest: the raw files' time
    index = raw_index.raw_index_path(res, "2026-11-20")
    assert index.stat().st_mtime_ns == old_ns
    assert raw_index.refresh_raw_index(raw, res, ["2026-11-20"]) == []  # unchanged: not rewritten
    subprocess.run(
        ["cp", "-a", str(src / "scan=N20261120-ROD01-MEAS-CYL2H"), str(raw / "night=2026-11-20")], check=True
    )
    assert raw_index.refresh_raw_index(raw, res, ["2026-11-20"]) == ["2026-11-20"]
    assert index.stat().st_mtime_ns > old_ns
    assert "scan=N20261120-ROD01-MEAS-CYL2H/lds.parquet" in index.read_text()


def test_catalog_step_fails_naming_scans_of_the_raw_root_the_history_lacks(tmp_path, demo_raw):
    raw, res = tmp_path / "raw", tmp_path / "res"
    for d in sorted((demo_raw / "night=2026-11-20").glob("scan=*ROD01*")):
        copy_scan(d, raw, "2026-11-20", d.name[5:])
    (raw / "night=2026-02-30").mkdir()
    scans, files, bad = stage_ingest(raw, "2026-11-20", res)
    stage = res / "stage"
    _common.write_table(scans, stage / "scans" / "night=2026-11-20.parquet")
    _common.write_table(files, stage / "scan_files" / "night=2026-11-20.parquet")
    lines: list[str] = []
    stage_catalog(res, raw_root=raw, log=lines.append)
    assert lines == [
        "SKIPPED night=2026-02-30: folder night is not a date YYYY-MM-DD; its scans are not processed",
        "every one of the 3 scans of the raw root is in the history",
    ]
    copy_scan(
        demo_raw / "night=2026-11-21" / "scan=N20261121-ROD01-VER-RGS150",
        raw,
        "2026-11-21",
        "N20261121-ROD01-VER-RGS150",
    )
    cov = raw_coverage(raw, res / "catalog.duckdb")
    assert cov.missing == ("night=2026-11-21/scan=N20261121-ROD01-VER-RGS150",) and cov.n_scans == 4
    with pytest.raises(
        HistoryGapError, match=r"lacks 1 of the 4 scans .*night=2026-11-21/scan=N20261121-ROD01-VER"
    ):
        stage_catalog(res, raw_root=raw, log=lines.append)


def test_quarantine_records_follow_the_catalog_with_names_that_never_collide(tmp_path, demo_raw):
    """Issue 40 item 3: a stale record is removed; folder ids longer than 64 characters, ``..`` and ``-``
    each get their own visible record.
    """
    raw, res = tmp_path / "raw", tmp_path / "res"
    rod = demo_raw / "night=2026-11-20" / "scan=N20261120-ROD01-MEAS-CYL2H"
    odd = ["L" * 70 + "A", "L" * 70 + "B", "..", "-"]
    for sid in ["N20261120-ROD01-MEAS-CYL2H", *odd]:
        copy_scan(rod, raw, "2026-11-20", sid)
    meta = raw / "night=2026-11-20" / "scan=-" / "scan.json"
    meta.write_text(meta.read_text().replace('"kind"', '"kind_typo"'))  # "-" is a valid id: make it bad
    scans, files, bad = stage_ingest(raw, "2026-11-20", res)
    assert sorted(q.scan_id for q in bad) == sorted(odd)
    for name, df in (
        ("scans", scans),
        ("scan_files", files),
        ("quarantine/stage=ingest", _common.quarantine_frame(bad)),
    ):
        _common.write_table(df, res / "stage" / name / "night=2026-11-20.parquet")
    (res / "quarantine" / "STALE-FROM-A-REVERTED-EDIT.json").write_text("{}")
    stage_catalog(res, raw_root=raw, log=lambda _: None)
    records = sorted((res / "quarantine").iterdir())
    assert len(records) == 4 and not any(p.name.startswith((".", "-")) for p in records)
    by_id = {__import__("json").loads(p.read_text())["scan_id"]: p.name for p in records}
    assert sorted(by_id) == sorted(odd)
    assert by_id[".."] == _common.quarantine_record_name("..", "2026-11-20") and by_id[".."].startswith(
        "scan-"
    )


# ------------------------------------------------------------------------- slow: the real workflow


def _python_for(user_cmd) -> list[str]:
    """Return a Python the user of ``user_cmd`` may execute with this venv's packages: this one, else the
    system's of the same version with this venv's site-packages on PYTHONPATH.
    """
    # through a shell, as Snakemake starts a job's script (setpriv itself may exec what a shell may not)
    if (
        subprocess.run(
            user_cmd(["/bin/sh", "-c", f"'{sys.executable}' -c pass"]), capture_output=True
        ).returncode
        == 0
    ):
        return [sys.executable], []
    system = shutil.which(f"python{sys.version_info.major}.{sys.version_info.minor}", path="/usr/bin:/bin")
    assert system, "no Python the unprivileged user can run"
    return [system], [p for p in sys.path if p.endswith("site-packages")]


def _workflow(checkout: Path, raw: Path, res: Path, home: Path, *extra: str, user=lambda c: c):
    python, site = _python_for(user)
    env = {
        "PATH": f"{Path(python[0]).parent}:/usr/bin:/bin",
        "HOME": str(home),
        "MPLBACKEND": "Agg",
        "PYTHONPATH": ":".join([str(checkout / "src"), *site]),
    }
    cmd = user(
        [
            *python,
            "-m",
            "snakemake",
            "--cores",
            "2",
            *extra,
            "--config",
            f"raw_root={raw}",
            f"results_root={res}",
        ]
    )
    return subprocess.run(cmd, cwd=checkout, capture_output=True, text=True, env=env, timeout=1500)


@pytest.fixture
def open_tmp():
    """Return a temporary folder every user can reach (pytest's are private to their user)."""
    path = Path(tempfile.mkdtemp(prefix="borescan-faults-"))
    path.chmod(0o755)
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.mark.slow
def test_crash_root_workflow_as_a_user_who_is_not_root(open_tmp, demo_raw):
    """Issue 40 items 5-8 through Snakemake: every night gets its tables and the catalog, each bad scan
    is quarantined naming its file or folder, the folders never processed are named, raw is untouched.
    """
    tmp_path = open_tmp
    root = make_crash_root(demo_raw, tmp_path / "raw")
    co = checkout_copy(ROOT, tmp_path / "checkout")
    res, home = tmp_path / "results", tmp_path / "home"
    res.mkdir(), home.mkdir()
    before = checksums(root.raw) if not can_drop_to_nobody() else None
    if can_drop_to_nobody():
        give_to_nobody(co, res, home)
        user = as_nobody
    else:  # not root: the umask-077 files are unreadable to this user already (chmod 0o600 by their owner)
        (root.raw / "night=2026-11-20" / f"scan={root.unreadable_file}" / "lds.parquet").chmod(0o000)
        (root.raw / "night=2026-11-20" / f"scan={root.unreadable_folder}").chmod(0o000)
        user = lambda c: c  # noqa: E731
    proc = _workflow(co, root.raw, res, home, "catalog", user=user)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    for night in ("2026-11-20", "2026-11-21", "2026-11-22"):
        for table in ("scans", "calibrations", "diameters", "pooled_findings", "calibration_drift"):
            assert (res / "stage" / table / f"night={night}.parquet").is_file(), (table, night)
    con = duckdb.connect(str(res / "catalog.duckdb"), read_only=True)
    rows = {
        s: (str(n), st, r)
        for s, n, st, r in con.execute("SELECT scan_id, night, status, reason FROM scans").fetchall()
    }
    assert {s: n for s, (n, _, _) in rows.items()} == root.expected_scans
    assert rows[root.unreadable_file][1:] == ("quarantined", "lds.parquet: unreadable: Permission denied")
    assert rows[root.unreadable_folder][1:] == (
        "quarantined",
        f"night=2026-11-20/scan={root.unreadable_folder}: cannot list the scan folder: Permission denied",
    )
    assert {s for s, (_, st, _) in rows.items() if st == "ok"} == {
        "N20261120-ROD01-CAL-RGS150",
        "N20261120-ROD01-MEAS-CYL2H",
        "N20261120-ROD01-VER-RGS150",
        "N20261121-ROD01-VER-RGS150",
    }  # the two refused calibration scans are quarantined by calibrate
    assert (
        con.execute("SELECT count(*) FROM diameters WHERE scan_id = 'N20261120-ROD01-MEAS-CYL2H'").fetchone()[
            0
        ]
        > 0
    )
    log = (res / "logs" / "build_catalog.log").read_text()
    assert (
        "SKIPPED night=2026-02-30: folder night is not a date YYYY-MM-DD; its scans are not processed" in log
    )
    assert "every one of the 8 scans of the raw root is in the history" in log
    if before is not None:
        assert checksums(root.raw) == before


def _rod_night(demo_raw: Path, raw: Path, night: str) -> None:
    """Return a night of the demo's rod scans only (the cheapest night that runs every stage), with its old
    file times (``cp -a``, as rsync -a or tar from a gauge PC copy them).
    """
    (raw / f"night={night}").mkdir(parents=True, exist_ok=True)
    for d in sorted((demo_raw / f"night={night}").glob("scan=*ROD01*")):
        subprocess.run(["cp", "-a", str(d), str(raw / f"night={night}")], check=True)


def _planned(proc) -> str:
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    return out


@pytest.mark.slow
def test_a_night_added_with_old_times_runs_from_a_checkout_without_records(tmp_path, demo_raw):
    """Issue 40 item 1 (both history cases): night 2026-11-20 processed from checkout A; night
    2026-11-21 added with ``cp -a``; checkout B (same code, its file times older than the results, no
    record of this results root in its .snakemake/) plans exactly the new night, and so does A on a
    copy of the results root. Before the fix B said "Nothing to be done" and the night never entered
    the history.
    """
    raw, res, home = tmp_path / "raw", tmp_path / "results", tmp_path / "home"
    home.mkdir()
    a, b = checkout_copy(ROOT, tmp_path / "A"), checkout_copy(ROOT, tmp_path / "B")
    _rod_night(demo_raw, raw, "2026-11-20")
    _planned(_workflow(a, raw, res, home, "catalog"))
    _rod_night(demo_raw, raw, "2026-11-21")
    copied = tmp_path / "copied-results"
    shutil.copytree(res, copied, symlinks=True)  # a results root moved or restored from a backup
    for name, checkout, results in (("second checkout", b, res), ("copied results root", a, copied)):
        out = _planned(_workflow(checkout, raw, results, home, "catalog", "--dry-run"))
        assert "Nothing to be done" not in out, name
        assert "registering the scans of night 2026-11-21" in out, name
        assert "registering the scans of night 2026-11-20" not in out, name  # the old night stays
        assert re.search(r"^ingest_night\s+1$", out, re.M), name
    out = _planned(_workflow(b, raw, res, home, "catalog"))
    con = duckdb.connect(str(res / "catalog.duckdb"), read_only=True)
    assert con.execute("SELECT count(*) FROM scans WHERE night = '2026-11-21'").fetchone()[0] == 2
    assert (
        "every one of the 5 scans of the raw root is in the history"
        in (res / "logs" / "build_catalog.log").read_text()
    )


def _verification_tolerances(res: Path) -> dict[str, set[float]]:
    return {
        f.name[6:16]: set(pl.read_parquet(f)["tolerance_mm"].to_list())
        for f in sorted((res / "stage" / "verifications").glob("night=*.parquet"))
    }


@pytest.mark.slow
def test_a_config_edit_applies_from_the_next_night_and_recompute_is_explicit(tmp_path, demo_raw):
    """Issue 40 item 2: after an edit of verification.tolerance_mm the past night is neither rerun nor
    rewritten (its stage tables byte-identical), the next night uses the new tolerance, each night's
    config hash is in the catalog; `borescan recompute --from` keeps the old results beside the new
    and records the change, and only then does the workflow recompute the past night.
    """
    raw, res, home = tmp_path / "raw", tmp_path / "results", tmp_path / "home"
    home.mkdir()
    a = checkout_copy(ROOT, tmp_path / "A")
    _rod_night(demo_raw, raw, "2026-11-20")
    _planned(_workflow(a, raw, res, home, "catalog"))
    past = checksums(res / "stage")
    cfg = a / "config" / "config.yaml"
    text = cfg.read_text()
    assert "  tolerance_mm: 0.015\n" in text
    cfg.write_text(text.replace("  tolerance_mm: 0.015\n", "  tolerance_mm: 0.03\n"))
    out = _planned(_workflow(a, raw, res, home, "catalog", "--dry-run"))
    assert "Nothing to be done" in out  # before the fix: calibrate and measure of the past night reran
    assert (
        "the config differs from the one nights 2026-11-20..2026-11-20 (1) were processed with "
        "(verification.tolerance_mm)" in out
    )
    _rod_night(demo_raw, raw, "2026-11-21")
    _planned(_workflow(a, raw, res, home, "catalog"))
    assert {k: v for k, v in checksums(res / "stage").items() if "2026-11-20" in k} == past
    assert _verification_tolerances(res) == {"2026-11-20": {0.015}, "2026-11-21": {0.03}}
    con = duckdb.connect(str(res / "catalog.duckdb"), read_only=True)
    hashes = dict(con.execute("SELECT strftime(night, '%Y-%m-%d'), config_hash FROM night_config").fetchall())
    con.close()
    assert sorted(hashes) == ["2026-11-20", "2026-11-21"] and hashes["2026-11-20"] != hashes["2026-11-21"]

    env = {**os.environ, "PYTHONPATH": str(a / "src")}
    proc = subprocess.run(
        [sys.executable, "-m", "borescan.cli", "recompute", "--from", "2026-11-20", "--results", str(res)],
        cwd=a,
        capture_output=True,
        text=True,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(
        "change-0001: 1 night(s) (2026-11-20..2026-11-20) will be recomputed with config "
        f"{hashes['2026-11-21']} (changed: verification.tolerance_mm)"
    )
    kept = res / "versions" / "change-0001"
    # the night's results are kept; its readings store (ingest's copy of the raw readings, no result) stays
    assert {k: v for k, v in checksums(kept / "stage").items()} == {
        k: v for k, v in past.items() if "2026-11-20" in k and not k.startswith("readings/")
    }
    out = _planned(_workflow(a, raw, res, home, "catalog", "--dry-run"))
    assert "Verifying calibrations and measuring parts of night 2026-11-20" in out
    # night 2026-11-21 keeps its scans and settings (not ingested again); its measurements, made with
    # the recomputed night's calibrations and verifications, follow them (Snakemake: updated inputs)
    assert "registering the scans of night 2026-11-21" not in out
    _planned(_workflow(a, raw, res, home, "catalog"))
    assert _verification_tolerances(res) == {"2026-11-20": {0.03}, "2026-11-21": {0.03}}
    con = duckdb.connect(str(res / "catalog.duckdb"), read_only=True)
    assert con.execute(
        "SELECT change_id, nights, new_hash, changed_keys, archive FROM config_changes"
    ).fetchall() == [
        (
            "change-0001",
            "2026-11-20",
            hashes["2026-11-21"],
            "verification.tolerance_mm",
            "versions/change-0001",
        )
    ]
    assert con.execute("SELECT recorded_by FROM night_config ORDER BY night").fetchall() == [
        ("recompute change-0001",),
        ("first run",),
    ]


def test_a_damaged_catalog_is_named_by_every_reader_and_rebuilt(tmp_path, demo_raw, capsys):
    """Issue 40 item 10: a catalog cut short is refused by open_catalog (sql, status, trace, report read
    through it) with the command that rebuilds it; the catalog step and the workflow rebuild it.
    """
    from borescan import catalog
    from borescan.cli import main

    raw, res = tmp_path / "raw", tmp_path / "res"
    for d in sorted((demo_raw / "night=2026-11-20").glob("scan=*ROD01*")):
        copy_scan(d, raw, "2026-11-20", d.name[5:])
    scans, files, _ = stage_ingest(raw, "2026-11-20", res)
    _common.write_table(scans, res / "stage" / "scans" / "night=2026-11-20.parquet")
    _common.write_table(files, res / "stage" / "scan_files" / "night=2026-11-20.parquet")
    stage_catalog(res, raw_root=raw, log=lambda _: None)
    final = res / "catalog.duckdb"
    intact = catalog.table_rows(catalog.open_catalog(res), "scans")
    data = final.read_bytes()
    final.write_bytes(data[: len(data) // 2])
    assert (
        catalog.catalog_damage(final) == f"it has {len(data) // 2} bytes, {len(data)} were written "
        "(truncated or cut off by a full disk?)"
    )
    with pytest.raises(catalog.CatalogDamaged, match=r"is damaged: .* borescan rebuild-catalog --results"):
        catalog.open_catalog(res)
    assert main(["sql", "--results", str(res), "SELECT count(*) FROM scans"]) != 0
    assert "is damaged: it has" in capsys.readouterr().err  # never an answer from half a file
    assert catalog.set_aside_damaged(res, dry_run=True).endswith("a run rebuilds it from the stage tables")
    assert final.is_file()
    update = stage_catalog(res, raw_root=raw, log=lambda _: None)  # what build_catalog runs
    assert update.mode == "full" and update.reason.startswith("the catalog is damaged")
    assert catalog.table_rows(catalog.open_catalog(res), "scans") == intact
    final.write_bytes(data[:4096])
    assert "kept as catalog.duckdb.damaged" in catalog.set_aside_damaged(res)  # what the workflow does first
    assert not final.exists() and (res / "catalog.duckdb.damaged").is_file()
