"""Rod solvers on the same simulated scans: exact-Jacobian LM (solve_rod) vs particle swarm.

Scene (Wang 2017, Section 4): two 150 mm ring gauges (r = 75.000 and 75.012 mm) at h = 100 and
400 mm on a 500 mm rod, l0 = 71 mm, rod axis 1.0/0.5 mm eccentric and deflected 0.3 deg towards
120 deg (skew to the holes' axis), 12 poses at random angles. Noise: the OD2-P30W04's 20 um
linearity read as a uniform +-20 um error, i.e. sigma = 0.02/sqrt(3) = 11.5 um.
Run: .venv/bin/python -m bench rod
"""

from __future__ import annotations

import time

import numpy as np

from borescan.geometry import Hole, RodAxis, RodLayer, rod_readings
from borescan.rod import solve_rod, solve_rod_pso

LAYERS = [RodLayer(1, 100.0, 71.0), RodLayer(2, 400.0, 71.0)]
HOLES = [Hole((0.0, 0.0), 75.0), Hole((0.01, -0.02), 75.012)]
R_TRUE = np.array([75.0, 75.012])
AXIS = RodAxis(1.0, 0.5, np.deg2rad(0.3), np.deg2rad(120.0))
SIG = 0.02 / np.sqrt(3)


def scans(n_scans: int = 12, n_poses: int = 12, seed: int = 0):
    """Yield ``n_scans`` noisy rod scans of ``n_poses`` random poses each."""
    rng = np.random.default_rng(seed)
    for _ in range(n_scans):
        alpha = np.sort(rng.uniform(0, 2 * np.pi, n_poses))
        v = rod_readings(alpha, LAYERS, HOLES, AXIS)
        yield v + rng.uniform(-0.02, 0.02, v.shape)


def main() -> None:
    """Print the errors and times of the rod solver on the scans."""
    err_a, err_p, t_a, t_p = [], [], [], []
    for k, v in enumerate(scans()):
        t0 = time.perf_counter()
        for _ in range(20):
            sa = solve_rod(v, [71.0, 71.0], u_reading_mm=SIG)
        t_a.append((time.perf_counter() - t0) / 20)
        t0 = time.perf_counter()
        sp = solve_rod_pso(v, [71.0, 71.0], seed=k)
        t_p.append(time.perf_counter() - t0)
        err_a.append(sa.radius_mm - R_TRUE)
        err_p.append(sp.radius_mm - R_TRUE)
    err_a, err_p = np.array(err_a) * 1e3, np.array(err_p) * 1e3
    rms_a, rms_p = np.sqrt(np.mean(err_a**2)), np.sqrt(np.mean(err_p**2))
    print(f"scans: {len(t_a)} x 12 poses x 2 holes, sigma = {SIG * 1e3:.1f} um (uniform +-20 um)")
    print(
        f"solve_rod (LM, exact Jacobian): radius error RMS {rms_a:8.2f} um, max "
        f"{np.abs(err_a).max():8.2f} um, "
        f"median time {np.median(t_a) * 1e3:7.2f} ms"
    )
    print(
        f"solve_rod_pso (80 x 1500, seeded): radius error RMS {rms_p:8.2f} um, max "
        f"{np.abs(err_p).max():8.2f} um, "
        f"median time {np.median(t_p) * 1e3:7.2f} ms"
    )
    print(
        f"ratios: PSO/LM time {np.median(t_p) / np.median(t_a):.0f}x, PSO/LM RMS error {rms_p / rms_a:.0f}x "
        f"(target >= 100x and >= 10x)"
    )


if __name__ == "__main__":
    main()
