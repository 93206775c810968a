"""The whole pipeline, run by Snakemake on the embedded demo nights (issue 6 tests)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import duckdb
import pytest

from conftest import checksums, run_snakemake

from borescan import rawio


def _con(run):
    return duckdb.connect(str(run["results"] / "catalog.duckdb"), read_only=True)


def test_pipeline_completes(pipeline_run):
    proc = pipeline_run["proc"]
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert (pipeline_run["results"] / "catalog.duckdb").is_file()
    assert (pipeline_run["results"] / "report.html").is_file()


def test_catalog_has_every_scan_with_checksums(pipeline_run):
    con = _con(pipeline_run)
    rows = con.execute("SELECT scan_id, night, status, raw_sha256 FROM scans").fetchall()
    n_raw = sum(1 for _ in pipeline_run["raw"].glob("night=*/scan=*"))
    assert len(rows) == n_raw
    ok = {r[0] for r in rows if r[2] == "ok"}
    # night 2's two calibration scans disagree (a 1.2 ms channel_delay on channel 2 of one of them):
    # no one beam geometry fits both to the noise, so that calibration is refused, not certified
    refused = {"N20261121-TRI01-CAL-P1-A", "N20261121-TRI01-CAL-P1-B"}
    assert ok == (set(pipeline_run["good_ids"]) - refused) | {pipeline_run["special"]["failed_verification"]}
    for scan_id in refused:
        status, reason = con.execute(
            "SELECT status, reason FROM scans WHERE scan_id = ?", [scan_id]
        ).fetchone()
        assert status == "quarantined"
        assert re.search(
            r"calibration refused: .*channel 2: residual rms is 1\.[3-9]\d times the readings' own "
            r"noise floor \(limit 1\.25\): the model misses an effect",
            reason,
        ), reason
    assert all(len(r[3]) == 64 for r in rows)
    for scan_id, night, file, sha in con.execute(
        "SELECT f.scan_id, s.night, f.file, f.sha256 FROM scan_files f JOIN scans s USING (scan_id, "
        "night) WHERE s.status = 'ok'"
    ).fetchall():
        assert rawio.sha256_file(pipeline_run["raw"] / f"night={night}" / f"scan={scan_id}" / file) == sha


def test_raw_files_untouched(pipeline_run):
    assert checksums(pipeline_run["raw"]) == pipeline_run["before"]


def test_rerun_does_nothing(pipeline_run):
    proc = run_snakemake(pipeline_run["raw"], pipeline_run["results"], "--dry-run")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Nothing to be done" in proc.stdout + proc.stderr


def test_slurm_profile_dry_run(tmp_path):
    """The SLURM profile (snakemake-executor-plugin-slurm) plans the whole workflow."""
    from borescan.synthetic import demo

    demo.make_demo(tmp_path / "demo")
    proc = run_snakemake(
        tmp_path / "demo" / "raw", tmp_path / "results", "--profile", "profiles/slurm", "--dry-run"
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout + proc.stderr
    assert "slurm_partition=compute" in out
    for rule in (
        "ingest_night",
        "signal_night",
        "calibrate_night",
        "measure_night",
        "build_catalog",
        "write_report",
    ):
        assert rule in out


def _truth_diameter(truth_root, scan_id, feature):
    """Return True diameter at the scan's temperature from the simulator's ground truth [mm]."""
    import json

    t = json.loads((truth_root / f"{scan_id}.truth.json").read_text())
    scene = t["scene"]
    if t["device_type"] == "rod":
        d20 = 2 * scene["holes"][int(feature.removeprefix("H")) - 1]["radius_mm"]
    else:
        d20 = 2 * scene["bore_radius_20_mm"]
    thermal = any(e["name"] == "thermal_expansion" for e in t["effects"])
    return d20 * (1 + scene["cte_per_k"] * (scene["temperature_c"] - 20)) if thermal else d20


def test_diameters_agree_with_simulated_truth_within_their_uncertainty(pipeline_run):
    """Every part and gauge diameter of the demo nights lies within 3 u of the truth."""
    rows = (
        _con(pipeline_run)
        .execute(
            "SELECT scan_id, feature, diameter_mm, u_diameter_mm, calibration_id FROM diameters "
            "WHERE night IN ('2026-11-20', '2026-11-21')"
        )
        .fetchall()
    )
    assert len(rows) == 18  # 5 static tri scans + 2 rod holes of the part + 2 of the gauge set per night
    tri_err, rod_err = [], []
    for scan_id, feature, d, u, cal_id in rows:
        truth = _truth_diameter(pipeline_run["truth"], scan_id, feature)
        assert abs(d - truth) <= 3 * u, (scan_id, feature, d - truth, u)
        assert cal_id, scan_id  # every result names the calibration it used
        if "-TRI" in scan_id:  # a three-sensor scan's one bore (feature B1 of a part, none of a gauge)
            tri_err.append(d - truth)
        else:
            assert "-rod_gauge-" in cal_id, (scan_id, cal_id)
            rod_err.append(d - truth)
    # the rod's base lengths are 12.3 / -8.7 um off its design (diameters 25 / 17 um off): its
    # ring-gauge calibration (night 1) brings the holes to an rms error below 12 um
    assert (sum(e * e for e in rod_err) / len(rod_err)) ** 0.5 <= 0.012, rod_err
    # three-sensor target of issue 5: <= 2 um RMS after the full-data calibration
    assert (sum(e * e for e in tri_err) / len(tri_err)) ** 0.5 <= 0.002


def test_verifications_pass_on_the_demo_nights(pipeline_run):
    rows = (
        _con(pipeline_run)
        .execute(
            "SELECT scan_id, error_mm, passed, feature FROM verifications WHERE night IN "
            "('2026-11-20', '2026-11-21')"
        )
        .fetchall()
    )
    assert len(rows) == 8 and all(
        r[2] for r in rows
    )  # 2 ring gauges of TRI-01 + 2 layers of ROD-01 per night
    assert all(abs(r[1]) < 0.002 for r in rows if r[3] is None)
    rod = [r[1] for r in rows if r[3] is not None]
    assert (sum(e * e for e in rod) / len(rod)) ** 0.5 < 0.012  # the rod, as its diameters above


def test_failed_verification_refuses_later_measurement_and_is_traceable(pipeline_run):
    con = _con(pipeline_run)
    ver = pipeline_run["special"]["failed_verification"]
    passed, error = con.execute(
        "SELECT passed, error_mm FROM verifications WHERE scan_id = ?", [ver]
    ).fetchone()
    assert not passed and abs(error + 0.05) < 0.003  # the gauge was labelled 50 um too large
    assert (
        con.execute(
            "SELECT count(*) FROM diameters WHERE scan_id = ?", [pipeline_run["special"]["refused"]]
        ).fetchone()[0]
        == 0
    )


def test_discrepancy_findings_for_every_examined_scan(pipeline_run):
    import json

    con = _con(pipeline_run)
    ok = [
        r[0]
        for r in con.execute(
            "SELECT scan_id FROM scans WHERE status = 'ok' AND night IN ('2026-11-20', '2026-11-21')"
        ).fetchall()
    ]
    for scan_id in ok:
        d = pipeline_run["results"] / "discrepancy" / scan_id
        f = json.loads((d / "findings.json").read_text())
        assert f["scan_id"] == scan_id
        assert f["verdict"] in ("missing_effect", "no_missing_effect", "ambiguous")
        assert {"gap_before", "gap_after", "noise_floor_mm", "named"} <= set(f)
        assert (d / "gap.png").stat().st_size > 10_000
    # the first night hides no effect at all
    verdicts = con.execute(
        "SELECT DISTINCT verdict FROM findings f JOIN scans s USING (scan_id) WHERE s.night = '2026-11-20'"
    ).fetchall()
    assert verdicts == [("no_missing_effect",)]
    # the second night hides a 1.2 ms channel_delay on channel 2 of one calibration scan
    named = con.execute(
        "SELECT effect, channel FROM findings WHERE scan_id = 'N20261121-TRI01-CAL-P1-B'"
    ).fetchall()
    assert ("channel_delay", 2) in named


def test_trace_follows_a_rod_diameter_to_its_gauge_calibration(pipeline_run):
    """A rod hole -> the rod's ring-gauge calibration -> its certificate, each layer's certified gauge
    and the layer-by-layer verifications.
    """
    from borescan import trace

    chain = trace.format_trace(trace.trace(pipeline_run["results"], "N20261121-ROD01-MEAS-CYL2H/H1"))
    for needle in (
        "-rod_gauge-",
        "method rod_gauge",
        "certificate.json sha256",
        "(matches catalog)",
        "calibration scan N20261120-ROD01-CAL-RGS150",
        "layer 1 (H1): ring gauge RG-150A, certificate RGS-150/2026-02, certified 150.0021 mm",
        "verified by N20261121-ROD01-VER-RGS150 layer H1 (RG-150A)",
    ):
        assert needle in chain, needle


def test_trace_follows_a_part_diameter_to_raw_files(pipeline_run):
    from borescan import trace

    chain = trace.format_trace(trace.trace(pipeline_run["results"], "N20261120-TRI01-MEAS-HSG1101"))
    for needle in (
        "TRI-01-20261120-full_lsq",
        "certificate.pdf",
        "N20261120-TRI01-CAL-P1-A",
        "RG-275",
        "lds.parquet",
    ):
        assert needle in chain


def _nothing_to_do(out: str) -> bool:
    """Snakemake's dry run planned no job."""
    import re

    return "Nothing to be done" in out or re.search(r"^total\s+0$", out, re.M) is not None


