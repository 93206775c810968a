"""Levenberg-Marquardt for tall problems: MINPACK's ``lmder`` (Moré 1978) on a LAPACK QR.

``scipy.optimize.least_squares(method="lm")`` calls MINPACK's ``lmder``, whose QR factorisation
of the Jacobian is column by column (unblocked Fortran) and which receives a copy of the
Jacobian at every evaluation. On a night's joint calibration (475 000 readings x 17 parameters)
that QR takes about 0.5 s of the 0.6 s an iteration costs. Everything ``lmder`` does after the
factorisation needs only the triangular factor R, the permutation and Q^T f, so this module
computes them from one blocked LAPACK QR of the m x (n+1) matrix [J f] (R of [J f] holds R of J
and Q^T f), followed by MINPACK's column-pivoted QR of that small (n+1) x n block: J P = Q R
exactly as ``lmder``'s ``qrfac`` would give up to rounding. The iteration (trust region, ``lmpar``'s
Levenberg-Marquardt parameter, step bound updates, convergence tests, ``mode=1`` scaling by the
Jacobian's column norms, ``factor=100``) follows ``lmder.f`` and ``lmpar.f`` line for line, so the
iterates are MINPACK's to rounding; the damped sub-problem ``qrsolv`` is solved by a QR of the
small (2n x n) stacked matrix [R; sqrt(par) D P] instead of Givens rotations (same factor).

A caller that can form J^T J and J^T f cheaper than J (the calibration's Jacobian has at most seven
non-zero entries a row) passes ``normal``: an iteration then takes R from the Cholesky factor of the
column-scaled J^T J where the scaled J is well conditioned (:data:`NORMAL_COND_MAX`), and factors J
itself from the first iterate where it is not, so an ill-conditioned problem iterates exactly as
without it.

Reference: J. J. Moré, "The Levenberg-Marquardt algorithm: implementation and theory", in
Numerical Analysis, Lecture Notes in Mathematics 630, Springer 1978, pp. 105-116; MINPACK-1
``lmder.f``, ``lmpar.f``, ``qrsolv.f`` (Argonne, 1980).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.linalg import qr, solve_triangular
from scipy.linalg.lapack import dgeqrf, dgeqrf_lwork

__all__ = ["LMResult", "levenberg_marquardt", "qr_of_stacked", "triangle_of_normal_equations"]

#: The messages of ``scipy.optimize.least_squares`` for its status codes (certificates quote them).
MESSAGES = {
    0: "The maximum number of function evaluations is exceeded.",
    1: "`gtol` termination condition is satisfied.",
    2: "`ftol` termination condition is satisfied.",
    3: "`xtol` termination condition is satisfied.",
    4: "Both `ftol` and `xtol` termination conditions are satisfied.",
}
#: MINPACK ``info`` -> ``least_squares`` status (6, 7, 8: the tolerance reached machine precision)
_STATUS = {1: 2, 2: 3, 3: 4, 4: 1, 5: 0, 6: 2, 7: 3, 8: 1}
_EPS = np.finfo(float).eps
_DWARF = np.finfo(float).tiny


@dataclass
class LMResult:
    """What ``least_squares`` returns that the callers use: the solution, r and J there, counts, status."""

    x: np.ndarray
    cost: float
    fun: np.ndarray
    jac: np.ndarray | None
    nfev: int
    njev: int
    status: int
    message: str

    @property
    def success(self) -> bool:
        """Whether the iteration converged (a positive status)."""
        return self.status > 0


#: rows per block of :func:`qr_of_stacked`: a block of [J f] (2048 x up to ~30 columns) stays in the
#: core's cache while LAPACK factors it; one factorisation of the whole tall matrix streams it from
#: memory once per column (``geqrf``'s panel is the whole matrix when n < its block size)
QR_BLOCK_ROWS = 2048


def qr_of_stacked(J: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Return the triangular factor of [J f].

    Return the (n+1) x (n+1) triangular factor of [J f] (LAPACK ``geqrf``): R of J, Q^T f and
    |residual|. Tall matrices are factored by blocks of :data:`QR_BLOCK_ROWS` rows and the blocks'
    triangles stacked and factored again (the tall-skinny QR of Demmel, Grigori, Hoemmen and Langou,
    SIAM J. Sci. Comput. 34 (2012) A206): the same R up to the signs of its rows and rounding, which
    nothing downstream sees (R^T R = [J f]^T [J f]; the step, the column norms and the corner |residual|
    do not depend on the rows' signs).
    """
    m, n = J.shape
    if m <= QR_BLOCK_ROWS:
        return _triangle(_stacked(J, f))
    buf = np.empty((QR_BLOCK_ROWS, n + 1), order="F")
    parts = []
    for s in range(0, m, QR_BLOCK_ROWS):
        rows = min(QR_BLOCK_ROWS, m - s)
        A = buf if rows == QR_BLOCK_ROWS else np.empty((rows, n + 1), order="F")
        A[:, :n] = J[s : s + rows]
        A[:, n] = f[s : s + rows]
        parts.append(_triangle(A)[: min(rows, n + 1)])
    return _triangle(np.asfortranarray(np.vstack(parts)))


