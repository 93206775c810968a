"""Vendor-style CSV export + metadata file -> a ``borescan-raw/1`` scan (``docs/import-csv.md``).

One CSV row is one acquisition tick. Columns (names are case-insensitive, surrounding spaces
ignored):

- time, exactly one of ``time_s`` / ``t_s`` (seconds, decimal), ``t_ns`` / ``time_ns``
  (integer nanoseconds) or ``timestamp`` / ``datetime`` (ISO 8601 date-times with ``Z`` or a UTC
  offset, converted to UTC); shifted so that the first row is at 0 and converted exactly (decimal
  arithmetic) to integer nanoseconds; must strictly increase;
- ``sample`` (optional, integer tick); default: the row index 0, 1, 2, ...;
- one column per channel: ``ch1``, ``channel1``, ``sensor1``, ``LDS1`` (also ``ch_1``, ``ch 1``,
  ``ch-1``), optionally with a unit suffix ``_mm``, `` [mm]`` or `` (mm)``; values in mm;
- optional spindle columns: ``encoder_deg`` (degrees) or ``angle_rad``, and ``x_mm``, ``y_mm``,
  ``rpm``; when any of them is present a ``spindle.parquet`` is written on the same ticks, with
  missing ``x_mm``/``y_mm``/``rpm`` taken from the metadata (``spindle.position``,
  ``spindle.rpm_nominal``);
- ``pose`` (optional integer; required in practice for ``rod`` scans).

Empty cells and ``NaN``, ``nan``, ``---``, ``null``, ``NA``, ``n/a`` mean "no reading" (null).
Other columns are ignored (and listed in :attr:`VendorCsv.ignored_columns`). Numbers use a
decimal point, or a decimal comma with ``decimal=","`` (then the separator must be another
character, usually ``;``).

Times carry their zone: ``started_at`` of the metadata (and a ``timestamp`` column) may have any
UTC offset and is stored converted to UTC (``...Z``); a time without a zone is refused. Before
anything is written, the scan passes the pipeline's own ingest checks
(:func:`borescan.validation.scan_problems`: format, sensor range, sample clock), so an import
never leaves a raw folder that the pipeline would quarantine.
"""

from __future__ import annotations

import datetime as _dt
import json
import re
import tempfile
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import yaml

from borescan import __version__, rawio, validation

__all__ = [
    "CsvImportError",
    "VendorCsv",
    "NULL_TOKENS",
    "channel_of_column",
    "read_vendor_csv",
    "load_metadata",
    "csv_to_frames",
    "utc_iso",
    "utc_started_at",
    "import_csv",
]

NULL_TOKENS = frozenset({"", "nan", "---", "null", "na", "n/a"})
_CHANNEL_RE = re.compile(
    r"(?:ch|channel|sensor|lds)[ _-]?(\d+)(?:[ _]?mm|\s*\[mm\]|\s*\(mm\))?", re.IGNORECASE
)
_TIME_S = ("time_s", "t_s")
_TIME_NS = ("t_ns", "time_ns")
_TIME_ISO = ("timestamp", "datetime")
_ISO_RE = re.compile(
    r"(\d{4}-\d{2}-\d{2})[T ](\d{2}):(\d{2}):(\d{2})(?:[.,](\d{1,9}))?\s*(Z|z|UTC|[+-]\d{2}(?::?\d{2})?)?"
)
_DECIMAL_COMMA_RE = re.compile(r"[+-]?\d*,\d+")
_SPINDLE_COLS = ("encoder_deg", "angle_rad", "x_mm", "y_mm", "rpm")


class CsvImportError(ValueError):
    """A CSV export or its metadata file that cannot become a valid scan (message names the file)."""


