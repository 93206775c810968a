"""Rod solve on effect-free scans drawn over the contract's ranges (the rod-deflection issue).

Each scan: 2-3 coaxial holes (diameter 100-200 mm, centres within 0.05 mm), layer heights
50-150 mm then 100-300 mm apart, beam offset |d| <= 0.5 mm, tilt |gamma| <= 0.5 deg, angle
|phi| <= 0.1 rad (known device geometry, as in device.nominal), eccentricity |e| <= 2.5 mm,
deflection omega ~ U(0, 1 deg) towards a uniform azimuth, 8-40 poses at uniformly random angles,
5-30 readings per pose with Gaussian noise 2-20 um; the solver sees the pose means and their
standard uncertainty sigma / sqrt(k). Prints: solved / refused (reasons), pooled z-scores of the
diameters (SD, RMS, max |z|, 95 % coverage), max u / CRB, wrong minima (cost at the solution
above the cost at the truth + sqrt(2 N) sigma^2), time; then the discrepancy workflow's verdicts
on a subset of effect-free rod scans (``simulate_rod`` + ``examine_scan``).
Run: .venv/bin/python -m bench rod_contract
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, replace

import numpy as np

from borescan.geometry import rod_readings
from borescan.plan_rod import hold_of_solution, predict_rod
from borescan.rod import RodSolveError, rod_cost_mm2, rod_crb, solve_rod
from borescan.rod_calibration import rod_coaxiality_mm
from borescan.synthetic.rod_scenarios import RodDraw, draw_rod_geometry

#: the holes' coaxiality the solve is told (the schema's default; the contract draws centres within it)
COAXIALITY_MM = rod_coaxiality_mm({})


@dataclass(frozen=True)
class ContractRodScan:
    """An effect-free rod scan over the contract: its draw and its pose-mean readings."""

    draw: RodDraw
    v_mm: np.ndarray  # (n_poses, n_holes) pose-mean readings [mm]
    sigma_mm: float  # their standard uncertainty, noise / sqrt(readings per pose) [mm]


def draw_scan(rng: np.random.Generator) -> ContractRodScan:
    """Return one effect-free rod scan over the contract.

    One effect-free rod scan over the contract (:func:`borescan.synthetic.rod_scenarios.draw_rod_geometry`);
    pose-mean readings.
    """
    g = draw_rod_geometry(rng)
    v0 = rod_readings(g.alpha_rad, g.layers, g.holes, g.axis)
    v = v0 + g.noise_mm * rng.standard_normal((g.samples_per_pose,) + v0.shape).mean(axis=0)
    return ContractRodScan(g, v, g.noise_mm / np.sqrt(g.samples_per_pose))


def evaluate(scan: ContractRodScan) -> dict:
    """Solve one drawn scan; z-scores, u/CRB and the wrong-minimum test against the truth."""
    s, g = scan, scan.draw
    r_true = np.array([hh.radius_mm for hh in g.holes])
    try:
        sol = solve_rod(s.v_mm, layers=g.layers, u_reading_mm=s.sigma_mm, coaxiality_mm=COAXIALITY_MM)
    except RodSolveError as err:
        return {
            "refused": str(err).split(":")[0]
            + (": " + str(err).split(":")[1].split("(")[0].strip() if ":" in str(err) else "")
        }
    crb = rod_crb(
        g.alpha_rad,
        layers=g.layers,
        holes=g.holes,
        axis=g.axis,
        sigma_mm=s.sigma_mm,
        coaxiality_mm=COAXIALITY_MM,
    )
    hold = hold_of_solution(sol, COAXIALITY_MM)  # borescan plan --rod-scan's view of this scan
    plan_own = np.asarray(predict_rod(hold).u_diameter_mm)
    plan_even = np.asarray(predict_rod(replace(hold, alpha_rad=None)).u_diameter_mm)
    c_true = rod_cost_mm2(s.v_mm, g.alpha_rad, g.layers, g.holes, g.axis)
    spread = np.sqrt(2.0 * s.v_mm.size) * s.sigma_mm**2
    return {
        "z": (sol.diameter_mm - 2 * r_true) / sol.u_diameter_mm,
        "u_crb": sol.u_radius_mm / crb,
        "wrong": bool(sol.cost_mm2 > c_true + spread),
        "cost": sol.cost_mm2,
        "cost_true": c_true,
        "err_um": (sol.diameter_mm - 2 * r_true) * 1e3,
        "err_crb": (sol.radius_mm - r_true) / crb,
        "ratio": sol.deflection_ratio,
        "plan_own": plan_own / sol.u_diameter_mm,
        "plan_even": plan_even / sol.u_diameter_mm,
    }


def run_contract(n_scans: int = 240, seed: int = 2017) -> dict:
    """Solve ``n_scans`` effect-free rod scans; return their z scores, CRB ratios and refusals."""
    rng = np.random.default_rng(seed)
    z, ucrb, err_crb, wrong, refused, t = [], [], [], 0, Counter(), time.perf_counter()
    plan_own, plan_even = [], []
    for _ in range(n_scans):
        res = evaluate(draw_scan(rng))
        if "refused" in res:
            refused[res["refused"]] += 1
            continue
        z.append(res["z"])
        ucrb.append(res["u_crb"])
        err_crb.append(res["err_crb"])
        plan_own.append(res["plan_own"])
        plan_even.append(res["plan_even"])
        wrong += res["wrong"]
    z = np.concatenate(z)
    ucrb = np.concatenate(ucrb)
    return {
        "n": n_scans,
        "solved": n_scans - sum(refused.values()),
        "refused": refused,
        "z": z,
        "u_crb": ucrb,
        "err_crb": np.concatenate(err_crb),
        "plan_own": np.concatenate(plan_own),
        "plan_even": np.concatenate(plan_even),
        "wrong": wrong,
        "seconds": time.perf_counter() - t,
    }


def run_discrepancy(n_scans: int = 20, seed: int = 7) -> Counter:
    """Verdicts of the discrepancy workflow on effect-free simulated rod scans (contract-like scenes)."""
    from borescan.discrepancy import examine_scan
    from borescan.synthetic.scenes import RodScene
    from borescan.synthetic.simulate import simulate_rod

    rng = np.random.default_rng(seed)
    out = Counter()
    for i in range(n_scans):
        g = draw_scan(rng).draw
        scene = RodScene(layers=g.layers, holes=g.holes, axis=g.axis, range_mm=(30.0,) * g.n_holes)
        feats = [
            {"id": f"H{j + 1}", "z_mm": lay.h_mm, "nominal_diameter_mm": round(2 * hh.radius_mm)}
            for j, (lay, hh) in enumerate(zip(g.layers, g.holes))
        ]
        art = {
            "id": "PART",
            "type": "part",
            "nominal_diameter_mm": feats[0]["nominal_diameter_mm"],
            "cte_per_k": 11.5e-6,
            "features": feats,
        }
        scan = simulate_rod(
            scene,
            g.alpha_rad,
            samples_per_pose=g.samples_per_pose,
            noise_mm=g.noise_mm,
            seed=1000 + i,
            artifact=art,
            nominal_layers=g.layers,
        )
        f = examine_scan(scan)
        out[f["verdict"]] += 1
    return out


def main() -> None:
    """Run the rod contract and print its figures."""
    res = run_contract()
    z = res["z"]
    print(
        f"effect-free rod scans: {res['n']} drawn, {res['solved']} solved, {res['n'] - res['solved']} "
        "refused "
        f"({res['seconds']:.1f} s)"
    )
    for why, k in res["refused"].most_common():
        print(f"  refused {k:3d}: {why}")
    print(
        f"diameters: {z.size}; z-scores SD {z.std():.3f}, RMS {np.sqrt(np.mean(z**2)):.3f}, mean "
        f"{z.mean():+.3f}, "
        f"max |z| {np.abs(z).max():.2f}; 95 % coverage {np.mean(np.abs(z) < 1.959964):.3f}"
    )
    print(
        f"u / CRB: max {res['u_crb'].max():.3f}, median {np.median(res['u_crb']):.3f}; wrong minima: "
        f"{res['wrong']}"
    )
    print(f"errors / CRB: rms {np.sqrt(np.mean(res['err_crb'] ** 2)):.3f} (an efficient estimator: 1)")
    for key, what in (("plan_own", "the hold's own poses"), ("plan_even", "its poses equally spaced")):
        q = res[key]
        print(
            f"borescan plan --rod-scan u(D) / the solve's u(D), {what}: median {np.median(q):.3f}, "
            f"5-95 % {np.quantile(q, 0.05):.3f}-{np.quantile(q, 0.95):.3f}, within 10 % "
            f"{100 * np.mean(np.abs(q - 1) <= 0.1):.1f} %"
        )
    t = time.perf_counter()
    verdicts = run_discrepancy()
    n = sum(verdicts.values())
    fa = n - verdicts.get("no_missing_effect", 0)
    print(
        f"discrepancy workflow on {n} effect-free rod scans: {dict(verdicts)}; false-alarm rate {fa / n:.2f} "
        f"({time.perf_counter() - t:.0f} s)"
    )


if __name__ == "__main__":
    main()
