"""GUM budgets (borescan.uncertainty): the GUM's own worked example, published t factors, closed-form
coverage intervals, merging of a quantity used twice, and GUM S1 Monte Carlo checks of the
propagation through a calibration (refits) and through a diameter (the non-linear circumcircle).
"""

import math

import numpy as np
import pytest
from scipy import stats

from borescan.uncertainty import (
    Budget,
    Input,
    Term,
    chi2_quantile,
    combine,
    coverage_factor,
    draw,
    format_value,
    linear_coverage_interval,
    monte_carlo,
    numerical_tolerance,
    round_uncertainty,
    s1_validate,
    standard_uncertainty,
    welch_satterthwaite,
)


def _inp(key, u, dist="normal", dof=float("inf"), estimate=0.0, unit="nm"):
    return Input(key, key, key, unit, estimate, u, dist, dof, "A" if np.isfinite(dof) else "B")


# --------------------------------------------------------------------------- the GUM's worked example H.1


def test_gum_h1_end_gauge_calibration():
    """JCGM 100:2008 H.1 (end gauge of nominal length 50 mm), Table H.1 and H.1.6: u_c(l) = 32 nm,
    nu_eff = 16 (16.7 truncated), k = t_95(16) = 2.12, U_95 = 68 nm (2.12 x 32 nm; 67 nm from the
    unrounded u_c). Inputs as printed: l_s (u 25 nm, nu 18, c 1), d (u 9.7 nm, nu 25.6, c 1),
    alpha_s and theta (c = 0 at first order), delta-alpha (u 0.58e-6 /degC, c = -l_s theta =
    50 mm x 0.1 degC), delta-theta (u 0.029 degC, nu 2, c = -l_s alpha_s = -50 mm x 11.5e-6 /degC).
    """
    l_s_nm, theta, alpha_s = 50.000623e6, -0.1, 11.5e-6
    b = Budget(("l",), ("nm",), [50.000838e6])
    b.add(Term(_inp("l_s", 25.0, dof=18), [1.0]))
    b.add(Term(_inp("d", 9.7, dof=25.6), [1.0]))
    b.add(Term(_inp("alpha_s", 1.2e-6, "rectangular"), [0.0]))
    b.add(Term(_inp("theta", 0.41), [0.0]))
    b.add(Term(_inp("delta_alpha", 0.58e-6, "rectangular", dof=50), [-l_s_nm * theta]))
    b.add(Term(_inp("delta_theta", 0.029, "rectangular", dof=2), [-l_s_nm * alpha_s]))
    rows = {r["key"]: r for r in b.rows(0)}
    assert rows["delta_alpha"]["contribution"] == pytest.approx(2.9, abs=0.05)  # Table H.1: 2.9 nm
    assert rows["delta_theta"]["contribution"] == pytest.approx(16.6, abs=0.1)  # 16.6 nm (16.7 unrounded)
    assert rows["theta"]["contribution"] == 0.0 and rows["alpha_s"]["contribution"] == 0.0
    c = b.combined(0, 0.95)
    assert c.u == pytest.approx(32.0, abs=0.5)
    assert c.nu_eff == pytest.approx(16.7, abs=0.1)
    assert c.k_guf == pytest.approx(2.12, abs=0.005)  # t_95(16), GUM Table G.2: 2.12
    assert c.k_guf * c.u == pytest.approx(67.0, abs=0.5)  # 2.12 x 31.7 nm; the GUM prints 2.12 x 32 = 68 nm
    # by hand: nu_eff = 31.7^4 / (25^4/18 + 9.7^4/25.6 + 2.9^4/50 + 16.6^4/2)
    uc = math.sqrt(25**2 + 9.7**2 + 2.9**2 + 16.675**2)
    assert welch_satterthwaite([25, 9.7, 2.9, 16.675], [18, 25.6, 50, 2]) == pytest.approx(
        uc**4 / (25**4 / 18 + 9.7**4 / 25.6 + 2.9**4 / 50 + 16.675**4 / 2), rel=1e-12
    )


