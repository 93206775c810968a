"""Glue between the Snakemake rules and the library: one ``stage_*`` function per rule.

Every stage works on one night at a time (batching keeps Snakemake's per-job overhead small),
reads raw scans only through :mod:`borescan.rawio`, writes its tables as Parquet under
``<results_root>/stage/<table>/night=<night>.parquet`` (hive layout, so DuckDB and polars read
all nights at once) and never stops for one bad scan: the scan is quarantined with its reason
(``<results_root>/quarantine/<scan_id>.json`` and a row in the stage's quarantine table) and the
stage goes on with the others.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from borescan import rawio
from borescan.atomic import atomic_write_text

NIGHT_RE = re.compile(r"^night=(\d{4}-\d{2}-\d{2})$")
SCAN_RE = re.compile(r"^scan=(.+)$")

QUARANTINE_SCHEMA = {
    "scan_id": pl.Utf8,
    "night": pl.Utf8,
    "stage": pl.Utf8,
    "file": pl.Utf8,
    "reason": pl.Utf8,
}


# --------------------------------------------------------------------------- discovery


def nights(raw_root: str | Path) -> list[str]:
    """Nights (YYYY-MM-DD) present under ``raw_root``, sorted; [] when it does not exist."""
    root = Path(raw_root)
    if not root.is_dir():
        return []
    out = []
    for p in root.iterdir():
        m = NIGHT_RE.match(p.name)
        if m and p.is_dir():
            out.append(m.group(1))
    return sorted(out)


def scan_dirs(raw_root: str | Path, night: str) -> list[Path]:
    """Scan folders of one night, sorted by folder name."""
    night_dir = Path(raw_root) / f"night={night}"
    if not night_dir.is_dir():
        return []
    return sorted(p for p in night_dir.iterdir() if p.is_dir() and SCAN_RE.match(p.name))


def night_raw_files(raw_root: str | Path, night: str) -> list[str]:
    """Every regular file of a night's scans (the inputs whose change must rerun that night)."""
    files = []
    for d in scan_dirs(raw_root, night):
        for f in sorted(d.iterdir()):
            if f.is_file():
                files.append(str(f))
    return files


def earlier_duplicate_ids(raw_root: str | Path, night: str) -> list[str]:
    """Scan ids of ``night`` that already occur in an earlier night (the earlier one wins).

    Depends only on this and earlier nights, so adding a later night changes nothing here.
    """
    ids_here = {SCAN_RE.match(d.name).group(1) for d in scan_dirs(raw_root, night)}
    seen: set[str] = set()
    for n in nights(raw_root):
        if n >= night:
            break
        seen.update(SCAN_RE.match(d.name).group(1) for d in scan_dirs(raw_root, n))
    return sorted(ids_here & seen)


# --------------------------------------------------------------------------- quarantine


@dataclass(frozen=True)
class Quarantined:
    """A scan set aside by a stage, with the file and the problem."""

    scan_id: str
    night: str
    stage: str
    file: str
    reason: str

    @classmethod
    def from_error(cls, err: rawio.ScanError, night: str, stage: str) -> "Quarantined":
        return cls(err.scan_id, night, stage, err.file, err.problem)


def write_quarantine_record(results_root: str | Path, q: Quarantined) -> Path:
    """Write ``<results_root>/quarantine/<scan_id>.json`` (atomic, deterministic bytes)."""
    path = Path(results_root) / "quarantine" / f"{q.scan_id}.json"
    payload = {
        "scan_id": q.scan_id,
        "night": q.night,
        "stage": q.stage,
        "file": q.file,
        "reason": q.reason,
        "message": f"{q.scan_id}: {q.file}: {q.reason}",
    }
    atomic_write_text(path, json.dumps(payload, indent=2, sort_keys=True) + "\n")
    return path


def quarantine_frame(records: list[Quarantined]) -> pl.DataFrame:
    """Quarantine rows as a polars frame (empty frame with the schema when none)."""
    if not records:
        return pl.DataFrame(schema=QUARANTINE_SCHEMA)
    return pl.DataFrame([r.__dict__ for r in records], schema=QUARANTINE_SCHEMA, orient="row")



