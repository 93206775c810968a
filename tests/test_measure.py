"""Static and rotating diameters against simulated truth; honest uncertainties; verification."""

import numpy as np
import pytest

from borescan.geometry import Beams, Bore, tri_spindle_readings, tri_static_readings
from borescan.measure import (
    diameter_row,
    measure_scan,
    measure_rotating,
    static_diameter,
    static_diameter_jacobian,
    verification_row,
    verify,
)

BEAMS = Beams(
    channels=(1, 2, 3),
    beta_rad=np.array([0.3, 0.3 + 2.1, 0.3 + 4.2]),
    rho_mm=np.array([5.5484, -2.5295, 1.5262]),
    d_b_mm=np.array([132.6718, 132.8883, 134.1108]),
)
R = 275.029 / 2
BORE = Bore((262.833, -273.182), R)


def _static(n, seed=0):
    rng = np.random.default_rng(seed)
    xy = np.array(BORE.center_xy_mm) + rng.uniform(-2.5, 2.5, (n, 2))
    ang = rng.uniform(0, 2 * np.pi, n)
    return tri_static_readings(xy, ang, BEAMS, BORE)


def test_noise_free_static_diameter_exact():
    v = _static(50)
    assert np.all((v > 0) & (v < 10))  # inside a 10 mm sensor range, like Yang's HG-C1030
    res = static_diameter(v, BEAMS)
    assert np.max(np.abs(res.diameter_mm - 2 * R)) < 1e-9
    one = static_diameter(v[0], BEAMS)
    assert one.diameter_mm == pytest.approx(2 * R, abs=1e-9) and isinstance(one.diameter_mm, float)


def test_more_than_three_channels_uses_ls_circle():
    b5 = Beams(
        (1, 2, 3, 4, 5),
        np.linspace(0, 2 * np.pi, 5, endpoint=False) + 0.1,
        np.array([1.0, -2.0, 0.5, 3.0, -1.0]),
        np.full(5, 133.0),
    )
    v = tri_static_readings(np.array([[263.5, -272.0]]), np.array([0.7]), b5, BORE)
    res = static_diameter(v, b5, u_reading_mm=0.002)
    assert res.method == "least-squares circle"
    assert res.diameter_mm[0] == pytest.approx(2 * R, abs=1e-9)
    # a centred 5-beam device: u(D) = 2 u_v sqrt(1/5) to first order (closed form, rho << R)
    assert res.u_readings_mm[0] == pytest.approx(2 * 0.002 / np.sqrt(5), rel=0.02)


def test_jacobian_matches_finite_differences():
    v = _static(3, seed=1)
    D, jp, jv, _ = static_diameter_jacobian(v, BEAMS)
    h = 1e-6
    for i in range(9):
        ch, kind = divmod(i, 3)
        arrs = [BEAMS.beta_rad.copy(), BEAMS.rho_mm.copy(), BEAMS.d_b_mm.copy()]
        arrs[kind][ch] += h
        Dp = static_diameter_jacobian(v, Beams(BEAMS.channels, *arrs))[0]
        arrs[kind][ch] -= 2 * h
        Dm = static_diameter_jacobian(v, Beams(BEAMS.channels, *arrs))[0]
        assert np.allclose((Dp - Dm) / (2 * h), jp[:, i], rtol=1e-5, atol=1e-6)
    for ch in range(3):
        dv = np.zeros(3)
        dv[ch] = h
        num = (static_diameter_jacobian(v + dv, BEAMS)[0] - static_diameter_jacobian(v - dv, BEAMS)[0]) / (
            2 * h
        )
        assert np.allclose(num, jv[:, ch], rtol=1e-5, atol=1e-7)


def test_uncertainty_is_honest_monte_carlo():
    """True beams fixed; calibrated beams = truth + N(0, cov); readings + N(0, u_v^2).
    The z-scores (D - D_true) / u have unit standard deviation (2000 draws, +-8 %).
    """
    rng = np.random.default_rng(7)
    sd = np.tile([2e-4, 0.02, 0.01], 3)  # beta [rad], rho [mm], d_b [mm]
    C = np.diag(sd**2)
    C[2, 5] = C[5, 2] = 0.5 * sd[2] * sd[5]  # some correlation between d_b1 and d_b2
    u_v = 0.003
    L = np.linalg.cholesky(C)
    v_true = _static(1, seed=3)[0]
    z = []
    for _ in range(2000):
        p = L @ rng.standard_normal(9)
        est = Beams(BEAMS.channels, BEAMS.beta_rad + p[0::3], BEAMS.rho_mm + p[1::3], BEAMS.d_b_mm + p[2::3])
        res = static_diameter(v_true + u_v * rng.standard_normal(3), est, C, u_v)
        z.append((res.diameter_mm - 2 * R) / res.u_diameter_mm)
    z = np.array(z)
    assert abs(np.mean(z)) < 0.1
    assert np.std(z) == pytest.approx(1.0, abs=0.08)


