"""Signal stage: filters against closed forms, spikes, period, sub-sample extrema, Yang §2.3 statuses.

Simulated scans use the exact forward model (geometry.tri_spindle_readings) with Yang 2017's
Table 1 beams, P1/P0 of §3.1 and the 275.029 mm gauge; ground truth for extremum positions is
the continuous optimum of the same model (scipy minimize_scalar).
"""

import math

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from borescan.geometry import Beams, Bore, tri_spindle_readings
from borescan.signal import (
    beam_status,
    filter_performance,
    filter_readings,
    find_extrema,
    find_revolutions,
    fit_extremum_cubic,
    gaussian_filter_upr,
    gaussian_transmission,
    kalman_filter,
    median_filter,
    moving_average,
    n_m_counts,
    period_from_encoder,
    period_from_readings,
    process_scan,
    process_arrays,
    remove_spikes,
    theta_t_rad,
)

SPINDLE = np.array([262.955, -275.502])
CENTER = (262.833, -273.182)
R_GAUGE = 275.029 / 2
N_REV = 660  # samples per revolution of the simulated 60 rpm scans (f_s = 660 Hz)


def _beams(rho=(5.5484, -2.5295, 1.5262)):
    return Beams(
        (1, 2, 3),
        np.array([0.3, 2.4, 4.5]),
        np.array(rho, dtype=float),
        np.array([132.6718, 132.8883, 134.1108]),
    )


def _simulate(
    n_rev=40,
    spr=N_REV,
    eps=0.0,
    noise_mm=0.0025,
    seed=0,
    rho=(5.5484, -2.5295, 1.5262),
    lobes=(),
    direction=+1,
    phi0=0.4,
):
    """Return readings (n, 3), the device angle per sample and the scene."""
    beams = _beams(rho)
    bore = Bore(CENTER, R_GAUGE, lobes=tuple(lobes))
    k = np.arange(int(n_rev * spr))
    phi = phi0 + direction * 2 * np.pi * (1 + eps) * k / spr
    truth = tri_spindle_readings(phi, SPINDLE, beams, bore)
    rng = np.random.default_rng(seed)
    return truth + rng.normal(0.0, noise_mm, truth.shape), truth, phi, beams, bore


def _true_extrema_phi(beams, bore, ch, kind):
    """Device angle of channel ch's extremum (continuous optimum of the exact model)."""
    sign = 1.0 if kind == "min" else -1.0
    grid = np.linspace(0, 2 * np.pi, 3601)
    v = tri_spindle_readings(grid, SPINDLE, beams, bore)[:, ch]
    g = grid[np.argmin(sign * v)]
    res = minimize_scalar(
        lambda p: sign * tri_spindle_readings(np.array([p]), SPINDLE, beams, bore)[0, ch],
        bounds=(g - 0.01, g + 0.01),
        method="bounded",
        options={"xatol": 1e-12},
    )
    return res.x


def _truth_positions(beams, bore, ch, kind, n_samples, spr, eps=0.0, direction=+1, phi0=0.4):
    """All true sample positions of an extremum in a scan (phi = phi0 + dir 2 pi (1+eps) k / spr)."""
    pe = _true_extrema_phi(beams, bore, ch, kind)
    step = 2 * np.pi * (1 + eps) / spr
    r = np.arange(-2, n_samples / spr + 3)
    k = (direction * (pe + 2 * np.pi * r) - phi0) / step
    return np.sort(k[(k > 0) & (k < n_samples - 1)])


# --------------------------------------------------------------------------- filters


def test_gaussian_transmission_is_half_at_cutoff_and_matches_closed_form_on_sinusoids():
    assert gaussian_transmission(50.0, 50.0) == pytest.approx(0.5, abs=1e-15)
    spr, n_rev = 660, 5
    k = np.arange(spr * n_rev)
    for f_upr in (1, 7, 50, 120):
        y = np.cos(2 * np.pi * f_upr * k / spr + 0.3)
        out = gaussian_filter_upr(y, cutoff_upr=50.0, samples_per_rev=spr)
        h = math.exp(-math.pi * (math.sqrt(math.log(2) / math.pi) * f_upr / 50.0) ** 2)
        assert np.max(np.abs(out - h * y)) < 1e-12