@pytest.mark.parametrize(
    "nu, k",
    [
        (1, 13.97),
        (2, 4.53),
        (3, 3.31),
        (4, 2.87),
        (5, 2.65),
        (10, 2.28),
        (20, 2.13),
        (50, 2.05),
        (float("inf"), 2.00),
    ],
)
def test_coverage_factor_matches_gum_table_g2(nu, k):
    """GUM Table G.2, column p = 95.45 %."""
    assert coverage_factor(0.9545, nu) == pytest.approx(k, abs=0.006)


def test_coverage_factor_truncates_nu_and_checks_p():
    assert coverage_factor(0.95, 16.9) == coverage_factor(0.95, 16)
    assert coverage_factor(0.95, 16.9, truncate=False) < coverage_factor(0.95, 16)
    with pytest.raises(ValueError, match="coverage probability"):
        coverage_factor(1.2)


def test_chi2_quantile_closed_forms_table_and_scipy_stats():
    """chi2_quantile against closed forms (1 and 2 degrees of freedom), the printed table and scipy.stats.

    One degree of freedom: the square of the two-sided normal quantile. Two: the exponential's, -2 ln(1 - p).
    Table values at p = 0.95 (3.841, 5.991, 7.815, 9.488 for 1-4 degrees of freedom). Equal, bit for bit, to
    scipy.stats.chi2.ppf, which evaluates the same formula: the DCC's coverage factors do not move.
    """
    for p in (0.5, 0.6827, 0.9, 0.95, 0.9545, 0.99, 0.9973):
        assert chi2_quantile(p, 1) == pytest.approx(coverage_factor(p) ** 2, rel=1e-12)
        assert chi2_quantile(p, 2) == pytest.approx(-2.0 * math.log1p(-p), rel=1e-12)
        for dof in range(1, 13):
            assert chi2_quantile(p, dof) == stats.chi2.ppf(p, dof)
    for dof, x in ((1, 3.841), (2, 5.991), (3, 7.815), (4, 9.488)):
        assert chi2_quantile(0.95, dof) == pytest.approx(x, abs=5e-4)
    for p, dof in ((0.0, 2), (1.0, 2), (0.95, 0)):
        with pytest.raises(ValueError):
            chi2_quantile(p, dof)


def test_standard_uncertainty_of_stated_bounds():
    assert standard_uncertainty(halfwidth=3.0) == pytest.approx(math.sqrt(3.0))
    assert standard_uncertainty(halfwidth=6.0, distribution="triangular") == pytest.approx(
        6.0 / math.sqrt(6.0)
    )
    assert standard_uncertainty(halfwidth=2.0, distribution="arcsine") == pytest.approx(math.sqrt(2.0))
    assert standard_uncertainty(expanded=1.5, k=2, distribution="normal") == 0.75
    with pytest.raises(ValueError, match="unknown distribution"):
        standard_uncertainty(halfwidth=1.0, distribution="gamma")
    with pytest.raises(ValueError, match="no half-width"):
        standard_uncertainty(halfwidth=1.0, distribution="normal")


# --------------------------------------------------------------------------- the propagated distribution


def test_linear_coverage_interval_closed_forms():
    p = 0.9545
    a = math.sqrt(3.0)  # u = 1
    assert linear_coverage_interval([("rectangular", 1.0, np.inf)], p) == pytest.approx(p * a, rel=1e-4)
    # two equal rectangulars: triangular on +-2a, P(|Y| <= q) = 1 - (1 - q / 2a)^2
    assert linear_coverage_interval([("rectangular", 1.0, np.inf)] * 2, p) == pytest.approx(
        2 * a * (1 - math.sqrt(1 - p)), rel=1e-4
    )
    # arcsine on +-a: P(|X| <= q) = (2 / pi) asin(q / a)
    assert linear_coverage_interval([("arcsine", 1.0, np.inf)], p) == pytest.approx(
        math.sqrt(2.0) * math.sin(p * math.pi / 2), rel=1e-4
    )
    assert linear_coverage_interval([("normal", 1.0, 5)], 0.95) == pytest.approx(
        stats.t.ppf(0.975, 5), rel=1e-4
    )
    assert linear_coverage_interval([("normal", 3.0, np.inf), ("normal", 4.0, np.inf)], p) == pytest.approx(
        5.0 * stats.norm.ppf(0.5 * (1 + p)), rel=1e-12
    )


