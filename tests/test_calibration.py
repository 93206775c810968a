"""Yang 2017 calibration (Eqs. 8-15) and the full-data least-squares calibration.

Closed forms are checked to rounding level; the methods are checked on scans simulated with the
exact forward model (geometry.tri_spindle_readings) with known truth.
"""

import json
import re

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from borescan.calibrate.full_fit import fit_full_calibration
from borescan.calibrate.result import CalibrationError, TriCalibration, make_calibration_id
from borescan.calibrate.sensitivities import full_residuals
from borescan.calibrate.yang import (
    yang_calibration,
    yang_d_b_r,
    yang_oe,
    yang_sensitivities,
    yang_status,
    yang_theta_c,
    yang_theta_t,
    yang_to_beams,
)
from borescan.geometry import Beams, Bore, tri_spindle_readings

TRUE = Beams(
    channels=(1, 2, 3),
    beta_rad=np.array([0.3, 0.3 + 2.1, 0.3 + 4.2]),
    rho_mm=np.array([5.5484, -2.5295, 1.5262]),
    d_b_mm=np.array([132.6718, 132.8883, 134.1108]),
)
R_MM = 275.029 / 2
OFFSET = np.array([262.955 - 262.833, -275.502 + 273.182])  # P1 - P0 of Yang 2017 §3.1


def _scan(rng, n_rev=5, N=200, noise_mm=0.002, offset=OFFSET, rpm=60.0, sign=1.0, beams=TRUE):
    w = sign * 2 * np.pi * rpm / 60.0
    t = np.arange(n_rev * N) / (N * rpm / 60.0)
    v = tri_spindle_readings(w * t, offset, beams, Bore((0.0, 0.0), R_MM))
    return t, v + rng.normal(0.0, noise_mm, v.shape)


def _nominal(rng):
    return Beams(
        TRUE.channels,
        TRUE.beta_rad + rng.uniform(-0.01, 0.01, 3),
        TRUE.rho_mm + rng.uniform(-0.5, 0.5, 3),
        TRUE.d_b_mm + rng.uniform(-0.1, 0.1, 3),
    )


# ----------------------------------------------------------------------------- Yang closed forms


def test_eq9_on_printed_coordinates():
    """Eq. 9 on P1, P0 of §3.1 gives 2.3232 mm; the paper prints 2.3222 mm."""
    assert yang_oe((262.955, -275.502), (262.833, -273.182)) == pytest.approx(
        np.hypot(0.122, 2.320), abs=1e-12
    )
    assert yang_oe((262.955, -275.502), (262.833, -273.182)) == pytest.approx(2.3232055, abs=1e-7)


def test_d_b_r_solve_eq8_exactly():
    rng = np.random.default_rng(0)
    d_min = rng.uniform(0.5, 3.0, 50)
    d_max = d_min + rng.uniform(3.0, 5.0, 50)
    d_b, r = yang_d_b_r(d_max, d_min, R_MM, 2.3222)
    ok = np.isfinite(r)
    assert ok.sum() > 10
    # Eq. 8 both lines, to rounding (the numbers are ~1.9e4 mm^2)
    assert np.max(np.abs(((d_b + d_min) ** 2 + r**2 - (R_MM - 2.3222) ** 2)[ok])) < 1e-8
    assert np.max(np.abs(((d_b + d_max) ** 2 + r**2 - (R_MM + 2.3222) ** 2)[ok])) < 1e-8
    # where Eq. 8 has no real r, r is NaN and the first line cannot be met
    assert np.all((R_MM - 2.3222) ** 2 - (d_b + d_min)[~ok] ** 2 < 0)


def test_sensitivities_match_central_differences():
    d_max, d_min, R, oe = 7.0549, 2.4067, R_MM, 2.3222
    s = yang_sensitivities(d_max, d_min, R, oe)
    h = 1e-6  # central-difference truncation ~1e-5 relative, roundoff ~1e-7 absolute
    args = {"d_max": d_max, "d_min": d_min, "R": R, "oe": oe}
    for name in args:
        up, dn = dict(args), dict(args)
        up[name] += h
        dn[name] -= h
        db_u, r_u = yang_d_b_r(up["d_max"], up["d_min"], up["R"], up["oe"])
        db_d, r_d = yang_d_b_r(dn["d_max"], dn["d_min"], dn["R"], dn["oe"])
        assert s[f"dr_d{name}"] == pytest.approx((r_u - r_d) / (2 * h), rel=1e-4)
        assert s[f"dd_b_d{name}"] == pytest.approx((db_u - db_d) / (2 * h), rel=1e-4, abs=1e-6)