def test_moving_average_gain_on_sinusoid_matches_closed_form():
    spr, w = 660, 25
    k = np.arange(spr * 3)
    y = np.cos(2 * np.pi * k / spr)
    out = moving_average(y, w)
    gain = math.sin(math.pi * w / spr) / (w * math.sin(math.pi / spr))
    inner = slice(w, -w)
    assert np.max(np.abs(out[inner] - gain * y[inner])) < 1e-12
    # the causal (trailing) window delays by (w - 1) / 2 samples exactly
    yc = moving_average(y, w, causal=True)
    shifted = gain * np.cos(2 * np.pi * (k - (w - 1) / 2) / spr)
    assert np.max(np.abs(yc[inner] - shifted[inner])) < 1e-12


@pytest.mark.parametrize(
    "method,params",
    [
        ("median", {"window_samples": 7}),
        ("moving_average", {"window_samples": 9}),
        ("kalman", {"model": "random_walk", "q_mm2": 1e-6}),
        ("kalman", {"model": "constant_velocity", "q_mm2": 1e-9}),
        ("gaussian", {"cutoff_upr": 50.0}),
    ],
)
def test_filters_never_bridge_gaps(method, params):
    y, *_ = _simulate(n_rev=3)
    y = y[:, :2].copy()
    y[100:130, 0] = np.nan
    y[700, 1] = np.nan
    out = filter_readings(y, method=method, samples_per_rev=N_REV, **params)
    assert np.array_equal(np.isnan(out), np.isnan(y))
    # and they do smooth: scatter about truth goes down or stays (median on steep flanks)
    _, truth, *_ = _simulate(n_rev=3)
    ok = ~np.isnan(y)
    rms_out = np.sqrt(np.mean((out - truth[:, :2])[ok] ** 2))
    assert rms_out < 1.05 * np.sqrt(np.mean((y - truth[:, :2])[ok] ** 2))


@pytest.mark.parametrize("w", [5, 7])
def test_median_filter_near_nulls_is_the_median_of_the_valid_neighbours(w):
    """Windows that touch a null take the median of their valid samples only (even count: mean of
    the middle two), the ends padded with the edge sample; checked against np.nanmedian per window.
    """
    rng = np.random.default_rng(11)
    y = rng.normal(5.0, 0.01, (400, 2))
    y[[0, 3, 4, 50, 51, 52, 53, 54, 55, 56, 200, 399], 0] = np.nan  # runs longer than a window too
    y[[1, 2, 120, 122, 124, 398], 1] = np.nan
    out = median_filter(y, w)
    h = w // 2
    for j in range(2):
        col = y[:, j]
        padded = np.concatenate([np.full(h, col[0]), col, np.full(h, col[-1])])
        for k in range(col.size):
            win = padded[k : k + w]
            if np.isnan(col[k]):
                assert np.isnan(out[k, j])
            elif np.isnan(win).any():
                assert out[k, j] == np.nanmedian(win), (j, k)
            else:
                assert out[k, j] == np.median(win), (j, k)


def test_unknown_filter_names_the_valid_ones():
    with pytest.raises(ValueError, match="valid: none, median, moving_average, kalman, gaussian"):
        filter_readings(np.zeros(10), method="butterworth")
    with pytest.raises(ValueError, match="valid: 'random_walk', 'constant_velocity'"):
        kalman_filter(np.zeros(10), model="singer")
    with pytest.raises(ValueError, match="odd"):
        median_filter(np.zeros(10), 4)


def test_random_walk_kalman_on_constant_converges_to_mean():
    """Random-walk Kalman with q = 0 is the running mean; the RTS smoother gives the overall mean."""
    rng = np.random.default_rng(3)
    y = 4.9685 + rng.normal(0, 0.0025, 500)
    f = kalman_filter(y, q_mm2=0.0, r_mm2=0.0025**2, smooth=False)
    # with the prior P0 = r at the first reading, x_k = mean(y[0..k]) (first reading counted twice)
    expect = (np.cumsum(y) + y[0]) / (np.arange(1, 501) + 1)
    assert np.max(np.abs(f - expect)) < 1e-12
    s = kalman_filter(y, q_mm2=0.0, r_mm2=0.0025**2, smooth=True)
    assert np.max(np.abs(s - expect[-1])) < 1e-12


