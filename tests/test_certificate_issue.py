"""Reissue of certificates from the history (``borescan certificate``, :mod:`borescan.certificate_issue`):
deleted certificates come back byte-identical; a changed laboratory section gives new documents
(ISO/IEC 17025 7.8.8.2) that name the ones they replace; ``borescan trace`` lists every issue."""

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

from borescan.certificate_dcc import DCC_FILE
from borescan.cli import main

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "config.yaml"  # the pipeline_run fixture's laboratory section


def _files(folder: Path) -> dict[str, str]:
    """SHA-256 of every file below ``folder``, through its links (calibration/<device>/<id> -> night folder)."""
    out = {}
    for d, _dirs, names in os.walk(folder, followlinks=True):
        for n in names:
            if n != ".snakemake_timestamp":
                p = Path(d) / n
                out[str(p.relative_to(folder))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def results(pipeline_run, tmp_path_factory):
    res = tmp_path_factory.mktemp("reissue") / "results"
    shutil.copytree(pipeline_run["results"], res, symlinks=True)
    return res


@pytest.mark.slow
def test_deleted_certificates_come_back_byte_identical(results, capsys):
    before = _files(results / "calibration")
    n_docs = sum(1 for k in before if k.endswith("certificate.json"))
    assert n_docs >= 8  # four calibrations, each in its night folder and through its link
    shutil.rmtree(results / "calibration")
    assert main(["certificate", "--all", "--results", str(results), "--config", str(CONFIG)]) == 0
    out = capsys.readouterr().out
    assert _files(results / "calibration") == before
    assert "DIFFERS" not in out and out.count("reissued unchanged") == n_docs // 2
    assert out.count("agrees with calibrations.certificate_sha256 of the catalog") == n_docs // 2
    # a file edited on disk is reported, not trusted: the history writes it back
    cal_dir = next((results / "calibration").glob("ROD-01/*"))
    (cal_dir / "certificate.json").write_text("{}\n")
    assert main(["certificate", cal_dir.name, "--results", str(results), "--config", str(CONFIG),
                 "--format", "json"]) == 0
    assert _files(results / "calibration") == before


@pytest.mark.slow
def test_a_changed_laboratory_gives_new_documents_naming_the_ones_they_replace(results, tmp_path, capsys):
    cfg = yaml.safe_load(CONFIG.read_text())
    cfg["laboratory"] = dict(cfg["laboratory"], name="Example Metrology Lab", address="1 Gauge Street, Exampletown")
    new_cfg = tmp_path / "config.yaml"
    new_cfg.write_text(yaml.safe_dump(cfg))
    rod = next((results / "calibration").glob("ROD-01/*")).name
    original = json.loads((results / "calibration" / "ROD-01" / rod / "certificate.json").read_text())
    sha = hashlib.sha256((results / "calibration" / "ROD-01" / rod / "certificate.json").read_bytes()).hexdigest()
    args = ["certificate", rod, "--results", str(results), "--config", str(new_cfg), "--issue-date", "2026-12-01"]
    assert main(args) == 0
    assert f"{rod}-R1: NEW certificate issued 2026-12-01, replaces {rod}" in capsys.readouterr().out
    doc = results / "certificates" / rod / f"{rod}-R1"
    new = json.loads((doc / "certificate.json").read_text())
    assert new["administrativeData"]["coreData"]["uniqueIdentifier"] == f"{rod}-R1"
    assert new["dates"]["issue"] == "2026-12-01" and new["laboratory"]["name"] == "Example Metrology Lab"
    assert new["reissue"]["replaces"] == {"document_id": rod, "sha256": sha, "issue_date": original["dates"]["issue"]}
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
    # trace lists every issue
    assert main(["trace", rod, "--results", str(results)]) == 0
    out = capsys.readouterr().out
    assert f"issue 0: {rod} of {original['dates']['issue']}" in out
    assert f"issue 1: {rod}-R1 of 2026-12-01, replaces {rod}" in out
    assert f"issue 2: {rod}-R2 of 2026-12-02, replaces {rod}-R1" in out
    assert out.count("matches its record") == 3
    # a changed decision rule would change verdicts: refused, naming the certificate
    cfg["laboratory"]["decision_rule"] = "guard_band"
    new_cfg.write_text(yaml.safe_dump(cfg))
    assert main(args[:-2]) == 1
    err = capsys.readouterr().err
    assert f"certificate {rod}-R2: laboratory.decision_rule changed" in err
