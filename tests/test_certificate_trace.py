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


def test_residual_panel_titles_sit_where_matplotlib_would_place_them():
    """The residual panels' titles are placed at the top of their axes without matplotlib measuring every
    y tick label at each drawing (layout._fixed_title): the page is pixel for pixel the one matplotlib's
    own title placement gives, for residuals of a few um and of thousands of um (whose labels would
    otherwise take a "1e3" multiplier, written in full now).
    """
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from borescan.certificate import write

    def png(fig):
        FigureCanvasAgg(fig)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=60)
        return np.asarray(__import__("PIL.Image", fromlist=["Image"]).open(buf))

    cert = {"calibration_id": "C", "parameters": [{"channel": c} for c in (1, 2, 3)]}
    rng = np.random.default_rng(8)
    t = np.arange(3000) / 500.0
    for scale_mm in (0.002, 0.004):
        res = rng.normal(0.0, scale_mm, (t.size, 3))
        ours = png(write._residual_figure(cert, t, res))
        fig = write._residual_figure(cert, t, res)
        for ax in fig.axes:  # matplotlib's own placement of the same titles
            ax.set_title(ax.get_title(loc="left"), fontsize=8, loc="left")
            ax._autotitlepos = True
        assert np.array_equal(ours, png(fig)), scale_mm
    big = write._residual_figure(cert, t, rng.normal(0.0, 30.0, (t.size, 3)))
    FigureCanvasAgg(big).draw()
    labels = [lab.get_text() for ax in big.axes for lab in ax.get_yticklabels()]
    assert not any(ax.yaxis.get_offset_text().get_text() for ax in big.axes)
    assert any(len(lab.replace("−", "").replace("-", "")) >= 5 for lab in labels)  # e.g. 50000 written out
