"""Scatter of the diameter estimators against their Cramér-Rao bounds (Gaussian reading noise).

1. Static three-sensor device (Yang 2017 geometry, Table 1 r/d_b, beams ~120 deg apart) in a
   275.029 mm ring: three readings determine (centre, R) exactly, so the CRB of D equals the
   first-order propagation of the reading noise, sigma^2 * |dD/dv|^2 (measure.static_diameter).
2. Measuring rod (Wang 2017 geometry, 12 poses, skew axis): CRB from the exact Fisher matrix
   (rod.rod_crb) vs the scatter of rod.solve_rod and of the PSO baseline.
3. Rotating scan, LS circle of N wall points: CRB sigma_r / sqrt(N) for the radius.
Run: .venv/bin/python -m bench diameters
"""

from __future__ import annotations

import numpy as np

from borescan.circlefit import fit_circle_ls
from borescan.geometry import Beams, Bore, Hole, RodAxis, RodLayer, rod_readings, tri_static_readings
from borescan.measure import static_diameter
from borescan.rod import rod_crb, solve_rod, solve_rod_pso

BEAMS = Beams(
    (1, 2, 3),
    np.deg2rad([0.0, 120.908, 240.182]),
    np.array([-5.5484, -2.5295, 1.5262]),
    np.array([132.6718, 132.8883, 134.1108]),
)
BORE = Bore((0.0, 0.0), 275.029 / 2)


def static_part(sigma=0.003, n_mc=4000, seed=0):
    """Print the scatter of static diameters against their CRB at three device positions."""
    rng = np.random.default_rng(seed)
    print(f"static 3-sensor, sigma = {sigma * 1e3:.1f} um per reading, {n_mc} draws per position")
    for pos in ([0.0, 0.0], [1.5, -1.0], [-2.5, 2.0]):
        v0 = tri_static_readings(np.array([pos]), np.array([0.4]), BEAMS, BORE)[0]
        crb = static_diameter(v0, BEAMS, None, sigma).u_diameter_mm
        D = static_diameter(v0 + sigma * rng.standard_normal((n_mc, 3)), BEAMS).diameter_mm
        print(
            f"  device at {pos} mm: scatter {np.std(D) * 1e3:6.3f} um, CRB {crb * 1e3:6.3f} um, "
            f"ratio {np.std(D) / crb:5.3f}, bias {np.mean(D - BORE.radius_mm * 2) * 1e3:+.3f} um"
        )


def rod_part(sigma=0.02 / np.sqrt(3), n_mc=300, seed=1):
    """Print the scatter of rod diameters against their reported uncertainty."""
    layers = [RodLayer(1, 150.0, 71.0), RodLayer(2, 450.0, 71.0)]
    holes = [Hole((0.0, 0.0), 75.0), Hole((0.01, -0.02), 75.012)]
    axis = RodAxis(1.0, 0.5, np.deg2rad(0.3), np.deg2rad(120.0))
    rng = np.random.default_rng(seed)
    alpha = np.linspace(0, 2 * np.pi, 12, endpoint=False) + 0.2
    v0 = rod_readings(alpha, layers, holes, axis)
    sol0 = solve_rod(v0, [71.0, 71.0], u_reading_mm=sigma)
    crb = rod_crb(sol0.alpha_rad, v0 + 71.0, sol0.xy_mm, sol0.radius_mm, sigma)
    est = np.array(
        [
            solve_rod(v0 + sigma * rng.standard_normal(v0.shape), [71.0, 71.0], u_reading_mm=sigma).radius_mm
            for _ in range(n_mc)
        ]
    )
    r_true = np.array([75.0, 75.012])
    print(f"rod, 2 holes x 12 poses, sigma = {sigma * 1e3:.1f} um, {n_mc} draws")
    print(f"  noise-free solve bias (model: tilt 0.3 deg): {np.round((sol0.radius_mm - r_true) * 1e3, 3)} um")
    print(
        f"  solve_rod: scatter {np.round(est.std(0) * 1e3, 2)} um, CRB {np.round(crb * 1e3, 2)} um, "
        f"ratio {np.round(est.std(0) / crb, 3)}"
    )
    pso = np.array(
        [
            solve_rod_pso(v0 + sigma * rng.standard_normal(v0.shape), [71.0, 71.0], seed=k).radius_mm
            for k in range(15)
        ]
    )
    rmse = np.sqrt(np.mean((pso - r_true) ** 2, axis=0))
    print(f"  PSO (15 draws): RMS error {np.round(rmse * 1e3, 1)} um = {np.round(rmse / crb, 1)} x CRB")


def rotating_part(sigma=0.002, n_pts=3000, n_mc=300, seed=2):
    """Print the scatter of the LS circle's radius against its CRB for one rotating scan."""
    rng = np.random.default_rng(seed)
    th = np.linspace(0, 2 * np.pi, n_pts, endpoint=False)
    R = [
        fit_circle_ls(
            *((137.5 + sigma * rng.standard_normal(n_pts)) * np.stack([np.cos(th), np.sin(th)]))
        ).radius_mm
        for _ in range(n_mc)
    ]
    crb = sigma / np.sqrt(n_pts)
    print(
        f"rotating LS circle, N = {n_pts}, sigma = {sigma * 1e3:.1f} um: scatter(R) "
        f"{np.std(R) * 1e6:.2f} nm, "
        f"CRB {crb * 1e6:.2f} nm, ratio {np.std(R) / crb:.3f}"
    )


def main() -> None:
    """Run the static, rod and rotating parts."""
    static_part()
    rod_part()
    rotating_part()


if __name__ == "__main__":
    main()