def write_table(df: pl.DataFrame, path: str | Path) -> None:
    """Write a stage table as Parquet atomically (temp file + rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    df.write_parquet(tmp, statistics=False)
    tmp.replace(path)


def write_stage_outputs(output, quarantined: list[Quarantined] | None = None, **tables: pl.DataFrame) -> None:
    """Write a stage's tables to the rule's outputs of the same names (``output.<name>``), and
    its quarantine records as ``output.quarantine`` when given."""
    if quarantined is not None:
        tables["quarantine"] = quarantine_frame(quarantined)
    for name, df in tables.items():
        write_table(df, getattr(output, name))


# --------------------------------------------------------------------------- ingest

SCANS_SCHEMA = {
    "scan_id": pl.Utf8,
    "night": pl.Utf8,
    "device_id": pl.Utf8,
    "device_type": pl.Utf8,
    "kind": pl.Utf8,
    "artifact_id": pl.Utf8,
    "started_at": pl.Utf8,
    "status": pl.Utf8,
    "reason": pl.Utf8,
    "raw_sha256": pl.Utf8,
    "raw_path": pl.Utf8,
    "simulated": pl.Boolean,
}
SCAN_FILES_SCHEMA = {"scan_id": pl.Utf8, "night": pl.Utf8, "file": pl.Utf8, "sha256": pl.Utf8, "bytes": pl.Int64}



def _meta_field(meta: dict, *keys: str) -> str | None:
    cur: object = meta
    for k in keys:
        if not isinstance(cur, dict) or k not in cur:
            return None
        cur = cur[k]
    return None if cur is None else str(cur)


def stage_ingest(raw_root: str | Path, night: str, results_root: str | Path, duplicate_ids: list[str] = (),
                 workers: int = 1) -> tuple[pl.DataFrame, pl.DataFrame, list[Quarantined]]:
    """Validate and register every scan of one night (spread over ``workers`` processes).

    Returns the ``scans`` rows (status ``ok`` or ``quarantined`` with the reason), the
    ``scan_files`` rows (SHA-256 and size of every raw file, bad scans included) and the
    quarantine records (also written as ``quarantine/<scan_id>.json``).
    """
    from borescan.parallel import map_in_order

    dup = set(duplicate_ids)
    jobs = [(raw_root, night, results_root, d, SCAN_RE.match(d.name).group(1) in dup) for d in scan_dirs(raw_root, night)]
    rows, file_rows, bad = [], [], []
    for row, files, problem in map_in_order(_ingest_one, jobs, workers):
        rows.append(row)
        file_rows += files
        if problem is not None:
            bad.append(problem)
    scans = pl.DataFrame(rows, schema=SCANS_SCHEMA, orient="row") if rows else pl.DataFrame(schema=SCANS_SCHEMA)
    files = pl.DataFrame(file_rows, schema=SCAN_FILES_SCHEMA, orient="row") if file_rows else pl.DataFrame(schema=SCAN_FILES_SCHEMA)
    return scans, files, bad


def _ingest_one(job) -> tuple[dict, list[dict], Quarantined | None]:
    """Hash, validate and describe one scan folder: (scans row, scan_files rows, quarantine or None)."""
    raw_root, night, results_root, d, duplicate = job
    scan_id = SCAN_RE.match(d.name).group(1)
    hashes, file_rows = {}, []
    inside = not d.is_symlink() and d.resolve().is_relative_to(Path(raw_root).resolve())
    for f in sorted(d.iterdir()) if inside else []:
        if f.is_file() and not f.is_symlink():
            digest = rawio.sha256_file(f)
            hashes[f.name] = digest
            file_rows.append({"scan_id": scan_id, "night": night, "file": f.name, "sha256": digest, "bytes": f.stat().st_size})
    meta: dict = {}
    try:
        meta = rawio.read_scan_meta(d)
    except rawio.ScanError:
        pass
    problem: Quarantined | None = None
    if duplicate:
        problem = Quarantined(scan_id, night, "ingest", "scan.json", "scan_id already used by a scan of an earlier night (scan ids are unique across nights)")
    else:
        try:
            scan = rawio.read_scan(d, raw_root=Path(raw_root))
        except rawio.ScanError as err:
            problem = Quarantined.from_error(err, night, "ingest")
        else:
            # The sensor reports null when out of range (raw-scan-format.md), so a logged value
            # outside [0, range_mm] is a mislabelled or corrupt export, not a measurement.
            out_of_range = [w for w in scan.warnings if "outside" in w]
            if out_of_range:
                file, _, msg = out_of_range[0].partition(": ")
                problem = Quarantined(scan_id, night, "ingest", file, msg + " (a sensor reports null when out of range)")
    if problem is not None:
        write_quarantine_record(results_root, problem)
    row = {
        "scan_id": scan_id,
        "night": night,
        "device_id": _meta_field(meta, "device", "id"),
        "device_type": _meta_field(meta, "device", "type"),
        "kind": _meta_field(meta, "kind"),
        "artifact_id": _meta_field(meta, "artifact", "id"),
        "started_at": _meta_field(meta, "started_at"),
        "status": "quarantined" if problem else "ok",
        "reason": f"{problem.file}: {problem.reason}" if problem else None,
        "raw_sha256": rawio.combined_sha256(hashes),
        "raw_path": str(d),
        "simulated": bool(meta.get("acquisition", {}).get("simulated", False)) if isinstance(meta.get("acquisition"), dict) else False,
    }
    return row, file_rows, problem


def ok_scans(scans_table: str | Path | pl.DataFrame) -> pl.DataFrame:
    """The rows of a ``scans`` stage table whose status is ``ok``."""
    df = scans_table if isinstance(scans_table, pl.DataFrame) else pl.read_parquet(scans_table)
    return df.filter(pl.col("status") == "ok").sort("scan_id")


# --------------------------------------------------------------------------- catalog

#: History tables the catalog is built from, each the union of ``stage/<table>/night=*.parquet``.
CATALOG_TABLES = ("scans", "scan_files", "calibrations", "calibration_scans", "diameters", "verifications", "findings", "artifacts")


def read_stage_table(results_root: str | Path, table: str) -> pl.DataFrame | None:
    """All nights of one stage table (hive partition column ``night`` dropped if duplicated)."""
    files = sorted((Path(results_root) / "stage" / table).glob("night=*.parquet"))
    if not files:
        return None
    frames = [pl.read_parquet(f) for f in files]
    frames = [f for f in frames if f.width > 0]
    if not frames:
        return None
    return pl.concat(frames, how="diagonal_relaxed")


def read_quarantine(results_root: str | Path) -> pl.DataFrame:
    """Every stage's quarantine rows."""
    files = sorted((Path(results_root) / "stage" / "quarantine").glob("stage=*/night=*.parquet"))
    frames = [pl.read_parquet(f) for f in files]
    frames = [f for f in frames if f.height > 0]
    if not frames:
        return pl.DataFrame(schema=QUARANTINE_SCHEMA)
    return pl.concat(frames, how="diagonal_relaxed").sort("scan_id", "stage")


def assemble_history(results_root: str | Path) -> dict[str, pl.DataFrame]:
    """The catalog's tables from the stage tables; a scan any stage set aside is ``quarantined``.

    The ``scans`` reason is the first stage's reason (ingest before later stages), prefixed with
    the file, so ``SELECT reason FROM scans`` answers "why" without a join.
    """
    tables: dict[str, pl.DataFrame] = {}
    for name in CATALOG_TABLES:
        df = read_stage_table(results_root, name)
        if df is not None:
            tables[name] = df
    quarantine = read_quarantine(results_root)
    tables["quarantine"] = quarantine
    if "scans" in tables and quarantine.height:
        order = {"ingest": 0, "signal": 1, "calibrate": 2, "measure": 3, "discrepancy": 4}
        first = (
            quarantine.with_columns(pl.col("stage").replace_strict(order, default=9).alias("_o"))
            .sort("scan_id", "night", "_o")
            .group_by("scan_id", "night", maintain_order=True)
            .first()
            .select("scan_id", "night", (pl.col("file") + ": " + pl.col("reason")).alias("_reason"))
        )
        scans = tables["scans"].join(first, on=["scan_id", "night"], how="left")
        tables["scans"] = scans.with_columns(
            pl.when(pl.col("_reason").is_not_null()).then(pl.lit("quarantined")).otherwise(pl.col("status")).alias("status"),
            pl.coalesce("reason", "_reason").alias("reason"),
        ).drop("_reason")
    if "scans" in tables:
        tables["scans"] = tables["scans"].sort("night", "scan_id")
    if "calibrations" in tables:  # a rod's nominal geometry recurs every night: first night wins
        tables["calibrations"] = tables["calibrations"].sort("night").unique(["calibration_id", "channel"], keep="first", maintain_order=True)
    if "calibration_scans" in tables:
        tables["calibration_scans"] = tables["calibration_scans"].unique(maintain_order=True)
    if "artifacts" in tables:  # the same gauge is seen on many nights: its latest record wins
        tables["artifacts"] = tables["artifacts"].unique("artifact_id", keep="last", maintain_order=True)
    return tables


def stage_catalog(results_root: str | Path, catalog_file: str | Path | None = None) -> dict[str, int]:
    """Rebuild ``catalog.duckdb`` from every stage table; returns rows per table."""
    from borescan import catalog

    tables = assemble_history(results_root)
    path = catalog.build_catalog(results_root, tables)
    if catalog_file is not None and Path(catalog_file).resolve() != Path(path).resolve():
        raise RuntimeError(f"catalog written to {path}, rule expected {catalog_file}")
    return {name: df.height for name, df in sorted(tables.items())}


