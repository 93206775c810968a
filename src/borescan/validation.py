"""The one validator of raw scans.

The one validator: every reason the pipeline sets a raw scan aside at ingest (ingest and
``borescan validate``).

:func:`scan_problems` is the single check of one scan folder. The ingest stage quarantines a
scan when it returns a problem (the first one becomes the quarantine reason), and
``borescan validate`` prints all of them, so the two cannot disagree. In order:

1. a ``scan_id`` already used by a scan of an earlier night (ids are unique across nights);
2. everything :func:`borescan.rawio.read_scan` rejects (the spec's Errors section and the
   decisions documented in :mod:`borescan.rawio`);
3. readings outside ``[0, range_mm]`` of their sensor: a sensor reports null when it is out of
   range (``raw-scan-format.md``), so a logged value outside is a mislabelled or corrupt export;
4. on spindle scans (a ``spindle.parquet`` is present; one clock drives every channel), the
   sample clock: the ``t_ns`` step per sample must match ``sample_rate_hz`` (median step within
   :data:`RATE_TOLERANCE`, :func:`rate_mismatch`), and no single step may be off by more than
   half a period (:func:`borescan.rawio.clock_jump`);
   and the spindle stream in the format's units (:func:`spindle_problem`): its ``t_ns`` spans the
   readings' seconds, its encoder turns at the speed its ``rpm`` (else ``spindle.rpm_nominal``) says,
   its ``rpm`` near ``spindle.rpm_nominal``, each within a factor :data:`SPINDLE_UNIT_FACTOR`;
5. the numbers of ``scan.json`` that feed a result against what a gauge room can produce
   (:func:`plausibility_problems`, bounds from the config's ``plausibility`` section).

:func:`validate_tree` runs it over the scans the pipeline would ingest (``rawio.nights`` and
``rawio.night_scan_dirs``, in night order, so the later of two scans sharing an id is the
duplicate) and adds the entries of the tree the pipeline would silently skip.
"""

from __future__ import annotations

import datetime as _dt
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from borescan import rawio
from borescan.artifacts import certificate_conflicts, certificate_fields
from borescan.config import schema_defaults
from borescan.rawio import ScanError

__all__ = [
    "DUPLICATE_REASON",
    "OUT_OF_RANGE_NOTE",
    "RATE_TOLERANCE",
    "RawRootError",
    "require_raw_root",
    "duplicate_reason",
    "earlier_night_of",
    "rate_mismatch",
    "clock_problem",
    "SPINDLE_UNIT_FACTOR",
    "spindle_problem",
    "scan_problems",
    "TreeReport",
    "validate_tree",
    "Plausibility",
    "plausibility_problems",
]

DUPLICATE_REASON = "scan_id already used by a scan of an earlier night (scan ids are unique across nights)"
OUT_OF_RANGE_NOTE = "(a sensor reports null when out of range)"

#: Largest relative difference between the rate of the ``t_ns`` clock (median step per sample)
#: and ``sample_rate_hz`` of ``scan.json``. Controller clocks agree with their nominal rate to
#: about 1e-4; a wrong rate setting (625 Hz declared, 660 Hz or 1 kHz logged) is 5 % or more off.
RATE_TOLERANCE = 0.01


class RawRootError(ValueError):
    """The raw root is missing or not a folder (a configuration error, not a bad scan)."""


def require_raw_root(raw_root: str | Path) -> Path:
    """``raw_root`` as a Path; raise :class:`RawRootError` naming it when it is not an existing folder.

    A pipeline run or a validation over a raw root that does not exist would otherwise find no
    nights and succeed having done nothing.
    """
    root = Path(raw_root)
    if not root.exists():
        raise RawRootError(f"raw root {root} does not exist")
    if not root.is_dir():
        raise RawRootError(f"raw root {root} is not a folder")
    return root


def duplicate_reason(earlier_night: str | None) -> str:
    """Return the problem of a scan whose id an earlier night has (that night named when known)."""
    if earlier_night is None:
        return DUPLICATE_REASON
    return f"scan_id already used by a scan of night={earlier_night} (scan ids are unique across nights)"