def test_nan_rows_and_bad_shapes():
    v = _static(2)
    v[1, 0] = np.nan
    res = static_diameter(v, BEAMS, u_reading_mm=0.001)
    assert np.isfinite(res.diameter_mm[0]) and np.isnan(res.diameter_mm[1])
    with pytest.raises(ValueError, match="cov_beams"):
        static_diameter(v[0], BEAMS, np.eye(3))


def test_rotating_scan_diameter_roundness_and_lobes():
    """Spindle scan of a 3-lobed bore (a = 4 um): LS diameter = 2R, MZ RONt = 2a, UPR 3 = a."""
    a = 0.004
    bore = Bore((262.833, -273.182), R, lobes=((3, a, 0.0),))
    phi = np.linspace(0, 2 * np.pi, 3000, endpoint=False)
    S = np.array([262.955, -275.502])
    v = tri_spindle_readings(phi, S, BEAMS, bore)
    res = measure_rotating(v, phi, S, BEAMS)
    assert res.diameter_mm == pytest.approx(2 * R, abs=2e-6)
    assert res.ront_mm["MZCI"] == pytest.approx(2 * a, abs=2e-6)
    assert res.amplitude_mm[3] == pytest.approx(a, abs=2e-7)
    # UPR 2, 4, 5, ... vanish; UPR 1 (eccentricity of the chosen centre) is small but not zero
    # because the eccentric spindle samples the wall with a non-uniform angular density.
    assert np.max(np.delete(res.amplitude_mm[2:], 1)) < 2e-7 and res.amplitude_mm[1] < 1e-6
    assert res.ront_mm["MZCI"] <= min(res.ront_mm.values()) + 1e-12


def test_verify_temperature_correction_sign():
    """A warm gauge is larger: a device that reads the expanded size exactly has zero error."""
    D20, cte, T = 275.029, 11.5e-6, 23.0
    expanded = D20 * (1 + cte * (T - 20))  # +9.5 um
    v = verify(expanded, 0.002, D20, 0.00075, cte, T, 0.015)
    assert v.expected_at_t_mm == pytest.approx(D20 + 0.0094885, abs=1e-7)
    assert v.error_mm == pytest.approx(0.0, abs=1e-12) and v.passed
    cold = verify(D20, 0.002, D20, 0.00075, cte, T, 0.005)  # reading the 20 degC size at 23 degC
    # the error is that of the reading brought to 20 degC: D20 / (1 + cte dT) - D20 = -9.4882 um
    assert (
        cold.error_mm == pytest.approx(-D20 * cte * (T - 20) / (1 + cte * (T - 20)), abs=1e-12)
        and not cold.passed
    )
    assert cold.measured_mm - cold.certified_mm == pytest.approx(cold.error_mm, abs=1e-12)
    assert cold.measured_at_t_mm == D20 and cold.expected_at_t_mm == pytest.approx(expanded, rel=1e-15)
    assert cold.u_error_mm == pytest.approx(np.hypot(0.002, 0.00075), rel=1e-4)
    row = verification_row("S1", "TRI-01", "RG-275", cold)
    assert {
        "scan_id",
        "device_id",
        "artifact_id",
        "measured_mm",
        "certified_mm",
        "error_mm",
        "tolerance_mm",
        "passed",
    } <= row.keys()
    d = diameter_row("S1", "TRI-01", "RG-275", None, 275.03, 0.004, "CAL1", "static circumcircle")
    assert list(d)[:8] == [
        "scan_id",
        "device_id",
        "artifact_id",
        "feature",
        "diameter_mm",
        "u_diameter_mm",
        "calibration_id",
        "method",
    ]


def test_measure_scan_on_simulated_raw_scans(tmp_path):
    """Through borescan-raw/1: a simulated static scan (10 poses) and a spindle scan."""
    from borescan.rawio import read_scan
    from borescan.synthetic.scenes import TriScene
    from borescan.synthetic.simulate import simulate_tri_spindle, simulate_tri_static, write_simulated

    scene = TriScene(beams=BEAMS, bore_center_xy_mm=(262.833, -273.182), bore_radius_20_mm=R)
    sim = simulate_tri_static(scene, scan_id="T-STATIC", noise_mm=0.0)
    scan = read_scan(write_simulated(sim, tmp_path / "raw", tmp_path / "truth"))
    res = measure_scan(scan, BEAMS)
    assert len(res["poses"]) == 10
    assert res["diameter_mm"] == pytest.approx(2 * R, abs=1e-9)
    assert all(q["diameter_mm"] == pytest.approx(2 * R, abs=1e-9) for q in res["poses"])
    sim = simulate_tri_spindle(scene, scan_id="T-SPIN", n_rev=2.0, noise_mm=0.0)
    scan = read_scan(write_simulated(sim, tmp_path / "raw", tmp_path / "truth"))
    res = measure_scan(scan, BEAMS)
    assert res["diameter_mm"] == pytest.approx(2 * R, abs=1e-6)
    assert res["ront_mm"]["MZCI"] < 1e-6