#: the largest condition number of the column-scaled Jacobian for which an iteration takes its
#: triangular factor from the normal equations (:func:`triangle_of_normal_equations`): a Cholesky
#: factor of J^T J carries a relative error of about eps cond^2 (2e-6 here) into the step, which the
#: next iterate's exact residuals correct; above it the iteration factors J itself
NORMAL_COND_MAX = 1e5


def triangle_of_normal_equations(JtJ: np.ndarray, Jtf: np.ndarray, ftf: float) -> np.ndarray | None:
    """Return the triangular factor of [J f] from J^T J, J^T f and f^T f, or None.

    R (upper triangular, R^T R = J^T J) is the Cholesky factor of J^T J scaled to unit column norms
    (Cholesky is exact to eps cond^2 of the scaled matrix, van der Sluis 1969), Q^T f solves
    R^T (Q^T f) = J^T f and the corner is sqrt(f^T f - |Q^T f|^2) (0 when rounding makes it
    negative): the factor :func:`qr_of_stacked` returns, up to its rows' signs and rounding. None when
    a column of J is zero or not finite, the Cholesky fails, or the scaled factor's condition number
    exceeds :data:`NORMAL_COND_MAX`: then only a QR of J itself is accurate enough.
    """
    n = JtJ.shape[0]
    d = np.sqrt(np.diag(JtJ))
    if not (np.all(np.isfinite(d)) and np.all(d > 0.0) and np.all(np.isfinite(Jtf))):
        return None
    try:
        Rs = np.linalg.cholesky(JtJ / np.outer(d, d)).T
    except np.linalg.LinAlgError:
        return None
    sv = np.linalg.svd(Rs, compute_uv=False)
    if not sv[-1] * NORMAL_COND_MAX > sv[0]:
        return None
    R0 = np.zeros((n + 1, n + 1))
    R0[:n, :n] = Rs * d
    R0[:n, n] = qtf = solve_triangular(R0[:n, :n], Jtf, trans="T", lower=False, check_finite=False)
    R0[n, n] = np.sqrt(max(ftf - float(qtf @ qtf), 0.0))
    return R0


def _stacked(J: np.ndarray, f: np.ndarray) -> np.ndarray:
    m, n = J.shape
    A = np.empty((m, n + 1), order="F")
    A[:, :n] = J
    A[:, n] = f
    return A


def _triangle(A: np.ndarray) -> np.ndarray:
    """Return the (n+1) x (n+1) triangular factor of the Fortran-ordered A (m x (n+1)); A is overwritten."""
    k = A.shape[1]
    if A.shape[0] < k:  # fewer rows than columns: padded with zero rows
        A = np.asfortranarray(np.vstack([A, np.zeros((k - A.shape[0], k))]))
    lwork, info = dgeqrf_lwork(*A.shape)
    # geqrf itself (scipy.linalg.qr would also build triu of the whole m x (n+1) array)
    a, _, _, info = dgeqrf(A, lwork=int(lwork), overwrite_a=True)
    if info != 0:
        raise ValueError(f"LAPACK dgeqrf failed (info {info})")
    return np.triu(a[:k])


def _enorm(v: np.ndarray) -> float:
    return float(np.sqrt(np.dot(v, v)))


