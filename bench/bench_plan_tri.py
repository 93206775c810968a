"""`borescan plan` for the three-sensor device checked against the calibration contract's scans.

For each effect-free calibration scan of a contract battery (:func:`borescan.synthetic.battery.write_battery`,
the seed of ``bench_calibration_contract``) the plan is asked what it would predict for that scan as a
proposal: the device's true beams, the scan's noise and sensor ranges (:class:`borescan.plan.DeviceDesign`),
its spindle offset and direction, revolutions, samples per revolution, speed, encoder or not, positions known
or not (:class:`borescan.plan.ScanDesign`). Its predicted u of every compared quantity (beta_c or beta_c -
beta_first as the calibration reports it, rho_c, d_b_c) is compared with

- the Cramer-Rao bound of the exact model at the truth on the readings really written
  (``bench_calibration_contract.crb_cov``: the scan's own sample times, nulls, speed profile and
  censoring-free readings), always;
- with ``--rows`` (the per-scan rows of ``python -m bench.bench_calibration_contract --rows FILE``, same
  ``--n`` and ``--seed``): the calibration's stated u and its errors against the truth (z = error / u_plan);
  and each beam's mirror depth predicted by the plan against the calibration's refit from -rho where it made
  one.

Printed per family: the ratio u_plan / u_crb (and u_plan / u_fit) as 5/50/95 % percentiles and the share
within 10 % and 20 %, by scan kind (speed change or not, encoder or not, a channel out of range or not). A
proposal splits its revolutions equally over its speeds, so a scan whose speed ramps once is planned as two
equal halves at its two speeds (the ramp itself left out); the table shows what that costs.

Run: ``python -m bench.bench_plan_tri [--n 200] [--seed 20270611] [--rows rows.jsonl]``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from bench.bench_calibration_contract import SEED, _compared, crb_cov

N_SCANS = 200


def plan_of_truth(truth: dict):
    """Return (DeviceDesign, gauge radius [mm], ScanDesign) of a contract scan's truth, as a proposal."""
    from borescan.geometry import Beams
    from borescan.plan import DeviceDesign, ScanDesign

    ct = truth["contract"]
    beams = Beams.from_nominal(ct["beams"])
    c = len(beams.channels)
    device = DeviceDesign(beams, (float(ct["noise_mm"]),) * c, tuple(float(r) for r in ct["range_mm"]))
    o = np.subtract(ct["spindle_xy_mm"], ct["center_xy_mm"])
    scan = ScanDesign(
        offset_mm=float(np.hypot(*o)),
        offset_direction_rad=float(math.atan2(o[1], o[0])),
        revolutions=float(ct["n_rev"]),
        samples_per_rev=int(ct["samples_per_rev"]),
        rpm=_speeds(ct),
        direction=str(ct["direction"]),
        encoder=bool(ct["encoder"]),
        positions_known=bool(ct["position_known"]),
        position_accuracy_mm=float(ct["position_error_mm"]),
    )
    return device, float(truth["scene"]["bore_radius_20_mm"]), scan


def _speeds(ct: dict) -> tuple[float, ...]:
    """Return the scan's speeds as a proposal states them: nominal, and after a speed change the second.

    A proposal splits the revolutions equally over its speeds; the contract's speed change ramps once, at a
    time drawn about half-way through the scan, so equal revolutions is the plan's approximation.
    """
    rpm = float(ct["rpm_nominal"])
    if ct.get("speed_change") and ct.get("speed_factor"):
        return (rpm, rpm * float(ct["speed_factor"]))
    return (rpm,)


def _compared_u(cov: np.ndarray, c: int, absolute: bool) -> tuple[list[str], np.ndarray]:
    """Return (families, u) of the compared quantities from a (3c, 3c) covariance.

    beta_c (absolute) or beta_c - beta_first, then rho_c, then d_b_c (the order of the rows of
    bench_calibration_contract).
    """
    A, fam = _compared(None, None if absolute else 0, c)
    return fam, np.sqrt(np.clip(np.einsum("ij,jk,ik->i", A, cov, A), 0.0, None))