def earlier_night_of(raw_root: str | Path, night: str, scan_id: str) -> str | None:
    """Return the first night before ``night`` with a folder ``scan=<scan_id>``; None when there is none."""
    for n in rawio.nights(raw_root):
        if n >= night:
            return None
        if (Path(raw_root) / f"night={n}" / f"scan={scan_id}").is_dir():
            return n
    return None


def rate_mismatch(sample: np.ndarray, t_s: np.ndarray, sample_rate_hz: float) -> str | None:
    """Describe a sample clock whose rate disagrees with ``sample_rate_hz``; None when it agrees.

    The clock's rate is 1 / (median of ``diff(t_s) / diff(sample)``), robust to a few jumps
    (:func:`borescan.rawio.clock_jump` finds those) and to dropped samples. It disagrees when
    ``|rate / sample_rate_hz - 1| > RATE_TOLERANCE``.

    Parameters
    ----------
    sample : (n,) sample numbers, strictly increasing.
    t_s : (n,) times of the samples [s], strictly increasing.
    sample_rate_hz : the scan's declared sample rate [Hz].
    """
    sample = np.asarray(sample)
    t_s = np.asarray(t_s, dtype=float)
    if sample.size < 2:
        return None
    period_s = float(np.median(np.diff(t_s) / np.diff(sample)))
    rate_hz = 1.0 / period_s
    if abs(rate_hz / sample_rate_hz - 1.0) <= RATE_TOLERANCE:
        return None
    return (
        f"sample clock runs at {rate_hz:.6g} Hz (median t_ns step {period_s * 1e3:.6g} ms per sample) but "
        f"scan.json says sample_rate_hz {sample_rate_hz:g} Hz (more than {RATE_TOLERANCE:.0%} apart)"
    )


def clock_problem(scan: rawio.RawScan) -> str | None:
    """Return the sample-clock problem of a spindle scan, or None.

    Return the sample-clock problem of a spindle scan (rate, then jumps); None when fine or not a spindle
    scan.
    """
    if scan.spindle is None:
        return None
    mat = rawio.lds_matrix(scan)
    rate = float(scan.meta["sample_rate_hz"])
    return rate_mismatch(mat.sample, mat.t_s, rate) or rawio.clock_jump(mat.sample, mat.t_s, rate)


#: How far (a factor either way) a spindle stream may disagree with the readings and scan.json before it is
#: taken for a stream in other units: a clock in microseconds is a factor 1000 off, an angle in degrees 57, an
#: rpm logged in rad/s 9.5; a real stream agrees within percent (a controller logging once a second spans the
#: same seconds as readings at 625 Hz, a two-speed pair states each speed).
SPINDLE_UNIT_FACTOR = 5.0


def _apart(a: float, b: float) -> bool:
    return not (b / SPINDLE_UNIT_FACTOR <= a <= b * SPINDLE_UNIT_FACTOR)


