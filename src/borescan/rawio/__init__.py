"""Reader, writer and validator of ``borescan-raw/1`` (``shared/spec/raw-scan-format.md``).

This package is the only place that touches raw files; its public names are importable from
``borescan.rawio``. Its modules: :mod:`~borescan.rawio.format` (names, schemas, ``ScanError``,
``RawScan``, ``ScanMeta``, ``LdsMatrix``, digests), :mod:`~borescan.rawio.meta` (``scan.json``),
:mod:`~borescan.rawio.lds` (the Parquet tables), :mod:`~borescan.rawio.reader` (one scan folder),
:mod:`~borescan.rawio.layout` (finding scans and nights, manifests, a root's problems),
:mod:`~borescan.rawio.writer` (atomic writes), :mod:`~borescan.rawio.matrix` (the wide view),
:mod:`~borescan.rawio.store` (the validated readings store ingest writes and later stages read,
``ScanMeta``). Layout::

    <raw_root>/night=<YYYY-MM-DD>/scan=<scan_id>/
        scan.json        required   metadata
        lds.parquet      required   long table: sample, t_ns, sensor, value_mm, pose
        spindle.parquet  optional   t_ns, angle_rad, x_mm, y_mm, rpm

Raw files are opened read-only and never modified; :func:`write_scan` writes a new scan folder
atomically (temporary folder beside it, then a rename) and refuses to replace an existing folder
with different content. A bad scan raises :class:`ScanError` naming the scan, the file and the
problem; :func:`validate_root` collects every problem of every scan.

Decisions the spec leaves open (documented here, enforced by the reader):

- all five ``lds.parquet`` columns are required, with exactly the listed Arrow types;
  ``sample``, ``t_ns``, ``sensor`` are never null; ``sample`` and ``t_ns`` are >= 0;
- rows are sorted by ``(sample, sensor)`` with no duplicate pair; all rows of one ``sample`` share
  one ``t_ns``, and ``t_ns`` strictly increases with ``sample``;
- ``value_mm`` null means "no reading"; NaN or +-inf is an error; every channel listed in
  ``sensors`` needs at least one non-null reading; readings outside ``[0, range_mm]`` are
  physical and only counted in :attr:`RawScan.warnings`;
- ``pose`` is non-null and >= 0 (and constant within a sample) on ``rod`` scans, and null on
  ``tri_lds`` scans that carry a ``spindle.parquet``;
- ``spindle.parquet``: ``t_ns`` non-null, >= 0, strictly increasing; ``x_mm``, ``y_mm``, ``rpm``
  non-null and finite; ``angle_rad`` null or finite; at least one row;
- ``started_at`` must carry an explicit UTC designator (``Z`` or ``+00:00``);
- scan folders (or files in them) that resolve outside ``raw_root`` are rejected.
"""

from __future__ import annotations

from borescan.rawio.format import (
    ARTIFACT_TYPES,
    DEVICE_TYPES,
    DIRECTIONS,
    FORMAT,
    KINDS,
    LDS_FILE,
    LDS_SCHEMA,
    SCAN_JSON,
    SPINDLE_FILE,
    SPINDLE_SCHEMA,
    LdsMatrix,
    RawScan,
    ScanError,
    ScanMeta,
    combined_sha256,
    sha256_file,
)
from borescan.rawio.layout import (
    clock_jump,
    discover_scans,
    earlier_duplicate_ids,
    night_manifest,
    night_raw_files,
    night_scan_dirs,
    nights,
    tree_problems,
    validate_root,
)
from borescan.rawio.lds import check_scan_data
from borescan.rawio.matrix import lds_matrix
from borescan.rawio.reader import inspect_scan, read_scan, read_scan_meta
from borescan.rawio.store import (
    clear_readings_dir,
    load_scan_json,
    load_scan_meta,
    load_stored_scan,
    readings_dir,
    stored_scan_dir,
    write_stored_scan,
)
from borescan.rawio.writer import write_scan

__all__ = [
    "FORMAT",
    "SCAN_JSON",
    "LDS_FILE",
    "SPINDLE_FILE",
    "KINDS",
    "DEVICE_TYPES",
    "ARTIFACT_TYPES",
    "DIRECTIONS",
    "ScanError",
    "RawScan",
    "LdsMatrix",
    "read_scan",
    "inspect_scan",
    "read_scan_meta",
    "write_scan",
    "ScanMeta",
    "readings_dir",
    "stored_scan_dir",
    "clear_readings_dir",
    "write_stored_scan",
    "load_stored_scan",
    "load_scan_meta",
    "load_scan_json",
    "discover_scans",
    "nights",
    "night_scan_dirs",
    "night_raw_files",
    "night_manifest",
    "earlier_duplicate_ids",
    "clock_jump",
    "validate_root",
    "tree_problems",
    "check_scan_data",
    "lds_matrix",
    "sha256_file",
    "combined_sha256",
    "LDS_SCHEMA",
    "SPINDLE_SCHEMA",
]