def test_dominant_rectangular_is_not_given_k2():
    """One rectangular input dominating: the GUF k = 2 would cover 100 %; GUM S1 does not validate it
    and the propagated k is used (1.65 for a rectangular alone at 95.45 %).
    """
    c = combine([(1.0, np.inf, "rectangular"), (0.05, np.inf, "normal")], 0.9545)
    assert c.method == "propagation of distributions"
    assert c.k == pytest.approx(1.65, abs=0.01) and c.k_guf == pytest.approx(2.0, abs=1e-4)
    c = combine([(1.0, np.inf, "normal"), (0.1, np.inf, "rectangular")], 0.9545)
    assert c.method == "GUF" and c.k == c.k_guf


def test_merged_terms_add_sensitivities():
    """The calibration's gauge and the verified gauge as one input: D transfers the gauge to the
    device (c = +1), the error E = D - D_g subtracts it (c = -1): it cancels.
    """
    g = _inp("gauge:RG-275@C1:D20", 0.75, unit="um")
    b = Budget(
        ("E",),
        ("um",),
        [0.0],
        [Term(g, [1.0]), Term(_inp("readings", 1.0, unit="um"), [1.0]), Term(g, [-1.0])],
    )
    m = b.merged()
    assert len(m.terms) == 2 and m.terms[0].sensitivity[0] == 0.0
    assert m.combined(0, 0.9545).u == pytest.approx(1.0)
    with pytest.raises(ValueError, match="vector term"):
        Budget(("y",), ("-",), [0.0], [Term(g, cov=[[1.0]]), Term(g, cov=[[1.0]])]).merged()


def test_budget_round_trip_and_vector_terms():
    cov = np.array([[4.0, 1.0], [1.0, 9.0]])
    b = Budget(
        ("a", "b"),
        ("mm", "mm"),
        [1.0, 2.0],
        [Term(_inp("fit", 0.002, dof=100), cov=cov), Term(_inp("x", 0.5, "rectangular"), [1.0, -1.0])],
    )
    back = Budget.from_dict(b.to_dict())
    assert np.array_equal(back.covariance(), b.covariance())
    assert np.allclose(b.covariance(), cov + 0.25 * np.array([[1, -1], [-1, 1]]))
    rows = b.rows(np.array([1.0, 1.0]))  # a + b: the rectangular cancels, the fit gives sqrt(4 + 9 + 2)
    assert rows[0]["contribution"] == pytest.approx(math.sqrt(15.0)) and rows[1]["contribution"] == 0.0


def test_rounding_and_formatting_follow_gum_7_2_6():
    assert round_uncertainty(0.0581) == (0.059, 3)  # rounded up, two significant digits
    assert round_uncertainty(9.96) == (10.0, 0)
    assert format_value(275.0319623, 0.0058, "mm") == "(275.0320 +- 0.0058) mm"
    assert format_value(275.0319623, 0.0058, "mm", 1.0, "um", 1e3) == "275.0320 mm +- 5.8 um"
    assert numerical_tolerance(31.7) == 0.5 and numerical_tolerance(0.0581) == 0.0005


def test_draw_has_the_stated_standard_deviation():
    rng = np.random.default_rng(1)
    for dist in ("normal", "rectangular", "triangular", "arcsine"):
        x = draw(dist, 5.0, 2.0, 200_000, rng)
        assert np.mean(x) == pytest.approx(5.0, abs=0.02) and np.std(x) == pytest.approx(2.0, rel=0.01), dist
    x = draw("normal", 0.0, 1.0, 200_000, rng, dof=10)  # u t_10: SD sqrt(10/8)
    assert np.std(x) == pytest.approx(math.sqrt(10 / 8), rel=0.02)