def test_zero_phase_filters_leave_extremum_unbiased_causal_ones_shift_it():
    tab = filter_performance(revolutions=8, seed=1).to_dicts()
    by = {r["filter"]: r for r in tab}
    # paper §4: ~15 um beat raw; a smoothed constant-velocity Kalman brings it to ~3 um or below
    assert 12.0 < by["raw"]["beat_um"] < 17.0
    assert by["kalman cv smoothed q=1e-9"]["beat_um"] < 3.5
    for name in ("moving average 25", "gaussian 50 UPR", "kalman cv smoothed q=1e-9", "median 5"):
        assert abs(by[name]["lag_samples"]) < 0.02, name  # 1-UPR phase: zero within noise
        assert abs(by[name]["min_shift_samples"]) < 0.15, name  # minimum position: u ~ 0.06 per rev, 6 revs
    # causal moving average: delay (w - 1) / 2 = 12 samples exactly, on phase and on the minimum
    assert by["moving average 25 causal"]["lag_samples"] == pytest.approx(12.0, abs=0.02)
    assert by["moving average 25 causal"]["min_shift_samples"] == pytest.approx(12.0, abs=0.15)
    # amplitude loss of the centred moving average: A (1 - sin(pi w/N) / (w sin(pi/N)))
    amp = 0.5 * (np.ptp(_simulate(n_rev=1, noise_mm=0)[1][:, 0]))
    gain = math.sin(math.pi * 25 / N_REV) / (25 * math.sin(math.pi / N_REV))
    assert by["moving average 25"]["amplitude_loss_um"] == pytest.approx(amp * (1 - gain) * 1e3, abs=0.1)


# --------------------------------------------------------------------------- spikes and nulls


def test_spike_removal_counts_exactly_the_injected_spikes_and_nulls():
    y, truth, *_ = _simulate(n_rev=20, seed=5)
    rng = np.random.default_rng(7)
    n = y.shape[0]
    injected = {}
    nulls = {}
    for ch in range(3):
        pos = np.sort(rng.choice(np.arange(10, n - 10), size=25 + 10 * ch, replace=False))
        size = rng.uniform(0.04, 0.3, pos.size) * rng.choice([-1, 1], pos.size)
        y[pos, ch] += size
        injected[ch] = set(pos.tolist())
        free = np.setdiff1d(np.arange(n), pos)
        nz = rng.choice(free, size=40 + ch, replace=False)
        y[nz, ch] = np.nan
        nulls[ch] = nz.size
    cleaned, spikes = remove_spikes(y)
    for ch in range(3):
        assert set(np.flatnonzero(spikes[:, ch]).tolist()) == injected[ch]
    assert np.array_equal(np.isnan(cleaned), np.isnan(y) | spikes)
    res = process_arrays(y, sample_rate_hz=660.0, rpm_nominal=60.0, scan_id="S")
    sa = res.set_aside.sort("channel")
    assert sa["spikes"].to_list() == [len(injected[c]) for c in range(3)]
    assert sa["nulls"].to_list() == [nulls[c] for c in range(3)]


def _spikes_by_definition(y, w=7, threshold=6.0, cand=2.5):
    """remove_spikes' documented rule, one sample at a time (independent of the vectorised code).

    Short records only (fewer than 5000 samples, so every MAD runs over all samples it names).
    """
    n = y.size
    h = w // 2

    def mad(r):
        r = r[~np.isnan(r)]
        return 1.4826 * np.median(np.abs(r - np.median(r)))

    chord = np.full(n, np.nan)
    chord[1:-1] = y[1:-1] - 0.5 * (y[:-2] + y[2:])
    sc_c = mad(chord)
    with np.errstate(invalid="ignore"):
        excluded = ~(np.abs(chord) <= cand * sc_c)  # candidates, nulls, ends

    def reference(k):
        js = [j for j in range(-h, h + 1) if j and 0 <= k + j < n and not excluded[k + j]]
        if len(js) < 2:
            return np.nan
        slopes = [(y[k + b] - y[k + a]) / (b - a) for i, a in enumerate(js) for b in js[i + 1 :]]
        s = np.median(slopes)
        return np.median([y[k + j] - j * s for j in js])

    probes = [k for k in range(n) if not excluded[k]]
    scale = mad(np.array([y[k] - reference(k) for k in probes]))
    spikes = np.zeros(n, dtype=bool)
    for k in np.flatnonzero(excluded & ~np.isnan(y)):
        r = y[k] - reference(k)
        spikes[k] = bool(abs(r) > threshold * scale)
    return spikes


