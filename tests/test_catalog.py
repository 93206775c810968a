"""History catalog: schema of outputs.md, idempotent rebuild, saved queries, atomic writes."""

from __future__ import annotations

import json
import os
from pathlib import Path

import duckdb
import polars as pl
import pytest

from borescan import atomic, catalog, rawio
from borescan.cli import main as cli_main

TOL = 0.015
RG_CERT = 275.029


def _sha(text: str) -> str:
    import hashlib

    return hashlib.sha256(text.encode()).hexdigest()


def make_history(results_root: Path) -> dict[str, pl.DataFrame]:
    """Return a small constructed history in the shapes of the stage tables.

    Device TRI-01 (tri_lds, 3 channels): calibrated on 2026-11-20 (CAL-A, two scans), verified
    on the 20th (pass) and the 21st (FAIL, error 0.020 > 0.015), recalibrated on the 22nd (CAL-B)
    and verified (pass). Parts measured: PART-7 on the 20th with CAL-A (before the failure, so
    suspect), PART-8 on the 22nd with CAL-B (not suspect). Device ROD-01 measured PART-9 on the 21st
    with its own calibration and no verification failure. One scan is quarantined.
    Also writes the raw files and certificate folders the rows point to.
    """
    raw = results_root.parent / "raw"
    scans, files = [], []
    spec = [
        # scan_id, night, device, type, kind, artifact, started_at, status, reason
        (
            "CAL-A-P1",
            "2026-11-20",
            "TRI-01",
            "tri_lds",
            "calibration",
            "RG-275",
            "2026-11-20T22:00:00Z",
            "ok",
            None,
        ),
        (
            "CAL-A-P2",
            "2026-11-20",
            "TRI-01",
            "tri_lds",
            "calibration",
            "RG-275",
            "2026-11-20T22:10:00Z",
            "ok",
            None,
        ),
        (
            "VER-20",
            "2026-11-20",
            "TRI-01",
            "tri_lds",
            "verification",
            "RG-275",
            "2026-11-20T22:20:00Z",
            "ok",
            None,
        ),
        (
            "PART-7",
            "2026-11-20",
            "TRI-01",
            "tri_lds",
            "measurement",
            "P-7",
            "2026-11-20T23:00:00Z",
            "ok",
            None,
        ),
        (
            "VER-21",
            "2026-11-21",
            "TRI-01",
            "tri_lds",
            "verification",
            "RG-275",
            "2026-11-21T22:20:00Z",
            "ok",
            None,
        ),
        (
            "ROD-CAL",
            "2026-11-21",
            "ROD-01",
            "rod",
            "calibration",
            "RG-275",
            "2026-11-21T21:00:00Z",
            "ok",
            None,
        ),
        (
            "PART-9",
            "2026-11-21",
            "ROD-01",
            "rod",
            "measurement",
            "P-9",
            "2026-11-21T23:30:00+01:00",
            "ok",
            None,
        ),
        (
            "BAD-1",
            "2026-11-21",
            "TRI-01",
            "tri_lds",
            "measurement",
            "P-7",
            "2026-11-21T23:40:00Z",
            "quarantined",
            "lds.parquet: non-monotonic sample",
        ),
        (
            "CAL-B",
            "2026-11-22",
            "TRI-01",
            "tri_lds",
            "calibration",
            "RG-275",
            "2026-11-22T22:00:00Z",
            "ok",
            None,
        ),
        (
            "VER-22",
            "2026-11-22",
            "TRI-01",
            "tri_lds",
            "verification",
            "RG-275",
            "2026-11-22T22:20:00Z",
            "ok",
            None,
        ),
        (
            "PART-8",
            "2026-11-22",
            "TRI-01",
            "tri_lds",
            "measurement",
            "P-8",
            "2026-11-22T23:00:00Z",
            "ok",
            None,
        ),
    ]
    for sid, night, dev, typ, kind, art, t0, status, reason in spec:
        d = raw / f"night={night}" / f"scan={sid}"
        d.mkdir(parents=True, exist_ok=True)
        shas = {}
        for name, content in (("scan.json", f'{{"scan_id": "{sid}"}}'), ("lds.parquet", f"lds of {sid}")):
            (d / name).write_text(content)
            shas[name] = _sha(content)
            files.append(
                {"scan_id": sid, "night": night, "file": name, "sha256": shas[name], "bytes": len(content)}
            )
        scans.append(
            {
                "scan_id": sid,
                "night": night,
                "device_id": dev,
                "device_type": typ,
                "kind": kind,
                "artifact_id": art,
                "started_at": t0,
                "status": status,
                "reason": reason,
                "raw_sha256": rawio.combined_sha256(shas),
                "raw_path": str(d),
                "simulated": True,
            }
        )
    cal_rows = []
    for cal_id, scan_id, drho in (("CAL-A", "CAL-A-P1", 0.0), ("CAL-B", "CAL-B", 0.004)):
        cert_dir = results_root / "calibration" / "TRI-01" / cal_id
        cert_dir.mkdir(parents=True, exist_ok=True)
        (cert_dir / "certificate.json").write_text(json.dumps({"calibration_id": cal_id}) + "\n")
        (cert_dir / "certificate.pdf").write_bytes(b"%PDF-1.4 " + cal_id.encode())
        for ch, beta in ((1, 1.571), (2, 3.665), (3, 5.760)):
            cal_rows.append(
                {
                    "calibration_id": cal_id,
                    "device_id": "TRI-01",
                    "scan_id": scan_id,
                    "channel": ch,
                    "rho_mm": 5.5 + ch * 0.01 + drho,
                    "d_b_mm": 132.7 + ch * 0.1,
                    "beta_rad": beta,
                    "u_rho_mm": 0.002,
                    "u_d_b_mm": 0.003,
                    "u_beta_rad": 1e-4,
                    "method": "full_lsq",
                    "certificate_path": f"calibration/TRI-01/{cal_id}/certificate.pdf",
                }
            )
    rod_dir = results_root / "calibration" / "ROD-01" / "ROD-CAL-1"
    rod_dir.mkdir(parents=True, exist_ok=True)
    (rod_dir / "certificate.json").write_text('{"calibration_id": "ROD-CAL-1"}\n')
    cal_rows.append(
        {
            "calibration_id": "ROD-CAL-1",
            "device_id": "ROD-01",
            "scan_id": "ROD-CAL",
            "channel": 1,
            "method": "wang_joint",
            "l0_mm": 120.0,
            "h_mm": 100.0,
            "phi_rad": 0.01,
            "d_mm": 0.2,
            "gamma_rad": 0.003,
            "certificate_path": "calibration/ROD-01/ROD-CAL-1/certificate.pdf",
        }
    )
    calibrations = pl.DataFrame(cal_rows)
    calibration_scans = pl.DataFrame(
        {
            "calibration_id": ["CAL-A", "CAL-A", "CAL-B"],
            "scan_id": ["CAL-A-P1", "CAL-A-P2", "CAL-B"],
        }
    )
    diameters = pl.DataFrame(
        {
            "scan_id": ["PART-7", "PART-8", "PART-9"],
            "device_id": ["TRI-01", "TRI-01", "ROD-01"],
            "artifact_id": ["P-7", "P-8", "P-9"],
            "feature": ["bore", "bore", "H1"],
            "diameter_mm": [150.0123, 150.0101, 80.0042],
            "u_diameter_mm": [0.0021, 0.0020, 0.004],
            "calibration_id": ["CAL-A", "CAL-B", "ROD-CAL-1"],
            "method": ["static_3lds", "static_3lds", "rod_joint"],
        }
    )
    verifications = pl.DataFrame(
        {
            "scan_id": ["VER-20", "VER-21", "VER-22"],
            "device_id": ["TRI-01"] * 3,
            "artifact_id": ["RG-275"] * 3,
            "measured_mm": [RG_CERT + 0.004, RG_CERT + 0.020, RG_CERT - 0.001],
            "certified_mm": [RG_CERT] * 3,
            "tolerance_mm": [TOL] * 3,
            "calibration_id": ["CAL-A", "CAL-A", "CAL-B"],
        }
    )
    for sid in ("PART-7", "PART-8"):
        (results_root / "discrepancy" / sid).mkdir(parents=True, exist_ok=True)
        (results_root / "discrepancy" / sid / "gap.png").write_bytes(b"\x89PNG fake")
    findings = pl.DataFrame(
        {
            "scan_id": ["PART-7", "PART-8"],
            "verdict": ["missing_effect", "no_missing_effect"],
            "effect": ["channel_delay", None],
            "channel": [2, None],
            "parameters": ['{"tau_s": 0.0012}', None],
            "gap_before_mm": [0.0061, 0.0021],
            "gap_after_mm": [0.0021, None],
        }
    )
    artifacts = pl.DataFrame(
        {
            "artifact_id": ["RG-275"],
            "type": ["ring_gauge"],
            "certificate": ["RG-275/2026-03"],
            "certified_diameter_mm": [RG_CERT],
            "u_diameter_mm": [0.0015],
            "k": [2.0],
            "cte_per_k": [11.5e-6],
        }
    )
    quarantine = pl.DataFrame(
        {
            "scan_id": ["BAD-1"],
            "night": ["2026-11-21"],
            "stage": ["ingest"],
            "file": ["lds.parquet"],
            "reason": ["non-monotonic sample"],
        }
    )
    return {
        "scans": pl.DataFrame(scans),
        "scan_files": pl.DataFrame(files),
        "calibrations": calibrations,
        "calibration_scans": calibration_scans,
        "diameters": diameters,
        "verifications": verifications,
        "findings": findings,
        "artifacts": artifacts,
        "quarantine": quarantine,
    }


