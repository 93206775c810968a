"""Raw roots a real gauge room produces that once crashed whole nights (issue 40, items 5-8), built
from the demo nights, and a way to run the workflow on them as a user who is not root.

``make_crash_root(demo_raw, raw)`` writes a raw root of:

- night 2026-11-20: the rod's three scans only (no three-sensor device: a rod-only root), plus a
  rod scan whose ``lds.parquet`` only its owner can read and one whose folder only its owner can
  list (acquisition writing with umask 077 as another user);
- night 2026-11-21: the three-sensor device's two calibration scans of that night, whose joint
  calibration is refused (a first night with no successful three-sensor calibration), and its rod
  verification;
- an empty ``night=2026-11-22/`` folder;
- ``night=2026-02-30/`` (no such date) holding a copy of a good rod scan.

The unreadable files are owned by root with mode 0o600 / 0o700; the workflow then runs as the
user ``nobody`` (:func:`as_nobody`), for whom they are unreadable as on the gauge PC.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

NOBODY = 65534


@dataclass(frozen=True)
class CrashRoot:
    raw: Path
    expected_scans: dict[str, str]  # scan_id -> night, every scan a catalog must hold
    unreadable_file: str  # scan id whose lds.parquet nobody may read
    unreadable_folder: str  # scan id whose folder nobody may list
    bad_night_folder: str  # "night=2026-02-30"
    empty_night: str


def copy_scan(src: Path, raw_root: Path, night: str, scan_id: str) -> Path:
    """Copy a scan folder under ``raw_root/night=<night>/scan=<scan_id>/`` with scan.json's ids set."""
    dst = raw_root / f"night={night}" / f"scan={scan_id}"
    shutil.copytree(src, dst)
    meta = json.loads((dst / "scan.json").read_text())
    meta["scan_id"], meta["night"] = scan_id, night
    (dst / "scan.json").write_text(json.dumps(meta, indent=1))
    return dst


def make_crash_root(demo_raw: Path, raw: Path) -> CrashRoot:
    n20, n21 = demo_raw / "night=2026-11-20", demo_raw / "night=2026-11-21"
    expected: dict[str, str] = {}
    for d in sorted(n20.glob("scan=*ROD01*")):
        copy_scan(d, raw, "2026-11-20", d.name[5:])
        expected[d.name[5:]] = "2026-11-20"
    for d in sorted(n21.glob("scan=*TRI01-CAL*")) + sorted(n21.glob("scan=*ROD01-VER*")):
        copy_scan(d, raw, "2026-11-21", d.name[5:])
        expected[d.name[5:]] = "2026-11-21"
    rod = n20 / "scan=N20261120-ROD01-MEAS-CYL2H"
    f = copy_scan(rod, raw, "2026-11-20", "UMASK077-FILE")
    expected["UMASK077-FILE"] = "2026-11-20"
    g = copy_scan(rod, raw, "2026-11-20", "UMASK077-FOLDER")
    expected["UMASK077-FOLDER"] = "2026-11-20"
    (raw / "night=2026-11-22").mkdir()
    copy_scan(rod, raw, "2026-02-30", "N20260230-ROD01-MEAS")
    for p in [raw, *raw.rglob("*")]:  # readable by everyone (as the gauge PC's share is) ...
        p.chmod(0o755 if p.is_dir() else 0o644)
    (f / "lds.parquet").chmod(0o600)  # ... but these two, written with umask 077 by root
    g.chmod(0o700)
    return CrashRoot(raw, expected, "UMASK077-FILE", "UMASK077-FOLDER", "night=2026-02-30", "2026-11-22")


def can_drop_to_nobody() -> bool:
    """Return whether the test can run the workflow as nobody (running as root with setpriv available)."""
    return os.geteuid() == 0 and shutil.which("setpriv") is not None


def as_nobody(cmd: list[str]) -> list[str]:
    """``cmd`` run as the user nobody (no supplementary groups)."""
    return ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups", *cmd]


