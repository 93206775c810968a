"""Coverage of a rod's GUM budget: calibrate-then-measure chains on certified ring gauges, over the contract.

Each chain (fixed seed, chain i from its own child seed) draws one measuring rod over the
contract (:func:`borescan.synthetic.rod_scenarios.draw_rod_geometry`: 2-3 layers 100-300 mm apart, beam angle,
offset and tilt of a real rod, 30 mm sensors mid-range, noise 2-20 um) whose design in scan.json
has each base length l0 off the truth by U(+-30 um) and phi = d = gamma = 0, and three holds of it
(each its own eccentricity up to 2.5 mm, deflection up to 1 deg, 8-40 poses at random angles,
5-30 readings per pose): in its ring-gauge set (calibration), in a part (measurement), in the
gauge set again (verification). Drawn from the distributions the budget states, everything the
pipeline takes as known:

- the gauge set: one ring per layer of true D20 = 2 r (r 50-100 mm), certificates stating D20 +
  N(0, (U/k)^2) (U = 1.2 um, k = 2); true temperature U(18, 22) degC, stated within
  +-``uncertainty.temperature_accuracy_c``; expansion coefficient within +-``uncertainty.cte_accuracy_per_k``;
- the sensors: linearity_fs log-uniform in 1e-5 .. 1e-3 of the range, and one linearity curve per
  sensor (a random cubic in v / range less its best straight line, +-linearity_fs range at its
  largest) added to every reading of every hold: a data sheet's linearity bounds one systematic
  curve, which the calibration's l0 absorbs at the gauges' readings (the budget's model,
  ``measure.linearity_terms``); repeatability = the readings' true noise;
- the part: holes of the gauges' D20 + U(+-50 um), at their own temperature U(18, 22) degC.

The pipeline's own path then calibrates (``rod_calibration.calibrate_hold``, as the stage does) and
measures (``measure.rod_diameters_with_budget``, ``rod_verifications``). Printed: the share
of 95.45 % intervals (k from the budget) that cover each true diameter (at 20 degC and at the
measured temperature) and the verification error, with binomial standard errors and z-score SDs;
chains whose poses cannot determine the radii are refused by the solve, with the reason. The
base length itself has no truth to score: l0 takes up the beam offset and tilt and the solve's
deflection average, which is its purpose.

To find which input an error comes from, ``--oracle geometry`` gives the solve the true phi, d,
gamma (l0 still off) and ``--oracle linearity`` drops the sensors' linearity curves; the chains
draw the same numbers either way, so ``--dump FILE`` of two runs pairs each error with its
counterpart (the difference is that input's share, to compare with its budget term).

Run: ``python -m bench rod_coverage`` or
``python -m bench.bench_rod_coverage [--n 200] [--seed 20270701] [--workers 2] [--oracle geometry]
[--dump FILE] [--fisher]``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from borescan.parallel import map_in_order

N_CHAINS = 200
SEED = 20270701
#: minutes on 2 cores: on request (python -m bench rod_coverage), not in every `make bench`
RUN_BY_DEFAULT = False
ROOT = Path(__file__).resolve().parents[1]
CTE = 11.5e-6
RANGE_MM = 30.0


def _config() -> dict:
    from borescan.config import load_config

    return load_config(ROOT / "config" / "config.yaml")


def _hold(rng, layers, d20_mm, T_c, kind, scan_id, artifact, design, sensors, base: Path):
    """Write one hold of the rod and read it back.

    Write one hold of the rod (a fresh draw of axis, poses and readings per pose) with the stated
    temperature and expansion coefficient and a linearity error per layer; read it back.
    """
    import polars as pl

    from borescan import rawio
    from borescan.synthetic import rod_scenarios, scenes, simulate
    from borescan.effects import Effect
    from borescan.geometry import Hole

    g = rod_scenarios.draw_rod_geometry(rng)
    m = len(layers)
    holes = tuple(Hole(tuple(float(x) for x in rng.uniform(-0.05, 0.05, 2)), float(d) / 2) for d in d20_mm)
    scene = scenes.RodScene(
        layers=tuple(layers),
        holes=holes,
        axis=g.axis,
        range_mm=(30.0,) * m,
        sample_rate_hz=100.0,
        cte_per_k=CTE,
        temperature_c=T_c,
    )
    sim = simulate.simulate_rod(
        scene,
        g.alpha_rad,
        samples_per_pose=g.samples_per_pose,
        noise_mm=sensors["noise_mm"],
        kind=kind,
        artifact=artifact,
        features=[f"H{j + 1}" for j in range(m)],
        nominal_layers=design,
        scan_id=scan_id,
        effects=[Effect("thermal_expansion", {"temperature_c": T_c})],
        seed=int(rng.integers(2**31)),
    )
    meta = json.loads(json.dumps(sim.meta))
    meta["environment"] = {"temperature_c": T_c + float(rng.uniform(-1, 1)) * sensors["a_T"]}
    meta["artifact"]["cte_per_k"] = CTE + float(rng.uniform(-1, 1)) * sensors["a_alpha"]
    meta["sensors"] = [
        dict(
            s,
            linearity_fs=sensors["lin_fs"],
            range_mm=30.0,
            repeatability_mm=sensors["noise_mm"],
            resolution_mm=1e-4,
        )
        for s in meta["sensors"]
    ]
    v = _with_linearity(sim.lds["value_mm"].to_numpy(), sim.lds["sensor"].cast(pl.Int64).to_numpy(), sensors)
    lds = sim.lds.with_columns(pl.Series("value_mm", v, dtype=sim.lds.schema["value_mm"]))
    folder = simulate.write_simulated(replace(sim, meta=meta, lds=lds), base / "raw", base / "truth")
    return rawio.read_scan(folder, raw_root=base / "raw")


def _calibration_hold(rng, layers, d20_mm, i, gauges, design, sensors, folder: Path):
    """Write chain ``i``'s calibration hold on its ring-gauge set (temperature drawn at 18-22 degC)."""
    return _hold(
        rng,
        layers,
        d20_mm,
        float(rng.uniform(18, 22)),
        "calibration",
        f"CAL-{i}",
        gauges,
        design,
        sensors,
        folder,
    )