def _copy_night(src_raw, dst_raw, night):
    import shutil

    shutil.copytree(src_raw / f"night={night}", dst_raw / f"night={night}")


def test_adding_a_night_reprocesses_only_that_night(pipeline_run, tmp_path):
    """Process one night, add the next: only the new night's stage jobs (and catalog, report) run."""
    raw, res = tmp_path / "raw", tmp_path / "results"
    _copy_night(pipeline_run["raw"], raw, "2026-11-20")
    assert run_snakemake(raw, res, "--until", "ingest_night").returncode == 0
    _copy_night(pipeline_run["raw"], raw, "2026-11-21")
    proc = run_snakemake(raw, res, "--until", "ingest_night", "--dry-run")
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-2000:]
    import re

    assert re.search(r"^ingest_night\s+1$", out, re.M), out[-2000:]  # one night to ingest: the new one
    # the rule's message names the night (the default profile prints messages, not each job's output files)
    assert "Validating and registering the scans of night 2026-11-21" in out, out[-2000:]


def test_two_runs_at_once_do_not_corrupt_results(pipeline_run, tmp_path):
    """Two snakemake runs started together on the same results: one may be refused (locked), none corrupts."""
    import subprocess

    from conftest import ROOT, SNAKEMAKE, workflow_env

    raw, res = tmp_path / "raw", tmp_path / "results"
    _copy_night(pipeline_run["raw"], raw, "2026-11-20")
    cmd = [
        str(SNAKEMAKE),
        "--cores",
        "1",
        "--config",
        f"raw_root={raw}",
        f"results_root={res}",
        "--until",
        "measure_night",
    ]
    env = workflow_env(tmp_path)
    procs = [
        subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for _ in range(2)
    ]
    outs = [p.communicate(timeout=600)[0] for p in procs]
    codes = [p.returncode for p in procs]
    assert 0 in codes, outs
    for code, out in zip(codes, outs):
        if code != 0:
            assert "lock" in out.lower(), out[-2000:]
    # whatever happened, a further run finds everything complete and consistent
    proc = run_snakemake(raw, res, "--until", "measure_night", "--dry-run")
    assert proc.returncode == 0 and _nothing_to_do(proc.stdout + proc.stderr), proc.stdout[-2000:]