# --------------------------------------------------------------------------- GUM S1 Monte Carlo checks


def test_monte_carlo_validates_the_guf_of_a_linear_model():
    """A linear model of normal inputs: the GUF interval is exact; GUM S1 §8 validates it."""
    rng = np.random.default_rng(3)
    ins = {"x": _inp("x", 1.0), "y": _inp("y", 2.0)}
    mc = monte_carlo(lambda d: 3.0 * d["x"] - d["y"], ins, 0.9545, 1_000_000, rng)
    u = math.sqrt(9.0 + 4.0)
    ok, d_lo, d_hi, delta = s1_validate(0.0, 2.0 * u, u, mc, n_dig=1)
    assert ok, (d_lo, d_hi, delta)
    assert mc.u == pytest.approx(u, rel=0.005)


@pytest.mark.parametrize("a_temp_k, method", [(0.5, "GUF"), (10.0, "propagation of distributions")])
def test_diameter_budget_against_gum_s1_monte_carlo(a_temp_k, method):
    """GUM S1 Monte Carlo through the non-linear measurement model of a static diameter at 20 degC.

    Model: D20 = circumcircle diameter of the wall points of readings v + e_meas with beams
    theta = theta_hat + (calibration errors), divided by 1 + alpha (T - 20). Calibration errors:
    a Type A vector (multivariate normal), the gauge (normal, on every d_b), the calibration's
    linearity per channel (rectangular, on its own d_b); measurement: the readings' scatter
    (normal), linearity per channel (rectangular, +-10 um), temperature (rectangular) and
    alpha (rectangular). 400 000 trials; the linearised budget of
    :func:`borescan.measure.diameter_uncertainty` must agree: u within 1 %, and the coverage
    interval end points within the numerical tolerance of u at two significant digits (GUM S1 §8).
    With the temperature known within +-0.5 K the output is near normal and the GUF (k = 2) is
    kept; with +-10 K the temperature's rectangular dominates, the GUF is not validated and the
    propagated k (about 1.8) is used, and the Monte Carlo interval agrees with that one.
    """
    from borescan.artifacts import ArtifactCte, ScanTemperature
    from borescan.geometry import Beams, Bore, tri_static_readings
    from borescan.measure import diameter_uncertainty, static_diameter_jacobian

    beams = Beams(
        (1, 2, 3),
        np.array([0.35, 2.46, 4.56]),
        np.array([-5.5, -2.5, 1.5]),
        np.array([132.67, 132.89, 134.11]),
    )
    R = 276.4 / 2
    v = tri_static_readings(np.array([[0.4, -0.3]]), np.array([0.2]), beams, Bore((0.0, 0.0), R))[0]
    c = 3
    # the calibration's budget over (beta, rho, d_b) per channel
    sd = np.tile([2e-4, 0.05, 0.002], c)
    C_fit = np.diag(sd**2)
    C_fit[1, 2] = C_fit[2, 1] = -0.9 * sd[1] * sd[2]
    theta0 = np.stack([beams.beta_rad, beams.rho_mm, beams.d_b_mm], axis=1).ravel()
    cal = Budget(
        tuple(f"p{i}" for i in range(3 * c)),
        ("rad", "mm", "mm") * c,
        theta0,
        [Term(_inp("fit", 0.004, dof=10_000, unit="mm"), cov=C_fit)],
    )
    e_db = np.zeros((c, 3 * c))
    for j in range(c):
        e_db[j, 3 * j + 2] = 1.0
    cal.add(Term(_inp("gauge", 0.00075, unit="mm"), 0.5 * e_db.sum(axis=0)))
    a_lin = 0.010
    for j in range(c):
        cal.add(Term(_inp(f"lin_cal{j}", a_lin / math.sqrt(3), "rectangular", unit="mm"), -e_db[j]))
    T, aT, cte, acte, u_rd = 23.0, a_temp_k, 11.5e-6, 1e-6, 0.0008
    temp = ScanTemperature(T, aT, aT / math.sqrt(3), False, "test")
    ct = ArtifactCte(cte, acte, acte / math.sqrt(3), False, "test")
    D, jp, jv, _ = static_diameter_jacobian(v[None, :], beams)
    sensors = {ch: {"linearity_fs": a_lin / 10.0, "range_mm": 10.0, "resolution_mm": 0.0} for ch in (1, 2, 3)}
    du = diameter_uncertainty(
        float(D[0]),
        jac_params=jp[0],
        calibration_budget=cal,
        jac_readings=jv[0],
        u_readings_mm=u_rd,
        dof_readings=float("inf"),
        sensors=sensors,
        channels=(1, 2, 3),
        noise_mm=None,
        temperature=temp,
        cte=ct,
        artifact={"id": "P"},
        scan_id="S",
        p=0.9545,
        default_resolution_mm=0.0,
    )

    rng = np.random.default_rng(20270611)
    n = 400_000

    along = jv[0] / float(
        jv[0] @ jv[0]
    )  # readings moved so that D moves by x["rd"] (the budget's readings term)

    def model(x):
        theta = theta0 + x["fit"]
        theta = theta + 0.5 * e_db.sum(axis=0) * x["gauge"][:, None]
        for j in range(c):
            theta = theta - e_db[j] * x[f"lin_cal{j}"][:, None]
        vv = v[None, :] + np.stack([x[f"lin{j}"] for j in range(c)], axis=1) + np.outer(x["rd"], along)
        out = np.empty(n)
        for k0 in range(0, n, 100_000):  # the circumcircle is vectorised over readings, not over beams
            sl = slice(k0, k0 + 100_000)
            out[sl] = _circum_diameters(vv[sl], theta[sl])
        return out / (1.0 + x["alpha"] * (x["T"] - 20.0))

    ins = {"fit": (np.zeros(3 * c), C_fit), "gauge": _inp("g", 0.00075)}
    for j in range(c):
        ins[f"lin_cal{j}"] = _inp("l", a_lin / math.sqrt(3), "rectangular")
        ins[f"lin{j}"] = _inp("l", a_lin / math.sqrt(3), "rectangular")
    ins["rd"] = _inp("rd", u_rd)
    ins["T"] = Input("T", "T", "T", "degC", T, aT / math.sqrt(3), "rectangular")
    ins["alpha"] = Input("a", "a", "a", "1/K", cte, acte / math.sqrt(3), "rectangular")
    mc = monte_carlo(model, ins, 0.9545, n, rng)
    c20 = du.combined_20
    assert c20.method == method and (c20.k == c20.k_guf if method == "GUF" else 1.7 < c20.k < 1.9), c20
    assert mc.u == pytest.approx(c20.u, rel=0.01)
    ok, d_lo, d_hi, delta = s1_validate(du.diameter_20_mm, c20.U, c20.u, mc, n_dig=2)
    assert ok, (d_lo, d_hi, delta, c20, mc)
    assert mc.y == pytest.approx(du.diameter_20_mm, abs=0.1 * c20.u)


