"""Wang 2017 Eq. 16 joint solve: recovery of simulated radii, honest u, refusals."""

import numpy as np
import pytest

from borescan.geometry import Hole, RodAxis, RodLayer, rod_readings
from borescan.rod import RodSolveError, rod_crb, rod_jacobian, rod_residuals, rod_start, solve_rod

# Wang 2017 Section 4: two 150 mm ring gauges on a 500 mm rod; OD2-P30W04 span 8 mm.
LAYERS = [RodLayer(1, 100.0, 71.0), RodLayer(2, 400.0, 71.0)]
HOLES = [Hole((0.0, 0.0), 75.0), Hole((0.01, -0.02), 75.012)]
R_TRUE = np.array([75.0, 75.012])
L0 = [71.0, 71.0]
SKEW = RodAxis(1.0, 0.5, np.deg2rad(0.3), np.deg2rad(120.0))  # rod axis skew to the holes' axis
SIG = 0.02 / np.sqrt(3)  # 20 um linearity read as a uniform +-20 um error: sigma = 11.5 um


def _scan(axis=SKEW, n=12, seed=0, noise=True, spread=2 * np.pi):
    rng = np.random.default_rng(seed)
    alpha = np.sort(rng.uniform(0, spread, n))
    v = rod_readings(alpha, LAYERS, HOLES, axis)
    assert np.all((v > 0) & (v < 8)), "readings inside the 8 mm span"
    if noise:
        v = v + rng.uniform(-0.02, 0.02, v.shape)
    return alpha, v


def test_noise_free_recovery_exact():
    """gamma = d = omega-bias aside, Eq. 16 is exact: radii to 1e-7 mm (tilt 0.3 deg bias < 1 um)."""
    axis = RodAxis(1.0, 0.5, 0.0, 0.0)
    layers = LAYERS
    # exact Eq. 16 geometry: give each layer its own parallel offset by moving the hole centres
    holes = [Hole((0.0, 0.0), 75.0), Hole((-0.8, 1.3), 75.012)]
    alpha = np.linspace(0.3, 0.3 + 2 * np.pi, 9, endpoint=False)
    v = rod_readings(alpha, layers, holes, axis)
    sol = solve_rod(v, L0, u_reading_mm=SIG)
    assert np.allclose(sol.radius_mm, R_TRUE, atol=1e-7)
    a = np.mod(sol.alpha_rad - sol.alpha_rad[0], 2 * np.pi)
    a_true = np.mod(alpha - alpha[0], 2 * np.pi)
    a_mirror = np.mod(-(alpha - alpha[0]), 2 * np.pi)  # the reflection is an exact symmetry
    assert min(np.max(np.abs(a - a_true)), np.max(np.abs(a - a_mirror))) < 1e-8
    assert sol.rank == sol.n_params == 3 * 2 + 9 - 1


@pytest.mark.parametrize("seed", range(5))
def test_noisy_recovery_within_3u(seed):
    _, v = _scan(seed=seed)
    sol = solve_rod(v, L0, u_reading_mm=SIG)
    assert sol.method == "joint"
    assert np.all(np.abs(sol.radius_mm - R_TRUE) < 3 * sol.u_radius_mm + 1e-3)  # +1 um tilt bias


def test_uncertainty_matches_monte_carlo_and_crb():
    """Gaussian noise sigma: scatter of r over 300 scans / reported u within 15 %; u equals the CRB."""
    rng = np.random.default_rng(11)
    alpha, v0 = _scan(noise=False)
    v0 = rod_readings(alpha, LAYERS, HOLES, SKEW)
    est, us = [], []
    for _ in range(300):
        sol = solve_rod(v0 + SIG * rng.standard_normal(v0.shape), L0, u_reading_mm=SIG)
        est.append(sol.radius_mm)
        us.append(sol.u_radius_mm)
    est, us = np.array(est), np.array(us)
    ratio = est.std(axis=0) / us.mean(axis=0)
    assert np.all(np.abs(ratio - 1) < 0.15), ratio
    sol = solve_rod(v0, L0, u_reading_mm=SIG)
    L = v0 + np.array(L0)
    crb = rod_crb(sol.alpha_rad, L, sol.xy_mm, sol.radius_mm, SIG)
    assert np.allclose(sol.u_radius_mm, crb, rtol=1e-3)


def test_exact_jacobian_matches_finite_differences():
    _, v = _scan()
    L = v + np.array(L0)
    mask = np.isfinite(L)
    p, _ = rod_start(L, mask)
    J = rod_jacobian(p, L, mask)
    h = 1e-7
    num = np.column_stack([(rod_residuals(p + h * e, L, mask) - rod_residuals(p - h * e, L, mask)) / (2 * h) for e in np.eye(p.size)])
    assert np.allclose(J, num, atol=1e-6)


def test_missing_readings_are_skipped():
    _, v = _scan(n=14, seed=3)
    v[2, 0] = np.nan
    v[7, 1] = np.nan
    sol = solve_rod(v, L0, u_reading_mm=SIG)
    assert np.all(np.abs(sol.radius_mm - R_TRUE) < 3 * sol.u_radius_mm + 1e-3)
    v[4, :] = [np.nan, 3.0]  # poses seen by one layer only (2, 4, 7): dropped, angle NaN
    sol = solve_rod(v, L0, u_reading_mm=SIG)
    assert np.isnan(sol.alpha_rad[4]) and np.isfinite(sol.alpha_rad[5]) and sol.n_params == 6 + 11 - 1  # poses 2, 4 and 7 dropped


def test_refuses_underdetermined():
    _, v = _scan(n=4)
    with pytest.raises(RodSolveError, match=r"underdetermined: 8 readings < 3m \+ n - 1 = 9 unknowns"):
        solve_rod(v, L0)
    with pytest.raises(RodSolveError, match="one hole"):
        solve_rod(v[:, :1], L0[:1])


def test_refuses_parallel_rod_and_bunched_poses():
    """Rod parallel to the holes: offsets (x_m, y_m) equal, |p| and r trade against the angles."""
    _, v = _scan(axis=RodAxis(1.0, 0.5, 0.0, 0.0))
    with pytest.raises(RodSolveError, match="degenerate geometry"):
        solve_rod(v, L0, u_reading_mm=SIG)
    _, v = _scan(spread=np.deg2rad(2.0))
    with pytest.raises(RodSolveError, match="all poses are at nearly one angle"):
        solve_rod(v, L0, u_reading_mm=SIG)
    _, v = _scan(spread=np.deg2rad(20.0))  # bunched, but not flat: ill-conditioned joint solve
    with pytest.raises(RodSolveError, match="degenerate geometry: radii ill-determined"):
        solve_rod(v, L0, u_reading_mm=SIG)


def test_centred_rod_gives_radii_without_angles():
    _, v = _scan(axis=RodAxis(), n=20, seed=4)
    with pytest.raises(RodSolveError, match="centred='mean'"):
        solve_rod(v, L0, u_reading_mm=SIG)
    sol = solve_rod(v, L0, u_reading_mm=SIG, centred="mean")
    assert sol.method == "centred" and np.all(np.isnan(sol.alpha_rad))
    assert np.all(np.abs(sol.radius_mm - R_TRUE) < 3 * sol.u_radius_mm)
    assert np.allclose(sol.u_radius_mm, SIG / np.sqrt(20))