def test_interrupted_run_resumes(pipeline_run, tmp_path):
    """A run killed mid-way leaves no corrupt output; the next run completes the rest."""
    import signal
    import subprocess
    import time

    import polars as pl

    from conftest import ROOT, SNAKEMAKE, workflow_env

    raw, res = tmp_path / "raw", tmp_path / "results"
    _copy_night(pipeline_run["raw"], raw, "2026-11-20")
    cmd = [
        str(SNAKEMAKE),
        "--cores",
        "2",
        "--config",
        f"raw_root={raw}",
        f"results_root={res}",
        "--until",
        "calibrate_night",
    ]
    env = workflow_env(tmp_path)
    p = subprocess.Popen(
        cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    deadline = time.time() + 120
    while time.time() < deadline and not (res / "stage" / "signal_summary").exists():
        time.sleep(0.2)
    os_killpg = __import__("os").killpg
    os_killpg(
        p.pid, signal.SIGINT
    )  # Ctrl-C during calibration (a power loss needs `snakemake --unlock` first)
    p.wait()
    for f in res.rglob("*.parquet"):
        pl.read_parquet(f)  # nothing half-written
    proc = run_snakemake(raw, res, "--until", "calibrate_night")
    assert proc.returncode == 0, proc.stderr[-3000:]
    cals = pl.read_parquet(res / "stage" / "calibrations" / "night=2026-11-20.parquet")
    assert cals.filter(pl.col("method") == "full_lsq").height == 3


def test_night_jobs_spread_scans_over_two_processes(pipeline_run):
    """A demo night (11 scans) is examined on 2 worker processes inside one job, every scan once,
    in scan order (the findings table does not depend on the number of workers).
    """
    import polars as pl

    res = pipeline_run["results"]
    log = (res / "logs" / "discrepancy_night" / "2026-11-20.log").read_text()
    assert "11 scans on 2 process(es)" in log
    f = pl.read_parquet(res / "stage" / "findings" / "night=2026-11-20.parquet")
    ids = f["scan_id"].unique(maintain_order=True).to_list()
    scans = pl.read_parquet(res / "stage" / "scans" / "night=2026-11-20.parquet")
    assert ids == sorted(ids) and set(ids) == set(scans["scan_id"])


def test_a_stage_script_runs_by_hand_and_gives_the_rules_output(pipeline_run, tmp_path):
    """`python workflow/scripts/<rule>.py night=... raw_root=... results_root=...` builds the rule's
    job from the Snakefile (for debugging one stage of one night) and writes what the rule wrote:
    to the last bit, though by hand a stage runs in one process and in the workflow on two (the
    first demo night's two calibrations, a three-sensor device and a rod, each on its own).
    """
    import polars as pl

    from conftest import ROOT

    night = sorted(p.name.removeprefix("night=") for p in pipeline_run["raw"].glob("night=*"))[0]
    for script, table in (
        ("ingest_night", "scans"),
        ("signal_night", "signal_summary"),
        ("calibrate_night", "calibrations"),
    ):
        proc = subprocess.run(
            [
                sys.executable,
                str(ROOT / "workflow" / "scripts" / f"{script}.py"),
                f"night={night}",
                f"raw_root={pipeline_run['raw']}",
                f"results_root={tmp_path}",
            ],
            capture_output=True,
            text=True,
            cwd=tmp_path,
            timeout=300,
            env={**os.environ, "MPLBACKEND": "Agg"},
        )
        assert proc.returncode == 0, proc.stderr[-2000:]
        by_hand = pl.read_parquet(tmp_path / "stage" / table / f"night={night}.parquet")
        by_rule = pl.read_parquet(pipeline_run["results"] / "stage" / table / f"night={night}.parquet")
        # every process computing a stage's items has one BLAS thread (parallel.start_job_workers), by hand
        # as in the workflow; yet on an AMD EPYC host the last bits differed between the two (SIMD loops may
        # round by where an array starts in memory, which differs from process to process), and an iteration
        # that stops on a tolerance carries such bits further: equal within their uncertainty, never
        # rounding noise
        _assert_equal_within_uncertainty(by_hand, by_rule, table)
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "workflow" / "scripts" / "signal_night.py"),
            f"raw_root={pipeline_run['raw']}",
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=300,
    )
    assert proc.returncode != 0 and "needs the wildcard(s) ['night']" in proc.stderr


