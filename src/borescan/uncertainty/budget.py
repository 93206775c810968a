"""GUM budgets: inputs, terms, the combined and expanded uncertainty of each output.

Part of :mod:`borescan.uncertainty` (package doc).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np

from .coverage import (
    _check_dist,
    coverage_factor,
    linear_coverage_interval,
    numerical_tolerance,
    welch_satterthwaite,
)

__all__ = [
    "Input",
    "Term",
    "Combined",
    "combine",
    "Budget",
]


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
