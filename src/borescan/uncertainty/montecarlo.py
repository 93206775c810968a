"""GUM Supplement 1 Monte Carlo of a budget and its validation; rounding and formatting.

Part of :mod:`borescan.uncertainty` (package doc).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from .budget import Input
from .coverage import NU_NORMAL, _check_dist, numerical_tolerance

__all__ = [
    "draw",
    "MonteCarloResult",
    "monte_carlo",
    "s1_validate",
    "round_uncertainty",
    "format_value",
]


# --------------------------------------------------------------------------- Monte Carlo (GUM S1)


def draw(
    distribution: str,
    estimate: float,
    u: float,
    size: int,
    rng: np.random.Generator,
    dof: float = float("inf"),
) -> np.ndarray:
    """``size`` draws of a quantity with the given estimate, standard uncertainty and distribution.

    ``normal`` with finite ``dof``: estimate + u t_dof (GUM S1 6.4.9); ``rectangular`` on
    +-u sqrt 3, ``triangular`` on +-u sqrt 6, ``arcsine`` on +-u sqrt 2 (GUM S1 6.4.2-6.4.6).
    """
    _check_dist(distribution)
    if distribution == "normal":
        z = rng.standard_t(dof, size) if np.isfinite(dof) and dof <= NU_NORMAL else rng.standard_normal(size)
        return estimate + u * z
    if distribution == "rectangular":
        return estimate + u * math.sqrt(3.0) * rng.uniform(-1.0, 1.0, size)
    if distribution == "triangular":
        return estimate + u * math.sqrt(6.0) * (rng.uniform(0, 1, size) - rng.uniform(0, 1, size))
    return estimate + u * math.sqrt(2.0) * np.sin(2.0 * math.pi * rng.uniform(0, 1, size))


@dataclass(frozen=True)
class MonteCarloResult:
    """GUM S1 Monte Carlo result.

    GUM S1 Monte Carlo result: estimate (mean), standard uncertainty (sample SD), the
    probabilistically symmetric coverage interval [low, high] for p, and the number of trials.
    """

    y: float
    u: float
    low: float
    high: float
    p: float
    n: int


def monte_carlo(
    model: Callable[[dict[str, np.ndarray]], np.ndarray],
    inputs: Mapping[str, Any],
    p: float,
    n: int,
    rng: np.random.Generator,
) -> MonteCarloResult:
    """Propagate distributions through ``model`` by Monte Carlo (GUM S1 §7).

    Parameters
    ----------
    model : takes a dict of input name -> (n,) draws (or (n, d) for a multivariate normal),
        returns (n,) output values
    inputs : name -> :class:`Input` (drawn by :func:`draw`), or (mean (d,), cov (d, d)) for a
        multivariate normal input (GUM S1 6.4.8)
    p : coverage probability; n : trials; rng : numpy Generator

    Returns
    -------
    MonteCarloResult with the probabilistically symmetric interval (quantiles (1 -+ p) / 2).
    """
    xs = {}
    for name, spec in inputs.items():
        if isinstance(spec, Input):
            est = 0.0 if spec.estimate is None else float(spec.estimate)
            xs[name] = draw(spec.distribution, est, spec.u, n, rng, spec.dof)
        else:
            mean, cov = spec
            xs[name] = rng.multivariate_normal(
                np.asarray(mean, float), np.asarray(cov, float), size=n, method="eigh"
            )
    y = np.asarray(model(xs), dtype=float)
    if y.shape != (n,):
        raise ValueError(f"model must return ({n},) values, got {y.shape}")
    lo, hi = np.quantile(y, [0.5 * (1 - p), 0.5 * (1 + p)])
    return MonteCarloResult(float(np.mean(y)), float(np.std(y, ddof=1)), float(lo), float(hi), p, n)


def s1_validate(
    y: float, U: float, u: float, mc: MonteCarloResult, n_dig: int = 2
) -> tuple[bool, float, float, float]:
    """Validate the GUF interval y +- U by the Monte Carlo interval (GUM S1 §8).

    d_low = |y - U - y_low|, d_high = |y + U - y_high|; validated when both are at most the
    numerical tolerance delta of u at ``n_dig`` significant digits (:func:`numerical_tolerance`).

    Returns
    -------
    (validated, d_low, d_high, delta)
    """
    delta = numerical_tolerance(u, n_dig)
    d_low = abs(y - U - mc.low)
    d_high = abs(y + U - mc.high)
    return bool(d_low <= delta and d_high <= delta), d_low, d_high, delta


# --------------------------------------------------------------------------- presentation


def round_uncertainty(U: float, digits: int = 2) -> tuple[float, int]:
    """Return U rounded up to ``digits`` significant digits.

    U rounded up to ``digits`` significant digits (GUM 7.2.6: round up rather than down) and the
    number of decimals it has (negative: tens, hundreds, ...).
    """
    U = abs(float(U))
    if U == 0.0 or not np.isfinite(U):
        return U, 0
    dec = digits - 1 - math.floor(math.log10(U))
    scale = 10.0**dec
    up = math.ceil(U * scale - 1e-9) / scale
    if up >= 10.0 ** (digits - dec):  # 9.96 -> 10: one digit more before the point
        dec -= 1
    return up, dec


def format_value(
    value: float,
    U: float,
    unit: str = "",
    scale: float = 1.0,
    unit_U: str | None = None,
    scale_U: float | None = None,
) -> str:
    """``"value +- U unit"`` with U at two significant digits and the value to the same decimal place.

    ``scale``/``unit``: the value is shown as value * scale in ``unit``; U likewise with
    ``scale_U``/``unit_U`` (default the value's), e.g. a diameter in mm with U in um.
    """
    scale_U = scale if scale_U is None else scale_U
    unit_U = unit if unit_U is None else unit_U
    Ur, dec = round_uncertainty(U * scale_U)
    dec_v = dec + int(round(math.log10(scale_U / scale))) if scale != scale_U else dec
    dec_v = max(dec_v, 0)
    v = f"{value * scale:.{dec_v}f}"
    u = f"{Ur:.{max(dec, 0)}f}"
    sep = " " if unit else ""
    if unit_U == unit:
        return f"({v} +- {u}){sep}{unit}"
    return f"{v}{sep}{unit} +- {u} {unit_U}"