def test_spike_removal_equals_its_definition_sample_by_sample():
    """Near-threshold spikes, runs of two, nulls and spikes beside nulls: the vectorised test must
    flag exactly what the rule says, sample by sample.
    """
    y, *_ = _simulate(n_rev=4, seed=21)
    rng = np.random.default_rng(22)
    n = y.shape[0]
    for ch in range(3):
        pos = rng.choice(np.arange(3, n - 3), size=60, replace=False)
        y[pos, ch] += rng.uniform(0.010, 0.030, pos.size) * rng.choice([-1, 1], pos.size)  # 4-12 sigma
        y[pos[:5] + 1, ch] += 0.05  # a few pairs of neighbouring spikes
        y[rng.choice(n, 30, replace=False), ch] = np.nan
    _, spikes = remove_spikes(y)
    for ch in range(3):
        expected = _spikes_by_definition(y[:, ch])
        assert 20 < expected.sum() < 70  # the set really is near the threshold, not all-or-nothing
        np.testing.assert_array_equal(spikes[:, ch], expected)


# --------------------------------------------------------------------------- period


def test_period_from_readings_recovers_a_speed_error_and_flags_it():
    eps = 0.005
    y, *_ = _simulate(n_rev=30, eps=eps, seed=11, lobes=((2, 0.01, 0.3),))
    est = period_from_readings(y, samples_per_rev_guess=N_REV, rpm_nominal=60.0, sample_rate_hz=660.0)
    true_p = N_REV / (1 + eps)
    assert abs(est.samples_per_rev - true_p) < 3 * est.u_samples_per_rev
    assert est.u_samples_per_rev < 1e-3
    assert est.period_disagrees_with_nominal and est.samples_per_rev_nominal == pytest.approx(660.0)
    y0, *_ = _simulate(n_rev=30, eps=0.0, seed=12)
    est0 = period_from_readings(y0, samples_per_rev_guess=N_REV, rpm_nominal=60.0, sample_rate_hz=660.0)
    assert abs(est0.samples_per_rev - N_REV) < 3 * est0.u_samples_per_rev
    assert not est0.period_disagrees_with_nominal


def test_period_from_readings_with_few_samples_per_revolution_on_a_long_record():
    """20 samples/rev over 60 000 revolutions (1.2 M samples): the coarse FFT must not decimate the
    fundamental above Nyquist (its stride is limited to an eighth of the nominal period; a stride
    of n / 65 536 = 18 samples used to alias it and find no peak near the guess).
    """
    spr = 20
    y, *_ = _simulate(n_rev=60_000, spr=spr, eps=0.002, seed=13)
    est = period_from_readings(y, samples_per_rev_guess=spr, rpm_nominal=60.0, sample_rate_hz=20.0)
    true_p = spr / 1.002
    assert abs(est.samples_per_rev - true_p) < 3 * est.u_samples_per_rev
    assert est.period_disagrees_with_nominal


def test_find_revolutions_bisection_equals_floor_rule():
    """Monotonic coordinates take a bisection path; it must equal revolution = floor(u) row by row,
    exact integer hits and a non-monotonic (general path) coordinate included.
    """

    def by_floor(u, sample0):  # one row per run of equal floor(u), sample by sample
        rows = []
        for k, r in enumerate(np.floor(u).astype(int).tolist()):
            if rows and rows[-1][0] == r:
                rows[-1] = (r, rows[-1][1], k + sample0, rows[-1][3] + 1)
            else:
                rows.append((r, k + sample0, k + sample0, 1))
        return rows

    rng = np.random.default_rng(4)
    cases = [
        np.arange(5000) / 659.72,
        np.arange(1320) / 660.0 - 0.25,
        np.cumsum(rng.uniform(0, 0.01, 3000)) + 0.3,
        np.arange(1000) / 200.0 + rng.normal(0, 3e-3, 1000),
    ]
    assert not (np.diff(cases[-1]) >= 0).all()  # the last one exercises the general path
    for u in cases:
        tab = find_revolutions(u, 7)
        cols = ("revolution", "first_sample", "last_sample", "n_samples")
        got = list(zip(*(tab[c].to_list() for c in cols)))
        assert got == by_floor(u, 7)
        assert tab["complete"].to_list() == [0 < i < tab.height - 1 for i in range(tab.height)]