def test_theta_t_eq15_and_status_rule():
    assert yang_theta_t(625 / 4, 625) == pytest.approx(np.pi / 2, abs=1e-15)
    assert yang_theta_t(222, 660) == pytest.approx(2 * np.pi * 222 / 660, abs=1e-15)
    # Table 2: sensor 1 mean 328 (min -> max) < 332 (max -> min): backward; sensor 3 advanced
    assert yang_status(328, 332) == "backward"
    assert yang_status(331, 329) == "advanced"


def test_theta_c_eq14_as_printed():
    X, r1, r2 = 135.2, 5.5, 2.5
    a1, a2 = np.arcsin(r1 / X), np.arcsin(r2 / X)
    assert yang_theta_c(r1, r2, X, "backward", "backward") == pytest.approx(a1 - a2, abs=1e-15)
    assert yang_theta_c(r1, r2, X, "advanced", "advanced") == pytest.approx(-a1 + a2, abs=1e-15)
    assert yang_theta_c(r1, r2, X, "advanced", "backward") == pytest.approx(-a1 - a2, abs=1e-15)
    assert yang_theta_c(r1, r2, X, "backward", "advanced") == pytest.approx(a1 + a2, abs=1e-15)
    with pytest.raises(ValueError, match="status must be one of"):
        yang_theta_c(r1, r2, X, "ahead", "backward")


def _exact_extremes(direction: str, N: int = 625):
    """Extremes and their sample positions of a noise-free scan, by dense sampling + refinement."""
    sgn = 1.0 if direction == "ccw" else -1.0
    bore = Bore((0.0, 0.0), R_MM)
    v = tri_spindle_readings(sgn * 2 * np.pi * np.arange(N) / N, OFFSET, TRUE, bore)
    out = {"d_min": [], "d_max": [], "n_min": [], "n_max": []}
    for j in range(3):

        def f(k, j=j):
            return tri_spindle_readings(np.array([sgn * 2 * np.pi * k / N]), OFFSET, TRUE, bore)[0, j]

        for key, sign, idx in (("min", 1, np.argmin(v[:, j])), ("max", -1, np.argmax(v[:, j]))):
            res = minimize_scalar(
                lambda k, sign=sign: sign * f(k),
                bounds=(idx - 1.5, idx + 1.5),
                method="bounded",
                options={"xatol": 1e-10},
            )
            out["d_" + key].append(sign * res.fun)
            out["n_" + key].append(res.x)
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.parametrize("direction", ["ccw", "cw"])
def test_yang_recovers_noise_free_simulation(direction):
    """Extremes of the exact forward model -> r, d_b to 1e-6 mm; statuses fix the sign of rho;
    Eqs. 12-15 (in the spec's frame) give beta_c - beta_1 to 2e-6 rad.
    """
    N = 625
    ex = _exact_extremes(direction, N)
    oe = np.hypot(*OFFSET)
    d_b, r = yang_d_b_r(ex["d_max"], ex["d_min"], R_MM, oe)
    assert np.max(np.abs(d_b - TRUE.d_b_mm)) < 1e-6
    assert np.max(np.abs(r - np.abs(TRUE.rho_mm))) < 1e-6
    n_mm = (ex["n_max"] - ex["n_min"]) % N
    statuses = [yang_status(a, N - a) for a in n_mm]
    # ccw: advanced <=> rho > 0 (the paper's sampling rule and its geometric definition agree)
    expect = ["advanced" if (rho > 0) == (direction == "ccw") else "backward" for rho in TRUE.rho_mm]
    assert statuses == expect
    cal = yang_calibration(
        ex["d_max"],
        ex["d_min"],
        statuses,
        ex["n_min"],
        N,
        R_MM,
        oe,
        beta_ref_rad=0.3,
        direction=direction,
        device_id="TRI-01",
        scan_ids=["s1"],
    )
    assert np.max(np.abs(cal.beams.rho_mm - TRUE.rho_mm)) < 1e-6
    assert np.max(np.abs(cal.beams.d_b_mm - TRUE.d_b_mm)) < 1e-6
    assert np.max(np.abs(cal.beams.beta_rad - TRUE.beta_rad)) < 2e-6
    assert cal.method == "yang2017" and np.all(cal.cov == 0.0)  # no input uncertainties given


