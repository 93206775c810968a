"""The command line without rough edges (issue 20 item 4): user errors give a message and exit 2 (1 where
the answer is "no"), never a traceback; argument checks; progress; sql output; closed pipes; paths;
times with their zone; `borescan status`.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from test_catalog import built  # noqa: F401 (the constructed catalog fixture, shared)

from borescan.synthetic import simulate
from borescan.cli import main
from borescan.commands import sql as sql_cmd
from borescan.commands._common import utc_text

BORESCAN = Path(sys.executable).with_name("borescan")


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    """Exit code, stdout, stderr of ``borescan argv`` in this process (argparse errors included)."""
    try:
        code = main(list(argv))
    except SystemExit as e:  # argparse: usage line + message, exit 2
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


# --------------------------------------------------------------------------- simulate


@pytest.fixture()
def one_scan(tmp_path, capsys):
    raw, truth = tmp_path / "raw", tmp_path / "truth"
    code, out, _ = _run(
        capsys,
        "simulate",
        "tri",
        "--raw-root",
        str(raw),
        "--truth-root",
        str(truth),
        "--n-rev",
        "2",
        "--scan-id",
        "T1",
    )
    assert code == 0 and out.strip() == str(raw / "night=2026-11-20" / "scan=T1")
    return raw, truth


def test_simulate_existing_scan_id_is_a_message_not_a_traceback(one_scan, capsys):
    raw, truth = one_scan
    code, out, err = _run(
        capsys,
        "simulate",
        "tri",
        "--raw-root",
        str(raw),
        "--truth-root",
        str(truth),
        "--n-rev",
        "2",
        "--scan-id",
        "T1",
        "--seed",
        "5",
    )
    assert (code, out) == (2, "")
    assert err == (
        "borescan simulate: T1: night=2026-11-20/scan=T1: exists with different content "
        "(raw folders are write-once); choose another --scan-id (or another --raw-root)\n"
    )
    # the same command again is a no-op (write-once, same content)
    code, out, _ = _run(
        capsys,
        "simulate",
        "tri",
        "--raw-root",
        str(raw),
        "--truth-root",
        str(truth),
        "--n-rev",
        "2",
        "--scan-id",
        "T1",
    )
    assert code == 0 and out.strip().endswith("scan=T1")


@pytest.mark.parametrize(
    "args, message",
    [
        (["--scan-id", "a/b"], "argument --scan-id: 'a/b' is not a scan id (1-64 of A-Z a-z 0-9 _ -)"),
        (["--night", "2026-13-45"], "argument --night: expected a date YYYY-MM-DD, got '2026-13-45'"),
        (["--night", "yesterday"], "argument --night: expected a date YYYY-MM-DD, got 'yesterday'"),
        (
            ["--effect", "channel_delay:tau_s=abc"],
            "argument --effect: effect 'channel_delay': parameter 'tau_s': 'abc' is not a number",
        ),
        (["--n-rev", "0"], "argument --n-rev: must be > 0, got 0"),
        (["--noise-mm", "nan"], "argument --noise-mm: expected a finite number, got 'nan'"),
    ],
)
def test_simulate_argument_errors_name_the_argument(tmp_path, capsys, args, message):
    code, out, err = _run(
        capsys,
        "simulate",
        "tri",
        "--raw-root",
        str(tmp_path / "raw"),
        "--truth-root",
        str(tmp_path / "truth"),
        *args,
    )
    assert (code, out) == (2, "")
    assert err.splitlines()[-1] == f"borescan simulate tri: error: {message}"
    assert not (tmp_path / "raw").exists()


@pytest.mark.parametrize(
    "effect, message",
    [
        ("bogus:a=1", "unknown effect 'bogus'; valid effects: sensor_offset, "),
        ("channel_delay:tau=1", "effect 'channel_delay' takes parameters ['channel', 'tau_s'], got ['tau']"),
        (
            "channel_delay:channel=9,tau_s=0.001",
            "effect 'channel_delay' names channel 9, device has channels (1, 2, 3)",
        ),
    ],
)
def test_simulate_bad_effects_exit_2_with_the_reason(tmp_path, capsys, effect, message):
    code, out, err = _run(
        capsys,
        "simulate",
        "tri",
        "--raw-root",
        str(tmp_path / "raw"),
        "--truth-root",
        str(tmp_path / "truth"),
        "--n-rev",
        "1",
        "--effect",
        effect,
    )
    assert (code, out) == (2, "")
    assert err.startswith(f"borescan simulate: {message}") and err.count("\n") == 1


def test_simulate_refuses_truth_inside_the_raw_root(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = _run(capsys, "simulate", "rod", "--raw-root", "raw", "--truth-root", "raw/truth")
    assert (code, out) == (2, "")
    assert err.startswith("borescan simulate: --truth-root raw/truth is inside --raw-root raw; ground truth")
    assert not (tmp_path / "raw").exists()
    # a relative raw root and an absolute truth root outside it are fine
    code, out, _ = _run(
        capsys, "simulate", "rod", "--raw-root", "raw", "--truth-root", str(tmp_path / "truth")
    )
    assert code == 0 and (tmp_path / "truth" / "SIM-ROD.truth.json").is_file()
    assert _run(capsys, "validate", "raw")[:2] == (0, "1 scans, all valid\n")


# --------------------------------------------------------------------------- discrepancy-battery


@pytest.mark.parametrize(
    "args, message",
    [
        (["--n", "0"], "argument --n: must be >= 1, got 0"),
        (["--n", "-3"], "argument --n: must be >= 1, got -3"),
        (["--p-free", "1.5"], "argument --p-free: must be a share between 0 and 1, got 1.5"),
        (["--p-pair", "-0.1"], "argument --p-pair: must be a share between 0 and 1, got -0.1"),
        (["--scale", "0"], "argument --scale: must be > 0, got 0"),
        (["--threshold", "inf"], "argument --threshold: expected a finite number, got 'inf'"),
    ],
)
def test_battery_argument_checks(capsys, args, message):
    code, out, err = _run(capsys, "discrepancy-battery", *args)
    assert (code, out) == (2, "")
    assert err.splitlines()[-1] == f"borescan discrepancy-battery: error: {message}"


def test_battery_shares_must_add_up(capsys):
    code, out, err = _run(capsys, "discrepancy-battery", "--p-free", "0.7", "--p-pair", "0.5")
    assert (code, out) == (2, "")
    assert (
        err == "borescan discrepancy-battery: --p-free 0.7 + --p-pair 0.5 exceed 1 (they are shares of the "
        "scans)\n"
    )


@pytest.mark.slow
def test_battery_reports_progress_and_no_nan(capsys):
    """Two scans with effects (no effect-free scan drawn): the false-alarm rate is n/a, not nan%."""
    code, out, err = _run(capsys, "discrepancy-battery", "--n", "2", "--p-free", "0", "--seed", "2")
    assert code == 0
    assert "nan" not in out
    assert "false-alarm rate    n/a (no effect-free scans drawn)" in out
    lines = err.splitlines()
    assert [re.sub(r",.*", "", x) for x in lines] == ["examined 1/2 (50 %)", "examined 2/2 (100 %)"]
    assert lines[-1].endswith("BAT2-0001")


# --------------------------------------------------------------------------- sql


def test_sql_table_is_rounded_and_aligned_on_the_decimal_point(built, capsys):  # noqa: F811
    res, _ = built
    code, out, _ = _run(
        capsys,
        "sql",
        "--results",
        str(res),
        "SELECT scan_id, measured_mm, error_mm FROM verifications ORDER BY scan_id",
    )
    assert code == 0
    lines = out.splitlines()
    assert lines[0].split() == ["scan_id", "measured_mm", "error_mm"]
    # 275.029 + 0.004 etc.: 7 significant digits, positional, no float noise
    assert [x.split() for x in lines[2:]] == [
        ["VER-20", "275.033", "0.004"],
        ["VER-21", "275.049", "0.02"],
        ["VER-22", "275.028", "-0.001"],
    ]
    for col in (1, 2):  # decimal points in one column
        ends = {line.index(line.split()[col]) + line.split()[col].index(".") for line in lines[2:]}
        assert len(ends) == 1
    assert max(len(x) for x in lines) < 60


def test_sql_digits_width_and_times_with_zone(built, capsys):  # noqa: F811
    res, _ = built
    q = (
        "SELECT scan_id, started_at, raw_path, 1.0 / 3 AS third, 123456.789 AS big FROM scans "
        "WHERE scan_id = 'PART-9'"
    )
    code, out, _ = _run(capsys, "sql", "--results", str(res), "--digits", "3", "--max-width", "20", q)
    assert code == 0
    row = out.splitlines()[2].split()
    # +01:00 in the raw metadata, UTC in the catalog, shown with its zone
    assert row[:2] == ["PART-9", "2026-11-21T22:30:00Z"]
    assert len(row[2]) == 20 and row[2].endswith("scan=PART-9") and "\u2026" in row[2]
    assert row[3:] == ["0.333", "123457"]
    code, out, _ = _run(capsys, "sql", "--results", str(res), "--format", "csv", q)
    header, line = out.splitlines()
    assert header == "scan_id,started_at,raw_path,third,big"
    assert line.split(",")[1] == "2026-11-21T22:30:00Z" and line.split(",")[3] == repr(1.0 / 3)
    code, out, _ = _run(capsys, "sql", "--results", str(res), "--format", "json", q)
    assert json.loads(out)[0]["started_at"] == "2026-11-21T22:30:00Z"


def test_sql_errors(built, capsys):  # noqa: F811
    res, _ = built
    assert _run(capsys, "sql", "--results", str(res))[0::2] == (
        2,
        'borescan sql: give SQL text (borescan sql "SELECT * FROM scans") or --query NAME\n',
    )
    assert _run(capsys, "sql", "--results", str(res), "--query", "suspect_measurements", "SELECT 1")[
        0::2
    ] == (2, "borescan sql: give either SQL text or --query NAME, not both\n")
    code, _, err = _run(capsys, "sql", "--results", str(res), "SELEC 1")
    assert code == 1 and err.startswith("borescan sql: Parser Error") and "Traceback" not in err
    code, _, err = _run(capsys, "sql", "--results", str(res), "--digits", "0", "SELECT 1")
    assert code == 2 and err.splitlines()[-1] == "borescan sql: error: argument --digits: must be >= 1, got 0"


def test_number_cells_closed_form():
    # the point of "275.0291" under that of "-0.00004214242" (11 decimals): 7 spaces after it, 12 after "3"
    assert sql_cmd._number_cells([275.02912345678, -0.0000421424242, None, 3], 7) == [
        "275.0291" + " " * 7,
        "-0.00004214242",
        "",
        "3" + " " * 12,
    ]
    assert sql_cmd._round(1e-12, 4) == "1e-12" and sql_cmd._round(0.0, 4) == "0"
    assert sql_cmd._cut("abcdefghijklmnopqrstuvwxyz", 10) == "abc\u2026uvwxyz"


def test_sql_on_a_closed_pipe_is_quiet(built):  # noqa: F811
    res, _ = built
    proc = subprocess.Popen(
        [str(BORESCAN), "sql", "--results", str(res), "--format", "csv", "SELECT * FROM range(300000)"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout.readline() == b"range\n"
    proc.stdout.close()  # what `| head -1` does
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 141  # 128 + SIGPIPE, as the shell reports a closed pipe
    assert err == ""


# --------------------------------------------------------------------------- trace


def test_trace_certificate_path_relative_to_the_current_folder(built, capsys, monkeypatch):  # noqa: F811
    res, _ = built
    monkeypatch.chdir(res.parent)
    rel = "results/calibration/TRI-01/CAL-A/certificate.pdf"
    for ident in (rel, "calibration/TRI-01/CAL-A/certificate.pdf", str(res.parent / rel)):
        code, out, _ = _run(capsys, "trace", "--results", "results", ident)
        assert code == 0, ident
        assert out.splitlines()[0] == f"trace {ident} (certificate)"
        assert "calibration CAL-A  device TRI-01" in out
    monkeypatch.chdir(res)
    code, out, _ = _run(capsys, "trace", "--results", ".", "calibration/TRI-01/CAL-A/certificate.pdf")
    assert code == 0 and "calibration CAL-A" in out
    code, out, err = _run(capsys, "trace", "--results", ".", "calibration/TRI-01/NOPE/certificate.pdf")
    assert (code, out) == (1, "") and err.startswith("borescan trace: unknown id 'calibration/TRI-01/NOPE/")


def test_trace_json_times_carry_their_zone(built, capsys):  # noqa: F811
    res, _ = built
    code, out, _ = _run(capsys, "trace", "--results", str(res), "--json", "PART-9")
    assert code == 0
    assert json.loads(out)["scan"]["started_at"] == "2026-11-21T22:30:00Z"


def test_utc_text():
    import datetime as dt

    assert utc_text(dt.datetime(2026, 11, 21, 22, 30)) == "2026-11-21T22:30:00Z"
    plus1 = dt.timezone(dt.timedelta(hours=1))
    assert utc_text(dt.datetime(2026, 11, 21, 23, 30, 0, 1600, tzinfo=plus1)) == "2026-11-21T22:30:00.001600Z"


# --------------------------------------------------------------------------- status


def test_status_lists_devices_calibration_validity_and_last_verification(built, capsys):  # noqa: F811
    res, _ = built
    code, out, _ = _run(
        capsys, "status", "--results", str(res), "--as-of", "2026-11-23", "--validity-days", "30"
    )
    assert code == 0
    assert (
        out.splitlines()[0]
        == "status as of 2026-11-23 (UTC); a calibration is valid for 30 days (--validity-days)"
    )
    blocks = {b.splitlines()[0].split()[0]: b for b in out.split("\n\n")[1:]}
    assert set(blocks) == {"ROD-01", "TRI-01"}
    tri = blocks["TRI-01"].splitlines()
    assert tri[0] == "TRI-01 (tri_lds)  last scan 2026-11-22T23:00:00Z"
    assert tri[1] == (
        "  calibration   CAL-B  full_lsq, from 2026-11-22, valid until 2026-12-22 (29 days left)  VALID"
    )
    assert tri[2] == "  certificate   calibration/TRI-01/CAL-B/certificate.pdf"
    assert tri[3] == "  verification  VER-22 on 2026-11-22: error -0.0010 mm (tolerance 0.015 mm) passed"
    rod = blocks["ROD-01"].splitlines()
    assert rod[1].startswith("  calibration   ROD-CAL-1  wang_joint, from 2026-11-21, valid until 2026-12-21")
    assert rod[-1] == "  verification  none"


def test_status_failed_and_expired_calibrations(built, capsys):  # noqa: F811
    res, _ = built
    # the 21st: CAL-A failed VER-21 that night; measurements are refused
    code, out, _ = _run(
        capsys,
        "status",
        "--results",
        str(res),
        "--as-of",
        "2026-11-21",
        "--format",
        "json",
        "--validity-days",
        "30",
        "--check",
    )
    assert code == 1  # --check: a device without a valid calibration
    tri = {d["device_id"]: d for d in json.loads(out)["devices"]}["TRI-01"]
    assert tri["state"] == "failed verification" and tri["calibration"]["calibration_id"] == "CAL-A"
    assert tri["reason"] == "latest calibration CAL-A of device TRI-01 failed its verification; recalibrate"
    assert tri["last_verification"] == {
        "scan_id": "VER-21",
        "night": "2026-11-21",
        "calibration_id": "CAL-A",
        "error_mm": pytest.approx(0.020, abs=1e-9),
        "tolerance_mm": 0.015,
        "passed": False,
        "verdict": None,
    }  # no statement in this history
    # 31 days after the 22nd: CAL-B expired (a calibration is valid through valid_from + validity_days)
    code, out, _ = _run(
        capsys, "status", "--results", str(res), "--as-of", "2026-12-23", "--validity-days", "30"
    )
    assert code == 0
    assert (
        "  calibration   CAL-B  full_lsq, from 2026-11-22, expired on 2026-12-22 (1 days ago)  EXPIRED"
        in out.splitlines()
    )
    code, out, _ = _run(
        capsys, "status", "--results", str(res), "--as-of", "2026-12-22", "--validity-days", "30"
    )
    assert "valid until 2026-12-22 (0 days left)  VALID" in out
    # before anything was scanned
    code, out, _ = _run(capsys, "status", "--results", str(res), "--as-of", "2026-01-01")
    assert (
        code == 0 and out.splitlines()[-1] == "no device has a scan or a calibration on or before 2026-01-01"
    )


def test_status_errors(tmp_path, capsys):
    code, out, err = _run(capsys, "status", "--results", str(tmp_path / "none"))
    assert (code, out) == (1, "") and err.startswith("borescan status: no history catalog at ")
    code, _, err = _run(capsys, "status", "--results", str(tmp_path), "--config", str(tmp_path / "c.yaml"))
    assert code == 2 and err == f"borescan status: config file {tmp_path / 'c.yaml'} does not exist\n"
    code, _, err = _run(capsys, "status", "--as-of", "2026-02-30")
    assert code == 2 and err.splitlines()[-1].endswith("expected a date YYYY-MM-DD, got '2026-02-30'")


# --------------------------------------------------------------------------- everything else


def test_missing_paths_are_usage_errors(tmp_path, capsys):
    assert _run(capsys, "validate", str(tmp_path / "raw"))[0::2] == (
        2,
        f"borescan validate: raw root {tmp_path / 'raw'} does not exist\n",
    )
    (tmp_path / "file").write_text("x")
    assert _run(capsys, "validate", str(tmp_path / "file"))[0::2] == (
        2,
        f"borescan validate: raw root {tmp_path / 'file'} is not a folder\n",
    )
    code, _, err = _run(
        capsys,
        "import-csv",
        str(tmp_path / "x.csv"),
        "--meta",
        str(tmp_path / "m.json"),
        "--raw-root",
        str(tmp_path / "raw"),
    )
    assert (code, err) == (2, f"borescan import-csv: CSV file {tmp_path / 'x.csv'} does not exist\n")


def test_demo_into_a_folder_with_other_scans(tmp_path, capsys):
    sim = simulate.simulate_rod(None, scan_id="N20261120-ROD01-MEAS-CYL2H", night="2026-11-20", seed=99)
    simulate.write_simulated(sim, tmp_path / "d" / "raw", tmp_path / "d" / "truth")
    code, out, err = _run(capsys, "simulate", "demo", "--out", str(tmp_path / "d"))
    assert (code, out) == (2, "")
    assert (
        err.startswith("borescan simulate: N20261120-ROD01-MEAS-CYL2H: ") and "choose an empty folder" in err
    )


def test_no_command_prints_help_and_exits_2(capsys):
    code, out, _ = _run(capsys)
    assert code == 2 and "status" in out and "validate" in out and "Exit codes:" in out


def test_sql_never_cuts_an_id(capsys):
    from borescan.commands.sql import format_table

    long_id = "TRI-01-20261124-full_lsq-d625a251"
    note = "a reason text longer than the width, cut in the middle"
    out = format_table(
        ["calibration_id", "diameter_id", "reason"], [(long_id, "N-TRI01-MEAS/B1", note)], 7, 20
    )
    row = out.splitlines()[2]
    assert long_id in row and "N-TRI01-MEAS/B1" in row
    assert note not in row and "\u2026" in row  # other text is still cut at --max-width


def test_simulate_demo_help_counts_the_demo_nights(capsys):
    from borescan.synthetic.demo import DEMO_NIGHTS

    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    assert f"({len(DEMO_NIGHTS)} nights, TRI-01 and ROD-01)" in capsys.readouterr().out