def test_period_from_encoder_and_revolution_index():
    eps = 0.005
    spr = N_REV / (1 + eps)
    t_enc = np.arange(0, 20.0, 0.01)
    rng = np.random.default_rng(2)
    ang = 0.4 + 2 * np.pi * (1 + eps) * t_enc + rng.normal(0, 1e-4, t_enc.size)
    t_lds = np.arange(20 * 660) / 660.0
    est = period_from_encoder(t_enc, ang, t_lds, rpm_nominal=60.0, sample_rate_hz=660.0)
    assert est.source == "encoder" and est.direction == "ccw"
    assert abs(est.samples_per_rev - spr) < 3 * est.u_samples_per_rev
    assert est.period_disagrees_with_nominal
    y, *_ = _simulate(n_rev=20, eps=eps, phi0=0.4)
    res = process_arrays(
        y, sample_rate_hz=660.0, rpm_nominal=60.0, t_s=t_lds, encoder_t_s=t_enc, encoder_angle_rad=ang
    )
    assert res.period.source == "encoder"
    revs = res.revolutions
    # revolution r starts where the angle has advanced by 2 pi r: sample ceil(r spr)
    for r in (1, 5, 13):
        first = revs.filter(revs["revolution"] == r)["first_sample"][0]
        assert abs(first - r * spr) <= 1.0


# --------------------------------------------------------------------------- extrema


def test_subsample_extrema_within_stated_uncertainty_on_asymmetric_waveform():
    """z = (pos - truth) / u over 40 revs x 3 channels x min/max: ~95 % within 2, mean ~ 0."""
    lobes = ((2, 0.02, 0.3), (3, 0.008, 1.0))  # makes the once-per-rev waveform clearly asymmetric
    y, truth, phi, beams, bore = _simulate(n_rev=40, seed=21, lobes=lobes)
    u = np.arange(y.shape[0]) / N_REV
    ext, info = find_extrema(y, u, samples_per_rev=N_REV)
    zs, zv = [], []
    for ch in range(3):
        for kind in ("min", "max"):
            e = ext.filter((ext["channel"] == ch + 1) & (ext["kind"] == kind))
            tp = _truth_positions(beams, bore, ch, kind, y.shape[0], N_REV)
            pos = e["sample_pos"].to_numpy()
            j = np.searchsorted(tp, pos)
            j = np.clip(j, 1, tp.size - 1)
            near = np.where(np.abs(tp[j] - pos) < np.abs(tp[j - 1] - pos), tp[j], tp[j - 1])
            zs.append((pos - near) / e["u_sample_pos"].to_numpy())
            # true extreme value at the true position
            pe = _true_extrema_phi(beams, bore, ch, kind)
            vtrue = tri_spindle_readings(np.array([pe]), SPINDLE, beams, bore)[0, ch]
            zv.append((e["value_mm"].to_numpy() - vtrue) / e["u_value_mm"].to_numpy())
            assert e.height >= 39
    zs, zv = np.concatenate(zs), np.concatenate(zv)
    assert zs.size >= 234
    assert 0.91 <= np.mean(np.abs(zs) < 2) <= 0.99
    assert abs(zs.mean()) < 3 / math.sqrt(zs.size)
    assert 0.91 <= np.mean(np.abs(zv) < 2) <= 0.99
    assert info["sigma_mm"][1] == pytest.approx(0.0025, rel=0.05)
    # typical position uncertainty ~0.14 samples with a +-41-sample cubic window and 2.5 um noise
    assert 0.1 < np.median(ext["u_sample_pos"].to_numpy()) < 0.2


def test_fit_extremum_cubic_closed_form():
    """v = 1 + 0.01 (x - 0.3)^2 + 0.001 (x - 0.3)^3: stationary point x* = 0.3, v* = 1, exactly."""
    x = np.arange(-20, 21, dtype=float)
    y = 1 + 0.01 * (x - 0.3) ** 2 + 0.001 * (x - 0.3) ** 3
    r = fit_extremum_cubic(y, kind="min", sigma_mm=0.0025)
    assert r["ok"] and r["x"] == pytest.approx(0.3, abs=1e-10) and r["value"] == pytest.approx(1.0, abs=1e-12)
    # u(x*) = sigma sqrt(g^T (X^T X)^-1 g), g = -[0, 1, 2x, 3x^2] / (2 c2 + 6 c3 x)
    X = np.stack([np.ones_like(x), x, x * x, x**3], 1)
    c2 = 0.01 - 3 * 0.001 * 0.3
    c3 = 0.001
    g = -np.array([0, 1, 0.6, 0.27]) / (2 * c2 + 6 * c3 * 0.3)
    assert r["u_x"] == pytest.approx(0.0025 * np.sqrt(g @ np.linalg.inv(X.T @ X) @ g), rel=1e-9)
    assert not fit_extremum_cubic(y, kind="max")["ok"]