@pytest.mark.parametrize("direction", ["ccw", "cw"])
def test_printed_eq14_has_the_opposite_sign(direction):
    """With angles measured in the sense of rotation (theta_t > 0 from line 2's feature point to
    line 1's, theta from line 1 to line 2) and statuses from the §2.3 sampling rule, the exact beam
    angle is theta_t - theta_c with theta_c of Eq. 14 as printed, not Eq. 12's theta_t + theta_c;
    the two differ by 2 theta_c (0.02-0.12 rad here).
    """
    N = 625
    ex = _exact_extremes(direction, N)
    oe = np.hypot(*OFFSET)
    _, r = yang_d_b_r(ex["d_max"], ex["d_min"], R_MM, oe)
    statuses = [yang_status(a, N - a) for a in (ex["n_max"] - ex["n_min"]) % N]
    sgn = 1.0 if direction == "ccw" else -1.0
    for i, j in ((0, 1), (1, 2), (0, 2)):
        # line 2 = beam i, line 1 = beam j; theta_t: rotation from i's feature point to j's
        theta_t = (2 * np.pi * (ex["n_min"][j] - ex["n_min"][i]) / N) % (2 * np.pi)
        theta_c = yang_theta_c(r[j], r[i], R_MM - oe, statuses[j], statuses[i])
        truth = (sgn * (TRUE.beta_rad[i] - TRUE.beta_rad[j])) % (2 * np.pi)
        assert (theta_t - theta_c) % (2 * np.pi) == pytest.approx(truth, abs=2e-6)
        assert abs((theta_t + theta_c) % (2 * np.pi) - truth) > 1e-2


def test_yang_to_beams_branch_and_gauge():
    b = yang_to_beams(
        (1, 2, 3),
        [1.0, 2.0, 3.0],
        [130.0, 131.0, 132.0],
        ["advanced", "backward", "advanced"],
        [10.0, 10.0 + 625 / 3, 10.0 + 2 * 625 / 3],
        625,
        135.0,
        beta_ref_rad=0.5,
        beta_nominal_rad=[0.5, 0.5 - 2.1, 0.5 - 4.2],
    )
    assert b.beta_rad[0] == 0.5
    assert np.all(np.abs(b.beta_rad - [0.5, 0.5 - 2.1, 0.5 - 4.2]) < 0.1)
    assert list(b.rho_mm) == [1.0, -2.0, 3.0]


def test_yang_calibration_raises_when_eq8_has_no_real_r():
    """Table 1 inputs with oe from Eq. 9 (2.3232 mm): sensors 2 and 3 have r^2 < 0."""
    with pytest.raises(
        CalibrationError, match=r"N20170205-P1: .*no real solution r for channel\(s\) \[2, 3\]"
    ):
        yang_calibration(
            [7.0549, 6.9256, 5.7177],
            [2.4067, 2.2804, 1.073],
            ["backward", "backward", "advanced"],
            [312.0, 88.0, 199.0],
            660.0,
            R_MM,
            yang_oe((262.955, -275.502), (262.833, -273.182)),
            scan_ids=["N20170205-P1"],
        )


def test_yang_uncertainty_propagation_matches_sensitivities():
    """u(r) from the propagated covariance equals |dr/dd_max| u(d_max) (+) |dr/dd_min| u(d_min) (+) |dr/doe|
    u(oe).
    """
    d_max, d_min, oe = np.array([7.0549, 6.9256, 5.7177]), np.array([2.4067, 2.2804, 1.073]), 2.3222
    u_dmax, u_dmin, u_oe = 1e-4, 2e-4, 1e-4
    cal = yang_calibration(
        d_max,
        d_min,
        ["backward", "backward", "advanced"],
        [312.0, 88.0, 199.0],
        660.0,
        R_MM,
        oe,
        u_d_max_mm=u_dmax,
        u_d_min_mm=u_dmin,
        u_oe_mm=u_oe,
    )
    s = yang_sensitivities(d_max, d_min, R_MM, oe)
    u_r = np.sqrt((s["dr_dd_max"] * u_dmax) ** 2 + (s["dr_dd_min"] * u_dmin) ** 2 + (s["dr_doe"] * u_oe) ** 2)
    u_db = np.sqrt(
        (s["dd_b_dd_max"] * u_dmax) ** 2 + (s["dd_b_dd_min"] * u_dmin) ** 2 + (s["dd_b_doe"] * u_oe) ** 2
    )
    assert np.allclose(cal.u_rho_mm, u_r, rtol=1e-4)
    assert np.allclose(cal.u_d_b_mm, u_db, rtol=1e-4)
    # sensor 3's r (1.56 mm) has u(r) of 0.6 mm: no meaningful r from 0.1-0.2 um level input uncertainty
    assert cal.u_rho_mm[2] > 0.3 * cal.beams.rho_mm[2]