@pytest.fixture()
def built(tmp_path):
    res = tmp_path / "results"
    tables = make_history(res)
    catalog.build_catalog(res, tables)
    return res, tables


# ------------------------------------------------------------ schema


def _columns(con, table):
    return {r[0]: r[1] for r in con.execute(f"DESCRIBE {table}").fetchall()}


def test_catalog_has_outputs_md_columns_and_types(built):
    res, _ = built
    con = catalog.open_catalog(res)
    required = {
        "scans": [
            "scan_id",
            "night",
            "device_id",
            "device_type",
            "kind",
            "artifact_id",
            "started_at",
            "status",
            "reason",
            "raw_sha256",
        ],
        "calibrations": [
            "calibration_id",
            "device_id",
            "scan_id",
            "channel",
            "rho_mm",
            "d_b_mm",
            "beta_rad",
            "u_rho_mm",
            "u_d_b_mm",
            "u_beta_rad",
            "method",
            "certificate_path",
            "l0_mm",
        ],
        "diameters": [
            "scan_id",
            "device_id",
            "artifact_id",
            "feature",
            "diameter_mm",
            "u_diameter_mm",
            "calibration_id",
            "method",
        ],
        "verifications": [
            "scan_id",
            "device_id",
            "artifact_id",
            "measured_mm",
            "certified_mm",
            "error_mm",
            "tolerance_mm",
            "passed",
        ],
        "findings": [
            "scan_id",
            "verdict",
            "effect",
            "channel",
            "parameters",
            "gap_before_mm",
            "gap_after_mm",
        ],
        "scan_files": ["scan_id", "file", "sha256", "bytes"],
        "calibration_scans": ["calibration_id", "scan_id"],
        "artifacts": [
            "artifact_id",
            "type",
            "certificate",
            "certified_diameter_mm",
            "u_diameter_mm",
            "k",
            "cte_per_k",
        ],
    }
    for table, cols in required.items():
        have = _columns(con, table)
        assert [c for c in cols if c not in have] == [], table
    assert _columns(con, "scans")["night"] == "DATE"
    assert _columns(con, "scans")["started_at"] == "TIMESTAMP"
    assert _columns(con, "calibrations")["channel"] == "SMALLINT"
    assert _columns(con, "diameters")["diameter_mm"] == "DOUBLE"
    assert _columns(con, "verifications")["passed"] == "BOOLEAN"
    assert _columns(con, "scan_files")["bytes"] == "BIGINT"
    # contents and derived columns
    assert con.execute("SELECT status, reason FROM scans WHERE scan_id='BAD-1'").fetchone() == (
        "quarantined",
        "lds.parquet: non-monotonic sample",
    )
    # +01:00 converted to UTC
    assert (
        str(con.execute("SELECT started_at FROM scans WHERE scan_id='PART-9'").fetchone()[0])
        == "2026-11-21 22:30:00"
    )
    err, passed = con.execute("SELECT error_mm, passed FROM verifications WHERE scan_id='VER-21'").fetchone()
    assert err == pytest.approx(0.020, abs=1e-9) and passed is False
    dia = con.execute(
        "SELECT diameter_id, night::VARCHAR, raw_sha256 FROM diameters WHERE scan_id='PART-7'"
    ).fetchone()
    scan_sha = con.execute("SELECT raw_sha256 FROM scans WHERE scan_id='PART-7'").fetchone()[0]
    assert dia == ("PART-7/bore", "2026-11-20", scan_sha)
    # calibration_scans: given for CAL-A/B, filled for the rod from calibrations.scan_id
    assert con.execute(
        "SELECT scan_id FROM calibration_scans WHERE calibration_id='ROD-CAL-1'"
    ).fetchall() == [("ROD-CAL",)]
    assert (
        con.execute("SELECT count(*) FROM calibration_scans WHERE calibration_id='CAL-A'").fetchone()[0] == 2
    )
    # certificate.json digest recorded
    sha = con.execute(
        "SELECT DISTINCT certificate_sha256 FROM calibrations WHERE calibration_id='CAL-A'"
    ).fetchone()[0]
    assert sha == _sha('{"calibration_id": "CAL-A"}\n')
    # the rod's tri_lds columns are null, the tri_lds rows' rod columns are null
    assert con.execute(
        "SELECT rho_mm, l0_mm FROM calibrations WHERE calibration_id='ROD-CAL-1'"
    ).fetchone() == (None, 120.0)
    assert (
        con.execute(
            "SELECT count(*) FROM calibrations WHERE device_id='TRI-01' AND l0_mm IS NOT NULL"
        ).fetchone()[0]
        == 0
    )
    con.close()