@dataclass(frozen=True)
class VendorCsv:
    """Parsed vendor CSV (one row per tick).

    Attributes
    ----------
    path : Path
    sample : ndarray (n,) int64
    t_ns : ndarray (n,) int64
        Time since the first row [ns].
    channels : tuple of int
        Ascending.
    values_mm : ndarray (n, c) float64
        NaN where the cell meant "no reading".
    pose : ndarray (n,) int64 or None
        -1 where empty.
    spindle : dict
        Present spindle columns, name -> float64 array (``angle_rad`` with NaN where empty).
    ignored_columns : tuple of str
    start_utc : str or None
        Time of the first row, ISO 8601 UTC with ``Z``, when the CSV has a ``timestamp`` column.
    """

    path: Path
    sample: np.ndarray
    t_ns: np.ndarray
    channels: tuple[int, ...]
    values_mm: np.ndarray
    pose: np.ndarray | None
    spindle: dict[str, np.ndarray]
    ignored_columns: tuple[str, ...]
    start_utc: str | None = None


def channel_of_column(name: str) -> int | None:
    """Channel number (1-based) of a CSV column name such as ``ch2``, ``LDS3 [mm]``; else None."""
    m = _CHANNEL_RE.fullmatch(name.strip())
    return int(m.group(1)) if m else None


def _fail(path: Path, problem: str) -> CsvImportError:
    return CsvImportError(f"{path}: {problem}")


def _cells(df: pl.DataFrame, col: str, decimal: str = ".") -> pl.Series:
    """Return stripped strings with the null tokens as null; a decimal comma becomes a point."""
    s = df[col].str.strip_chars()
    if decimal == ",":
        s = s.str.replace_all(",", ".", literal=True)
    return (
        pl.select(pl.when(s.str.to_lowercase().is_in(list(NULL_TOKENS))).then(None).otherwise(s))
        .to_series()
        .alias(col)
    )


def _not_a_number(col: str, i: int, cell: str, decimal: str) -> str:
    hint = (
        " (a decimal comma? use --decimal ,)" if decimal == "." and _DECIMAL_COMMA_RE.fullmatch(cell) else ""
    )
    return f"column '{col}': row {i + 1}: {cell!r} is not a number{hint}"


def _floats(df: pl.DataFrame, col: str, path: Path, *, allow_null: bool, decimal: str = ".") -> np.ndarray:
    cells = _cells(df, col, decimal)
    vals = cells.cast(pl.Float64, strict=False)
    bad = vals.is_null() & cells.is_not_null()
    if bad.any():
        i = int(bad.arg_true()[0])
        raise _fail(path, _not_a_number(col, i, df[col][i].strip(), decimal))
    arr = vals.fill_null(np.nan).to_numpy()
    nonfinite = np.isinf(arr)
    if nonfinite.any():
        i = int(np.flatnonzero(nonfinite)[0])
        raise _fail(path, f"column '{col}': row {i + 1}: {cells[i]!r} is not a finite number")
    if not allow_null and cells.is_null().any():
        i = int(cells.is_null().arg_true()[0])
        raise _fail(path, f"column '{col}': row {i + 1}: empty cell (a value is required)")
    return arr


def _ints(df: pl.DataFrame, col: str, path: Path, *, allow_null: bool) -> np.ndarray:
    cells = _cells(df, col)
    vals = cells.cast(pl.Int64, strict=False)
    bad = vals.is_null() & cells.is_not_null()
    if bad.any():
        i = int(bad.arg_true()[0])
        raise _fail(path, f"column '{col}': row {i + 1}: {cells[i]!r} is not an integer")
    if not allow_null and cells.is_null().any():
        i = int(cells.is_null().arg_true()[0])
        raise _fail(path, f"column '{col}': row {i + 1}: empty cell (a value is required)")
    return vals.fill_null(-1).to_numpy()


def _seconds_to_ns(df: pl.DataFrame, col: str, path: Path, decimal: str = ".") -> np.ndarray:
    """Decimal seconds -> integer ns, exactly (round half to even at 1 ns)."""
    cells = _cells(df, col, decimal)
    out = np.empty(len(cells), dtype=np.int64)
    for i, c in enumerate(cells.to_list()):
        if c is None:
            raise _fail(path, f"column '{col}': row {i + 1}: empty time cell")
        try:
            d = Decimal(c)
        except InvalidOperation:
            raise _fail(path, _not_a_number(col, i, df[col][i].strip(), decimal)) from None
        if not d.is_finite():
            raise _fail(path, f"column '{col}': row {i + 1}: {c!r} is not a finite time")
        out[i] = int((d * 1_000_000_000).to_integral_value())
    return out