# ----------------------------------------------------------------------------- full-data fit


def test_full_fit_noise_free_is_exact_and_gauge_is_reported():
    rng = np.random.default_rng(1)
    t, v = _scan(rng, n_rev=3, noise_mm=0.0)
    nominal = Beams(
        TRUE.channels, TRUE.beta_rad + [0.0, 0.01, -0.01], TRUE.rho_mm + [0.3, -0.3, 0.3], TRUE.d_b_mm + 0.05
    )
    cal = fit_full_calibration(
        t, v, TRUE.channels, nominal, R_MM, rpm=60.0, scan_ids=["A"], device_id="TRI-01"
    )
    assert cal.residual_rms_mm < 1e-9
    assert np.max(np.abs(cal.beams.beta_rad - TRUE.beta_rad)) < 1e-8  # nominal beta_1 = true beta_1 here
    assert np.max(np.abs(cal.beams.rho_mm - TRUE.rho_mm)) < 1e-6
    assert np.max(np.abs(cal.beams.d_b_mm - TRUE.d_b_mm)) < 1e-8
    nu = cal.nuisance["A"]
    assert nu["oe_mm"] == pytest.approx(np.hypot(*OFFSET), abs=1e-9)
    assert nu["omega_rad_s"] == pytest.approx(2 * np.pi, abs=1e-9)
    d = cal.diagnostics
    # 3c - 1 beam parameters + 3 per scan; with beta_1 and the phase free two directions are null
    assert d["n_params"] == 11 and cal.rank == 11
    assert d["n_params_all_free"] == 13 and d["rank_all_free"] == 11
    assert cal.u_beta_rad[0] == 0.0 and cal.cov.shape == (9, 9)
    # the fit reports through the project's one fit result, in its internal parameters
    f = cal.fit
    assert f.p == 11 and f.rank == cal.rank and f.dof == cal.dof and f.success
    assert f.names[:2] == ("psi_2_rad", "psi_3_rad") and f.names[-3:] == ("A.ox", "A.oy", "A.scale")
    assert f.values()["rho_1_mm"] == pytest.approx(cal.beams.rho_mm[0], abs=1e-12)


def test_full_fit_recovers_truth_within_3u():
    rng = np.random.default_rng(5)
    t, v = _scan(rng, n_rev=10, noise_mm=0.002)
    nominal = _nominal(rng)
    nominal = Beams(
        nominal.channels, np.r_[TRUE.beta_rad[0], nominal.beta_rad[1:]], nominal.rho_mm, nominal.d_b_mm
    )
    cal = fit_full_calibration(
        t, v, TRUE.channels, nominal, R_MM, rpm=60.0, scan_ids=["N20261121-TRI01-CAL-P1"], device_id="TRI-01"
    )
    assert np.all(np.abs(cal.beams.beta_rad[1:] - TRUE.beta_rad[1:]) < 3 * cal.u_beta_rad[1:])
    assert np.all(np.abs(cal.beams.rho_mm - TRUE.rho_mm) < 3 * cal.u_rho_mm)
    assert np.all(np.abs(cal.beams.d_b_mm - TRUE.d_b_mm) < 3 * cal.u_d_b_mm)
    nu = cal.nuisance["N20261121-TRI01-CAL-P1"]
    assert abs(nu["omega_rad_s"] - 2 * np.pi) < 3 * nu["u_omega_rad_s"]
    assert cal.residual_rms_mm == pytest.approx(0.002, rel=0.05)
    assert cal.dof == 3 * t.size - 11 and cal.converged
    corr = cal.correlation
    assert np.allclose(np.diag(corr)[1:], 1.0) and np.all(np.abs(corr) <= 1.0 + 1e-12)
    res = full_residuals(cal, t, v, R_MM)
    assert np.sqrt(np.mean(res**2)) == pytest.approx(cal.residual_rms_mm, rel=1e-9)
    assert re.fullmatch(r"TRI-01-20261121-full_lsq-[0-9a-f]{8}", cal.calibration_id)