# --------------------------------------------------------------------------- shared helpers


def night_scans(raw_root: str | Path, night: str, scans_table: str | Path | pl.DataFrame, **where: str) -> list[tuple[dict, Path]]:
    """The ``ok`` rows of a night's ``scans`` table (optionally filtered, e.g. kind=...) with their folders."""
    df = ok_scans(scans_table)
    for col, value in where.items():
        df = df.filter(pl.col(col) == value)
    return [(row, Path(raw_root) / f"night={night}" / f"scan={row['scan_id']}") for row in df.iter_rows(named=True)]


def _quarantine(results_root, records: list[Quarantined], scan_id: str, night: str, stage: str, file: str, reason: str) -> None:
    q = Quarantined(scan_id, night, stage, file, reason)
    records.append(q)
    write_quarantine_record(results_root, q)


def _frames_or_empty(frames: list[pl.DataFrame]) -> pl.DataFrame:
    frames = [f for f in frames if f.height]
    return pl.concat(frames, how="diagonal_relaxed") if frames else pl.DataFrame()


def clock_jump(sample: "np.ndarray", t_s: "np.ndarray", sample_rate_hz: float) -> str | None:
    """Describe the first tick whose time step disagrees with the sample step by > half a period.

    On a spindle scan one clock drives every channel (raw-scan-format.md), so t_ns must advance
    by (sample step) / sample_rate_hz; a jump means the logger's clock or counter slipped.
    """
    import numpy as np

    if sample.size < 2:
        return None
    expected = np.diff(sample) / sample_rate_hz
    err = np.diff(t_s) - expected
    bad = np.flatnonzero(np.abs(err) > 0.5 / sample_rate_hz)
    if bad.size == 0:
        return None
    i = int(bad[0])
    return (f"clock jump: t_ns advances {np.diff(t_s)[i]:.6g} s between samples {int(sample[i])} and "
            f"{int(sample[i + 1])}, expected {expected[i]:.6g} s at {sample_rate_hz:g} Hz")


# --------------------------------------------------------------------------- signal


def signal_options(cfg: dict) -> dict:
    """Translate the ``signal`` config section into :func:`borescan.signal.process_scan` keywords."""
    method = cfg.get("filter", "median")
    params: dict = {}
    if method in ("median", "moving_average"):
        params["window_samples"] = int(cfg.get("window_samples", 5))
    elif method == "gaussian":
        params["cutoff_upr"] = float(cfg.get("gaussian_cutoff_upr", 50))
    return {"filter": method, "filter_params": params, "spike_threshold": float(cfg.get("spike_threshold_mad", 6.0)),
            "extrema_on": cfg.get("extrema_on", "despiked")}


def stage_signal(raw_root, night: str, results_root, scans_table, cfg: dict, log=print,
                 workers: int = 1) -> tuple[pl.DataFrame, pl.DataFrame, list[Quarantined]]:
    """Revolutions, sub-sample extrema and per-channel summaries of every spindle scan of a night.

    Returns (extrema, summary, quarantined). The summary has one row per scan and channel with
    mean d_min/d_max and their uncertainties, n/m counts, advanced/backward status and the
    rotation period (``period_*`` columns, including whether it disagrees with the nominal).
    Scans are spread over ``workers`` processes.
    """
    from borescan.parallel import map_in_order, workers_for

    opts = signal_options(cfg)
    jobs = [(raw_root, night, results_root, d, opts) for _, d in night_scans(raw_root, night, scans_table, device_type="tri_lds")]
    log(f"{len(jobs)} three-sensor scans on {workers_for(len(jobs), workers)} process(es)")
    extrema, summaries, bad = [], [], []
    for ext, summ, q, msg in map_in_order(_signal_one, jobs, workers):
        bad += q
        if ext is not None:
            extrema.append(ext)
            summaries.append(summ)
        if msg:
            log(msg)
    return _frames_or_empty(extrema), _frames_or_empty(summaries), bad


def _signal_one(job) -> tuple[pl.DataFrame | None, pl.DataFrame | None, list[Quarantined], str | None]:
    """Signal stage of one scan: (extrema, summary, quarantined, log line); None frames when skipped."""
    import numpy as np

    from borescan import signal

    raw_root, night, results_root, d, opts = job
    bad: list[Quarantined] = []
    scan = rawio.read_scan(d, raw_root=Path(raw_root))
    if scan.spindle is None:
        return None, None, bad, None  # static readings: no revolutions
    mat = rawio.lds_matrix(scan)
    jump = clock_jump(np.asarray(mat.sample), np.asarray(mat.t_s), float(scan.meta["sample_rate_hz"]))
    if jump:
        _quarantine(results_root, bad, scan.scan_id, night, "signal", "lds.parquet", jump)
        return None, None, bad, None
    try:
        res = signal.process_scan(scan, mat, **opts)
    except (ValueError, np.linalg.LinAlgError, IndexError) as err:
        _quarantine(results_root, bad, scan.scan_id, night, "signal", "lds.parquet", f"signal stage failed: {err}")
        return None, None, bad, None
    frames = res.to_frames()
    period = {(k if k.startswith("period_") else f"period_{k}"): v for k, v in res.period.to_dict().items()}
    feats = signal.feature_points(frames["extrema"], res.period.samples_per_rev).select(
        "channel", "feature_sample", "u_feature_sample")
    summary = frames["summary"].join(feats, on="channel", how="left").with_columns(
        n_samples_recorded=pl.lit(mat.values_mm.shape[0]), **{k: pl.lit(v) for k, v in period.items()})
    msg = (f"{scan.scan_id}: {frames['revolutions'].height} revolutions, "
           f"{res.period.samples_per_rev:.3f} samples/rev ({res.period.source})")
    return frames["extrema"], summary, bad, msg


# --------------------------------------------------------------------------- calibrate


def config_hash(cfg: dict) -> str:
    """SHA-256 (hex, 16 chars) of a config section, for certificates and provenance."""
    return hashlib.sha256(json.dumps(cfg, sort_keys=True, default=str).encode()).hexdigest()[:16]


def gauge_radius_mm(meta: dict) -> float:
    """Radius of the ring gauge at the scan's temperature: R20 (1 + cte (T - 20)) [mm]."""
    art = meta.get("artifact") or {}
    d20 = art.get("certified_diameter_mm", art.get("nominal_diameter_mm"))
    if d20 is None:
        raise ValueError("artifact has neither certified_diameter_mm nor nominal_diameter_mm")
    temp = (meta.get("environment") or {}).get("temperature_c", 20.0)
    return 0.5 * float(d20) * (1.0 + float(art.get("cte_per_k", 0.0)) * (float(temp) - 20.0))


