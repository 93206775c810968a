"""The raw format: names, schemas, ``ScanError``, ``ScanMeta``, ``RawScan``, ``LdsMatrix``, digests."""

from __future__ import annotations

import hashlib
import re
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa

FORMAT = "borescan-raw/1"
SCAN_JSON = "scan.json"
LDS_FILE = "lds.parquet"
SPINDLE_FILE = "spindle.parquet"

KINDS = ("calibration", "centering", "verification", "measurement")
DEVICE_TYPES = ("tri_lds", "rod")
ARTIFACT_TYPES = ("ring_gauge", "part")
#: ``spindle.direction`` seen from +z (spec "Units and frames"): counter-clockwise or clockwise.
DIRECTIONS = ("ccw", "cw")

SCAN_ID_RE = re.compile(r"[A-Za-z0-9_-]{1,64}")
NIGHT_RE = re.compile(r"\d{4}-\d{2}-\d{2}")

LDS_SCHEMA = pa.schema(
    [
        ("sample", pa.int64()),
        ("t_ns", pa.int64()),
        ("sensor", pa.int16()),
        ("value_mm", pa.float64()),
        ("pose", pa.int32()),
    ]
)
LDS_NULLABLE = frozenset({"value_mm", "pose"})
SPINDLE_SCHEMA = pa.schema(
    [
        ("t_ns", pa.int64()),
        ("angle_rad", pa.float64()),
        ("x_mm", pa.float64()),
        ("y_mm", pa.float64()),
        ("rpm", pa.float64()),
    ]
)
SPINDLE_NULLABLE = frozenset({"angle_rad"})

_NO_SCAN = "-"


class ScanError(Exception):
    """A raw scan that breaks ``borescan-raw/1``.

    Parameters
    ----------
    scan_id : str
        Scan the problem belongs to (``"-"`` when no scan can be named).
    file : str
        File (or folder, relative to the raw root) with the problem.
    problem : str
        What is wrong, in words.
    """

    def __init__(self, scan_id: str, file: str, problem: str):
        self.scan_id = str(scan_id)
        self.file = str(file)
        self.problem = str(problem)
        super().__init__(f"{self.scan_id}: {self.file}: {self.problem}")

    def __reduce__(self):
        return (type(self), (self.scan_id, self.file, self.problem))


def _number(value: Any) -> float | None:
    return None if value is None or isinstance(value, bool) else float(value)


def _section(meta: dict, key: str) -> dict:
    value = meta.get(key)
    return value if isinstance(value, dict) else {}


@dataclass(frozen=True)
class ScanMeta:
    """The ``scan.json`` fields the stages use, typed (``borescan-raw/1``; None where absent).

    Attributes
    ----------
    scan_id, night, kind, started_at : str
        Identity of the scan (``started_at`` as written, UTC).
    device_id, device_type : str
        ``device.id`` and ``device.type`` (``tri_lds`` or ``rod``).
    sample_rate_hz : float
        ``sample_rate_hz``.
    channels : tuple of int
        Channels listed in ``sensors``, ascending.
    artifact_id, artifact_type : str or None
        ``artifact.id`` and ``artifact.type`` (``ring_gauge`` or ``part``).
    certified_diameter_mm, u_diameter_mm, nominal_diameter_mm, cte_per_k : float or None
        The artifact's certificate values (at 20 degC) and its expansion coefficient [1/K].
    temperature_c : float or None
        ``environment.temperature_c``.
    rpm_nominal : float or None
        ``spindle.rpm_nominal``.
    direction : str or None
        ``spindle.direction`` (``ccw`` or ``cw``).
    spindle_x_mm, spindle_y_mm : float or None
        ``spindle.position`` of a three-sensor scan.
    has_device_nominal : bool
        Whether ``device.nominal`` is given (the device's nominal geometry).
    simulated : bool
        ``acquisition.simulated``.
    """

    scan_id: str
    night: str
    kind: str
    started_at: str
    device_id: str
    device_type: str
    sample_rate_hz: float
    channels: tuple[int, ...]
    artifact_id: str | None = None
    artifact_type: str | None = None
    certified_diameter_mm: float | None = None
    u_diameter_mm: float | None = None
    nominal_diameter_mm: float | None = None
    cte_per_k: float | None = None
    temperature_c: float | None = None
    rpm_nominal: float | None = None
    direction: str | None = None
    spindle_x_mm: float | None = None
    spindle_y_mm: float | None = None
    has_device_nominal: bool = False
    simulated: bool = False

    @classmethod
    def from_scan_json(cls, meta: dict) -> ScanMeta:
        """Return the typed fields of a parsed, validated ``scan.json``."""
        device, art = _section(meta, "device"), _section(meta, "artifact")
        spindle = _section(meta, "spindle")
        position = spindle.get("position") if isinstance(spindle.get("position"), dict) else {}
        art_id = art.get("id")
        return cls(
            scan_id=str(meta["scan_id"]),
            night=str(meta["night"]),
            kind=str(meta["kind"]),
            started_at=str(meta["started_at"]),
            device_id=str(device["id"]),
            device_type=str(device["type"]),
            sample_rate_hz=float(meta["sample_rate_hz"]),
            channels=tuple(sorted(int(s["channel"]) for s in meta.get("sensors") or ())),
            artifact_id=None if art_id is None else str(art_id),
            artifact_type=art.get("type"),
            certified_diameter_mm=_number(art.get("certified_diameter_mm")),
            u_diameter_mm=_number(art.get("u_diameter_mm")),
            nominal_diameter_mm=_number(art.get("nominal_diameter_mm")),
            cte_per_k=_number(art.get("cte_per_k")),
            temperature_c=_number(_section(meta, "environment").get("temperature_c")),
            rpm_nominal=_number(spindle.get("rpm_nominal")),
            direction=spindle.get("direction"),
            spindle_x_mm=_number(position.get("x_mm")),
            spindle_y_mm=_number(position.get("y_mm")),
            has_device_nominal=isinstance(device.get("nominal"), dict),
            simulated=bool(_section(meta, "acquisition").get("simulated", False)),
        )

    def to_dict(self) -> dict:
        """JSON-ready fields (``channels`` as a list)."""
        out = asdict(self)
        out["channels"] = list(self.channels)
        return out

    @classmethod
    def from_dict(cls, d: dict) -> ScanMeta:
        """Inverse of :meth:`to_dict`; a field this version does not know is an error."""
        known = {f.name for f in fields(cls)}
        extra = set(d) - known
        if extra:
            raise ValueError(f"unknown ScanMeta fields {sorted(extra)}")
        return cls(**{**d, "channels": tuple(int(c) for c in d["channels"])})