# ------------------------------------------------------------ readings per pose (rod)


def test_pose_means_and_counts():
    from borescan.measure import pose_means

    v = np.array([[1.0, 10.0], [3.0, np.nan], [5.0, 20.0], [7.0, 40.0], [100.0, 100.0]])
    pose = np.array([0, 0, 1, 1, -1])  # -1: between poses, left out
    poses, means, counts = pose_means(v, pose)
    np.testing.assert_array_equal(poses, [0, 1])
    np.testing.assert_array_equal(means, [[2.0, 10.0], [6.0, 30.0]])
    np.testing.assert_array_equal(counts, [[2, 1], [2, 2]])


def test_reading_u_from_linearity_and_repeatability():
    from borescan.measure import mean_reading_u_mm, reading_u_mm

    sensors = {
        1: {"linearity_fs": 0.0003, "range_mm": 10.0, "repeatability_mm": 0.004},  # a = 3 um rectangular
        2: {"repeatability_mm": 0.002},
    }
    u = reading_u_mm(sensors, (1, 2, 3))
    np.testing.assert_allclose(u, [np.hypot(0.003 / np.sqrt(3), 0.004), 0.002, 0.0], rtol=1e-15)
    counts = np.array([[100, 4, 9], [25, 16, 9]])
    # largest u / sqrt(fewest readings per channel): channel 1: u1 / 5, channel 2: 0.002 / 2
    assert mean_reading_u_mm(u, counts) == pytest.approx(max(u[0] / 5.0, 0.001), rel=1e-15)
    assert mean_reading_u_mm(np.zeros(3), counts) is None
    assert mean_reading_u_mm([0.002], np.array([[0]])) == pytest.approx(0.002)  # no reading: counted as one


# ------------------------------------------------------------ GUM budget, temperature, decision rule


def _centred():
    """Three beams 120 deg apart through the axis (rho = 0), d_b = 130 mm, in a centred 270 mm bore:
    every reading is 5 mm and dD/dv_c = dD/dd_b,c = 2/3 exactly (the circumcircle of three
    symmetric points moves by a third of one point's radial shift).
    """
    beams = Beams((1, 2, 3), np.array([0.0, 2 * np.pi / 3, 4 * np.pi / 3]), np.zeros(3), np.full(3, 130.0))
    return beams, np.full(3, 5.0)