def test_every_file_the_papers_rule_writes_is_declared(pipeline_run):
    """The reproduction's files are the rule's declared outputs (index.csv lists what it wrote):
    deleting one and rerunning regenerates it, and `snakemake --report` can show them.
    """
    import polars as pl

    from conftest import ROOT

    papers = pipeline_run["results"] / "papers"
    written = set(pl.read_csv(papers / "index.csv")["file"]) | {"index.csv", "index.parquet"}
    assert written == {p.name for p in papers.iterdir() if p.is_file()}
    smk = (ROOT / "rules" / "papers.smk").read_text()
    declared = set(re.findall(r'f"\{RES\}/papers/([^"]+)"', smk))
    assert declared == written


def test_a_device_model_is_carried_by_a_night_calibration(pipeline_run, tmp_path):
    """The calibrate stage of the first demo night with a device model in the config (devices: TRI-01:
    effects: [...]) and an earlier night's pooled findings: a sensor gain of channel 2 estimated there as 0 +-
    2e-4 is carried
    (the readings are corrected by a factor 1: the beams are the run's own to rounding), the budget
    gains its input (u(d_b) grows), the certificate names it; an effect listed without an estimate is
    said so and changes nothing.
    """
    import json

    import polars as pl

    from borescan import night_config
    from borescan.config import schema_defaults
    from borescan.stages.calibrate import stage_calibrate
    from borescan.uncertainty import Budget

    raw, res = pipeline_run["raw"], pipeline_run["results"]
    n2 = sorted(p.name.removeprefix("night=") for p in raw.glob("night=*"))[0]  # the first demo night
    n1 = "2026-11-19"  # a pooled examination of the night before
    pooled = tmp_path / "pooled.parquet"
    pl.DataFrame(
        [
            {
                "night": n1,
                "device_id": "TRI-01",
                "effect": "sensor_gain",
                "channel": 2,
                "parameters": json.dumps({"g": 0.0}),
                "uncertainties": json.dumps({"u_g": 2e-4}),
                "evidence_scans": "A,B",
                "in_device_model": False,
            }
        ]
    ).write_parquet(pooled)
    cfg = schema_defaults()
    night_config.settle(tmp_path, [n2], cfg)  # the night's record (date of issue), as the workflow first does
    # the run's readings store (ingest's output, what the calibrate stage reads) under this results root
    store = Path("stage") / "readings" / f"night={n2}"
    shutil.copytree(res / store, tmp_path / store)
    lines = []
    cals, _, bad = stage_calibrate(
        raw,
        n2,
        tmp_path,
        res / "stage" / "scans" / f"night={n2}.parquet",
        res / "stage" / "signal_summary" / f"night={n2}.parquet",
        cfg["calibration"],
        log=lines.append,
        devices={"TRI-01": {"effects": ["sensor_gain@2", "sensor_offset@3"]}},
        pooled_tables=[pooled],
    )
    assert not bad
    run = pl.read_parquet(res / "stage" / "calibrations" / f"night={n2}.parquet").filter(
        pl.col("device_id") == "TRI-01"
    )
    mine = cals.filter(pl.col("device_id") == "TRI-01")
    assert mine["beta_rad"].to_list() == pytest.approx(run["beta_rad"].to_list(), abs=1e-12)
    assert mine["d_b_mm"].to_list() == pytest.approx(run["d_b_mm"].to_list(), abs=1e-9)
    assert mine["u_d_b_mm"][1] > run["u_d_b_mm"][1]  # channel 2's gain is uncertain by 2e-4 of its reading
    cal = json.loads(mine["calibration_json"][0])
    (gain, offset) = cal["diagnostics"]["device_model"]
    assert gain["key"] == "sensor_gain@2" and gain["night"] == n1 and gain["u"] == {"g": 2e-4}
    assert offset["key"] == "sensor_offset@3" and not offset["estimated"]
    b = Budget.from_dict(cal["diagnostics"]["budget"])
    assert [t.input.key for t in b.terms if t.input.key.startswith("device_model:")] == [
        f"device_model:TRI-01:sensor_gain@2:g@{n1}"
    ]
    cert = json.loads(
        next((tmp_path / "calibration").glob(f"night={n2}/TRI-01/*/certificate.json")).read_text()
    )
    assert [m["key"] for m in cert["fit"]["device_model"]] == ["sensor_gain@2", "sensor_offset@3"]
    assert any("sensor_offset@3 (config) not estimated yet" in x for x in lines)