def _offset_s(zone: str | None) -> int | None:
    """Seconds east of UTC of ``Z``/``UTC``/``+hh[:mm]``; None without a zone."""
    if zone is None:
        return None
    if zone.upper() in ("Z", "UTC"):
        return 0
    sign = -1 if zone[0] == "-" else 1
    digits = zone[1:].replace(":", "")
    return sign * (int(digits[:2]) * 3600 + int(digits[2:4] or 0) * 60)


def _iso_ns(text: str) -> tuple[int, int | None] | None:
    """ISO 8601 date-time -> (ns since 1970 in UTC, offset s or None when no zone); None if not one.

    Exact to the nanosecond (up to 9 fraction digits), with the offset subtracted.
    """
    m = _ISO_RE.fullmatch(text.strip())
    if m is None:
        return None
    date, hh, mm, ss, frac, zone = m.groups()
    try:
        base = _dt.datetime.fromisoformat(f"{date}T{hh}:{mm}:{ss}").replace(tzinfo=_dt.timezone.utc)
    except ValueError:
        return None
    off = _offset_s(zone)
    ns = int(base.timestamp()) * 1_000_000_000 + (int(frac.ljust(9, "0")) if frac else 0)
    return ns - (off or 0) * 1_000_000_000, off


def utc_iso(ns: int) -> str:
    """ns since 1970 (UTC) -> ``YYYY-MM-DDTHH:MM:SS[.fraction]Z`` (fraction without trailing zeros)."""
    sec, frac = divmod(int(ns), 1_000_000_000)
    text = _dt.datetime.fromtimestamp(sec, _dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")
    return text + (f".{frac:09d}".rstrip("0") if frac else "") + "Z"


def _timestamps_to_ns(df: pl.DataFrame, col: str, path: Path) -> tuple[np.ndarray, str]:
    """ISO 8601 date-times with a zone -> (integer ns since the first row, first row in UTC)."""
    out = np.empty(df.height, dtype=np.int64)
    for i, c in enumerate(_cells(df, col).to_list()):
        if c is None:
            raise _fail(path, f"column '{col}': row {i + 1}: empty time cell")
        parsed = _iso_ns(c)
        if parsed is None:
            raise _fail(
                path,
                f"column '{col}': row {i + 1}: {c!r} is not an ISO 8601 date-time "
                "(e.g. 2026-11-21T23:14:03.0016+01:00)",
            )
        if parsed[1] is None:
            raise _fail(
                path,
                f"column '{col}': row {i + 1}: {c!r} has no time zone; add Z (UTC) or an "
                "offset such as +01:00",
            )
        out[i] = parsed[0]
    return out, utc_iso(int(out[0]))


def utc_started_at(value: object, label: str) -> tuple[str, bool]:
    """``started_at`` as ISO 8601 UTC with ``Z``, and whether it was converted from another offset.

    Raises
    ------
    CsvImportError
        Not a date-time, or one without a zone (``label`` names the metadata file).
    """
    parsed = _iso_ns(value) if isinstance(value, str) else None
    if parsed is None:
        raise CsvImportError(
            f"{label}: started_at {value!r} is not an ISO 8601 date-time (e.g. 2026-11-21T22:14:03Z)"
        )
    ns, off = parsed
    if off is None:
        raise CsvImportError(
            f"{label}: started_at {value!r} has no time zone; add Z (UTC) or an offset "
            "such as +01:00 (it is stored converted to UTC)"
        )
    text = utc_iso(ns)
    return text, text != value


def read_vendor_csv(  # noqa: C901 (one branch per checked column and format rule of the vendor CSV)
    csv_path: Path, *, separator: str = ",", decimal: str = "."
) -> VendorCsv:
    """Parse a vendor CSV export (see module docstring for the accepted columns).

    Lines starting with ``#`` are comments. Row numbers in errors count data rows from 1.
    ``decimal`` is ``"."`` or ``","`` (then ``separator`` must differ from it).

    Raises
    ------
    CsvImportError
        Unreadable file, missing/duplicate/ambiguous columns, non-numeric cells, time not
        strictly increasing; the message starts with the file path.
    """
    path = Path(csv_path)
    if decimal not in (".", ","):
        raise _fail(path, f"decimal mark must be '.' or ',', got {decimal!r}")
    if decimal == separator:
        raise _fail(
            path,
            f"decimal mark and field separator are both {separator!r}; "
            "with --decimal , give --separator ';' (or another character)",
        )
    try:
        df = pl.read_csv(
            path, separator=separator, infer_schema=False, comment_prefix="#", truncate_ragged_lines=False
        )
    except FileNotFoundError:
        raise _fail(path, "no such file") from None
    except Exception as e:  # noqa: BLE001 - any parser failure is a bad CSV
        first_line = str(e).splitlines()[0] if str(e) else ""
        hint = ""
        if separator == "," and _first_data_line(path).count(";") > 0:
            hint = " (fields separated by ';'? use --separator ';', and --decimal , for decimal commas)"
        raise _fail(path, f"not a readable CSV: {type(e).__name__}: {first_line}{hint}") from None
    if df.height == 0:
        raise _fail(path, "no data rows")
    cols = {c.strip().lower(): c for c in df.columns}
    if len(cols) != len(df.columns):
        raise _fail(path, "duplicate column names (case-insensitive)")

    time_s = [cols[c] for c in _TIME_S if c in cols]
    time_ns = [cols[c] for c in _TIME_NS if c in cols]
    time_iso = [cols[c] for c in _TIME_ISO if c in cols]
    if len(time_s) + len(time_ns) + len(time_iso) != 1:
        raise _fail(
            path,
            "need exactly one time column (time_s, t_s, t_ns, time_ns, timestamp or datetime); "
            f"found {time_s + time_ns + time_iso or 'none'}",
        )
    start_utc = None
    if time_s:
        t_ns = _seconds_to_ns(df, time_s[0], path, decimal)
    elif time_ns:
        t_ns = _ints(df, time_ns[0], path, allow_null=False)
    else:
        t_ns, start_utc = _timestamps_to_ns(df, time_iso[0], path)
    t_ns = t_ns - t_ns[0]
    dt = np.diff(t_ns)
    if (dt <= 0).any():
        i = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise _fail(path, f"time is not strictly increasing at row {i + 1}")

    used = set(time_s + time_ns + time_iso)
    if "sample" in cols:
        sample = _ints(df, cols["sample"], path, allow_null=False)
        used.add(cols["sample"])
        if (np.diff(sample) <= 0).any() or sample[0] < 0:
            raise _fail(path, "column 'sample' must be >= 0 and strictly increasing")
    else:
        sample = np.arange(df.height, dtype=np.int64)

    chan_cols: dict[int, str] = {}
    for c in df.columns:
        ch = channel_of_column(c)
        if ch is None:
            continue
        if ch < 1:
            raise _fail(path, f"column '{c}': channels are 1-based")
        if ch in chan_cols:
            raise _fail(path, f"columns '{chan_cols[ch]}' and '{c}' both name channel {ch}")
        chan_cols[ch] = c
    if not chan_cols:
        raise _fail(path, "no channel columns (expected names like ch1, sensor1, LDS1)")
    channels = tuple(sorted(chan_cols))
    values = np.column_stack(
        [_floats(df, chan_cols[ch], path, allow_null=True, decimal=decimal) for ch in channels]
    )
    used.update(chan_cols.values())

    pose = None
    if "pose" in cols:
        pose = _ints(df, cols["pose"], path, allow_null=True)
        used.add(cols["pose"])

    spindle: dict[str, np.ndarray] = {}
    if "encoder_deg" in cols and "angle_rad" in cols:
        raise _fail(path, "give either encoder_deg or angle_rad, not both")
    for name in _SPINDLE_COLS:
        if name in cols:
            arr = _floats(
                df, cols[name], path, allow_null=name in ("encoder_deg", "angle_rad"), decimal=decimal
            )
            if name == "encoder_deg":
                spindle["angle_rad"] = np.deg2rad(arr)
            else:
                spindle[name] = arr
            used.add(cols[name])
    ignored = tuple(c for c in df.columns if c not in used)
    return VendorCsv(path, sample, t_ns, channels, values, pose, spindle, ignored, start_utc)


def _first_data_line(path: Path) -> str:
    """Return the first line that is not a comment (for hints); '' when unreadable."""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            return next((line for line in fh if not line.startswith("#")), "")
    except OSError:
        return ""


def _plain(x: Any) -> Any:
    """YAML dates/datetimes -> ISO strings (UTC datetimes end in 'Z'), recursively."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_plain(v) for v in x]
    if isinstance(x, _dt.datetime):
        s = x.isoformat()
        return s[:-6] + "Z" if s.endswith("+00:00") else s
    if isinstance(x, _dt.date):
        return x.isoformat()
    return x


def load_metadata(meta_path: Path) -> dict:
    """Read the metadata file (``.json``, or ``.yaml``/``.yml``) into a scan.json-like dict.

    Raises
    ------
    CsvImportError
        Unreadable, not parseable, or not a mapping.
    """
    path = Path(meta_path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise _fail(path, f"unreadable metadata file: {e}") from None
    try:
        if path.suffix.lower() in (".yaml", ".yml"):
            meta = yaml.safe_load(text)
        else:
            meta = json.loads(text)
    except (ValueError, yaml.YAMLError) as e:
        lang = "YAML" if path.suffix.lower() in (".yaml", ".yml") else "JSON"
        raise _fail(path, f"invalid {lang}: {e}") from None
    if not isinstance(meta, dict):
        raise _fail(path, "metadata must be a mapping of scan.json keys")
    return _plain(meta)


def csv_to_frames(
    vendor: VendorCsv, meta: dict, *, csv_sha256: str | None = None
) -> tuple[dict, pl.DataFrame, pl.DataFrame | None]:
    """Build (scan.json dict, lds frame, spindle frame or None) from a parsed CSV and metadata.

    ``format`` defaults to ``borescan-raw/1``; a missing ``started_at`` is the first row's time
    when the CSV has a ``timestamp`` column; a missing ``sensors`` list becomes one
    ``{"channel": c}`` entry per CSV channel; ``acquisition`` gains ``imported_from`` (CSV file
    name) and, if given, ``source_sha256``.
    """
    meta = json.loads(json.dumps(meta))  # deep copy, plain JSON types
    meta.setdefault("format", rawio.FORMAT)
    if vendor.start_utc is not None:
        meta.setdefault("started_at", vendor.start_utc)
    if "sensors" not in meta:
        meta["sensors"] = [{"channel": c} for c in vendor.channels]
    acq = meta.setdefault("acquisition", {})
    if isinstance(acq, dict):
        acq.setdefault("software", f"borescan import-csv {__version__}")
        acq["imported_from"] = vendor.path.name
        if csv_sha256 is not None:
            acq["source_sha256"] = csv_sha256

    n, c = vendor.values_mm.shape
    vals = vendor.values_mm.reshape(-1)
    pose = None if vendor.pose is None else np.repeat(vendor.pose, c)
    lds = pl.DataFrame(
        {
            "sample": np.repeat(vendor.sample, c),
            "t_ns": np.repeat(vendor.t_ns, c),
            "sensor": np.tile(np.asarray(vendor.channels, dtype=np.int16), n),
            "value_mm": pl.Series(vals, dtype=pl.Float64, nan_to_null=True),
            "pose": (
                pl.Series(pose, dtype=pl.Int32).replace(-1, None)
                if pose is not None
                else pl.Series([None] * (n * c), dtype=pl.Int32)
            ),
        },
        schema=dict(zip(rawio.LDS_SCHEMA.names, (pl.Int64, pl.Int64, pl.Int16, pl.Float64, pl.Int32))),
    )
    spindle = None
    if vendor.spindle:
        sp_meta = meta.get("spindle") if isinstance(meta.get("spindle"), dict) else {}
        pos = sp_meta.get("position") if isinstance(sp_meta.get("position"), dict) else {}
        fallback = {"x_mm": pos.get("x_mm"), "y_mm": pos.get("y_mm"), "rpm": sp_meta.get("rpm_nominal")}
        cols = {"t_ns": vendor.t_ns}
        cols["angle_rad"] = vendor.spindle.get("angle_rad", np.full(n, np.nan))
        for name in ("x_mm", "y_mm", "rpm"):
            if name in vendor.spindle:
                cols[name] = vendor.spindle[name]
            elif isinstance(fallback[name], (int, float)) and not isinstance(fallback[name], bool):
                cols[name] = np.full(n, float(fallback[name]))
            else:
                src = "spindle.position." + name if name != "rpm" else "spindle.rpm_nominal"
                raise _fail(
                    vendor.path,
                    f"spindle columns present but no '{name}' column and no metadata {src}",
                )
        spindle = pl.DataFrame(
            {
                "t_ns": cols["t_ns"],
                "angle_rad": pl.Series(cols["angle_rad"], dtype=pl.Float64, nan_to_null=True),
                "x_mm": cols["x_mm"],
                "y_mm": cols["y_mm"],
                "rpm": cols["rpm"],
            }
        )
    return meta, lds, spindle


def import_csv(
    csv_path: Path, meta_path: Path | dict, raw_root: Path, *, separator: str = ",", decimal: str = "."
) -> Path:
    """Convert a vendor CSV export + metadata into ``<raw_root>/night=.../scan=.../``.

    Parameters
    ----------
    csv_path : Path
    meta_path : Path or dict
        Metadata file (JSON/YAML) with the scan.json fields, or the dict itself.
    raw_root : Path
    separator : str
        CSV field separator.
    decimal : str
        Decimal mark of the CSV's numbers, ``"."`` or ``","``.

    Returns
    -------
    Path
        The written scan folder.

    Raises
    ------
    CsvImportError
        Any problem, naming the CSV or metadata file (all problems, one per line): the format,
        and everything the pipeline's ingest would quarantine the scan for (readings outside the
        sensor range, a sample clock that disagrees with ``sample_rate_hz``).
    FileExistsError
        The scan exists already with different content.
    """
    csv_path = Path(csv_path)
    vendor = read_vendor_csv(csv_path, separator=separator, decimal=decimal)
    if isinstance(meta_path, dict):
        meta_in, meta_label = _plain(meta_path), "metadata"
    else:
        meta_in, meta_label = load_metadata(Path(meta_path)), str(meta_path)
    if "started_at" in meta_in:
        given = meta_in["started_at"]
        utc, converted = utc_started_at(given, meta_label)
        if converted:  # stored in UTC; the time as written is kept beside it
            acq = meta_in.get("acquisition", {})
            meta_in = dict(meta_in, started_at=utc)
            if isinstance(acq, dict):
                meta_in["acquisition"] = dict(acq, started_at_given=given)
    meta, lds, spindle = csv_to_frames(vendor, meta_in, csv_sha256=rawio.sha256_file(csv_path))
    errors = rawio.check_scan_data(
        meta, lds, spindle, meta_file=meta_label, lds_file=str(csv_path), spindle_file=str(csv_path)
    )
    if not errors:
        errors = _ingest_problems(meta, lds, spindle, str(csv_path))
    if errors:
        raise CsvImportError("\n".join(str(e) for e in errors))
    return rawio.write_scan(Path(raw_root), meta, lds, spindle)


def _ingest_problems(meta: dict, lds: pl.DataFrame, spindle: pl.DataFrame | None, csv_label: str) -> list:
    """Return what the pipeline's ingest would quarantine this scan for.

    Return what the pipeline's ingest would quarantine this scan for, from a staged copy (the one
    validator reads a folder); files named after the CSV.
    """
    with tempfile.TemporaryDirectory(prefix="borescan-import-") as tmp:
        root = Path(tmp)
        scan_dir = rawio.write_scan(root, meta, lds, spindle)
        _, problems = validation.scan_problems(scan_dir, root)
    return [
        rawio.ScanError(
            e.scan_id, csv_label if e.file in (rawio.LDS_FILE, rawio.SPINDLE_FILE) else e.file, e.problem
        )
        for e in problems
    ]
