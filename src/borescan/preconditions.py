"""What each stage needs of a scan that ingest accepted: the one place of the stages' preconditions.

The raw spec makes ``device.nominal`` (the design geometry) optional, and a scan may be too
short to calibrate from; neither is bad raw data, so ingest accepts such a scan and a later
stage sets it aside with its own reason. The stages call these functions, and
``borescan validate`` calls the same ones (:func:`expected_outcomes`) so that it says, before a
run, what each scan will get:

- three-sensor calibration (``calibrate``): a spindle stream, ``device.nominal.beams`` (the fit's
  starting point), and at least ``calibration.min_revolutions`` whole revolutions recorded and
  with a once-per-revolution extremum (:func:`calibration_revolutions_problem`, on the signal
  stage's summary);
- rod gauge calibration (``calibrate``): ``device.nominal.layers`` (the design base lengths it
  corrects);
- model-discrepancy examination (``discrepancy``): the device's calibration, else
  ``device.nominal`` (a scan of a device that has neither has nothing to be compared with).

A missing design geometry raises :class:`MissingDesignGeometry`, another missing key a stage needs
:class:`MissingScanKey` (``ValueError`` subclasses whose ``file`` is ``scan.json``), which every
stage catches and turns into a quarantine record naming that file.
"""

from __future__ import annotations

from dataclasses import dataclass

import polars as pl

from borescan.geometry import Beams

__all__ = [
    "MissingScanKey",
    "MissingDesignGeometry",
    "design_beams",
    "design_layers",
    "has_design_geometry",
    "missing_geometry_reason",
    "NO_SPINDLE_REASON",
    "CALIBRATE_STAGE",
    "summary_revolutions",
    "summary_period_source",
    "calibration_revolutions_problem",
    "StageOutcome",
    "expected_outcomes",
]

SCAN_JSON = "scan.json"


class MissingScanKey(ValueError):
    """An optional key of ``scan.json`` that a stage needs is missing (``file``: the file to name)."""

    file = SCAN_JSON


class MissingDesignGeometry(MissingScanKey):
    """``device.nominal`` (or its ``beams`` / ``layers``) is missing where a stage needs it."""


def _nominal(meta: dict) -> dict:
    return ((meta.get("device") or {}).get("nominal")) or {}


def has_design_geometry(meta: dict) -> bool:
    """``device.nominal`` lists the device's beams (``tri_lds``) or layers (``rod``)."""
    key = "layers" if (meta.get("device") or {}).get("type") == "rod" else "beams"
    return bool(_nominal(meta).get(key))


def missing_geometry_reason(key: str, why: str) -> str:
    """Return the reason given for a scan without ``device.nominal.<key>`` that a stage needs (``why``)."""
    return f"device.nominal.{key} missing (optional in the raw format, but {why})"


#: Why a three-sensor calibration scan without a spindle stream is set aside.
NO_SPINDLE_REASON = "calibration scan has no spindle stream (a ring-gauge calibration turns on a spindle)"


def design_beams(meta: dict, why: str) -> Beams:
    """Return ``device.nominal.beams`` of a three-sensor scan.

    Raise :class:`MissingDesignGeometry` naming ``why`` (what needs them) when the scan has none.
    """
    beams = _nominal(meta).get("beams")
    if not beams:
        raise MissingDesignGeometry(missing_geometry_reason("beams", why))
    return Beams.from_nominal(beams)


def design_layers(meta: dict, why: str) -> list[dict]:
    """``device.nominal.layers`` of a rod scan, by channel; :class:`MissingDesignGeometry` when none."""
    layers = _nominal(meta).get("layers")
    if not layers:
        raise MissingDesignGeometry(missing_geometry_reason("layers", why))
    return sorted(layers, key=lambda lay: int(lay["channel"]))


#: Why a three-sensor calibration needs the design geometry (the message of its quarantine).
CALIBRATION_NEEDS_BEAMS = "a three-sensor calibration starts its fit from the design beam geometry"
#: Why a rod gauge calibration needs it.
ROD_CALIBRATION_NEEDS_LAYERS = "a rod calibration corrects the design base lengths l0 of its layers"
#: Why a discrepancy examination needs it when the device has no calibration.
EXAMINATION_NEEDS_GEOMETRY = (
    "the device has no calibration to compare the scan with, and the examination "
    "otherwise starts from the design geometry"
)


