"""Standard uncertainties of the stated distributions and coverage factors (GUM 4.3, G.4, S1 5.3).

Part of :mod:`borescan.uncertainty` (package doc).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

# the distribution functions themselves: scipy.stats and scipy.signal cost ~1.3 s of imports in
# every process that loads this module (each stage job and worker), for nothing these need
from scipy import special

__all__ = [
    "DISTRIBUTIONS",
    "standard_uncertainty",
    "welch_satterthwaite",
    "coverage_factor",
    "chi2_quantile",
    "numerical_tolerance",
    "linear_coverage_interval",
]


#: distribution -> divisor of the half-width a giving the standard uncertainty (GUM 4.3.7, 4.3.9, S1 6.4)
DISTRIBUTIONS: dict[str, float] = {
    "normal": float("nan"),  # given by its standard deviation (or U / k)
    "rectangular": math.sqrt(3.0),
    "triangular": math.sqrt(6.0),
    "arcsine": math.sqrt(2.0),
}


#: a t distribution with more degrees of freedom than this is taken as normal
NU_NORMAL = 1.0e4


def _check_dist(distribution: str) -> str:
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"unknown distribution {distribution!r}; valid: {sorted(DISTRIBUTIONS)}")
    return distribution


def standard_uncertainty(
    *,
    halfwidth: float | None = None,
    expanded: float | None = None,
    k: float | None = None,
    distribution: str = "rectangular",
) -> float:
    """Return standard uncertainty from a stated bound or an expanded uncertainty.

    Parameters
    ----------
    halfwidth : half-width a of a bounded distribution (``rectangular``: a / sqrt 3, GUM 4.3.7;
        ``triangular``: a / sqrt 6, GUM 4.3.9; ``arcsine``: a / sqrt 2) [unit of the quantity]
    expanded, k : an expanded uncertainty U and its coverage factor (``normal``: U / k, GUM 4.3.3)
    distribution : one of :data:`DISTRIBUTIONS`

    Returns
    -------
    float : u [unit of the quantity]
    """
    _check_dist(distribution)
    if expanded is not None:
        if k is None or not k > 0:
            raise ValueError("an expanded uncertainty needs its coverage factor k > 0")
        return float(expanded) / float(k)
    if halfwidth is None:
        raise ValueError("give halfwidth or expanded and k")
    if distribution == "normal":
        raise ValueError("a normal distribution has no half-width; give expanded and k")
    return float(halfwidth) / DISTRIBUTIONS[distribution]


def welch_satterthwaite(u_i, nu_i) -> float:
    """Effective degrees of freedom nu_eff = u_c^4 / sum(u_i^4 / nu_i) (GUM Eq. G.2b).

    Parameters
    ----------
    u_i : contributions u_i(y) = |c_i| u(x_i) [unit of y]
    nu_i : their degrees of freedom (inf for Type B inputs known exactly enough)

    Returns
    -------
    float : nu_eff (inf when every nu_i is infinite or every u_i is 0); not truncated.
    """
    u = np.abs(np.asarray(u_i, dtype=float))
    nu = np.broadcast_to(np.asarray(nu_i, dtype=float), u.shape)
    if np.any(nu <= 0):
        raise ValueError("degrees of freedom must be > 0")
    uc2 = float(np.sum(u**2))
    fin = np.isfinite(nu) & (u > 0)
    den = float(np.sum(u[fin] ** 4 / nu[fin]))
    if uc2 == 0.0 or den == 0.0:
        return float("inf")
    return uc2**2 / den


def coverage_factor(p: float, nu_eff: float = float("inf"), *, truncate: bool = True) -> float:
    """Coverage factor k_p = t_p(nu_eff), two-sided (GUM G.3.2, Table G.2).

    ``truncate``: nu_eff is rounded down to an integer first (GUM G.4.1 note 1). nu_eff above
    :data:`NU_NORMAL` or infinite gives the normal quantile (p = 0.9545 gives k = 2.000).
    """
    if not 0.0 < p < 1.0:
        raise ValueError(f"coverage probability must lie in (0, 1), got {p}")
    q = 0.5 * (1.0 + p)
    if not np.isfinite(nu_eff) or nu_eff > NU_NORMAL:
        return float(special.ndtri(q))
    nu = max(1.0, math.floor(nu_eff)) if truncate else float(nu_eff)
    return float(special.stdtrit(nu, q))


def chi2_quantile(p: float, dof: int) -> float:
    """Return the quantile at ``p`` of the chi-square distribution with ``dof`` degrees of freedom.

    x with P(chi2_dof <= x) = p: 2 P^-1(dof / 2, p), P the regularised lower incomplete gamma function.
    The same numbers as ``scipy.stats.chi2.ppf(p, dof)`` (the formula it evaluates), without loading
    scipy.stats (about 0.3 s of imports in each process). The coverage factor of a coverage region
    for ``dof`` jointly normal results is its square root (GUM Supplement 2, JCGM 102, coverage regions).
    """
    if not 0.0 < p < 1.0:
        raise ValueError(f"probability must lie in (0, 1), got {p}")
    if dof < 1:
        raise ValueError(f"degrees of freedom must be at least 1, got {dof}")
    return float(2.0 * special.gammaincinv(dof / 2.0, p))


def numerical_tolerance(u: float, n_dig: int = 2) -> float:
    """GUM S1 7.9.2: u written with ``n_dig`` significant digits as c x 10^l gives delta = 10^l / 2."""
    u = abs(float(u))
    if u == 0.0 or not np.isfinite(u):
        return 0.0
    ell = math.floor(math.log10(u)) - (n_dig - 1)
    return 0.5 * 10.0**ell


# --------------------------------------------------------------------------- distribution of a linear model


def _cell_masses(dist: str, scale: float, nu: float, edges: np.ndarray) -> np.ndarray:
    """Return the probability of each cell of a zero-mean term.

    Probability of each cell [edges[i], edges[i+1]) of a zero-mean term with standard uncertainty
    ``scale``.
    """
    if dist == "normal":
        if np.isfinite(nu) and nu <= NU_NORMAL:
            cdf = special.stdtr(nu, edges / scale)
        else:
            cdf = special.ndtr(edges / scale)
    elif dist == "rectangular":
        a = scale * math.sqrt(3.0)
        cdf = np.clip((edges + a) / (2 * a), 0.0, 1.0)
    elif dist == "triangular":
        a = scale * math.sqrt(6.0)
        x = np.clip(edges / a, -1.0, 1.0)
        cdf = np.where(x < 0, 0.5 * (1 + x) ** 2, 1 - 0.5 * (1 - x) ** 2)
    elif dist == "arcsine":
        a = scale * math.sqrt(2.0)
        cdf = 0.5 + np.arcsin(np.clip(edges / a, -1.0, 1.0)) / math.pi
    else:
        raise ValueError(f"unknown distribution {dist!r}; valid: {sorted(DISTRIBUTIONS)}")
    return np.diff(cdf)


def _fast_length(n: int) -> int:
    """Return the smallest 5-smooth integer >= n.

    Smallest 5-smooth integer >= n (2^a 3^b 5^c: a fast real FFT length; scipy.fft.next_fast_len(n,
    real=True), without importing scipy.fft).
    """
    best, p5 = 2 * n, 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            m = p35
            while m < n:
                m *= 2
            best = min(best, m)
            p35 *= 3
        p5 *= 5
    return best


def _fft_convolve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Full linear convolution of two 1-D arrays by real FFT (zero-padded to a fast length)."""
    n = a.size + b.size - 1
    nfft = _fast_length(n)
    return np.fft.irfft(np.fft.rfft(a, nfft) * np.fft.rfft(b, nfft), nfft)[:n]


