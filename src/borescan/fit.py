"""One least-squares result type and the linear algebra every fit of the project shares.

The three-sensor calibration (:func:`borescan.calibrate.full_fit.fit_full_calibration`), the rod solve
(:func:`borescan.rod.solve_rod`) and the discrepancy workflow
(:func:`borescan.discrepancy.fitting.fit_least_squares`) each minimise a sum of squared
(weighted) residuals by MINPACK's Levenberg-Marquardt (:mod:`borescan.levmar`, the iteration of
``scipy.optimize.least_squares(method="lm")`` on a LAPACK QR); what they report about the optimum
comes from here, once:

- :func:`jacobian_summary`: rank and condition of the column-scaled Jacobian and the unit-noise
  covariance ``(J^T J)^+`` from its SVD (pseudo-inverse over the numerical rank);
- :func:`fit_result`: the :class:`FitResult` (values, standard uncertainties, covariance,
  correlation, residuals, RSS, rank, condition, success, message, AIC / BIC) at an optimum;
- :func:`least_squares_fit`: Levenberg-Marquardt (:func:`borescan.levmar.levenberg_marquardt`) wrapped
  to return a :class:`FitResult`, with an analytic Jacobian or scaled forward differences.

Information criteria of a Gaussian least-squares fit with the variance profiled out
(Burnham & Anderson 2002, Sec. 2.2): ``AIC = n ln(RSS/n) + 2p``, ``BIC = n ln(RSS/n) + p ln n``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from borescan.levmar import levenberg_marquardt

__all__ = [
    "FitResult",
    "JacobianSummary",
    "aic",
    "bic",
    "difference_groups",
    "fit_result",
    "jacobian_summary",
    "least_squares_fit",
]


def bic(rss: float, n: int, p: int) -> float:
    """Bayesian information criterion of a Gaussian least-squares fit: n ln(RSS/n) + p ln(n)."""
    return float(n * np.log(max(rss, 1e-300) / n) + p * np.log(n))


def aic(rss: float, n: int, p: int) -> float:
    """Akaike information criterion of a Gaussian least-squares fit: n ln(RSS/n) + 2p."""
    return float(n * np.log(max(rss, 1e-300) / n) + 2.0 * p)


@dataclass(frozen=True)
class JacobianSummary:
    """What the Jacobian at an optimum says about the parameters.

    rank : numerical rank of the column-scaled Jacobian (singular values above ``rtol`` x largest)
    condition : largest / smallest singular value of the column-scaled Jacobian (inf when singular)
    cov_unit : (p, p) ``(J^T J)^+`` in the original parameter units (multiply by the noise variance)
    singular_values : of the column-scaled Jacobian, descending
    """

    rank: int
    condition: float
    cov_unit: np.ndarray
    singular_values: np.ndarray


def jacobian_summary(J: np.ndarray, *, rtol: float | None = None) -> JacobianSummary:
    """Rank, condition and unit-noise covariance of a least-squares Jacobian (n, p).

    Columns are scaled to unit norm first, so the condition number measures how well the data
    separate the parameters and not their units. ``rtol`` (default ``max(n, p) * eps``, the
    LAPACK convention) sets the rank: directions with singular values below ``rtol * s_max`` are
    left out of the pseudo-inverse.
    """
    J = np.asarray(J, dtype=float)
    p = J.shape[1] if J.ndim == 2 else 0
    if p == 0 or J.shape[0] == 0:
        return JacobianSummary(0, float("nan"), np.zeros((p, p)), np.zeros(0))
    col = np.linalg.norm(J, axis=0)
    col[col == 0] = 1.0
    Js = J / col
    if Js.shape[0] > 4 * p:
        # a tall Jacobian: the SVD of its triangular factor (J = Q R, Householder, backward stable) has
        # the same singular values and right vectors, without forming the (n, p) left vectors (3x faster)
        Js = np.linalg.qr(Js, mode="r")
    _, sv, Vt = np.linalg.svd(Js, full_matrices=False)
    tol = sv[0] * (max(J.shape) * np.finfo(float).eps if rtol is None else rtol)
    keep = sv > tol
    rank = int(np.sum(keep))
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    V = Vt[keep].T
    cov_s = (V / sv[keep] ** 2) @ V.T
    return JacobianSummary(rank, cond, cov_s / np.outer(col, col), sv)


@dataclass
class FitResult:
    """Result of one least-squares fit (the project's only fit result type).

    Attributes
    ----------
    names : free parameter names, in ``x`` order
    x : best-fit values (physical units); u : standard uncertainties (k = 1)
    cov : (p, p) covariance, ``sigma^2 (J^T J)^+`` (``sigma`` given or ``sqrt(RSS / (n - p))``)
    residual : (weighted) residual vector at the optimum; rss : its sum of squares
    n, p : numbers of residuals and free parameters
    rank, condition : of the column-scaled Jacobian (:func:`jacobian_summary`)
    sigma : the noise scale the covariance uses
    success, message, nfev : optimiser status
    extra : further fit-specific information (``singular_values`` of the column-scaled Jacobian, ...)
    """

    names: tuple[str, ...]
    x: np.ndarray
    u: np.ndarray
    cov: np.ndarray
    residual: np.ndarray
    rss: float
    n: int
    p: int
    rank: int = -1
    condition: float = float("nan")
    sigma: float = float("nan")
    success: bool = True
    message: str = ""
    nfev: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def bic(self) -> float:
        """n ln(RSS/n) + p ln(n)."""
        return bic(self.rss, self.n, self.p)

    @property
    def aic(self) -> float:
        """n ln(RSS/n) + 2p."""
        return aic(self.rss, self.n, self.p)

    @property
    def dof(self) -> int:
        """Degrees of freedom n - p."""
        return self.n - self.p

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix (p, p); zero rows/columns where u = 0."""
        u = np.sqrt(np.clip(np.diag(self.cov), 0.0, None))
        uu = np.outer(u, u)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(uu > 0, self.cov / uu, 0.0)
        np.fill_diagonal(r, np.where(u > 0, 1.0, 0.0))
        return r

    def values(self) -> dict[str, float]:
        """Parameter name -> value."""
        return {k: float(v) for k, v in zip(self.names, self.x)}

    def uncertainties(self) -> dict[str, float]:
        """Parameter name -> standard uncertainty."""
        return {k: float(v) for k, v in zip(self.names, self.u)}

    def summary(self) -> dict:
        """JSON-safe diagnostics: n, p, dof, rss, rank, condition, sigma, success, message, nfev, aic, bic."""
        return {
            "n": int(self.n),
            "p": int(self.p),
            "dof": int(self.dof),
            "rss": float(self.rss),
            "rank": int(self.rank),
            "condition": float(self.condition),
            "sigma": float(self.sigma),
            "success": bool(self.success),
            "message": str(self.message),
            "nfev": int(self.nfev),
            "aic": self.aic,
            "bic": self.bic,
        }


def fit_result(
    names: Sequence[str],
    x,
    residual,
    J,
    *,
    sigma: float | None = None,
    success: bool = True,
    message: str = "",
    nfev: int = 0,
    rtol: float | None = None,
    extra: dict | None = None,
) -> FitResult:
    """Return the :class:`FitResult` at an optimum ``x`` with residual vector ``residual`` and Jacobian ``J``.

    ``sigma`` is the noise scale of the residuals (None: estimated as sqrt(RSS / (n - p)));
    ``rtol`` as in :func:`jacobian_summary`.
    """
    names = tuple(names)
    x = np.asarray(x, dtype=float)
    r = np.asarray(residual, dtype=float)
    n, p = int(r.size), int(x.size)
    rss = float(r @ r)
    if sigma is None:
        sigma = float(np.sqrt(rss / max(n - p, 1)))
    extra = dict(extra or {})
    if p:
        js = jacobian_summary(J, rtol=rtol)
        cov = sigma**2 * js.cov_unit
        rank, cond = js.rank, js.condition
        extra.setdefault("singular_values", js.singular_values)
    else:
        cov, rank, cond = np.zeros((0, 0)), 0, float("nan")
    u = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return FitResult(
        names,
        x,
        u,
        cov,
        r,
        rss,
        n,
        p,
        rank,
        cond,
        float(sigma),
        bool(success),
        str(message),
        int(nfev),
        extra,
    )


def least_squares_fit(
    fun: Callable[[np.ndarray], np.ndarray],
    x0: Sequence[float],
    names: Sequence[str],
    *,
    jac: Callable[[np.ndarray], np.ndarray] | None = None,
    scale: Sequence[float] | None = None,
    diff_step: float = 1e-4,
    sigma: float | None = None,
    max_nfev: int | None = None,
    xtol: float = 1e-10,
    ftol: float = 1e-12,
    gtol: float = 1e-8,
    sparsity: np.ndarray | None = None,
    fun_stack: Callable[[np.ndarray, list[np.ndarray]], list[np.ndarray]] | None = None,
) -> FitResult:
    """Minimise ``sum(fun(x)**2)`` (Levenberg-Marquardt) and return its :class:`FitResult`.

    With ``jac`` None the Jacobian is taken by forward differences of ``diff_step`` in the
    scaled variables ``x / scale`` (``scale``: typical magnitudes of the parameters), accurate
    when the model is smooth on that scale. ``sparsity`` (bool, residuals x parameters; True
    where a residual may depend on the parameter) lets parameters whose residuals do not overlap
    share one step (:func:`difference_groups`): the same Jacobian, bit for bit, from fewer
    evaluations of ``fun`` when it is right (e.g. one angle per pose, one beam per channel).
    ``fun_stack`` (optional): ``fun_stack(x, xs)`` is ``fun`` at each of the forward differences' steps
    ``xs`` from ``x``, in one call: a model that predicts a stack of states at once, or that takes a small
    step from ``x`` to first order (the tri examination's bore and spindle parameters).
    A failed optimisation is reported in ``success`` and ``message``, not raised.
    """
    names = tuple(names)
    s = np.ones(len(names)) if scale is None else np.asarray(scale, dtype=float)
    z0 = np.asarray(x0, dtype=float) / s
    last: list = [None, None]  # the last point evaluated and its residuals

    def f(z: np.ndarray) -> np.ndarray:
        # the iteration asks for J where it has just evaluated fun (an accepted step), and the
        # differences start from fun there: that point's residuals are not computed twice
        if last[0] is not None and np.array_equal(z, last[0]):
            return last[1]
        out = fun(z * s)
        last[0], last[1] = np.array(z, dtype=float), np.array(out, dtype=float)
        return out

    if jac is None:
        groups = difference_groups(sparsity) if sparsity is not None else [[i] for i in range(z0.size)]
        f_stack = None if fun_stack is None else (lambda z, zs: fun_stack(z * s, [zz * s for zz in zs]))
        jz = _difference_jacobian(f, f_stack, groups, sparsity, diff_step)
    else:

        def jz(z: np.ndarray) -> np.ndarray:
            return np.asarray(jac(z * s)) * s

    if z0.size:
        # least_squares(f, z0, jac=jz, method="lm") to rounding, its QR by LAPACK (borescan.levmar)
        res = levenberg_marquardt(f, z0, jz, max_nfev=max_nfev, xtol=xtol, ftol=ftol, gtol=gtol)
        z, r, Jz, ok, msg, nfev = res.x, res.fun, res.jac, bool(res.success), str(res.message), int(res.nfev)
    else:
        z, r, Jz, ok, msg, nfev = z0, f(z0), np.zeros((0, 0)), True, "nothing to fit", 1
    return fit_result(
        names, z * s, r, Jz / s if z.size else Jz, sigma=sigma, success=ok, message=msg, nfev=nfev
    )


def _difference_jacobian(f, f_stack, groups: list[list[int]], sparsity, step: float):
    """Return the forward-difference Jacobian of ``f`` (:func:`least_squares_fit`'s, in scaled variables).

    One step per group of columns (:func:`difference_groups`); ``f_stack`` (``f_stack(z, zs)``: ``f`` at the
    steps ``zs`` from ``z`` in one call) evaluates the steps together, else ``f`` one step at a time.
    """
    # the residuals each parameter of a shared step moves (a fit's sparsity is fixed: found once)
    support = {i: np.flatnonzero(sparsity[:, i]) for g in groups if len(g) > 1 for i in g}

    def jz(z: np.ndarray) -> np.ndarray:
        f0 = f(z)
        J = np.empty((f0.size, z.size))
        zs = []
        for g in groups:
            zz = z.copy()
            zz[g] += step
            zs.append(zz)
        fs = f_stack(z, zs) if f_stack is not None else (f(zz) for zz in zs)
        rest = None
        for g, fg in zip(groups, fs, strict=True):
            col = (fg - f0) / step
            if len(g) == 1:
                J[:, g[0]] = col
            else:  # each parameter of the group moves only its own residuals; elsewhere the column a
                # step of it alone gives, (f0 - f0) / step: 0, NaN where f0 is NaN
                rest = (f0 - f0) / step if rest is None else rest
                J[:, g] = rest[:, None]
                for i in g:
                    J[support[i], i] = col[support[i]]
        return J

    return jz


def difference_groups(sparsity: np.ndarray) -> list[list[int]]:
    """Columns of a Jacobian that one finite-difference step can share (Curtis, Powell & Reid 1974).

    ``sparsity`` (m, p) bool: True where residual i may depend on parameter j. Greedy, in column
    order: a column joins the first group none of whose columns touches its residuals; a column
    that touches every residual stays alone. Returns the groups, each a list of column indices.
    """
    S = np.asarray(sparsity, dtype=bool)
    groups: list[list[int]] = []
    used: list[np.ndarray] = []
    for j in range(S.shape[1]):
        col = S[:, j]
        for g, u in zip(groups, used):
            if not np.any(u & col):
                g.append(j)
                u |= col
                break
        else:
            groups.append([j])
            used.append(col.copy())
    return groups
