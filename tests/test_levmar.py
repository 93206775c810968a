"""borescan.levmar: MINPACK's lmder on a LAPACK QR, checked against scipy's least_squares(method="lm").

The iteration is a line-for-line port, so on well-posed problems the evaluation counts are MINPACK's
(within the one step that rounding decides at a minimum reached to machine precision) and the
solution is the same far below its standard uncertainty.
"""

import numpy as np
import pytest
from scipy.optimize import least_squares

from borescan.levmar import MESSAGES, levenberg_marquardt, qr_of_stacked


def _problems():
    rng = np.random.default_rng(20261124)
    t = np.linspace(0.0, 4.0, 2000)
    y = 2.0 * np.exp(-1.3 * t) + 0.5 * np.exp(-0.2 * t) + rng.normal(0, 0.01, t.size)

    def exp_f(p):
        return p[0] * np.exp(-p[1] * t) + p[2] * np.exp(-p[3] * t) - y

    def exp_j(p):
        e1, e3 = np.exp(-p[1] * t), np.exp(-p[3] * t)
        return np.column_stack([e1, -p[0] * t * e1, e3, -p[2] * t * e3])

    yield "two exponentials", exp_f, exp_j, np.array([1.0, 1.0, 1.0, 0.1])
    th = rng.uniform(0, 2 * np.pi, 500)
    xy = np.c_[3 + 10 * np.cos(th), -2 + 10 * np.sin(th)] + rng.normal(0, 0.05, (500, 2))

    def circ_f(p):
        return np.hypot(xy[:, 0] - p[0], xy[:, 1] - p[1]) - p[2]

    def circ_j(p):
        d = np.hypot(xy[:, 0] - p[0], xy[:, 1] - p[1])
        return np.column_stack([-(xy[:, 0] - p[0]) / d, -(xy[:, 1] - p[1]) / d, -np.ones_like(d)])

    yield "circle from far", circ_f, circ_j, np.array([0.0, 0.0, 1.0])
    yield (
        "Rosenbrock",
        lambda p: np.array([10 * (p[1] - p[0] ** 2), 1 - p[0]]),
        lambda p: np.array([[-20 * p[0], 10.0], [-1.0, 0.0]]),
        np.array([-1.2, 1.0]),
    )
    tt = np.linspace(0, 1, 50)
    yy = 1e3 * np.sin(3 * tt) + 1e-3 * tt
    yield (
        "badly scaled",
        lambda p: p[0] * np.sin(p[1] * tt) + p[2] * tt - yy,
        lambda p: np.column_stack([np.sin(p[1] * tt), p[0] * tt * np.cos(p[1] * tt), tt]),
        np.array([900.0, 2.9, 0.0]),
    )
    # a tall harmonic fit like the calibration's: 60 000 readings, 9 parameters, Fortran-ordered J
    phi = np.linspace(0, 40 * np.pi, 60_000)
    truth = np.array([0.3, -0.2, 0.05, 0.01, -0.02, 1.001, 0.4, 5.0, 0.002])

    def harm(p):
        a = p[5] * phi + p[6]
        return (
            p[7]
            + p[0] * np.cos(a)
            + p[1] * np.sin(a)
            + p[2] * np.cos(2 * a)
            + p[3] * np.sin(2 * a)
            + p[4] * np.cos(3 * a)
            + p[8] * phi
        )

    yh = harm(truth) + rng.normal(0, 1e-3, phi.size)

    def harm_j(p):
        a = p[5] * phi + p[6]
        da = (
            -p[0] * np.sin(a)
            + p[1] * np.cos(a)
            - 2 * p[2] * np.sin(2 * a)
            + 2 * p[3] * np.cos(2 * a)
            - 3 * p[4] * np.sin(3 * a)
        )
        J = np.empty((phi.size, 9), order="F")
        J[:, 0], J[:, 1], J[:, 2], J[:, 3], J[:, 4] = (
            np.cos(a),
            np.sin(a),
            np.cos(2 * a),
            np.sin(2 * a),
            np.cos(3 * a),
        )
        J[:, 5], J[:, 6], J[:, 7], J[:, 8] = da * phi, da, 1.0, phi
        return J

    yield (
        "tall harmonic",
        (lambda p: harm(p) - yh),
        harm_j,
        truth + np.array([0.02, 0.02, 0, 0, 0, 2e-5, 0.01, 0.01, 0]),
    )


