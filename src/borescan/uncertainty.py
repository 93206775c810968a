"""GUM uncertainty budgets: inputs, sensitivities, combination, coverage factor, Monte Carlo check.

Pure functions and small value types on numpy arrays; what the inputs of a calibration or a
diameter are is decided by their callers (:mod:`borescan.stages.calibration_fit`,
:mod:`borescan.measure`).

Model (JCGM 100:2008, "GUM"): an output vector y = f(x) of m quantities, linearised at the
estimates, y - y0 = sum_i s_i (x_i - x_i0). Each input x_i is a :class:`Term`: its
:class:`Input` (estimate, standard uncertainty u(x_i), distribution, degrees of freedom nu_i,
type A or B) and its sensitivity vector s_i = dy/dx_i (m,); an input that is itself the
estimate of a vector (the least-squares fit of a calibration, Type A) carries the covariance
(m, m) it gives the outputs instead. The inputs are independent of each other (correlated
physical quantities are one input, or one vector term); the same physical quantity used twice
(the gauge of a calibration and of a later verification) has one ``key`` and its sensitivities
add (:meth:`Budget.merged`).

For a scalar output (one of y, or a combination j . y):

- contribution u_i(y) = |c_i| u(x_i), c_i = j . s_i (GUM 5.1.3); for a vector term sqrt(j^T C_i j);
- combined standard uncertainty u_c(y) = sqrt(sum u_i(y)^2) (GUM Eq. 10 with independent inputs);
- effective degrees of freedom nu_eff = u_c^4 / sum(u_i^4 / nu_i) (Welch-Satterthwaite, GUM G.4.1
  Eq. G.2b), truncated to the next lower integer for Student's t (GUM G.4.1 note);
- coverage factor k_GUF = t_p(nu_eff) (GUM G.4.1, G.6.4), expanded uncertainty U = k u_c.

The t-based factor assumes the output is close to normal (GUM G.6.6). Where one rectangular or
U-shaped contribution dominates it is not (a lone rectangular has p = 100 % at k = 2): the
distribution of the linearised output, the convolution of the stated input distributions (each
Type A input a scaled and shifted t_nu, JCGM 101:2008 "GUM S1" 6.4.9), is evaluated numerically
(:func:`linear_coverage_interval`) and, following GUM S1 §8, the GUF interval y +- k_GUF u_c is
kept when its end points agree with the propagated ones within the numerical tolerance of u_c
at two significant digits; otherwise the coverage factor of the propagated distribution is used
and the result says so (``Combined.method``).

:func:`monte_carlo` propagates distributions through any (non-linear) model by GUM S1 Monte
Carlo; :func:`s1_validate` is the comparison of GUM S1 §8. Both check the linearised budgets in
the tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy import (
    special,
)  # the distribution functions themselves: scipy.stats and scipy.signal cost ~1.3 s of
# imports in every process that loads this module (each stage job and worker), for nothing these need

__all__ = [
    "DISTRIBUTIONS",
    "standard_uncertainty",
    "welch_satterthwaite",
    "coverage_factor",
    "numerical_tolerance",
    "linear_coverage_interval",
    "Input",
    "Term",
    "Combined",
    "Budget",
    "combine",
    "draw",
    "MonteCarloResult",
    "monte_carlo",
    "s1_validate",
    "round_uncertainty",
    "format_value",
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


# --------------------------------------------------------------------------- budget types


@dataclass(frozen=True)
class Input:
    """One input quantity of a measurement model.

    key : identity of the physical quantity (the same gauge or sensor used twice has one key)
    quantity, symbol, unit : what it is
    estimate : its value (None where it is a vector or has none, e.g. an error of estimate 0 shown as 0)
    u : standard uncertainty [unit]
    distribution : one of :data:`DISTRIBUTIONS` (``normal`` with finite ``dof``: Student's t)
    dof : degrees of freedom (inf: known well enough, GUM G.4.2)
    type : ``"A"`` (from the scatter of data) or ``"B"`` (other information)
    source : where the estimate and u come from (certificate, data sheet, config key)
    """

    key: str
    quantity: str
    symbol: str
    unit: str
    estimate: float | None
    u: float
    distribution: str
    dof: float = float("inf")
    type: str = "B"
    source: str = ""

    def __post_init__(self) -> None:
        _check_dist(self.distribution)
        if self.type not in ("A", "B"):
            raise ValueError(f"uncertainty type must be 'A' or 'B', got {self.type!r}")
        if not (self.u >= 0.0):
            raise ValueError(f"{self.key}: standard uncertainty must be >= 0, got {self.u}")

    def to_dict(self) -> dict:
        """Return the input as JSON-ready data (:meth:`from_dict` reads it back)."""
        return {
            "key": self.key,
            "quantity": self.quantity,
            "symbol": self.symbol,
            "unit": self.unit,
            "estimate": self.estimate,
            "standard_uncertainty": self.u,
            "distribution": self.distribution,
            "degrees_of_freedom": None if not np.isfinite(self.dof) else float(self.dof),
            "type": self.type,
            "source": self.source,
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> "Input":
        """Return the input written by :meth:`to_dict`."""
        dof = d.get("degrees_of_freedom")
        return cls(
            d["key"],
            d["quantity"],
            d["symbol"],
            d["unit"],
            d.get("estimate"),
            float(d["standard_uncertainty"]),
            d["distribution"],
            float("inf") if dof is None else float(dof),
            d.get("type", "B"),
            d.get("source", ""),
        )


def _array(x) -> np.ndarray | None:
    """Return a JSON list (nested for a matrix; None for NaN) as a float array; None stays None."""
    if x is None:
        return None

    def nan(v):
        return [nan(w) for w in v] if isinstance(v, list) else (np.nan if v is None else float(v))

    return np.array(nan(list(x)), dtype=float)


@dataclass(frozen=True)
class Term:
    """An input's effect on the m outputs of a :class:`Budget`.

    Exactly one of ``sensitivity`` (m,) [output unit / input unit] (y moves by s (x - x0)) and
    ``cov`` (m, m) [output units^2] (an input that is the estimate of a vector: its covariance
    as seen by the outputs). ``note`` explains a term that contributes nothing on purpose.
    """

    input: Input
    sensitivity: np.ndarray | None = None
    cov: np.ndarray | None = None
    note: str = ""

    def __post_init__(self) -> None:
        if (self.sensitivity is None) == (self.cov is None):
            raise ValueError(f"{self.input.key}: give exactly one of sensitivity and cov")
        if self.sensitivity is not None:
            object.__setattr__(self, "sensitivity", np.atleast_1d(np.asarray(self.sensitivity, dtype=float)))
        else:
            c = np.atleast_2d(np.asarray(self.cov, dtype=float))
            object.__setattr__(self, "cov", 0.5 * (c + c.T))

    @property
    def m(self) -> int:
        """Number of outputs the term reaches."""
        return int(self.sensitivity.size if self.sensitivity is not None else self.cov.shape[0])

    def covariance(self) -> np.ndarray:
        """Covariance (m, m) this term gives the outputs."""
        if self.cov is not None:
            return self.cov
        s = self.sensitivity
        return np.outer(s, s) * self.input.u**2

    def along(self, j) -> tuple[float | None, float]:
        """(sensitivity c = j . s or None for a vector term, contribution u_i >= 0) of the output j . y."""
        j = np.asarray(j, dtype=float)
        if self.sensitivity is not None:
            c = float(j @ self.sensitivity)
            return c, abs(c) * self.input.u
        return None, float(math.sqrt(max(float(j @ self.cov @ j), 0.0)))

    def mapped(self, A) -> "Term":
        """Return the term for outputs y' = A y (A (m', m))."""
        A = np.atleast_2d(np.asarray(A, dtype=float))
        if self.sensitivity is not None:
            return replace(self, sensitivity=A @ self.sensitivity)
        return replace(self, cov=A @ self.cov @ A.T)

    def to_dict(self) -> dict:
        """Return the term as JSON-ready data (:meth:`from_dict` reads it back)."""
        return {
            "input": self.input.to_dict(),
            "sensitivity": None if self.sensitivity is None else self.sensitivity.tolist(),
            "cov": None if self.cov is None else self.cov.tolist(),
            "note": self.note,
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> "Term":
        """Return the term written by :meth:`to_dict`."""
        return cls(
            Input.from_dict(d["input"]), _array(d.get("sensitivity")), _array(d.get("cov")), d.get("note", "")
        )


@dataclass(frozen=True)
class Combined:
    """Combined standard uncertainty and expanded uncertainty of one output.

    u : u_c(y); nu_eff : Welch-Satterthwaite (not truncated; inf possible); p : coverage probability;
    k_guf : t_p(nu_eff); k_propagated : from the propagated distribution of the linear model;
    k, U : the coverage factor used and U = k u; method : ``"GUF"`` (validated by GUM S1 §8) or
    ``"propagation of distributions"``; dominant : key of the largest contribution.
    """

    u: float
    nu_eff: float
    p: float
    k_guf: float
    k_propagated: float
    k: float
    U: float
    method: str
    dominant: str = ""

    def to_dict(self) -> dict:
        """Return the combined uncertainty as JSON-ready data."""
        return {
            "standard_uncertainty": self.u,
            "effective_degrees_of_freedom": None if not np.isfinite(self.nu_eff) else self.nu_eff,
            "coverage_probability": self.p,
            "coverage_factor_guf": self.k_guf,
            "coverage_factor_propagated": self.k_propagated,
            "coverage_factor": self.k,
            "expanded_uncertainty": self.U,
            "coverage_method": self.method,
            "dominant_input": self.dominant,
        }


def combine(
    contributions: Sequence[tuple[float, float, str]], p: float, keys: Sequence[str] | None = None
) -> Combined:
    """Combine independent contributions of one output.

    Parameters
    ----------
    contributions : (u_i [unit of y], nu_i, distribution) per input
    p : coverage probability
    keys : names of the inputs (for ``Combined.dominant``)

    Returns
    -------
    Combined : u_c, Welch-Satterthwaite nu_eff, k_GUF = t_p(nu_eff) (truncated nu), the coverage
    factor of the propagated distribution of the linear model (:func:`linear_coverage_interval`),
    and the one used: k_GUF when the GUF interval's end points lie within the numerical tolerance
    of u_c at two significant digits of the propagated ones (GUM S1 §8), else the propagated one.
    """
    u = np.array([abs(float(c[0])) for c in contributions])
    nu = np.array([float(c[1]) for c in contributions])
    uc = float(math.sqrt(float(np.sum(u**2))))
    nu_eff = welch_satterthwaite(u, nu) if u.size else float("inf")
    k_guf = coverage_factor(p, nu_eff)
    if uc == 0.0:
        return Combined(0.0, nu_eff, p, k_guf, k_guf, k_guf, 0.0, "GUF", "")
    q = linear_coverage_interval([(c[2], abs(c[0]), c[1]) for c in contributions], p)
    k_prop = q / uc
    delta = numerical_tolerance(uc, 2)
    validated = abs(k_guf * uc - q) <= delta
    k = k_guf if validated else k_prop
    dom = str(keys[int(np.argmax(u))]) if keys is not None and len(keys) else ""
    return Combined(
        uc, nu_eff, p, k_guf, k_prop, k, k * uc, "GUF" if validated else "propagation of distributions", dom
    )


@dataclass
class Budget:
    """Uncertainty budget of m outputs y (names, units, estimates) as independent :class:`Term` s."""

    outputs: tuple[str, ...]
    units: tuple[str, ...]
    estimates: np.ndarray
    terms: list[Term] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.outputs = tuple(self.outputs)
        self.units = tuple(self.units)
        self.estimates = np.atleast_1d(np.asarray(self.estimates, dtype=float))
        m = len(self.outputs)
        if len(self.units) != m or self.estimates.size != m:
            raise ValueError("outputs, units and estimates must have one entry per output")
        for t in self.terms:
            if t.m != m:
                raise ValueError(f"term {t.input.key} has {t.m} outputs, the budget {m}")

    @property
    def m(self) -> int:
        """Number of outputs."""
        return len(self.outputs)

    def add(self, term: Term) -> "Budget":
        """Return the budget with ``term`` added (its outputs must be the budget's)."""
        if term.m != self.m:
            raise ValueError(f"term {term.input.key} has {term.m} outputs, the budget {self.m}")
        self.terms.append(term)
        return self

    def covariance(self) -> np.ndarray:
        """Return combined covariance (m, m) of the outputs: the sum of every term's."""
        out = np.zeros((self.m, self.m))
        for t in self.terms:
            out += t.covariance()
        return out

    def u(self) -> np.ndarray:
        """Return combined standard uncertainty of each output (m,)."""
        return np.sqrt(np.clip(np.diag(self.covariance()), 0.0, None))

    def mapped(self, A, outputs: Sequence[str], units: Sequence[str], estimates) -> "Budget":
        """Return the budget of y' = A y (+ a constant): every term mapped by A (m', m)."""
        return Budget(
            tuple(outputs), tuple(units), np.asarray(estimates, float), [t.mapped(A) for t in self.terms]
        )

    def merged(self) -> "Budget":
        """Terms with the same input key united: sensitivities added (the same quantity used twice)."""
        order, by_key = [], {}
        for t in self.terms:
            k = t.input.key
            if k not in by_key:
                by_key[k] = t
                order.append(k)
                continue
            prev = by_key[k]
            if prev.sensitivity is None or t.sensitivity is None:
                raise ValueError(f"input {k} appears twice as a vector term; they cannot be merged")
            by_key[k] = replace(
                prev,
                sensitivity=prev.sensitivity + t.sensitivity,
                note="; ".join(x for x in (prev.note, t.note) if x),
            )
        return Budget(self.outputs, self.units, self.estimates, [by_key[k] for k in order])

    def rows(self, j) -> list[dict]:
        """Budget table of the output j . y (j an index or an (m,) vector): one row per term."""
        j = self._vec(j)
        rows = []
        for t in self.terms:
            c, contrib = t.along(j)
            d = t.input.to_dict()
            d.update(
                sensitivity_coefficient=c,
                contribution=contrib,
                distribution=t.input.distribution if t.sensitivity is not None else "multivariate normal",
                note=t.note,
            )
            rows.append(d)
        return rows

    def combined(self, j, p: float) -> Combined:
        """:func:`combine` of the output j . y (index or (m,) vector)."""
        j = self._vec(j)
        contribs, keys = [], []
        for t in self.terms:
            _, ui = t.along(j)
            dist = t.input.distribution if t.sensitivity is not None else "normal"
            contribs.append((ui, t.input.dof, dist))
            keys.append(t.input.key)
        return combine(contribs, p, keys)

    def _vec(self, j) -> np.ndarray:
        if isinstance(j, (int, np.integer)):
            e = np.zeros(self.m)
            e[int(j)] = 1.0
            return e
        j = np.asarray(j, dtype=float)
        if j.shape != (self.m,):
            raise ValueError(f"output combination must have shape ({self.m},), got {j.shape}")
        return j

    def to_dict(self) -> dict:
        """Return the budget as JSON-ready data (:meth:`from_dict` reads it back)."""
        return {
            "outputs": list(self.outputs),
            "units": list(self.units),
            "estimates": self.estimates.tolist(),
            "terms": [t.to_dict() for t in self.terms],
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> "Budget":
        """Return the budget written by :meth:`to_dict`."""
        return cls(
            tuple(d["outputs"]),
            tuple(d["units"]),
            np.array(d["estimates"], dtype=float),
            [Term.from_dict(t) for t in d["terms"]],
        )


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