def test_diameter_budget_against_a_hand_computed_gum_budget():
    """u_c(D_T)^2 = 3 (2/3)^2 u_db^2 + u_rd^2 + 3 (2/3)^2 a^2 / 3 ; D20 = D_T / f, f = 1 + alpha (T - 20):
    u_c(D20)^2 = u_c(D_T)^2 / f^2 + (D alpha / f^2)^2 u_T^2 + (D (T - 20) / f^2)^2 u_alpha^2, and
    Welch-Satterthwaite with the calibration's Type A (nu 12) and the readings (nu 9), by hand.
    """
    from borescan.artifacts import ArtifactCte, ScanTemperature
    from borescan.measure import diameter_uncertainty
    from borescan.uncertainty import Budget, Input, Term, coverage_factor

    beams, v = _centred()
    D, jp, jv, _ = static_diameter_jacobian(v[None, :], beams)
    assert D[0] == pytest.approx(270.0, abs=1e-9)
    np.testing.assert_allclose(jv[0], [2 / 3] * 3, atol=1e-12)
    np.testing.assert_allclose(jp[0][2::3], [2 / 3] * 3, atol=1e-12)
    u_db, u_rd, a, T, aT, cte, acte = 0.002, 0.001, 0.005, 22.0, 0.2, 11.5e-6, 1e-6
    cov = np.zeros((9, 9))
    cov[2::3, 2::3] = np.eye(3) * u_db**2
    cal = Budget(
        tuple(f"p{i}" for i in range(9)),
        ("-",) * 9,
        np.zeros(9),
        [Term(Input("fit", "fit", "p", "mm", None, 0.004, "normal", 12, "A"), cov=cov)],
    )
    sensors = {ch: {"linearity_fs": a / 10.0, "range_mm": 10.0, "resolution_mm": 0.0001} for ch in (1, 2, 3)}
    temp = ScanTemperature(T, aT, aT / np.sqrt(3), False, "hand")
    ct = ArtifactCte(cte, acte, acte / np.sqrt(3), False, "hand")
    du = diameter_uncertainty(
        270.0,
        jac_params=jp[0],
        calibration_budget=cal,
        jac_readings=jv[0],
        u_readings_mm=u_rd,
        dof_readings=9,
        sensors=sensors,
        channels=(1, 2, 3),
        noise_mm=np.full(3, 0.003),
        temperature=temp,
        cte=ct,
        artifact={"id": "P1"},
        scan_id="S",
        p=0.9545,
        default_resolution_mm=0.001,
    )
    f = 1 + cte * (T - 20)
    u_cal2, u_lin2 = 3 * (2 / 3) ** 2 * u_db**2, 3 * (2 / 3) ** 2 * a**2 / 3
    uT2 = u_cal2 + u_rd**2 + u_lin2
    u20_2 = uT2 / f**2 + (270 * cte / f**2) ** 2 * aT**2 / 3 + (270 * (T - 20) / f**2) ** 2 * acte**2 / 3
    assert du.combined_t.u == pytest.approx(np.sqrt(uT2), rel=1e-12)
    assert du.combined_20.u == pytest.approx(np.sqrt(u20_2), rel=1e-12)
    assert du.diameter_20_mm == pytest.approx(270.0 / f, rel=1e-15)
    assert du.thermal_correction_mm == pytest.approx(270.0 / f - 270.0, rel=1e-12)
    assert du.u_thermal_correction_mm == pytest.approx(
        np.sqrt(
            (270 * cte / f**2) ** 2 * aT**2 / 3
            + (270 * (T - 20) / f**2) ** 2 * acte**2 / 3
            + (1 / f - 1) ** 2 * uT2
        ),
        rel=1e-9,
    )
    nu = u20_2**2 / ((u_cal2 / f**2) ** 2 / 12 + (u_rd**2 / f**2) ** 2 / 9)
    assert du.combined_20.nu_eff == pytest.approx(nu, rel=1e-9)
    if du.combined_20.method == "GUF":
        assert du.combined_20.k == pytest.approx(coverage_factor(0.9545, nu), rel=1e-12)
    rows = {r["key"]: r for r in du.rows_20}
    assert rows["resolution:S:ch1"]["contribution"] == 0.0 and "dithered" in rows["resolution:S:ch1"]["note"]
    assert rows["linearity:S:ch2"]["sensitivity_coefficient"] == pytest.approx(2 / 3 / f, rel=1e-12)
    assert rows["temperature:S"]["sensitivity_coefficient"] == pytest.approx(-270 * cte / f**2, rel=1e-12)
    cols = du.columns()
    assert cols["diameter_20_mm"] == du.diameter_20_mm and cols["temperature_assumed"] is False
    assert cols["expanded_u_diameter_20_mm"] == pytest.approx(cols["k"] * cols["u_diameter_20_mm"], rel=1e-12)


def test_decision_rules():
    from borescan.measure import decide

    ok, A, text = decide(0.010, 0.008, 0.015, "simple_acceptance")
    assert ok and A == 0.015 and text.startswith("CONFORMS")
    ok, A, text = decide(
        0.010, 0.008, 0.015, "guard_band", 1.0
    )  # A = 15 - 8 um < 10 <= 15: in the guard band
    assert not ok and A == pytest.approx(0.007) and text.startswith("CANNOT DECIDE") and "w = 8.0 um" in text
    ok, A, text = decide(0.0, 0.020, 0.015, "guard_band")  # U > T: nothing can be shown to conform
    assert not ok and text.startswith("CANNOT DECIDE") and "not smaller than the tolerance" in text
    with pytest.raises(ValueError, match="unknown decision rule"):
        decide(0.0, 0.001, 0.015, "shared_risk")
    v = verify(275.040, 0.002, 275.029, 0.00075, 0.0, 20.0, 0.015, decision_rule="guard_band", k=2.0)
    assert v.acceptance_limit_mm == pytest.approx(0.015 - 2 * np.hypot(0.002, 0.00075)) and not v.passed


def _tri_cal(beams, cov=None):
    from borescan.calibrate.result import TriCalibration

    return TriCalibration(
        "CAL-T", "TRI-01", beams, np.zeros((9, 9)) if cov is None else cov, "full_lsq", ("C",)
    )


def _static_scan(tmp_path, temperature_c=20.6, scan_id="T-STATIC", noise_mm=0.002):
    from borescan.effects import Effect
    from borescan.rawio import read_scan
    from borescan.synthetic.scenes import TriScene
    from borescan.synthetic.simulate import simulate_tri_static, write_simulated

    scene = TriScene(beams=BEAMS, bore_center_xy_mm=(262.833, -273.182), bore_radius_20_mm=R)
    sim = simulate_tri_static(
        scene,
        scan_id=scan_id,
        noise_mm=noise_mm,
        seed=4,
        effects=[Effect("thermal_expansion", {"temperature_c": temperature_c})],
    )
    if temperature_c is None or scan_id.endswith("NOTEMP"):
        sim.meta.pop("environment")
    return read_scan(write_simulated(sim, tmp_path / "raw", tmp_path / "truth")), sim