def checkout_copy(root: Path, dst: Path) -> Path:
    """Return a second checkout of the project (its tracked workflow, config and package, no .snakemake)."""
    dst.mkdir(parents=True, exist_ok=True)
    skip = shutil.ignore_patterns(
        ".git", ".snakemake", "results", "demo", "__pycache__", ".pytest_cache", "*.egg-info"
    )
    for name in ("Snakefile", "rules", "workflow", "config", "src", "profiles", "data"):
        src = root / name
        if src.is_dir():
            shutil.copytree(src, dst / name, ignore=skip)
        elif src.exists():
            shutil.copy2(src, dst / name)
    return dst


def give_to_nobody(*paths: Path) -> None:
    """Make ``paths`` (recursively) owned by nobody, as a non-root user's working folders are."""
    for top in paths:
        for p in [top, *top.rglob("*")]:
            os.lchown(p, NOBODY, NOBODY)


# ------------------------------------------------------ absurd numbers of scan.json (issue 40 item 4)

ROD = "scan=N20261120-ROD01-VER-RGS150"  # a rod verification: sensors, temperature, a gauge with features
ROD_MEAS = "scan=N20261120-ROD01-MEAS-CYL2H"  # a part with toleranced features


def _set(path: str, value):
    def edit(meta: dict) -> None:
        node, keys = meta, path.split(".")
        for k in keys[:-1]:
            node = node[int(k)] if k.isdigit() else node[k]
        node[int(keys[-1]) if keys[-1].isdigit() else keys[-1]] = value

    return edit


#: (case, scan, edit, the problem's text): the issue's findings and their neighbours
PLAUSIBILITY_CASES = [
    (
        "range 1e200",
        ROD,
        _set("sensors.0.range_mm", 1e200),
        "key 'sensors[0].range_mm' 1e+200 mm exceeds plausibility.max_sensor_range_mm 1000 mm",
    ),
    (
        "zero linearity",
        ROD,
        _set("sensors.1.linearity_fs", 0),
        "key 'sensors[1].linearity_fs' must be a positive number (a data-sheet uncertainty), got 0",
    ),
    (
        "zero repeatability",
        ROD,
        _set("sensors.0.repeatability_mm", 0.0),
        "key 'sensors[0].repeatability_mm' must be a positive number",
    ),
    (
        "Fahrenheit",
        ROD,
        _set("environment.temperature_c", 68.0),
        "key 'environment.temperature_c' 68 degC is outside the workshop's range [10, 35] degC",
    ),
    (
        "below absolute zero",
        ROD,
        _set("environment.temperature_c", -300),
        "key 'environment.temperature_c' -300 degC is outside",
    ),
    (
        "zero gauge uncertainty",
        ROD,
        _set("artifact.u_diameter_mm", 0),
        "key 'artifact.u_diameter_mm' must be a positive number, got 0",
    ),
    ("k zero", ROD, _set("artifact.k", 0), "key 'artifact.k' must be a positive number"),
    ("CTE in ppm", ROD, _set("artifact.cte_per_k", 11.5), "key 'artifact.cte_per_k' 11.5 /K is no metal's"),
    (
        "negative certified",
        ROD,
        _set("artifact.features.0.certified_diameter_mm", -150.0021),
        "key 'artifact.features[0].certified_diameter_mm' must be a positive number, got -150.0021",
    ),
    (
        "far-off certified",
        ROD,
        _set("artifact.features.1.certified_diameter_mm", 159.9987),
        "key 'artifact.features[1].certified_diameter_mm' 159.999 mm is "
        "9.999 mm from 'artifact.features[1].nominal_diameter_mm' 150 mm",
    ),
    (
        "tolerance as text",
        ROD_MEAS,
        _set("artifact.features.0.tolerance_mm", "0.02"),
        "key 'artifact.features[0].tolerance_mm' must be a positive number, got '0.02'",
    ),
    (
        "tolerance zero",
        ROD_MEAS,
        _set("artifact.features.1.tolerance_mm", 0),
        "key 'artifact.features[1].tolerance_mm' must be a positive number, got 0",
    ),
    (
        "started in 9999",
        ROD_MEAS,
        _set("started_at", "9999-12-31T23:00:00Z"),
        "key 'started_at' 9999-12-31T23:00:00Z is not within night 2026-11-20",
    ),
    (
        "started the day before",
        ROD_MEAS,
        _set("started_at", "2026-11-19T23:00:00Z"),
        "key 'started_at' 2026-11-19T23:00:00Z is not within night",
    ),
]