def test_the_demo_closes_the_loop(pipeline_run):
    """The demo's loop nights through the real run (config/config.yaml dates channel_delay@2 from
    2026-11-24): the pooled examination of 2026-11-23 (60 and 30 rpm) names the 1.2 ms delay of the
    truth within 4 u, the single scans did not get it (their values are absorbed by that night's
    beta); the calibration of 2026-11-24 carries that estimate and its residual falls to the noise,
    that night's scans have nothing missing, and the report draws the gaps with the change marked.
    """
    import json

    import duckdb

    from borescan.synthetic.demo import LOOP_NIGHTS

    res = pipeline_run["results"]
    truth_tau = 0.0012
    con = duckdb.connect(str(res / "catalog.duckdb"), read_only=True)
    examined, carrying = LOOP_NIGHTS
    named = con.execute(
        "SELECT verdict, parameters, uncertainties, evidence_scans, in_device_model FROM pooled_findings "
        "WHERE night = ? AND device_id = 'TRI-01' AND effect = 'channel_delay' AND channel = 2",
        [examined],
    ).fetchall()
    assert len(named) == 1 and named[0][0] == "missing_effect" and not named[0][4]
    tau, u_tau = json.loads(named[0][1])["tau_s"], json.loads(named[0][2])["u_tau_s"]
    assert abs(tau - truth_tau) < 4 * u_tau and u_tau < 1e-4
    assert named[0][3] == "N20261123-TRI01-CAL-P1-A,N20261123-TRI01-CAL-P1-B"
    single = [
        json.loads(p)["tau_s"]
        for (p,) in con.execute(
            "SELECT parameters FROM findings WHERE night = ? AND effect = 'channel_delay'", [examined]
        ).fetchall()
    ]
    assert single and all(abs(t - truth_tau) > 4 * u_tau for t in single)

    def calibration(night):
        (cj,) = con.execute(
            "SELECT DISTINCT calibration_json FROM calibrations WHERE night = ? AND device_id = 'TRI-01'",
            [night],
        ).fetchone()
        d = json.loads(cj)
        worst = max(max(x for x in nu["residual_to_noise"] if x is not None) for nu in d["nuisance"].values())
        return d["diagnostics"].get("device_model") or [], worst

    before_model, before = calibration(examined)
    model, after = calibration(carrying)
    assert before_model == []  # the config's entry applies from 2026-11-24
    (entry,) = model
    assert entry["key"] == "channel_delay@2" and entry["night"] == examined and entry["estimated"]
    assert entry["values"]["tau_s"] == pytest.approx(tau, rel=1e-9)
    assert after < before and after <= 1.05
    verdicts = con.execute("SELECT DISTINCT verdict FROM findings WHERE night = ?", [carrying]).fetchall()
    assert verdicts == [("no_missing_effect",)]
    assert (res / "report" / carrying[:7] / "devicemodel_TRI-01.png").is_file()