def test_combined_sha256_is_over_sorted_name_lines():
    import hashlib

    got = rawio.combined_sha256({"scan.json": "bb", "lds.parquet": "aa"})
    assert got == hashlib.sha256(b"lds.parquet:aa\nscan.json:bb\n").hexdigest()


def test_rebuild_is_idempotent_and_atomic(tmp_path):
    res = tmp_path / "results"
    tables = make_history(res)
    path = catalog.build_catalog(res, tables)
    con = catalog.open_catalog(res)
    first = {t: catalog.table_rows(con, t) for t in catalog.SCHEMA}
    con.close()
    # same inputs, rows in another order: same contents
    shuffled = {k: v.reverse() for k, v in tables.items()}
    assert catalog.build_catalog(res, shuffled) == path
    con = catalog.open_catalog(res)
    second = {t: catalog.table_rows(con, t) for t in catalog.SCHEMA}
    con.close()
    assert first == second
    assert first["scans"] and first["diameters"]
    assert not path.with_name("catalog.duckdb.tmp").exists()
    assert sorted(p.name for p in res.iterdir() if p.name.startswith("catalog")) == [
        "catalog.duckdb",
        "catalog.duckdb.sha256",
    ]  # the catalog and its seal


def test_build_from_stage_parquet_files(tmp_path):
    """The catalog reads the per-night stage Parquet files the pipeline writes."""
    res = tmp_path / "results"
    tables = make_history(res)
    for name, df in tables.items():
        if name == "quarantine" or "night" not in df.columns:
            continue
        for (night,), part in df.partition_by("night", as_dict=True).items():
            out = res / "stage" / name / f"night={night}.parquet"
            out.parent.mkdir(parents=True, exist_ok=True)
            part.write_parquet(out)
    con = duckdb.connect()
    n = con.execute(
        f"SELECT count(*) FROM read_parquet('{res}/stage/scans/night=*.parquet', union_by_name=true)"
    ).fetchone()[0]
    assert n == tables["scans"].height
    stage_tables = {
        name: pl.concat([pl.read_parquet(f) for f in sorted((res / "stage" / name).glob("night=*.parquet"))])
        for name in ("scans", "scan_files")
    }
    catalog.build_catalog(res, stage_tables)
    con = catalog.open_catalog(res)
    assert con.execute("SELECT count(*) FROM scans").fetchone()[0] == tables["scans"].height
    assert (
        con.execute("SELECT count(*) FROM diameters").fetchone()[0] == 0
    )  # missing table: empty, same columns
    assert "diameter_mm" in _columns(con, "diameters")
    con.close()