def _linearity_curve_mm(coef, a_mm: float, v_mm):
    """Return the sensor's linearity deviation at readings ``v_mm`` [mm].

    A cubic in v / range (coefficients ``coef``) less its best straight line over the range, scaled
    to +-a at its largest.
    """
    u = np.linspace(0.0, 1.0, 301)
    curve = np.polynomial.polynomial.polyval(u, coef)
    line = np.polyfit(u, curve, 1)
    dev = curve - np.polyval(line, u)
    scale = a_mm / np.max(np.abs(dev))
    x = np.asarray(v_mm, dtype=float) / RANGE_MM
    return scale * (np.polynomial.polynomial.polyval(x, coef) - np.polyval(line, x))


def _with_linearity(v_mm, sensor, sensors):
    """Return the readings with each sensor's one linearity curve added (the same curve in every hold)."""
    out = np.array(v_mm, dtype=float)
    for j, coef in enumerate(sensors["curves"]):
        on = (sensor == j + 1) & np.isfinite(out)
        out[on] += sensors["lin_scale"] * _linearity_curve_mm(coef, sensors["lin_fs"] * RANGE_MM, out[on])
    return out


def _chain_setup(i, seed, cfg, oracle):
    """Return chain i's draws before its holds: rng, true and design layers, sensors, gauge set, part, D20."""
    from borescan.synthetic import rod_scenarios

    unc = cfg["uncertainty"]
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(i),)))
    g = rod_scenarios.draw_rod_geometry(rng)
    r = np.array([hh.radius_mm for hh in g.holes])
    true = tuple(replace(lay, l0_mm=float(rr - 15.0)) for lay, rr in zip(g.layers, r))
    design = tuple(
        replace(lay, l0_mm=lay.l0_mm + float(rng.uniform(-0.03, 0.03)), phi_rad=0.0, d_mm=0.0, gamma_rad=0.0)
        for lay in true
    )
    if "geometry" in oracle:  # the design's phi, d, gamma are the truth (l0 still off): what they cost
        design = tuple(replace(t, l0_mm=d.l0_mm) for t, d in zip(true, design))
    m = len(true)
    sensors = {
        "lin_fs": float(10 ** rng.uniform(-5, -3)),
        "noise_mm": g.noise_mm,
        "a_T": float(unc["temperature_accuracy_c"]),
        "a_alpha": float(unc["cte_accuracy_per_k"]),
        "lin_scale": 0.0 if "linearity" in oracle else 1.0,
        "curves": rng.standard_normal((m, 4)),  # each sensor's one linearity curve (cubic)
    }
    U_g, k_g = 0.0012, 2.0
    g20 = 2 * r
    feats = [f"H{j + 1}" for j in range(m)]
    gset = {
        "id": f"RGS-{i}",
        "type": "ring_gauge",
        "u_diameter_mm": U_g,
        "k": k_g,
        "certificate": f"C-{i}",
        "features": [
            {
                "id": f,
                "z_mm": lay.h_mm,
                "certified_diameter_mm": float(d + U_g / k_g * rng.standard_normal()),
                "gauge_id": f"RG-{i}-{f}",
            }
            for f, lay, d in zip(feats, true, g20)
        ],
    }
    part = {
        "id": f"P-{i}",
        "type": "part",
        "features": [
            {"id": f, "z_mm": lay.h_mm, "nominal_diameter_mm": float(d)}
            for f, lay, d in zip(feats, true, g20)
        ],
    }
    return rng, true, design, sensors, gset, part, g20


