"""Why resolved beams' stated u leave [0.9, 1.2] x the Cramer-Rao bound (issue 36): the bound at the fit.

Every scan of the calibration contract battery (:mod:`bench.bench_calibration_contract`, same seed; an
already written battery with ``--battery DIR``) is calibrated by the pipeline's path and compared with its
truth. For each compared quantity of a beam whose sign the calibration resolves (beta differences or
absolute beta, rho, d_b) it records:

- ``u``, the calibration's stated standard uncertainty;
- ``crb_truth``, the bench's Cramer-Rao bound at the TRUE beams (:func:`crb_compared`);
- ``crb_fit``, the same bound with the beams replaced by the FIT's (rho, d_b and the compared beta
  differences; offset, phase and speed scale stay the truth's, which the data fix to micrometres):
  the information the calibration's own curvature sees;
- the beam's mirror depth Eq. (1) at the truth (:func:`borescan.mirror.predicted_depth`; inf where no
  mirror exists, |rho| <= sqrt(2) e), the scan's angle source, speed change, positions known, whether
  a channel leaves its range, and whether a non-linear rho profile widened the scan's covariance.

Printed: the share of u / crb_truth in [0.9, 1.2] split by family, side, sqrt(depth), case; for the
out-of-band quantities u / crb_fit (is the stated u the fit's own bound?) and crb_fit / crb_truth (does
the information move between the fit and the truth?); and the issue's hypothesis for weak rho, that
crb_fit / crb_truth - 1 follows about 2 z / sqrt(depth).

``--weak-anchor-mc N``: instead, N noise draws of one scene with a weak anchor (two strong beams, rho 12 and
-9 mm, and rho_3 = 0.6 mm with u(rho_3) about 1.9 mm; commanded angle, no positions, 5 revolutions of 660
samples, sigma 8 um, e = 2 mm on a 137.5 mm gauge, the scene of ``tests/test_calibration_shared_mode.py``),
each calibrated (``fit_full_calibration``): for the strong beams' rho and d_b, the spread of the errors over
the bound at the truth (:func:`borescan.plan.predict`), the stated u's z SD and coverage, u / CRB(truth) and
u / CRB(fit) in [0.9, 1.2], and the coverage a u equal to the truth's bound would have.

Run: ``python -m bench.bench_calibration_band --n 200 --workers 2 [--battery /tmp/pb200] [--rows OUT]``;
``python -m bench.bench_calibration_band --weak-anchor-mc 200 --workers 2``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from bench.bench_calibration_contract import (
    SEED,
    _compared,
    crb_compared,
    default_calibration_config,
    evaluate_scan_with_calibration,
)
from bench.calibration_contract_tables import FAMILIES, _channel_of_row, fixed_channel

from borescan.parallel import map_in_order

#: several minutes for 200 scans: runs only when named
RUN_BY_DEFAULT = False
BAND = (0.9, 1.2)
#: |rho| / u(rho) of the scan's weakest beam: bins of the split
ANCHOR_EDGES = (2.0, 5.0, 10.0, 20.0, math.inf)
#: sqrt of the mirror depth Eq. (1) at the truth: bins of the split (inf: no mirror)
SQRT_DEPTH_EDGES = (5.0, 10.0, 30.0, 100.0, math.inf)


@dataclass(frozen=True)
class BandRecord:
    """One compared quantity of a resolved beam (module doc)."""

    scan_id: str
    family: str
    channel_index: int
    z: float
    u: float
    crb_truth: float
    crb_fit: float
    sqrt_depth_truth: float
    rho_true_mm: float
    rho_over_crb: float
    angle_source: str
    speed_change: bool
    position_known: bool
    out_of_range: bool
    profiled: bool
    anchor_rho_over_crb: float
    anchor_rho_over_u_hat: float
    anchor_ratio: float
    is_anchor: bool


def _fit_scene(scene, cal, f: int | None):
    """Return the truth ``scene`` with the fit's beams in the truth's beta gauge (module doc)."""
    from borescan.geometry import Beams

    tb, fb = scene.beams, cal.beams
    if f is None:
        beta = np.asarray(fb.beta_rad, float)
    else:
        beta = np.asarray(tb.beta_rad, float)[f] + np.asarray(fb.beta_rad, float) - float(fb.beta_rad[f])
    return replace(scene, beams=Beams(tb.channels, beta, np.asarray(fb.rho_mm, float), np.asarray(fb.d_b_mm)))


def evaluate(job: tuple) -> list[dict]:
    """Calibrate one scan; return its resolved beams' records (as dicts)."""
    path, truth_root, cal_cfg = job
    from borescan import rawio
    from borescan.mirror import mirror_exists, predicted_depth
    from borescan.synthetic import scenes, simulate

    row, cal = evaluate_scan_with_calibration(job)
    if cal is None or not row.get("u_crb"):
        return []
    scan = rawio.read_scan(Path(path))
    truth = simulate.load_truth(truth_root, scan.scan_id)
    ct = truth["contract"]
    scene = scenes.TriScene.from_dict(truth["scene"])
    c = len(scene.beams.channels)
    f = fixed_channel(row["beta_reference"], cal.beams.channels)
    A, fam = _compared(cal.params, f, c)
    crb_fit = crb_compared(_fit_scene(scene, cal, f), scan, cal, ct, A, fam)
    e_true = float(np.hypot(*np.subtract(ct["spindle_xy_mm"], ct["center_xy_mm"])))
    n_ch = np.isfinite(np.asarray(rawio.lds_matrix(scan).values_mm, dtype=float)).sum(axis=0)
    rho_t = scene.beams.rho_mm
    depth = [
        predicted_depth([int(n_ch[j])], [e_true], float(rho_t[j]), [ct["noise_mm"]], scene.bore_radius_20_mm)
        if mirror_exists(float(rho_t[j]), e_true)
        else math.inf
        for j in range(c)
    ]
    profiled = any("extra_cov_params" in p for p in cal.diagnostics.get("rho_profiles", []))
    flagged = {j for j, m in enumerate(row["mirror"]) if not m["resolved"]}
    nb = sum(1 for x in fam if x == "beta")
    # the scan's weakest rho (smallest |rho| / CRB at the truth): every channel's rho^2 shifts with it
    rho_crb = np.array(row["u_crb"][nb : nb + c])
    rho_hat = np.asarray(cal.beams.rho_mm, float)
    w = int(np.argmin(np.abs(rho_t) / rho_crb))
    anchor_hat = float(np.min(np.abs(rho_hat) / np.array(row["u"][nb : nb + c])))
    out = []
    for k, fm in enumerate(fam):
        j = _channel_of_row(k, fam, c, f)
        if j in flagged or (fm == "beta" and f is not None and f in flagged) or row["u"][k] <= 0:
            continue
        out.append(
            asdict(
                BandRecord(
                    scan_id=row["scan_id"],
                    family=fm,
                    channel_index=j,
                    z=row["err"][k] / row["u"][k],
                    u=row["u"][k],
                    crb_truth=row["u_crb"][k],
                    crb_fit=float(crb_fit[k]),
                    sqrt_depth_truth=math.sqrt(depth[j]),
                    rho_true_mm=float(rho_t[j]),
                    rho_over_crb=abs(float(rho_t[j])) / row["u_crb"][nb + j],
                    angle_source=row["angle_source"],
                    speed_change=bool(row["speed_change"]),
                    position_known=bool(row["position_known"]),
                    out_of_range=bool(row["out_of_range"]),
                    profiled=profiled,
                    anchor_rho_over_crb=float(abs(rho_t[w]) / rho_crb[w]),
                    anchor_rho_over_u_hat=anchor_hat,
                    anchor_ratio=float(abs(rho_hat[w]) / abs(rho_t[w])),
                    is_anchor=j == w,
                )
            )
        )
    return out