def spindle_problem(scan: rawio.RawScan) -> str | None:
    """Return what is impossible in a spindle stream's units (naming the column), or None.

    In order: ``t_ns`` (the stream's seconds against those of lds.parquet's readings: both are time since the
    scan start), ``angle_rad`` (the encoder's mean speed, its travel over its time, against the stream's
    ``rpm`` median, else ``spindle.rpm_nominal``), ``rpm`` (its median against ``spindle.rpm_nominal``).
    A disagreement beyond :data:`SPINDLE_UNIT_FACTOR` is another unit, not a slower or faster spindle.
    """
    sp = scan.spindle
    if sp is None or sp.height < 2:
        return None
    t_s = sp["t_ns"].to_numpy().astype(float) * 1e-9
    lds_t_s = np.asarray(rawio.lds_matrix(scan).t_s, dtype=float)
    span_s, lds_span_s = float(t_s[-1] - t_s[0]), float(lds_t_s[-1] - lds_t_s[0])
    if lds_span_s > 0 and _apart(span_s, lds_span_s):
        return (
            f"t_ns spans {span_s:.6g} s where the readings of lds.parquet span {lds_span_s:.6g} s "
            f"({span_s / lds_span_s:.3g} times): the spindle clock is not in nanoseconds since the scan "
            "start (an impossible sample period of the stream; raw format: time in integer nanoseconds)"
        )
    nominal = (scan.meta.get("spindle") or {}).get("rpm_nominal")
    nominal = float(nominal) if nominal is not None and float(nominal) > 0 else None
    rpm = np.abs(sp["rpm"].cast(float).fill_null(np.nan).to_numpy())
    rpm = rpm[np.isfinite(rpm)]
    logged = float(np.median(rpm)) if rpm.size and np.median(rpm) > 0 else None
    angle = sp["angle_rad"].cast(float).fill_null(np.nan).to_numpy()
    ok = np.isfinite(angle)
    ref, ref_name = (logged, "its rpm column") if logged else (nominal, "scan.json spindle.rpm_nominal")
    if ok.sum() >= 2 and ref is not None and t_s[ok][-1] > t_s[ok][0]:
        turned = (
            float(np.abs(np.diff(angle[ok])).sum()) / float(t_s[ok][-1] - t_s[ok][0]) * 60 / (2 * math.pi)
        )
        if _apart(turned, ref):
            return (
                f"angle_rad turns at {turned:.4g} rpm over t_ns where {ref_name} says {ref:.4g} rpm: an "
                "impossible rotation speed (the angle not in radians, or the clock not in nanoseconds)"
            )
    if logged is not None and nominal is not None and _apart(logged, nominal):
        return (
            f"rpm is {logged:.4g} (median) where scan.json spindle.rpm_nominal is {nominal:.4g}: an "
            "impossible rotation speed (rpm not in revolutions per minute)"
        )
    return None


def scan_problems(
    scan_dir: str | Path,
    raw_root: str | Path,
    *,
    duplicate: bool = False,
    earlier_night: str | None = None,
    limits: Plausibility | None = None,
) -> tuple[rawio.RawScan | None, list[ScanError]]:
    """Every reason the ingest stage sets this scan aside, in the order above ([] = accepted).

    Parameters
    ----------
    scan_dir : ``<raw_root>/night=<night>/scan=<scan_id>``
    raw_root : the raw root (folders and files must resolve inside it)
    duplicate : the scan id is used by a scan of an earlier night
        (:func:`borescan.rawio.earlier_duplicate_ids`)
    earlier_night : that night, when known (named in the problem; implies ``duplicate``)
    limits : the config's plausibility bounds (:func:`plausibility_problems`; None: the schema's)

    Returns
    -------
    (scan, problems)
        The scan when it could be read (even if a later check failed), else None.
    """
    scan_dir = Path(scan_dir)
    problems: list[ScanError] = []
    sid = scan_dir.name[5:] if scan_dir.name.startswith("scan=") else scan_dir.name
    if duplicate or earlier_night is not None:
        problems.append(ScanError(sid, rawio.SCAN_JSON, duplicate_reason(earlier_night)))
    scan, errors = rawio.inspect_scan(scan_dir, Path(raw_root))
    if errors:
        return None, problems + errors
    for w in scan.warnings:
        if "outside" in w:  # rawio's range warnings: "<file>: channel <c>: <n> readings outside [0, <r>] mm"
            file, _, msg = w.partition(": ")
            problems.append(ScanError(scan.scan_id, file, f"{msg} {OUT_OF_RANGE_NOTE}"))
    clock = clock_problem(scan)
    if clock:
        problems.append(ScanError(scan.scan_id, rawio.LDS_FILE, clock))
    spindle = spindle_problem(scan)
    if spindle:
        problems.append(ScanError(scan.scan_id, rawio.SPINDLE_FILE, spindle))
    problems += plausibility_problems(scan.meta, scan.scan_id, limits)
    return scan, problems