def test_temperature_explicit_at_t_and_at_20(tmp_path):
    """A 20.6 degC static verification: D at T is the expanded gauge, D20 the certified one; the
    verification row adds up (measured_mm at 20 degC - certified = error).
    """
    from borescan.config import schema_defaults
    from borescan.measure import tri_diameter_with_budget, verification_row, verify_budget

    unc = schema_defaults()["uncertainty"]
    scan, sim = _static_scan(tmp_path, 20.6, noise_mm=0.0)
    res, du = tri_diameter_with_budget(scan, _tri_cal(BEAMS), unc)
    cte = scan.meta["artifact"]["cte_per_k"]
    assert du.diameter_mm == pytest.approx(2 * R * (1 + cte * 0.6), abs=2e-6)
    assert du.diameter_20_mm == pytest.approx(2 * R, abs=2e-6)
    assert du.temperature.temperature_c == 20.6 and not du.temperature.assumed
    assert du.thermal_correction_mm == pytest.approx(-2 * R * cte * 0.6, rel=1e-3)  # -1.9 um
    v = verify_budget(du, scan.meta["artifact"], 0.015, 0.9545)
    row = verification_row("S", "TRI-01", "RG-275", v)
    assert row["measured_mm"] - row["certified_mm"] == pytest.approx(row["error_mm"], abs=1e-12)
    assert row["measured_at_t_mm"] == du.diameter_mm and row["temperature_c"] == 20.6
    assert abs(row["error_mm"]) < 2e-6 and row["passed"]
    # the same gauge as the calibration's: its certified diameter enters twice and cancels (here the
    # calibration has no budget, so it enters once, with sensitivity -1: u(E) includes U / k = 0.75 um)
    assert {r["key"]: r for r in v.budget_rows}["gauge:RG-275@RG-275/2026-03:D20"][
        "contribution"
    ] == pytest.approx(0.00075)


def test_missing_temperature_is_refused_or_flagged(tmp_path):
    from borescan.artifacts import MissingTemperature
    from borescan.config import schema_defaults
    from borescan.measure import tri_diameter_with_budget

    scan, _ = _static_scan(tmp_path, 20.0, scan_id="T-NOTEMP")
    assert "environment" not in scan.meta
    refuse = dict(schema_defaults()["uncertainty"], missing_temperature="refuse")
    with pytest.raises(MissingTemperature, match="T-NOTEMP: scan.json has no environment.temperature_c"):
        tri_diameter_with_budget(scan, _tri_cal(BEAMS), refuse)
    assume = dict(refuse, missing_temperature="assume_20c", assumed_temperature_accuracy_c=2.0)
    _, du = tri_diameter_with_budget(scan, _tri_cal(BEAMS), assume)
    assert du.temperature.assumed and du.temperature.temperature_c == 20.0
    assert du.temperature.u_c == pytest.approx(2.0 / np.sqrt(3)) and "ASSUMED" in du.temperature.source
    cols = du.columns()
    assert cols["temperature_assumed"] is True
    # the assumed temperature's +-2 K is in the budget of D20 (sensitivity -D alpha), not of D_T
    rows = {r["key"]: r for r in du.rows_20}
    t_row = rows["temperature:T-NOTEMP"]
    assert t_row["contribution"] == pytest.approx(2 * R * 11.5e-6 * 2.0 / np.sqrt(3), rel=1e-6)
    assert du.combined_20.u > du.combined_t.u


def test_missing_temperature_refused_in_calibration_inputs(tmp_path):
    from borescan.artifacts import MissingTemperature
    from borescan.config import schema_defaults
    from borescan.rawio import read_scan
    from borescan.synthetic.scenes import TriScene
    from borescan.synthetic.simulate import simulate_tri_spindle, write_simulated
    from borescan.stages.calibration_fit import spindle_inputs

    scene = TriScene(beams=BEAMS, bore_center_xy_mm=(262.833, -273.182), bore_radius_20_mm=R)
    sim = simulate_tri_spindle(scene, scan_id="C-NOTEMP", n_rev=2.0, noise_mm=0.002)
    sim.meta.pop("environment")
    scan = read_scan(write_simulated(sim, tmp_path / "raw", tmp_path / "truth"))
    unc = schema_defaults()["uncertainty"]
    with pytest.raises(MissingTemperature, match="C-NOTEMP"):
        spindle_inputs(scan, dict(unc, missing_temperature="refuse"))
    x = spindle_inputs(scan, dict(unc, missing_temperature="assume_20c"))
    assert x.temperature.assumed and x.radius_mm == pytest.approx(R, rel=1e-15)


