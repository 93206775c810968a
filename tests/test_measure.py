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
    b5 = Beams((1, 2, 3, 4, 5), np.linspace(0, 2 * np.pi, 5, endpoint=False) + 0.1,
               np.array([1.0, -2.0, 0.5, 3.0, -1.0]), np.full(5, 133.0))
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
        num = (static_diameter_jacobian(v + dv, BEAMS)[0] - static_diameter_jacobian(v - dv, BEAMS)[0]) / (2 * h)
        assert np.allclose(num, jv[:, ch], rtol=1e-5, atol=1e-7)


def test_uncertainty_is_honest_monte_carlo():
    """True beams fixed; calibrated beams = truth + N(0, cov); readings + N(0, u_v^2).
    The z-scores (D - D_true) / u have unit standard deviation (2000 draws, +-8 %)."""
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
    assert cold.error_mm == pytest.approx(-0.0094885, abs=1e-7) and not cold.passed
    assert cold.u_error_mm == pytest.approx(np.hypot(0.002, 0.00075), rel=1e-4)
    row = verification_row("S1", "TRI-01", "RG-275", cold)
    assert {"scan_id", "device_id", "artifact_id", "measured_mm", "certified_mm", "error_mm",
            "tolerance_mm", "passed"} <= row.keys()
    d = diameter_row("S1", "TRI-01", "RG-275", None, 275.03, 0.004, "CAL1", "static circumcircle")
    assert list(d)[:8] == ["scan_id", "device_id", "artifact_id", "feature", "diameter_mm",
                           "u_diameter_mm", "calibration_id", "method"]


def test_measure_scan_on_simulated_raw_scans(tmp_path):
    """Through borescan-raw/1: a simulated static scan (10 poses) and a spindle scan."""
    from borescan.rawio import read_scan
    from borescan.simulate import TriScene, simulate_tri_spindle, simulate_tri_static, write_simulated

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


# --------------------------------------------------------------------------- readings per pose (rod)


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

    sensors = {1: {"linearity_fs": 0.0003, "range_mm": 10.0, "repeatability_mm": 0.004},  # a = 3 um rectangular
               2: {"repeatability_mm": 0.002}}
    u = reading_u_mm(sensors, (1, 2, 3))
    np.testing.assert_allclose(u, [np.hypot(0.003 / np.sqrt(3), 0.004), 0.002, 0.0], rtol=1e-15)
    counts = np.array([[100, 4, 9], [25, 16, 9]])
    # largest u / sqrt(fewest readings per channel): channel 1: u1 / 5, channel 2: 0.002 / 2
    assert mean_reading_u_mm(u, counts) == pytest.approx(max(u[0] / 5.0, 0.001), rel=1e-15)
    assert mean_reading_u_mm(np.zeros(3), counts) is None
    assert mean_reading_u_mm([0.002], np.array([[0]])) == pytest.approx(0.002)  # no reading: counted as one