def test_cubic_extremum_is_unbiased_noise_free_on_asymmetric_waveform():
    lobes = ((2, 0.03, 0.3), (3, 0.01, 1.0))
    y, truth, phi, beams, bore = _simulate(n_rev=6, noise_mm=0.0, lobes=lobes)
    u = np.arange(y.shape[0]) / N_REV
    ext, _ = find_extrema(truth, u, samples_per_rev=N_REV)
    for ch in range(3):
        for kind in ("min", "max"):
            tp = _truth_positions(beams, bore, ch, kind, y.shape[0], N_REV)
            pos = ext.filter((ext["channel"] == ch + 1) & (ext["kind"] == kind))["sample_pos"].to_numpy()
            err = pos[:, None] - tp[None, :]
            err = err[np.arange(pos.size), np.argmin(np.abs(err), axis=1)]
            assert np.max(np.abs(err)) < 0.015, (ch, kind, err)  # vs u ~ 0.14 with noise


@pytest.mark.parametrize("direction", [+1, -1])
def test_status_follows_the_beam_side_for_both_rho_signs_and_directions(direction):
    """rho > 0 -> n > m (advanced) for ccw; cw flips n/m, and the implied rho sign flips back.

    Closed form: n - m = 2 delta P / 2 pi with delta = atan(rho / (d_b + v_min)) -
    atan(rho / (d_b + v_max)) (the wall point at the extrema lies on the line O'C).
    """
    rho = (5.5484, -4.0, 2.5)
    y, truth, phi, beams, bore = _simulate(n_rev=40, seed=31, rho=rho, direction=direction)
    res = process_arrays(
        y, sample_rate_hz=660.0, rpm_nominal=60.0, direction="ccw" if direction > 0 else "cw"
    )
    summ = res.summary.sort("channel").to_dicts()
    for ch, row in enumerate(summ):
        vmin, vmax = truth[:, ch].min(), truth[:, ch].max()
        d_b, r = beams.d_b_mm[ch], beams.rho_mm[ch]
        delta = math.atan(r / (d_b + vmin)) - math.atan(r / (d_b + vmax))
        expect = direction * 2 * delta * N_REV / (2 * np.pi)
        diff, u = row["n_minus_m_samples"], row["u_n_minus_m_samples"]
        # 0.03 samples: the cubic fits' noise-free bias on n - m (measured <= 0.02)
        assert abs(diff - expect) < 4 * u + 0.03, (ch, diff, expect, u)
        assert row["rho_sign"] == np.sign(r)
        if abs(r) > 5.0:  # |n - m| = 0.29 samples against u ~ 0.06 after 40 revolutions
            assert row["status_significant"]
        status = "advanced" if direction * r > 0 else "backward"
        assert row["status"] == status
        assert row["n_samples"] + row["m_samples"] == pytest.approx(N_REV, abs=0.05)


def test_feature_spacings_and_theta_t_match_geometry():
    y, truth, phi, beams, bore = _simulate(n_rev=30, seed=41)
    res = process_arrays(y, sample_rate_hz=660.0, rpm_nominal=60.0)
    sp = {(r["from_channel"], r["to_channel"]): r for r in res.spacings.to_dicts()}
    pmin = [_true_extrema_phi(beams, bore, ch, "min") for ch in range(3)]
    for a, b in ((1, 2), (2, 3), (3, 1)):
        dphi = (pmin[b - 1] - pmin[a - 1]) % (2 * np.pi)
        row = sp[(a, b)]
        assert row["theta_t_rad"] == pytest.approx(dphi, abs=4 * row["u_theta_t_rad"] + 1e-4)
        expect = dphi * N_REV / (2 * np.pi)
        assert row["spacing_samples"] == pytest.approx(expect, abs=4 * row["u_spacing_samples"])
    # going once round the channels 1 -> 2 -> 3 -> 1 adds up to a whole number of revolutions
    total = sum(r["spacing_samples"] for r in sp.values())
    assert total == pytest.approx(N_REV * round(total / N_REV), abs=0.1)
    assert theta_t_rad(222, 625) == pytest.approx(222 * 2 * np.pi / 625)