def test_full_fit_two_scans_cw_missing_samples_and_speed_error():
    """Two clockwise scans at different spindle positions, 3 % NaN, spindle 0.3 % fast."""
    rng = np.random.default_rng(9)
    t1, v1 = _scan(rng, n_rev=5, offset=OFFSET, sign=-1.0, rpm=60.18)
    t2, v2 = _scan(rng, n_rev=5, offset=np.array([-1.9, 1.2]), sign=-1.0, rpm=60.18)
    for v in (v1, v2):
        v[rng.random(v.shape) < 0.03] = np.nan
    nominal = _nominal(rng)
    nominal = Beams(
        nominal.channels, np.r_[TRUE.beta_rad[0], nominal.beta_rad[1:]], nominal.rho_mm, nominal.d_b_mm
    )
    cal = fit_full_calibration(
        [t1, t2],
        [v1, v2],
        TRUE.channels,
        nominal,
        R_MM,
        rpm=[60.0, 60.0],
        direction="cw",
        scan_ids=["P1", "P2"],
    )
    assert np.all(np.abs(cal.beams.beta_rad[1:] - TRUE.beta_rad[1:]) < 3 * cal.u_beta_rad[1:])
    assert np.all(np.abs(cal.beams.rho_mm - TRUE.rho_mm) < 3 * cal.u_rho_mm)
    assert np.all(np.abs(cal.beams.d_b_mm - TRUE.d_b_mm) < 3 * cal.u_d_b_mm)
    for sid, off in (("P1", OFFSET), ("P2", [-1.9, 1.2])):
        assert cal.nuisance[sid]["oe_mm"] == pytest.approx(np.hypot(*off), abs=5e-3)
        nu = cal.nuisance[sid]
        # fitted with rpm = 60 nominal: the speed found is the true 60.18 rpm (omega < 0: clockwise)
        assert (
            nu["omega_rad_s"] < 0
            and abs(-nu["omega_rad_s"] - 2 * np.pi * 60.18 / 60) < 3 * nu["u_omega_rad_s"]
        )
    assert cal.diagnostics["rank_all_free"] == cal.diagnostics["n_params_all_free"] - 3  # 1 + 2 scans


def test_non_convergence_raises_naming_the_scan():
    rng = np.random.default_rng(2)
    t, v = _scan(rng, n_rev=2)
    nominal = Beams(TRUE.channels, TRUE.beta_rad + 0.02, TRUE.rho_mm + 1.0, TRUE.d_b_mm + 0.2)
    with pytest.raises(CalibrationError, match=r"^N20261121-TRI01-CAL-P1: full_lsq did not converge"):
        fit_full_calibration(
            t, v, TRUE.channels, nominal, R_MM, rpm=60.0, max_nfev=2, scan_ids=["N20261121-TRI01-CAL-P1"]
        )


def test_centred_spindle_is_rank_deficient():
    """Spindle on the gauge centre: readings are constant, rho and d_b are not separable."""
    rng = np.random.default_rng(3)
    t, v = _scan(rng, n_rev=2, offset=np.array([0.0, 0.0]), noise_mm=0.0)
    with pytest.raises(CalibrationError, match=r"^C0: full_lsq (Jacobian rank|did not converge)"):
        fit_full_calibration(t, v, TRUE.channels, TRUE, R_MM, rpm=60.0, scan_ids=["C0"])


def test_too_few_samples_raises():
    t = np.arange(3) / 200.0
    v = np.ones((3, 3))
    with pytest.raises(CalibrationError, match="9 valid samples for 11 parameters"):
        fit_full_calibration(t, v, TRUE.channels, TRUE, R_MM, scan_ids=["tiny"])