def _half_span(dist: str, scale: float, nu: float, tail: float = 1e-9) -> float:
    if dist == "normal":
        if np.isfinite(nu) and nu <= NU_NORMAL:
            return float(-scale * special.stdtrit(nu, tail))
        return float(-scale * special.ndtri(tail))
    return float(scale * DISTRIBUTIONS[dist])


def linear_coverage_interval(
    terms: Sequence[tuple[str, float, float]], p: float, *, cells_per_u: int = 400
) -> float:
    """Half-width of the probabilistically symmetric coverage interval of a sum of independent terms.

    Y = sum_i Z_i, each Z_i of zero mean, symmetric, with standard uncertainty u_i and a
    distribution: ``normal`` (with nu_i finite below :data:`NU_NORMAL`: u_i times Student's
    t_nu, GUM S1 6.4.9), ``rectangular``, ``triangular`` or ``arcsine``. The distribution of Y
    is the convolution of the terms' (GUM S1 5.2), evaluated on a grid of u_c / ``cells_per_u``
    (each term's exact cell probabilities from its distribution function, convolved by FFT);
    normal terms of infinite nu are first pooled into one.

    Parameters
    ----------
    terms : (distribution, u_i, nu_i) per term [unit of Y]
    p : coverage probability

    Returns
    -------
    float : q with P(|Y| <= q) = p [unit of Y]; the coverage factor is q / u_c.
    """
    normal_u2, rest = 0.0, []
    for dist, u, nu in terms:
        u = abs(float(u))
        if u == 0.0:
            continue
        _check_dist(dist)
        if dist == "normal" and not (np.isfinite(nu) and nu <= NU_NORMAL):
            normal_u2 += u * u
        else:
            rest.append((dist, u, float(nu)))
    if normal_u2 > 0:
        rest.append(("normal", math.sqrt(normal_u2), float("inf")))
    if not rest:
        return 0.0
    if len(rest) == 1 and rest[0][0] == "normal" and not np.isfinite(rest[0][2]):
        return float(rest[0][1] * special.ndtri(0.5 * (1 + p)))
    uc = math.sqrt(sum(u * u for _, u, _ in rest))
    h = uc / cells_per_u
    pmf = np.array([1.0])
    for dist, u, nu in rest:
        n = int(math.ceil(_half_span(dist, u, nu) / h)) + 1
        edges = (np.arange(-n, n + 2) - 0.5) * h
        mass = _cell_masses(dist, u, nu, edges)
        pmf = _fft_convolve(pmf, mass)
        pmf = np.clip(pmf, 0.0, None)
    pmf /= pmf.sum()
    n = (pmf.size - 1) // 2
    x = (np.arange(pmf.size) - n) * h
    # P(|Y| <= q): fold the symmetric distribution; cells at +-x carry the mass of [x - h/2, x + h/2]
    folded = pmf[n:].copy()
    folded[1:] += pmf[:n][::-1]
    cum = np.cumsum(folded)
    # mass of |Y| <= x_k + h/2 is cum[k]; interpolate q on the cell boundaries (cell 0 is |Y| <= h/2)
    bounds = x[n:] + 0.5 * h
    i = int(np.searchsorted(cum, p))
    if i == 0:
        return float(bounds[0] * p / cum[0])
    if i >= cum.size:
        return float(bounds[-1])
    f = (p - cum[i - 1]) / (cum[i] - cum[i - 1])
    return float(bounds[i - 1] + f * h)
