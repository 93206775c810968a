"""Readings censored at a sensor's range limits (the raw format's null "out of range").

The sensor decides on the *noisy* value: near a limit the valid readings are a truncated sample
(noise biased away from the limit by sigma phi(a) / Phi(a), a = distance / sigma) and a few noisy
ones beyond it stay valid. The full-data calibration sets aside the readings whose fitted value
lies within ``CENSOR_GUARD_SIGMA`` sigma of a limit, a selection on the model, not on the noise.
"""

import numpy as np

from borescan.calibrate.censoring import CENSOR_GUARD_SIGMA, censoring_keep
from borescan.calibrate.full_fit import fit_full_calibration
from borescan.geometry import Beams, Bore, tri_spindle_readings

TRUE = Beams(
    (1, 2, 3),
    np.array([0.3, 0.3 + 2.1, 0.3 + 4.2]),
    np.array([5.5484, -2.5295, 1.5262]),
    np.array([132.6718, 132.8883, 134.1108]),
)
R_MM = 275.029 / 2
OFFSET = np.array([262.955 - 262.833, -275.502 + 273.182])
RANGE_MM = 10.0


def _censored_scene(n_rev=30, N=500):
    """Channel 1's lowest reading exactly at the lower limit 0, channel 2's highest at the upper
    limit (10 mm): both dwell near a limit around their extremes (the slowest crossing).
    """
    t = np.arange(n_rev * N) / N  # 60 rpm, N samples per revolution
    v0 = tri_spindle_readings(2 * np.pi * t, OFFSET, TRUE, Bore((0.0, 0.0), R_MM))
    d_b = TRUE.d_b_mm + np.array([v0[:, 0].min(), v0[:, 1].max() - RANGE_MM, v0[:, 2].min() - 3.0])
    beams = Beams(TRUE.channels, TRUE.beta_rad, TRUE.rho_mm, d_b)
    return t, beams, tri_spindle_readings(2 * np.pi * t, OFFSET, beams, Bore((0.0, 0.0), R_MM))


def _params(cal):
    return np.r_[cal.beams.beta_rad[1:], cal.beams.rho_mm, cal.beams.d_b_mm]


def _u(cal):
    return np.r_[cal.u_beta_rad[1:], cal.u_rho_mm, cal.u_d_b_mm]


def test_censoring_keep_rule():
    v = np.array([[-0.01, 5.0], [0.003, 5.0], [0.05, 9.998], [0.05, 9.5]])
    y = v.copy()
    y[0, 0] = np.nan  # the sensor nulled it
    keep, lim = censoring_keep(v, y, np.array([10.0, 10.0]), np.array([0.001, 0.001]))
    assert CENSOR_GUARD_SIGMA == 4.0
    assert keep[:, 0].tolist() == [False, False, True, True] and keep[:, 1].tolist() == [
        True,
        True,
        False,
        True,
    ]
    assert lim == {"lower": [True, True], "upper": [True, True]}
    # a sensor with valid readings beyond a stated limit is not censored there
    keep, lim = censoring_keep(v, v + [0.0, 1.0], np.array([10.0, 10.0]), np.array([0.001, 0.001]))
    assert lim == {"lower": [False, True], "upper": [True, False]}
    assert keep[:, 0].all() and keep[2, 1]


def test_censored_readings_do_not_bias_the_calibration():
    """Against the same noise with a selection the noise cannot move (readings whose *true* value lies
    more than 4 sigma inside the range, every other one kept as read, also the negative ones), the
    calibration of the censored readings (null where the noisy value leaves [0, 10 mm]) agrees within
    0.15 u in every parameter; without the guard it is off by ~0.3-0.7 u (channel 1's rho and d_b,
    channel 2's). Both are within 3.5 u of the simulated truth.
    """
    t, beams, v = _censored_scene()
    sigma = 0.004
    rng = np.random.default_rng(0)
    y = v + rng.normal(0.0, sigma, v.shape)
    censored = y.copy()
    censored[(y < 0.0) | (y > RANGE_MM)] = np.nan
    oracle = y.copy()
    oracle[(v <= CENSOR_GUARD_SIGMA * sigma) | (v >= RANGE_MM - CENSOR_GUARD_SIGMA * sigma)] = np.nan
    nominal = Beams(
        TRUE.channels,
        beams.beta_rad + [0.0, 0.01, -0.01],
        beams.rho_mm + [0.3, -0.3, 0.3],
        beams.d_b_mm + 0.05,
    )
    kw = dict(rpm=60.0, range_mm=[RANGE_MM] * 3, scan_ids=["A"])
    cal = fit_full_calibration(t, censored, TRUE.channels, nominal, R_MM, **kw)
    ref = fit_full_calibration(t, oracle, TRUE.channels, nominal, R_MM, **kw)
    set_aside = cal.diagnostics["censoring_guard"]["set_aside"]["A"]
    assert set_aside[0] > 100 and set_aside[1] > 100 and set_aside[2] == 0
    truth = np.r_[beams.beta_rad[1:], beams.rho_mm, beams.d_b_mm]
    u = _u(cal)
    assert np.all(np.abs(_params(cal) - _params(ref)) < 0.15 * u)
    assert np.all(np.abs(_params(cal) - truth) < 3.5 * u)
    assert np.all(np.abs(_params(ref) - truth) < 3.5 * _u(ref))