def test_nm_counts_and_status_rule_on_paper_numbers():
    """Yang Table 2, sensor-1 first rows: minima 312, 971; maxima 639, 1300 -> n = 327, 331; m = 332."""
    n, m = n_m_counts(np.array([312, 971, 1628]), np.array([639, 1300]))
    assert n.tolist() == [327, 329] and m.tolist() == [332, 328]
    assert beam_status(328, 332)["status"] == "backward"
    assert beam_status(332, 328) == {"status": "advanced", "rho_sign": 1}
    assert beam_status(332, 328, "cw") == {"status": "advanced", "rho_sign": -1}
    with pytest.raises(ValueError, match="direction"):
        beam_status(1, 2, "clockwise")


def test_extrema_windows_with_gaps_are_dropped_not_bridged():
    y, *_ = _simulate(n_rev=10, seed=51)
    u = np.arange(y.shape[0]) / N_REV
    ext0, _ = find_extrema(y, u, samples_per_rev=N_REV)
    e0 = ext0.filter((ext0["channel"] == 1) & (ext0["kind"] == "min"))
    c = int(round(e0["sample_pos"][4]))
    y[c - 30 : c + 30, 0] = np.nan  # wipe out one minimum's neighbourhood
    ext, info = find_extrema(y, u, samples_per_rev=N_REV)
    e = ext.filter((ext["channel"] == 1) & (ext["kind"] == "min"))
    assert e.height == e0.height - 1
    assert info["dropped"][1] == 1
    assert not np.any(np.abs(e["sample_pos"].to_numpy() - c) < 5)


def test_extrema_equal_for_every_memory_layout_of_the_readings():
    """Channel rows laid in one buffer (process_arrays' padded rows: windows gathered from one flat
    view) and row-major (n, c) readings (a 3-D window view) give the same extrema, gaps included.
    """
    y, *_ = _simulate(n_rev=6, seed=81)
    y[[100, 101, 2000], [0, 0, 2]] = np.nan
    u = np.arange(y.shape[0]) / N_REV
    padded = np.full((3, y.shape[0] + 6), np.nan)
    padded[:, 3:-3] = y.T
    layouts = [y, np.asfortranarray(y), padded[:, 3:-3].T]
    got = [find_extrema(v, u, samples_per_rev=N_REV)[0] for v in layouts]
    assert got[0].height >= 30  # 6 revolutions x 3 channels x min and max, less the ends
    for g in got[1:]:
        assert g.equals(got[0])


# --------------------------------------------------------------------------- process_scan on a raw scan


def _meta(scan_id):
    return {
        "format": "borescan-raw/1",
        "scan_id": scan_id,
        "night": "2026-11-21",
        "started_at": "2026-11-21T22:14:03Z",
        "kind": "calibration",
        "device": {"id": "TRI-01", "type": "tri_lds"},
        "sample_rate_hz": 660.0,
        "sensors": [{"channel": c, "model": "HG-C1030", "range_mm": 10.0} for c in (1, 2, 3)],
        "spindle": {"rpm_nominal": 60.0, "direction": "ccw"},
        "artifact": {"id": "RG-275", "type": "ring_gauge"},
        "acquisition": {"software": "test", "simulated": True},
    }


@pytest.mark.parametrize("with_angle", [True, False])
def test_process_scan_on_a_raw_scan(tmp_path, with_angle):
    import polars as pl

    from borescan import rawio

    eps = 0.004
    y, *_ = _simulate(n_rev=12, eps=eps, seed=61, phi0=0.0)
    n = y.shape[0]
    y[500, 1] = np.nan
    y[900, 2] += 0.2
    k = np.arange(n)
    lds = pl.DataFrame(
        {
            "sample": np.repeat(k, 3),
            "t_ns": np.repeat(np.round(k * 1e9 / 660.0), 3).astype(np.int64),
            "sensor": np.tile([1, 2, 3], n),
            "value_mm": pl.Series(y.reshape(-1)).fill_nan(None),
            "pose": pl.Series([None] * (3 * n), dtype=pl.Int32),
        }
    )
    t_enc = np.arange(0, n / 660.0, 0.005)
    angle = 2 * np.pi * (1 + eps) * t_enc + np.random.default_rng(62).normal(0, 2e-5, t_enc.size)
    spindle = pl.DataFrame(
        {
            "t_ns": np.round(t_enc * 1e9).astype(np.int64),
            "angle_rad": pl.Series(angle if with_angle else [None] * t_enc.size, dtype=pl.Float64),
            "x_mm": np.full(t_enc.size, SPINDLE[0]),
            "y_mm": np.full(t_enc.size, SPINDLE[1]),
            "rpm": np.full(t_enc.size, 60.0),
        }
    )
    sid = f"S-{int(with_angle)}"
    scan = rawio.read_scan(rawio.write_scan(tmp_path, _meta(sid), lds, spindle))
    res = process_scan(scan)
    assert res.period.source == ("encoder" if with_angle else "readings")
    assert abs(res.period.samples_per_rev - 660 / (1 + eps)) < 3 * res.period.u_samples_per_rev
    assert res.period.period_disagrees_with_nominal
    assert res.set_aside.sort("channel")["nulls"].to_list() == [0, 1, 0]
    assert res.set_aside.sort("channel")["spikes"].to_list() == [0, 0, 1]
    frames = res.to_frames()
    assert set(frames) == {"revolutions", "extrema", "summary", "spacings", "period", "set_aside"}
    assert all(f["scan_id"].unique().to_list() == [sid] for f in frames.values())
    ext = frames["extrema"]
    assert ext.columns[:9] == [
        "scan_id",
        "channel",
        "revolution",
        "kind",
        "sample_pos",
        "u_sample_pos",
        "value_mm",
        "u_value_mm",
        "n_valid",
    ]
    assert ext.height >= 3 * 2 * 11
    for name, f in frames.items():
        f.write_parquet(tmp_path / f"{name}.parquet")


