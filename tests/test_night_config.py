"""borescan.night_config: each night keeps the settings it was processed with; recompute is explicit."""

from __future__ import annotations

import datetime as dt
import json
import os

import polars as pl
import pytest

from borescan import night_config, tables
from borescan.config import load_config
from borescan.raw_index import raw_index_path
from borescan.stages._common import write_table


def _config(tolerance_mm: float) -> dict:
    cfg = load_config()
    cfg["verification"] = {**cfg["verification"], "tolerance_mm": tolerance_mm}
    cfg["results_root"] = "somewhere"  # a run key: never part of a night's settings
    return cfg


def test_changed_keys_names_nested_additions_and_removals():
    assert night_config.changed_keys({"a": {"b": 1, "c": 2}, "d": 1}, {"a": {"b": 1, "c": 3}, "e": None}) == [
        "a.c",
        "d",
        "e",
    ]


def test_settle_records_a_night_once_and_keeps_it(tmp_path):
    settings, differ = night_config.settle(tmp_path, ["2026-11-20"], _config(0.015))
    assert differ == [] and settings["2026-11-20"]["verification"]["tolerance_mm"] == 0.015
    assert "results_root" not in settings["2026-11-20"]
    rec = night_config.read_record(tmp_path, "2026-11-20")
    assert rec.recorded_by == "first run" and rec.config_hash == night_config.settings_hash(rec.settings)
    settings, differ = night_config.settle(tmp_path, ["2026-11-20", "2026-11-21"], _config(0.002))
    assert differ == ["2026-11-20"]
    assert settings["2026-11-20"]["verification"]["tolerance_mm"] == 0.015  # the past keeps its rule
    assert settings["2026-11-21"]["verification"]["tolerance_mm"] == 0.002  # the new night takes the edit
    assert night_config.read_record(tmp_path, "2026-11-20") == rec


def test_recompute_keeps_the_old_results_records_the_change_and_marks_the_nights(tmp_path):
    night_config.settle(tmp_path, ["2026-11-20", "2026-11-21", "2026-11-22"], _config(0.015))
    night_config.settle(tmp_path, ["2026-11-23"], _config(0.002))
    for night in ("2026-11-20", "2026-11-21", "2026-11-22"):
        write_table(
            tables.frame("verifications", [{"scan_id": f"V{night}", "tolerance_mm": 0.015}]),
            tmp_path / "stage" / "verifications" / f"night={night}.parquet",
        )
        index = raw_index_path(tmp_path, night)
        index.parent.mkdir(parents=True, exist_ok=True)
        index.write_text("scan=V/scan.json 1 1\n")
        os.utime(index, ns=(10**18, 10**18))
    change = night_config.recompute(tmp_path, "2026-11-21", _config(0.002))
    assert change.change_id == "change-0001" and change.nights == ("2026-11-21", "2026-11-22")
    assert change.keys == ("verification.tolerance_mm",) and change.archive == "versions/change-0001"
    kept = tmp_path / "versions" / "change-0001" / "stage"
    assert sorted(p.name for p in (kept / "verifications").iterdir()) == [
        "night=2026-11-21.parquet",
        "night=2026-11-22.parquet",
    ]
    assert sorted(p.name for p in (kept / "night_config").iterdir()) == [
        "night=2026-11-21.parquet",
        "night=2026-11-22.parquet",
    ]
    by = {
        n: night_config.read_record(tmp_path, n).recorded_by
        for n in ("2026-11-20", "2026-11-21", "2026-11-23")
    }
    assert by == {"2026-11-20": "first run", "2026-11-21": "recompute change-0001", "2026-11-23": "first run"}
    assert raw_index_path(tmp_path, "2026-11-21").stat().st_mtime_ns > 10**18
    assert raw_index_path(tmp_path, "2026-11-20").stat().st_mtime_ns == 10**18
    rows = pl.read_parquet(tmp_path / "stage" / "config_changes" / "night=2026-11-21.parquet")
    assert rows.select("change_id", "nights", "changed_keys").rows() == [
        ("change-0001", "2026-11-21,2026-11-22", "verification.tolerance_mm")
    ]
    assert night_config.recompute(tmp_path, "2026-11-21", _config(0.002)) is None  # nothing differs any more


def test_the_date_of_issue_is_the_day_the_night_was_first_processed(tmp_path, monkeypatch):
    from borescan.certificate import certificate_dates

    night = "2026-11-20"
    before = dt.datetime.now(dt.UTC).date().isoformat()
    night_config.settle(tmp_path, [night], _config(0.015))
    after = dt.datetime.now(dt.UTC).date().isoformat()
    today = night_config.first_processed(tmp_path, night)
    assert today in (before, after)
    scans = [{"started_at": "2026-11-20T22:14:03Z"}]
    assert certificate_dates(scans, night, 30, today)["issue"] == today
    # processed again days later (a rerun, a regenerated certificate, a recomputation): the same date
    monkeypatch.setattr(night_config, "_today", lambda: "2027-03-01")
    night_config.settle(tmp_path, [night, "2026-11-21"], _config(0.015))
    assert night_config.first_processed(tmp_path, night) == today
    assert night_config.first_processed(tmp_path, "2026-11-21") == "2027-03-01"  # a new night: its own day
    assert night_config.recompute(tmp_path, night, _config(0.002)).nights == (night, "2026-11-21")
    assert night_config.first_processed(tmp_path, night) == today
    assert (
        certificate_dates(scans, night, 30, night_config.first_processed(tmp_path, night))["issue"] == today
    )


def test_a_record_from_before_the_date_was_kept_gets_its_files_date_once(tmp_path):
    night = "2026-11-20"
    path = night_config.record_path(tmp_path, night)
    path.parent.mkdir(parents=True)
    settings = night_config.night_settings(_config(0.015))
    pl.DataFrame(
        {
            "night": [night],
            "config_hash": [night_config.settings_hash(settings)],
            "config_json": [json.dumps(settings, sort_keys=True)],
            "recorded_by": ["first run"],
        }
    ).write_parquet(path)
    stamp_s = 1_795_000_000  # 2026-11-18 11:06:40 UTC
    os.utime(path, (stamp_s, stamp_s))
    assert night_config.read_record(tmp_path, night).first_processed is None
    night_config.settle(tmp_path, [night], _config(0.015))
    assert night_config.first_processed(tmp_path, night) == "2026-11-18"
    os.utime(path, None)  # a later write of the file no longer moves the date
    night_config.settle(tmp_path, [night], _config(0.015))
    assert night_config.first_processed(tmp_path, night) == "2026-11-18"


def test_a_night_without_a_record_has_no_date_of_issue_and_says_where_it_looked(tmp_path):
    with pytest.raises(
        ValueError, match=r"night 2026-11-20: .*night_config/night=2026-11-20.parquet does not exist"
    ):
        night_config.first_processed(tmp_path, "2026-11-20")