@dataclass
class RawScan:
    """One validated raw scan.

    Attributes
    ----------
    scan_id, night : str
        From the folder names (equal to ``scan.json``).
    path : Path
        The scan folder.
    meta : dict
        Parsed ``scan.json`` (unknown keys kept as read).
    lds : pl.DataFrame
        The five ``lds.parquet`` columns (extra columns are not read).
    spindle : pl.DataFrame or None
        The five ``spindle.parquet`` columns, or None when the file is absent.
    files : dict
        File name -> the path it was read from.
    warnings : list of str
        Non-fatal findings (readings outside ``[0, range_mm]``, counted per channel).
    sha256 : dict (property)
        File name -> hex SHA-256 digest of the raw bytes. ``scan.json`` is hashed as it is read;
        the Parquet files on first use of ``sha256`` (stages that only use the data do not pay
        for hashing megabytes; raw files are never modified).
    """

    scan_id: str
    night: str
    path: Path
    meta: dict
    lds: pl.DataFrame
    spindle: pl.DataFrame | None
    files: dict[str, Path]
    warnings: list[str] = field(default_factory=list)
    _digests: dict[str, str] = field(default_factory=dict, repr=False)
    # (the ``lds`` frame, its wide matrix) when validation built the matrix on the way: see lds_matrix
    _matrix: tuple[pl.DataFrame, LdsMatrix] | None = field(default=None, repr=False, compare=False)

    @property
    def sha256(self) -> dict[str, str]:
        """File name -> hex SHA-256 of the raw bytes (computed once per file, on first use)."""
        for name, path in self.files.items():
            if name not in self._digests:
                self._digests[name] = sha256_file(path)
        return dict(self._digests)

    @property
    def device_type(self) -> str:
        """``meta["device"]["type"]`` (``tri_lds`` or ``rod``)."""
        return self.meta["device"]["type"]

    @property
    def scan_meta(self) -> ScanMeta:
        """The typed fields of ``meta`` the stages use (:class:`ScanMeta`)."""
        return ScanMeta.from_scan_json(self.meta)

    @property
    def channels(self) -> tuple[int, ...]:
        """Channels listed in ``sensors``, ascending."""
        return tuple(sorted(int(s["channel"]) for s in self.meta["sensors"]))


@dataclass(frozen=True)
class LdsMatrix:
    """Wide view of ``lds.parquet``: one row per sample, one column per channel.

    Attributes
    ----------
    sample : ndarray, shape (n,), int64
    t_s : ndarray, shape (n,), float64
        Time since scan start [s] (``t_ns / 1e9``, correctly rounded).
    channels : tuple of int
        Column order of ``values_mm`` (ascending channel).
    values_mm : ndarray, shape (n, c), float64
        Readings [mm]; NaN where null or where a channel has no row for the sample.
    pose : ndarray, shape (n,), int64
        Rod pose index, -1 where null.
    """

    sample: np.ndarray
    t_s: np.ndarray
    channels: tuple[int, ...]
    values_mm: np.ndarray
    pose: np.ndarray

    def channel(self, ch: int) -> np.ndarray:
        """Return readings [mm] of channel ``ch`` (1-based)."""
        return self.values_mm[:, self.channels.index(ch)]


# ---------------------------------------------------------------------------------------------
# helpers


def sha256_file(path: Path) -> str:
    """Hex SHA-256 of a file's bytes (read-only, streamed)."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def combined_sha256(file_hashes: dict[str, str]) -> str:
    r"""One digest for a scan: SHA-256 over the sorted ``"name:sha256\n"`` lines of its raw files."""
    lines = "".join(f"{name}:{digest}\n" for name, digest in sorted(file_hashes.items()))
    return hashlib.sha256(lines.encode()).hexdigest()
