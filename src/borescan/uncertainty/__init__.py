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

from .coverage import (
    DISTRIBUTIONS,
    standard_uncertainty,
    welch_satterthwaite,
    coverage_factor,
    chi2_quantile,
    numerical_tolerance,
    linear_coverage_interval,
)
from .budget import Input, Term, Combined, Budget, combine
from .montecarlo import draw, MonteCarloResult, monte_carlo, s1_validate, round_uncertainty, format_value

__all__ = [
    "DISTRIBUTIONS",
    "standard_uncertainty",
    "welch_satterthwaite",
    "coverage_factor",
    "chi2_quantile",
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