def test_tricalibration_json_round_trip_and_id():
    rng = np.random.default_rng(4)
    t, v = _scan(rng, n_rev=2)
    cal = fit_full_calibration(
        t,
        v,
        TRUE.channels,
        TRUE,
        R_MM,
        scan_ids=["N20261121-TRI01-CAL-P1"],
        device_id="TRI-01",
        raw_sha256={"lds.parquet": "0" * 64},
    )
    d = json.loads(json.dumps(cal.to_dict(), allow_nan=False))
    back = TriCalibration.from_dict(d)
    assert back.calibration_id == cal.calibration_id and back.method == "full_lsq"
    assert np.array_equal(back.cov, cal.cov)
    assert np.array_equal(back.beams.rho_mm, cal.beams.rho_mm)
    assert back.raw_sha256 == {"lds.parquet": "0" * 64}
    assert back.nuisance == cal.nuisance
    a = make_calibration_id("TRI-01", ["N20261121-TRI01-CAL-P2", "N20261121-TRI01-CAL-P1"], "full_lsq")
    b = make_calibration_id("TRI-01", ["N20261121-TRI01-CAL-P1", "N20261121-TRI01-CAL-P2"], "full_lsq")
    assert a == b and re.fullmatch(r"TRI-01-20261121-full_lsq-[0-9a-f]{8}", a)
    assert make_calibration_id("TRI-01", ["x"], "yang2017", night="2026-11-22").startswith(
        "TRI-01-20261122-yang2017-"
    )
    assert make_calibration_id("TRI-01", ["x"], "yang2017") != make_calibration_id(
        "TRI-01", ["x"], "full_lsq"
    )


@pytest.mark.slow
def test_uncertainties_are_honest_over_200_calibrations():
    """About 95 % of true values inside +-2u over 200 seeded calibrations (5 rev x 200 samples, 1 um noise).

    Binomial sd of a 200-trial fraction at 0.95 is 0.015, so each parameter must lie in
    [0.88, 1.0] and the pooled fraction (1600 values) in [0.90, 0.99]. At 2 um noise channel 3
    (rho = 1.53 mm) sits in the nonlinear regime |rho| < 3 u(rho) and its d_b is under-covered
    (0.89, mean z^2 4.9; bench/bench_calibration.py prints it).
    """
    rng = np.random.default_rng(7)
    z = []
    for _ in range(200):
        nominal = _nominal(rng)
        t, v = _scan(rng, n_rev=5, N=200, noise_mm=0.001)
        cal = fit_full_calibration(t, v, TRUE.channels, nominal, R_MM, rpm=60.0)
        dbeta = (cal.beams.beta_rad - cal.beams.beta_rad[0]) - (TRUE.beta_rad - TRUE.beta_rad[0])
        err = np.r_[dbeta[1:], cal.beams.rho_mm - TRUE.rho_mm, cal.beams.d_b_mm - TRUE.d_b_mm]
        u = np.r_[cal.u_beta_rad[1:], cal.u_rho_mm, cal.u_d_b_mm]
        z.append(err / u)
    inside = np.abs(np.array(z)) <= 2.0
    per_param = inside.mean(axis=0)
    assert np.all(per_param >= 0.88), per_param
    assert 0.90 <= inside.mean() <= 0.99, inside.mean()


# ----------------------------------------------------------------------------- any scan the contract allows


def _twin_scan(scene, *, encoder, n_rev=20, seed=0, effects=(), noise_mm=0.003, spindle_stream=True):
    """Return a scan drawn by the digital twin, reduced to what the fit reads (times, readings, angle
    model).
    """
    import polars as pl

    from borescan import kinematics
    from borescan.synthetic import simulate

    sim = simulate.simulate_tri_spindle(
        scene,
        n_rev=n_rev,
        encoder=encoder,
        seed=seed,
        effects=effects,
        noise_mm=noise_mm,
        center_xy_mm=scene.bore_center_xy_mm,
    )
    w = sim.lds.pivot(on="sensor", index="t_ns", values="value_mm").sort("t_ns")
    t = w["t_ns"].to_numpy() * 1e-9
    v = w.select([str(c) for c in scene.beams.channels]).to_numpy().astype(float)
    sp = sim.spindle
    if spindle_stream:
        am = kinematics.angle_model_from_arrays(
            rpm_nominal=scene.rpm_nominal,
            direction=scene.direction,
            spindle_t_s=sp["t_ns"].to_numpy() * 1e-9,
            spindle_angle_rad=sp["angle_rad"].cast(pl.Float64).fill_null(np.nan).to_numpy(),
            spindle_rpm=sp["rpm"].to_numpy(),
        )
    else:
        am = kinematics.angle_model_from_arrays(rpm_nominal=60.0, direction=scene.direction)
    return t, v, am