@dataclass
class TreeReport:
    """What :func:`validate_tree` found.

    Attributes
    ----------
    problems : list of ScanError
        Tree entries first (scan_id ``"-"``), then per scan in night and folder order.
    n_scans : int
        Scan folders checked.
    bad_scan_ids : set of str
        Scans that ingest would quarantine.
    """

    problems: list[ScanError] = field(default_factory=list)
    n_scans: int = 0
    bad_scan_ids: set[str] = field(default_factory=set)


def validate_tree(
    raw_root: str | Path,
    progress: Callable[[int, int], None] | None = None,
    limits: Plausibility | None = None,
) -> TreeReport:
    """Check a raw tree as the pipeline would ingest it (see the module docstring).

    ``progress(i, n)`` is called after each scan. Raises :class:`RawRootError` when ``raw_root``
    is not an existing folder.
    """
    root = require_raw_root(raw_root)
    nights = rawio.nights(root)
    jobs: list[tuple[Path, str | None]] = []
    first_night: dict[str, str] = {}
    for night in nights:
        for d in rawio.night_scan_dirs(root, night):
            jobs.append((d, first_night.get(d.name[5:])))
            first_night.setdefault(d.name[5:], night)
    # entries the pipeline never ingests (a folder night=2026-02-30, a stray file) or cannot list
    report = TreeReport(problems=rawio.tree_problems(root))
    listed = {d for d, _ in jobs}
    stray = [d for d in rawio.discover_scans(root) if d not in listed and d.parent.name[6:] in nights]
    for d in stray:  # e.g. an empty "scan=" folder: the pipeline skips it, say why
        report.problems += rawio.inspect_scan(d, root)[1] or [
            ScanError("-", f"{d.parent.name}/{d.name}", "not a scan=<scan_id> folder; the pipeline skips it")
        ]
    by_night: dict[str, list[dict]] = {}  # the accepted scans' artifact certificates, for the check below
    for i, (d, earlier) in enumerate(jobs):
        scan, problems = scan_problems(d, root, earlier_night=earlier, limits=limits)
        report.problems += problems
        if problems:
            report.bad_scan_ids.add(d.name[5:])
        else:
            by_night.setdefault(d.parent.name[6:], []).append(
                {
                    "scan_id": d.name[5:],
                    "night": d.parent.name[6:],
                    "status": "ok",
                    "started_at": scan.meta.get("started_at"),
                    "artifact_id": (scan.meta.get("artifact") or {}).get("id"),
                    **certificate_fields(scan.meta),
                }
            )
        if progress is not None:
            progress(i + 1, len(jobs))
    report.n_scans = len(jobs)
    # a certificate that changes its value (ingest quarantines the later scan; artifacts.on_conflict)
    earlier: list[dict] = []
    for night in sorted(by_night):
        for sid, why in certificate_conflicts(earlier, by_night[night]).items():
            report.problems.append(ScanError(sid, "scan.json", why))
            report.bad_scan_ids.add(sid)
        earlier += [r for r in by_night[night] if r["scan_id"] not in report.bad_scan_ids]
    return report


# --------------------------------------------------------------------------- plausibility (issue 40)


@dataclass(frozen=True)
class Plausibility:
    """The config's ``plausibility`` bounds (``workflow/schemas/config.schema.yaml``)."""

    temperature_min_c: float
    temperature_max_c: float
    max_sensor_range_mm: float
    certified_vs_nominal_max_mm: float

    @classmethod
    def from_config(cls, section: dict | None) -> Plausibility:
        """Return the bounds of the config's section, missing keys from the schema.

        Keys are missing in a night recorded before the section existed.
        """
        return cls(**{**schema_defaults()["plausibility"], **(section or {})})