def test_sensitivity_to_every_base_length_sums_to_two(tmp_path):
    """Moving every d_b (or every reading) by delta moves every wall point outwards by delta cos(asin(rho/r)):
    D grows by about 2 delta, in the static and the rotating evaluation alike.
    """
    from borescan.rawio import read_scan
    from borescan.synthetic.scenes import TriScene
    from borescan.synthetic.simulate import simulate_tri_spindle, write_simulated

    scan, _ = _static_scan(tmp_path, 20.0)
    res = measure_scan(scan, BEAMS)
    assert np.sum(res["jac_readings"]) == pytest.approx(2.0, abs=2e-3)
    assert np.sum(res["jac_params"][2::3]) == pytest.approx(2.0, abs=2e-3)
    scene = TriScene(beams=BEAMS, bore_center_xy_mm=(262.833, -273.182), bore_radius_20_mm=R)
    rot = read_scan(
        write_simulated(
            simulate_tri_spindle(scene, scan_id="T-ROT", n_rev=2.0, noise_mm=0.0),
            tmp_path / "raw",
            tmp_path / "truth",
        )
    )
    res = measure_scan(rot, BEAMS)
    assert np.sum(res["jac_readings"]) == pytest.approx(2.0, abs=2e-3)
    np.testing.assert_allclose(res["jac_params"][2::3], res["jac_readings"], rtol=1e-4)


def test_second_order_term_of_the_calibration_hardly_moves_a_diameter_of_the_gauges_size():
    """The fit adds 3 u(rho)^4 / (4 R^2) to var(d_b) (d_b = g - rho^2 / (2R) is quadratic in rho).
    A diameter of about the gauge's size moves along the fit's path (psi, g fixed) by q delta^2 only,
    with q from D's own curvature. Monte Carlo over delta ~ N(0, u^2) (u = 1 mm, one channel):
    the rms of D's second-order part (D - its linear part) is sqrt(3) |q| u^2 as the budget says
    (within 10 %), and a hundred times smaller than the d_b term mapped linearly (7 um).
    """
    from borescan.measure import DiameterModel
    from borescan.measure.budget import _second_order_variance
    from borescan.measure.rotating import _with_params

    beams = Beams(
        (1, 2, 3),
        np.array([0.35, 2.46, 4.56]),
        np.array([-5.5, -2.5, 1.5]),
        np.array([132.67, 132.89, 134.11]),
    )
    Rg, u = 275.029 / 2, 1.0
    for Rp in (Rg, Rg + 2.0):
        v = tri_static_readings(
            np.array([[0.3, -0.2], [-0.5, 0.4]]), np.array([0.1, 2.0]), beams, Bore((0, 0), Rp)
        )
        model = DiameterModel("static", v)
        cov = np.zeros((9, 9))
        cov[2, 2] = 3 * u**4 / (4 * Rg**2)  # channel 1 only
        var = _second_order_variance(model, beams, cov, Rg)
        _, jp, _, _ = static_diameter_jacobian(v, beams)
        j = jp.mean(axis=0)
        rng = np.random.default_rng(2)
        d0, rho = model(beams), beams.rho_mm[0]
        second = []
        for delta in rng.normal(0.0, u, 4000):
            dl = np.zeros(9)
            dl[0] = -(np.arcsin((rho + delta) / Rg) - np.arcsin(rho / Rg))
            dl[1] = delta
            dl[2] = -(2 * rho * delta + delta**2) / (2 * Rg)
            lin = j[0] * (-delta / np.sqrt(Rg**2 - rho**2)) + j[1] * delta + j[2] * (-rho * delta / Rg)
            second.append(model(_with_params(beams, dl)) - d0 - lin)
        second = np.array(second)
        assert np.sqrt(np.mean(second**2)) == pytest.approx(np.sqrt(var), rel=0.1)
        assert np.sqrt(var) < 0.02 * abs(j[2]) * np.sqrt(cov[2, 2])


def test_part_feature_picks_the_named_feature_else_the_only_one_else_the_artifact():
    from borescan.measure import part_feature

    art = {
        "id": "HSG",
        "nominal_diameter_mm": 300.0,
        "tolerance_mm": 0.05,
        "features": [
            {"id": "H1", "nominal_diameter_mm": 150.0, "tolerance_mm": 0.01},
            {"id": "H2", "nominal_diameter_mm": 180.0},
        ],
    }
    assert part_feature(art, "H1") == {"nominal_diameter_mm": 150.0, "tolerance_mm": 0.01}
    # H2 has no tolerance of its own: the artifact's applies
    assert part_feature(art, "H2") == {"nominal_diameter_mm": 180.0, "tolerance_mm": 0.05}
    # no feature named and two features: the artifact's own nominal
    assert part_feature(art, None) == {"nominal_diameter_mm": 300.0, "tolerance_mm": 0.05}
    one = {"features": [{"id": "B", "nominal_diameter_mm": 250.0}]}
    assert part_feature(one, None) == {"nominal_diameter_mm": 250.0, "tolerance_mm": None}
    assert part_feature(one, "X") == {"nominal_diameter_mm": None, "tolerance_mm": None}
    assert part_feature({}, None) == {"nominal_diameter_mm": None, "tolerance_mm": None}


