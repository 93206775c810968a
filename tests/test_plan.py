"""``borescan plan``: the Cramer-Rao prediction of a calibration scan against fits of simulated scans, the
recommendation, the command.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from borescan.calibrate.full_fit import fit_full_calibration
from borescan.synthetic import scenes
from borescan.geometry import Beams
from borescan.plan import DeviceDesign, ScanDesign, predict, recommend

R_MM = 137.5
BEAMS = Beams(
    (1, 2, 3), np.array([0.3, 2.4, 4.3]), np.array([8.0, -6.0, 4.0]), np.array([128.0, 129.0, 130.0])
)
SIGMA_MM = 0.002
SCAN = ScanDesign(offset_mm=4.0, revolutions=5, samples_per_rev=400, encoder=False, positions_known=False)


def _fit(seed: int):
    scene = scenes.TriScene(
        beams=BEAMS,
        bore_center_xy_mm=(0.0, 0.0),
        bore_radius_20_mm=R_MM,
        spindle_xy_mm=(4.0, 0.0),
        sample_rate_hz=400.0,
        range_mm=(20.0, 20.0, 20.0),
    )
    t = np.arange(2000) / 400.0
    v = scenes.tri_readings(scene, t)
    y = v + SIGMA_MM * np.random.default_rng(seed).standard_normal(v.shape)
    return fit_full_calibration(t, y, (1, 2, 3), BEAMS, R_MM, rpm=60.0, range_mm=20.0, scan_ids=[f"P{seed}"])


def test_prediction_is_the_fits_own_uncertainty():
    """Every beam resolved (depths 1900-7600) and no rho weak: the calibration's u of each parameter on three
    scans is the prediction within 10 % (its s^2 and its Jacobian at the estimate, not the truth).
    """
    p = predict(DeviceDesign(BEAMS, (SIGMA_MM,) * 3, (20.0,) * 3), R_MM, SCAN)
    assert all(p.resolved) and p.in_range and p.beta_reference == "channel 1 fixed"
    for seed in (1, 2, 3):
        cal = _fit(seed)
        np.testing.assert_allclose(cal.u_rho_mm, p.u_rho_mm, rtol=0.1)
        np.testing.assert_allclose(cal.u_d_b_mm, p.u_d_b_mm, rtol=0.1)
        np.testing.assert_allclose(cal.u_beta_rad[1:], p.u_beta_rad[1:], rtol=0.1)


@pytest.mark.slow
def test_prediction_is_the_spread_of_fits_over_simulated_scans():
    """40 scans (seeds 100-139): the standard deviation of each parameter's error is the prediction within
    10 %, pooled over the 8 free parameters as the SD of err / u_pred (its own sampling SE ~4 %).
    """
    p = predict(DeviceDesign(BEAMS, (SIGMA_MM,) * 3, (20.0,) * 3), R_MM, SCAN)
    truth = np.stack([BEAMS.beta_rad, BEAMS.rho_mm, BEAMS.d_b_mm], axis=1).ravel()
    u = np.sqrt(np.diag(p.cov))
    free = u > 0
    z = np.array([(_fit(s).params - truth)[free] / u[free] for s in range(100, 140)])
    assert 0.9 <= float(np.sqrt(np.mean(z**2))) <= 1.1
    assert np.all(np.abs(np.sqrt(np.mean(z**2, axis=0)) - 1.0) < 0.35)  # each parameter: 40 draws, SE 11 %


def test_recommendation_is_the_smallest_scan_reaching_the_target():
    """Check that the scan recommended for Yang's ring resolves every rho and reaches u(beta) <= 1 mrad.

    Yang's ring and beams (sigma 2 um, 660 samples per revolution, 10 mm sensors): fewer revolutions than
    recommended, or the next smaller offset, do not reach it. (50 urad is out of reach: beta is
    psi - asin(rho / R), and u(rho) / R stays above 400 urad for offsets the 10 mm range allows; recommend
    says None.)
    """
    dev = DeviceDesign(scenes.YANG_BEAMS, (SIGMA_MM,) * 3, (10.0,) * 3)
    R = scenes.YANG_RING_GAUGE_DIAMETER_MM / 2
    base = ScanDesign(offset_mm=1.0, encoder=True, positions_known=True)
    offsets = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
    revs = [1, 2, 5, 10, 20, 30, 60]
    assert recommend(dev, R, base, 50e-6, offsets, revs) is None
    rec = recommend(dev, R, base, 1e-3, offsets, revs)
    assert rec is not None and all(rec.resolved) and max(rec.u_dbeta_rad) <= 1e-3
    from dataclasses import replace

    i_r, i_o = revs.index(rec.scan.revolutions), offsets.index(rec.scan.offset_mm)
    if i_o > 0:
        q = predict(dev, R, replace(rec.scan, offset_mm=offsets[i_o - 1]))
        assert not (all(q.resolved) and max(q.u_dbeta_rad) <= 1e-3 and q.in_range)
    if i_r > 0:
        for off in offsets:
            q = predict(dev, R, replace(rec.scan, revolutions=revs[i_r - 1], offset_mm=off))
            assert not (all(q.resolved) and max(q.u_dbeta_rad) <= 1e-3 and q.in_range)
    # the offset the mirror check states resolves the smallest rho at this scan's samples
    j = int(np.argmin(np.abs(dev.beams.rho_mm)))
    assert rec.offset_to_resolve_mm[j] == pytest.approx(
        R * (2 * 25 * SIGMA_MM**2 / (rec.scan.n_samples * dev.beams.rho_mm[j] ** 2)) ** 0.25, rel=1e-12
    )
    assert math.isfinite(rec.mirror_depth[j])


def test_plan_command_prints_the_prediction_and_the_recommendation(capsys):
    """``borescan plan --device yang``: the proposed scan's table (u(rho) of channel 1 the library's), a
    recommendation for a reachable target (exit 0), and for 50 urad the best reachable scan (exit 1).
    """
    from borescan.cli import main

    assert main(["plan", "--device", "yang", "--target-u-beta-urad", "1000"]) == 0
    out = capsys.readouterr().out
    dev = DeviceDesign(scenes.YANG_BEAMS, (SIGMA_MM,) * 3, (10.0,) * 3)
    p = predict(dev, scenes.YANG_RING_GAUGE_DIAMETER_MM / 2, ScanDesign(offset_mm=2.3, revolutions=60))
    assert f"{p.u_rho_mm[0] * 1e3:10.2f}" in out
    assert "recommended (u(beta_c - beta_1) <= 1000 urad, every rho resolved): offset 3 mm" in out
    assert main(["plan", "--device", "yang"]) == 1
    assert "best reachable of those" in capsys.readouterr().out
    assert main(["plan", "--scan", "/nonexistent/scan=X"]) == 2
    assert "scan" in capsys.readouterr().err


def test_large_bore_with_short_range_sensors_says_no_offset_resolves_the_sign(capsys):
    """R 500 mm, 5 mm sensors read at mid-range, rho 8 mm, sigma 4 um, 4000 samples: the offset that
    resolves the sign (Eq. (1) solved for e, about 3.7 mm) exceeds what the range allows (about 2.5 mm), so
    the plan says no offset does; the samples it names put the mirror exactly 25 in chi^2 above at the
    largest offset (mirror.predicted_depth, Eq. (1)), and that offset keeps every reading inside (0, 5 mm)
    while 1 % more does not.
    """
    from borescan.commands.plan import _print
    from borescan.plan import largest_offset_mm, samples_to_resolve
    from borescan.physics.tri import tri_spindle_jacobian
    from borescan.mirror import predicted_depth

    r_mm = 500.0
    beams = Beams((1, 2, 3), np.array([0.2, 2.3, 4.4]), np.array([8.0, -8.0, 8.0]), np.full(3, 0.0))
    # d_b so that each centred reading is 2.5 mm (mid-range): v = sqrt(R^2 - rho^2) - d_b at o = 0
    beams = Beams(beams.channels, beams.beta_rad, beams.rho_mm, np.sqrt(r_mm**2 - beams.rho_mm**2) - 2.5)
    dev = DeviceDesign(beams, (0.004,) * 3, (5.0,) * 3)
    e_max = largest_offset_mm(dev, r_mm)
    phi = np.linspace(0.0, 2 * math.pi, 720, endpoint=False)
    v_in, _ = tri_spindle_jacobian(phi, beams, np.array([e_max, 0.0]), r_mm)
    v_out, _ = tri_spindle_jacobian(phi, beams, np.array([1.01 * e_max, 0.0]), r_mm)
    assert v_in.min() > 0.0 and v_in.max() < 5.0
    assert v_out.min() <= 0.0 or v_out.max() >= 5.0
    assert e_max == pytest.approx(2.5, abs=0.1)  # the reading moves by about +-e around 2.5 mm
    p = predict(dev, r_mm, ScanDesign(offset_mm=2.0, revolutions=10, samples_per_rev=400))
    assert p.offset_limit_mm == e_max
    assert p.offset_to_resolve_mm[0] > e_max
    assert p.offset_can_resolve == (False, False, False)
    n_fix = samples_to_resolve(r_mm, 0.004, e_max, 8.0)
    assert predicted_depth([n_fix], [e_max], 8.0, [0.004], r_mm) == pytest.approx(25.0, rel=1e-12)
    _print(p, "proposed")
    out = capsys.readouterr().out
    assert out.count("no offset resolves the sign of rho") == 3
    assert f"take {math.ceil(n_fix)} samples per channel" in out
    # Yang's design: the 10 mm sensors allow the offset that resolves every beam at Yang's scan
    yang = DeviceDesign(scenes.YANG_BEAMS, (SIGMA_MM,) * 3, (10.0,) * 3)
    q = predict(yang, scenes.YANG_RING_GAUGE_DIAMETER_MM / 2, ScanDesign(offset_mm=2.3232, revolutions=24))
    assert q.offset_can_resolve == (True, True, True)
    assert max(q.offset_to_resolve_mm) < q.offset_limit_mm


def test_plan_of_a_contract_scan_matches_the_bound_at_its_truth(tmp_path):
    """The plan of a recorded contract scan agrees with the bound at its truth within 15 %.

    The plan from the scan's true design, offset, revolutions, speeds and angle source (a speed change as two
    equal halves) against the Cramer-Rao bound of the exact simulator at the truth on the readings really
    written (central differences of ``scenes.tri_readings``, bench/bench_calibration_contract.crb_cov): an
    independent computation of the same information. Where every reading stays in range the two agree within
    15 % for every compared quantity (the 200-scan battery: 95-97 % within 10 %, ``python -m
    bench.bench_plan_tri``); the gap left is the nulls, and a ramp that the plan leaves out.
    """
    from bench.bench_plan_tri import evaluate
    from borescan.synthetic import battery

    paths = battery.write_battery(tmp_path, 6, 20270611)
    checked = 0
    for p in paths:
        row = evaluate(p, tmp_path / "truth")
        if row["out_of_range"]:
            continue
        ratio = np.asarray(row["u_plan"]) / np.asarray(row["u_crb_truth"])
        assert np.all(np.abs(ratio - 1.0) < 0.15), (row["scan_id"], ratio)
        checked += 1
    assert checked >= 3
