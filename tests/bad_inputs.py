"""A battery of bad raw scans (issue 8), each made from a copy of a good simulated scan.

``make_bad_scans(raw_root, good_tri, good_rod)`` writes every case under ``raw_root`` and returns
``BadCase`` records: the scan id, the file the error must name and a regular expression the
problem must match. The pipeline test runs Snakemake once over all of them beside good scans.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq


@dataclass(frozen=True)
class BadCase:
    scan_id: str
    file: str
    problem: str  # regular expression, case-insensitive
    stage: str = "ingest"


def _copy(src: Path, raw_root: Path, night: str, scan_id: str) -> Path:
    dst = raw_root / f"night={night}" / f"scan={scan_id}"
    shutil.copytree(src, dst)
    meta = json.loads((dst / "scan.json").read_text())
    meta["scan_id"] = scan_id
    meta["night"] = night
    (dst / "scan.json").write_text(json.dumps(meta, indent=1))
    return dst


def _edit_meta(d: Path, fn: Callable[[dict], None]) -> None:
    meta = json.loads((d / "scan.json").read_text())
    fn(meta)
    (d / "scan.json").write_text(json.dumps(meta, indent=1))


def _edit_table(d: Path, name: str, fn: Callable[[pa.Table], pa.Table]) -> None:
    t = pq.read_table(d / name)
    pq.write_table(fn(t), d / name)


def _set_col(t: pa.Table, col: str, values, typ=None) -> pa.Table:
    i = t.schema.get_field_index(col)
    arr = pa.array(values, type=typ or t.schema.field(col).type)
    return t.set_column(i, pa.field(col, arr.type, nullable=True), arr)


def _values(t: pa.Table, col: str) -> np.ndarray:
    return t.column(col).to_numpy(zero_copy_only=False).copy()


def make_bad_scans(
    raw_root: Path, night: str, good_tri: Path, good_rod: Path, earlier_night_scan_id: str
) -> list[BadCase]:
    """Write the battery under ``raw_root/night=<night>/`` and return what each must produce."""
    cases: list[BadCase] = []

    def case(scan_id: str, file: str, problem: str, src: Path = good_tri) -> Path:
        cases.append(BadCase(scan_id, file, problem))
        return _copy(src, raw_root, night, scan_id)

    d = case("BAD-TRUNCATED-PARQUET", "lds.parquet", r"parquet|read|corrupt")
    data = (d / "lds.parquet").read_bytes()
    (d / "lds.parquet").write_bytes(data[: len(data) // 3])

    d = case("BAD-GARBAGE-PARQUET", "lds.parquet", r"parquet|read|corrupt")
    (d / "lds.parquet").write_bytes(np.random.default_rng(0).bytes(5000))

    d = case("BAD-MISSING-LDS", "lds.parquet", r"missing|not found|no such")
    (d / "lds.parquet").unlink()

    d = case("BAD-MISSING-JSON", "scan.json", r"missing|not found|no such")
    (d / "scan.json").unlink()

    d = case("BAD-INVALID-JSON", "scan.json", r"json")
    (d / "scan.json").write_text('{"format": "borescan-raw/1", "scan_id": ')

    d = case("BAD-UNKNOWN-FORMAT", "scan.json", r"format")
    _edit_meta(d, lambda m: m.update(format="borescan-raw/9"))

    d = case("BAD-MISSING-KIND", "scan.json", r"kind")
    _edit_meta(d, lambda m: m.pop("kind"))

    d = case("BAD-KIND-VALUE", "scan.json", r"kind")
    _edit_meta(d, lambda m: m.update(kind="tea-break"))

    d = case("BAD-UNKNOWN-DEVICE-TYPE", "scan.json", r"device")
    _edit_meta(d, lambda m: m["device"].update(type="laser_tracker"))

    d = case("BAD-RATE-TYPE", "scan.json", r"sample_rate_hz")
    _edit_meta(d, lambda m: m.update(sample_rate_hz="fast"))

    d = case("BAD-STARTED-AT", "scan.json", r"started_at")
    _edit_meta(d, lambda m: m.update(started_at="last tuesday"))

    d = case("BAD-ID-MISMATCH", "scan.json", r"scan_id")
    _edit_meta(d, lambda m: m.update(scan_id="SOMEONE-ELSE"))

    d = case("BAD-NO-SENSORS", "scan.json", r"sensors")
    _edit_meta(d, lambda m: m.update(sensors=[]))

    d = case("BAD-MISSING-COLUMN", "lds.parquet", r"value_mm")
    _edit_table(d, "lds.parquet", lambda t: t.drop_columns(["value_mm"]))

    d = case("BAD-DTYPE", "lds.parquet", r"sensor")
    _edit_table(
        d, "lds.parquet", lambda t: _set_col(t, "sensor", _values(t, "sensor").astype(float), pa.float64())
    )

    def shuffle_samples(t: pa.Table) -> pa.Table:
        s = _values(t, "sample")
        s[10], s[40] = s[40], s[10]
        return _set_col(t, "sample", s)

    d = case("BAD-NONMONOTONIC-SAMPLE", "lds.parquet", r"sample|sorted|monoton")
    _edit_table(d, "lds.parquet", shuffle_samples)

    def clock_backwards(t: pa.Table) -> pa.Table:
        v = _values(t, "t_ns")
        v[len(v) // 2 :] -= 5_000_000_000
        return _set_col(t, "t_ns", np.maximum(v, 0))

    d = case("BAD-CLOCK-BACKWARDS", "lds.parquet", r"t_ns")
    _edit_table(d, "lds.parquet", clock_backwards)

    def clock_jumps_forward(t: pa.Table) -> pa.Table:
        v = _values(t, "t_ns")
        v[len(v) // 2 :] += 2_000_000_000
        return _set_col(t, "t_ns", v)

    cases.append(BadCase("BAD-CLOCK-JUMP", "lds.parquet", r"clock jump", stage="ingest"))
    _edit_table(_copy(good_tri, raw_root, night, "BAD-CLOCK-JUMP"), "lds.parquet", clock_jumps_forward)

    def duplicate_rows(t: pa.Table) -> pa.Table:
        return pa.concat_tables([t.slice(0, 3), t.slice(0, 3), t.slice(3)])

    d = case("BAD-DUPLICATE-ROWS", "lds.parquet", r"duplicate|sorted|sample")
    _edit_table(d, "lds.parquet", duplicate_rows)

    def unlisted_channel(t: pa.Table) -> pa.Table:
        s = _values(t, "sensor")
        s[s == 3] = 7
        return _set_col(t, "sensor", s)

    d = case("BAD-UNLISTED-CHANNEL", "lds.parquet", r"channel|sensor")
    _edit_table(d, "lds.parquet", unlisted_channel)

    def all_null_channel(t: pa.Table) -> pa.Table:
        v = t.column("value_mm").to_pylist()
        s = _values(t, "sensor")
        v = [None if ch == 2 else x for x, ch in zip(v, s)]
        return _set_col(t, "value_mm", v)

    d = case("BAD-ALL-NULL-CHANNEL", "lds.parquet", r"channel 2")
    _edit_table(d, "lds.parquet", all_null_channel)

    def with_value(x: float) -> Callable[[pa.Table], pa.Table]:
        def fn(t: pa.Table) -> pa.Table:
            v = _values(t, "value_mm").astype(float)
            v[100] = x
            return _set_col(t, "value_mm", v)

        return fn

    d = case("BAD-NAN-VALUE", "lds.parquet", r"nan")
    _edit_table(d, "lds.parquet", with_value(float("nan")))

    d = case("BAD-INF-VALUE", "lds.parquet", r"inf")
    _edit_table(d, "lds.parquet", with_value(float("inf")))

    d = case("BAD-OUT-OF-RANGE", "lds.parquet", r"outside|range")
    _edit_table(d, "lds.parquet", with_value(57.0))

    d = case("BAD-ZERO-LENGTH", "lds.parquet", r"no rows|empty|zero|no valid")
    _edit_table(d, "lds.parquet", lambda t: t.slice(0, 0))

    d = case("BAD-SPINDLE-CORRUPT", "spindle.parquet", r"parquet|read|corrupt")
    (d / "spindle.parquet").write_bytes(b"PAR1 not really")

    d = case("BAD-SPINDLE-COLUMNS", "spindle.parquet", r"x_mm")
    _edit_table(d, "spindle.parquet", lambda t: t.drop_columns(["x_mm"]))

    # Spindle streams in other units (issue 40 item 11): named with their column, not "barely vary".
    d = case("BAD-SPINDLE-CLOCK-US", "spindle.parquet", r"^t_ns spans .* not in nanoseconds")
    _edit_table(d, "spindle.parquet", lambda t: _set_col(t, "t_ns", _values(t, "t_ns") // 1000))

    d = case("BAD-SPINDLE-ANGLE-DEG", "spindle.parquet", r"^angle_rad turns at .* impossible rotation speed")
    _edit_table(d, "spindle.parquet", lambda t: _set_col(t, "angle_rad", np.degrees(_values(t, "angle_rad"))))

    d = case("BAD-SPINDLE-DIRECTION", "scan.json", r"spindle\.direction")
    _edit_meta(d, lambda m: m["spindle"].update(direction="sideways"))

    d = case("BAD-POSE-ON-SPINDLE-SCAN", "lds.parquet", r"pose")
    _edit_table(d, "lds.parquet", lambda t: _set_col(t, "pose", np.zeros(t.num_rows, dtype=np.int32)))

    d = case("BAD-ROD-NULL-POSE", "lds.parquet", r"pose", src=good_rod)
    _edit_table(d, "lds.parquet", lambda t: _set_col(t, "pose", [None] * t.num_rows, pa.int32()))

    # A scan folder that is a symlink leading outside the raw root.
    outside = raw_root.parent / "outside" / "scan=BAD-ESCAPES-ROOT"
    shutil.copytree(good_tri, outside)
    _edit_meta(outside, lambda m: m.update(scan_id="BAD-ESCAPES-ROOT", night=night))
    (raw_root / f"night={night}" / "scan=BAD-ESCAPES-ROOT").symlink_to(outside, target_is_directory=True)
    cases.append(BadCase("BAD-ESCAPES-ROOT", f"night={night}/scan=BAD-ESCAPES-ROOT", r"outside the raw root"))

    # The same scan id as a scan of an earlier night.
    case(earlier_night_scan_id, "scan.json", r"earlier night|unique")
    return cases


def make_stage_cases(raw_root: Path, truth_root: Path, night: str) -> tuple[list[BadCase], dict]:
    """Return scans that are valid raw data but cannot be calibrated or measured (issue 8).

    Returns the cases and the ids of the verification that must fail and of the measurement
    that must then be refused.
    """
    from dataclasses import replace

    from borescan.synthetic import demo, scenes, simulate

    cases: list[BadCase] = []
    base = scenes.default_tri_scene()
    started = simulate.started_at_plus(night, 23, 0)
    ring = dict(demo.RG275)

    def write(sim):
        simulate.write_simulated(sim, raw_root, truth_root)

    # Too few revolutions to calibrate (2 < min_revolutions).
    scene = replace(base, spindle_xy_mm=scenes.YANG_P1_XY_MM)
    write(
        simulate.simulate_tri_spindle(
            scene,
            n_rev=2,
            artifact=ring,
            spindle_label="P1",
            center_xy_mm=scenes.YANG_P0_XY_MM,
            nominal_beams=demo.NOMINAL_BEAMS,
            scan_id="BAD-FEW-REVOLUTIONS",
            night=night,
            kind="calibration",
            seed=11,
            started_at=started,
        )
    )
    cases.append(BadCase("BAD-FEW-REVOLUTIONS", "lds.parquet", r"too few revolutions", stage="calibrate"))

    # A calibration that cannot converge: the spindle turns at the gauge centre, so the readings
    # are constant and the beam geometry is undetermined (device TRI-02, nothing else calibrates it).
    scene = replace(base, spindle_xy_mm=scenes.YANG_P0_XY_MM)
    write(
        simulate.simulate_tri_spindle(
            scene,
            n_rev=8,
            artifact=ring,
            spindle_label="P0",
            center_xy_mm=scenes.YANG_P0_XY_MM,
            nominal_beams=demo.NOMINAL_BEAMS,
            scan_id="BAD-CAL-NO-CONVERGENCE",
            night=night,
            kind="calibration",
            seed=12,
            started_at=started,
            device_id="TRI-02",
        )
    )
    cases.append(
        BadCase("BAD-CAL-NO-CONVERGENCE", "calibrate stage", r"calibration failed", stage="calibrate")
    )

    # A device that has no calibration at all.
    part = {"id": "HSG-9001", "type": "part", "nominal_diameter_mm": 277.0, "cte_per_k": 11.5e-6}
    scene = replace(base, bore_center_xy_mm=(0.0, 0.0), bore_radius_20_mm=138.5)
    xy = [[0.3, -0.2], [-0.4, 0.1], [0.1, 0.5]]
    write(
        simulate.simulate_tri_static(
            scene,
            xy,
            [0.1, 1.0, 2.0],
            artifact=part,
            nominal_beams=demo.NOMINAL_BEAMS,
            scan_id="BAD-UNCALIBRATED-DEVICE",
            night=night,
            kind="measurement",
            seed=13,
            started_at=started,
            device_id="TRI-77",
        )
    )
    cases.append(
        BadCase("BAD-UNCALIBRATED-DEVICE", "scan.json", r"no calibration of device TRI-77", stage="measure")
    )

    # Too few rod poses for Wang Eq. 16 (2 holes need 3m + n - 1 <= mn, i.e. n >= 5).
    write(
        simulate.simulate_rod(
            scenes.default_rod_scene(),
            n_poses=3,
            samples_per_pose=3,
            artifact=dict(part, id="CYL-X"),
            features=("H1", "H2"),
            device_id="ROD-01",
            scan_id="BAD-FEW-ROD-POSES",
            night=night,
            kind="measurement",
            seed=14,
            started_at=started,
        )
    )
    cases.append(BadCase("BAD-FEW-ROD-POSES", "lds.parquet", r"pose|equations|unknowns", stage="measure"))

    # A ring gauge labelled with another gauge's certificate (its id and its diameter): the verification
    # fails (a result, not bad input), and the same night's measurement with that calibration must be
    # refused. (The same certificate id with another value is a certificate conflict, set aside at
    # ingest: tests/test_artifacts.py.)
    wrong = dict(
        ring,
        certified_diameter_mm=ring["certified_diameter_mm"] + 0.05,
        certificate=f"{ring.get('certificate')}-OTHER-GAUGE",
    )
    scene = replace(base, bore_center_xy_mm=(0.0, 0.0), bore_radius_20_mm=ring["certified_diameter_mm"] / 2)
    write(
        simulate.simulate_tri_static(
            scene,
            xy,
            [0.1, 1.0, 2.0],
            artifact=wrong,
            nominal_beams=demo.NOMINAL_BEAMS,
            scan_id="VER-MISLABELLED-GAUGE",
            night=night,
            kind="verification",
            seed=15,
            started_at=started,
        )
    )
    scene = replace(base, bore_center_xy_mm=(0.0, 0.0), bore_radius_20_mm=139.0)
    write(
        simulate.simulate_tri_static(
            scene,
            xy,
            [0.1, 1.0, 2.0],
            artifact=dict(part, id="HSG-9002"),
            nominal_beams=demo.NOMINAL_BEAMS,
            scan_id="MEAS-AFTER-FAILED-VERIFICATION",
            night=night,
            kind="measurement",
            seed=16,
            started_at=started,
        )
    )
    cases.append(
        BadCase("MEAS-AFTER-FAILED-VERIFICATION", "scan.json", r"failed its verification", stage="measure")
    )
    return cases, {
        "failed_verification": "VER-MISLABELLED-GAUGE",
        "refused": "MEAS-AFTER-FAILED-VERIFICATION",
    }