def _circum_diameters(v: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Diameter of the circumcircle of three wall points W_i = rho_i n_i + (d_b,i + v_i) u_i, row by row."""
    beta, rho, d_b = theta[:, 0::3], theta[:, 1::3], theta[:, 2::3]
    u = np.stack([np.cos(beta), np.sin(beta)], axis=-1)
    nvec = np.stack([-np.sin(beta), np.cos(beta)], axis=-1)
    W = rho[..., None] * nvec + (d_b + v)[..., None] * u
    a, b, c = W[:, 0], W[:, 1], W[:, 2]
    ab, bc, ca = np.linalg.norm(a - b, axis=1), np.linalg.norm(b - c, axis=1), np.linalg.norm(c - a, axis=1)
    cross = np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    return ab * bc * ca / cross  # 2R = abc / (2 area) = abc / |cross|


@pytest.mark.slow
def test_calibration_sensitivities_against_gum_s1_refits():
    """GUM S1 through the calibration itself: 150 refits of one scan's readings with the gauge's
    diameter, its temperature, the reported positions and each channel's linearity drawn from their
    stated distributions (the readings' noise fixed). The spread of the refitted parameters is the
    Type B part of the linearised budget (:func:`borescan.stages.calibration_fit.calibration_budget`):
    the sample SD within +-20 % (its sampling error at 150 draws is about 6 %) wherever the Type B
    part is more than a tenth of the parameter's u, and below a fifth of u elsewhere.
    """
    from borescan.calibrate.full_fit import fit_full_calibration
    from borescan.calibrate.sensitivities import full_lsq_sensitivities
    from borescan.geometry import Beams, Bore, tri_spindle_readings
    from borescan.kinematics import angle_model_from_arrays

    truth = Beams(
        (1, 2, 3),
        np.array([0.3, 2.4, 4.5]),
        np.array([5.5484, -2.5295, 1.5262]),
        np.array([132.6718, 132.8883, 134.1108]),
    )
    D20, cte, T, aT, a_pos, a_lin = 275.029, 11.5e-6, 21.0, 0.1, 0.002, 0.004
    R = 0.5 * D20 * (1 + cte * (T - 20))
    rng = np.random.default_rng(5)
    t = np.arange(1000) / 200.0
    S, C = np.array([262.955, -275.502]), np.array([262.833, -273.182])
    v = tri_spindle_readings(2 * np.pi * t, S - C, truth, Bore((0.0, 0.0), R)) + rng.normal(
        0, 0.001, (1000, 3)
    )
    am = angle_model_from_arrays(rpm_nominal=60.0, direction="ccw")

    def fit(Rm, vv, Sm, Cm):
        return fit_full_calibration(
            [t], [vv], truth.channels, truth, Rm, [Sm], center_xy_mm=[Cm], angle_models=[am], scan_ids=["A"]
        )

    cal = fit(R, v, S, C)
    sens = full_lsq_sensitivities(cal, [t], [v], R, [am], spindle_xy_mm=[S], center_xy_mm=[C])
    dRdD, dRdT = 0.5 * (1 + cte * (T - 20)), 0.5 * D20 * cte
    typeB = (
        np.outer(sens["dR"], sens["dR"]) * (dRdD**2 * 0.00075**2 + dRdT**2 * aT**2 / 3)
        + sum(np.outer(s_, s_) for s_ in sens["offset_prior"]["A"].T) * (a_pos**2 * 2 / 3)
        + sens["reading_offset"] @ sens["reading_offset"].T * a_lin**2 / 3
    )
    draws = []
    for _ in range(150):
        Dg = D20 + 0.00075 * rng.standard_normal()
        Tm = T + rng.uniform(-aT, aT)  # the recorded temperature's error
        Rm = 0.5 * Dg * (1 + cte * (Tm - 20))
        e = rng.uniform(-a_lin, a_lin, 3)
        dS, dC = rng.uniform(-a_pos, a_pos, 2), rng.uniform(-a_pos, a_pos, 2)
        draws.append(fit(Rm, v + e, S + dS, C + dC).params)
    sd_mc = np.std(np.array(draws), axis=0, ddof=1)
    sd_lin = np.sqrt(np.diag(typeB))
    u_all = np.sqrt(np.diag(cal.cov) + np.diag(typeB))
    big = sd_lin > 0.1 * u_all
    assert big[2::3].all()  # every d_b (the gauge and the linearity move it one to one)
    ratio = sd_mc[big] / sd_lin[big]
    assert np.all(np.abs(ratio - 1) < 0.2), ratio
    # and the small parts are small in the refits too
    assert np.all(sd_mc[~big] <= 0.2 * u_all[~big] + 1e-12), (sd_mc[~big], u_all[~big])  # held beta_1: 0
