"""What a scan's model-discrepancy examination compares it with."""

import json

import numpy as np
import polars as pl

from borescan.calibration import TriCalibration
from borescan.discrepancy.reference import discrepancy_reference
from borescan.geometry import Beams


def _row(cal_id, valid_from, rho, method="full_lsq", device="TRI-01"):
    beams = Beams(channels=(1, 2, 3), beta_rad=np.array([0.0, 2.1, 4.2]), rho_mm=np.array([rho, 0.0, 0.0]),
                  d_b_mm=np.array([120.0, 120.0, 120.0]))
    cal = TriCalibration(cal_id, device, beams, np.eye(9) * 1e-8, method, ("S",))
    return {"calibration_id": cal_id, "device_id": device, "valid_from": valid_from, "method": method,
            "calibration_json": json.dumps(cal.to_dict())}


CALS = pl.DataFrame([_row("A", "2026-11-01", 1.0), _row("B", "2026-11-20", 2.0), _row("C", "2026-11-25", 3.0),
                     _row("N", "2026-11-21", 9.0, method="nominal")])


def test_latest_calibration_on_or_before_the_night():
    kw, ref = discrepancy_reference(CALS, "TRI-01", "tri_lds", "2026-11-21")
    assert ref == "calibration B" and kw["beams"].rho_mm[0] == 2.0  # the nominal record of the 21st is not one
    kw, ref = discrepancy_reference(CALS, "TRI-01", "tri_lds", "2026-11-20")
    assert ref == "calibration B"


def test_uncalibrated_device_is_compared_with_its_design_geometry_freed():
    expected = ({"free_beams": ("d_b", "beta", "rho")}, "device.nominal (beam geometry free)")
    assert discrepancy_reference(CALS, "TRI-01", "tri_lds", "2026-10-01") == expected
    assert discrepancy_reference(CALS, "TRI-02", "tri_lds", "2026-11-21") == expected
    assert discrepancy_reference(pl.DataFrame(), "TRI-01", "tri_lds", "2026-11-21") == expected


def test_rod_is_compared_with_its_design_geometry():
    assert discrepancy_reference(CALS, "ROD-01", "rod", "2026-11-21") == ({}, "device.nominal")
