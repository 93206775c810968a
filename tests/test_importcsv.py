"""Vendor CSV import -> borescan-raw/1 (issue 2 item 4; docs/import-csv.md)."""

from __future__ import annotations

import json
import re
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest

from borescan import rawio
from borescan.cli import main
from borescan.importcsv import CsvImportError, channel_of_column, import_csv, load_metadata, read_vendor_csv
from borescan.rawio import lds_matrix, read_scan

META = {
    "scan_id": "CSV01",
    "night": "2026-11-21",
    "started_at": "2026-11-21T22:14:03Z",
    "kind": "measurement",
    "device": {"id": "TRI-01", "type": "tri_lds"},
    "sample_rate_hz": 625.0,
    "sensors": [{"channel": c, "model": "HG-C1030", "range_mm": 10.0} for c in (1, 2, 3)],
    "artifact": {"id": "RG-275", "type": "ring_gauge"},
    "spindle": {"rpm_nominal": 60.0, "position": {"label": "P1", "x_mm": 262.955, "y_mm": -275.502}},
}
NULL_SPELLINGS = ["", "NaN", "---", "nan", " null "]


def write_csv(path: Path, header: list[str], rows: list[list[str]], sep: str = ",") -> Path:
    path.write_text("\n".join(sep.join(r) for r in [header, *rows]) + "\n")
    return path


def write_meta(path: Path, meta: dict | None = None) -> Path:
    path.write_text(json.dumps(META if meta is None else meta))
    return path


def synthetic(n=60, c=3, seed=3):
    rng = np.random.default_rng(seed)
    values = rng.uniform(0.5, 9.5, (n, c))
    values[rng.random((n, c)) < 0.1] = np.nan
    time_s = np.arange(n) / 625.0
    return time_s, values


def cells(values: np.ndarray) -> list[list[str]]:
    out = []
    for i, row in enumerate(values):
        out.append(
            [
                NULL_SPELLINGS[(i + j) % len(NULL_SPELLINGS)] if np.isnan(v) else repr(float(v))
                for j, v in enumerate(row)
            ]
        )
    return out


def test_round_trip_recovers_the_numbers_exactly(tmp_path):
    time_s, values = synthetic()
    rows = [[repr(float(t)), *r] for t, r in zip(time_s, cells(values))]
    csv = write_csv(tmp_path / "export.csv", ["time_s", "ch1", "ch2", "ch3"], rows)
    path = import_csv(csv, write_meta(tmp_path / "meta.json"), tmp_path / "raw")
    assert path == tmp_path / "raw" / "night=2026-11-21" / "scan=CSV01"
    scan = read_scan(path)
    m = lds_matrix(scan)
    assert m.channels == (1, 2, 3)
    np.testing.assert_array_equal(m.sample, np.arange(60))
    np.testing.assert_array_equal(m.values_mm, values)  # bit-exact, NaN where the cell was empty
    assert int(np.isnan(m.values_mm).sum()) == int(np.isnan(values).sum()) > 0
    expected_ns = [int((Decimal(repr(float(t))) * 10**9).to_integral_value()) for t in time_s]
    assert expected_ns == [i * 1_600_000 for i in range(60)]
    np.testing.assert_array_equal(scan.lds["t_ns"].unique(maintain_order=True).to_numpy(), expected_ns)
    assert scan.spindle is None
    assert scan.meta["format"] == "borescan-raw/1"
    assert scan.meta["acquisition"]["imported_from"] == "export.csv"
    assert scan.meta["acquisition"]["source_sha256"] == rawio.sha256_file(csv)
    assert rawio.validate_root(tmp_path / "raw") == []


def test_accepted_channel_names():
    assert [
        channel_of_column(n)
        for n in [
            "ch1",
            "CH2",
            "ch_3",
            "ch 4",
            "ch-5",
            "channel6",
            "sensor7",
            "Sensor_8",
            "LDS9",
            "lds10 [mm]",
            "ch11_mm",
            "LDS12 (mm)",
        ]
    ] == list(range(1, 13))
    assert [channel_of_column(n) for n in ["ch", "chx", "time_s", "x_mm", "rpm", "ch1x", "sensor1_um"]] == [
        None
    ] * 7


