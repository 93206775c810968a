"""What a person does about a quarantined scan or a discrepancy verdict."""

from __future__ import annotations


from borescan.effects import EFFECTS
from borescan.report.text import _e

#: Quarantine reasons by class (first match of a lower-case fragment of the reason wins):
#: (class, fragments, what an operator does), after the README's "When something needs attention".
QUARANTINE_ACTIONS = (
    (
        "scan id reused",
        ("already used", "unique across nights"),
        "Write the scan under a new scan id (ids are unique across nights) and rerun.",
    ),
    (
        "calibration refused",
        ("calibration refused",),
        "Read discrepancy/<scan>/findings.json of these scans: it names what the model misses. Check that "
        "sensor or its cabling, recalibrate. Measurements keep the last valid calibration until it expires.",
    ),
    (
        "calibration failed verification",
        ("failed its verification",),
        "Recalibrate the device; its measurements are refused until a new calibration passes verification.",
    ),
    ("calibration expired", ("expired",), "Recalibrate the device, then rerun the night."),
    (
        "design geometry missing",
        ("device.nominal",),
        "Write the scan again under a new scan id with device.nominal "
        "(the design beams of a three-sensor device, the "
        "layers of a rod; optional in the raw format) or calibrate "
        "the device from a scan that has it: scans of a "
        "calibrated device are measured and examined against its calibration.",
    ),
    (
        "no calibration",
        ("no calibration",),
        "Calibrate the device (a calibration scan on or before the night), then rerun the night.",
    ),
    (
        "too few revolutions or poses",
        ("too few", "revolutions", "poses"),
        "Rescan with more whole revolutions (or poses), the spindle at the gauge centre, under a new "
        "scan id.",
    ),
    (
        "scan metadata",
        ("needs a ring_gauge",),
        "Correct scan.json (kind, artifact, certificate) in a new scan id and rerun; never edit the "
        "raw folder in place.",
    ),
    (
        "processing error",
        ("stage failed", "measurement failed", "examination failed", "calibration failed"),
        "Read the stage's log under logs/ and quarantine/<scan>.json; if borescan validate passes on "
        "the scan, "
        "report it with the record.",
    ),
)
#: A reason that matches no class: the raw file itself is broken.
BROKEN_FILE_ACTION = (
    "broken file",
    "Fix the export or rescan under a new scan id (never edit the raw folder in place); "
    "borescan validate RAW_ROOT shows the same verdict before a run.",
)


def quarantine_action(reason: str | None) -> tuple[str, str]:
    """(class, what to do) of a quarantine reason (README "When something needs attention").

    Reasons that name no processing class (truncated file, wrong types, clock jump, readings
    out of range, non-monotonic samples, ...) are a broken raw file.
    """
    text = (reason or "").lower()
    for cls, fragments, action in QUARANTINE_ACTIONS:
        if any(f in text for f in fragments):
            return cls, action
    return BROKEN_FILE_ACTION


def _verdict_note(verdict: str, effects: list[str]) -> str:
    """Return what a verdict means for the person reading it (HTML)."""
    if verdict == "ambiguous":
        names = ", ".join(dict.fromkeys(effects))
        hints = sorted({EFFECTS[e].separated_by for e in effects if e in EFFECTS and EFFECTS[e].separated_by})
        how = (
            " A scan at " + " or ".join(hints) + " separates them."
            if hints
            else " A scan that differs in what separates them does."
        )
        return _e(
            f"Ambiguous between {names}: they explain this scan's data equally well (outputs.md lists every "
            "such candidate); one scan cannot tell them apart, nothing is wrong with the software." + how
        )
    if verdict == "missing_effect":
        return _e(
            "The model misses this effect; if it persists over scans, service the device (sensor, cabling, "
            "spindle)."
        )
    return ""
