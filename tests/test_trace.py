"""borescan trace: the chain from a diameter down to the raw files' SHA-256."""

from __future__ import annotations

import json

import pytest
from test_catalog import _sha, built  # noqa: F401 (built: the catalog fixture, shared)

from borescan import trace
from borescan.cli import main as cli_main


def _sha_of(tables, scan_id):
    return tables["scans"].filter(scan_id=scan_id)["raw_sha256"].item()


def test_trace_diameter_prints_full_chain(built, capsys):
    res, tables = built
    assert cli_main(["trace", "--results", str(res), "PART-7/bore"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0] == "trace PART-7/bore (diameter)"
    # diameter -> calibration -> certificate -> calibration scans -> artifact -> raw files, in that order
    steps = [
        "diameter PART-7/bore  150.0123 mm (u 0.0021 mm, k=1)",
        "scan PART-7  night 2026-11-20",
        "calibration CAL-A  device TRI-01",
        "certificate calibration/TRI-01/CAL-A/certificate.pdf",
        "calibration/TRI-01/CAL-A/certificate.json sha256 "
        + _sha('{"calibration_id": "CAL-A"}\n')
        + " (matches catalog)",
        "calibration scan CAL-A-P1",
        "artifact RG-275 (ring_gauge), certificate RG-275/2026-03, certified 275.029 mm",
        "raw_sha256 " + _sha_of(tables, "CAL-A-P1"),
        "calibration scan CAL-A-P2",
        "raw_sha256 " + _sha_of(tables, "CAL-A-P2"),
        "verified by VER-21 on 2026-11-21: error 0.02 mm (tolerance 0.015 mm) FAILED",
    ]
    pos = 0
    for step in steps:
        found = out.find(step, pos)
        assert found >= 0, f"missing or out of order: {step!r}\n{out}"
        pos = found
    # every raw file of the measurement and the calibration scans with its own digest
    files = tables["scan_files"].filter(
        tables["scan_files"]["scan_id"].is_in(["PART-7", "CAL-A-P1", "CAL-A-P2"])
    )
    for f in files.iter_rows(named=True):
        assert f"{f['file']:<16s} sha256 {f['sha256']}  ({f['bytes']} bytes)" in out


def test_trace_structured_chain(built):
    res, tables = built
    chain = trace.trace(res, "PART-7")
    assert chain["kind"] == "scan"
    (d,) = chain["diameters"]
    assert d["diameter_mm"] == 150.0123 and d["calibration_id"] == "CAL-A"
    cal = d["calibration"]
    assert [s["scan_id"] for s in cal["scans"]] == ["CAL-A-P1", "CAL-A-P2"]
    assert cal["certificate"]["json_sha256"] == cal["certificate"]["catalog_sha256"]
    assert cal["scans"][0]["artifact"]["certificate"] == "RG-275/2026-03"
    assert cal["scans"][0]["raw_sha256"] == _sha_of(tables, "CAL-A-P1")
    assert [v["passed"] for v in cal["verifications"]] == [True, False]


def test_trace_by_calibration_certificate_and_part(built, capsys):
    res, _ = built
    cal = trace.trace(res, "CAL-A")
    assert cal["kind"] == "calibration" and [s["scan_id"] for s in cal["calibration"]["scans"]] == [
        "CAL-A-P1",
        "CAL-A-P2",
    ]
    # CAL-B is both a scan id and a calibration id: the scan's chain names the calibration made from it
    scan = trace.trace(res, "CAL-B")
    assert scan["kind"] == "scan" and [c["calibration_id"] for c in scan["calibrations"]] == ["CAL-B"]
    for ident in (
        "calibration/TRI-01/CAL-B/certificate.json",
        str(res / "calibration/TRI-01/CAL-B"),
        "calibration/TRI-01/CAL-B/certificate.pdf",
    ):
        chain = trace.trace(res, ident)
        assert chain["kind"] == "certificate"
        assert [c["calibration_id"] for c in chain["calibrations"]] == ["CAL-B"]
    part = trace.trace(res, "P-9")
    assert part["kind"] == "part"
    assert part["diameters"][0]["calibration"]["calibration_id"] == "ROD-CAL-1"
    assert cli_main(["trace", "--results", str(res), "--json", "VER-21"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["verification"]["passed"] is False
    assert data["verification_calibration"]["calibration_id"] == "CAL-A"


def test_trace_flags_certificate_changed_after_cataloguing(built, capsys):
    res, _ = built
    (res / "calibration/TRI-01/CAL-A/certificate.json").write_text('{"calibration_id": "tampered"}\n')
    assert cli_main(["trace", "--results", str(res), "CAL-A"]) == 0
    assert "DIFFERS from catalog" in capsys.readouterr().out


def test_trace_unknown_id_fails_clearly(built, capsys):
    res, _ = built
    with pytest.raises(trace.UnknownId, match="unknown id 'NO-SUCH-SCAN'"):
        trace.trace(res, "NO-SUCH-SCAN")
    assert cli_main(["trace", "--results", str(res), "NO-SUCH-SCAN"]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("borescan trace: unknown id 'NO-SUCH-SCAN': not a diameter, scan, part")
    assert cli_main(["trace", "--results", str(res / "nowhere"), "PART-7"]) == 1
    assert "no history catalog" in capsys.readouterr().err


def test_trace_shows_the_certificate_a_scan_used_not_a_later_record(tmp_path):
    """History that cannot be rewritten: a calibration made against RG-275 at 275.029 mm still traces
    to 275.029 mm after a later night records the gauge (recertified) at 275.031 mm.
    """
    import duckdb

    from borescan.tables import TABLES

    con = duckdb.connect()
    for name in ("scans", "artifacts", "scan_files"):
        con.execute(TABLES[name].ddl())
    con.execute(
        "INSERT INTO scans (scan_id, night, artifact_id, status, artifact_certificate, "
        "artifact_certified_diameter_mm, artifact_u_diameter_mm) VALUES "
        "('CAL-1', '2026-11-20', 'RG-275', 'ok', 'RG-275/2026-03', 275.029, 0.0015)"
    )
    con.execute(
        "INSERT INTO artifacts (artifact_id, type, certificate, certified_diameter_mm, u_diameter_mm, k) "
        "VALUES ('RG-275', 'ring_gauge', 'RG-275/2027-01', 275.031, 0.0015, 2)"
    )
    t = trace._Tracer(con, tmp_path)
    art = t.scan_artifact(t.scan("CAL-1"))
    assert art["certified_diameter_mm"] == 275.029 and art["certificate"] == "RG-275/2026-03"
    assert art["latest"]["certified_diameter_mm"] == 275.031
    lines = trace._scan_lines(dict(t.scan("CAL-1"), artifact=art), "")
    assert any("certified 275.029 mm" in x and "as this scan used it" in x for x in lines)
    assert any(x.startswith("  NOTE: the artifact's latest record differs") and "275.031" in x for x in lines)


def test_a_diameter_names_its_feature_or_the_bore_never_feature_question_mark():
    base = {
        "diameter_20_mm": 276.4131,
        "expanded_u_diameter_20_mm": 0.0091,
        "k": 2.0,
        "temperature_c": 20.4,
        "diameter_mm": 276.4144,
        "method": "static circumcircle",
        "scan": {"scan_id": "S", "missing": True},
        "calibration": None,
    }
    part = trace._dia_lines(dict(base, diameter_id="S/B1", feature="B1"), "")[0]
    gauge = trace._dia_lines(dict(base, diameter_id="S/", feature=None), "")[0]
    assert ", feature B1, method static circumcircle" in part
    assert ", the bore, method static circumcircle" in gauge and "?" not in gauge