def run_chain(job) -> dict:
    """One calibrate-then-measure-then-verify chain: its z-scores and coverage flags."""
    i, seed, cfg, oracle = job
    from borescan import rod_calibration
    from borescan import measure

    unc = cfg["uncertainty"]
    rng, true, design, sensors, gset, part, g20 = _chain_setup(i, seed, cfg, oracle)
    m = len(true)
    out = {"index": i, "lin_fs": sensors["lin_fs"], "m": m}
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp)
        try:
            cal = _calibration_hold(rng, true, g20, i, gset, design, sensors, base / "c")
            hold = rod_calibration.calibrate_hold(cal, unc, design)
            rows = hold.rows(cal.night, None, float(unc["coverage_probability"]))
            p20 = g20 + rng.uniform(-0.05, 0.05, m)
            T_p = float(rng.uniform(18, 22))
            meas = _hold(rng, true, p20, T_p, "measurement", f"MEAS-{i}", part, design, sensors, base / "m")
            res = measure.rod_diameters_with_budget(meas, rows, unc, "C")
            ver = _hold(
                rng,
                true,
                g20,
                float(rng.uniform(18, 22)),
                "verification",
                f"VER-{i}",
                gset,
                design,
                sensors,
                base / "v",
            )
            vres = measure.rod_diameters_with_budget(ver, rows, unc, "C")
            vrows = measure.rod_verifications(ver, vres, "C", unc, cfg["laboratory"], 1.0)
        except (ValueError, np.linalg.LinAlgError) as err:
            return dict(out, error=str(err)[:160])
    zs = {"D20": [], "D_T": [], "E": []}
    cov = {"D20": [], "D_T": [], "E": []}
    errs = {"D20": [], "E": []}
    u_geo = {"D20": [_geo_u(rr["du"].rows_20) for rr in res], "E": [_geo_u(v["budget"]) for v in vrows]}
    for rr, d20 in zip(res, p20):
        du = rr["du"]
        dT = d20 * (1 + CTE * (T_p - 20))
        for key, val, truth, comb in (
            ("D20", du.diameter_20_mm, d20, du.combined_20),
            ("D_T", du.diameter_mm, dT, du.combined_t),
        ):
            zs[key].append((val - truth) / comb.u)
            cov[key].append(abs(val - truth) <= comb.U)
        errs["D20"].append(float(du.diameter_20_mm - d20))
    for v, d20 in zip(vrows, g20):
        e = v["measured_mm"] - d20  # the error of the gauge's measured D20 against its true D20
        zs["E"].append(e / v["u_error_mm"])
        cov["E"].append(abs(e) <= v["expanded_u_error_mm"])
        errs["E"].append(float(e))
    return dict(out, z=zs, covered=cov, error_mm=errs, u_geo_mm=u_geo)


def _geo_u(rows: list[dict]) -> float:
    """Return the layer geometry's standard uncertainty in a budget's rows [mm] (0: no such input)."""
    return next(
        (float(b["standard_uncertainty"]) for b in rows if b["key"].startswith("layer_geometry:")), 0.0
    )