def _rounding_floor_cost(jac, x, ulps=16):
    """Return the cost that a change of ``ulps`` units in the last place of one parameter gives a zero
    residual.

    Two minima whose costs differ by less than this are the same minimum: the residuals' last digits, and so
    costs of about 1e-25, depend on the order in which the CPU's BLAS and libm sum, not on the algorithm.
    """
    step = ulps * np.spacing(np.abs(x))
    return float(np.max(0.5 * np.sum((jac * step) ** 2, axis=0)))


def _assert_same_minimum(a, b, name: str) -> None:
    """Assert that the fits ``a`` (the reference) and ``b`` reached the same minimum.

    Costs equal far below a change of chi-square of one (relative 1e-9), or both at the rounding floor of
    a zero residual, which decides the last digits differently on another CPU or BLAS; and the same
    parameters: far below their standard uncertainty (1e-5 u) where the residual is real, within the
    uncertainty that the rounding floor leaves where the residual is zero (any point there is the minimum).
    """
    floor = _rounding_floor_cost(a.jac, a.x)
    assert abs(b.cost - a.cost) <= 1e-9 * a.cost + floor, name
    zero_residual = a.cost <= floor
    s2 = 2 * max(a.cost, floor) / max(a.fun.size - a.x.size, 1)
    u = np.sqrt(np.diag(np.linalg.inv(a.jac.T @ a.jac)) * s2)
    assert np.all(np.abs(b.x - a.x) <= (1.0 if zero_residual else 1e-5) * u + 1e-12 * np.abs(a.x)), name


@pytest.mark.parametrize("tol", [1e-8, 1e-10, 1e-12])
def test_the_iteration_is_minpacks(tol):
    for name, f, j, x0 in _problems():
        a = least_squares(f, x0, jac=j, method="lm", x_scale="jac", xtol=tol, ftol=tol, gtol=tol)
        b = levenberg_marquardt(f, x0, j, xtol=tol, ftol=tol, gtol=tol)
        # at a minimum reached to machine precision, actred and prered are rounding noise, so whether
        # the ftol test or one more Jacobian (gtol) ends the iteration is decided by rounding
        assert a.success and b.success, name
        assert abs(b.nfev - a.nfev) <= 1 and abs(b.njev - a.njev) <= 1, name
        assert b.message == MESSAGES[b.status]
        _assert_same_minimum(a, b, name)
        np.testing.assert_allclose(b.fun, f(b.x), rtol=0, atol=0)
        np.testing.assert_allclose(b.jac, j(b.x), rtol=0, atol=0)


def test_an_evaluation_limit_stops_it_as_minpack_does():
    name, f, j, x0 = next(p for p in _problems() if p[0] == "Rosenbrock")
    for k in (3, 5, 8):
        a = least_squares(f, x0, jac=j, method="lm", x_scale="jac", max_nfev=k)
        b = levenberg_marquardt(f, x0, j, max_nfev=k)
        assert (b.status, b.success, b.nfev) == (a.status, a.success, a.nfev) == (0, False, k)
        np.testing.assert_allclose(b.x, a.x, rtol=1e-9)


def test_the_triangular_factor_of_the_stacked_matrix():
    rng = np.random.default_rng(7)
    J = np.asfortranarray(rng.normal(size=(5000, 6)) * np.array([1, 10, 1e-3, 1e3, 1, 1]))
    f = rng.normal(size=5000)
    R = qr_of_stacked(J, f)
    A = np.column_stack([J, f])
    assert R.shape == (7, 7) and np.allclose(np.tril(R, -1), 0.0)
    np.testing.assert_allclose(R.T @ R, A.T @ A, rtol=1e-11, atol=1e-9)
    # the corner is the least-squares residual norm
    x, *_ = np.linalg.lstsq(J, f, rcond=None)
    assert abs(R[6, 6]) == pytest.approx(np.linalg.norm(J @ x - f), rel=1e-10)
    # fewer rows than columns + 1: padded with zero rows
    Rs = qr_of_stacked(J[:3], f[:3])
    assert Rs.shape == (7, 7)
    np.testing.assert_allclose(Rs.T @ Rs, A[:3].T @ A[:3], atol=1e-6)


