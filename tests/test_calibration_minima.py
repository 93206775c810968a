"""The full-data calibration never accepts a wrong minimum (issue 17, item 4).

Contract scans drawn by :func:`borescan.synthetic.battery.write_battery` (fixed seeds), calibrated by the
pipeline's own path. The accepted solution must be the global minimum of what the fit minimises,
SSR + prior penalty, as far as the truth can show it: the truth (in the fit's gauge) is a feasible
point, so the accepted cost can exceed its cost by no more than the optimizer's tolerance (the
sharp check); the issue's looser rule SSR_fit <= SSR_truth + sigma^2 sqrt(2 N) follows. Where the
cost valley along a rho is not the linear one (rho enters the readings mostly through rho^2), the
covariance must carry the valley's spread, and every distinct minimum found must be reported.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from borescan import rawio
from borescan.synthetic import battery, scenes, simulate
from borescan.config import schema_defaults
from borescan.geometry import Beams
from borescan.noise import noise_floor_mm
from borescan.stages.calibration_fit import fit_device_calibration, spindle_inputs


def _calibrate(tmp_path, seed: int, n: int, index: int):
    path = battery.write_battery(tmp_path, n, seed, only=[index])[0]
    scan = rawio.read_scan(path)
    truth = simulate.load_truth(tmp_path / "truth", scan.scan_id)
    cfg = schema_defaults()["calibration"]
    x = spindle_inputs(scan)
    nominal = Beams.from_nominal(scan.meta["device"]["nominal"]["beams"])
    cal = fit_device_calibration([scan], [x], nominal, cfg)
    return scan, truth, cfg, x, cal


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """``_calibrate`` once per (seed, n, index) in this module: seed 20270619 #8 takes about 90 s and two
    tests examine its calibration.
    """
    done = {}

    def get(seed: int, n: int, index: int):
        if (seed, n, index) not in done:
            done[seed, n, index] = _calibrate(tmp_path_factory.mktemp(f"cal{seed}-{index}"), seed, n, index)
        return done[seed, n, index]

    return get


def _cost_at_truth(truth, cfg, x) -> tuple[float, float, float]:
    """(SSR + prior penalty at the truth, its SSR, the fit's sigma^2) on the readings the fit saw.

    The truth with beta_1 moved to the fit's fixed value and the phase moved back by as much gives
    the same readings: it is a point of the fit's own parameter space.
    """
    scene = scenes.TriScene.from_dict(truth["scene"])
    ct = truth["contract"]
    y = x.readings_mm
    m = np.isfinite(y)
    v_true = scenes.tri_readings(scene, x.t_s)
    ssr = float(np.sum((y - v_true)[m] ** 2))
    sigma2 = float(np.mean(noise_floor_mm(y, order=4) ** 2))
    penalty = 0.0
    if ct["position_known"]:
        o_rep = np.subtract(ct["spindle_reported_xy_mm"], ct["center_reported_xy_mm"])
        o_true = np.subtract(ct["spindle_xy_mm"], ct["center_xy_mm"])
        u_o = float(cfg["position_accuracy_mm"]) * math.sqrt(2.0 / 3.0)
        penalty = sigma2 * float(np.sum((o_true - o_rep) ** 2)) / u_o**2
    return ssr + penalty, ssr, sigma2


def _z_channel(k: int, c: int, fixed: bool) -> int:
    """Return the channel index of row ``k`` of :func:`_z`.

    The rows are the betas of the free channels, then rho, then d_b.
    """
    nb = c - 1 if fixed else c
    if k < nb:
        return k + 1 if fixed else k
    return (k - nb) % c


def _z(cal, truth_beams: Beams) -> np.ndarray:
    dbeta = (cal.beams.beta_rad - truth_beams.beta_rad + np.pi) % (2 * np.pi) - np.pi
    cov = cal.cov
    if cal.diagnostics["beta_reference"] == "absolute":
        z_beta = dbeta / cal.u_beta_rad
    else:  # beta_c - beta_1, its variance from the covariance (beta_1 held: zero rows)
        z_beta = (dbeta[1:] - dbeta[0]) / np.sqrt(np.diag(cov)[3::3])
    return np.r_[
        z_beta,
        (cal.beams.rho_mm - truth_beams.rho_mm) / cal.u_rho_mm,
        (cal.beams.d_b_mm - truth_beams.d_b_mm) / cal.u_d_b_mm,
    ]


# seed 20270619 #8: a skewed rho valley (channel 2 comes out +5.2 mm against -6.07 mm, Delta chi^2 6.8 at the
# truth's rho on the profile): before the profile its beta z was -10.8 (u(beta) a third of the bound at
# the truth)
# seed 20270611 #3: encoder and positions known (absolute beta), one of the scans whose beta read low
# seed 20270611 #167: channel 3 comes out on its mirror (rho +7.30 mm, truth -7.29 mm), the other sign 3.9 s^2
# above; that minimum was taken as spanned by channel 2's profile and left out of u: z 9.2
@pytest.mark.slow
@pytest.mark.parametrize("seed,n,index", [(20270619, 9, 8), (20270611, 200, 3), (20270611, 200, 167)])
def test_accepted_solution_is_the_global_minimum_and_its_u_covers_the_valley(calibrated, seed, n, index):
    scan, truth, cfg, x, cal = calibrated(seed, n, index)
    d = cal.diagnostics
    cost_truth, ssr_truth, sigma2 = _cost_at_truth(truth, cfg, x)
    cost_fit = 2.0 * d["cost"]  # SSR + prior penalty at the accepted solution (least_squares' cost is half)
    n_obs = d["n_obs"]
    # sharp: the accepted minimum is not above the truth's cost (optimizer tolerance: 0.01 sigma^2)
    assert cost_fit <= cost_truth + 0.01 * sigma2, (cost_fit - cost_truth) / sigma2
    # the issue's rule on the readings' SSR alone
    ssr_fit = cal.residual_rms_mm**2 * n_obs
    assert ssr_fit <= ssr_truth + sigma2 * math.sqrt(2.0 * n_obs)
    # every minimum reported is above the one kept, and the count agrees with the list
    assert d["n_minima"] == 1 + len(d["minima"])
    assert all(m["delta_ssr_over_s2"] >= -0.01 for m in d["minima"])
    assert d["ambiguous_minima"] == any(m["delta_ssr_over_s2"] < 4.0 for m in d["minima"])
    # a mirror minimum the data cannot reject is not folded into one u (issue 36): its beam is flagged and
    # carries the two solutions, the mirror's refit delta chi^2 the one the minima list gives
    from borescan.mirror import mirror_checks_of

    checks = {m.channel: m for m in mirror_checks_of(d)}
    for m in d["minima"]:
        if m["source"].startswith("mirror start") and m["delta_ssr_over_s2"] < 4.0:
            other = [
                ch
                for ch, r, r0 in zip(cal.beams.channels, m["rho_mm"], cal.beams.rho_mm)
                if np.sign(r) != np.sign(r0)
            ]
            assert other and all(
                not checks[ch].resolved and checks[ch].refit_delta_chi2 <= m["delta_ssr_over_s2"] + 1e-9
                for ch in other
            )
    # the uncertainty is honest where the valley is not linear: every z of a resolved beam within 4.5 (a
    # skewed valley makes the truth's z larger than its profile-likelihood distance: sqrt(6.8) = 2.6 for
    # seed 20270619 #8); a flagged beam's truth within 4.5 u of one of its two solutions
    truth_beams = Beams.from_nominal(truth["contract"]["beams"])
    z = _z(cal, truth_beams)
    c = len(cal.beams.channels)
    fixed = cal.diagnostics["beta_reference"] != "absolute"
    flagged = [j for j, ch in enumerate(cal.beams.channels) if not checks[ch].resolved]
    nb = c - 1 if fixed else c  # a beta of the fixed reference's frame moves with that beam's sign too
    resolved_rows = [
        k
        for k in range(z.size)
        if _z_channel(k, c, fixed) not in flagged and not (fixed and k < nb and 0 in flagged)
    ]
    assert np.all(np.abs(z[resolved_rows]) < 4.5), np.round(z, 2)
    for j in flagged:
        alt = checks[cal.beams.channels[j]].alternative
        z_alt = abs(alt.params[3 * j + 1] - truth_beams.rho_mm[j]) / math.sqrt(alt.cov[3 * j + 1][3 * j + 1])
        assert min(abs(z[(c - 1 if fixed else c) + j]), z_alt) < 4.5
    # every rho's profile was checked at +-2 u, and a non-linear one was walked past the estimate on both
    # sides
    for prof, rho in zip(d["rho_profiles"], cal.beams.rho_mm):
        if not prof["linear"]:
            lo, hi = prof["rho_range_mm"]
            assert lo < rho < hi
    if (seed, index) == (20270619, 8):
        # the skewed valley of channel 2's rho is profiled, its walked range reaches the truth, and the
        # valley's spread is in the covariance: wider than the linear u at the estimate
        prof = {p["channel"]: p for p in d["rho_profiles"]}[2]
        rho_true = Beams.from_nominal(truth["contract"]["beams"]).rho_mm[1]
        lo, hi = prof["rho_range_mm"]
        assert not prof["linear"] and lo <= rho_true <= hi
        assert cal.u_rho_mm[1] > 1.2 * prof["u_rho_linear_mm"]
    if (seed, index) == (20270611, 167):
        # channel 3 comes out on its mirror (rho +7.30 mm, truth -7.29 mm), the other sign 3.9 s^2 above:
        # flagged, the truth's sign is the second solution's, whose weight is the stated probability of the
        # wrong sign
        m3 = checks[3]
        assert not m3.resolved and cal.beams.rho_mm[2] > 0 > truth["contract"]["beams"][2]["rho"]
        assert m3.rho_alt_mm < 0 and 0.05 < m3.p_wrong_sign < 0.5


@pytest.mark.slow
def test_a_diameter_maps_a_non_linear_rho_profile_by_itself_not_by_its_linear_sensitivities(calibrated):
    """Seed 20270619 #8 (channel 2's rho profiled: its mirror is predicted within 25 and the refit from -rho
    finds no separate minimum, one valley through both signs). The calibration's covariance is its budget's
    fit terms summed (readings, positions, second order, profiles, mirrors: nothing lost or counted
    twice). A bore of about the gauge's size measured with it: along a profile (every other parameter
    refitted) the beams move together and D hardly moves, so the diameter's profile term is D's own
    weighted spread at the profile's points beyond its linear part, computed here independently by
    the static solve at each point's beams; mapped by the linear sensitivities instead, the same term
    is hundreds of times larger (the over-coverage of issue 19's coverage study: z SD 0.28 on such
    chains).
    """
    from borescan.calibrate.budget import calibration_budget
    from borescan.artifacts import artifact_cte, scan_temperature
    from borescan.geometry import Bore, tri_static_readings
    from borescan.measure import (
        DiameterModel,
        diameter_uncertainty,
        static_diameter,
        static_diameter_jacobian,
    )
    from borescan.measure.rotating import _with_params

    scan, truth, cfg, x, cal = calibrated(20270619, 9, 8)
    unc = schema_defaults()["uncertainty"]
    b = calibration_budget(cal, [x], unc, scan_ids=[scan.scan_id])
    fit_cov = sum(t.covariance() for t in b.terms if t.input.key.startswith(("fit:", "position:")))
    scale = np.sqrt(np.diag(cal.cov))
    scale[scale == 0] = 1.0  # the gauge-fixed beta
    # to 1e-3 of each variance: the fit's covariance and the budget's linear part (implicit
    # differentiation of the normal equations) come by two computations that agree to about 3e-4
    assert np.max(np.abs(fit_cov - cal.cov) / np.outer(scale, scale)) < 1e-3
    profiles = [p for p in cal.diagnostics["rho_profiles"] if "points" in p]
    from borescan.mirror import mirror_checks_of

    m2 = mirror_checks_of(cal.diagnostics)[1]  # one valley through both signs: the sign not determined
    assert m2.one_valley and not m2.sign_determined and "one valley" in m2.statement()
    assert [p["channel"] for p in profiles] == [2] and all(
        f"fit:{cal.calibration_id}:profile{p['channel']}" in {t.input.key for t in b.terms} for p in profiles
    )

    R = float(x.radius_mm)
    xy = np.array([[0.4, -0.3], [-0.6, 0.2], [0.1, 0.7], [-0.2, -0.5]])
    ang = np.array([0.3, 1.9, 3.4, 5.0])
    v = tri_static_readings(xy, ang, cal.beams, Bore((0.0, 0.0), R + 0.05))
    model = DiameterModel("static", v)
    _, jp, jv, _ = static_diameter_jacobian(v, cal.beams)
    j = jp.mean(axis=0)
    du = diameter_uncertainty(
        model(cal.beams),
        jac_params=j,
        calibration_budget=b,
        jac_readings=jv.mean(axis=0),
        u_readings_mm=1e-4,
        dof_readings=float("inf"),
        temperature=scan_temperature(scan.meta, unc),
        cte=artifact_cte(scan.meta, unc),
        artifact=dict(scan.meta["artifact"]),
        scan_id="PART",
        p=0.9545,
        default_resolution_mm=1e-4,
        calibration_id=cal.calibration_id,
        model=model,
        beams=cal.beams,
        rho_profiles=cal.diagnostics["rho_profiles"],
    )
    rows = {r["key"]: r for r in du.rows_t}
    d0 = float(
        np.mean(static_diameter(v, cal.beams).diameter_mm)
    )  # the mean of the poses, as the measure stage
    for p in profiles:
        key = f"fit:{cal.calibration_id}:profile{p['channel']}"
        pts = np.asarray(p["points"]["delta_params"])
        w = np.asarray(p["points"]["weight"])
        dD = np.array([np.mean(static_diameter(v, _with_params(cal.beams, d)).diameter_mm) - d0 for d in pts])
        lin = (j @ np.asarray(p["linear_cov_column"])) ** 2 / p["u_rho_linear_mm"] ** 2
        expected = math.sqrt(max(float(np.sum(w * dD**2)) - lin, 0.0))
        assert rows[key]["contribution"] == pytest.approx(expected, rel=1e-6, abs=1e-9)
        assert expected < 1e-3  # under a micrometre along a walk of several mm in rho
        linear_mapping = math.sqrt(float(j @ np.asarray(p["extra_cov_params"]) @ j))
        assert linear_mapping > 100 * max(expected, 1e-6)


# seed 20270611: #0 (161 760 readings, every rho clear of 0 and its mirror far above: no refit), #18 (116 400
# readings, rho of channels 2 and 3 not told from 0), #187 (114 608 readings, channel 3 weak)
@pytest.mark.slow
@pytest.mark.parametrize("index", [0, 18, 187])
def test_the_mirror_triage_keeps_what_the_full_search_finds(tmp_path, monkeypatch, index):
    """The search refits a beam's mirror only where the triage cannot set it aside (no mirror possible, or its
    predicted depth and unrefitted start both >= MIRROR_CLEAR_DCHI2). Against the search that refits every
    mirror: the same solution (each parameter within 1e-4 of its u), the same u (1e-4), the same verdict per
    beam, and every minimum within Delta chi^2 < 25 of the full search found by the triaged one (within
    0.05 u(rho)); a beam set aside has its full search's refit at least 25 above or no separate minimum.
    """
    from borescan.calibrate import mirror_search
    from borescan.mirror import mirror_checks_of

    *_, triaged = _calibrate(tmp_path / "a", 20270611, 200, index)
    monkeypatch.setattr(mirror_search, "MIRROR_CLEAR_DCHI2", math.inf)
    *_, full = _calibrate(tmp_path / "b", 20270611, 200, index)
    u_t = np.r_[triaged.u_beta_rad, triaged.u_rho_mm, triaged.u_d_b_mm]
    u_f = np.r_[full.u_beta_rad, full.u_rho_mm, full.u_d_b_mm]
    p_t = np.r_[triaged.beams.beta_rad, triaged.beams.rho_mm, triaged.beams.d_b_mm]
    p_f = np.r_[full.beams.beta_rad, full.beams.rho_mm, full.beams.d_b_mm]
    held = u_f == 0  # the gauge-fixed beta
    assert np.all(np.abs(p_t - p_f)[~held] <= 1e-4 * u_f[~held])
    assert np.allclose(u_t, u_f, rtol=1e-4, atol=0.0), np.max(np.abs(u_t / np.where(u_f > 0, u_f, 1) - 1))
    m_t, m_f = mirror_checks_of(triaged.diagnostics), mirror_checks_of(full.diagnostics)
    assert [m.resolved for m in m_t] == [m.resolved for m in m_f]
    for a, b in zip(m_t, m_f):
        if not a.refitted:
            assert b.refit_delta_chi2 is None or b.refit_delta_chi2 >= 25.0
    for m in full.diagnostics["minima"]:
        if m["delta_ssr_over_s2"] < 25.0:
            assert any(
                np.all(np.abs(np.subtract(m["rho_mm"], o["rho_mm"])) <= 0.05 * u_f[3:6])
                for o in triaged.diagnostics["minima"]
            ), m
    if index == 0:
        assert not any(m.refitted for m in m_t)


def test_profiles_excess_is_the_largest_per_parameter_not_the_sum():
    """Three PSD excesses sharing parameters: the parts stay PSD, add up to a PSD total whose diagonal is
    each parameter's largest single excess, and keep the sum's correlations.
    """
    from borescan.calibrate.profiles import _largest_per_parameter

    rng = np.random.default_rng(7)
    parts = []
    for _ in range(3):
        a = rng.normal(size=(6, 2))
        parts.append(a @ a.T)
    parts[2][:, 5] = parts[2][5, :] = 0.0  # a parameter one profile leaves alone
    out = _largest_per_parameter(parts)
    total = sum(out)
    top = np.max([np.diag(e) for e in parts], axis=0)
    np.testing.assert_allclose(np.diag(total), top, rtol=1e-12)
    assert np.all(np.diag(total) < np.diag(sum(parts)))
    for e in out + [total]:
        assert np.min(np.linalg.eigvalsh(e)) > -1e-12 * np.max(np.diag(total))
    s_ = sum(parts)
    corr = lambda m: m / np.sqrt(np.outer(np.diag(m), np.diag(m)))  # noqa: E731
    np.testing.assert_allclose(corr(total), corr(s_), rtol=1e-10, atol=1e-12)
    assert _largest_per_parameter([]) == []