def _spindle_inputs(scan) -> dict:
    """Times, despiked readings, rotation angle model and positions of a spindle scan for the full fit."""
    import numpy as np

    from borescan import kinematics, signal

    mat = rawio.lds_matrix(scan)
    clean, _ = signal.remove_spikes(np.asarray(mat.values_mm, dtype=float))
    meta = scan.meta
    sp = scan.spindle
    sp_meta = meta.get("spindle") or {}
    pos = sp_meta.get("position") or {}
    if pos.get("x_mm") is not None and pos.get("y_mm") is not None:
        spindle_xy = (float(pos["x_mm"]), float(pos["y_mm"]))
    else:
        spindle_xy = (float(sp["x_mm"].mean()), float(sp["y_mm"].mean()))
    center = meta.get("center")
    try:
        angle_model = kinematics.angle_model_from_arrays(
            rpm_nominal=sp_meta.get("rpm_nominal"), direction=sp_meta.get("direction", "ccw"),
            spindle_t_s=sp["t_ns"].to_numpy() * 1e-9,
            spindle_angle_rad=sp["angle_rad"].cast(pl.Float64).fill_null(np.nan).to_numpy(),
            spindle_rpm=sp["rpm"].cast(pl.Float64).fill_null(np.nan).to_numpy(),
        )
    except ValueError as err:
        raise ValueError(f"{scan.scan_id}: spindle.parquet: {err}") from None
    sensors = {int(s["channel"]): s for s in meta.get("sensors", [])}
    return {
        "t_s": np.asarray(mat.t_s, dtype=float),
        "readings": clean,
        "channels": tuple(mat.channels),
        "spindle_xy": spindle_xy,
        "center_xy": None if not center else (float(center["x_mm"]), float(center["y_mm"])),
        "rpm": float(abs(angle_model.mean_omega_rad_s()) * 60.0 / (2.0 * np.pi)),
        "direction": sp_meta.get("direction", "ccw"),
        "angle_model": angle_model,
        "range_mm": [float((sensors.get(ch) or {}).get("range_mm") or 10.0) for ch in mat.channels],
        "R": gauge_radius_mm(meta),
    }


def acceptance_rule(cal_cfg: dict):
    """The calibration section's acceptance settings as a :class:`calibration.AcceptanceRule`."""
    from borescan.calibration import AcceptanceRule

    return AcceptanceRule(
        max_residual_to_noise=float(cal_cfg["max_residual_to_noise"]),
        head_radius_mm=float(cal_cfg["head_radius_mm"]),
        position_accuracy_mm=float(cal_cfg["position_accuracy_mm"]),
        speed_scale_range=(float(cal_cfg["speed_scale_min"]), float(cal_cfg["speed_scale_max"])),
    )


def fit_device_calibration(scans, inputs, nominal, cal_cfg: dict, night: str | None = None):
    """Full-data calibration of one device from its spindle scans (``_spindle_inputs`` of each).

    Raises ``calibration.CalibrationError`` (naming the scans and the reason) when the fit fails
    or is refused.
    """
    from borescan import calibration

    raw_files = {f"{s.scan_id}/{k}": v for s in scans for k, v in sorted(s.sha256.items())}
    return calibration.fit_full_calibration(
        [x["t_s"] for x in inputs], [x["readings"] for x in inputs], inputs[0]["channels"], nominal,
        inputs[0]["R"], [x["spindle_xy"] for x in inputs], center_xy_mm=[x["center_xy"] for x in inputs],
        angle_models=[x["angle_model"] for x in inputs], range_mm=inputs[0]["range_mm"],
        rule=acceptance_rule(cal_cfg), scan_ids=[s.scan_id for s in scans],
        device_id=scans[0].meta["device"]["id"], raw_sha256=raw_files, night=night,
    )


def calibrate_raw_scans(scans, cal_cfg: dict, night: str | None = None):
    """Full-data calibration of the calibration scans ``scans`` (``rawio.RawScan``, one device).

    The same path as the night's calibrate stage; ``cal_cfg`` is the config's ``calibration``
    section with its schema defaults. Raises ``calibration.CalibrationError``.
    """
    from borescan.geometry import Beams

    inputs = [_spindle_inputs(s) for s in scans]
    nominal = Beams.from_nominal(scans[0].meta["device"]["nominal"]["beams"])
    return fit_device_calibration(scans, inputs, nominal, cal_cfg, night=night or scans[0].night)


def _calibration_rows(cal, device_type: str, night: str, certificate_path: str | None, raw_sha256: str) -> list[dict]:
    rows = []
    u_beta, u_rho, u_db = cal.u_beta_rad, cal.u_rho_mm, cal.u_d_b_mm
    cal_json = json.dumps(cal.to_dict(), sort_keys=True)
    for i, ch in enumerate(cal.beams.channels):
        rows.append({
            "calibration_id": cal.calibration_id, "device_id": cal.device_id, "device_type": device_type,
            "scan_id": cal.scan_ids[0], "channel": int(ch),
            "rho_mm": float(cal.beams.rho_mm[i]), "d_b_mm": float(cal.beams.d_b_mm[i]), "beta_rad": float(cal.beams.beta_rad[i]),
            "u_rho_mm": float(u_rho[i]), "u_d_b_mm": float(u_db[i]), "u_beta_rad": float(u_beta[i]),
            "method": cal.method, "certificate_path": certificate_path, "night": night, "valid_from": night,
            "status": "valid", "raw_sha256": raw_sha256, "residual_rms_mm": float(cal.residual_rms_mm),
            "calibration_json": cal_json,
        })
    return rows


def rod_nominal_calibration_rows(meta: dict, night: str, scan_id: str) -> list[dict]:
    """The rod's layer geometry from ``device.nominal`` as a calibration record (method ``nominal``).

    Wang 2017 calibrates nothing: the layer base lengths l0 are design values. Recording them as
    a calibration lets every rod diameter name the geometry it used, like a tri_lds diameter.
    """
    layers = sorted(((meta.get("device") or {}).get("nominal") or {}).get("layers") or [], key=lambda l: int(l["channel"]))
    if not layers:
        return []
    digest = hashlib.sha256(json.dumps(layers, sort_keys=True).encode()).hexdigest()[:8]
    cal_id = f"{meta['device']['id']}-nominal-{digest}"
    return [{
        "calibration_id": cal_id, "device_id": meta["device"]["id"], "device_type": "rod", "scan_id": scan_id,
        "channel": int(l["channel"]), "l0_mm": float(l["l0"]), "h_mm": float(l.get("h", float("nan"))),
        "phi_rad": float(l.get("phi", 0.0)), "d_mm": float(l.get("d", 0.0)), "gamma_rad": float(l.get("gamma", 0.0)),
        "method": "nominal", "certificate_path": None, "night": night, "valid_from": night, "status": "valid",
    } for l in layers]