def _share(recs: list[dict], key: str = "crb_truth") -> float:
    r = np.array([x["u"] / x[key] for x in recs])
    return float(np.mean((r >= BAND[0]) & (r <= BAND[1]))) if r.size else float("nan")


def _line(label: str, recs: list[dict]) -> str:
    if not recs:
        return f"  {label:34s}     0"
    r = np.array([x["u"] / x["crb_truth"] for x in recs])
    lo, hi = int(np.sum(r < BAND[0])), int(np.sum(r > BAND[1]))
    return (
        f"  {label:34s} {len(recs):5d}  in band {_share(recs):6.1%}  below {lo:4d}  above {hi:4d}  "
        f"u/CRB_fit in band {_share(recs, 'crb_fit'):6.1%}"
    )


def print_tables(recs: list[dict]) -> dict:  # noqa: C901 (one block per split of the printout)
    """Print the splits of the module doc; return the headline figures."""
    out = [x for x in recs if not BAND[0] <= x["u"] / x["crb_truth"] <= BAND[1]]
    print(f"resolved-beam quantities {len(recs)}, u / CRB(truth) in [0.9, 1.2]: {_share(recs):.1%}")
    print(
        f"u / CRB at the FIT in [0.9, 1.2]: {_share(recs, 'crb_fit'):.1%} "
        "(the stated u against the bound the fit's own point gives)"
    )
    print("by family:")
    for fam in FAMILIES:
        print(_line(fam, [x for x in recs if x["family"] == fam]))
    print("by sqrt of the mirror depth Eq. (1) at the truth:")
    lo = 0.0
    for hi in SQRT_DEPTH_EDGES:
        label = f"sqrt(dchi2_m) in [{lo:g}, {hi:g})" if math.isfinite(hi) else f"sqrt(dchi2_m) >= {lo:g}"
        print(
            _line(
                label,
                [
                    x
                    for x in recs
                    if lo <= x["sqrt_depth_truth"] < hi and math.isfinite(x["sqrt_depth_truth"])
                ],
            )
        )
        lo = hi
    print(
        _line("no mirror (|rho| <= sqrt(2) e)", [x for x in recs if not math.isfinite(x["sqrt_depth_truth"])])
    )
    for key, what in (
        ("anchor_rho_over_crb", "truth: |rho| / CRB(rho)"),
        ("anchor_rho_over_u_hat", "fit: |rho| / u(rho)"),
    ):
        print(f"by the scan's weakest rho ({what}):")
        lo = 0.0
        for hi in ANCHOR_EDGES:
            print(_line(f"[{lo:g}, {hi:g})", [x for x in recs if lo <= x[key] < hi]))
            lo = hi
    print("by case:")
    for label, pred in (
        ("encoder", lambda x: x["angle_source"] == "encoder"),
        ("rpm profile (no encoder)", lambda x: x["angle_source"] != "encoder"),
        ("speed change", lambda x: x["speed_change"]),
        ("constant speed", lambda x: not x["speed_change"]),
        ("a channel out of range", lambda x: x["out_of_range"]),
        ("every channel in range", lambda x: not x["out_of_range"]),
        ("positions known", lambda x: x["position_known"]),
        ("positions unknown", lambda x: not x["position_known"]),
        ("a rho profile widened the cov", lambda x: x["profiled"]),
        ("no profile used", lambda x: not x["profiled"]),
    ):
        print(_line(label, [x for x in recs if pred(x)]))
    ratio_fit = np.array([x["crb_fit"] / x["crb_truth"] for x in out])
    u_fit = np.array([x["u"] / x["crb_fit"] for x in out])
    print(f"out of band: {len(out)} quantities in {len({x['scan_id'] for x in out})} scans")
    if out:
        q = np.percentile
        print(
            f"  CRB(fit) / CRB(truth): 5/50/95 % {q(ratio_fit, 5):.3f} / {q(ratio_fit, 50):.3f} / "
            f"{q(ratio_fit, 95):.3f}; u / CRB(fit) {q(u_fit, 5):.3f} / {q(u_fit, 50):.3f} / "
            f"{q(u_fit, 95):.3f}"
        )
        moved = np.mean((u_fit >= BAND[0]) & (u_fit <= BAND[1]))
        print(f"  of them with u / CRB(fit) in [0.9, 1.2] (the stated u is the fit's own bound): {moved:.1%}")
    # the hypothesis: the bound's relative change between truth and fit ~ 2 z / sqrt(depth)
    weak = [x for x in recs if x["family"] != "beta" and math.isfinite(x["sqrt_depth_truth"])]
    if weak:
        pred = np.array([2.0 * x["z"] / x["sqrt_depth_truth"] for x in weak])
        obs = np.array([x["crb_fit"] / x["crb_truth"] - 1.0 for x in weak])
        sd_pred, sd_obs = float(np.std(pred)), float(np.std(obs))
        corr = float(np.corrcoef(np.abs(pred), np.abs(obs))[0, 1]) if len(weak) > 2 else float("nan")
        print(
            f"hypothesis (rho, d_b of beams with a mirror, {len(weak)}): "
            f"SD of 2 z / sqrt(depth) {sd_pred:.3f}, "
            f"SD of CRB(fit)/CRB(truth) - 1 {sd_obs:.3f}, corr of their sizes {corr:.2f}"
        )
    # the shared rho^2 mode: the other beams' bound moves with the weakest rho, |rho_w fit| / |rho_w true|
    others = [x for x in recs if x["family"] != "beta" and not x["is_anchor"] and x["anchor_ratio"] > 0]
    if len(others) > 2:
        lr = np.log(np.array([x["crb_fit"] / x["crb_truth"] for x in others]))
        la = np.log(np.array([x["anchor_ratio"] for x in others]))
        slope = float(np.sum(lr * la) / np.sum(la * la))
        print(
            f"shared mode (rho, d_b of the other beams, {len(others)}): corr of log CRB(fit)/CRB(truth) with "
            f"log |rho_w fit| / |rho_w true| {np.corrcoef(lr, la)[0, 1]:.2f}, slope {slope:.2f}"
        )
    per_scan: dict[str, list[float]] = {}
    for x in out:
        per_scan.setdefault(x["scan_id"], []).append(x["u"] / x["crb_truth"])
    print("scans with >= 4 out-of-band quantities (u / CRB(truth) of each):")
    for sid, v in sorted(per_scan.items(), key=lambda kv: -len(kv[1])):
        if len(v) >= 4:
            print(f"  {sid}: {len(v)}  {np.round(sorted(v), 2).tolist()}")
    return {"share": _share(recs), "share_fit": _share(recs, "crb_fit"), "out": len(out)}


