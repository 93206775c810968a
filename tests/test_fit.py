"""The one fit result type (borescan.fit) against closed forms of linear regression."""

import numpy as np
import pytest

from borescan.fit import fit_result, jacobian_summary, least_squares_fit


def _line(n=50, seed=3, sigma=0.01):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 10.0, n)
    y = 2.0 + 0.5 * t + sigma * rng.standard_normal(n)
    return t, y


def test_straight_line_matches_the_textbook_covariance():
    """Slope/intercept, their covariance s^2 (X^T X)^-1 and the correlation, exactly."""
    t, y = _line()
    X = np.column_stack([np.ones_like(t), t])
    beta = np.linalg.solve(X.T @ X, X.T @ y)
    r = y - X @ beta
    s2 = r @ r / (t.size - 2)
    cov = s2 * np.linalg.inv(X.T @ X)
    fr = least_squares_fit(
        lambda p: y - (p[0] + p[1] * t),
        [0.0, 0.0],
        ["a_mm", "b_mm_per_s"],
        jac=lambda p: -X,
        ftol=1e-15,
        xtol=1e-15,
    )
    assert fr.success and fr.rank == 2 and fr.dof == t.size - 2
    np.testing.assert_allclose(fr.x, beta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fr.cov, cov, rtol=1e-9)
    np.testing.assert_allclose(fr.u, np.sqrt(np.diag(cov)), rtol=1e-9)
    rho = cov[0, 1] / np.sqrt(cov[0, 0] * cov[1, 1])
    np.testing.assert_allclose(fr.correlation, [[1, rho], [rho, 1]], rtol=1e-9)
    n, rss = t.size, float(r @ r)
    assert fr.bic == pytest.approx(n * np.log(rss / n) + 2 * np.log(n), rel=1e-10)
    assert fr.aic == pytest.approx(n * np.log(rss / n) + 4, rel=1e-10)
    assert fr.values() == {"a_mm": pytest.approx(beta[0]), "b_mm_per_s": pytest.approx(beta[1])}


def test_forward_differences_agree_with_the_analytic_jacobian():
    """Scaled forward differences give the same optimum and uncertainties (a linear model: exact)."""
    t, y = _line(seed=5)
    X = np.column_stack([np.ones_like(t), t])
    a = least_squares_fit(lambda p: y - X @ p, [1.0, 1.0], ["a", "b"], jac=lambda p: -X)
    b = least_squares_fit(lambda p: y - X @ p, [1.0, 1.0], ["a", "b"], scale=[1.0, 0.1])
    np.testing.assert_allclose(b.x, a.x, atol=1e-10)
    np.testing.assert_allclose(b.u, a.u, rtol=1e-6)


def test_known_noise_scale_is_used_as_given():
    """sigma given: cov = sigma^2 (J^T J)^-1, whatever the residuals."""
    t, y = _line()
    X = np.column_stack([np.ones_like(t), t])
    fr = fit_result(["a", "b"], [2.0, 0.5], y - X @ [2.0, 0.5], -X, sigma=0.02)
    np.testing.assert_allclose(fr.cov, 0.02**2 * np.linalg.inv(X.T @ X), rtol=1e-10)
    assert fr.sigma == 0.02


def test_rank_deficiency_and_condition_are_reported():
    """Two identical columns: rank 1, infinite condition (or beyond 1e15); the pseudo-inverse splits
    the variance equally between them.
    """
    t = np.linspace(0, 1, 20)
    J = np.column_stack([t, t])
    js = jacobian_summary(J)
    assert js.rank == 1
    assert js.condition > 1e15
    # (J^T J)^+ of [[s, s], [s, s]] with s = sum t^2 is [[1, 1], [1, 1]] / (4 s)
    s = float(t @ t)
    np.testing.assert_allclose(js.cov_unit, np.full((2, 2), 1 / (4 * s)), rtol=1e-10)
    # units do not change the condition: scaling a column leaves it unchanged
    J2 = np.column_stack([t, 1 + t**2])
    assert jacobian_summary(J2).condition == pytest.approx(
        jacobian_summary(J2 * [1e6, 1e-3]).condition, rel=1e-9
    )


def test_discrepancy_fits_report_through_the_one_type():
    """The discrepancy workflow's fit is borescan.fit's, with its closed-form covariance."""
    from borescan.discrepancy.fitting import fit_least_squares
    from borescan.fit import FitResult

    t, y = _line(seed=11)
    X = np.column_stack([np.ones_like(t), t])
    fr = fit_least_squares(lambda p: y - (p["a"] + p["b"] * t), ["a", "b"], [0.0, 0.0], [1.0, 1.0])
    assert isinstance(fr, FitResult)
    beta = np.linalg.lstsq(X, y, rcond=None)[0]
    np.testing.assert_allclose(fr.x, beta, atol=1e-9)
    s2 = float(np.sum((y - X @ beta) ** 2)) / (t.size - 2)
    np.testing.assert_allclose(fr.u, np.sqrt(np.diag(s2 * np.linalg.inv(X.T @ X))), rtol=1e-6)


