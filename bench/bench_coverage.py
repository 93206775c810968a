"""Coverage of the GUM budgets: >= 200 simulated calibrate-then-measure chains over the contract.

Each chain (fixed seed, chain i from its own child seed) draws a three-sensor ring-gauge
calibration scan over the whole contract (:func:`borescan.synthetic.tri_scenarios.draw_tri_calibration`) and
then draws, from the distributions the budget states, everything the pipeline takes as known:

- the gauge: its true temperature T_g uniform in 18-22 degC (the scene's radius is the gauge at
  T_g), its true D20 = 2 R / (1 + alpha (T_g - 20)); the certificate states D20 + N(0, (U/k)^2)
  (U = 1.5 um, k = 2); scan.json states T_g + U(+-a_T) (a_T = ``uncertainty.temperature_accuracy_c``)
  and alpha + U(+-a_alpha) (``uncertainty.cte_accuracy_per_k``);
- the reported centre and spindle position: off the truth by U(+-a) per coordinate (the
  scenarios' draw, a = ``calibration.position_accuracy_mm``);
- the sensors: linearity_fs log-uniform in 1e-5 .. 1e-3 (scan.json), and a linearity error per
  channel U(+-linearity_fs range) added to every reading of the calibration scan and,
  independently, of the measurement (the budget's model); repeatability_mm = the readings' true
  noise; resolution_mm = 0.1 um;
- a part: a bore of radius R + U(-0.1, 0.1) mm at a true temperature T_p uniform in 18-22 degC
  (true D20 from it), stated T and alpha drawn as for the gauge, measured statically by the same
  device (10 poses of 20 samples within half the calibration's spindle offset of the bore centre,
  the scan's noise, every reading in range).

The pipeline's own path then calibrates (``stages.calibration_fit.calibrate_raw_scans`` with the
``uncertainty`` section: fit, GUM budget) and measures (``measure.tri_diameter_with_budget``).
Printed: per calibrated parameter family (beta, rho, d_b; beta as beta_c - beta_ref where the
calibration holds a reference) and per diameter (at 20 degC and at the measured temperature) the
share of 95.45 % intervals (k from the budget) that cover the truth, with its binomial standard
error, the z-score SD, and the same split by the budget's dominant input. Acceptance (issue 19):
93-97 % for every row of the first table.

``--flagged`` (issue 36): only calibration scenes in which Eq. (1) of :mod:`borescan.mirror` at the truth
puts some beam's mirror less than 25 in chi^2 above the minimum (the contract's draws with bores to R 500 mm,
kept by that condition alone), and a part of another size than the gauge (R + U(-w, w), w 90 % of the
smallest sensor range, as far as the static poses' readings stay in range): printed besides, for the chains
whose calibration has a flagged beam, the coverage of the diameters' own 95 % intervals (the two-solution
mixture, JCGM 101), refusals outside the valid bore range apart from other refusals, and the wrong-sign main
solutions against the stated probabilities.

Run: ``python -m bench coverage`` or
``python -m bench.bench_coverage [--n 200] [--seed 20270619] [--workers 2] [--flagged]``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench.coverage_flagged import draw_calibration, print_flagged, shallowest_mirror
from borescan.parallel import map_in_order

N_CHAINS = 200
SEED = 20270619
ROOT = Path(__file__).resolve().parents[1]


def _config() -> dict:
    from borescan.config import load_config

    return load_config(ROOT / "config" / "config.yaml")


def _with_offsets(lds, channels, offsets_mm):
    """Add a constant per channel to every (non-null) reading of a long-format lds frame."""
    import polars as pl

    add = dict(zip((int(c) for c in channels), (float(o) for o in offsets_mm)))
    return lds.with_columns(
        (pl.col("value_mm") + pl.col("sensor").cast(pl.Int64).replace_strict(add, default=0.0)).alias(
            "value_mm"
        )
    )


def _sensors(meta: dict, lin_fs: float, noise_mm: float) -> list[dict]:
    return [
        dict(s, linearity_fs=lin_fs, repeatability_mm=noise_mm, resolution_mm=1e-4) for s in meta["sensors"]
    ]


def draw_chain(i: int, seed: int, base: Path, cfg: dict, flagged: bool = False) -> dict:
    """Write chain i's calibration and measurement scans (raw) and return its truth.

    With ``flagged`` (issue 36): the calibration from :func:`bench.coverage_flagged.draw_calibration`, and
    the part a bore of another size than the gauge: R + U(-w, w), w 90 % of the smallest sensor range
    (what the static poses' readings allow), redrawn until every reading is in range.
    """
    from borescan import geometry
    from borescan.synthetic import battery, scenes, simulate

    unc = cfg["uncertainty"]
    sid = battery.battery_scan_id(seed, i)
    night = "2027-02-01"
    sim = draw_calibration(i, seed, flagged)
    ct = sim.truth["contract"]
    scene = scenes.TriScene.from_dict(sim.truth["scene"])
    beams = scene.beams
    rng2 = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(i), 1)))
    a_T, a_a = float(unc["temperature_accuracy_c"]), float(unc["cte_accuracy_per_k"])
    k_g, U_g = 2.0, 0.0015
    lin_fs = float(10 ** rng2.uniform(-5, -3))
    a_lin = lin_fs * np.asarray(ct["range_mm"], float)
    alpha = float(scene.cte_per_k)
    # the gauge
    T_g = float(rng2.uniform(18.0, 22.0))
    R_T = float(ct["bore_radius_mm"])  # the scene's gauge radius: the gauge at T_g
    D20_g = 2 * R_T / (1 + alpha * (T_g - 20))
    meta = json.loads(json.dumps(sim.meta))
    meta["artifact"]["certified_diameter_mm"] = D20_g + U_g / k_g * float(rng2.standard_normal())
    meta["artifact"]["u_diameter_mm"], meta["artifact"]["k"] = U_g, k_g
    meta["artifact"]["cte_per_k"] = alpha + float(rng2.uniform(-a_a, a_a))
    meta["environment"] = {"temperature_c": T_g + float(rng2.uniform(-a_T, a_T))}
    meta["sensors"] = _sensors(meta, lin_fs, ct["noise_mm"])
    e_cal = rng2.uniform(-a_lin, a_lin)
    sim_cal = replace(sim, meta=meta, lds=_with_offsets(sim.lds, beams.channels, e_cal))
    cal_path = simulate.write_simulated(sim_cal, base / "raw", base / "truth")
    # the part, measured statically with the same device
    ecc = float(ct["spindle_offset_mm"])
    C = np.asarray(ct["center_xy_mm"], float)
    part = None
    half_width_mm = 0.9 * float(np.min(ct["range_mm"])) if flagged else 0.1
    for _ in range(200):
        R_p = R_T + float(rng2.uniform(-half_width_mm, half_width_mm))
        r = 0.5 * ecc * np.sqrt(rng2.uniform(0, 1, 10))
        ang = rng2.uniform(0, 2 * np.pi, 10)
        xy = C + np.stack([r * np.cos(ang), r * np.sin(ang)], -1)
        dev_ang = rng2.uniform(0, 2 * np.pi, 10)
        v = geometry.tri_static_readings(xy, dev_ang, beams, geometry.Bore(tuple(C), R_p))
        lo = np.max(a_lin) + 0.01
        if np.all(np.isfinite(v)) and np.all(v > lo) and np.all(v < np.asarray(ct["range_mm"]) - lo):
            part = (R_p, xy, dev_ang)
            break
    out = {
        "index": i,
        "scan_id": sid,
        "cal_path": str(cal_path),
        "beams": beams.to_nominal(),
        "lin_fs": lin_fs,
        "e_cal_mm": e_cal.tolist(),
        "gauge_T_c": T_g,
        "noise_mm": ct["noise_mm"],
        "angle_source": ct["angle_source"],
        "position_known": ct["position_known"],
        "gauge_D20_mm": D20_g,
        "meas_path": None,
        "gauge_radius_mm": R_T,
        "shallowest_mirror": shallowest_mirror(sim.truth),
    }
    if part is None:
        return out
    R_p, xy, dev_ang = part
    T_p = float(rng2.uniform(18.0, 22.0))
    D20_p = 2 * R_p / (1 + alpha * (T_p - 20))
    pscene = replace(scene, bore_radius_20_mm=R_p, temperature_c=20.0)  # R_p is the bore as it is, at T_p
    art = {
        "id": f"PART-{i:05d}",
        "type": "part",
        "nominal_diameter_mm": float(round(2 * R_p, 1)),
        "cte_per_k": alpha + float(rng2.uniform(-a_a, a_a)),
    }
    psim = simulate.simulate_tri_static(
        pscene,
        xy,
        dev_ang,
        scan_id=f"{sid}-MEAS",
        night=night,
        kind="measurement",
        samples_per_pose=20,
        noise_mm=ct["noise_mm"],
        seed=int(rng2.integers(2**31)),
        device_id=sim.meta["device"]["id"],
        artifact=art,
    )
    pmeta = json.loads(json.dumps(psim.meta))
    pmeta["environment"] = {"temperature_c": T_p + float(rng2.uniform(-a_T, a_T))}
    pmeta["sensors"] = _sensors(pmeta, lin_fs, ct["noise_mm"])
    e_meas = rng2.uniform(-a_lin, a_lin)
    psim = replace(psim, meta=pmeta, lds=_with_offsets(psim.lds, beams.channels, e_meas))
    out.update(
        meas_path=str(simulate.write_simulated(psim, base / "raw", base / "truth")),
        part_D20_mm=D20_p,
        part_DT_mm=2 * R_p,
        e_meas_mm=e_meas.tolist(),
        part_T_c=T_p,
    )
    return out


def evaluate_chain(job: tuple) -> dict:
    """Calibrate and measure one chain by the pipeline's path; return its errors.

    Calibrate and measure one chain by the pipeline's path; errors against the truth in units of u and
    U.
    """
    truth, cfg = job
    from borescan import measure, rawio
    from borescan.calibrate.result import CalibrationError
    from borescan.geometry import Beams
    from borescan.stages.calibration_fit import calibrate_raw_scans
    from borescan.uncertainty import Budget

    unc = cfg["uncertainty"]
    p = float(unc["coverage_probability"])
    row = {k: truth[k] for k in ("index", "scan_id", "lin_fs", "noise_mm", "angle_source", "position_known")}
    t0 = time.perf_counter()
    scan = rawio.read_scan(Path(truth["cal_path"]))
    try:
        cal = calibrate_raw_scans([scan], cfg["calibration"], uncertainty=unc)
    except CalibrationError as e:
        row.update(accepted=False, reason=e.problem, seconds=time.perf_counter() - t0)
        return row
    row["accepted"] = True
    b = Budget.from_dict(cal.diagnostics["budget"])
    tb = Beams.from_nominal(truth["beams"])
    true_p = np.stack([tb.beta_rad, tb.rho_mm, tb.d_b_mm], axis=1).ravel()
    c = len(tb.channels)
    ref = cal.diagnostics.get("beta_reference", "absolute")
    f = None if ref == "absolute" else list(cal.beams.channels).index(int(str(ref).split()[1]))
    params = []
    for j in range(c):
        for k, fam in enumerate(("beta", "rho", "d_b")):
            if fam == "beta" and f is not None and j == f:
                continue
            vec = np.zeros(3 * c)
            vec[3 * j + k] = 1.0
            if fam == "beta" and f is not None:
                vec[3 * f] = -1.0
            err = float(vec @ (cal.params - true_p))
            if fam == "beta":
                err = (err + np.pi) % (2 * np.pi) - np.pi
            comb = b.combined(vec, p)
            params.append(
                {
                    "family": fam,
                    "channel": int(tb.channels[j]),
                    "err": err,
                    "u": comb.u,
                    "U": comb.U,
                    "k": comb.k,
                    "dominant": comb.dominant.split(":", 1)[0],
                }
            )
    row["params"] = params
    row["weak_rho"] = list(cal.diagnostics.get("weak_rho_channels", []))
    from borescan.mirror import mirror_checks_of

    checks = mirror_checks_of(cal.diagnostics)
    row["flagged"] = any(not m.resolved for m in checks)
    # issue 36: per flagged beam the stated probability of the wrong sign and whether the kept sign is wrong
    row["flagged_beams"] = [
        {
            "channel": int(m.channel),
            "p_wrong_sign": float(m.p_wrong_sign),
            "wrong_sign": bool(np.sign(cal.beams.rho_mm[j]) != np.sign(tb.rho_mm[j])),
        }
        for m in checks
        if not m.resolved
        for j in [list(cal.beams.channels).index(int(m.channel))]
    ]
    row["shallowest_mirror"] = truth.get("shallowest_mirror")
    row["part_over_gauge"] = truth.get("part_DT_mm", float("nan")) / (2 * truth["gauge_radius_mm"])
    if truth.get("meas_path"):
        pscan = rawio.read_scan(Path(truth["meas_path"]))
        try:
            pres, du = measure.tri_diameter_with_budget(pscan, cal, unc)
            mix = pres.get("mirror_mixture")
            row["mixture"] = mix is not None
            # the coverage interval itself: the mixture's probabilistically symmetric one (JCGM 101 7.7),
            # else the GUM's D +- U
            lo20, hi20 = (
                mix.interval_20_mm if mix is not None else (du.diameter_20_mm - du.combined_20.U,) * 2
            )
            lot, hit = mix.interval_mm if mix is not None else (du.diameter_mm - du.combined_t.U,) * 2
            if mix is None:
                hi20, hit = du.diameter_20_mm + du.combined_20.U, du.diameter_mm + du.combined_t.U
            row["diameters"] = [
                {
                    "family": "D at 20 degC",
                    "err": du.diameter_20_mm - truth["part_D20_mm"],
                    "u": du.combined_20.u,
                    "U": du.combined_20.U,
                    "k": du.combined_20.k,
                    "dominant": du.combined_20.dominant.split(":", 1)[0],
                    "interval_err": [lo20 - truth["part_D20_mm"], hi20 - truth["part_D20_mm"]],
                },
                {
                    "family": "D at T",
                    "err": du.diameter_mm - truth["part_DT_mm"],
                    "u": du.combined_t.u,
                    "U": du.combined_t.U,
                    "k": du.combined_t.k,
                    "dominant": du.combined_t.dominant.split(":", 1)[0],
                    "interval_err": [lot - truth["part_DT_mm"], hit - truth["part_DT_mm"]],
                },
            ]
        except ValueError as e:
            row["measure_error"] = str(e)
    row["seconds"] = time.perf_counter() - t0
    return row


def run(
    n: int = N_CHAINS,
    seed: int = SEED,
    workers: int | None = None,
    rows_path: Path | None = None,
    flagged: bool = False,
) -> list[dict]:
    """Draw, write, calibrate and measure ``n`` chains; return per-chain rows.

    Draw, write, calibrate and measure ``n`` chains; per-chain rows (also appended to ``rows_path``
    as JSON lines as they come, when given).
    """
    workers = workers or min(2, os.cpu_count() or 1)
    cfg = _config()
    with tempfile.TemporaryDirectory(prefix="coverage-") as tmp:
        t0 = time.perf_counter()
        truths = [draw_chain(i, seed, Path(tmp), cfg, flagged) for i in range(n)]
        print(f"{n} chains drawn and written in {time.perf_counter() - t0:.0f} s (seed {seed})", flush=True)
        jobs = [(t, cfg) for t in truths]
        rows: list[dict] = []
        sink = None
        if rows_path is not None:
            rows_path.parent.mkdir(parents=True, exist_ok=True)
            sink = rows_path.open("w")

        def keep(row: dict) -> None:
            rows.append(row)
            if sink is not None:
                sink.write(json.dumps(row, default=float) + "\n")
                sink.flush()

        t0 = time.perf_counter()
        for i, row in enumerate(map_in_order(evaluate_chain, jobs, workers)):  # one BLAS thread per worker
            keep(row)
            if (i + 1) % 25 == 0:
                print(f"  {i + 1}/{n} chains ({time.perf_counter() - t0:.0f} s)", flush=True)
        if sink is not None:
            sink.close()
        print(f"evaluated in {time.perf_counter() - t0:.0f} s with {workers} worker(s)", flush=True)
    return rows


def covered(x: dict) -> bool:
    """Whether the quantity's 95 % interval holds the truth.

    Its own interval (a mixture's is asymmetric) when the row has one, else err within +-U.
    """
    if "interval_err" in x:
        lo, hi = x["interval_err"]
        return bool(lo <= 0.0 <= hi)
    return bool(abs(x["err"]) <= x["U"])


def _stats(items: list[dict]) -> dict:
    if not items:
        return {
            "n": 0,
            "cover": float("nan"),
            "se": float("nan"),
            "z_sd": float("nan"),
            "k_mean": float("nan"),
        }
    cov = np.array([covered(x) for x in items], float)
    z = np.array([x["err"] / x["u"] for x in items if x["u"] > 0])
    return {
        "n": len(items),
        "cover": float(cov.mean()),
        "se": float(math.sqrt(cov.mean() * (1 - cov.mean()) / len(items))),
        "z_sd": float(np.std(z)) if z.size else float("nan"),
        "z_max": float(np.max(np.abs(z))) if z.size else float("nan"),
        "k_mean": float(np.mean([x["k"] for x in items])),
    }


def summarize(rows: list[dict]) -> dict:
    """Return the coverage figures of the chains' rows per quantity family."""
    acc = [r for r in rows if r.get("accepted")]
    groups: dict[str, list] = {}
    for r in acc:
        for x in r["params"] + r.get("diameters", []):
            groups.setdefault(x["family"], []).append(x)
    out = {
        "chains": len(rows),
        "accepted": len(acc),
        "measured": sum(1 for r in acc if r.get("diameters")),
        "refused": sorted({r.get("reason", "")[:120] for r in rows if not r.get("accepted")}),
        "families": {k: _stats(v) for k, v in groups.items()},
        "by_dominant": {},
    }
    for fam, items in groups.items():
        doms = sorted({x["dominant"] for x in items})
        out["by_dominant"][fam] = {d: _stats([x for x in items if x["dominant"] == d]) for d in doms}
    return out


def print_table(rows: list[dict]) -> dict:
    """Print the coverage table of the rows; return :func:`summarize` of them."""
    s = summarize(rows)
    print(f"chains {s['chains']}, calibrations accepted {s['accepted']}, parts measured {s['measured']}")
    for reason in s["refused"]:
        print(f"  refused: {reason}")
    print(
        f"{'quantity':16s} {'n':>5s} {'cover95':>8s} {'+-se':>6s} {'z SD':>6s} {'max|z|':>7s} "
        f"{'mean k':>7s}  "
        "accept 93-97 %"
    )
    for fam in ("beta", "rho", "d_b", "D at 20 degC", "D at T"):
        d = s["families"].get(fam)
        if not d:
            continue
        ok = "yes" if 0.93 <= d["cover"] <= 0.97 else "NO"
        print(
            f"{fam:16s} {d['n']:5d} {d['cover']:8.1%} {d['se']:6.1%} {d['z_sd']:6.3f} {d['z_max']:7.2f} "
            f"{d['k_mean']:7.3f}  {ok}"
        )
    print_flagged(rows)
    print("by the budget's dominant input:")
    for fam, by in s["by_dominant"].items():
        for dom, d in by.items():
            print(
                f"  {fam:14s} {dom:12s} n {d['n']:4d}  cover95 {d['cover']:6.1%}  z SD {d['z_sd']:.3f}  "
                f"mean k {d['k_mean']:.3f}"
            )
    return s


def main(argv: list[str] | None = None) -> None:
    """Draw, calibrate and measure the chains and print the coverage table (options: ``--help``)."""
    ap = argparse.ArgumentParser(prog="python -m bench.bench_coverage", description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=N_CHAINS, help=f"chains (default {N_CHAINS})")
    ap.add_argument("--seed", type=int, default=SEED, help=f"seed (default {SEED})")
    ap.add_argument("--workers", type=int, default=None, help="processes (default min(2, cpus))")
    ap.add_argument("--rows", type=Path, default=None, help="write the per-chain rows here (JSON lines)")
    ap.add_argument(
        "--table", type=Path, default=None, help="only print the table of rows written earlier by --rows"
    )
    ap.add_argument(
        "--flagged",
        action="store_true",
        help="issue 36: only scenes whose Eq. (1) mirror depth is below 25 for a beam (bores to R 500 mm), "
        "parts of other sizes than the gauge (within the sensors' range)",
    )
    args = ap.parse_args([] if argv is None else argv)
    if args.table is not None:
        print_table([json.loads(line) for line in args.table.read_text().splitlines() if line.strip()])
        return
    rows = run(args.n, args.seed, args.workers, args.rows, args.flagged)
    print_table(rows)


if __name__ == "__main__":
    main(sys.argv[1:])