#: the weak-anchor scene of ``--weak-anchor-mc`` (module doc)
MC_RADIUS_MM, MC_OFFSET_MM, MC_SIGMA_MM = 137.5, 2.0, 0.008
MC_RHO_MM = (12.0, -9.0, 0.6)
MC_SEED = 100


def _mc_scene():
    from borescan.geometry import Beams
    from borescan.synthetic import scenes

    beams = Beams((1, 2, 3), np.array([0.3, 2.4, 4.3]), np.array(MC_RHO_MM), np.array([128.0, 129.0, 130.0]))
    return scenes.TriScene(
        beams=beams,
        bore_center_xy_mm=(0.0, 0.0),
        bore_radius_20_mm=MC_RADIUS_MM,
        spindle_xy_mm=(MC_OFFSET_MM, 0.0),
        sample_rate_hz=660.0,
        range_mm=(20.0, 20.0, 20.0),
    )


def _mc_bound(beams):
    """Return (u_rho, u_d_b) per channel of :func:`borescan.plan.predict` for the MC scan at ``beams``."""
    from borescan.plan import DeviceDesign, ScanDesign, predict

    scan = ScanDesign(
        offset_mm=MC_OFFSET_MM,
        revolutions=5,
        samples_per_rev=660,
        rpm=(60.0,),
        encoder=False,
        positions_known=False,
    )
    p = predict(DeviceDesign(beams, (MC_SIGMA_MM,) * 3, (20.0,) * 3), MC_RADIUS_MM, scan)
    return np.array(p.u_rho_mm), np.array(p.u_d_b_mm)