def test_spindle_columns_pose_t_ns_and_yaml_metadata(tmp_path):
    n = 20
    rows = []
    for i in range(n):
        enc = "" if i == 4 else repr(i * 0.024)  # 2.5 rpm (rpm_nominal) at 1.6 ms per sample
        rows.append(
            [str(10_000_000_000 + i * 1_600_000), repr(1.0 + i), repr(2.0 + i), enc, "0.25", str(i // 5)]
        )
    csv = write_csv(
        tmp_path / "rod.csv", ["t_ns", "sensor1", "LDS2 [mm]", "encoder_deg", "x_mm", "pose"], rows
    )
    yml = tmp_path / "meta.yaml"
    yml.write_text(
        "scan_id: ROD01\nnight: 2026-11-21\nstarted_at: 2026-11-21T23:00:00Z\nkind: measurement\n"
        "device: {id: ROD-01, type: rod}\nsample_rate_hz: 625\n"
        "artifact: {id: PART-7, type: part}\nspindle: {rpm_nominal: 2.5, position: {x_mm: 1.0, y_mm: -2.0}}\n"
    )
    meta = load_metadata(yml)
    assert meta["night"] == "2026-11-21" and meta["started_at"] == "2026-11-21T23:00:00Z"
    scan = read_scan(import_csv(csv, yml, tmp_path / "raw"))
    assert scan.meta["sensors"] == [{"channel": 1}, {"channel": 2}]  # built from the CSV columns
    np.testing.assert_array_equal(
        scan.lds["t_ns"].unique(maintain_order=True).to_numpy(), np.arange(n) * 1_600_000
    )
    np.testing.assert_array_equal(lds_matrix(scan).pose, np.arange(n) // 5)
    np.testing.assert_array_equal(
        lds_matrix(scan).values_mm, np.column_stack([1.0 + np.arange(n), 2.0 + np.arange(n)])
    )
    sp = scan.spindle
    assert sp["angle_rad"].null_count() == 1 and sp["angle_rad"][4] is None
    np.testing.assert_allclose(
        sp["angle_rad"].drop_nulls().to_numpy(),
        np.deg2rad(np.delete(np.arange(n) * 0.024, 4)),
        rtol=0,
        atol=1e-15,
    )
    assert sp["x_mm"].to_list() == [0.25] * n  # from the CSV
    assert sp["y_mm"].to_list() == [-2.0] * n and sp["rpm"].to_list() == [2.5] * n  # from the metadata


def test_semicolon_separator_comments_and_ignored_columns(tmp_path, capsys):
    csv = tmp_path / "semi.csv"
    csv.write_text(
        "# vendor preamble\nTime_s;Ch1;ch2;ch3;temperature\n0;1.5;2.5;3.5;20.1\n0.0016;1.25;---;3.25;20.1\n"
    )
    vendor = read_vendor_csv(csv, separator=";")
    assert vendor.ignored_columns == ("temperature",)
    np.testing.assert_array_equal(vendor.values_mm, [[1.5, 2.5, 3.5], [1.25, np.nan, 3.25]])
    meta = write_meta(tmp_path / "m.json")
    raw = tmp_path / "raw"
    assert (
        main(["import-csv", str(csv), "--meta", str(meta), "--raw-root", str(raw), "--separator", ";"]) == 0
    )
    out = capsys.readouterr()
    assert out.out.strip() == str(raw / "night=2026-11-21" / "scan=CSV01")
    assert "note: ignored columns temperature" in out.err
    assert main(["validate", str(raw)]) == 0
    # the example meta has no device.nominal (optional): validate says what the scan will lack
    assert capsys.readouterr().out == (
        "CSV01: scan.json: note: discrepancy: no device.nominal: examined against the "
        "device's calibration only; quarantined at this stage if the device has none\n"
        "1 scans, all valid (see the notes)\n"
    )


@pytest.mark.parametrize(
    "text, match",
    [
        ("time_s,ch1\n0,1.0\n0.001,abc\n", "column 'ch1': row 2: 'abc' is not a number"),
        ("time_s,ch1\n0,1.0\n0.001,inf\n", "column 'ch1': row 2: 'inf' is not a finite number"),
        ("ch1,ch2\n1,2\n", "need exactly one time column"),
        ("time_s,t_ns,ch1\n0,0,1\n", r"need exactly one time column .*found \['time_s', 't_ns'\]"),
        ("time_s,x_mm\n0,1\n", "no channel columns"),
        ("time_s,ch1,sensor1\n0,1,2\n", "columns 'ch1' and 'sensor1' both name channel 1"),
        ("time_s,ch0\n0,1\n", "channels are 1-based"),
        ("time_s,ch1\n0,1\n0.002,1\n0.001,1\n", "time is not strictly increasing at row 3"),
        ("time_s,ch1\n0,1\n,1\n", "column 'time_s': row 2: empty time cell"),
        ("time_s,ch1\n0,1\nsoon,1\n", "column 'time_s': row 2: 'soon' is not a number"),
        ("time_s,ch1\n", "no data rows"),
        ("", "not a readable CSV"),
        ("time_s,ch1\n0,1\n0.001,1,7\n", "not a readable CSV"),
        ("time_s,ch1,rpm\n0,1,60\n0.001,1,\n", "column 'rpm': row 2: empty cell"),
        ("time_s,ch1,encoder_deg,angle_rad\n0,1,0,0\n", "either encoder_deg or angle_rad"),
        ("time_s,ch1,Ch1 \n0,1,1\n", "duplicate column names|both name channel 1"),
    ],
)
def test_bad_csv_names_the_file(tmp_path, text, match):
    csv = tmp_path / "bad.csv"
    csv.write_text(text)
    with pytest.raises(CsvImportError, match=match) as ei:
        import_csv(csv, write_meta(tmp_path / "m.json"), tmp_path / "raw")
    assert str(ei.value).startswith(f"{csv}: ")
    assert not (tmp_path / "raw").exists()


def test_missing_file_and_bad_metadata(tmp_path, capsys):
    with pytest.raises(CsvImportError, match=re.escape(f"{tmp_path / 'nope.csv'}: no such file")):
        read_vendor_csv(tmp_path / "nope.csv")
    csv = write_csv(
        tmp_path / "ok.csv",
        ["time_s", "ch1", "ch2", "ch3"],
        [["0", "1", "2", "3"], ["0.0016", "1", "2", "3"]],
    )
    bad = dict(META)
    del bad["kind"]
    meta = write_meta(tmp_path / "meta.json", bad)
    with pytest.raises(CsvImportError, match=re.escape(f"CSV01: {meta}: missing required key 'kind'")):
        import_csv(csv, meta, tmp_path / "raw")
    # channel 4 in the CSV but not in the metadata sensors: the CSV is named
    csv4 = write_csv(
        tmp_path / "four.csv", ["time_s", "ch1", "ch2", "ch3", "ch4"], [["0", "1", "2", "3", "4"]]
    )
    with pytest.raises(
        CsvImportError, match=re.escape(f"CSV01: {csv4}: channel 4 is not listed in scan.json sensors")
    ):
        import_csv(csv4, write_meta(tmp_path / "m2.json"), tmp_path / "raw")
    # a spindle column but neither x_mm nor metadata position
    no_pos = {k: v for k, v in META.items() if k != "spindle"}
    csv_sp = write_csv(
        tmp_path / "sp.csv", ["time_s", "ch1", "ch2", "ch3", "rpm"], [["0", "1", "2", "3", "60"]]
    )
    with pytest.raises(CsvImportError, match="no 'x_mm' column and no metadata spindle.position.x_mm"):
        import_csv(csv_sp, write_meta(tmp_path / "m3.json", no_pos), tmp_path / "raw")
    (tmp_path / "broken.yaml").write_text("scan_id: [unclosed\n")
    with pytest.raises(CsvImportError, match="broken.yaml: invalid YAML"):
        load_metadata(tmp_path / "broken.yaml")
    assert main(["import-csv", str(csv), "--meta", str(meta), "--raw-root", str(tmp_path / "raw")]) == 1
    assert "missing required key 'kind'" in capsys.readouterr().err
    assert not (tmp_path / "raw").exists()


def test_reimport_is_idempotent_and_write_once(tmp_path):
    time_s, values = synthetic(n=10)
    header = ["time_s", "ch1", "ch2", "ch3"]
    csv = write_csv(tmp_path / "a.csv", header, [[repr(float(t)), *r] for t, r in zip(time_s, cells(values))])
    meta = write_meta(tmp_path / "m.json")
    first = import_csv(csv, meta, tmp_path / "raw")
    assert import_csv(csv, meta, tmp_path / "raw") == first
    values[0, 0] = 4.0
    csv2 = write_csv(
        tmp_path / "a.csv", header, [[repr(float(t)), *r] for t, r in zip(time_s, cells(values))]
    )
    with pytest.raises(FileExistsError, match="write-once"):
        import_csv(csv2, meta, tmp_path / "raw")


# ------------------------------------------------------------ issue 20: zones, decimal commas, ingest checks


def test_started_at_with_an_offset_is_stored_in_utc(tmp_path):
    csv = write_csv(
        tmp_path / "a.csv", ["time_s", "ch1", "ch2", "ch3"], [["0", "1", "2", "3"], ["0.0016", "1", "2", "3"]]
    )
    scan = read_scan(import_csv(csv, dict(META, started_at="2026-11-21T23:14:03.25+01:00"), tmp_path / "raw"))
    assert scan.meta["started_at"] == "2026-11-21T22:14:03.25Z"
    assert scan.meta["acquisition"]["started_at_given"] == "2026-11-21T23:14:03.25+01:00"
    # YAML reads an offset as a datetime: the same
    yml = tmp_path / "m.yaml"
    yml.write_text(
        json.dumps(dict(META, scan_id="CSV02", started_at="X")).replace('"X"', "2026-11-21T17:14:03-05:00")
    )
    scan = read_scan(import_csv(csv, yml, tmp_path / "raw"))
    assert scan.meta["started_at"] == "2026-11-21T22:14:03Z"
    # UTC as given stays as given, with no note
    scan = read_scan(import_csv(csv, dict(META, scan_id="CSV03"), tmp_path / "raw"))
    assert (
        scan.meta["started_at"] == META["started_at"] and "started_at_given" not in scan.meta["acquisition"]
    )


def test_started_at_without_a_zone_is_refused_with_a_hint(tmp_path, capsys):
    csv = write_csv(tmp_path / "a.csv", ["time_s", "ch1", "ch2", "ch3"], [["0", "1", "2", "3"]])
    meta = write_meta(tmp_path / "m.json", dict(META, started_at="2026-11-21T22:14:03"))
    with pytest.raises(
        CsvImportError,
        match=re.escape(
            f"{meta}: started_at '2026-11-21T22:14:03' has no time zone; "
            "add Z (UTC) or an offset such as +01:00"
        ),
    ):
        import_csv(csv, meta, tmp_path / "raw")
    assert main(["import-csv", str(csv), "--meta", str(meta), "--raw-root", str(tmp_path / "raw")]) == 1
    assert "has no time zone" in capsys.readouterr().err
    assert not (tmp_path / "raw").exists()


def test_timestamp_column_with_offsets(tmp_path):
    rows = [
        ["2026-11-21T23:14:03.0000+01:00", "1", "2", "3"],
        ["2026-11-21T23:14:03.0016+01:00", "1", "2", "3"],
        ["2026-11-21T22:14:03.0032Z", "1", "2", "3"],
    ]  # another zone, same clock
    csv = write_csv(tmp_path / "ts.csv", ["timestamp", "ch1", "ch2", "ch3"], rows)
    meta = {k: v for k, v in META.items() if k != "started_at"}
    scan = read_scan(import_csv(csv, meta, tmp_path / "raw"))
    assert scan.meta["started_at"] == "2026-11-21T22:14:03Z"  # the first row, in UTC
    np.testing.assert_array_equal(lds_matrix(scan).t_s * 1e9, [0, 1_600_000, 3_200_000])
    bad = write_csv(tmp_path / "naive.csv", ["timestamp", "ch1"], [["2026-11-21T23:14:03", "1"]])
    with pytest.raises(
        CsvImportError, match=r"column 'timestamp': row 1: '2026-11-21T23:14:03' has no time zone"
    ):
        read_vendor_csv(bad)


def test_decimal_comma(tmp_path, capsys):
    time_s, values = synthetic(n=30)
    rows = [[repr(float(t)), *r] for t, r in zip(time_s, cells(values))]
    point = write_csv(tmp_path / "point.csv", ["time_s", "ch1", "ch2", "ch3"], rows)
    comma = write_csv(
        tmp_path / "comma.csv",
        ["time_s", "ch1", "ch2", "ch3"],
        [[c.replace(".", ",") for c in r] for r in rows],
        sep=";",
    )
    a = read_vendor_csv(point)
    b = read_vendor_csv(comma, separator=";", decimal=",")
    np.testing.assert_array_equal(a.values_mm, b.values_mm)  # bit-exact
    np.testing.assert_array_equal(a.t_ns, b.t_ns)
    with pytest.raises(
        CsvImportError,
        match=r"column 'time_s': row 1: '0,0' is not a number "
        r"\(a decimal comma\? use --decimal ,\)",
    ):
        read_vendor_csv(comma, separator=";")
    with pytest.raises(CsvImportError, match="decimal mark and field separator are both ','"):
        read_vendor_csv(comma, decimal=",")
    meta = write_meta(tmp_path / "m.json")
    raw = tmp_path / "raw"
    assert (
        main(
            [
                "import-csv",
                str(comma),
                "--meta",
                str(meta),
                "--raw-root",
                str(raw),
                "--separator",
                ";",
                "--decimal",
                ",",
            ]
        )
        == 0
    )
    np.testing.assert_array_equal(
        lds_matrix(read_scan(raw / "night=2026-11-21" / "scan=CSV01")).values_mm, values
    )
    capsys.readouterr()
    assert main(["import-csv", str(comma), "--meta", str(meta), "--raw-root", str(raw)]) == 1
    assert (
        "(fields separated by ';'? use --separator ';', and --decimal , for decimal commas)"
        in capsys.readouterr().err
    )


def _spindle_rows(n: int, rate_hz: float, value=lambda i: "5.0") -> list[list[str]]:
    return [[repr(i / rate_hz), value(i), "5.0", "5.0", repr(i * 0.576), "60"] for i in range(n)]


def test_import_runs_the_ingest_checks_before_writing(tmp_path, capsys):
    """A 1 kHz export declared as 625 Hz, and a 250 mm reading on a 10 mm sensor, are refused: the
    pipeline would quarantine them (borescan.validation), and raw folders are write-once.
    """
    header = ["time_s", "ch1", "ch2", "ch3", "encoder_deg", "rpm"]
    fast = write_csv(tmp_path / "fast.csv", header, _spindle_rows(50, 1000.0))
    with pytest.raises(CsvImportError) as ei:
        import_csv(fast, dict(META, sample_rate_hz=625.0), tmp_path / "raw")
    assert str(ei.value) == (
        f"CSV01: {fast}: sample clock runs at 1000 Hz (median t_ns step 1 ms per sample) but "
        "scan.json says sample_rate_hz 625 Hz (more than 1% apart)"
    )
    big = write_csv(
        tmp_path / "big.csv", header, _spindle_rows(50, 625.0, lambda i: "250.0" if i == 7 else "5.0")
    )
    meta = write_meta(tmp_path / "m.json")
    assert main(["import-csv", str(big), "--meta", str(meta), "--raw-root", str(tmp_path / "raw")]) == 1
    assert capsys.readouterr().err == (
        f"borescan import-csv: CSV01: {big}: channel 1: 1 readings outside [0, 10] mm "
        "(a sensor reports null when out of range)\n"
    )
    assert not (tmp_path / "raw").exists()
    # the same data at the declared rate and in range are imported
    ok = write_csv(tmp_path / "ok.csv", header, _spindle_rows(50, 625.0))
    assert import_csv(ok, meta, tmp_path / "raw").is_dir()


def test_import_exit_codes(tmp_path, capsys):
    csv = write_csv(tmp_path / "a.csv", ["time_s", "ch1", "ch2", "ch3"], [["0", "1", "2", "3"]])
    meta = write_meta(tmp_path / "m.json")
    raw = tmp_path / "raw"
    assert main(["import-csv", str(tmp_path / "none.csv"), "--meta", str(meta), "--raw-root", str(raw)]) == 2
    assert (
        capsys.readouterr().err == f"borescan import-csv: CSV file {tmp_path / 'none.csv'} does not exist\n"
    )
    assert main(["import-csv", str(csv), "--meta", str(tmp_path), "--raw-root", str(raw)]) == 2
    assert capsys.readouterr().err == f"borescan import-csv: metadata file {tmp_path} is not a file\n"
    assert main(["import-csv", str(csv), "--meta", str(meta), "--raw-root", str(raw)]) == 0
    capsys.readouterr()
    other = write_csv(tmp_path / "b.csv", ["time_s", "ch1", "ch2", "ch3"], [["0", "1", "2", "4"]])
    assert main(["import-csv", str(other), "--meta", str(meta), "--raw-root", str(raw)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("borescan import-csv: CSV01: ") and err.endswith("; import under another scan_id\n")