def test_a_three_sensor_diameter_of_a_one_bore_part_keeps_its_feature():
    """The diameter of a three-sensor part scan belongs to the part's only feature (its id ``scan/B1``,
    ``trace`` names it), none for a ring gauge or a part of several features the scan does not name.
    """
    from borescan.measure import only_feature_id, part_feature

    one = {"id": "HSG-1101", "features": [{"id": "B1", "nominal_diameter_mm": 276.4, "tolerance_mm": 0.01}]}
    assert only_feature_id(one) == "B1"
    assert part_feature(one, only_feature_id(one)) == part_feature(one, None)  # the same verdict as before
    assert only_feature_id({"id": "RG-275", "type": "ring_gauge"}) is None
    assert only_feature_id({"features": [{"id": "H1"}, {"id": "H2"}]}) is None


@pytest.mark.parametrize(
    "dev_um, U_um, tol_um, rule, verdict",
    [
        (+9.0, 4.0, 10.0, "simple_acceptance", "conforms"),  # |9| <= 10
        (-11.0, 4.0, 10.0, "simple_acceptance", "does not conform"),  # |-11| > 10
        (+9.0, 4.0, 10.0, "guarded_acceptance", "cannot decide"),  # 10 - 4 = 6 < 9 <= 10
        (-5.5, 4.0, 10.0, "guarded_acceptance", "conforms"),  # 5.5 <= 6
        (+9.0, 12.0, 10.0, "simple_acceptance", "cannot decide"),  # U = 12 >= T = 10
    ],
)
def test_part_conformity_applies_the_decision_rule_to_the_deviation_at_20c(
    dev_um, U_um, tol_um, rule, verdict
):
    from borescan.measure import part_conformity

    r = part_conformity(150.0 + dev_um * 1e-3, U_um * 1e-3, 150.0, tol_um * 1e-3, rule, 1.0)
    assert r["deviation_mm"] == pytest.approx(dev_um * 1e-3, abs=1e-12)
    assert (
        r["conformity"].split(" (")[0] == verdict and f"U {U_um:.1f} um, T {tol_um:.1f} um" in r["conformity"]
    )
    assert part_conformity(150.0, 0.004, None, 0.01)["conformity"] is None  # no nominal: no verdict
    assert part_conformity(150.0, 0.004, 150.0, None)["deviation_mm"] == 0.0  # no tolerance: deviation only
    assert part_conformity(150.0, 0.004, 150.0, None)["conformity"] is None


def test_rotating_sensitivities_equal_central_differences_of_the_circle_fit(tmp_path):
    """The rotating diameter's sensitivities (one circle fit and the points' derivatives) against central
    differences of the whole diameter model (a circle fit per step): to 1e-6 relative, or 1e-7 absolute (the
    differences divide the fit's last digits, about 1e-12 mm, by steps of 1e-5).
    """
    from borescan import rawio
    from borescan.measure import measure_scan
    from borescan.measure.rotating import _with_params
    from borescan.synthetic import scenes, simulate

    scene = scenes.default_tri_scene()
    sim = simulate.simulate_tri_spindle(
        scene,
        n_rev=3,
        scan_id="SENS",
        kind="measurement",
        seed=4,
        artifact={"id": "B", "type": "part", "nominal_diameter_mm": 275.0},
    )
    scan = rawio.read_scan(simulate.write_simulated(sim, tmp_path / "raw", tmp_path / "truth"))
    beams = scene.beams
    res = measure_scan(scan, beams)
    model, jp, jv = res["model"], res["jac_params"], res["jac_readings"]
    assert model.kind == "rotating"
    c = len(beams.channels)
    for i in range(3 * c):
        e = np.zeros(3 * c)
        e[i] = 1e-6 if i % 3 == 0 else 1e-5
        fd = (model(_with_params(beams, e)) - model(_with_params(beams, -e))) / (2 * e[i])
        assert jp[i] == pytest.approx(fd, rel=1e-6, abs=1e-7)
    for j in range(c):
        e = np.zeros(c)
        e[j] = 1e-5
        assert jv[j] == pytest.approx((model(beams, e) - model(beams, -e)) / 2e-5, rel=1e-6, abs=1e-7)