def mc_draw(seed: int) -> dict:
    """Calibrate one noise draw of the weak-anchor scene; return errors, stated u and the bound at the fit."""
    from borescan.calibrate.full_fit import fit_full_calibration
    from borescan.synthetic import scenes

    sc = _mc_scene()
    t = np.arange(3300) / 660.0
    y = scenes.tri_readings(sc, t) + MC_SIGMA_MM * np.random.default_rng(seed).standard_normal((t.size, 3))
    cal = fit_full_calibration(
        t, y, (1, 2, 3), sc.beams, MC_RADIUS_MM, rpm=60.0, range_mm=20.0, scan_ids=["MC"]
    )
    true_p = np.stack([sc.beams.beta_rad, sc.beams.rho_mm, sc.beams.d_b_mm], axis=1).ravel()
    u_rho, u_db = _mc_bound(cal.beams)
    return {
        "err": (cal.params - true_p).tolist(),
        "u": np.sqrt(np.diag(cal.cov)).tolist(),
        "rho3_mm": float(cal.beams.rho_mm[2]),
        "crb_fit_rho": u_rho.tolist(),
        "crb_fit_db": u_db.tolist(),
    }


def weak_anchor_mc(draws: int, workers: int) -> None:
    """Print the weak-anchor Monte Carlo's figures (module doc)."""
    sc = _mc_scene()
    ct_rho, ct_db = _mc_bound(sc.beams)
    d = list(map_in_order(mc_draw, range(MC_SEED, MC_SEED + draws), workers))
    err, u = np.array([x["err"] for x in d]), np.array([x["u"] for x in d])
    r3 = np.array([x["rho3_mm"] for x in d])
    print(
        f"weak-anchor scene, {draws} draws: rho_3 true {MC_RHO_MM[2]} mm, CRB {ct_rho[2]:.2f} mm, "
        f"fitted 5/50/95 % {np.percentile(r3, 5):.2f} / {np.median(r3):.2f} / {np.percentile(r3, 95):.2f} mm"
    )
    for j in (0, 1):
        for k, fam, ct, cf in (
            (3 * j + 1, "rho", ct_rho[j], np.array([x["crb_fit_rho"][j] for x in d])),
            (3 * j + 2, "d_b", ct_db[j], np.array([x["crb_fit_db"][j] for x in d])),
        ):
            e, uu = err[:, k], u[:, k]
            z, rt, rf = e / uu, uu / ct, uu / cf
            print(
                f"  channel {j + 1} {fam}: errors SD / CRB(truth) {e.std() / ct:.3f}; stated u: z SD "
                f"{z.std():.3f}, cover95 {np.mean(np.abs(z) <= 1.959964):.1%}; u / CRB(truth) 5/50/95 % "
                f"{np.percentile(rt, 5):.2f} / {np.median(rt):.2f} / {np.percentile(rt, 95):.2f}, "
                f"in [0.9, 1.2] {np.mean((rt >= 0.9) & (rt <= 1.2)):.1%}; u / CRB(fit) in [0.9, 1.2] "
                f"{np.mean((rf >= 0.9) & (rf <= 1.2)):.1%}; a u = CRB(truth) would cover "
                f"{np.mean(np.abs(e / ct) <= 1.959964):.1%}"
            )