def _positive(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0


def _gauge_problems(node: dict, where: str, limits: Plausibility) -> list[str]:
    """Return the problems in an artifact's or feature's diameters, uncertainty, k, CTE and tolerance."""
    out = []
    for key in (
        "nominal_diameter_mm",
        "certified_diameter_mm",
        "u_diameter_mm",
        "k",
        "cte_per_k",
        "tolerance_mm",
    ):
        if key in node and node[key] is not None and not _positive(node[key]):
            out.append(f"key '{where}.{key}' must be a positive number, got {node[key]!r:.40}")
    cert, nom = node.get("certified_diameter_mm"), node.get("nominal_diameter_mm")
    if _positive(cert) and _positive(nom) and abs(cert - nom) > limits.certified_vs_nominal_max_mm:
        out.append(
            f"key '{where}.certified_diameter_mm' {cert:g} mm is {abs(cert - nom):.4g} mm from "
            f"'{where}.nominal_diameter_mm' {nom:g} mm (plausibility.certified_vs_nominal_max_mm "
            f"{limits.certified_vs_nominal_max_mm:g} mm): a typo?"
        )
    if _positive(node.get("cte_per_k")) and node["cte_per_k"] > 1e-4:
        out.append(
            f"key '{where}.cte_per_k' {node['cte_per_k']:g} /K is no metal's (1e-4 /K at most): a unit slip?"
        )
    return out


def plausibility_problems(meta: dict, scan_id: str, limits: Plausibility | None = None) -> list[ScanError]:
    """Return the numbers of ``scan.json`` that feed a result, against what a gauge room can produce.

    Sensor range (0, ``max_sensor_range_mm``], data-sheet linearity and repeatability > 0 (a zero would
    shrink every uncertainty), ``environment.temperature_c`` within the workshop's range, the artifact's
    and its features' diameters, uncertainty, coverage factor, CTE and tolerance positive numbers, a
    certified diameter within ``certified_vs_nominal_max_mm`` of the nominal, ``started_at`` on the
    night's date or the next day. One :class:`ScanError` per problem, naming the key.
    """
    limits = limits or Plausibility.from_config(None)
    out: list[str] = []
    for i, s in enumerate(meta.get("sensors") or []):
        if not isinstance(s, dict):
            continue
        rng = s.get("range_mm")
        if _positive(rng) and rng > limits.max_sensor_range_mm:
            out.append(
                f"key 'sensors[{i}].range_mm' {rng:g} mm exceeds plausibility.max_sensor_range_mm "
                f"{limits.max_sensor_range_mm:g} mm"
            )
        for key in ("linearity_fs", "repeatability_mm"):
            if key in s and not _positive(s[key]):
                out.append(
                    f"key 'sensors[{i}].{key}' must be a positive number (a data-sheet uncertainty), "
                    f"got {s[key]!r:.40}"
                )
    env = meta.get("environment")
    t = env.get("temperature_c") if isinstance(env, dict) else None
    if (
        isinstance(t, (int, float))
        and not isinstance(t, bool)
        and not (limits.temperature_min_c <= t <= limits.temperature_max_c)
    ):
        out.append(
            f"key 'environment.temperature_c' {t:g} degC is outside the workshop's range "
            f"[{limits.temperature_min_c:g}, {limits.temperature_max_c:g}] "
            "degC (plausibility.temperature_*_c)"
        )
    art = meta.get("artifact")
    if isinstance(art, dict):
        out += _gauge_problems(art, "artifact", limits)
        for i, f in enumerate(art.get("features") or []):
            if isinstance(f, dict):
                out += _gauge_problems(f, f"artifact.features[{i}]", limits)
    out += _started_problem(meta)
    return [ScanError(scan_id, rawio.SCAN_JSON, p) for p in out]


def _started_problem(meta: dict) -> list[str]:
    night, started = meta.get("night"), meta.get("started_at")
    try:
        day = _dt.date.fromisoformat(night)
        ts = _dt.datetime.fromisoformat(started)
    except (TypeError, ValueError):
        return []  # the format check names these
    if ts.date() not in (day, day + _dt.timedelta(days=1)):
        return [f"key 'started_at' {started} is not within night {night} (its date or the next day)"]
    return []