def _qrsolv(R: np.ndarray, perm: np.ndarray, d: np.ndarray, qtb: np.ndarray):
    """x minimising |J x - b|^2 + |D x|^2 from J P = Q R, Q^T b (``qrsolv.f``).

    Returns x and the triangular factor S of [R; D P] (S^T S = R^T R + P^T D^2 P).
    """
    n = R.shape[1]
    Q2, S = np.linalg.qr(np.vstack([R, np.diag(d[perm])]), mode="reduced")
    w = Q2.T[:, :n] @ qtb
    return _back_substitute(S, w, perm), S


def _back_substitute(T: np.ndarray, b: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """Return x with x[perm] = T^-1 b for upper triangular T.

    x with x[perm] = T^-1 b for upper triangular T; from the first zero diagonal on, the
    components are 0 (MINPACK's least-squares solution of a singular triangle).
    """
    n = T.shape[1]
    zero = np.flatnonzero(np.diag(T) == 0.0)
    nsing = int(zero[0]) if zero.size else n
    z = np.zeros(n)
    if nsing:
        z[:nsing] = solve_triangular(T[:nsing, :nsing], b[:nsing], lower=False, check_finite=False)
    x = np.empty(n)
    x[perm] = z
    return x


def _lmpar(R, perm, diag, qtb, delta, par):
    """Return the Levenberg-Marquardt parameter and step for trust radius ``delta`` (``lmpar.f``)."""
    x = _back_substitute(R, qtb, perm)  # the Gauss-Newton step
    it = 0
    dx = diag * x
    dxnorm = _enorm(dx)
    fp = dxnorm - delta
    if fp <= 0.1 * delta:
        return 0.0, x
    parl = 0.0
    if np.all(np.diag(R) != 0.0):  # full rank: the lower bound of lmpar.f
        w = diag[perm] * (dx[perm] / dxnorm)
        w = solve_triangular(R, w, trans="T", lower=False, check_finite=False)
        t = _enorm(w)
        parl = ((fp / delta) / t) / t
    w = (R.T @ qtb) / diag[perm]
    gnorm = _enorm(w)
    paru = gnorm / delta
    if paru == 0.0:
        paru = _DWARF / min(delta, 0.1)
    par = min(max(par, parl), paru)
    if par == 0.0:
        par = gnorm / dxnorm
    while True:
        it += 1
        if par == 0.0:
            par = max(_DWARF, 0.001 * paru)
        x, S = _qrsolv(R, perm, np.sqrt(par) * diag, qtb)
        dx = diag * x
        dxnorm = _enorm(dx)
        t = fp
        fp = dxnorm - delta
        if abs(fp) <= 0.1 * delta or (parl == 0.0 and fp <= t and t < 0.0) or it == 10:
            return par, x
        w = diag[perm] * (dx[perm] / dxnorm)
        w = solve_triangular(S, w, trans="T", lower=False, check_finite=False)
        t = _enorm(w)
        parc = ((fp / delta) / t) / t
        if fp > 0.0:
            parl = max(parl, par)
        if fp < 0.0:
            paru = min(paru, par)
        par = max(parl, par + parc)


def levenberg_marquardt(  # noqa: C901 (MINPACK lmder's iteration, kept step for step)
    fun: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    jac: Callable[[np.ndarray], np.ndarray],
    *,
    xtol: float = 1e-8,
    ftol: float = 1e-8,
    gtol: float = 1e-8,
    max_nfev: int | None = None,
    factor: float = 100.0,
    jac_at_solution: bool = True,
    normal: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
) -> LMResult:
    """Minimise ``0.5 |fun(x)|^2`` as ``least_squares(fun, x0, jac=jac, method="lm", x_scale="jac")``.

    Same iteration, tolerances, counts (``nfev`` function evaluations including the first, ``njev``
    Jacobian evaluations inside the iteration), status codes and messages; ``fun`` and ``jac`` of
    the result are at ``x`` (``jac_at_solution=False``: ``jac`` is the last one evaluated, which may be
    at an earlier iterate, for callers that need only ``x`` and ``cost``; it saves one evaluation, and
    it is None when every iteration took the normal equations).

    ``normal(x, f)``, when given, returns J^T J and J^T f at ``x`` (``f`` the residuals there) without
    forming J: an iteration takes its triangular factor from them where J is well enough conditioned
    (:func:`triangle_of_normal_equations`); from their first refusal on, every iteration factors
    ``jac`` itself (J's conditioning changes little between iterates). For a tall J with few non-zero entries
    per row (a calibration's readings) they cost a fraction of J and its QR.
    Raises ``ValueError`` when the residuals at ``x0`` are not finite.
    """
    x = np.array(x0, dtype=float)
    n = x.size
    if max_nfev is None:
        max_nfev = 100 * n
    fvec = np.asarray(fun(x), dtype=float)
    if not np.all(np.isfinite(fvec)):
        raise ValueError("Residuals are not finite in the initial point.")
    if fvec.size < n:
        raise ValueError(
            f"{fvec.size} residuals for {n} variables: Levenberg-Marquardt needs at least as many"
        )
    nfev, njev = 1, 0
    fnorm = _enorm(fvec)
    par = 0.0
    it = 1
    info = 0
    diag = np.ones(n)
    delta = xnorm = 0.0
    J = None
    x_of_J = None
    while info == 0:
        R0 = None if normal is None else triangle_of_normal_equations(*normal(x, fvec), fnorm**2)
        if R0 is None:
            normal = None  # refused once (ill-conditioned): J itself for the rest, not both each time
            J = np.asarray(jac(x), dtype=float)
            x_of_J = x.copy()
            R0 = qr_of_stacked(J, fvec)
        njev += 1
        acnorm = np.sqrt(np.sum(R0[:, :n] ** 2, axis=0))  # column norms of J
        Q2, R, perm = qr(R0[:, :n], mode="economic", pivoting=True, check_finite=False)
        R = R[:n]
        qtf = Q2.T[:n] @ R0[:, n]
        if it == 1:
            diag = np.where(acnorm == 0.0, 1.0, acnorm)
            xnorm = _enorm(diag * x)
            delta = factor * xnorm if xnorm != 0.0 else factor
        gnorm = 0.0
        if fnorm != 0.0:
            g = R.T @ (qtf / fnorm)
            an = acnorm[perm]
            ok = an != 0.0
            if ok.any():
                gnorm = float(np.max(np.abs(g[ok] / an[ok])))
        if gnorm <= gtol:
            info = 4
            break
        diag = np.maximum(diag, acnorm)
        while True:
            par, step = _lmpar(R, perm, diag, qtf, delta, par)
            step = -step
            x_new = x + step
            pnorm = _enorm(diag * step)
            if it == 1:
                delta = min(delta, pnorm)
            f_new = np.asarray(fun(x_new), dtype=float)
            nfev += 1
            fnorm1 = _enorm(f_new)
            actred = 1.0 - (fnorm1 / fnorm) ** 2 if 0.1 * fnorm1 < fnorm else -1.0
            t1 = _enorm(R @ step[perm]) / fnorm
            t2 = (np.sqrt(par) * pnorm) / fnorm
            prered = t1**2 + t2**2 / 0.5
            dirder = -(t1**2 + t2**2)
            ratio = actred / prered if prered != 0.0 else 0.0
            if ratio <= 0.25:
                t = 0.5 if actred >= 0.0 else 0.5 * dirder / (dirder + 0.5 * actred)
                if 0.1 * fnorm1 >= fnorm or t < 0.1:
                    t = 0.1
                delta = t * min(delta, pnorm / 0.1)
                par = par / t
            elif par == 0.0 or ratio >= 0.75:
                delta = pnorm / 0.5
                par = 0.5 * par
            if ratio >= 1e-4:
                x, fvec, fnorm = x_new, f_new, fnorm1
                xnorm = _enorm(diag * x)
                it += 1
            small = abs(actred) <= ftol and prered <= ftol and 0.5 * ratio <= 1.0
            if small:
                info = 1
            if delta <= xtol * xnorm:
                info = 3 if small else 2
            if info:
                break
            if nfev >= max_nfev:  # as in lmder.f, a later test overrides an earlier one
                info = 5
            if abs(actred) <= _EPS and prered <= _EPS and 0.5 * ratio <= 1.0:
                info = 6
            if delta <= _EPS * xnorm:
                info = 7
            if gnorm <= _EPS:
                info = 8
            if info or ratio >= 1e-4:
                break
    if jac_at_solution and (x_of_J is None or not np.array_equal(x_of_J, x)):
        J = np.asarray(jac(x), dtype=float)
    status = _STATUS[info]
    return LMResult(
        x=x,
        cost=0.5 * float(np.dot(fvec, fvec)),
        fun=fvec,
        jac=J,
        nfev=nfev,
        njev=njev,
        status=status,
        message=MESSAGES[status],
    )