def summary_revolutions(summary, method: str = "full_lsq") -> tuple[int | None, int]:
    """Return (whole revolutions recorded, revolutions with every channel's extremum) of one scan.

    From its rows of the signal stage's summary (a polars frame: ``period_samples_per_rev``,
    ``n_samples_recorded``, ``n_revolutions_min`` and ``n_revolutions_max`` per channel). The
    paper's closed forms (``method`` ``yang2017``) need each channel's minimum; the full fit needs
    each channel to turn with the spindle, its minimum or its maximum: a channel whose readings leave
    its range at one end of each turn (the contract allows it) still fixes its beam.
    """
    spr = float(summary["period_samples_per_rev"][0])
    recorded = (
        int(summary["n_samples_recorded"][0] // spr) if "n_samples_recorded" in summary.columns else None
    )
    per_channel = summary["n_revolutions_min"]
    if method != "yang2017" and "n_revolutions_max" in summary.columns:
        per_channel = summary.select(pl.max_horizontal("n_revolutions_min", "n_revolutions_max"))[:, 0]
    return recorded, int(per_channel.min())


#: The ``file`` of a calibration's quarantine record when no raw file is at fault (a fit that fails, readings
#: that barely vary with rotation): the record names the stage, never a file that is fine.
CALIBRATE_STAGE = "calibrate stage"


def summary_period_source(summary) -> str | None:
    """Return where the signal stage took one scan's rotation period from (``encoder``, ``profile``, ...)."""
    return str(summary["period_source"][0]) if "period_source" in summary.columns else None


def calibration_revolutions_problem(
    recorded: int | None, with_extrema: int, min_rev: int, period_source: str | None = None
) -> tuple[str, str] | None:
    """Why a spindle scan is too short to calibrate from, as (file, reason); None when it is long enough.

    ``recorded``: whole revolutions recorded (samples // samples per revolution; None if not known);
    ``with_extrema``: revolutions in which every channel has its once-per-revolution minimum. Too few
    revolutions recorded is the content of ``lds.parquet``; too few with an extremum is what the calibrate
    stage finds in readings that are otherwise fine (:data:`CALIBRATE_STAGE`); when the period came from the
    spindle stream (``period_source`` ``encoder`` or ``profile``), that stream is the other suspect.
    """
    if recorded is not None and recorded < min_rev:
        return (
            "lds.parquet",
            f"too few revolutions to calibrate: {recorded} whole revolutions recorded, "
            f"at least {min_rev} needed (calibration.min_revolutions)",
        )
    if with_extrema < min_rev:
        return (
            CALIBRATE_STAGE,
            f"calibration failed: a once-per-revolution extremum was found in only {with_extrema} "
            f"revolutions (at least {min_rev} needed); the readings barely vary with rotation, "
            "is the spindle at the gauge centre?"
            + (
                f" Or the rotation period taken from spindle.parquet ({period_source}) does not match them"
                if period_source in ("encoder", "profile")
                else ""
            ),
        )
    return None


@dataclass(frozen=True)
class StageOutcome:
    """What a stage will do with a scan that ingest accepts.

    Set it aside (``quarantined``) or process it with a ``note``.
    """

    scan_id: str
    stage: str
    file: str
    reason: str
    quarantined: bool

    def __str__(self) -> str:
        what = "quarantined" if self.quarantined else "note"
        return f"{self.scan_id}: {self.file}: {self.stage}: {what}: {self.reason}"


def expected_outcomes(
    meta: dict,
    *,
    has_spindle: bool,
    revolutions: tuple[int | None, int] | None,
    min_rev: int,
    period_source: str | None = None,
) -> list[StageOutcome]:
    """Return the preconditions above applied to one accepted scan, in stage order ([] = processed as usual).

    ``revolutions``: (recorded, with extrema) of a three-sensor spindle scan from the signal stage's
    processing; None when not computed (static scans, rods). The first ``quarantined`` outcome is
    the reason the pipeline will give; a ``note`` is a result the scan will lack.
    """
    sid, kind = meta["scan_id"], meta["kind"]
    dev = meta.get("device") or {}
    out: list[StageOutcome] = []
    geometry = has_design_geometry(meta)
    if kind == "calibration" and dev.get("type") == "tri_lds":
        if not has_spindle:
            out.append(StageOutcome(sid, "calibrate", "spindle.parquet", NO_SPINDLE_REASON, True))
        else:  # in the stage's order: the revolutions, then the design geometry
            problem = (
                None
                if revolutions is None
                else calibration_revolutions_problem(*revolutions, min_rev, period_source)
            )
            if problem:
                out.append(StageOutcome(sid, "calibrate", *problem, True))
            elif not geometry:
                out.append(
                    StageOutcome(
                        sid,
                        "calibrate",
                        SCAN_JSON,
                        missing_geometry_reason("beams", CALIBRATION_NEEDS_BEAMS),
                        True,
                    )
                )
    if kind == "calibration" and dev.get("type") == "rod" and not geometry:
        out.append(
            StageOutcome(
                sid,
                "calibrate",
                SCAN_JSON,
                f"rod calibration: {missing_geometry_reason('layers', ROD_CALIBRATION_NEEDS_LAYERS)}",
                True,
            )
        )
    if not geometry and not any(o.quarantined for o in out):
        out.append(
            StageOutcome(
                sid,
                "discrepancy",
                SCAN_JSON,
                "no device.nominal: examined against the device's "
                "calibration only; quarantined at this stage if the device has none",
                False,
            )
        )
    return out
