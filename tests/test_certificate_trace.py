"""A certificate's residual trace is drawn from each run's extremes: every extreme reading, in time order."""

import numpy as np

from borescan.certificate.write import TRACE_RUNS, trace_envelope


def test_the_envelope_keeps_each_runs_minimum_and_maximum_in_time_order():
    """52 000 samples (a contract calibration scan) drawn with 2 x 2000 points: in each run of 26
    samples exactly its smallest and largest reading, at their own times and in time order, so the
    spike and the trace's range are those of the readings.
    """
    rng = np.random.default_rng(3)
    n = 52_000
    t = np.arange(n) / 5000.0
    y = rng.normal(0.0, 3.0, n)
    y[20_011] = 40.0
    te, ye = trace_envelope(t, y)
    per = -(-n // TRACE_RUNS)
    assert te.size == ye.size == 2 * (-(-n // per))
    assert np.all(np.diff(te) >= 0.0)
    assert ye.max() == 40.0 and ye.min() == y.min()
    for k in range(0, n // per, 97):  # every 97th run against the readings themselves
        run = slice(k * per, (k + 1) * per)
        i_lo, i_hi = sorted((int(np.argmin(y[run])), int(np.argmax(y[run]))))
        assert te[2 * k : 2 * k + 2].tolist() == [t[run][i_lo], t[run][i_hi]]
        assert ye[2 * k : 2 * k + 2].tolist() == [y[run][i_lo], y[run][i_hi]]


def test_missing_readings_are_passed_over_and_a_run_of_nothing_breaks_the_line():
    t = np.arange(60.0)
    y = np.sin(t)
    y[3] = np.nan  # in a run with readings: passed over
    y[30:40] = np.nan  # a whole run of 10 without a reading
    te, ye = trace_envelope(t, y, runs=6)
    assert np.isnan(ye[6:8]).all() and np.isfinite(np.delete(ye, [6, 7])).all()
    first = sorted((int(np.nanargmin(y[:10])), int(np.nanargmax(y[:10]))))
    assert te[:2].tolist() == first and ye[:2].tolist() == y[first].tolist()


def test_a_short_trace_is_drawn_sample_by_sample():
    t, y = np.arange(3000.0), np.cos(np.arange(3000.0))
    te, ye = trace_envelope(t, y, runs=2000)  # runs of two samples: nothing to leave out
    assert te is t and ye is y