def stage_calibrate(raw_root, night: str, results_root, scans_table, summary_table, cfg: dict, log=print):
    """Calibrate every tri_lds device from its calibration scans of the night; write certificates.

    ``cfg["method"]``: ``full_lsq`` (every sample, exact forward model, all calibration scans of
    the device together) or ``yang2017`` (the paper's extrema method, per device from the first
    calibration scan with a known centre). Returns (calibrations rows, calibration_scans rows,
    quarantined). A scan with too few revolutions, or a calibration that does not converge, is
    quarantined with the reason; the other devices and nights go on.
    """
    from borescan.geometry import Beams

    method = cfg.get("method", "full_lsq")
    min_rev = int(cfg.get("min_revolutions", 5))
    summary = pl.read_parquet(summary_table) if not isinstance(summary_table, pl.DataFrame) else summary_table
    cal_rows, link_rows, bad = [], [], []
    by_device: dict[str, list] = {}
    for row, d in night_scans(raw_root, night, scans_table, kind="calibration", device_type="tri_lds"):
        by_device.setdefault(row["device_id"], []).append((row, d))
    for device_id, items in sorted(by_device.items()):
        scans, inputs = [], []
        for row, d in items:
            scan = rawio.read_scan(d, raw_root=Path(raw_root))
            s = summary.filter(pl.col("scan_id") == scan.scan_id) if summary.height else summary
            if scan.spindle is None:
                _quarantine(results_root, bad, scan.scan_id, night, "calibrate", "spindle.parquet",
                            "calibration scan has no spindle stream (a ring-gauge calibration turns on a spindle)")
                continue
            if s.height == 0:
                continue  # set aside by the signal stage already
            spr = float(s["period_samples_per_rev"][0])
            recorded = int(s["n_samples_recorded"][0] // spr) if "n_samples_recorded" in s.columns else None
            with_extrema = int(s["n_revolutions_min"].min())
            if recorded is not None and recorded < min_rev:
                _quarantine(results_root, bad, scan.scan_id, night, "calibrate", "lds.parquet",
                            f"too few revolutions to calibrate: {recorded} whole revolutions recorded, at least {min_rev} needed")
                continue
            if with_extrema < min_rev:
                _quarantine(results_root, bad, scan.scan_id, night, "calibrate", "lds.parquet",
                            f"calibration failed: a once-per-revolution extremum was found in only {with_extrema} revolutions "
                            f"(at least {min_rev} needed); the readings barely vary with rotation, is the spindle at the gauge centre?")
                continue
            try:
                inputs.append(_spindle_inputs(scan))
            except ValueError as err:
                _quarantine(results_root, bad, scan.scan_id, night, "calibrate", "scan.json", str(err))
                continue
            scans.append(scan)
        if not scans:
            continue
        nominal = Beams.from_nominal(scans[0].meta["device"]["nominal"]["beams"])
        # full_lsq fits all calibration scans of the device together; the paper's method
        # calibrates from one scan's extrema, so each scan gives its own calibration.
        groups = [(scans, inputs)] if method != "yang2017" else [([s], [x]) for s, x in zip(scans, inputs)]
        for group_scans, group_inputs in groups:
            cal_rows, link_rows = _calibrate_group(group_scans, group_inputs, method, nominal, summary, night,
                                                   results_root, cfg, bad, cal_rows, link_rows, log)
    for row, d in night_scans(raw_root, night, scans_table, device_type="rod"):
        meta = rawio.read_scan_meta(d, raw_root=Path(raw_root))
        rows = rod_nominal_calibration_rows(meta, night, row["scan_id"])
        if rows and rows[0]["calibration_id"] not in {r["calibration_id"] for r in cal_rows}:
            cal_rows += rows
            link_rows.append({"calibration_id": rows[0]["calibration_id"], "scan_id": row["scan_id"]})
    cals = pl.DataFrame(cal_rows, infer_schema_length=None) if cal_rows else pl.DataFrame()
    links = pl.DataFrame(link_rows) if link_rows else pl.DataFrame()
    return cals, links, bad


def _yang_from_summary(scan, inputs: dict, summary: pl.DataFrame, nominal, night: str, log=print):
    """Yang 2017 (Eq. 8-15) from the signal stage's per-channel means of one scan."""
    from borescan import calibration

    s = summary.filter(pl.col("scan_id") == scan.scan_id).sort("channel")
    statuses = list(s["status"])
    if "status_significant" in s.columns:
        # |n - m| within its uncertainty: the data cannot tell the beam's side (the sign of rho);
        # take it from the design geometry, as an engineer would, and say so.
        sgn = 1.0 if inputs["direction"] == "ccw" else -1.0
        for i, (ch, ok) in enumerate(zip(s["channel"], s["status_significant"])):
            if not ok:
                statuses[i] = "advanced" if sgn * nominal.rho_mm[i] > 0 else "backward"
                log(f"{scan.scan_id}: channel {ch}: status not significant (|n - m| within its uncertainty); "
                    f"side of the beam taken from device.nominal (rho {nominal.rho_mm[i]:+.3f} mm): {statuses[i]}")
    if inputs["center_xy"] is None:
        raise ValueError("yang2017 needs scan.json center (the gauge centre from a centring scan) for oe (Eq. 9)")
    oe = calibration.yang_oe(inputs["spindle_xy"], inputs["center_xy"])
    spr = float(s["period_samples_per_rev"][0])
    return calibration.yang_calibration(
        s["d_max_mm"].to_numpy(), s["d_min_mm"].to_numpy(), statuses, s["feature_sample"].to_numpy(), spr, inputs["R"], oe,
        channels=tuple(int(c) for c in s["channel"]), device_id=scan.meta["device"]["id"], scan_ids=[scan.scan_id],
        raw_sha256=dict(scan.sha256), beta_ref_rad=float(nominal.beta_rad[0]), beta_nominal_rad=nominal.beta_rad,
        direction=inputs["direction"], u_d_max_mm=s["u_d_max_mm"].to_numpy(), u_d_min_mm=s["u_d_min_mm"].to_numpy(),
        u_feature_sample=s["u_feature_sample"].to_numpy(), night=night,
    )


# --------------------------------------------------------------------------- measure and verify


def _read_tables(paths) -> pl.DataFrame:
    frames = [pl.read_parquet(p) for p in (paths if isinstance(paths, (list, tuple)) else [paths])]
    return _frames_or_empty([f for f in frames if f.width])


def _days_between(a: str, b: str) -> int:
    import datetime as dt

    return (dt.date.fromisoformat(b) - dt.date.fromisoformat(a)).days


def choose_calibration(calibrations: pl.DataFrame, failed_ids: set[str], device_id: str, night: str,
                       validity_days: int, allow_unverified: bool) -> tuple[str | None, str | None]:
    """The calibration a device's result of ``night`` must use, or the reason there is none.

    The latest calibration of the device made on or before the night (same night included), if
    it has not expired (older than ``validity_days``) and has not failed a verification. A failed
    or expired latest calibration is refused (never silently replaced by an older one) unless
    ``allow_unverified``.
    """
    if calibrations.height == 0 or "device_id" not in calibrations.columns:
        return None, f"no calibration of device {device_id} on or before night {night}"
    c = calibrations.filter((pl.col("device_id") == device_id) & (pl.col("valid_from") <= night))
    if c.height == 0:
        return None, f"no calibration of device {device_id} on or before night {night}"
    c = c.sort("valid_from", "calibration_id")
    cal_id, valid_from = c["calibration_id"][-1], c["valid_from"][-1]
    if allow_unverified:
        return cal_id, None
    if cal_id in failed_ids:
        return None, f"latest calibration {cal_id} of device {device_id} failed its verification; recalibrate"
    age = _days_between(valid_from, night)
    if age > validity_days:
        return None, f"latest calibration {cal_id} of device {device_id} expired ({age} days old, validity {validity_days} days)"
    return cal_id, None


def _tri_calibration(calibrations: pl.DataFrame, cal_id: str):
    from borescan.calibration import TriCalibration

    row = calibrations.filter(pl.col("calibration_id") == cal_id).row(0, named=True)
    return TriCalibration.from_dict(json.loads(row["calibration_json"]))


def _artifact_row(meta: dict) -> dict | None:
    art = meta.get("artifact") or {}
    if not art.get("id"):
        return None
    return {"artifact_id": art["id"], "type": art.get("type"), "certificate": art.get("certificate"),
            "nominal_diameter_mm": art.get("nominal_diameter_mm"), "certified_diameter_mm": art.get("certified_diameter_mm"),
            "u_diameter_mm": art.get("u_diameter_mm"), "k": art.get("k"), "cte_per_k": art.get("cte_per_k")}


def measure_rod_scan(scan, layer_rows: pl.DataFrame) -> list[dict]:
    """Hole diameters of a rod scan: mean reading per pose and layer, then the joint rod solve
    (Wang Eq. 16 generalised: layer geometry phi, d, gamma, l0 and the axis deflection; ``rod.solve_rod``)."""
    import numpy as np

    from borescan import rod

    mat = rawio.lds_matrix(scan)
    pose = np.asarray(mat.pose)
    poses = np.unique(pose[pose >= 0])
    v = np.asarray(mat.values_mm, dtype=float)
    means = np.vstack([np.nanmean(v[pose == p], axis=0) for p in poses])
    counts = np.vstack([np.sum(np.isfinite(v[pose == p]), axis=0) for p in poses])
    from borescan.geometry import RodLayer

    rows = {int(r["channel"]): r for r in layer_rows.sort("channel").iter_rows(named=True)}
    num = lambda r, k: float(r[k]) if r.get(k) is not None and np.isfinite(float(r[k])) else 0.0  # noqa: E731
    # the layer geometry of the calibration row (phi, d, gamma, h, l0): the solve uses the spec's exact beam
    lays = [RodLayer(int(ch), num(rows[int(ch)], "h_mm"), float(rows[int(ch)]["l0_mm"]), num(rows[int(ch)], "phi_rad"),
                     num(rows[int(ch)], "d_mm"), num(rows[int(ch)], "gamma_rad")) for ch in mat.channels]
    sensors = {int(s["channel"]): s for s in scan.meta.get("sensors", [])}
    # one reading's standard uncertainty: the sensor's stated linearity (a rectangular +-a) and repeatability
    u_one = np.array([np.hypot((sensors.get(ch, {}).get("linearity_fs") or 0.0) * (sensors.get(ch, {}).get("range_mm") or 0.0) / np.sqrt(3),
                               sensors.get(ch, {}).get("repeatability_mm") or 0.0) for ch in mat.channels])
    u_mean = float(np.max(u_one / np.sqrt(np.maximum(counts.min(axis=0), 1)))) if np.any(u_one > 0) else None
    sol = rod.solve_rod(means, layers=lays, u_reading_mm=u_mean)
    feat = {int(l["channel"]): l.get("feature") for l in (scan.meta.get("rod") or {}).get("layers", [])}
    return [{"channel": int(ch), "feature": feat.get(int(ch)) or f"layer{ch}", "diameter_mm": float(sol.diameter_mm[j]),
             "u_diameter_mm": float(sol.u_diameter_mm[j]), "poses": int(len(poses)), "condition": float(sol.condition)}
            for j, ch in enumerate(mat.channels)]


def stage_measure(raw_root, night: str, results_root, scans_table, calibration_tables, verification_tables_before,
                  cfg: dict, log=print, workers: int = 1):
    """Verification scans first, then measurements, each with the calibration it may use.

    Returns (diameters, verifications, artifacts, quarantined). ``verification_tables_before``
    are the verifications of earlier nights (a calibration that failed one is refused). The
    verifications run in order (a failed one bars its calibration from the rest of the night);
    the measurements are spread over ``workers`` processes.
    """
    from borescan.parallel import map_in_order, workers_for

    ver_cfg, meas_cfg, cal_cfg = cfg["verification"], cfg["measurement"], cfg["calibration"]
    tol = float(ver_cfg.get("tolerance_mm", 0.015))
    allow = bool(meas_cfg.get("allow_unverified_calibration", False))
    validity = int(cal_cfg.get("validity_days", 30))
    cals = _read_tables(calibration_tables)
    earlier = _read_tables(verification_tables_before)
    failed = set(earlier.filter(~pl.col("passed"))["calibration_id"].drop_nulls()) if earlier.height else set()
    diam, ver, arts, bad = [], [], {}, []
    items = night_scans(raw_root, night, scans_table)

    def job(row, d):
        cal_id, why = choose_calibration(cals, failed, row["device_id"], night, validity, allow)
        cal = cals.filter(pl.col("calibration_id") == cal_id) if cal_id is not None else None
        return (raw_root, night, results_root, row, d, cal_id, why, cal, tol)

    def take(out):
        diam.extend(out["diameters"])
        ver.extend(out["verifications"])
        bad.extend(out["quarantined"])
        if out["artifact"]:
            arts[out["artifact"]["artifact_id"]] = out["artifact"]
        if out["log"]:
            log(out["log"])

    for row, d in sorted((it for it in items if it[0]["kind"] == "verification"), key=lambda it: it[0]["scan_id"]):
        out = _measure_one(job(row, d))
        take(out)
        failed.update(v["calibration_id"] for v in out["verifications"] if not v["passed"])
    jobs = [job(row, d) for row, d in sorted((it for it in items if it[0]["kind"] == "measurement"), key=lambda it: it[0]["scan_id"])]
    log(f"{len(jobs)} measurements on {workers_for(len(jobs), workers)} process(es)")
    for out in map_in_order(_measure_one, jobs, workers):
        take(out)
    diameters = pl.DataFrame(diam, infer_schema_length=None) if diam else pl.DataFrame()
    verifications = pl.DataFrame(ver, infer_schema_length=None) if ver else pl.DataFrame()
    artifacts = pl.DataFrame(list(arts.values()), infer_schema_length=None) if arts else pl.DataFrame()
    return diameters, verifications, artifacts, bad


def _measure_one(job) -> dict:
    """Measure (and for a verification scan, verify) one scan with the calibration chosen for it.

    Returns {"diameters", "verifications", "quarantined": lists, "artifact": row or None, "log": str}.
    """
    import numpy as np

    from borescan import measure, rod
    from borescan.calibration import CalibrationError

    raw_root, night, results_root, row, d, cal_id, why, cals, tol = job
    out = {"diameters": [], "verifications": [], "quarantined": [], "artifact": None, "log": None}
    bad = out["quarantined"]
    scan = rawio.read_scan(d, raw_root=Path(raw_root))
    meta, sid, dev = scan.meta, scan.scan_id, row["device_id"]
    out["artifact"] = _artifact_row(meta)
    if cal_id is None:
        _quarantine(results_root, bad, sid, night, "measure", "scan.json", why)
        return out
    try:
        if row["device_type"] == "rod":
            res = measure_rod_scan(scan, cals)
            for r in res:
                out["diameters"].append(measure.diameter_row(sid, dev, row["artifact_id"], r["feature"], r["diameter_mm"],
                                                             r["u_diameter_mm"], cal_id, "rod_wang2017_eq16"))
            out["log"] = f"{sid}: " + ", ".join(f"{r['feature']} {r['diameter_mm']:.4f} +- {r['u_diameter_mm'] * 1e3:.1f} um" for r in res)
            return out
        cal = _tri_calibration(cals, cal_id)
        res = measure.measure_scan(scan, cal.beams, cal.cov)
    except (rod.RodSolveError, CalibrationError, ValueError, np.linalg.LinAlgError) as err:
        _quarantine(results_root, bad, sid, night, "measure", "lds.parquet", f"measurement failed: {err}")
        return out
    out["diameters"].append(measure.diameter_row(sid, dev, row["artifact_id"], None, res["diameter_mm"], res["u_diameter_mm"], cal_id, res["method"]))
    msg = f"{sid}: D = {res['diameter_mm']:.4f} mm +- {res['u_diameter_mm'] * 1e3:.2f} um ({res['method']}, {cal_id})"
    if row["kind"] == "verification":
        a = meta.get("artifact") or {}
        if a.get("type") != "ring_gauge" or a.get("certified_diameter_mm") is None:
            _quarantine(results_root, bad, sid, night, "measure", "scan.json", "verification scan needs a ring_gauge artifact with certified_diameter_mm")
            return out
        k = float(a.get("k") or 2.0)
        temp_c = float((meta.get("environment") or {}).get("temperature_c", 20.0))
        v = measure.verify(res["diameter_mm"], res["u_diameter_mm"], a["certified_diameter_mm"], float(a.get("u_diameter_mm") or 0.0) / k,
                           float(a.get("cte_per_k") or 0.0), temp_c, tol)
        vrow = measure.verification_row(sid, dev, a["id"], v)
        vrow["calibration_id"] = cal_id
        out["verifications"].append(vrow)
        msg += f"; error {v.error_mm * 1e3:+.2f} um vs {a['certified_diameter_mm']} at {temp_c} degC: {'PASS' if v.passed else 'FAIL'}"
    out["log"] = msg
    return out


# --------------------------------------------------------------------------- papers


def stage_papers(out_dir: str | Path, log=print) -> pl.DataFrame:
    """Reproduce the papers' printed results beside them; returns (and writes) ``index.csv``.

    Yang 2017 Tables 1-3 (calibration inputs, extrema sample numbers, verification diameters),
    Wang 2017 Eq. 7, Eq. 15, Figs. 9 and 11, and the model-discrepancy finding on Table 2 (its
    sample numbers disagree with the stated 625 samples per revolution).
    """
    from borescan.papers import wang, yang_table1, yang_table2, yang_table3

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []

    def add(source: str, result) -> None:
        paths = result.values() if isinstance(result, dict) else result
        for p in paths:
            rows.append({"source": source, "file": Path(p).name})
        log(f"{source}: " + ", ".join(Path(p).name for p in paths))

    add("Yang 2017 Table 1", yang_table1.write_reproduction(out_dir))
    add("Yang 2017 Table 2", yang_table2.write_reproduction(out_dir))
    add("Yang 2017 Table 3", yang_table3.write_reproduction(out_dir))
    add("Wang 2017 Eq. 7, Eq. 15, Figs. 9 and 11", wang.write_reproduction(out_dir))
    try:
        from borescan.discrepancy.table2 import examine_table2
    except ImportError:  # pragma: no cover - discrepancy package absent
        examine_table2 = None
    if examine_table2 is not None:
        from borescan.atomic import atomic_write_json

        findings = examine_table2()
        path = atomic_write_json(out_dir / "yang2017_table2_findings.json", findings)
        add("Yang 2017 Table 2 model discrepancy", [path])
    index = pl.DataFrame(rows)
    write_table(index, out_dir / "index.parquet")
    index.write_csv(out_dir / "index.csv")
    return index



def _calibrate_group(scans, inputs, method, nominal, summary, night, results_root, cfg, bad, cal_rows, link_rows, log):
    """Calibrate one device from ``scans`` (already checked), write the certificate, add rows.

    A calibration that fails (no convergence, rank deficiency, no real solution) quarantines
    the scans it was made from, with the reason.
    """
    import numpy as np

    from borescan import __version__, calibration, certificate

    device_id = scans[0].meta["device"]["id"]
    ids = [s.scan_id for s in scans]
    raw_files = {f"{s.scan_id}/{k}": v for s in scans for k, v in sorted(s.sha256.items())}
    try:
        if method == "yang2017":
            cal = _yang_from_summary(scans[0], inputs[0], summary, nominal, night, log=log)
        else:
            cal = fit_device_calibration(scans, inputs, nominal, cfg, night=night)
    except (calibration.CalibrationError, ValueError, np.linalg.LinAlgError) as err:
        for s in scans:
            _quarantine(results_root, bad, s.scan_id, night, "calibrate", "lds.parquet", f"calibration failed: {err}")
        return cal_rows, link_rows
    out_dir = certificate.certificate_dir(results_root, cal)
    scan0, first = scans[0], inputs[0]
    art = scan0.meta.get("artifact") or {}
    if cal.method == "full_lsq":
        residual_mm = calibration.full_residuals(cal, first["t_s"], first["readings"], first["R"], scan0.scan_id,
                                                 angle_model=first["angle_model"])
        residuals = {"t_s": first["t_s"], "residual_mm": residual_mm}
    else:
        residuals = {"t_s": np.zeros(0), "residual_mm": np.zeros((0, len(cal.beams.channels)))}
    revolutions = int(summary.filter(pl.col("scan_id") == scan0.scan_id)["n_revolutions_min"].min())
    certificate.write_certificate(
        cal, out_dir,
        device={"id": device_id, "type": "tri_lds", "sensors": scan0.meta.get("sensors", [])},
        artifact={"id": art.get("id"), "certificate": art.get("certificate"),
                  "certified_diameter_mm": art.get("certified_diameter_mm"),
                  "u_diameter_mm": art.get("u_diameter_mm"), "k": art.get("k", 2)},
        conditions={"temperature_c": (scan0.meta.get("environment") or {}).get("temperature_c"),
                    "spindle_position": (scan0.meta.get("spindle") or {}).get("position"),
                    "rpm": first["rpm"], "revolutions": revolutions, "gauge_radius_at_temperature_mm": first["R"]},
        residuals=residuals, raw_files=raw_files, software_version=__version__, config_hash=config_hash(cfg),
    )
    rel_cert = str((Path(out_dir) / "certificate.pdf").relative_to(Path(results_root)))
    cal_rows += _calibration_rows(cal, "tri_lds", night, rel_cert, rawio.combined_sha256(raw_files))
    link_rows += [{"calibration_id": cal.calibration_id, "scan_id": sid} for sid in ids]
    log(f"{device_id}: {cal.calibration_id} ({cal.method}) from {', '.join(ids)}; "
        f"residual rms {cal.residual_rms_mm * 1e3:.2f} um")
    return cal_rows, link_rows


# --------------------------------------------------------------------------- discrepancy


def findings_rows(findings: dict) -> list[dict]:
    """The catalog's ``findings`` rows of one scan: one per named effect (one empty row if none)."""
    base = {"scan_id": findings["scan_id"], "verdict": findings["verdict"],
            "gap_before_mm": (findings.get("gap_before") or {}).get("rms_mm"),
            "gap_after_mm": (findings.get("gap_after") or {}).get("rms_mm"),
            "noise_floor_mm": findings.get("noise_floor_mm")}
    named = findings.get("named") or []
    if not named:
        return [dict(base, effect=None, channel=None, parameters=None)]
    return [dict(base, effect=n.get("effect"), channel=n.get("channel"),
                 parameters=json.dumps(n.get("parameters") or {}, sort_keys=True)) for n in named]


def discrepancy_reference(calibrations: pl.DataFrame, device_id: str, device_type: str, night: str) -> tuple[dict, str]:
    """What a scan is compared with: the device's latest calibration, else its design geometry.

    A three-sensor device's design geometry (``device.nominal``) is off the real device by
    degrees and tens of um; compared with it, every scan would "miss" offsets and gains that are
    the calibration's business. So a calibrated device is examined against its latest
    calibration made on or before the night (the scan's own calibration for calibration scans),
    and a device without one against ``device.nominal`` with its beam lengths and angles freed.
    """
    if device_type == "tri_lds" and calibrations.height and "device_id" in calibrations.columns:
        c = calibrations.filter((pl.col("device_id") == device_id) & (pl.col("valid_from") <= night)
                                & (pl.col("method") != "nominal"))
        if c.height:
            cal_id = c.sort("valid_from", "calibration_id")["calibration_id"][-1]
            return {"beams": _tri_calibration(calibrations, cal_id).beams}, f"calibration {cal_id}"
    if device_type == "tri_lds":
        return {"free_beams": ("d_b", "beta")}, "device.nominal (beam lengths and angles free)"
    return {}, "device.nominal"


def stage_discrepancy(raw_root, night: str, results_root, scans_table, calibration_tables, cfg: dict,
                      log=print, workers: int = 1) -> tuple[pl.DataFrame, list[Quarantined]]:
    """Model-discrepancy examination of every scan of a night (``discrepancy/<scan_id>/``).

    Each scan is compared with its device as :func:`discrepancy_reference` says; the named
    missing effect, the gap before and after and the noise floor go to ``findings.json``
    (with ``reference`` naming what the scan was compared with), the residual plots to ``gap.png``.
    Scans are spread over ``workers`` processes.
    """
    from borescan.parallel import map_in_order, workers_for

    threshold = float(cfg.get("delta_bic_threshold", 10.0))
    cals = _read_tables(calibration_tables) if calibration_tables else pl.DataFrame()
    jobs = []
    for row, d in night_scans(raw_root, night, scans_table):
        ref_kw, ref = discrepancy_reference(cals, row["device_id"], row["device_type"], night)
        jobs.append((raw_root, night, results_root, d, threshold, ref_kw, ref))
    log(f"{len(jobs)} scans on {workers_for(len(jobs), workers)} process(es)")
    rows, bad = [], []
    for r, q, msg in map_in_order(_discrepancy_one, jobs, workers):
        rows += r
        bad += q
        log(msg)
    schema = {"scan_id": pl.Utf8, "verdict": pl.Utf8, "effect": pl.Utf8, "channel": pl.Int64, "parameters": pl.Utf8,
              "gap_before_mm": pl.Float64, "gap_after_mm": pl.Float64, "noise_floor_mm": pl.Float64}
    return (pl.DataFrame(rows, schema=schema, orient="row") if rows else pl.DataFrame(schema=schema)), bad


def _discrepancy_one(job) -> tuple[list[dict], list[Quarantined], str]:
    """Examine one scan, write findings.json and gap.png: (findings rows, quarantined, log line)."""
    from borescan import discrepancy

    raw_root, night, results_root, d, threshold, ref_kw, ref = job
    bad: list[Quarantined] = []
    scan = rawio.read_scan(d, raw_root=Path(raw_root))
    out_dir = Path(results_root) / "discrepancy" / scan.scan_id
    try:
        ex = discrepancy.analyse_scan(scan, threshold=threshold, **ref_kw)
        findings = ex.findings
        findings["reference"] = ref
        discrepancy.write_findings(findings, out_dir)
        discrepancy.plot_gap(ex, out_dir / "gap.png")
    except (ValueError, KeyError, ArithmeticError) as err:
        _quarantine(results_root, bad, scan.scan_id, night, "discrepancy", "lds.parquet", f"model-discrepancy examination failed: {err}")
        return [], bad, f"{scan.scan_id}: quarantined ({err})"
    named = ", ".join(f"{n['effect']}" + (f" ch{n['channel']}" if n.get("channel") else "") for n in findings.get("named", []))
    msg = (f"{scan.scan_id} vs {ref}: {findings['verdict']}{': ' + named if named else ''} "
           f"(gap {findings['gap_before']['rms_mm'] * 1e3:.2f} -> {findings['gap_after']['rms_mm'] * 1e3:.2f} um, "
           f"noise floor {findings['noise_floor_mm'] * 1e3:.2f} um)")
    return findings_rows(findings), bad, msg
