"""What a scan's model-discrepancy examination compares it with."""

import json

import numpy as np
import polars as pl

from borescan.calibrate.result import TriCalibration
from borescan.discrepancy.reference import discrepancy_reference
from borescan.geometry import Beams


def _row(cal_id, valid_from, rho, method="full_lsq", device="TRI-01"):
    beams = Beams(
        channels=(1, 2, 3),
        beta_rad=np.array([0.0, 2.1, 4.2]),
        rho_mm=np.array([rho, 0.0, 0.0]),
        d_b_mm=np.array([120.0, 120.0, 120.0]),
    )
    cal = TriCalibration(cal_id, device, beams, np.eye(9) * 1e-8, method, ("S",))
    return {
        "calibration_id": cal_id,
        "device_id": device,
        "valid_from": valid_from,
        "method": method,
        "calibration_json": json.dumps(cal.to_dict()),
    }


CALS = pl.DataFrame(
    [
        _row("A", "2026-11-01", 1.0),
        _row("B", "2026-11-20", 2.0),
        _row("C", "2026-11-25", 3.0),
        _row("N", "2026-11-21", 9.0, method="nominal"),
    ]
)


def test_latest_calibration_on_or_before_the_night():
    kw, ref = discrepancy_reference(CALS, "TRI-01", "tri_lds", "2026-11-21")
    assert (
        ref == "calibration B" and kw["beams"].rho_mm[0] == 2.0
    )  # the nominal record of the 21st is not one
    kw, ref = discrepancy_reference(CALS, "TRI-01", "tri_lds", "2026-11-20")
    assert ref == "calibration B"


def test_uncalibrated_device_is_compared_with_its_design_geometry_freed():
    expected = ({"free_beams": ("d_b", "beta", "rho")}, "device.nominal (beam geometry free)")
    assert discrepancy_reference(CALS, "TRI-01", "tri_lds", "2026-10-01") == expected
    assert discrepancy_reference(CALS, "TRI-02", "tri_lds", "2026-11-21") == expected
    assert discrepancy_reference(pl.DataFrame(), "TRI-01", "tri_lds", "2026-11-21") == expected


def test_rod_is_compared_with_its_design_geometry_until_it_is_calibrated_on_gauges():
    assert discrepancy_reference(CALS, "ROD-01", "rod", "2026-11-21") == ({}, "device.nominal")
    rod = pl.DataFrame(
        [
            {
                "calibration_id": cid,
                "device_id": "ROD-01",
                "valid_from": v,
                "method": m,
                "channel": ch,
                "l0_mm": l0 + ch * 1e-3,
                "h_mm": 100.0 * ch,
                "phi_rad": 0.01,
                "d_mm": None,
                "gamma_rad": 0.002,
            }
            for cid, v, m, l0 in (
                ("ROD-nominal", "2026-11-01", "nominal", 71.0),
                ("ROD-G1", "2026-11-10", "rod_gauge", 71.012),
                ("ROD-G2", "2026-11-30", "rod_gauge", 71.020),
            )
            for ch in (2, 1)
        ]
    )
    cals = pl.concat([CALS, rod], how="diagonal_relaxed")
    assert discrepancy_reference(cals, "ROD-01", "rod", "2026-11-05") == ({}, "device.nominal")
    kw, ref = discrepancy_reference(cals, "ROD-01", "rod", "2026-11-21")
    assert ref == "calibration ROD-G1"
    assert kw == {
        "layers": [
            {"channel": 1, "l0": 71.013, "h": 100.0, "phi": 0.01, "d": 0.0, "gamma": 0.002},
            {"channel": 2, "l0": 71.014, "h": 200.0, "phi": 0.01, "d": 0.0, "gamma": 0.002},
        ]
    }


def test_a_calibration_that_carried_a_device_model_brings_its_effects_into_the_base():
    from dataclasses import replace

    from borescan.device_model import DeviceEffect
    from borescan.effects import Effect

    row = _row("D", "2026-11-22", 1.0)
    cal = TriCalibration.from_dict(json.loads(row["calibration_json"]))
    delay = Effect("channel_delay", {"channel": 2, "tau_s": 1.2e-3})
    model = [
        DeviceEffect("channel_delay@2", (delay,), {"tau_s": 2e-5}, "2026-11-21", ("S",)),
        DeviceEffect("sensor_offset@3"),
    ]  # listed, not estimated: nothing to carry
    cal = replace(cal, diagnostics={"device_model": [m.to_dict() for m in model]})
    cals = pl.DataFrame([dict(row, calibration_json=json.dumps(cal.to_dict()))])
    kw, ref = discrepancy_reference(cals, "TRI-01", "tri_lds", "2026-11-22")
    assert kw["device_effects"] == [delay] and kw["beams"].rho_mm[0] == 1.0
    assert ref == "calibration D with its device model (channel_delay:channel=2,tau_s=0.0012)"
