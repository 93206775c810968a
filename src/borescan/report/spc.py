"""Control charts of verification errors: individuals/moving-range limits and the run rules."""

from __future__ import annotations

from typing import Any

import numpy as np


#: Individuals chart: limits at mean ± 3 MR̄/d2 with d2 = 1.128 (n = 2), i.e. ± 2.66 MR̄.
MR_D2_FACTOR = 2.66
#: Moving-range chart: UCL = D4 MR̄ with D4 = 3.267 (n = 2).
MR_D4 = 3.267
#: d2 of moving ranges of two (Montgomery, Appendix VI): σ̂ = MR̄ / d2.
MR_D2 = 1.128


def control_limits(values: np.ndarray | list[float]) -> dict[str, Any]:
    """Individuals / moving-range control-chart limits of a series.

    Parameters
    ----------
    values
        The individual values in time order (here: verification errors [mm]). NaN are dropped.

    Returns
    -------
    dict
        ``mean``, ``mr`` (moving ranges ``|x_i - x_{i-1}|``, length n-1), ``mr_bar`` (their mean),
        ``ucl = mean + 2.66 mr_bar``, ``lcl = mean - 2.66 mr_bar``, ``mr_ucl = 3.267 mr_bar``,
        ``mr_lcl = 0``. With fewer than two values the MR-based limits are NaN.
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    mean = float(x.mean()) if x.size else float("nan")
    mr = np.abs(np.diff(x))
    mr_bar = float(mr.mean()) if mr.size else float("nan")
    return {
        "mean": mean,
        "mr": mr,
        "mr_bar": mr_bar,
        "ucl": mean + MR_D2_FACTOR * mr_bar,
        "lcl": mean - MR_D2_FACTOR * mr_bar,
        "mr_ucl": MR_D4 * mr_bar,
        "mr_lcl": 0.0,
    }


#: The Western Electric run rules this report applies (Western Electric, *Statistical Quality
#: Control Handbook*, 1956; Montgomery §5.3.6): rule number -> what breaks it.
RUN_RULES = {
    1: "a point beyond 3σ",
    2: "2 of 3 in a row beyond 2σ on one side",
    4: "8 in a row on one side of the centre line",
}


def run_rules(values: np.ndarray | list[float], centre: float, sigma: float) -> dict[int, np.ndarray]:
    """Return the points of a series that break Western Electric run rules 1, 2 and 4.

    Parameters
    ----------
    values
        The individual values in time order [any unit]. NaN never counts and breaks a run.
    centre
        Centre line [same unit] (the chart's mean).
    sigma
        Standard deviation of one value [same unit]; for an individuals chart σ̂ = MR̄ / 1.128.

    Returns
    -------
    dict
        Rule number -> boolean array (one per value), True where the value takes part in a
        breach: rule 1, ``|x - centre| > 3 sigma``; rule 2, two of three consecutive values beyond
        ``2 sigma`` on the same side (the values beyond, in every such window); rule 4, eight or
        more consecutive values strictly on one side of the centre line (every value of the run).
        All False when ``sigma`` or ``centre`` is not finite or ``sigma`` <= 0.
    """
    x = np.asarray(values, dtype=float)
    n = x.size
    out = {r: np.zeros(n, dtype=bool) for r in RUN_RULES}
    if not (np.isfinite(centre) and np.isfinite(sigma) and sigma > 0):
        return out
    z = (x - centre) / sigma
    fin = np.isfinite(z)
    out[1] = fin & (np.abs(z) > 3.0)
    for sign in (1.0, -1.0):
        beyond = fin & (sign * z > 2.0)
        for i in range(max(n - 2, 0)):
            if beyond[i : i + 3].sum() >= 2:
                out[2][i : i + 3] |= beyond[i : i + 3]
        side = fin & (sign * z > 0.0)
        run = 0
        for i in range(n):
            run = run + 1 if side[i] else 0
            if run >= 8:
                out[4][i - run + 1 : i + 1] = True
    return out
