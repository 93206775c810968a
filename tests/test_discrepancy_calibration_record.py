"""A verdict read against a calibration says what the calibration's own scans were found to carry."""

from borescan.discrepancy.calibration_record import (
    CalibrationFinding,
    calibration_findings,
    with_calibration_findings,
)

CAL = "TRI-01-20261123-full_lsq-b9f662b0"


def _row(sid, verdict, effect=None, channel=None):
    return {"scan_id": sid, "verdict": verdict, "effect": effect, "channel": channel}


def test_the_calibration_scans_findings_are_read_per_scan_in_the_calibrations_order():
    """Rows of the findings table (one per named effect) become one record per scan of the calibration;
    a scan of the calibration that was not examined is left out, other scans' rows are ignored.
    """
    rows = [
        _row("VER", "ambiguous", "sensor_gain", 1),
        _row("CAL-B", "missing_effect", "channel_delay", 2),
        _row("CAL-A", "ambiguous", "sensor_offset", None),
        _row("CAL-A", "ambiguous", "thermal_expansion", None),
    ]
    got = calibration_findings(CAL, ("CAL-A", "CAL-B", "CAL-C"), rows)
    assert got == [
        CalibrationFinding(CAL, "CAL-A", "ambiguous", ("sensor_offset@all", "thermal_expansion@all")),
        CalibrationFinding(CAL, "CAL-B", "missing_effect", ("channel_delay@2",)),
    ]
    assert got[1].to_dict() == {
        "calibration_id": CAL,
        "scan_id": "CAL-B",
        "verdict": "missing_effect",
        "effects": ["channel_delay@2"],
        "thermal_as_recorded": False,
    }


def test_a_verdict_read_against_a_flawed_calibration_leads_with_it():
    """The night-23 case of the demo: both calibration scans name a 1.2 ms delay on channel 2; the static
    verification's offset-like verdict is led by it and the advice to fix it and recalibrate; a clean
    calibration or a verdict with nothing missing leaves the statement as it was (the record still there).
    """
    f = {
        "verdict": "ambiguous",
        "statement": "offset-like: one combination ... recalibrate the sensors' zeroes",
    }
    flawed = calibration_findings(
        CAL,
        ("A", "B"),
        [_row("A", "missing_effect", "channel_delay", 2), _row("B", "missing_effect", "channel_delay", 2)],
    )
    out = with_calibration_findings(f, flawed)
    assert out["statement"] == (
        f"its calibration {CAL} was itself found to carry channel_delay on channel 2 (A, B): fix that and "
        "recalibrate before reading this; what this scan alone shows: " + f["statement"]
    )
    assert [c["effects"] for c in out["calibration_findings"]] == [["channel_delay@2"]] * 2
    clean = calibration_findings(CAL, ("A",), [_row("A", "no_missing_effect")])
    assert with_calibration_findings(f, clean) == dict(f, calibration_findings=[clean[0].to_dict()])
    quiet = {"verdict": "no_missing_effect", "statement": "the residual is at the noise floor"}
    assert with_calibration_findings(quiet, flawed)["statement"] == quiet["statement"]
    tied = calibration_findings(
        CAL, ("A",), [_row("A", "ambiguous", "sensor_offset"), _row("A", "ambiguous", "thermal_expansion")]
    )
    assert with_calibration_findings(f, tied)["statement"].startswith(
        f"its calibration {CAL} was itself found to carry one of sensor_offset, thermal_expansion "
        "(they look alike there) (A)"
    )


def test_a_calibration_whose_scans_show_only_its_recorded_thermal_expansion_is_no_flaw():
    """Warm calibration scans name thermal expansion at 20.57 +- 0.02 degC, tied with a common offset; read at
    20.6 degC the calibration corrected for it, so a scan read against it is not told to recalibrate; recorded
    at 20.0 degC the same finding is a flaw.
    """
    import json

    rows = [
        {"scan_id": "A", "verdict": "ambiguous", "effect": "sensor_offset", "channel": None,
         "parameters": json.dumps({"b_mm": 0.0009}), "uncertainties": json.dumps({"u_b_mm": 3e-5})},
        {"scan_id": "A", "verdict": "ambiguous", "effect": "thermal_expansion", "channel": None,
         "parameters": json.dumps({"temperature_c": 20.573}),
         "uncertainties": json.dumps({"u_temperature_c": 0.019})},
    ]  # fmt: skip
    f = {"verdict": "ambiguous", "statement": "offset-like"}
    (warm,) = calibration_findings(CAL, ("A",), rows, 20.6)
    assert warm.thermal_as_recorded and not warm.flawed
    assert with_calibration_findings(f, [warm])["statement"] == "offset-like"
    (cold,) = calibration_findings(CAL, ("A",), rows, 20.0)
    assert cold.flawed and with_calibration_findings(f, [cold])["statement"].startswith("its calibration")