def fisher_chain(job) -> dict:
    """Return what chain i's calibration hold fixes of the layers' phi, d, gamma (posterior / prior SD)."""
    i, seed, cfg, oracle = job
    from borescan import rod_calibration
    from borescan.rod_layer_geometry import layer_geometry_information, layer_geometry_prior

    unc = cfg["uncertainty"]
    rng, true, design, sensors, gset, _part, g20 = _chain_setup(i, seed, cfg, oracle)
    with tempfile.TemporaryDirectory() as tmp:
        try:
            cal = _calibration_hold(rng, true, g20, i, gset, design, sensors, Path(tmp))
            _ch, means, u_mean, _s = rod_calibration.pose_means_of_scan(cal)
            sd = layer_geometry_information(
                means, design, u_mean, rod_calibration.rod_coaxiality_mm(unc), layer_geometry_prior(unc)
            )
        except (ValueError, np.linalg.LinAlgError) as err:
            return {"index": i, "error": str(err)[:160]}
    return {"index": i, "sd_ratio": sd.tolist()}


def _print_fisher(results) -> None:
    ok = [r for r in results if "error" not in r]
    best = np.array([r["sd_ratio"][0] for r in ok])
    all_sd = np.concatenate([r["sd_ratio"] for r in ok])
    print(
        f"Calibration holds' information on the layers' phi, d, gamma ({len(ok)} of {len(results)} holds; "
        "posterior SD / the tolerances' rectangular SD per direction):"
    )
    print(
        f"  best-fixed direction per hold: median {np.median(best):.2f}, 5-95 % "
        f"{np.percentile(best, 5):.2f}-{np.percentile(best, 95):.2f}; directions below 0.5: "
        f"{int(np.sum(all_sd < 0.5))} of {all_sd.size}, above 0.9: {int(np.sum(all_sd > 0.9))}"
    )


def main(argv=None) -> int:
    """Run the rod chains and print the coverage table (options: ``--help``); return 0."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=N_CHAINS, help="chains (default %(default)s)")
    ap.add_argument("--seed", type=int, default=SEED)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--oracle",
        default="",
        help="comma-separated inputs made exact, for the error's decomposition: geometry (the design's phi, "
        "d, gamma are the truth), linearity (no linearity error)",
    )
    ap.add_argument(
        "--dump",
        type=Path,
        help="write each chain's z-scores, errors and layer-geometry u [mm] to this JSON file",
    )
    ap.add_argument(
        "--fisher",
        action="store_true",
        help="instead: what each chain's calibration hold fixes of the layers' phi, d, gamma (Fisher)",
    )
    a = ap.parse_args(argv)
    if a.n < 1:
        ap.error("--n must be at least 1")
    cfg = _config()
    t0 = time.perf_counter()
    if a.fisher:
        jobs = [(i, a.seed, cfg, ()) for i in range(a.n)]
        _print_fisher(list(map_in_order(fisher_chain, jobs, a.workers)))
        return 0
    results, done = [], 0
    for r in map_in_order(
        run_chain, [(i, a.seed, cfg, tuple(filter(None, a.oracle.split(",")))) for i in range(a.n)], a.workers
    ):
        results.append(r)
        done += 1
        if done % 20 == 0 or done == a.n:
            print(f"  {done}/{a.n} chains ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    ok = [r for r in results if "error" not in r]
    if a.dump:
        a.dump.write_text(json.dumps(results, default=float))
    print(
        f"Rod calibrate-then-measure coverage: {len(ok)} of {a.n} chains solved (seed {a.seed}); "
        f"{time.perf_counter() - t0:.0f} s"
    )
    refused = [r for r in results if "error" in r]
    if refused:
        print(f"  refused by the rod solve ({len(refused)}), first five:")
        for r in refused[:5]:
            print(f"    chain {r['index']}: {r['error']}")
    print(f"{'quantity':<36}{'n':>5}{'covered 95.45 %':>18}{'+- s.e.':>9}{'z SD':>8}{'max |z|':>9}")
    labels = {
        "D20": "part hole diameter at 20 degC",
        "D_T": "part hole diameter at T",
        "E": "verification error on own gauges",
    }
    for key, label in labels.items():
        z = np.array([x for r in ok for x in r["z"][key]])
        c = np.array([x for r in ok for x in r["covered"][key]])
        if not z.size:
            continue
        p = c.mean()
        print(
            f"{label:<36}{z.size:>5}{100 * p:>17.1f}%{100 * math.sqrt(p * (1 - p) / z.size):>8.1f}%"
            f"{np.std(z):>8.2f}{np.max(np.abs(z)):>9.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
