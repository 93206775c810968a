"""Signal stage: filters, null/spike handling, revolutions, sub-sample extrema, Yang §2.3 statuses.

Everything below the entry point :func:`process_scan` is a pure function of numpy arrays
(``(n,)`` or ``(n, c)``, NaN = missing reading), so it can be tested without any file.

Modules (the names below are all importable from ``borescan.signal``):

- ``filters``: median, moving average, Kalman (Yang 2017 §4), ISO 16610-21 Gaussian in UPR;
- ``spikes``: :func:`remove_spikes`, Hampel test against a Theil-Sen local-linear reference;
- ``period``: rotation period from the encoder or the readings, revolution coordinate, revolutions;
- ``extrema``: sub-sample minima and maxima by cubic fits;
- ``features``: n/m counts, advanced/backward status, feature points, spacings, theta_t (Eq. 15);
- ``stage``: :class:`SignalResult`, :func:`process_arrays`, :func:`process_scan`;
- ``performance``: :func:`filter_performance` (what each filter does to a simulated scan).

Conventions
-----------
- Sample positions are in acquisition ticks (``sample`` of ``borescan-raw/1``), fractional
  where sub-sample. A "revolution coordinate" ``u`` (revolutions since the first sample) maps
  every sample to its revolution, ``revolution = floor(u)``.
- Missing readings are never bridged: filters return NaN wherever the input is NaN, spikes are
  set aside as NaN and counted, and an extremum whose fit window holds too few valid samples is
  dropped (and counted), not interpolated.
- Zero-phase filtering is the default everywhere. A causal filter delays the signal, which moves
  every extremum later by the group delay and so corrupts the feature-point spacing and
  theta_t of Yang 2017, Eq. 15 whenever channels are filtered differently (and the absolute
  angle always). ``filter_performance`` quantifies this.

Advanced / backward (Yang 2017, §2.3)
-------------------------------------
``n`` = samples from a minimum to the next maximum, ``m`` = from a maximum to the next minimum.
The paper's rule: n < m -> "backward", n > m -> "advanced" (counter-clockwise rotation). In the
spec's frame (``F = rho * n_hat``), a ccw turn moves the beam foot point ahead of the line
O'-feature point when rho > 0, and the exact geometry gives n > m for rho > 0: advanced <=> rho > 0
(ccw). For clockwise rotation time runs against the angle, so n and m swap roles: the rule
"n < m -> backward" still reads the status relative to the rotation, but the implied sign of
rho flips (cw: backward <=> rho > 0). :func:`beam_status` returns both.
"""

from __future__ import annotations

from borescan.signal.extrema import find_extrema, fit_extremum_cubic
from borescan.signal.features import beam_status, feature_points, feature_spacings, n_m_counts, theta_t_rad
from borescan.signal.filters import (
    FILTERS,
    filter_readings,
    gaussian_filter_upr,
    gaussian_transmission,
    kalman_filter,
    median_filter,
    moving_average,
)
from borescan.signal.performance import filter_performance
from borescan.signal.period import (
    PeriodEstimate,
    find_revolutions,
    period_from_encoder,
    period_from_readings,
    revolution_coordinate,
)
from borescan.signal.spikes import remove_spikes
from borescan.signal.stage import SignalResult, process_arrays, process_scan

__all__ = [
    "FILTERS",
    "PeriodEstimate",
    "SignalResult",
    "gaussian_transmission",
    "median_filter",
    "moving_average",
    "kalman_filter",
    "gaussian_filter_upr",
    "filter_readings",
    "remove_spikes",
    "period_from_encoder",
    "period_from_readings",
    "find_revolutions",
    "revolution_coordinate",
    "fit_extremum_cubic",
    "find_extrema",
    "n_m_counts",
    "beam_status",
    "feature_spacings",
    "theta_t_rad",
    "process_arrays",
    "process_scan",
    "filter_performance",
    "feature_points",
]