def evaluate(path: Path, truth_root: Path) -> dict:
    """Plan and bound of one scan (a row of the table)."""
    from borescan import rawio
    from borescan.plan import predict
    from borescan.synthetic import scenes, simulate

    scan = rawio.read_scan(path)
    truth = simulate.load_truth(truth_root, scan.scan_id)
    ct = truth["contract"]
    device, radius_mm, design = plan_of_truth(truth)
    plan = predict(device, radius_mm, design)
    c = len(device.beams.channels)
    absolute = plan.beta_reference == "absolute"
    fam, u_plan = _compared_u(plan.cov, c, absolute)
    mat = rawio.lds_matrix(scan)
    mask = np.isfinite(np.asarray(mat.values_mm, dtype=float))
    scene = scenes.TriScene.from_dict(truth["scene"])
    prior = design.position_accuracy_mm * math.sqrt(2.0 / 3.0) if design.positions_known else None
    crb = crb_cov(
        scene,
        np.asarray(mat.t_s, dtype=float),
        mask,
        float(ct["noise_mm"]),
        free_beta=[absolute or j > 0 for j in range(c)],
        free_phase=(not design.encoder) and design.positions_known,
        free_scale=not design.encoder,
        prior_sigma_mm=prior,
    )
    rho_var = np.diag(crb)[1::3]
    crb[np.arange(2, 3 * c, 3), np.arange(2, 3 * c, 3)] += 3.0 * rho_var**2 / (4.0 * radius_mm**2)
    _, u_crb = _compared_u(crb, c, absolute)
    return {
        "scan_id": scan.scan_id,
        "families": fam,
        "u_plan": u_plan.tolist(),
        "u_crb_truth": u_crb.tolist(),
        "mirror_depth_plan": list(plan.mirror_depth),
        "mirror_possible_plan": list(plan.mirror_possible),
        "speed_change": bool(ct["speed_change"]),
        "encoder": bool(ct["encoder"]),
        "out_of_range": ct["out_of_range"] is not None,
        "beta_reference": plan.beta_reference,
    }


def _ratio_line(label: str, r: np.ndarray) -> str:
    r = r[np.isfinite(r)]
    if r.size == 0:
        return f"  {label:<40} -"
    p5, p50, p95 = np.percentile(r, [5, 50, 95])
    w10 = np.mean(np.abs(r - 1.0) <= 0.10) * 100
    w20 = np.mean(np.abs(r - 1.0) <= 0.20) * 100
    return f"  {label:<40} {r.size:5d}  {p5:6.3f} {p50:6.3f} {p95:6.3f}   {w10:5.1f} % {w20:5.1f} %"


def fit_values(r: dict, fr: dict | None) -> list[tuple[str, float, float, float, bool]]:
    """(family, u_plan, u_fit, error, sign determined) of each compared quantity of an accepted calibration.

    Empty where the calibration was refused or holds another beta than the plan (its gauge differs).
    """
    from bench.calibration_contract_tables import _channel_of_row, fixed_channel

    if not fr or not fr.get("accepted") or fr.get("families") != r["families"]:
        return []
    mirror = fr.get("mirror") or []
    c = len(fr.get("rho_true_mm", []))
    channels = [int(m["channel"]) for m in mirror] if len(mirror) == c else list(range(1, c + 1))
    f = fixed_channel(fr["beta_reference"], channels)
    if f != (None if r["beta_reference"] == "absolute" else 0):
        return []
    out = []
    for k, fam in enumerate(r["families"]):
        j = _channel_of_row(k, r["families"], c, f)
        det = bool(mirror[j].get("sign_determined", True)) if j < len(mirror) else True
        if fam == "beta" and f is not None and f < len(mirror):
            det = det and bool(mirror[f].get("sign_determined", True))
        out.append((fam, r["u_plan"][k], fr["u"][k], fr["err"][k], det))
    return out


KINDS = {
    "all": lambda r: True,
    "one speed": lambda r: not r["speed_change"],
    "speed change": lambda r: r["speed_change"],
    "encoder": lambda r: r["encoder"],
    "no encoder": lambda r: not r["encoder"],
    "a channel out of range": lambda r: r["out_of_range"],
}