def test_unknown_table_and_duplicate_key_fail_clearly(tmp_path):
    with pytest.raises(ValueError, match="unknown catalog table"):
        catalog.build_catalog(tmp_path, {"scanz": pl.DataFrame({"a": [1]})})
    dup = pl.DataFrame({"scan_id": ["A", "A"], "night": ["2026-11-20"] * 2})
    with pytest.raises(ValueError, match="scans: duplicate key"):
        catalog.build_catalog(tmp_path, {"scans": dup})
    assert not (tmp_path / "catalog.duckdb").exists()
    with pytest.raises(FileNotFoundError, match="no history catalog"):
        catalog.open_catalog(tmp_path)


def test_bad_timestamp_of_quarantined_scan_becomes_null(tmp_path):
    scans = pl.DataFrame(
        {
            "scan_id": ["Q"],
            "night": ["2026-11-21"],
            "started_at": ["yesterday"],
            "status": ["quarantined"],
            "reason": ["scan.json: started_at is not ISO 8601"],
        }
    )
    catalog.build_catalog(tmp_path, {"scans": scans, "scan_files": pl.DataFrame()})
    con = catalog.open_catalog(tmp_path)
    assert con.execute("SELECT started_at, status FROM scans").fetchall() == [(None, "quarantined")]
    con.close()