#: values found by an iteration that stops at a stated fraction of their uncertainty, compared to it: a
#: rod's base lengths l0 settle when the solve's radii are within 1e-3 u of the gauges'
#: (rod_calibration.calibrate_l0); on an AMD EPYC host the process layout's last bits moved the stop from
#: solve 2 to solve 4 (l0 5e-6 mm apart)
SETTLED_TO_U = {"l0_mm": 1e-3}
#: JSON keys that count the solver's steps, not a result: they follow the stop above
SOLVER_PATH_KEYS = {"iterations"}


def _assert_equal_within_uncertainty(a, b, table: str) -> None:
    """Check every non-float column equal and every float column within its uncertainty.

    A float column X with a column u_X within 1e-6 u_X (a millionth of its standard uncertainty; an
    iterated value within the fraction of u_X it settles to, ``SETTLED_TO_U``); an
    uncertainty (u_X, expanded_u_X; known to a few per cent at best) and any other float column to a
    relative 1e-6; all of them at least to 1e-12 (a value at zero, such as the period's uncertainty of a
    scan whose revolutions all have the same length).
    """
    import numpy as np
    import polars as pl
    from polars.testing import assert_frame_equal

    assert a.columns == b.columns and a.height == b.height, table
    floats = [c for c, t in a.schema.items() if t in (pl.Float64, pl.Float32)]
    # certificate.json prints the same floats to their last digit, so its digest differs with them
    digests_of_floats = [c for c in ("certificate_sha256",) if c in a.columns]
    # a JSON column (the calibration's) is compared number by number like the float columns
    json_cols = [c for c in a.columns if c.endswith("_json")]
    drop = floats + digests_of_floats + json_cols
    assert_frame_equal(a.drop(drop), b.drop(drop), check_exact=True)
    for col in json_cols:
        for x, y in zip(a[col].to_list(), b[col].to_list(), strict=True):
            _assert_json_close(
                None if x is None else json.loads(x), None if y is None else json.loads(y), col
            )
    for col in floats:
        x, y = a[col].to_numpy().astype(float), b[col].to_numpy().astype(float)
        assert np.array_equal(np.isnan(x), np.isnan(y)), (table, col)
        ok = ~np.isnan(x)
        if f"u_{col}" in a.columns:
            tol = SETTLED_TO_U.get(col, 1e-6) * np.abs(b[f"u_{col}"].to_numpy().astype(float))
            tol = np.where(np.isfinite(tol), tol, 1e-9 * np.abs(y))
        else:
            tol = (
                1e-6 * np.abs(y) + 1e-12
            )  # an uncertainty (u_, expanded_u_) or a value without one; 1e-12 floor
        diff = np.abs(x - y)
        assert np.all(diff[ok] <= tol[ok]), (table, col, float(np.max(diff[ok] - tol[ok])))