def main(argv: list[str] | None = None) -> None:
    """Calibrate the battery and print the band's splits (options: ``--help``)."""
    from borescan.synthetic import battery

    p = argparse.ArgumentParser(
        prog="python -m bench.bench_calibration_band", description=__doc__.splitlines()[0]
    )
    p.add_argument("--n", type=int, default=200)
    p.add_argument("--seed", type=int, default=SEED)
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--battery", type=Path, default=None, help="a battery already written (same seed and n)")
    p.add_argument("--only", type=str, default=None, metavar="I,J,...")
    p.add_argument("--rows", type=Path, default=None, help="write the records here (JSON lines)")
    p.add_argument("--from-rows", type=Path, default=None, help="print the tables of records written before")
    p.add_argument(
        "--weak-anchor-mc", type=int, default=None, metavar="N", help="the weak-anchor Monte Carlo"
    )
    args = p.parse_args([] if argv is None else argv)
    if args.weak_anchor_mc is not None:
        weak_anchor_mc(args.weak_anchor_mc, args.workers or min(2, os.cpu_count() or 1))
        return
    if args.from_rows is not None:
        print_tables([json.loads(s) for s in args.from_rows.read_text().splitlines() if s.strip()])
        return
    only = [int(x) for x in args.only.split(",")] if args.only else None
    cal_cfg = default_calibration_config()
    workers = args.workers or min(2, os.cpu_count() or 1)
    with tempfile.TemporaryDirectory(prefix="band-") as tmp:
        if args.battery is not None:
            base = args.battery
            ids = json.loads((base / "battery.json").read_text())["scan_ids"]
            idx = only if only is not None else range(min(args.n, len(ids)))
            paths = [next((base / "raw").glob(f"night=*/scan={ids[i]}")) for i in idx]
        else:
            base = Path(tmp)
            paths = battery.write_battery(base, args.n, args.seed, only=only)
        jobs = [(str(q), str(base / "truth"), cal_cfg) for q in paths]
        recs = [r for rs in map_in_order(evaluate, jobs, workers) for r in rs]
    if args.rows is not None:
        args.rows.parent.mkdir(parents=True, exist_ok=True)
        args.rows.write_text("".join(json.dumps(r) + "\n" for r in recs))
    print_tables(recs)


if __name__ == "__main__":
    main(sys.argv[1:])