def _contract_scene(**kw):
    from dataclasses import replace

    from borescan.synthetic import scenes

    beams = Beams(
        (1, 2, 3), np.array([0.9, 2.9, 5.1]), np.array([7.2, -3.1, 0.8]), np.array([96.8, 99.0, 98.3])
    )
    scene = scenes.default_tri_scene(
        beams=beams,
        bore_radius_20_mm=101.5,
        bore_center_xy_mm=(10.0, -4.0),
        spindle_xy_mm=(11.2, -2.9),
        sample_rate_hz=450.0,
        rpm_nominal=60.0,
    )
    return replace(scene, **kw)


def _z(cal, truth: Beams):
    dbeta = cal.beams.beta_rad - truth.beta_rad
    u_beta = cal.u_beta_rad.copy()
    if cal.diagnostics["beta_reference"] != "absolute":
        dbeta = dbeta - dbeta[0]
        dbeta, u_beta = dbeta[1:], u_beta[1:]
    return np.r_[
        dbeta / u_beta,
        (cal.beams.rho_mm - truth.rho_mm) / cal.u_rho_mm,
        (cal.beams.d_b_mm - truth.d_b_mm) / cal.u_d_b_mm,
    ]


RAMP = ((0.0, 60.0), (8.0, 60.0), (9.0, 34.0))


@pytest.mark.parametrize("encoder", [True, False])
def test_speed_change_with_and_without_encoder(encoder):
    """60 rpm, a 1 s ramp, then 34 rpm: the angle comes from the encoder, else from the rpm profile."""
    scene = _contract_scene(rpm_profile=RAMP, phase_rad=1.3, direction="cw")
    t, v, am = _twin_scan(scene, encoder=encoder, seed=3)
    truth = scene.beams
    nominal = Beams(truth.channels, truth.beta_rad + 0.018, truth.rho_mm - 0.8, truth.d_b_mm + 0.6)
    cal = fit_full_calibration(
        t,
        v,
        truth.channels,
        nominal,
        scene.bore_radius_20_mm,
        scene.spindle_xy_mm,
        center_xy_mm=scene.bore_center_xy_mm,
        angle_models=[am],
        scan_ids=["R"],
    )
    z = _z(cal, truth)
    assert np.all(np.abs(z) < 4), z
    nu = cal.nuisance["R"]
    assert nu["angle_source"] == ("encoder" if encoder else "profile")
    if encoder:
        # the encoder, the centre and the spindle position make every beta absolute: no design value is kept
        assert cal.diagnostics["beta_reference"] == "absolute" and cal.u_beta_rad[0] > 0
        assert abs(cal.beams.beta_rad[0] - truth.beta_rad[0]) < 4 * cal.u_beta_rad[0]
    else:
        assert cal.diagnostics["beta_reference"] == "channel 1 fixed"
        assert abs(nu["speed_scale"] - 1.0) < 4 * nu["u_speed_scale"]
    assert max(nu["residual_to_noise"]) < 1.1


def test_stated_u_rho_is_the_curvature_of_the_rho_profile():
    """A speed change read by the encoder (the kind of contract scan whose errors were 2-3 u, issue 36).

    The profile chi2 of each rho (SSR / sigma^2 minimised over every other parameter, rho held at the
    fit +- its stated u) rises by 1 where the stated u is the data's own curvature; the tolerance
    0.75-1.3 allows the valley's curvature (d_b = g - rho^2 / (2R)) and nothing like a missed
    parameter or an unused prior, which would move it by factors.
    """
    from scipy.optimize import least_squares

    from borescan.geometry import Bore, tri_spindle_readings

    scene = _contract_scene(rpm_profile=RAMP, phase_rad=1.3, direction="cw")
    sigma_mm = 0.003
    t, v, am = _twin_scan(scene, encoder=True, seed=3, noise_mm=sigma_mm)
    truth = scene.beams
    cal = fit_full_calibration(
        t,
        v,
        truth.channels,
        truth,
        scene.bore_radius_20_mm,
        scene.spindle_xy_mm,
        center_xy_mm=scene.bore_center_xy_mm,
        angle_models=[am],
        scan_ids=["P"],
    )
    phi, ok = am.phi_rad(t), np.isfinite(v)
    nu = cal.nuisance["P"]
    x_fit = np.r_[cal.params, nu["offset_x_mm"], nu["offset_y_mm"]]

    def chi2_min(x0, held):
        free = [i for i in range(x0.size) if i not in held]

        def res(z):
            x = x0.copy()
            x[free] = z
            b = x[:9].reshape(3, 3)
            vm = tri_spindle_readings(
                phi, x[9:11], Beams(truth.channels, *b.T), Bore((0.0, 0.0), scene.bore_radius_20_mm)
            )
            return (v - vm)[ok] / sigma_mm

        return 2.0 * least_squares(res, x0[free], method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12).cost

    base = chi2_min(x_fit, [])
    for k in range(3):
        for sign in (-1.0, 1.0):
            x0 = x_fit.copy()
            x0[3 * k + 1] += sign * cal.u_rho_mm[k]
            rise = chi2_min(x0, [3 * k + 1]) - base
            assert 0.75 < rise < 1.3, (k, sign, rise)