def _contract_rotating_model(seed, n=6600):
    """Return a rotating scan drawn over the contract: bore radius 75-200 mm (lobed, 1 um noise), spindle
    0.5-3 mm
    off the bore's centre, any beam directions, rho up to +-30 mm, the angle per channel (n, c) as with
    channel delays on even seeds, 1 % of the readings null.
    """
    from borescan.measure import DiameterModel

    rng = np.random.default_rng(seed)
    R = rng.uniform(75.0, 200.0)
    rho = rng.uniform(-30.0, 30.0, 3)
    beta = rng.uniform(0.0, 2 * np.pi, 3)
    beams = Beams((1, 2, 3), beta, rho, np.sqrt(R**2 - rho**2) - rng.uniform(2.0, 8.0, 3))
    C = rng.uniform(-300.0, 300.0, 2)
    off, az = rng.uniform(0.5, 3.0), rng.uniform(0.0, 2 * np.pi)
    phi = 2 * np.pi * np.arange(n) / 660.0 + rng.uniform(0.0, 2 * np.pi)
    if seed % 2 == 0:
        phi = phi[:, None] - 2 * np.pi * rng.uniform(-2e-3, 2e-3, 3)[None, :]
    S = C + off * np.array([np.cos(az), np.sin(az)]) + rng.normal(0.0, 2e-3, (n, 2))
    bore = Bore(tuple(C), R, lobes=((3, 2e-3, 0.4), (5, 1e-3, 1.0)))
    v = tri_spindle_readings(phi, S, beams, bore) + rng.normal(0.0, 1e-3, (n, 3))
    v[rng.uniform(size=v.shape) < 0.01] = np.nan
    return DiameterModel("rotating", v, phi, S), beams, R


@pytest.mark.parametrize("seed", range(6))
def test_rotating_sensitivities_against_refits_over_the_contract(seed):
    """The analytic sensitivities (exact points' derivatives through the linearised circle) against central
    differences of D through full circle refits (h = 1e-4 rad, 1e-3 mm), on scans drawn over the contract.
    Tolerance 1e-6 relative plus 1e-8 of the family's scale (R mm/rad for beta, 1 for rho, d_b and the
    readings): the linearised circle response neglects the residuals' curvature (residuals over R), which
    leaves about 1e-9 of that scale (at most 1.1e-9 measured on twelve such scans).
    """
    from borescan.measure.rotating import _rotating_sensitivities, _with_params

    model, beams, R = _contract_rotating_model(seed)
    jp, jv = _rotating_sensitivities(model, beams)
    for i in range(9):
        e = np.zeros(9)
        e[i] = 1e-4 if i % 3 == 0 else 1e-3
        fd = (model(_with_params(beams, e)) - model(_with_params(beams, -e))) / (2 * e[i])
        assert jp[i] == pytest.approx(fd, rel=1e-6, abs=1e-8 * (R if i % 3 == 0 else 1.0))
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1e-3
        assert jv[j] == pytest.approx((model(beams, e) - model(beams, -e)) / 2e-3, rel=1e-6, abs=1e-8)
    np.testing.assert_array_equal(jv, jp[2::3])  # a reading's constant error moves the point as d_b does


@pytest.mark.parametrize("seed", range(6))
def test_second_order_variance_of_a_rotating_scan_equals_fresh_circle_fits(seed, monkeypatch):
    """The rotating second-order term takes D at rho +- u(rho) along the fit's path from Gauss-Newton steps
    from the scan's own circle, moving only that channel's points. On scans drawn over the contract, with
    gauges of the bore's size (odd seeds: D hardly moves) or of any size in 75-200 mm and u(rho) 0.03-1 mm,
    it equals the central second difference of fresh fits (Kasa start, :class:`DiameterModel`) to 1e-6
    relative, without falling back on them. Measured: at most 4e-8 on sixteen such scans, 2e-7 on the
    reference night's scans where the term is a million times smaller (the fresh fits' own last digits
    over q u^2).
    """
    from borescan.measure import DiameterModel
    from borescan.measure.budget import _second_order_variance
    from borescan.measure.rotating import _with_params

    model, beams, R = _contract_rotating_model(seed)
    rng = np.random.default_rng(100 + seed)
    Rg = R * (1 + rng.uniform(-0.02, 0.02)) if seed % 2 else rng.uniform(75.0, 200.0)
    u = rng.uniform(0.03, 1.0, 3)
    cov = np.zeros((9, 9))
    cov[[2, 5, 8], [2, 5, 8]] = 3 * u**4 / (4 * Rg**2)
    d0, cold = model(beams), 0.0
    for j in range(3):
        rho, vals = beams.rho_mm[j], []
        for h in (u[j], -u[j]):
            dl = np.zeros(9)
            dl[3 * j] = -(np.arcsin((rho + h) / Rg) - np.arcsin(rho / Rg))
            dl[3 * j + 1] = h
            dl[3 * j + 2] = -(2 * rho * h + h * h) / (2 * Rg)
            vals.append(model(_with_params(beams, dl)))
        q = (vals[0] - 2 * d0 + vals[1]) / (2 * u[j] ** 2)
        cold += 3 * q * q * u[j] ** 4

    def no_fresh_fit(self, beams, offsets_mm=None):
        raise AssertionError("fell back on a fresh fit")

    monkeypatch.setattr(DiameterModel, "__call__", no_fresh_fit)
    assert _second_order_variance(model, beams, cov, Rg) == pytest.approx(cold, rel=1e-6)