def test_the_blocked_factor_is_the_one_factor_of_the_whole_matrix():
    """Blocks of QR_BLOCK_ROWS, the last one shorter than a row per column: R of one LAPACK QR of [J f]."""
    from borescan.levmar import QR_BLOCK_ROWS

    rng = np.random.default_rng(11)
    n = 12
    m = 3 * QR_BLOCK_ROWS + 5  # the last block has 5 rows for 13 columns
    J = np.asfortranarray(rng.normal(size=(m, n)) * np.logspace(-3, 3, n))
    f = rng.normal(size=m)
    R = qr_of_stacked(J, f)
    A = np.column_stack([J, f])
    _, R_one = np.linalg.qr(A)
    # unique up to the signs of its rows: compare |R| and the Gram matrix, to rounding
    scale = np.abs(R_one).max(axis=1, keepdims=True)
    np.testing.assert_allclose(np.abs(R) / scale, np.abs(R_one) / scale, rtol=0, atol=1e-12)
    np.testing.assert_allclose(R.T @ R, A.T @ A, rtol=1e-11, atol=1e-9)
    x, *_ = np.linalg.lstsq(J, f, rcond=None)
    assert abs(R[n, n]) == pytest.approx(np.linalg.norm(J @ x - f), rel=1e-10)


def test_non_finite_start_is_refused():
    with pytest.raises(ValueError, match="not finite"):
        levenberg_marquardt(
            lambda p: np.array([np.nan, 1.0, p[0]]), np.array([1.0]), lambda p: np.ones((3, 1))
        )


def test_without_the_jacobian_at_the_solution_the_solution_is_the_same():
    name, f, j, x0 = next(p for p in _problems() if p[0] == "two exponentials")
    calls = []

    def jc(p):
        calls.append(p.copy())
        return j(p)

    a = levenberg_marquardt(f, x0, j)
    b = levenberg_marquardt(f, x0, jc, jac_at_solution=False)
    assert np.array_equal(a.x, b.x) and a.cost == b.cost and len(calls) == b.njev


def test_a_rank_deficient_jacobian_reaches_the_least_squares_cost():
    """Two identical columns: the minimiser is not unique, the minimum cost is (MINPACK's
    truncated back-substitution from the first zero diagonal, as lmpar.f does).
    """
    rng = np.random.default_rng(3)
    X = rng.normal(size=(300, 3))
    X = np.c_[X, X[:, 0]]
    b = rng.normal(size=300)
    res = levenberg_marquardt(lambda p: X @ p - b, np.zeros(4), lambda p: X)
    x_ls, *_ = np.linalg.lstsq(X, b, rcond=None)
    assert res.success
    assert res.cost == pytest.approx(0.5 * np.sum((X @ x_ls - b) ** 2), rel=1e-12)