def test_mistyped_speed_without_spindle_stream():
    """No spindle stream, rpm_nominal 60 while the spindle turns at 64.5 rpm (7.5 % off)."""
    from dataclasses import replace

    scene = _contract_scene(rpm_nominal=64.5)
    t, v, am = _twin_scan(scene, encoder=False, seed=4, spindle_stream=False)
    cal = fit_full_calibration(
        t, v, scene.beams.channels, scene.beams, scene.bore_radius_20_mm, angle_models=[am], scan_ids=["M"]
    )
    nu = cal.nuisance["M"]
    assert nu["angle_source"] == "nominal"
    assert abs(nu["speed_scale"] - 64.5 / 60.0) < 4 * nu["u_speed_scale"]
    assert np.all(np.abs(_z(cal, replace(scene).beams)) < 4)


def test_mirror_rho_start_finds_the_true_minimum():
    """Design offsets of the wrong sign on every beam: the rho profile start still lands on the truth."""
    scene = _contract_scene(rpm_profile=RAMP)
    t, v, am = _twin_scan(scene, encoder=True, seed=5)
    truth = scene.beams
    nominal = Beams(truth.channels, truth.beta_rad, -truth.rho_mm, truth.d_b_mm)
    cal = fit_full_calibration(
        t,
        v,
        truth.channels,
        nominal,
        scene.bore_radius_20_mm,
        scene.spindle_xy_mm,
        center_xy_mm=scene.bore_center_xy_mm,
        angle_models=[am],
        scan_ids=["X"],
    )
    assert np.all(np.sign(cal.beams.rho_mm) == np.sign(truth.rho_mm))
    assert np.all(np.abs(_z(cal, truth)) < 4)


def test_unmodelled_effect_is_refused_with_the_reason():
    """A 6 um, 7.3 Hz vibration on every channel, which no beam geometry absorbs: no certificate."""
    from borescan.effects import Effect

    scene = _contract_scene()
    t, v, am = _twin_scan(
        scene, encoder=True, seed=6, effects=[Effect("vibration", {"f_hz": 7.3, "a_mm": 0.006, "phase": 0.4})]
    )
    with pytest.raises(
        CalibrationError,
        match=r"^B: calibration refused: B channel 1: residual rms is \d+\.\d\d times "
        r"the readings' own noise floor \(limit 1\.25\)",
    ):
        fit_full_calibration(
            t,
            v,
            scene.beams.channels,
            scene.beams,
            scene.bore_radius_20_mm,
            scene.spindle_xy_mm,
            center_xy_mm=scene.bore_center_xy_mm,
            angle_models=[am],
            scan_ids=["B"],
        )


def test_impossible_geometry_is_refused():
    """A head radius smaller than a beam's true offset: the fit is refused for physics, not noise."""
    from borescan.calibrate.result import AcceptanceRule

    scene = _contract_scene()
    t, v, am = _twin_scan(scene, encoder=True, seed=7)
    with pytest.raises(
        CalibrationError, match=r"channel 1: \|rho\| = 7\.\d{3} mm exceeds the head radius 5 mm"
    ):
        fit_full_calibration(
            t,
            v,
            scene.beams.channels,
            scene.beams,
            scene.bore_radius_20_mm,
            scene.spindle_xy_mm,
            center_xy_mm=scene.bore_center_xy_mm,
            angle_models=[am],
            scan_ids=["H"],
            rule=AcceptanceRule.defaults(head_radius_mm=5.0),
        )