def _assert_json_close(x, y, where: str) -> None:
    """Check equal JSON values, numbers to a relative 1e-4 (at least 1e-12).

    The calibration's JSON holds finite-difference sensitivities of its budget, which carry the processes'
    last-bit differences up to a relative 3e-6 on an AMD EPYC host; an uncertainty is known to a few per cent
    at best, and the calibrated values themselves are compared to a millionth of their u in their columns.
    """
    if isinstance(x, dict) and isinstance(y, dict):
        assert x.keys() == y.keys(), where
        for k in x:
            if k not in SOLVER_PATH_KEYS:
                _assert_json_close(x[k], y[k], f"{where}.{k}")
    elif isinstance(x, list) and isinstance(y, list):
        assert len(x) == len(y), where
        numbers = all(isinstance(v, float | int) and not isinstance(v, bool) for v in x + y)
        if numbers and y:  # a vector (sensitivities): to 1e-4 of its largest element, a zero's noise included
            scale = max(abs(v) for v in y)
            assert all(abs(u - v) <= 1e-4 * scale + 1e-12 for u, v in zip(x, y, strict=True)), (where, x, y)
            return
        for i, (u, v) in enumerate(zip(x, y, strict=True)):
            _assert_json_close(u, v, f"{where}[{i}]")
    elif isinstance(x, float | int) and isinstance(y, float | int) and not isinstance(x, bool):
        assert abs(x - y) <= 1e-4 * abs(y) + 1e-12, (where, x, y)
    else:
        assert x == y, where
