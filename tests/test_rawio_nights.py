"""rawio's night-level discovery (the pipeline's unit of work) and the clock-jump check."""

import numpy as np
import pytest

from borescan import rawio


@pytest.fixture
def tree(tmp_path):
    for night, scans in {"2026-11-20": ["A", "B"], "2026-11-21": ["B", "C"], "2026-11-22": ["A"]}.items():
        for s in scans:
            d = tmp_path / f"night={night}" / f"scan={s}"
            d.mkdir(parents=True)
            (d / "scan.json").write_text("{}")
    (tmp_path / "night=garbage" / "scan=X").mkdir(parents=True)
    (tmp_path / "night=2026-02-30" / "scan=Y").mkdir(parents=True)  # the date pattern, no such date
    (tmp_path / "night=2026-11-20" / "scan=").mkdir()
    (tmp_path / "night=2026-11-20" / "notes").mkdir()
    (tmp_path / "night=2026-11-23").write_text("a file, not a night")
    return tmp_path


def test_nights_lists_date_folders_only(tree, tmp_path):
    assert rawio.nights(tree) == ["2026-11-20", "2026-11-21", "2026-11-22"]
    assert rawio.nights(tmp_path / "missing") == []


def test_night_scan_dirs_and_files(tree):
    assert [d.name for d in rawio.night_scan_dirs(tree, "2026-11-20")] == ["scan=A", "scan=B"]
    assert rawio.night_scan_dirs(tree, "2030-01-01") == []
    assert rawio.night_raw_files(tree, "2026-11-21") == [
        str(tree / "night=2026-11-21" / "scan=B" / "scan.json"),
        str(tree / "night=2026-11-21" / "scan=C" / "scan.json"),
    ]


def test_earlier_duplicate_ids_depend_only_on_earlier_nights(tree):
    assert rawio.earlier_duplicate_ids(tree, "2026-11-20") == []
    assert rawio.earlier_duplicate_ids(tree, "2026-11-21") == ["B"]
    assert rawio.earlier_duplicate_ids(tree, "2026-11-22") == ["A"]


def test_clock_jump_none_for_a_steady_clock():
    sample = np.arange(0, 1000, 2)  # every other sample logged: steps of 2 samples
    assert rawio.clock_jump(sample, sample / 1000.0, 1000.0) is None
    assert rawio.clock_jump(np.array([5]), np.array([0.0]), 1000.0) is None
    # jitter below half a period is not a jump
    t = sample / 1000.0 + 0.00049 * (-1) ** np.arange(sample.size) / 2
    assert rawio.clock_jump(sample, t, 1000.0) is None


def test_clock_jump_names_the_first_bad_tick():
    sample = np.arange(10)
    t = sample / 100.0
    t[6:] += 0.5  # the logger's clock slips by half a second between samples 5 and 6
    t[8:] += 0.5
    msg = rawio.clock_jump(sample, t, 100.0)
    assert msg == "clock jump: t_ns advances 0.51 s between samples 5 and 6, expected 0.01 s at 100 Hz"
