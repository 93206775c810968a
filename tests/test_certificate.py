"""Certificates: content, layout and byte-identical regeneration."""

import json
import re

import numpy as np
import pytest

from borescan.calibration import fit_full_calibration, full_residuals, yang_calibration
from borescan.certificate import certificate_dir, write_certificate
from borescan.geometry import Beams, Bore, tri_spindle_readings

TRUE = Beams((1, 2, 3), np.array([0.3, 2.4, 4.5]), np.array([5.5484, -2.5295, 1.5262]),
             np.array([132.6718, 132.8883, 134.1108]))
R_MM = 275.029 / 2


@pytest.fixture(scope="module")
def calibrated():
    rng = np.random.default_rng(11)
    t = np.arange(1000) / 200.0
    v = tri_spindle_readings(2 * np.pi * t, np.array([0.122, -2.320]), TRUE, Bore((0.0, 0.0), R_MM))
    v = v + rng.normal(0, 0.002, v.shape)
    cal = fit_full_calibration(t, v, TRUE.channels, TRUE, R_MM, rpm=60.0, scan_ids=["N20261121-TRI01-CAL-P1"],
                               device_id="TRI-01", raw_sha256={"lds.parquet": "a" * 64})
    kw = dict(
        device={"id": "TRI-01", "type": "tri_lds", "sensors": "HG-C1030 x3"},
        artifact={"id": "RG-275", "certificate": "RG-275/2026-03", "certified_diameter_mm": 275.029,
                  "u_diameter_mm": 0.0015, "k": 2},
        conditions={"temperature_c": 20.4, "spindle_position": {"label": "P1", "x_mm": 262.955, "y_mm": -275.502},
                    "rpm": 60.0, "revolutions": 5},
        residuals={"t_s": t, "residual_mm": full_residuals(cal, t, v, R_MM)},
        raw_files={"scan.json": "b" * 64, "lds.parquet": "a" * 64},
        software_version="0.1.0",
        config_hash="c0ffee12",
    )
    return cal, kw


def test_regeneration_is_byte_identical(calibrated, tmp_path):
    cal, kw = calibrated
    a = write_certificate(cal, certificate_dir(tmp_path / "a", cal), **kw)
    first = {k: p.read_bytes() for k, p in a.items()}
    b = write_certificate(cal, certificate_dir(tmp_path / "b", cal), **kw)
    again = write_certificate(cal, certificate_dir(tmp_path / "a", cal), **kw)  # overwrite in place
    for k in ("json", "pdf", "png"):
        assert b[k].read_bytes() == first[k], k
        assert again[k].read_bytes() == first[k], k
    assert sorted(p.name for p in a["json"].parent.iterdir()) == ["certificate.json", "certificate.pdf", "residuals.png"]


def test_layout_and_metadata(calibrated, tmp_path):
    cal, kw = calibrated
    paths = write_certificate(cal, certificate_dir(tmp_path, cal), **kw)
    assert paths["pdf"].parent == tmp_path / "calibration" / "TRI-01" / cal.calibration_id
    pdf = paths["pdf"].read_bytes()
    assert pdf.startswith(b"%PDF")
    for key in (b"/CreationDate", b"/ModDate", b"/Producer", b"/Creator"):
        assert key not in pdf
    assert len(re.findall(rb"/Type /Page\b(?!s)", pdf)) == 2  # parameter page + residual page
    png = paths["png"].read_bytes()
    assert png.startswith(b"\x89PNG") and b"Software" not in png and b"matplotlib" not in png


def test_json_content(calibrated, tmp_path):
    cal, kw = calibrated
    text = write_certificate(cal, tmp_path, **kw)["json"].read_text()
    cert = json.loads(text)
    assert text == json.dumps(cert, sort_keys=True, indent=2) + "\n"  # sorted keys, no NaN
    assert cert["calibration_id"] == cal.calibration_id and cert["method"] == "full_lsq"
    assert list(cert["raw_files"]) == ["lds.parquet", "scan.json"]
    for j, p in enumerate(cert["parameters"]):
        assert p["channel"] == j + 1
        assert p["U_rho_mm"] == pytest.approx(2 * cal.u_rho_mm[j], rel=1e-11)
        assert p["U_d_b_mm"] == pytest.approx(2 * cal.u_d_b_mm[j], rel=1e-11)
        assert p["d_b_mm"] == pytest.approx(cal.beams.d_b_mm[j], rel=1e-11)
    assert cert["parameters"][0]["U_beta_rad"] == 0.0  # gauge
    assert np.array(cert["covariance"]).shape == (9, 9)
    assert cert["residuals"]["n_samples"] == 1000
    assert np.allclose(cert["residuals"]["rms_mm_per_channel"], 0.002, rtol=0.1)
    assert cert["artifact"]["certified_diameter_mm"] == 275.029 and cert["conditions"]["temperature_c"] == 20.4
    assert cert["software_version"] == "0.1.0" and cert["config_hash"] == "c0ffee12"


def test_yang_certificate_without_fit_diagnostics(tmp_path):
    cal = yang_calibration([7.0549, 6.9256, 5.7177], [2.4067, 2.2804, 1.073], ["backward", "backward", "advanced"],
                           [312.0, 88.0, 199.0], 660.0, R_MM, 2.3222, device_id="TRI-01", scan_ids=["N20170205-P1"],
                           u_d_max_mm=1e-4, u_d_min_mm=1e-4)
    t = np.arange(5) * 0.1
    paths = write_certificate(cal, tmp_path, device={"id": "TRI-01"}, artifact={"id": "RG-275"}, conditions={},
                              residuals={"t_s": t, "residual_mm": np.zeros((5, 3))}, raw_files={},
                              software_version="0.1.0", config_hash="x")
    cert = json.loads(paths["json"].read_text())
    assert cert["method"] == "yang2017" and cert["fit"]["residual_rms_mm"] is None
    assert cert["parameters"][2]["rho_mm"] == pytest.approx(1.5627026, abs=1e-6)
