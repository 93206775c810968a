"""Coverage of a rod's GUM budget: simulated calibrate-then-measure chains on certified ring gauges.

Each chain (fixed seed, chain i from its own child seed) draws a measuring rod whose true layers
are off its design (base length l0 = 71 mm + U(+-30 um), beam offset d U(+-0.4 mm), tilt gamma
U(+-0.3 deg), in-plane angle phi U(+-0.05 rad); the design in scan.json has l0 = 71 mm and the
rest 0) and draws, from the distributions the budget states, everything the pipeline takes as known:

- the gauge set: two rings of true D20 = 150 mm + U(+-10 um), their certificates stating D20 +
  N(0, (U/k)^2) (U = 1.2 um, k = 2); true temperature U(18, 22) degC, stated within
  +-``uncertainty.temperature_accuracy_c``; expansion coefficient stated within
  +-``uncertainty.cte_accuracy_per_k``;
- the sensors: linearity_fs log-uniform in 1e-5 .. 1e-3 of the 8 mm range (scan.json), and a
  linearity error per layer U(+-linearity_fs range) added to every reading of the calibration
  scan and, independently, of the measurement (the budget's model); repeatability = the readings'
  true noise (10 um);
- the rod held skew to the holes as the procedure asks: eccentricity 0.5-1.5 mm in a random
  direction, deflection U(0.1, 0.3) deg across it (+-0.5 rad); 24 poses of 5 samples each;
- a part with two holes of D20 = 150 mm + U(+-20 um) at its own temperature U(18, 22) degC,
  measured the same way with a new hold of the rod.

The pipeline's own path then calibrates (``rod_calibration.calibrate_l0`` + its budget) and
measures (``rod_calibration.rod_diameters_with_budget``). Printed: the share of 95.45 %
intervals (k from the budget) that cover each true diameter (at 20 degC and at the measured
temperature), with its binomial standard error and the z-score SD; the same for the verification
error on the calibration's own gauges, measured in a second hold. The base length itself has no
truth to score: l0 takes up the beam offset and tilt and the solve's deflection average, which is
its purpose.

Run: ``python -m bench rod_coverage`` or ``python -m bench.bench_rod_coverage [--n 200] [--seed 20270701] [--workers 2]``.
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


def _config() -> dict:
    from borescan.config import load_config

    return load_config(ROOT / "config" / "config.yaml")


def _scan(rng, layers, d20_mm, T_c, kind, scan_id, artifact, design, lin_fs, unc, base: Path):
    """Write one rod scan with the stated temperature, sensors and a linearity error per layer; read it back."""
    import polars as pl

    from borescan import rawio, simulate
    from borescan.effects import Effect
    from borescan.geometry import Hole, RodAxis

    e = float(rng.uniform(0.5, 1.5))
    az = float(rng.uniform(0, 2 * np.pi))
    axis = RodAxis(e * math.cos(az), e * math.sin(az), math.radians(float(rng.uniform(0.1, 0.3))),
                   az + math.pi / 2 + float(rng.uniform(-0.5, 0.5)))
    scene = simulate.RodScene(layers=layers, holes=(Hole((0.0, 0.0), d20_mm[0] / 2), Hole((0.01, -0.02), d20_mm[1] / 2)),
                              axis=axis, range_mm=(8.0, 8.0), sample_rate_hz=100.0, cte_per_k=CTE, temperature_c=T_c)
    sim = simulate.simulate_rod(scene, n_poses=24, samples_per_pose=5, kind=kind, artifact=artifact,
                                features=("H1", "H2"), nominal_layers=design, scan_id=scan_id,
                                effects=[Effect("thermal_expansion", {"temperature_c": T_c})],
                                seed=int(rng.integers(2**31)))
    meta = json.loads(json.dumps(sim.meta))
    meta["environment"] = {"temperature_c": T_c + float(rng.uniform(-1, 1)) * float(unc["temperature_accuracy_c"])}
    meta["artifact"]["cte_per_k"] = CTE + float(rng.uniform(-1, 1)) * float(unc["cte_accuracy_per_k"])
    meta["sensors"] = [dict(s, linearity_fs=lin_fs, repeatability_mm=simulate.ROD_NOISE_MM, resolution_mm=1e-4)
                       for s in meta["sensors"]]
    err = rng.uniform(-1, 1, 2) * lin_fs * 8.0
    lds = sim.lds.with_columns((pl.col("value_mm") + pl.col("sensor").cast(pl.Int64).replace_strict(
        {1: float(err[0]), 2: float(err[1])}, default=0.0)).alias("value_mm"))
    folder = simulate.write_simulated(replace(sim, meta=meta, lds=lds), base / "raw", base / "truth")
    return rawio.read_scan(folder, raw_root=base / "raw")


def run_chain(job) -> dict:
    """One calibrate-then-measure chain: its z-scores and coverage flags."""
    i, seed, cfg = job
    from borescan import rod_calibration
    from borescan.artifacts import artifact_cte, scan_temperature
    from borescan.geometry import RodLayer

    unc = cfg["uncertainty"]
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(i),)))
    true = tuple(RodLayer(ch, h, 71.0 + float(rng.uniform(-0.03, 0.03)), float(rng.uniform(-0.05, 0.05)),
                          float(rng.uniform(-0.4, 0.4)), math.radians(float(rng.uniform(-0.3, 0.3))))
                 for ch, h in ((1, 100.0), (2, 400.0)))
    design = tuple(replace(lay, l0_mm=71.0, phi_rad=0.0, d_mm=0.0, gamma_rad=0.0) for lay in true)
    lin_fs = float(10 ** rng.uniform(-5, -3))
    U_g, k_g = 0.0012, 2.0
    g20 = 150.0 + rng.uniform(-0.01, 0.01, 2)
    gset = {"id": f"RGS-{i}", "type": "ring_gauge", "u_diameter_mm": U_g, "k": k_g, "certificate": f"C-{i}",
            "features": [{"id": f, "z_mm": z, "certified_diameter_mm": float(d + U_g / k_g * rng.standard_normal()),
                          "gauge_id": f"RG-{i}-{f}"} for f, z, d in zip(("H1", "H2"), (100.0, 400.0), g20)]}
    out = {"index": i, "lin_fs": lin_fs}
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp)
        try:
            cal = _scan(rng, true, g20, float(rng.uniform(18, 22)), "calibration", f"CAL-{i}", gset, design, lin_fs,
                        unc, base / "c")
            channels, means, u_mean, sensors = rod_calibration.pose_means_of_scan(cal)
            gauges = rod_calibration.layer_gauges(cal.meta, channels)
            temp, cte = scan_temperature(cal.meta, unc), artifact_cte(cal.meta, unc)
            r_t = [0.5 * g["certified_diameter_mm"] * (1 + cte.cte_per_k * (temp.temperature_c - 20)) for g in gauges]
            layers, sol, _n = rod_calibration.calibrate_l0(means, design, u_mean, r_t)
            budget = rod_calibration.rod_calibration_budget([lay.l0_mm for lay in layers], sol, gauges, temp, cte,
                                                            sensors, cal.scan_id, float(unc["sensor_resolution_mm"]))
            blob = json.dumps({"budget": rod_calibration._json_safe(budget.to_dict())})
            rows = [{"channel": lay.channel, "l0_mm": lay.l0_mm, "h_mm": lay.h_mm, "phi_rad": 0.0, "d_mm": 0.0,
                     "gamma_rad": 0.0, "calibration_json": blob} for lay in layers]
            p20 = 150.0 + rng.uniform(-0.02, 0.02, 2)
            T_p = float(rng.uniform(18, 22))
            part = {"id": f"P-{i}", "type": "part", "features": [{"id": f, "z_mm": z, "nominal_diameter_mm": 150.0}
                                                                for f, z in (("H1", 100.0), ("H2", 400.0))]}
            meas = _scan(rng, true, p20, T_p, "measurement", f"MEAS-{i}", part, design, lin_fs, unc, base / "m")
            res = rod_calibration.rod_diameters_with_budget(meas, rows, unc, "C")
            T_v = float(rng.uniform(18, 22))
            ver = _scan(rng, true, g20, T_v, "verification", f"VER-{i}", gset, design, lin_fs, unc, base / "v")
            vres = rod_calibration.rod_diameters_with_budget(ver, rows, unc, "C")
            vrows = rod_calibration.rod_verifications(ver, vres, "C", unc, cfg["laboratory"], 1.0)
        except (ValueError, np.linalg.LinAlgError) as err:
            return dict(out, error=str(err)[:200])
    zs = {"D20": [], "D_T": [], "E": []}
    cov = {"D20": [], "D_T": [], "E": []}
    for r, d20 in zip(res, p20):
        du = r["du"]
        dT = d20 * (1 + CTE * (T_p - 20))
        for key, val, truth, comb in (("D20", du.diameter_20_mm, d20, du.combined_20),
                                      ("D_T", du.diameter_mm, dT, du.combined_t)):
            zs[key].append((val - truth) / comb.u)
            cov[key].append(abs(val - truth) <= comb.U)
    for v, d20, cert in zip(vrows, g20, [f["certified_diameter_mm"] for f in gset["features"]]):
        e_true = 0.0  # the gauge measured as it is: the error of the measurement is D20 measured - true D20
        e = v["measured_mm"] - d20
        zs["E"].append((e - e_true) / v["u_error_mm"])
        cov["E"].append(abs(e - e_true) <= v["expanded_u_error_mm"])
    return dict(out, z=zs, covered=cov)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=N_CHAINS, help="chains (default %(default)s)")
    ap.add_argument("--seed", type=int, default=SEED)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    if a.n < 1:
        ap.error("--n must be at least 1")
    cfg = _config()
    t0 = time.perf_counter()
    results, done = [], 0
    for r in map_in_order(run_chain, [(i, a.seed, cfg) for i in range(a.n)], a.workers):
        results.append(r)
        done += 1
        if done % 20 == 0 or done == a.n:
            print(f"  {done}/{a.n} chains ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    ok = [r for r in results if "error" not in r]
    print(f"Rod calibrate-then-measure coverage: {len(ok)} of {a.n} chains solved (seed {a.seed}); "
          f"{time.perf_counter() - t0:.0f} s")
    for r in results:
        if "error" in r:
            print(f"  chain {r['index']}: refused: {r['error']}")
    print(f"{'quantity':<36}{'n':>5}{'covered 95.45 %':>18}{'+- s.e.':>9}{'z SD':>8}{'max |z|':>9}")
    labels = {"D20": "part hole diameter at 20 degC", "D_T": "part hole diameter at T",
              "E": "verification error on own gauges"}
    for key, label in labels.items():
        z = np.array([x for r in ok for x in r["z"][key]])
        c = np.array([x for r in ok for x in r["covered"][key]])
        if not z.size:
            continue
        p = c.mean()
        print(f"{label:<36}{z.size:>5}{100 * p:>17.1f}%{100 * math.sqrt(p * (1 - p) / z.size):>8.1f}%"
              f"{np.std(z):>8.2f}{np.max(np.abs(z)):>9.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