def test_catalog_is_read_only_by_default(built):
    res, _ = built
    con = catalog.open_catalog(res)
    with pytest.raises(duckdb.Error):
        con.execute("DELETE FROM scans")
    con.close()


def test_upsert_rows_replaces_by_key(built):
    res, _ = built
    con = catalog.open_catalog(res, read_only=False)
    catalog.upsert_rows(
        con,
        "artifacts",
        pl.DataFrame({"artifact_id": ["RG-275"], "type": ["ring_gauge"], "certified_diameter_mm": [275.03]}),
    )
    assert con.execute("SELECT count(*), max(certified_diameter_mm) FROM artifacts").fetchone() == (1, 275.03)
    con.close()


# ------------------------------------------------------------ saved queries


def test_saved_queries_have_header_comments():
    queries = catalog.saved_queries()
    assert {"verification_drift", "calibration_history", "suspect_measurements"} <= set(queries)
    for name, (desc, sql) in queries.items():
        assert len(desc.splitlines()) >= 2 and sql.strip(), name
        assert "Answers:" in desc, name


def test_verification_drift_query(built):
    res, _ = built
    con = catalog.open_catalog(res)
    rows = con.execute(
        "SELECT scan_id, error_mm, change_mm, moving_range_mm, passed, drift_mm_per_day, margin_mm "
        "FROM verification_drift WHERE device_id='TRI-01'"
    ).fetchall()
    con.close()
    assert [r[0] for r in rows] == ["VER-20", "VER-21", "VER-22"]
    assert [round(r[1], 9) for r in rows] == [0.004, 0.020, -0.001]
    assert rows[0][2] is None and rows[1][2] == pytest.approx(0.016) and rows[2][2] == pytest.approx(-0.021)
    assert rows[2][3] == pytest.approx(0.021)
    assert [r[4] for r in rows] == [True, False, True]
    # slope through (0, .004), (1, .020): 0.016 mm/day; then through all three: -0.0025 mm/day
    assert rows[0][5] is None
    assert rows[1][5] == pytest.approx(0.016)
    assert rows[2][5] == pytest.approx(-0.0025)
    assert rows[1][6] == pytest.approx(-0.005)


def test_calibration_history_query(built):
    res, _ = built
    con = catalog.open_catalog(res)
    rows = con.execute(
        "SELECT calibration_id, channel, valid_from::VARCHAR, delta_rho_mm, scan_ids, l0_mm "
        "FROM calibration_history ORDER BY device_id, channel, valid_from"
    ).fetchall()
    con.close()
    tri1 = [r for r in rows if r[1] == 1 and r[0].startswith("CAL")]
    assert [(r[0], r[2]) for r in tri1] == [("CAL-A", "2026-11-20"), ("CAL-B", "2026-11-22")]
    assert tri1[0][3] is None and tri1[1][3] == pytest.approx(0.004)
    assert tri1[0][4] == "CAL-A-P1,CAL-A-P2" and tri1[1][4] == "CAL-B"
    assert [r for r in rows if r[0] == "ROD-CAL-1"] == [
        ("ROD-CAL-1", 1, "2026-11-21", None, "ROD-CAL", 120.0)
    ]