def test_filter_runs_only_where_it_shapes_a_result(monkeypatch):
    """extrema_on="despiked" (default): the extrema are the unfiltered fit and the filter is computed
    only when filtered_mm is read (then equal to filter_readings of the despiked readings);
    extrema_on="filtered": the extrema come from the filtered readings.
    """
    import borescan.signal.stage as sig

    y, *_ = _simulate(n_rev=8, seed=71)
    calls = []
    real = sig.filter_readings
    monkeypatch.setattr(
        sig, "filter_readings", lambda *a, **k: calls.append(k.get("method")) or real(*a, **k)
    )
    plain = process_arrays(y, sample_rate_hz=660.0, rpm_nominal=60.0, filter="none")
    res = process_arrays(
        y, sample_rate_hz=660.0, rpm_nominal=60.0, filter="median", filter_params={"window_samples": 25}
    )
    assert calls == []
    assert res.extrema.equals(plain.extrema)
    expect = real(res.despiked_mm, method="median", window_samples=25)
    np.testing.assert_array_equal(res.filtered_mm, expect)
    assert calls == ["median"]
    _ = res.filtered_mm  # cached: computed once
    assert calls == ["median"]
    filt = process_arrays(
        y,
        sample_rate_hz=660.0,
        rpm_nominal=60.0,
        filter="median",
        filter_params={"window_samples": 25},
        extrema_on="filtered",
    )
    assert calls == ["median", "median"]
    np.testing.assert_array_equal(filt.filtered_mm, expect)
    assert not filt.extrema["value_mm"].equals(plain.extrema["value_mm"])  # fitted on other readings
    with pytest.raises(ValueError, match="extrema_on"):
        process_arrays(y, sample_rate_hz=660.0, rpm_nominal=60.0, extrema_on="smoothed")
    with pytest.raises(ValueError, match="unknown filter"):
        process_arrays(y, sample_rate_hz=660.0, rpm_nominal=60.0, filter="butterworth")


def test_revolutions_follow_the_rpm_profile_when_the_speed_changes(tmp_path):
    """No encoder, 60 rpm then a ramp to 30 rpm: revolutions come from the profile's angle, not one period."""
    from dataclasses import replace

    from borescan import rawio
    from borescan.synthetic import scenes, simulate

    scene = replace(scenes.default_tri_scene(), rpm_profile=((0.0, 60.0), (6.0, 60.0), (7.0, 30.0)))
    sim = simulate.simulate_tri_spindle(scene, n_rev=20, encoder=False, seed=2, scan_id="RAMP")
    path = simulate.write_simulated(sim, tmp_path / "raw", tmp_path / "truth")
    res = process_scan(rawio.read_scan(path))
    assert res.period.source == "profile"
    # 20 revolutions in 660 * 6.5 + 1320 * 13.5 samples: mean 1056 samples per revolution
    n = sim.lds["sample"].n_unique()
    assert res.period.samples_per_rev == pytest.approx(n / 20, rel=2e-3)
    assert res.revolutions.height == 20
    assert res.summary["n_revolutions_min"].min() >= 19
