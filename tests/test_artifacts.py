"""Certified artifacts: a ring gauge's radius at the scan's temperature, its catalog row."""

import pytest

from borescan.artifacts import artifact_row, gauge_radius_mm, radius_at_temperature_mm


def test_radius_at_temperature_closed_form():
    # steel gauge, 275.029 mm at 20 degC, 11.5e-6 /K, at 25 degC: R = 137.5145 (1 + 5 * 11.5e-6)
    assert radius_at_temperature_mm(137.5145, 11.5e-6, 25.0) == pytest.approx(137.5145 * 1.0000575, rel=1e-15)
    assert radius_at_temperature_mm(137.5145, 11.5e-6, 20.0) == 137.5145
    assert radius_at_temperature_mm(100.0, 1e-5, 10.0) == pytest.approx(99.99, rel=1e-15)  # contracts below 20 degC


def test_gauge_radius_from_scan_json():
    meta = {"artifact": {"certified_diameter_mm": 275.029, "nominal_diameter_mm": 275.0, "cte_per_k": 11.5e-6},
            "environment": {"temperature_c": 20.6}}
    assert gauge_radius_mm(meta) == 0.5 * 275.029 * (1.0 + 11.5e-6 * (20.6 - 20.0))


def test_gauge_radius_defaults_nominal_diameter_20_degc_and_no_expansion():
    assert gauge_radius_mm({"artifact": {"nominal_diameter_mm": 280.0}}) == 140.0
    assert gauge_radius_mm({"artifact": {"nominal_diameter_mm": 280.0, "cte_per_k": 1e-5}}) == 140.0
    assert gauge_radius_mm({"artifact": {"certified_diameter_mm": 280.0}, "environment": {"temperature_c": 30.0}}) == 140.0


def test_gauge_without_diameter_is_an_error():
    with pytest.raises(ValueError, match="neither certified_diameter_mm nor nominal_diameter_mm"):
        gauge_radius_mm({"artifact": {"id": "RG-275"}})
    with pytest.raises(ValueError, match="neither"):
        gauge_radius_mm({})


def test_artifact_row():
    meta = {"artifact": {"id": "RG-275", "type": "ring_gauge", "certified_diameter_mm": 275.029, "k": 2}}
    row = artifact_row(meta)
    assert row["artifact_id"] == "RG-275" and row["certified_diameter_mm"] == 275.029 and row["cte_per_k"] is None
    assert artifact_row({"artifact": {"type": "part"}}) is None and artifact_row({}) is None