def test_suspect_measurements_query(built):
    res, _ = built
    con = catalog.open_catalog(res)
    rows = con.execute(
        "SELECT scan_id, feature, calibration_id, failed_verification_scan_id, failed_night::VARCHAR, "
        "measured_before_failure FROM suspect_measurements"
    ).fetchall()
    con.close()
    # PART-7 used CAL-A, whose verification of the 21st failed; PART-8 (CAL-B) and PART-9 are fine
    assert rows == [("PART-7", "bore", "CAL-A", "VER-21", "2026-11-21", True)]


def test_sql_command_runs_queries(built, capsys):
    res, _ = built
    assert (
        cli_main(
            [
                "sql",
                "--results",
                str(res),
                "SELECT scan_id, status FROM scans WHERE kind='calibration' ORDER BY 1",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["scan_id", "status"]
    assert out[2].split() == ["CAL-A-P1", "ok"]
    assert len(out) == 2 + 4  # header, rule, four calibration scans
    assert (
        cli_main(["sql", "--results", str(res), "--query", "suspect_measurements", "--format", "json"]) == 0
    )
    data = json.loads(capsys.readouterr().out)
    assert [d["scan_id"] for d in data] == ["PART-7"]
    assert data[0]["failed_night"] == "2026-11-21"
    assert (
        cli_main(
            [
                "sql",
                "--results",
                str(res),
                "--format",
                "csv",
                "SELECT scan_id, diameter_mm FROM diameters ORDER BY 1",
            ]
        )
        == 0
    )
    assert capsys.readouterr().out.splitlines()[:2] == ["scan_id,diameter_mm", "PART-7,150.0123"]


def test_sql_command_is_read_only_and_reports_errors(built, capsys):
    res, _ = built
    assert cli_main(["sql", "--results", str(res), "DELETE FROM scans"]) == 1
    assert "read-only" in capsys.readouterr().err.lower()
    assert cli_main(["sql", "--results", str(res), "--query", "nope"]) == 1
    assert "unknown saved query 'nope'" in capsys.readouterr().err
    assert cli_main(["sql", "--results", str(res / "missing"), "SELECT 1"]) == 1
    assert "no history catalog" in capsys.readouterr().err


def test_sql_command_lists_saved_queries(built, capsys):
    res, _ = built
    assert cli_main(["sql", "--results", str(res), "--list"]) == 0
    out = capsys.readouterr().out
    assert "verification_drift" in out and "suspect_measurements" in out and "calibration_history" in out


# ------------------------------------------------------------ atomic writes


def test_atomic_json_is_canonical(tmp_path):
    p = tmp_path / "a" / "x.json"
    atomic.atomic_write_json(p, {"b": 0.1, "a": [1, 2.5e-7], "c": float("nan"), "d": (1, 2), "e": Path("q")})
    text = p.read_text()
    assert (
        text == '{\n  "a": [\n    1,\n    2.5e-07\n  ],\n  "b": 0.1,\n  "c": null,\n  "d": [\n    1,\n    '
        '2\n  ],\n  "e": "q"\n}\n'
    )
    before = p.read_bytes()
    atomic.atomic_write_json(p, {"d": [1, 2], "c": None, "b": 0.1, "a": [1, 2.5e-7], "e": "q"})
    assert p.read_bytes() == before
    assert [f.name for f in p.parent.iterdir()] == ["x.json"]
    with pytest.raises(TypeError, match="cannot write object"):
        atomic.atomic_write_json(tmp_path / "y.json", {"x": object()})
    assert not (tmp_path / "y.json").exists()


def test_atomic_bytes_and_text(tmp_path):
    p = tmp_path / "f.bin"
    atomic.atomic_write_bytes(p, b"one")
    atomic.atomic_write_text(p, "two\n")
    assert p.read_text() == "two\n"
    assert oct(os.stat(p).st_mode & 0o777) == "0o644"


def test_atomic_dir_replaces_or_leaves_untouched(tmp_path):
    target = tmp_path / "cert"
    with atomic.atomic_dir(target) as d:
        (d / "a.txt").write_text("A")
        assert not target.exists()
    assert (target / "a.txt").read_text() == "A"
    with pytest.raises(RuntimeError, match="boom"):
        with atomic.atomic_dir(target) as d:
            (d / "b.txt").write_text("B")
            raise RuntimeError("boom")
    assert sorted(p.name for p in target.iterdir()) == ["a.txt"]
    with atomic.atomic_dir(target) as d:
        (d / "c.txt").write_text("C")
    assert sorted(p.name for p in target.iterdir()) == ["c.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cert"]
    with pytest.raises(FileExistsError):
        with atomic.atomic_dir(target, replace=False) as d:
            (d / "d.txt").write_text("D")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cert"]


# ------------------------------------------------------------ SLURM profile (history on shared storage)

PROFILE = Path(__file__).resolve().parents[1] / "profiles" / "slurm"


def test_slurm_profile_is_valid_yaml_with_expected_keys():
    import yaml

    cfg = yaml.safe_load((PROFILE / "config.yaml").read_text())
    assert cfg["executor"] == "slurm"
    assert isinstance(cfg["jobs"], int) and cfg["jobs"] > 0
    assert cfg["latency-wait"] >= 30
    res = cfg["default-resources"]
    assert {"slurm_partition", "runtime", "mem_mb"} <= set(res)
    assert isinstance(res["runtime"], int) and isinstance(res["mem_mb"], int)
    readme = (PROFILE / "README.md").read_text()
    for phrase in (
        "pip install snakemake-executor-plugin-slurm",
        "snakemake --profile profiles/slurm",
        "-readonly",
        "read_parquet(",
        "not** a borescan dependency",
    ):
        assert phrase in readme


def test_slurm_profile_keys_are_snakemake_options(tmp_path):
    """Every key is a real snakemake option: run a toy workflow with the profile, executor overridden.

    (The SLURM plugin is not installed here, so ``--executor local`` replaces it; the default
    resources must reach the job.)
    """
    import subprocess
    import sys

    (tmp_path / "Snakefile").write_text(
        'rule make_a:\n    output: "a.txt"\n'
        '    shell: "echo {resources.slurm_partition} {resources.mem_mb} {resources.runtime} > {output}"\n'
    )
    snakemake = Path(sys.executable).with_name("snakemake")
    proc = subprocess.run(
        [str(snakemake), "--profile", str(PROFILE), "--executor", "local", "--cores", "1", "--quiet"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "a.txt").read_text().split() == ["compute", "4000", "30"]


def test_sql_saved_query_falls_back_to_catalog_view(built, capsys, monkeypatch, tmp_path):
    """Without the workflow/queries folder (a plain install) --query uses the view in the catalog."""
    res, _ = built
    monkeypatch.setattr(catalog.queries, "DEFAULT_QUERIES_DIR", tmp_path / "no-queries-here")
    assert catalog.saved_queries() == {}
    assert cli_main(["sql", "--results", str(res), "--query", "suspect_measurements", "--format", "csv"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2 and lines[1].startswith("PART-7,2026-11-20,TRI-01,P-7,bore,150.0123")


def test_upsert_rows_keeps_a_calibrations_record_and_its_digest(tmp_path):
    import hashlib

    res = tmp_path / "results"
    tables = make_history(res)
    cal = tables["calibrations"].with_columns(pl.lit('{"v": 1}').alias("calibration_json"))
    catalog.build_catalog(res, {**tables, "calibrations": cal})
    con = catalog.open_catalog(res, read_only=False)
    row = cal.filter(pl.col("calibration_id") == "CAL-B").with_columns(
        pl.lit('{"v": 2}').alias("calibration_json")
    )
    assert catalog.upsert_rows(con, "calibrations", row) == 3  # its three channels
    got = con.execute(
        "SELECT calibration_json, calibration_json_sha256 FROM calibrations WHERE calibration_id = 'CAL-B'"
    ).fetchall()
    con.close()
    assert got == [('{"v": 2}', hashlib.sha256(b'{"v": 2}').hexdigest())] * 3
