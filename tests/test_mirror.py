"""The mirror check of a three-sensor calibration (issue 36): Eq. (1) of borescan.mirror against exact
readings, the offset that resolves a mirror, the bore range where a flagged calibration may be used, and a
fit on a simulated scan with one beam resolved by its mirror's depth, one flagged and one without a mirror.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from borescan.calibrate.full_fit import fit_full_calibration
from borescan.calibrate.mirror_search import MIRROR_CLEAR_DCHI2
from borescan.synthetic import scenes, simulate
from borescan.geometry import Beams
from borescan.mirror import (
    MirrorSolution,
    RESOLVED_DCHI2,
    BeamMirror,
    mirror_checks_of,
    mixture_components,
    offset_to_resolve_mm,
    predicted_depth,
    valid_bore_radius_range_mm,
)

R_MM = 137.5


def _scene(rho_mm, e_mm, rate_hz=660.0):
    beams = Beams(
        (1, 2, 3), np.array([0.3, 2.4, 4.3]), np.asarray(rho_mm, float), np.array([128.0, 129.0, 130.0])
    )
    return scenes.TriScene(
        beams=beams,
        bore_center_xy_mm=(0.0, 0.0),
        bore_radius_20_mm=R_MM,
        spindle_xy_mm=(e_mm, 0.0),
        sample_rate_hz=rate_hz,
        range_mm=(20.0, 20.0, 20.0),
    )


@pytest.mark.parametrize("rho_mm", [3.0, 5.0, 8.0])
def test_depth_formula_is_the_mirror_misfit_of_exact_readings(rho_mm):
    """The mirror (rho -> -rho, beta -> beta + 2 asin(rho / R), d_b kept) of exact readings differs from
    them by sum (dv)^2 / sigma^2 = N e^4 rho^2 / (2 sigma^2 R^4) to first order in e / R and rho / R:
    within 1.5 % here (e / R = 0.7 %, rho / R <= 6 %); the refit of the other parameters only lowers it.
    """
    e, sigma = 1.0, 0.002
    scene = _scene([rho_mm, -3.0, 1.0], e)
    b = scene.beams
    mirror = Beams(
        b.channels,
        b.beta_rad + np.array([2 * math.asin(rho_mm / R_MM), 0, 0]),
        b.rho_mm * [-1, 1, 1],
        b.d_b_mm,
    )
    t = np.arange(6600) / 660.0
    dv = scenes.tri_readings(replace(scene, beams=mirror), t)[:, 0] - scenes.tri_readings(scene, t)[:, 0]
    exact = float(np.sum(dv**2) / sigma**2)
    assert predicted_depth([6600], [e], rho_mm, [sigma], R_MM) == pytest.approx(exact, rel=0.015)


def test_offset_to_resolve_puts_the_mirror_at_k():
    """X = L (2 K sigma^2 / (N rho^2))^(1/4) is Eq. (1) solved for e: the depth there is K; Yang's ring
    (R 137.5 mm, sigma 2 um, N 16 000) with its smallest rho, 1.526 mm (Yang Table 1), needs about 1.2 mm (the
    issue's figure); X scales as rho^(-1/2).
    """
    x = offset_to_resolve_mm(R_MM, 0.002, 16000, 1.5262)
    assert predicted_depth([16000], [x], 1.5262, [0.002], R_MM) == pytest.approx(RESOLVED_DCHI2, rel=1e-12)
    assert 1.15 < x < 1.25
    assert predicted_depth([8000, 8000], [x, x], 1.5262, [0.002, 0.002], R_MM) == pytest.approx(
        RESOLVED_DCHI2, rel=1e-12
    )
    assert offset_to_resolve_mm(R_MM, 0.002, 16000, 4 * 1.5262) == pytest.approx(x / 2, rel=1e-12)


def test_valid_bore_range_is_where_the_solutions_turn_apart_by_two_u():
    """A mirror of beam 1 (rho 5 mm) agrees with the main solution at the gauge; at the range's ends the
    relative direction of beam 1 moves by 2 u(beta) between them: 2 rho |1/L - 1/L_cal| = 2 u.
    """
    rho, u = 5.0, 0.01
    main = np.array([0.3, rho, 128.0, 2.4, -3.0, 129.0, 4.3, 1.0, 130.0])
    alt = main.copy()
    alt[0] += 2 * math.asin(rho / R_MM)
    alt[1] = -rho
    lo, hi = valid_bore_radius_range_mm(R_MM, main, alt, u)
    # small-angle form: 1/L = 1/L_cal +- u / rho (the grid's step in 1/L is 1e-3 / L_cal)
    assert 1.0 / lo == pytest.approx(1.0 / R_MM + u / rho, rel=2e-3)
    assert 1.0 / hi == pytest.approx(1.0 / R_MM - u / rho, rel=2e-3)
    lo2, hi2 = valid_bore_radius_range_mm(R_MM, main, alt, 1.0)
    assert hi2 == math.inf and lo2 < R_MM / 2


def test_mixture_weights_are_normalised_likelihood_ratios():
    alt = {"params": tuple(range(9)), "cov": tuple(tuple(0.0 for _ in range(9)) for _ in range(9))}
    from borescan.mirror import MirrorSolution

    checks = [
        BeamMirror(
            1, 5.0, 1.0, True, 3.0, 2.0, False, 0.0, 0.0, 1.0, MirrorSolution(**alt, delta_chi2=2.0, weight=0)
        ),
        BeamMirror(2, 1.0, 1.0, False, 0.1, None, True, 1.0, 0.0, 3.0),
        BeamMirror(
            3, 4.0, 1.0, True, 4.0, 6.0, False, 0.0, 0.0, 1.0, MirrorSolution(**alt, delta_chi2=6.0, weight=0)
        ),
    ]
    comps = mixture_components(np.zeros(9), np.eye(9), checks)
    raw = np.array([1.0, math.exp(-1.0), math.exp(-3.0)])
    assert [w for w, _, _ in comps] == pytest.approx(list(raw / raw.sum()), rel=1e-12)
    assert BeamMirror.from_dict(checks[0].to_dict()) == checks[0]


def test_one_rule_says_whether_the_scan_determines_the_sign():
    """A mirror possible at the fit and its depth < 25 (the refit's where it found a separate minimum, else
    Eq. (1)): not determined, flagged with two solutions or in one valley; otherwise determined.
    """
    alt = MirrorSolution((0.0,) * 9, tuple((0.0,) * 9 for _ in range(9)), 4.0, 0.1)

    def beam(possible, predicted, refit, resolved):
        return BeamMirror(
            1, 5.0, 1.0, possible, predicted, refit, resolved, 1.0, 0.0, 2.0, None if resolved else alt
        )

    cases = [
        (beam(False, 3.0, None, True), True, False),  # no mirror (|rho| <= sqrt(2) e)
        (beam(True, 30.0, None, True), True, False),  # predicted >= 25, no separate minimum
        (beam(True, 10.0, 40.0, True), True, False),  # the refit found it 40 above: the refit decides
        (beam(True, 30.0, 4.0, False), False, False),  # a separate minimum 4 above: two solutions
        (beam(True, 10.0, None, True), False, True),  # predicted 10, the refit slid back: one valley
    ]
    for m, determined, valley in cases:
        assert (m.sign_determined, m.one_valley) == (determined, valley), m
        d = m.to_dict()
        assert (d["sign_determined"], d["one_valley"]) == (determined, valley)
        assert BeamMirror.from_dict(d) == m
    assert "one valley through both signs" in cases[4][0].statement()
    assert "not determined by this scan" in cases[4][0].statement()


def test_the_fix_respects_the_sensors_range():
    """The advice names the offset X only where the range allows it; else the samples that would resolve the
    sign at the largest allowed offset (Eq. (1) at 25 there), or the offsets at which no mirror exists.
    """
    from borescan.plan import samples_to_resolve

    L, sigma, n, rho = 500.0, 0.004, 4000.0, 8.0
    x = offset_to_resolve_mm(L, sigma, n, rho)  # 3.74 mm
    alt = MirrorSolution((0.0,) * 9, tuple((0.0,) * 9 for _ in range(9)), 4.0, 0.1)

    def beam(limit, rho_mm=rho):
        n_fix = samples_to_resolve(L, sigma, limit, rho_mm) if limit is not None else None
        return BeamMirror(
            1,
            rho_mm,
            1.0,
            True,
            4.0,
            4.0,
            False,
            0.9,
            0.1,
            x,
            alt,
            -rho_mm,
            (900.0, 1100.0),
            offset_limit_mm=limit,
            samples_to_resolve=n_fix,
        )

    assert (
        beam(None).fix() == f"a spindle offset of at least {x:.2f} mm from the gauge centre would resolve it"
    )
    inside = beam(5.0)
    assert f"at least {x:.2f} mm" in inside.fix() and "allows up to 5.00 mm" in inside.fix()
    short = beam(2.5)  # 5 mm sensors at mid-range: the offset X is out of reach
    n_fix = short.samples_to_resolve
    assert predicted_depth([n_fix], [2.5], rho, [sigma], L) == pytest.approx(RESOLVED_DCHI2, rel=1e-12)
    text = short.fix()
    assert text.startswith("no spindle offset the sensors' range allows resolves it")
    assert f"needs {x:.2f} mm and the range allows 2.50 mm" in text
    assert f"take {math.ceil(n_fix)} samples per channel" in text and "longer-range sensor" in text
    assert text in short.statement()
    assert BeamMirror.from_dict(short.to_dict()) == short
    # a beam with |rho| <= sqrt(2) e at the largest offset has no mirror there: the advice is that band
    small = beam(2.5, rho_mm=3.0)
    assert small.fix().startswith(f"a spindle offset between {3.0 / math.sqrt(2.0):.2f} and 2.50 mm")


@pytest.fixture(scope="module")
def flagged_fit():
    """Commanded angle, no positions, 5 revolutions of 660 samples, sigma 2 um, e = 1 mm: beam 1 (rho 20 mm,
    depth ~460) resolved by its mirror's depth, beam 2 (rho -3 mm, depth ~10) flagged, beam 3 (rho 0.5 mm <
    sqrt(2) e) without a mirror.
    """
    scene = _scene([20.0, -3.0, 0.5], 1.0)
    t = np.arange(3300) / 660.0
    v = scenes.tri_readings(scene, t)
    y = v + 0.002 * np.random.default_rng(11).standard_normal(v.shape)
    cal = fit_full_calibration(t, y, (1, 2, 3), scene.beams, R_MM, rpm=60.0, range_mm=20.0, scan_ids=["MIR"])
    return scene, cal


def test_fit_flags_only_the_beam_whose_mirror_is_shallow(flagged_fit):
    scene, cal = flagged_fit
    m1, m2, m3 = mirror_checks_of(cal.diagnostics)
    # beam 1: a mirror, deep: resolved without the refit from -rho (issue 38), its predicted depth and the
    # unrefitted mirror start both far above; the start within its noise of Eq. (1) (the formula is the
    # start's second-harmonic difference to first order; the noise moves it by 2 sqrt(depth) sd)
    assert m1.resolved and m1.refit_delta_chi2 is None and not m1.refitted
    assert min(m1.predicted_delta_chi2, m1.start_delta_chi2) >= MIRROR_CLEAR_DCHI2
    assert (
        abs(m1.start_delta_chi2 - m1.predicted_delta_chi2)
        < 3 * 2 * math.sqrt(m1.predicted_delta_chi2) + 0.1 * m1.predicted_delta_chi2
    )
    assert "mirror predicted" in m1.statement() and "resolved" in m1.statement()
    assert {p["channel"]: "not_profiled" in p for p in cal.diagnostics["rho_profiles"]} == {
        1: True,
        2: True,
        3: True,
    }
    # beam 3: |rho| < sqrt(2) e: no mirror, the refit returned to the solution
    assert not m3.mirror_possible and m3.resolved and m3.refit_delta_chi2 is None
    assert [m.sign_determined for m in (m1, m2, m3)] == [True, False, True]
    # beam 2: flagged, two solutions of opposite sign; weights exp(-d/2) normalised; the truth in one of them
    assert not m2.resolved and m2.refit_delta_chi2 < RESOLVED_DCHI2
    assert np.sign(m2.rho_alt_mm) == -np.sign(m2.rho_mm)
    w = math.exp(-0.5 * m2.refit_delta_chi2)
    assert m2.p_wrong_sign == pytest.approx(w / (1 + w), rel=1e-12)
    assert m2.valid_bore_diameter_mm[0] <= 2 * R_MM <= m2.valid_bore_diameter_mm[1]
    alt = m2.alternative
    z_main = abs(cal.beams.rho_mm[1] - scene.beams.rho_mm[1]) / cal.u_rho_mm[1]
    z_alt = abs(alt.params[4] - scene.beams.rho_mm[1]) / math.sqrt(alt.cov[4][4])
    assert min(z_main, z_alt) < 4.0
    assert "the sign of rho of channel 2 is not determined by this scan" in m2.statement()


def test_the_refit_of_a_deep_mirror_changes_nothing(flagged_fit, monkeypatch):
    """The same scan with every mirror refitted (the check's threshold for skipping it lifted): beam 1's
    refit lies within its noise of Eq. (1) (the refit of the other parameters takes 0-16 % of it, the noise
    moves it by 2 sqrt(depth) sd), far above 25, and every parameter and u is the one of the fit that
    skipped it (the optimizer's tolerance).
    """
    from borescan.calibrate import mirror_search

    scene, cal = flagged_fit
    monkeypatch.setattr(mirror_search, "MIRROR_CLEAR_DCHI2", math.inf)
    t = np.arange(3300) / 660.0
    y = scenes.tri_readings(scene, t) + 0.002 * np.random.default_rng(11).standard_normal((t.size, 3))
    full = fit_full_calibration(t, y, (1, 2, 3), scene.beams, R_MM, rpm=60.0, range_mm=20.0, scan_ids=["MIR"])
    m1 = mirror_checks_of(full.diagnostics)[0]
    assert m1.refitted and m1.resolved and m1.refit_delta_chi2 > MIRROR_CLEAR_DCHI2
    assert (
        abs(m1.refit_delta_chi2 - 0.92 * m1.predicted_delta_chi2)
        < 3 * 2 * math.sqrt(m1.predicted_delta_chi2) + 0.1 * m1.predicted_delta_chi2
    )
    u = np.sqrt(np.diag(cal.cov))
    held = u == 0
    assert np.all(np.abs(full.params - cal.params)[~held] <= 1e-4 * u[~held])
    np.testing.assert_allclose(np.sqrt(np.diag(full.cov)), u, rtol=1e-4)


def test_resolved_beams_keep_their_own_curvature(flagged_fit):
    """The covariance of the resolved beams 1 and 3 is the fit's own curvature at the solution, s^2 (J^T J)^-1
    mapped to (beta, rho, d_b), plus what their own rho profiles and d_b's second-order term add: nothing from
    beam 2's mirror (whose parameters shift the offset and beta_2 by many u).
    """
    from borescan.calibrate.problem import public_index
    from borescan.physics.tri_params import dbeta_drho_at_psi, dd_b_drho_at_g

    _, cal = flagged_fit
    c = 3
    idx = public_index(c, 0)
    ok = idx >= 0
    # internal (psi, rho, g, nuisance) -> public (beta, rho, d_b, nuisance), beta of channel 1 fixed
    rho = cal.fit.x[c - 1 : 2 * c - 1]
    A = np.eye(cal.fit.x.size)
    for j in range(c):
        A[2 * c - 1 + j, c - 1 + j] = dd_b_drho_at_g(rho, R_MM)[j]
        if j > 0:
            A[j - 1, c - 1 + j] = dbeta_drho_at_psi(rho, R_MM)[j]
    lin = A @ cal.fit.cov @ A.T
    expected = np.zeros((3 * c, 3 * c))
    expected[np.ix_(ok, ok)] = lin[np.ix_(idx[ok], idx[ok])]
    for prof in cal.diagnostics["rho_profiles"]:
        j = prof["channel"] - 1
        if prof["linear"]:
            expected[3 * j + 2, 3 * j + 2] += 3.0 * lin[idx[3 * j + 1], idx[3 * j + 1]] ** 2 / (4 * R_MM**2)
        elif "extra_cov_params" in prof:
            expected += np.asarray(prof["extra_cov_params"])
    m2 = mirror_checks_of(cal.diagnostics)[1]
    d = m2.alternative.params_array - cal.params
    assert (
        abs(d[7]) > 10 * cal.u_d_b_mm[2]
        or abs(d[6]) > 3 * cal.u_beta_rad[2]
        or abs(d[1]) > 3 * cal.u_rho_mm[0]
    )
    for j in (0, 2):
        blk = slice(3 * j, 3 * j + 3)
        np.testing.assert_allclose(cal.cov[blk, blk], expected[blk, blk], rtol=1e-9, atol=1e-30)


def test_mixture_diameter_against_the_mixture_in_closed_form():
    """Two solutions (weights 0.8 / 0.2, D 100.000 / 100.010 mm, u 2 um, the mirror's own fit adding
    (3 um)^2): mean, variance and the p-quantiles of the Gaussian mixture in closed form, within the Monte
    Carlo's error (10^6 draws: mean to 0.02 um, quantiles' CDF to 5e-4); the same seed gives the same
    numbers.
    """
    from scipy.optimize import brentq
    from scipy.stats import norm

    from borescan.mirror import mixture_diameter

    w, d, extra, u = np.array([0.8, 0.2]), np.array([100.0, 100.010]), np.array([0.0, 0.003**2]), 0.002
    mix = mixture_diameter(list(zip(w, d, extra)), 1.0, u, u, 0.95, seed=7)
    s = np.sqrt(u**2 + extra)
    mean = float(w @ d)
    var = float(w @ (s**2) + w @ (d - mean) ** 2)
    assert mix.diameter_mm == pytest.approx(mean, abs=2e-5)
    assert mix.u_mm == pytest.approx(math.sqrt(var), rel=2e-3)

    def cdf(x):
        return float(w @ norm.cdf((x - d) / s))

    assert cdf(mix.interval_mm[0]) == pytest.approx(0.025, abs=5e-4)
    assert cdf(mix.interval_mm[1]) == pytest.approx(0.975, abs=5e-4)
    lo = brentq(lambda x: cdf(x) - 0.025, 99.98, 100.03)
    assert mix.interval_mm[0] == pytest.approx(lo, abs=2e-4)
    assert mixture_diameter(list(zip(w, d, extra)), 1.0, u, u, 0.95, seed=7) == mix


def test_a_bore_outside_the_valid_range_is_refused_with_the_reason(flagged_fit):
    from borescan.mirror import refusal

    _, cal = flagged_fit
    checks = mirror_checks_of(cal.diagnostics)
    lo = checks[1].valid_bore_diameter_mm[0]
    assert refusal("S1", cal.calibration_id, 2 * R_MM, checks) is None
    why = refusal("S1", cal.calibration_id, 0.5 * lo, checks)
    assert why.startswith(f"S1: bore diameter {0.5 * lo:.3f} mm outside {lo:.1f} mm to ")
    assert "the sign of rho of channel 2 is not determined by its scan" in why


def test_a_flagged_beam_carries_the_offset_the_range_allows(flagged_fit):
    """The calibration gives an undetermined beam the largest offset its fitted beams and the sensors' range
    allow (:func:`borescan.plan.largest_offset_mm`, computed here independently), and its statement the fix.
    """
    from borescan.plan import DeviceDesign, largest_offset_mm

    _, cal = flagged_fit
    m1, m2, m3 = mirror_checks_of(cal.diagnostics)
    assert m1.offset_limit_mm is None and m3.offset_limit_mm is None  # determined: nothing to advise
    device = DeviceDesign(cal.beams, (0.002,) * 3, (20.0,) * 3)
    assert m2.offset_limit_mm == pytest.approx(largest_offset_mm(device, R_MM), abs=1e-6)
    assert m2.offset_to_resolve_mm < m2.offset_limit_mm  # 20 mm sensors: the offset X is allowed
    assert m2.fix() in m2.statement() and f"allows up to {m2.offset_limit_mm:.2f} mm" in m2.statement()


def test_calibration_rows_carry_each_beams_mirror_check(flagged_fit):
    from borescan.calibrations import calibration_rows

    _, cal = flagged_fit
    rows = {r["channel"]: r for r in calibration_rows(cal, "tri_lds", "2026-11-20", None, "f" * 64)}
    m = {x.channel: x for x in mirror_checks_of(cal.diagnostics)}
    assert rows[2]["rho_sign_resolved"] is False and rows[2]["p_wrong_sign"] == m[2].p_wrong_sign > 0
    assert rows[2]["valid_bore_min_mm"] <= 2 * R_MM
    assert rows[1]["rho_sign_resolved"] is True and rows[1]["p_wrong_sign"] == 0.0
    assert rows[1]["mirror_delta_chi2"] == m[1].refit_delta_chi2 and rows[3]["mirror_delta_chi2"] is None


def test_certificate_json_states_the_undetermined_sign_with_both_solutions(flagged_fit):
    from borescan.certificate import rho_sign_part

    _, cal = flagged_fit
    part = rho_sign_part(cal)
    b = {m["channel"]: m for m in part["beams"]}
    assert b[2]["statement"].startswith(
        "the sign of rho of channel 2 is not determined by this scan: two solutions"
    )
    alt = b[2]["alternative"]
    assert np.sign(alt["rho_mm"]) == -np.sign(b[2]["u_main"]["rho_mm"])
    assert alt["weight"] + b[2]["weight_main"] == pytest.approx(1.0, abs=1e-12)
    assert np.asarray(alt["covariance"]).shape == (9, 9) and "offset_to_resolve_mm" in b[2]
    assert b[1]["resolved"] and "alternative" not in b[1]


def test_report_lists_a_flagged_beam_with_what_to_do(flagged_fit):
    import polars as pl

    from borescan.calibrations import calibration_rows
    from borescan.report.section_calibration import _rho_sign_notes

    _, cal = flagged_fit
    html = _rho_sign_notes(pl.DataFrame(calibration_rows(cal, "tri_lds", "2026-11-20", None, "f" * 64)))
    m2 = mirror_checks_of(cal.diagnostics)[1]
    assert html.count("<li>") == 1 and "the sign of rho of channel 2 is not determined by its scan" in html
    assert f"at least {m2.offset_to_resolve_mm:.2f} mm from the gauge centre" in html
    assert f"the sensors&#x27; range allows up to {m2.offset_limit_mm:.2f} mm" in html  # the fix, escaped


@pytest.mark.parametrize("where", ["gauge", "beyond"])
def test_a_diameter_with_a_flagged_calibration_is_the_mixture_or_refused(flagged_fit, tmp_path, where):
    """A static scan (10 poses, sigma 2 um) of a bore measured with the flagged calibration: at the
    gauge's size the diameter is the two-solution Monte Carlo (JCGM 101) and its interval holds the true
    diameter; 10 % beyond the valid range's upper end (sensors of a range that reaches it) the measurement
    is refused with the reason.
    """
    from borescan import rawio
    from borescan.config import schema_defaults
    from borescan.measure import tri_diameter_with_budget

    scene, cal = flagged_fit
    lo, hi = mirror_checks_of(cal.diagnostics)[1].valid_bore_diameter_mm
    assert math.isfinite(hi)
    R = R_MM if where == "gauge" else 0.55 * hi
    reach = float(R - min(scene.beams.d_b_mm) + 10.0)
    st = replace(scene, bore_radius_20_mm=R, bore_center_xy_mm=(0.0, 0.0), range_mm=(reach,) * 3)
    art = {
        "id": "RG",
        "type": "ring_gauge",
        "nominal_diameter_mm": 2 * R,
        "certified_diameter_mm": 2 * R,
        "u_diameter_mm": 0.0,
        "k": 2,
        "cte_per_k": 0.0,
    }
    sim = simulate.simulate_tri_static(
        st, noise_mm=0.002, seed=3, artifact=art, scan_id="STAT1", extra_meta=None
    )
    scan = rawio.read_scan(simulate.write_simulated(sim, tmp_path / "raw", tmp_path / "truth"))
    unc = schema_defaults()["uncertainty"]
    if lo <= 2 * R <= hi:
        res, du = tri_diameter_with_budget(scan, cal, unc)
        mix = res["mirror_mixture"]
        assert du.combined_t.method.startswith("Monte Carlo (JCGM 101), 2-solution mixture")
        assert mix.weights[1] == pytest.approx(mirror_checks_of(cal.diagnostics)[1].p_wrong_sign, rel=1e-12)
        assert mix.interval_mm[0] <= 2 * R <= mix.interval_mm[1]
        assert du.combined_t.U >= du.combined_t.u * 1.9
    else:
        with pytest.raises(
            ValueError,
            match=r"^STAT1: bore diameter .* outside .* the sign of rho of channel 2 is "
            r"not determined",
        ):
            tri_diameter_with_budget(scan, cal, unc)


def test_small_probabilities_read_as_numbers_not_zero():
    """exp(-8.2) = 2.7e-4 reads "3e-4", not "0.000"; its complement "1 - 3e-4", not "1.000"; three
    decimals from 0.001 to 0.999; the statement of a flagged beam uses the same form.
    """
    from borescan.mirror import format_probability

    assert format_probability(math.exp(-8.2)) == "3e-4"
    assert format_probability(1.0 - math.exp(-8.2)) == "1 - 3e-4"
    assert format_probability(math.exp(-12.5)) == "4e-6"
    assert [format_probability(p) for p in (0.184, 0.001, 0.999, 0.0, 1.0)] == [
        "0.184",
        "0.001",
        "0.999",
        "0",
        "1",
    ]
    assert format_probability(float("nan")) == "n/a"
    m = BeamMirror.from_dict(
        dict(
            BeamMirror(2, 5.0, 1.0, True, 3.0, 8.2, False, 0.0, 0.0, 1.0).to_dict(),
            weight_main=1.0 - math.exp(-4.1),
            p_wrong_sign=math.exp(-4.1),
            refit_delta_chi2=8.2,
            rho_alt_mm=-5.0,
        )
    )
    assert "weight 0.017 = probability of the wrong sign" in m.statement()


def test_the_mirror_component_maps_its_covariance_through_its_own_derivatives(flagged_fit, tmp_path):
    """A static scan of a bore 3 mm larger than the gauge, measured with the flagged calibration: the
    mirror component's variance is dD/dp at the MIRROR's beams (central differences of D, an independent
    computation, against the exact form to 1e-6) through the mirror's covariance; the kept solution's dD/dp
    differs there.
    """
    from borescan import rawio
    from borescan.config import schema_defaults
    from borescan.measure import tri_diameter_with_budget

    scene, cal = flagged_fit
    m2 = mirror_checks_of(cal.diagnostics)[1]
    R = R_MM + 3.0
    assert m2.valid_bore_diameter_mm[0] <= 2 * R <= m2.valid_bore_diameter_mm[1]
    st = replace(scene, bore_radius_20_mm=R, bore_center_xy_mm=(0.0, 0.0), range_mm=(30.0,) * 3)
    art = {"id": "RG", "type": "ring_gauge", "nominal_diameter_mm": 2 * R, "certified_diameter_mm": 2 * R}
    art.update(u_diameter_mm=0.0, k=2, cte_per_k=0.0)
    sim = simulate.simulate_tri_static(st, noise_mm=0.002, seed=5, artifact=art, scan_id="STAT2")
    scan = rawio.read_scan(simulate.write_simulated(sim, tmp_path / "raw", tmp_path / "truth"))
    res, du = tri_diameter_with_budget(scan, cal, schema_defaults()["uncertainty"])
    mix, model = res["mirror_mixture"], res["model"]
    pa, cov_a = m2.alternative.params_array, m2.alternative.cov_array
    steps = np.tile([1e-6, 1e-4, 1e-4], 3)

    def d_of(p):
        return model(Beams(cal.beams.channels, p[0::3], p[1::3], p[2::3]))

    g = np.array([(d_of(pa + h * e) - d_of(pa - h * e)) / (2 * h) for h, e in zip(steps, np.eye(9))])
    from borescan.measure.tri import _jac_params_at

    np.testing.assert_allclose(
        _jac_params_at(model, Beams(cal.beams.channels, pa[0::3], pa[1::3], pa[2::3])),
        g,
        rtol=1e-6,
        atol=1e-7,
    )
    jp = np.asarray(res["jac_params"], float)
    cov_fit = np.asarray(cal.diagnostics.get("cov_fit", cal.cov), float)
    extra = max(float(g @ cov_a @ g) - float(jp @ cov_fit @ jp), 0.0)
    assert mix.u_components_mm[1] ** 2 == pytest.approx(mix.u_components_mm[0] ** 2 + extra, rel=1e-4)
    assert abs(float(jp @ cov_a @ jp) - float(g @ cov_a @ g)) > 1e-3 * float(g @ cov_a @ g)
