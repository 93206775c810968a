"""Reissue of certificates from the history (``borescan certificate``, :mod:`borescan.certificate_issue`):
deleted certificates come back byte-identical; a changed laboratory section gives new documents
(ISO/IEC 17025 7.8.8.2) that name the ones they replace; ``borescan trace`` lists every issue.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
from pathlib import Path

import pytest
import yaml

sys.path.insert(0, str(Path(__file__).parent))

import dcc_reader as rd
from test_catalog import built  # noqa: F401 (the catalog fixture, shared)

from borescan import night_config
from borescan.certificate.dcc import DCC_FILE
from borescan.certificate_issue import issues_of
from borescan.cli import main

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "config.yaml"  # the pipeline_run fixture's laboratory section


def _files(folder: Path) -> dict[str, str]:
    """Return the SHA-256 of every file below ``folder``, through its links.

    The links are calibration/<device>/<id> -> night folder.
    """
    out = {}
    for d, _dirs, names in os.walk(folder, followlinks=True):
        for n in names:
            if n != ".snakemake_timestamp":
                p = Path(d) / n
                out[str(p.relative_to(folder))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """Return a history of two certificates written by the stages' own path, under the laboratory section of
    config/config.yaml: a three-sensor calibration (a simulated ring-gauge scan, fit, GUM budget) and a rod
    calibration (a contract scan of a rod in certified ring gauges, ``calibrate_rod_scan``), each with
    its ``stage/certificate_issues`` row.
    """
    import polars as pl

    from borescan import certificate, rawio
    from borescan.calibrate.sensitivities import full_residuals
    from borescan.synthetic import battery, scenes, simulate
    from borescan.certificate_issue import ISSUE_TABLE, issue_frame, issue_row
    from borescan.config import load_config
    from borescan.stages._common import link_into_night
    from borescan.stages.calibrate_jobs import RodCalibrationContext
    from borescan.stages.calibrate_rod import calibrate_rod_scan
    from borescan.stages.calibration_fit import calibrate_raw_scans, spindle_inputs

    tmp = tmp_path_factory.mktemp("history")
    res, cfg, night = tmp / "results", load_config(CONFIG), "2026-11-21"
    scene = scenes.default_tri_scene()
    sim = simulate.simulate_tri_spindle(
        scene,
        scan_id="N20261121-TRI01-CAL-P1",
        night=night,
        n_rev=5,
        noise_mm=0.002,
        seed=11,
        center_xy_mm=scene.bore_center_xy_mm,
    )
    scan = rawio.read_scan(simulate.write_simulated(sim, tmp / "raw", tmp / "truth"))
    cal = calibrate_raw_scans([scan], cfg["calibration"], uncertainty=cfg["uncertainty"])
    x = spindle_inputs(scan, cfg["uncertainty"])
    residuals = {
        "t_s": x.t_s,
        "residual_mm": full_residuals(
            cal, x.t_s, x.readings_mm, x.radius_mm, scan.scan_id, angle_model=x.angle_model
        ),
    }
    out = certificate.certificate_night_dir(res, cal, night)
    paths = certificate.write_certificate(
        cal,
        out,
        device={"id": "TRI-01", "type": "tri_lds", "sensors": scan.meta["sensors"]},
        artifact=dict(scan.meta["artifact"]),
        residuals=residuals,
        raw_files=dict(scan.sha256),
        conditions={
            "temperature": {
                "value_c": 20.0,
                "u_c": 0.0577,
                "U_c": 0.0953,
                "k": 1.65,
                "assumed": False,
                "source": "scan.json",
            },
            "gauge_radius_at_temperature_mm": x.radius_mm,
            "position_accuracy_mm": 0.002,
            "scans": [],
        },
        software_version="0.1.0",
        config_hash="c0ffee12",
        laboratory=cfg["laboratory"],
        dates=certificate.certificate_dates([scan.meta], night, 30, night),
    )
    link_into_night(certificate.certificate_dir(res, cal), out)
    rows = {night: [issue_row(paths, res, night, residuals)]}
    rod_scan = rawio.read_scan(battery.write_battery(tmp / "battery", 40, 0, kinds=("rod",), only=[0])[0])
    assert rod_scan.meta["kind"] == "verification"  # the rod in a set of certified ring gauges
    ctx = RodCalibrationContext(
        cfg["uncertainty"],
        cfg["laboratory"],
        cfg["verification"],
        pl.DataFrame(schema={"scan_id": pl.Utf8, "status": pl.Utf8, "kind": pl.Utf8, "device_id": pl.Utf8}),
    )
    night_config.settle(res, [rod_scan.night], cfg)  # as the workflow does first: the date of issue
    made = calibrate_rod_scan(rod_scan, rod_scan.night, res, ctx, cfg["calibration"], lambda _m: None)
    assert not made.quarantined and len(made.certificate_rows) == 1
    rows[rod_scan.night] = list(made.certificate_rows)
    for n, r in rows.items():
        f = res / ISSUE_TABLE / f"night={n}.parquet"
        f.parent.mkdir(parents=True, exist_ok=True)
        issue_frame(r).write_parquet(f)
    assert pl.read_parquet(res / ISSUE_TABLE / f"night={night}.parquet")["residual_channels"].to_list() == [3]
    return res


@pytest.mark.slow
def test_deleted_certificates_come_back_byte_identical(results, capsys):
    before = _files(results / "calibration")
    n_docs = sum(1 for k in before if k.endswith("certificate.json"))
    assert n_docs == 4  # two calibrations, each in its night folder and through its link
    shutil.rmtree(results / "calibration")
    assert main(["certificate", "--all", "--results", str(results), "--config", str(CONFIG)]) == 0
    out = capsys.readouterr().out
    assert _files(results / "calibration") == before
    assert "DIFFERS" not in out and out.count("reissued unchanged") == n_docs // 2
    # a file edited on disk is reported, not trusted: the history writes it back
    cal_dir = next((results / "calibration").glob("ROD-*/*"))
    (cal_dir / "certificate.json").write_text("{}\n")
    assert (
        main(
            [
                "certificate",
                cal_dir.name,
                "--results",
                str(results),
                "--config",
                str(CONFIG),
                "--format",
                "json",
            ]
        )
        == 0
    )
    assert _files(results / "calibration") == before


@pytest.mark.slow
def test_a_changed_laboratory_gives_new_documents_naming_the_ones_they_replace(results, tmp_path, capsys):
    cfg = yaml.safe_load(CONFIG.read_text())
    cfg["laboratory"] = dict(
        cfg["laboratory"], name="Example Metrology Lab", address="1 Gauge Street, Exampletown"
    )
    new_cfg = tmp_path / "config.yaml"
    new_cfg.write_text(yaml.safe_dump(cfg))
    rod_dir = next((results / "calibration").glob("ROD-*/*"))
    rod = rod_dir.name
    original = json.loads((rod_dir / "certificate.json").read_text())
    sha = hashlib.sha256((rod_dir / "certificate.json").read_bytes()).hexdigest()
    args = [
        "certificate",
        rod,
        "--results",
        str(results),
        "--config",
        str(new_cfg),
        "--issue-date",
        "2026-12-01",
    ]
    assert main(args) == 0
    assert f"{rod}-R1: NEW certificate issued 2026-12-01, replaces {rod}" in capsys.readouterr().out
    doc = results / "certificates" / rod / f"{rod}-R1"
    new = json.loads((doc / "certificate.json").read_text())
    assert new["administrativeData"]["coreData"]["uniqueIdentifier"] == f"{rod}-R1"
    assert new["dates"]["issue"] == "2026-12-01" and new["laboratory"]["name"] == "Example Metrology Lab"
    assert new["reissue"]["replaces"] == {
        "document_id": rod,
        "sha256": sha,
        "issue_date": original["dates"]["issue"],
    }
    assert new["reissue"]["changed"] == ["address", "name"]
    for key in ("measurementResults", "covariance", "verifications", "conformity", "parameters", "raw_files"):
        assert new[key] == original[key], key  # the results are the original's
    dcc = rd.decode(doc / DCC_FILE)  # valid against the schema
    prev = dcc["dcc:administrativeData"]["dcc:coreData"]["dcc:previousReport"]
    assert (prev["dcc:referralID"], prev["dcc:value"]) == (rod, sha)
    lab = dcc["dcc:administrativeData"]["dcc:calibrationLaboratory"]["dcc:contact"]
    assert rd.text(lab["dcc:name"]) == "Example Metrology Lab"
    assert (doc / "certificate.pdf").read_bytes().startswith(b"%PDF")
    # the same laboratory again: the new document is the latest issue and comes back byte-identical
    first = _files(doc)
    assert main(args[:-2]) == 0
    assert "-R1: reissued unchanged (issue 1 of 2026-12-01)" in capsys.readouterr().out
    assert _files(doc) == first
    # a second change: R2 replaces R1
    cfg["laboratory"]["signatory"] = "B. Example"
    new_cfg.write_text(yaml.safe_dump(cfg))
    assert main(args[:-2] + ["--issue-date", "2026-12-02"]) == 0
    r2 = json.loads((results / "certificates" / rod / f"{rod}-R2" / "certificate.json").read_text())
    assert r2["reissue"]["replaces"]["document_id"] == f"{rod}-R1"
    assert r2["reissue"]["replaces"]["sha256"] == first["certificate.json"]
    # every issue is recorded, the latest last (`borescan trace` lists them; test_trace_lists_every_issue)
    issues = issues_of(results, rod)
    assert [(i.document_id, i.issue, i.replaces) for i in issues] == [
        (rod, 0, None),
        (f"{rod}-R1", 1, rod),
        (f"{rod}-R2", 2, f"{rod}-R1"),
    ]
    assert [i.issue_date for i in issues[1:]] == ["2026-12-01", "2026-12-02"]
    # a changed decision rule would change verdicts: refused, naming the certificate
    cfg["laboratory"]["decision_rule"] = "guard_band"
    new_cfg.write_text(yaml.safe_dump(cfg))
    assert main(args[:-2]) == 1
    err = capsys.readouterr().err
    assert f"certificate {rod}-R2: laboratory.decision_rule changed" in err


def test_trace_lists_every_issue_and_finds_a_reissue_by_its_number(built, capsys):  # noqa: F811
    """A catalogued calibration (tests/test_catalog.py's history) with an original certificate and a
    reissue recorded: ``borescan trace`` lists both, each against its record, and knows the reissue's number.
    """
    from borescan.certificate_issue import ISSUE_TABLE, issue_frame

    res, _ = built
    folder = "calibration/TRI-01/CAL-A"
    text = (res / folder / "certificate.json").read_text()
    sha = hashlib.sha256(text.encode()).hexdigest()
    base = {
        "calibration_id": "CAL-A",
        "device_id": "TRI-01",
        "night": "2026-11-20",
        "laboratory_sha256": "0" * 64,
        "content_json": text,
        "residual_t_s": None,
        "residual_mm": None,
        "residual_channels": None,
    }
    rows = [
        dict(
            base,
            document_id="CAL-A",
            issue=0,
            issue_date="2026-11-20",
            replaces=None,
            replaces_sha256=None,
            folder=folder,
            files_sha256=json.dumps({"certificate.json": sha}),
        ),
        dict(
            base,
            document_id="CAL-A-R1",
            issue=1,
            issue_date="2026-12-01",
            replaces="CAL-A",
            replaces_sha256=sha,
            folder="certificates/CAL-A/CAL-A-R1",
            files_sha256=json.dumps({"certificate.json": "f" * 64}),
        ),
    ]
    (res / ISSUE_TABLE).mkdir(parents=True)
    issue_frame(rows[:1]).write_parquet(res / ISSUE_TABLE / "night=2026-11-20.parquet")
    (res / ISSUE_TABLE / "reissues").mkdir()
    issue_frame(rows[1:]).write_parquet(res / ISSUE_TABLE / "reissues" / "CAL-A-R1.parquet")
    assert main(["trace", "--results", str(res), "CAL-A"]) == 0
    out = capsys.readouterr().out
    assert f"issue 0: CAL-A of 2026-11-20; {folder}/certificate.json matches its record" in out
    assert (
        "issue 1: CAL-A-R1 of 2026-12-01, replaces CAL-A; certificates/CAL-A/CAL-A-R1/certificate.json "
        "MISSING on disk"
    ) in out
    assert main(["trace", "--results", str(res), "CAL-A-R1"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("trace CAL-A-R1 (certificate)") and "calibration CAL-A " in out


def test_an_unknown_certificate_and_bad_arguments_are_messages(tmp_path, capsys):
    assert main(["certificate", "NOPE", "--results", str(tmp_path), "--config", str(CONFIG)]) == 1
    assert "certificate 'NOPE': no issue recorded in" in capsys.readouterr().err
    assert main(["certificate", "--results", str(tmp_path), "--config", str(CONFIG)]) == 2
    assert "give a calibration id or certificate number, or --all" in capsys.readouterr().err
    assert (
        main(["certificate", "X", "--results", str(tmp_path), "--config", str(tmp_path / "none.yaml")]) == 2
    )
    assert "none.yaml: no such file" in capsys.readouterr().err