def test_the_factor_from_the_normal_equations_is_the_factor_of_the_stacked_matrix():
    """R from J^T J, J^T f, f^T f (Cholesky of the column-scaled J^T J) against the QR of [J f]: the
    same up to its rows' signs, within 1e-10 of each row's largest entry (eps cond^2 of the scaled J,
    about 1e2 here); None for a zero column or a scaled condition number above NORMAL_COND_MAX.
    """
    from borescan.levmar import NORMAL_COND_MAX, triangle_of_normal_equations

    rng = np.random.default_rng(13)
    J = np.asfortranarray(rng.normal(size=(20_000, 9)) * np.logspace(-4, 4, 9))
    f = rng.normal(size=20_000)
    R = triangle_of_normal_equations(J.T @ J, J.T @ f, float(f @ f))
    R_qr = qr_of_stacked(J, f)
    scale = np.abs(R_qr).max(axis=1, keepdims=True)
    np.testing.assert_allclose(np.abs(R) / scale, np.abs(R_qr) / scale, rtol=0, atol=1e-10)
    assert np.all(np.diag(R)[:-1] > 0)
    J0 = J.copy()
    J0[:, 3] = 0.0
    assert triangle_of_normal_equations(J0.T @ J0, J0.T @ f, float(f @ f)) is None
    # two columns that differ by 1e-6 of their norm: scaled condition number about 1e6
    Jc = J.copy()
    ratio = np.linalg.norm(Jc[:, 4]) / np.linalg.norm(Jc[:, 5])
    Jc[:, 4] = Jc[:, 5] * ratio * (1 + 1e-6 * rng.normal(size=Jc.shape[0]))
    assert np.linalg.cond(Jc / np.linalg.norm(Jc, axis=0)) > NORMAL_COND_MAX
    assert triangle_of_normal_equations(Jc.T @ Jc, Jc.T @ f, float(f @ f)) is None


def test_the_iteration_from_the_normal_equations_is_the_iteration_from_the_jacobian():
    """``normal=`` (the factor from J^T J and J^T f) against the factor of J, on every test problem:
    counts within one, the same minimum (as in test_the_iteration_is_minpacks); ``fun`` and ``jac`` of
    the result at its ``x``.
    """
    for name, f, j, x0 in _problems():
        calls = []

        def normal(x, fx, j=j, calls=calls):
            calls.append(1)
            J = j(x)
            return J.T @ J, J.T @ fx

        a = levenberg_marquardt(f, x0, j, xtol=1e-10, ftol=1e-10, gtol=1e-10)
        b = levenberg_marquardt(f, x0, j, xtol=1e-10, ftol=1e-10, gtol=1e-10, normal=normal)
        assert a.success and b.success, name
        assert len(calls) == b.njev and abs(b.nfev - a.nfev) <= 1 and abs(b.njev - a.njev) <= 1, name
        _assert_same_minimum(a, b, name)
        np.testing.assert_array_equal(b.fun, f(b.x))
        np.testing.assert_array_equal(b.jac, j(b.x))


def test_an_ill_conditioned_jacobian_is_factored_itself():
    """Where the normal equations are refused (scaled condition number above NORMAL_COND_MAX) every
    iteration factors J: the iterates are those without ``normal``, bit for bit, and the normal
    equations are not formed again after their first refusal.
    """
    from borescan.levmar import NORMAL_COND_MAX

    rng = np.random.default_rng(17)
    t = np.linspace(0.0, 1.0, 3000)
    g = t * (1.0 + 1e-6 * np.cos(7.0 * t))  # nearly the column t: scaled condition number about 1e7
    y = 1.0 * t + 2.0 * g + 3.0 * np.exp(-0.5 * t) + rng.normal(0, 1e-4, t.size)

    def f(p):
        return p[0] * t + p[1] * g + p[2] * np.exp(-p[3] * t) - y

    def j(p):
        e = np.exp(-p[3] * t)
        return np.column_stack([t, g, e, -p[2] * t * e])

    x0 = np.array([0.9, 2.1, 3.1, 0.45])
    J0 = j(x0)
    assert np.linalg.cond(J0 / np.linalg.norm(J0, axis=0)) > 10 * NORMAL_COND_MAX
    a = levenberg_marquardt(f, x0, j)
    jacs, normals = [], []
    b = levenberg_marquardt(
        f,
        x0,
        lambda p: jacs.append(1) or j(p),
        normal=lambda p, fx: normals.append(1) or (j(p).T @ j(p), j(p).T @ fx),
    )
    assert len(jacs) >= b.njev  # every iteration fell back to J (and one more at the solution, if moved)
    assert len(normals) == 1 < b.njev
    np.testing.assert_array_equal(a.x, b.x)
    assert (a.nfev, a.njev, a.status) == (b.nfev, b.njev, b.status)
