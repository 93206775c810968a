"""bench_coverage --flagged (issue 36): the scenes it draws and the figures it prints of flagged chains."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.bench_coverage import covered
from bench.coverage_flagged import draw_calibration as _draw_calibration, flagged_summary


def test_flagged_scenes_have_a_shallow_mirror_and_the_default_draw_is_the_batterys():
    """Each --flagged scene has a beam with |rho| > sqrt(2) e and N e^4 rho^2 / (2 sigma^2 L^4) < 25 at the
    truth (Eq. (1), written out here), a bore within R 75-500 mm; without --flagged the scene is the
    contract battery's scan i.
    """
    from borescan.synthetic import battery, tri_scenarios

    for i in range(3):
        ct = _draw_calibration(i, 11, True).truth["contract"]
        e = math.hypot(*np.subtract(ct["spindle_xy_mm"], ct["center_xy_mm"]))
        n, s, L = ct["n_samples"], ct["noise_mm"], ct["bore_radius_mm"]
        depths = [
            n * e**4 * b["rho"] ** 2 / (2 * s**2 * L**4)
            for b in ct["beams"]
            if abs(b["rho"]) > math.sqrt(2) * e
        ]
        assert depths and min(depths) < 25.0 and 75.0 <= L <= 500.0
    ref = tri_scenarios.draw_tri_calibration(
        battery.battery_rng(11, 2), scan_id=battery.battery_scan_id(11, 2), night="2027-02-01"
    )
    assert _draw_calibration(2, 11, False).truth["contract"] == ref.truth["contract"]


def _row(p_wrong, wrong, interval_err, err=0.0, u=1.0):
    diam = [
        {"family": f, "err": err, "u": u, "U": 2 * u, "k": 2.0, "interval_err": interval_err}
        for f in ("D at 20 degC", "D at T")
    ]
    beams = [
        {"channel": j + 1, "p_wrong_sign": p, "wrong_sign": w} for j, (p, w) in enumerate(zip(p_wrong, wrong))
    ]
    return {
        "accepted": True,
        "flagged": True,
        "flagged_beams": beams,
        "params": [],
        "diameters": diam,
        "mixture": True,
    }


def test_flagged_summary_counts_wrong_signs_against_the_weights_and_covers_by_the_own_interval():
    """Wrong signs 2 of stated (0.5, 0.5, 0.1): P(X >= 2) = 0.5 * 0.5 + 2 * 0.5 * 0.5 * 0.1 = 0.30 in closed
    form; a mixture's interval that misses the truth on one side is not covered though |err| <= U; a refusal
    outside the valid range is counted apart.
    """
    rows = [
        _row([0.5, 0.5], [True, False], [-1.0, 3.0]),
        _row([0.1], [True], [-3.0, -0.5], err=-1.5),  # |err| 1.5 <= U 2 but the interval misses the truth
        {
            "accepted": True,
            "flagged": True,
            "params": [],
            "flagged_beams": [],
            "measure_error": "S: bore diameter 1.000 mm outside 2.0 mm to 3.0 mm, the range where calib C",
        },
    ]
    f = flagged_summary(rows)
    assert f["wrong_sign"] == 2 and f["wrong_sign_stated"] == pytest.approx(1.1, abs=1e-12)
    assert f["wrong_sign_p_at_least"] == pytest.approx(0.30, abs=1e-12)
    assert f["families"]["D at T"]["n"] == 2 and f["families"]["D at T"]["cover"] == 0.5
    assert f["refused_valid_range"] == 1 and f["refused_other"] == [] and f["mixtures"] == 2
    assert covered({"err": -1.5, "U": 2.0}) and not covered(rows[1]["diameters"][0])
