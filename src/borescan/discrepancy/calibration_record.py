"""What the examinations of a calibration's own scans found, carried into the verdicts read against it.

A scan examined against a calibration inherits its flaws: a channel delay in the calibration's scans biases
its channel's beta, and a static verification read against that geometry then "misses" gains or offsets
that are the calibration's, not the sensors'. Where the calibration's scans were examined too (this night's
examinations, or an earlier night's ``findings`` table) and named an effect, the scan's findings.json says
so (``calibration_findings``: one :class:`CalibrationFinding` per scan of the calibration), and a verdict
that names an effect leads with it: fix that and recalibrate before reading this one.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass

from borescan.discrepancy.classes import recorded_thermal

__all__ = ["CalibrationFinding", "calibration_findings", "with_calibration_findings"]


@dataclass(frozen=True)
class CalibrationFinding:
    """The examination of one scan a calibration was made from.

    calibration_id : the calibration; scan_id : its scan; verdict : that scan's verdict;
    effects : the effects it named, ``effect@channel`` (``@all`` for no channel), in findings order;
    thermal_as_recorded : one of them is the gauge's thermal expansion at the temperature the calibration
    records (:func:`~borescan.discrepancy.classes.recorded_thermal`): the calibration corrected for it.
    """

    calibration_id: str
    scan_id: str
    verdict: str
    effects: tuple[str, ...]
    thermal_as_recorded: bool = False

    @property
    def flawed(self) -> bool:
        """Return whether the scan names an effect the calibration did not correct for."""
        return self.verdict != "no_missing_effect" and bool(self.effects) and not self.thermal_as_recorded

    def to_dict(self) -> dict:
        """Return the JSON-ready form (findings.json ``calibration_findings``)."""
        return {
            "calibration_id": self.calibration_id,
            "scan_id": self.scan_id,
            "verdict": self.verdict,
            "effects": list(self.effects),
            "thermal_as_recorded": self.thermal_as_recorded,
        }


def _label(effect: str, channel) -> str:
    return f"{effect}@{int(channel)}" if channel is not None else f"{effect}@all"


def _named(r: dict) -> dict:
    return {
        "effect": r.get("effect"),
        "parameters": json.loads(r.get("parameters") or "{}"),
        "uncertainties": json.loads(r.get("uncertainties") or "{}"),
    }


def calibration_findings(
    calibration_id: str, scan_ids: Iterable[str], rows: Iterable[dict], recorded_c: float | None = None
) -> list[CalibrationFinding]:
    """Return the examinations of the calibration's scans found in ``rows`` (``findings`` table rows).

    One per scan of ``scan_ids`` that has rows (in the calibration's order); a scan not examined is left out.
    ``recorded_c``: the temperature [degC] the calibration read its gauge at.
    """
    by_scan: dict[str, list[dict]] = {}
    for r in rows:
        by_scan.setdefault(r["scan_id"], []).append(r)
    out = []
    for sid in scan_ids:
        if sid not in by_scan:
            continue
        rs = by_scan[sid]
        effects = tuple(dict.fromkeys(_label(r["effect"], r.get("channel")) for r in rs if r.get("effect")))
        thermal = recorded_thermal([_named(r) for r in rs if r.get("effect")], recorded_c) is not None
        out.append(CalibrationFinding(calibration_id, sid, str(rs[0]["verdict"]), effects, thermal))
    return out


def _words(label: str) -> str:
    effect, _, ch = label.partition("@")
    return effect if ch == "all" else f"{effect} on channel {ch}"


def with_calibration_findings(findings: dict, record: list[CalibrationFinding]) -> dict:
    """Return ``findings`` with ``calibration_findings``, its statement led by what they name, if anything.

    The statement of a verdict that names an effect (not ``no_missing_effect``) starts with what the
    calibration's scans carry and the advice to fix that and recalibrate before reading the rest.
    """
    out = dict(findings, calibration_findings=[f.to_dict() for f in record])
    flawed = [f for f in record if f.flawed]
    if not flawed or findings.get("verdict") == "no_missing_effect":
        return out
    words = [_words(e) for e in dict.fromkeys(e for f in flawed for e in f.effects)]
    tied = any(f.verdict == "ambiguous" for f in flawed) and len(words) > 1
    what = "one of " + ", ".join(words) + " (they look alike there)" if tied else " and ".join(words)
    scans = ", ".join(f.scan_id for f in flawed)
    out["statement"] = (
        f"its calibration {flawed[0].calibration_id} was itself found to carry {what} ({scans}): fix that "
        f"and recalibrate before reading this; what this scan alone shows: {findings.get('statement')}"
    )
    return out