def print_table(rows: list[dict], fit_rows: dict[str, dict]) -> dict:
    """Print the comparison; return the pooled ratio arrays (for tests and docs)."""
    out: dict = {}
    print(f"{len(rows)} scans planned; ratios: n, 5 / 50 / 95 % percentiles, share within 10 % / 20 %")
    print("u_plan / CRB at the truth (the readings written, nulls and out-of-range readings left out)")
    for kname, want in KINDS.items():
        for fam in ("beta", "rho", "d_b"):
            vals = [
                p / d
                for r in rows
                if want(r)
                for p, d, f in zip(r["u_plan"], r["u_crb_truth"], r["families"])
                if f == fam and d > 0
            ]
            arr = np.asarray(vals, dtype=float)
            print(_ratio_line(f"{kname}: {fam}", arr))
            out[("crb", kname, fam)] = arr
    if fit_rows:
        out.update(print_fit_table(rows, fit_rows))
    return out


def print_fit_table(rows: list[dict], fit_rows: dict[str, dict]) -> dict:  # noqa: C901 (one block a figure)
    """Print the plan against the calibrations (their stated u, errors, mirror refits); return the arrays."""
    out: dict = {}
    print("u_plan / the calibration's u (beams whose sign the scan determines; all beams)")
    for kname, want in KINDS.items():
        for fam in ("beta", "rho", "d_b"):
            det, every = [], []
            for r in rows:
                if want(r):
                    for fm, up, uf, _, d in fit_values(r, fit_rows.get(r["scan_id"])):
                        if fm == fam and uf > 0:
                            every.append(up / uf)
                            if d:
                                det.append(up / uf)
            print(_ratio_line(f"{kname}: {fam}, sign determined", np.asarray(det)))
            if kname == "all":
                print(_ratio_line(f"{kname}: {fam}, every beam", np.asarray(every)))
            out[("fit", kname, fam)] = np.asarray(det)
    for label, keep in (("sign determined", True), ("every beam", False)):
        z = np.asarray(
            [
                e / up
                for r in rows
                for _, up, _, e, d in fit_values(r, fit_rows.get(r["scan_id"]))
                if up > 0 and (d or not keep)
            ]
        )
        out[("z", label)] = z
        print(
            f"errors of the calibrations over the plan's u, {label}: z SD {np.std(z):.3f}, "
            f"95 % coverage {np.mean(np.abs(z) <= 1.96) * 100:.1f} % ({z.size} values)"
        )
    dm = []
    for r in rows:
        for k, m in enumerate((fit_rows.get(r["scan_id"]) or {}).get("mirror", [])):
            ref_d = m.get("refit_delta_chi2")
            if ref_d is not None and r["mirror_possible_plan"][k] and np.isfinite(ref_d) and ref_d > 0:
                dm.append(r["mirror_depth_plan"][k] / ref_d)
    print(_ratio_line("mirror depth: plan / the refit from -rho", np.asarray(dm, dtype=float)))
    out["mirror"] = np.asarray(dm)
    return out


def run(n: int, seed: int, battery_dir: Path | None) -> list[dict]:
    """Write the battery (or reuse ``battery_dir``) and plan every scan."""
    from borescan.synthetic import battery

    with tempfile.TemporaryDirectory(prefix="bench_plan_tri_") as tmp:
        base = battery_dir or Path(tmp)
        paths = battery.write_battery(base, n, seed)
        rows = []
        for i, p in enumerate(paths):
            rows.append(evaluate(p, base / "truth"))
            if (i + 1) % 25 == 0:
                print(f"  {i + 1}/{len(paths)} planned", flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    """Plan the battery's scans and print the comparison (options: ``--help``)."""
    p = argparse.ArgumentParser(prog="python -m bench.bench_plan_tri", description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=N_SCANS, help=f"scans (default {N_SCANS})")
    p.add_argument("--seed", type=int, default=SEED, help=f"battery seed (default {SEED})")
    p.add_argument("--battery", type=Path, default=None, help="keep (or reuse) the battery here")
    p.add_argument("--rows", type=Path, default=None, help="bench_calibration_contract's rows (JSON lines)")
    args = p.parse_args([] if argv is None else argv)
    fit_rows = {}
    if args.rows is not None:
        for line in args.rows.read_text().splitlines():
            r = json.loads(line)
            fit_rows[r["scan_id"]] = r
    rows = run(args.n, args.seed, args.battery)
    figs = print_table(rows, fit_rows)
    pooled = np.concatenate([figs[("crb", "all", f)] for f in ("beta", "rho", "d_b")])
    # exit 1 when the plan is off the bound for more than a tenth of the quantities by more than 20 %
    return 0 if pooled.size and np.mean(np.abs(pooled - 1.0) <= 0.20) >= 0.9 else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
