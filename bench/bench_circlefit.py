"""Time of the ISO 12181 reference circles against the number of profile points.

A 275 mm bore 700 mm from the origin, r = R + 10 um cos 3 theta + 4 um cos 7 theta + 3 um noise at
random angles; n = 1000, 5000, 20000, 100000 points. Per n: the least-squares circle, the minimum
zone (SLP), maximum inscribed (Voronoi vertices) and minimum circumscribed (Welzl) circles, best of
3 runs, and the number of MIC candidate centres (Voronoi vertices that are local maxima and lie
inside the profile).
Run: .venv/bin/python -m bench circlefit
"""

from __future__ import annotations

import time
from functools import partial

import numpy as np

from borescan.circlefit import fit_circle_ls, max_inscribed_circle, min_circumscribed_circle, min_zone_circle


def _profile(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    th = rng.uniform(0, 2 * np.pi, n)
    r = 137.5 + 0.010 * np.cos(3 * th) + 0.004 * np.cos(7 * th + 1.0) + 0.003 * rng.standard_normal(n)
    return 700.0 + r * np.cos(th), -275.0 + r * np.sin(th)


def _best_of(fun, repeat: int = 3) -> tuple[float, object]:
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fun()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> None:
    """Print the best-of times of the four circle fits and their RONt for growing point counts."""
    head = ("n", "LSCI s", "MZCI s", "MICI s", "MCCI s", "MIC cand", "RONt MZ/MI/MC um")
    print(f"{head[0]:>7} " + " ".join(f"{h:>8}" for h in head[1:5]) + f" {head[5]:>9} {head[6]:>20}")
    for n in (1000, 5000, 20000, 100000):
        x, y = _profile(n)
        t_ls, ls = _best_of(partial(fit_circle_ls, x, y))
        c = ls.center_xy_mm
        t_mz, mz = _best_of(partial(min_zone_circle, x, y, c))
        t_mi, mi = _best_of(partial(max_inscribed_circle, x, y, c))
        t_mc, mc = _best_of(partial(min_circumscribed_circle, x, y, c))
        ront = f"{mz.ront_mm * 1e3:.2f}/{mi.ront_mm * 1e3:.2f}/{mc.ront_mm * 1e3:.2f}"
        print(f"{n:7d} {t_ls:8.3f} {t_mz:8.3f} {t_mi:8.3f} {t_mc:8.3f} {mi.n_iter:9d} {ront:>20}")


if __name__ == "__main__":
    main()