def test_difference_groups_share_steps_only_between_disjoint_columns():
    """Curtis-Powell-Reid grouping: columns in one group never touch the same residual, and a
    dense column stays alone.
    """
    from borescan.fit import difference_groups

    S = np.zeros((6, 5), dtype=bool)
    S[0:2, 0] = S[2:4, 1] = S[4:6, 2] = True  # three disjoint blocks
    S[:, 3] = True  # dense
    S[1:3, 4] = True  # overlaps columns 0 and 1, not 2
    groups = difference_groups(S)
    assert sorted(i for g in groups for i in g) == list(range(5))
    for g in groups:
        for a in g:
            for b in g:
                assert a == b or not np.any(S[:, a] & S[:, b])
    assert [3] in groups and [0, 1, 2] in groups and len(groups) == 3


def test_grouped_differences_give_the_dense_fit_bit_for_bit():
    """Per-block parameters (a line per block, as a pose angle moves only its pose) fitted with the
    declared sparsity: the same iterates and result as one step per parameter, with fewer calls.
    """
    rng = np.random.default_rng(5)
    n_blocks, per = 8, 20
    block = np.repeat(np.arange(n_blocks), per)
    t = np.tile(np.linspace(0.0, 1.0, per), n_blocks)
    truth = rng.uniform(-1, 1, n_blocks)
    y = np.sin(truth[block] + 0.7 * t) * np.exp(-0.3 * t) + 0.01 * rng.standard_normal(t.size)
    calls = {"n": 0}

    def fun(p):
        calls["n"] += 1
        return y - np.sin(p[:n_blocks][block] + p[-1] * t) * np.exp(-0.3 * t)

    names = [f"a[{k}]" for k in range(n_blocks)] + ["w"]
    S = np.zeros((t.size, n_blocks + 1), dtype=bool)
    S[np.arange(t.size), block] = True
    S[:, -1] = True
    x0 = np.zeros(n_blocks + 1)
    dense = least_squares_fit(fun, x0, names)
    n_dense = calls["n"]
    calls["n"] = 0
    grouped = least_squares_fit(fun, x0, names, sparsity=S)
    assert calls["n"] < n_dense / 2  # 3 calls per Jacobian instead of 10
    assert np.array_equal(grouped.x, dense.x) and grouped.rss == dense.rss
    assert np.array_equal(grouped.cov, dense.cov)
    assert dense.success and np.max(np.abs(dense.x[:n_blocks] - truth)) < 5 * np.max(dense.u[:n_blocks])


def test_a_fit_is_scipy_least_squares_lm_to_rounding():
    """least_squares_fit iterates as scipy.optimize.least_squares(method="lm") (MINPACK lmder, x_scale
    "jac"), its QR by LAPACK: the same minimum, evaluation count, status and Jacobian to rounding, on a
    nonlinear problem with forward differences in scaled variables (the discrepancy workflow's fits).
    """
    from scipy.optimize import least_squares

    rng = np.random.default_rng(17)
    t = np.linspace(0.0, 4.0, 3000)
    y = 1.5 * np.exp(-0.8 * t) * np.cos(3.1 * t + 0.4) + 0.02 + 0.005 * rng.standard_normal(t.size)

    def fun(p):
        return y - (p[0] * np.exp(-p[1] * t) * np.cos(p[2] * t + p[3]) + p[4])

    x0, scale = [1.0, 0.5, 3.0, 0.0, 0.0], np.array([1.0, 0.1, 0.1, 0.1, 0.01])
    fr = least_squares_fit(fun, x0, list("abcde"), scale=scale, xtol=1e-10, ftol=1e-12, gtol=1e-8)

    def jz(z):  # least_squares_fit's forward differences of step 1e-4 in z = x / scale
        f0 = fun(z * scale)
        return np.column_stack([(fun((z + 1e-4 * e) * scale) - f0) / 1e-4 for e in np.eye(5)])

    ref = least_squares(
        lambda z: fun(z * scale), np.array(x0) / scale, jac=jz, method="lm", xtol=1e-10, ftol=1e-12, gtol=1e-8
    )
    assert fr.success and ref.success and fr.nfev == ref.nfev
    np.testing.assert_allclose(fr.x, ref.x * scale, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(fr.rss, 2.0 * ref.cost, rtol=1e-9)
    np.testing.assert_allclose(fr.cov, fr.cov.T)
    J_ref = ref.jac / scale
    cov_ref = np.linalg.inv(J_ref.T @ J_ref) * fr.sigma**2
    np.testing.assert_allclose(fr.cov, cov_ref, rtol=1e-6)


def test_a_fit_never_evaluates_its_model_twice_at_one_point():
    """The forward differences start from the residuals the iteration has just computed at the point
    (an accepted step), not from a new evaluation: no two consecutive calls of ``fun`` at one point,
    and the fit is the one whose differences evaluate ``fun`` there again (same x, bit for bit).
    """
    rng = np.random.default_rng(23)
    t = np.linspace(0.0, 4.0, 2000)
    y = 1.5 * np.exp(-0.8 * t) * np.cos(3.1 * t + 0.4) + 0.02 + 0.005 * rng.standard_normal(t.size)

    def fun(p):
        return y - (p[0] * np.exp(-p[1] * t) * np.cos(p[2] * t + p[3]) + p[4])

    points = []

    def counted(p):
        points.append(np.array(p))
        return fun(p)

    x0, scale = [1.0, 0.5, 3.0, 0.0, 0.0], np.array([1.0, 0.1, 0.1, 0.1, 0.01])
    fr = least_squares_fit(counted, x0, list("abcde"), scale=scale)
    assert fr.success and len(points) > 10
    assert not any(np.array_equal(a, b) for a, b in zip(points, points[1:]))
