"""Three-sensor calibration over the whole contract: >= 200 effect-free scans of borescan.scenarios.

Every scan of a fixed-seed contract battery (:func:`borescan.scenarios.write_battery`, written to a
temporary folder) is calibrated by the pipeline's own path,
``borescan.stages.calibration_fit.calibrate_raw_scans([rawio.read_scan(path)], cfg["calibration"])`` with the
validated default config (config/config.yaml, schema defaults filled in). Printed, against the
acceptance of the issue "A battery over the whole contract":

- scans, accepted, refused (with the reasons);
- per parameter family (beta, rho, d_b) the z-scores (estimate - truth) / u: SD and max |z|;
  the pooled SD; the coverage of the 95 % intervals (|z| <= 1.96). Where the calibration holds
  the first channel's beta (``diagnostics["beta_reference"] == "channel <c> fixed"``) the
  compared quantity is beta_c - beta_<c> (its variance from ``cov``); with ``"absolute"`` beta itself;
- u / CRB, the Cramer-Rao bound sigma^2 (J^T J + prior)^-1 of the exact model at the truth (J by
  central differences of :func:`borescan.simulate.tri_readings` over the beams and the
  nuisance the angle source implies: offset o = S - C always, the phase where the calibration
  frees it, the speed scale without an encoder; beta gauge as the calibration's), on the
  readings that were written (not null). The prior on o where scan.json gives the positions:
  the spread the scenarios actually draw (centre and spindle each uniform within +-e per
  coordinate, so o per coordinate has sigma = e sqrt(2/3));
- the wrong-minimum check: SSR of the accepted fit (its own beams and nuisance, over every
  reading written) <= SSR at the truth (``simulate.tri_readings(scene, t)``) + sigma^2 sqrt(2 N),
  the noise's expected spread of the SSR (the issue's test); and a sharp one, in sigma^2 units:
  the global minimum of SSR + prior penalty P can exceed the truth's SSR only by the truth's own
  prior penalty, so SSR_fit - SSR_truth <= sigma^2 (P_truth + 3), P_truth = |o_true - o_reported|^2 /
  (a sqrt(2/3))^2 with a = ``position_accuracy_mm`` of the config (0 without positions). The spread
  sigma^2 sqrt(2 N) is hundreds of sigma^2 for these scans: it cannot see a wrong minimum whose
  SSR is a few tens of sigma^2 above the truth's, while the sharp check does.

Run: ``python -m bench.bench_calibration_contract [--n 200] [--seed 20270611] [--workers 2]``
(or ``python -m bench contract``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from borescan.parallel import map_in_order

N_SCANS = 200
SEED = 20270611
ROOT = Path(__file__).resolve().parents[1]
FAMILIES = ("beta", "rho", "d_b")


def default_calibration_config() -> dict:
    """Return the config's ``calibration`` section validated against the schema.

    ``calibration`` section of config/config.yaml validated against the workflow schema (defaults
    filled).
    """
    import yaml
    from snakemake.utils import validate

    cfg = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    validate(cfg, str(ROOT / "workflow" / "schemas" / "config.schema.yaml"), set_default=True)
    return cfg["calibration"]


def _wrap(a):
    return (np.asarray(a, dtype=float) + np.pi) % (2 * np.pi) - np.pi


def _fixed_channel(beta_reference: str, channels) -> int | None:
    """Index of the beta held fixed (``"channel <c> fixed"``), None for ``"absolute"``."""
    if beta_reference == "absolute":
        return None
    parts = str(beta_reference).split()
    if len(parts) >= 2 and parts[0] == "channel":
        return list(channels).index(int(parts[1]))
    raise ValueError(f"unknown beta_reference {beta_reference!r}")


def _compared(params: np.ndarray, f: int | None, c: int):
    """Rows of the linear map from (3c,) per-channel (beta, rho, d_b) to the compared quantities.

    Returns (A (m, 3c), families (m,)); beta rows are beta_c (absolute) or beta_c - beta_f.
    """
    rows, fam = [], []
    for j in range(c):
        if f is not None and j == f:
            continue
        a = np.zeros(3 * c)
        a[3 * j] = 1.0
        if f is not None:
            a[3 * f] = -1.0
        rows.append(a)
        fam.append("beta")
    for k, name in ((1, "rho"), (2, "d_b")):
        for j in range(c):
            a = np.zeros(3 * c)
            a[3 * j + k] = 1.0
            rows.append(a)
            fam.append(name)
    return np.array(rows), fam


def crb_cov(  # noqa: C901 (one block per parameter kind of the CRB's Jacobian)
    scene,
    t_s: np.ndarray,
    mask: np.ndarray,
    sigma_mm: float,
    *,
    free_beta: list[bool],
    free_phase: bool,
    free_scale: bool,
    prior_sigma_mm: float | None,
) -> np.ndarray:
    """Cramer-Rao covariance (3c, 3c) of (beta, rho, d_b) per channel at the truth ``scene``.

    Parameters (in this order, the fixed ones left out): beta_c (where ``free_beta``), rho_c,
    d_b_c, o = S - C (2), phase (``free_phase``), speed scale (``free_scale``). J by central
    differences of :func:`borescan.simulate.tri_readings` (d_b analytically: -1) on the samples
    ``mask`` (n, c); information J^T J / sigma^2 plus 1 / prior_sigma^2 on o when given.
    Gauge-fixed betas get zero rows/columns.
    """
    from dataclasses import replace

    from borescan.effects import Effect
    from borescan.geometry import Beams
    from borescan.simulate import tri_readings

    c = len(scene.beams.channels)
    C = np.asarray(scene.bore_center_xy_mm, float)
    S = np.asarray(scene.spindle_xy_mm, float)
    base = replace(scene, bore_center_xy_mm=(0.0, 0.0), spindle_xy_mm=tuple(S - C))

    def model(beta, rho, o, phase, scale):
        sc = replace(
            base,
            beams=Beams(scene.beams.channels, beta, rho, scene.beams.d_b_mm),
            spindle_xy_mm=(float(o[0]), float(o[1])),
            phase_rad=float(phase),
        )
        eff = [] if scale == 1.0 else [Effect("speed_error", {"eps": scale - 1.0})]
        return tri_readings(sc, t_s, eff)[mask]

    b0, r0 = scene.beams.beta_rad.copy(), scene.beams.rho_mm.copy()
    o0, ph0 = S - C, float(scene.phase_rad)
    cols, names = [], []

    def central(fn, h):
        return (fn(h) - fn(-h)) / (2 * h)

    for j in range(c):
        if free_beta[j]:
            cols.append(central(lambda h, j=j: model(b0 + h * np.eye(c)[j], r0, o0, ph0, 1.0), 1e-6))
            names.append(("beta", j))
    for j in range(c):
        cols.append(central(lambda h, j=j: model(b0, r0 + h * np.eye(c)[j], o0, ph0, 1.0), 1e-5))
        names.append(("rho", j))
    chan = np.nonzero(mask)[1]
    for j in range(c):
        cols.append(-(chan == j).astype(float))
        names.append(("d_b", j))
    for k in range(2):
        cols.append(central(lambda h, k=k: model(b0, r0, o0 + h * np.eye(2)[k], ph0, 1.0), 1e-5))
        names.append(("o", k))
    if free_phase:
        cols.append(central(lambda h: model(b0, r0, o0, ph0 + h, 1.0), 1e-6))
        names.append(("phase", 0))
    if free_scale:
        cols.append(central(lambda h: model(b0, r0, o0, ph0, 1.0 + h), 1e-8))
        names.append(("scale", 0))
    J = np.stack(cols, axis=1)
    info = J.T @ J / sigma_mm**2
    if prior_sigma_mm is not None:
        for i, nm in enumerate(names):
            if nm[0] == "o":
                info[i, i] += 1.0 / prior_sigma_mm**2
    cov_free = np.linalg.inv(info)
    out = np.zeros((3 * c, 3 * c))
    pos = {"beta": 0, "rho": 1, "d_b": 2}
    idx = [(i, 3 * nm[1] + pos[nm[0]]) for i, nm in enumerate(names) if nm[0] in pos]
    fi, ci = zip(*idx)
    out[np.ix_(ci, ci)] = cov_free[np.ix_(fi, fi)]
    return out


def fitted_readings(cal, scan, t_s: np.ndarray, R_mm: float) -> np.ndarray:
    """Return the readings (n, c) of the accepted fit.

    Return readings (n, c) of the accepted fit: its beams, offset, and angle (encoder, or phase + scale
    Phi).
    """
    from borescan import kinematics
    from borescan.geometry import Bore, tri_spindle_readings

    nu = cal.nuisance[scan.scan_id]
    sp, sm = scan.spindle, scan.meta.get("spindle") or {}
    am = kinematics.angle_model_from_arrays(
        rpm_nominal=sm.get("rpm_nominal"),
        direction=sm.get("direction", "ccw"),
        spindle_t_s=sp["t_ns"].to_numpy() * 1e-9,
        spindle_angle_rad=sp["angle_rad"].to_numpy().astype(float),
        spindle_rpm=sp["rpm"].to_numpy().astype(float),
    )
    if am.source == "encoder":
        phi = am.phi_rad(t_s)
    else:
        phi = am.phi_rad(t_s, phase_rad=float(nu["phase0_rad"]), speed_scale=float(nu["speed_scale"]))
    o = np.array([nu["offset_x_mm"], nu["offset_y_mm"]], dtype=float)
    return tri_spindle_readings(phi, o, cal.beams, Bore((0.0, 0.0), R_mm))


def evaluate_scan(job: tuple) -> dict:
    """Calibrate one scan and compare with its truth (the row the table is made of)."""
    path, truth_root, cal_cfg = job
    from borescan import rawio, simulate
    from borescan.calibrate.result import CalibrationError
    from borescan.artifacts import gauge_radius_mm
    from borescan.stages.calibration_fit import calibrate_raw_scans

    scan = rawio.read_scan(Path(path))
    truth = simulate.load_truth(truth_root, scan.scan_id)
    ct = truth["contract"]
    row = {
        "scan_id": scan.scan_id,
        "angle_source": ct["angle_source"],
        "position_known": ct["position_known"],
        "speed_change": ct["speed_change"],
        "out_of_range": ct["out_of_range"] is not None,
        "n_rev": ct["n_rev"],
        "noise_mm": ct["noise_mm"],
    }
    t0 = time.perf_counter()
    try:
        cal = calibrate_raw_scans([scan], cal_cfg)
    except CalibrationError as e:
        row.update(accepted=False, reason=e.problem, seconds=time.perf_counter() - t0)
        return row
    except Exception as e:  # noqa: BLE001 - a crash is a refusal of another kind; the table says which
        row.update(accepted=False, reason=f"{type(e).__name__}: {e}", seconds=time.perf_counter() - t0)
        return row
    row["seconds"] = time.perf_counter() - t0
    row["accepted"] = True
    scene = simulate.TriScene.from_dict(truth["scene"])
    c = len(scene.beams.channels)
    tb = scene.beams
    true_p = np.stack([tb.beta_rad, tb.rho_mm, tb.d_b_mm], axis=1).ravel()
    est_p = cal.params
    ref = cal.diagnostics.get("beta_reference", "absolute")
    f = _fixed_channel(ref, cal.beams.channels)
    A, fam = _compared(est_p, f, c)
    err = A @ est_p - A @ true_p
    is_beta = np.array([x == "beta" for x in fam])
    err[is_beta] = _wrap(err[is_beta])
    u = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", A, cal.cov, A), 0.0, None))
    row.update(
        beta_reference=ref,
        families=fam,
        err=err.tolist(),
        u=u.tolist(),
        rho_true_mm=tb.rho_mm.tolist(),
        weak_rho=list(cal.diagnostics.get("weak_rho_channels", [])),
        residual_to_noise=float(cal.residual_rms_mm / ct["noise_mm"]),
    )
    # the mirror check of each beam (issue 36): resolved or flagged, its delta chi^2, the stated probability
    # of the wrong sign, whether the kept sign is the truth's; and Eq. (1) at the truth (|rho| > sqrt(2) e)
    from borescan.mirror import mirror_checks_of, mirror_exists, predicted_depth

    checks = {m.channel: m for m in mirror_checks_of(cal.diagnostics)}
    e_true = float(np.hypot(*np.subtract(ct["spindle_xy_mm"], ct["center_xy_mm"])))
    n_ch = np.isfinite(np.asarray(rawio.lds_matrix(scan).values_mm, dtype=float)).sum(axis=0)
    row["mirror"] = [
        {
            "channel": int(ch),
            "resolved": bool(checks[ch].resolved) if ch in checks else True,
            "refit_delta_chi2": checks[ch].refit_delta_chi2 if ch in checks else None,
            "p_wrong_sign": float(checks[ch].p_wrong_sign) if ch in checks else 0.0,
            "sign_right": bool(np.sign(cal.beams.rho_mm[j]) == np.sign(tb.rho_mm[j])),
            "formula_flagged": bool(
                mirror_exists(float(tb.rho_mm[j]), e_true)
                and predicted_depth(
                    [int(n_ch[j])],
                    [e_true],
                    float(tb.rho_mm[j]),
                    [ct["noise_mm"]],
                    float(scene.bore_radius_20_mm),
                )
                < 25.0
            ),
        }
        for j, ch in enumerate(cal.beams.channels)
    ]
    # Cramer-Rao bound in the calibration's gauge
    mat = rawio.lds_matrix(scan)
    t_s = np.asarray(mat.t_s, dtype=float)
    y = np.asarray(mat.values_mm, dtype=float)
    mask = np.isfinite(y)
    nu = cal.nuisance.get(scan.scan_id, {})
    encoder = ct["angle_source"] == "encoder"
    prior = ct["position_error_mm"] * math.sqrt(2.0 / 3.0) if ct["position_known"] else None
    try:
        crb = crb_cov(
            scene,
            t_s,
            mask,
            ct["noise_mm"],
            free_beta=[f is None or j != f for j in range(c)],
            free_phase=bool(nu.get("phase_free", (not encoder) and ct["position_known"])),
            free_scale=not encoder,
            prior_sigma_mm=prior,
        )
        row["u_crb"] = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", A, crb, A), 0.0, None)).tolist()
    except np.linalg.LinAlgError as e:
        row["u_crb"] = None
        row["crb_error"] = str(e)
    # wrong-minimum check over every reading written
    R = gauge_radius_mm(scan.meta)
    v_true = simulate.tri_readings(scene, t_s)
    ssr_true = float(np.sum((y - v_true)[mask] ** 2))
    try:
        v_fit = fitted_readings(cal, scan, t_s, R)
        ssr_fit = float(np.sum((y - v_fit)[mask] ** 2))
    except (KeyError, ValueError) as e:
        ssr_fit = float("nan")
        row["ssr_error"] = str(e)
    spread = ct["noise_mm"] ** 2 * math.sqrt(2.0 * mask.sum())
    p_true = 0.0
    if ct["position_known"]:
        o_rep = np.subtract(ct["spindle_reported_xy_mm"], ct["center_reported_xy_mm"])
        o_true = np.subtract(ct["spindle_xy_mm"], ct["center_xy_mm"])
        # the calibration's prior on o: +-a on the centre and on the spindle position, u = a sqrt(2/3)
        p_true = float(
            np.sum((o_true - o_rep) ** 2)
            / (float(cal_cfg["position_accuracy_mm"]) * math.sqrt(2.0 / 3.0)) ** 2
        )
    row.update(
        ssr_fit=ssr_fit,
        ssr_true=ssr_true,
        ssr_spread=spread,
        n_obs=int(mask.sum()),
        ssr_excess_sigma2=(ssr_fit - ssr_true) / ct["noise_mm"] ** 2,
        prior_penalty_true=p_true,
    )
    return row


def run(
    n: int = N_SCANS,
    seed: int = SEED,
    workers: int | None = None,
    out_dir: Path | None = None,
    only: list[int] | None = None,
) -> list[dict]:
    """Write the battery and calibrate every scan; return per-scan rows.

    Write the battery (temp folder unless ``out_dir``; only the scan indices ``only`` if given),
    calibrate every scan; per-scan rows.
    """
    from borescan import scenarios

    workers = workers or min(2, os.cpu_count() or 1)
    cal_cfg = default_calibration_config()
    with tempfile.TemporaryDirectory(prefix="contract-") as tmp:
        base = Path(out_dir) if out_dir else Path(tmp)
        t0 = time.perf_counter()
        paths = scenarios.write_battery(base, n, seed, only=only)
        n = len(paths)
        print(f"battery: {n} scans, seed {seed}, written in {time.perf_counter() - t0:.1f} s", flush=True)
        jobs = [(str(p), str(base / "truth"), cal_cfg) for p in paths]
        t0 = time.perf_counter()
        rows: list[dict] = []
        for i, row in enumerate(map_in_order(evaluate_scan, jobs, workers)):  # one BLAS thread per worker
            rows.append(row)
            if (i + 1) % 25 == 0:
                print(f"  {i + 1}/{n} calibrated ({time.perf_counter() - t0:.0f} s)", flush=True)
        print(f"calibrated in {time.perf_counter() - t0:.1f} s with {workers} worker(s)", flush=True)
    return rows


def summarize(rows: list[dict]) -> dict:
    """Return the acceptance figures of the rows (see the module doc); also printed by :func:`print_table`."""
    acc = [r for r in rows if r["accepted"]]
    out = {
        "scans": len(rows),
        "accepted": len(acc),
        "refused": len(rows) - len(acc),
        "reasons": Counter(r["reason"].split(";")[0][:160] for r in rows if not r["accepted"]),
    }
    z_all = []
    for fam in FAMILIES:
        z, ratio = [], []
        for r in acc:
            for k, fm in enumerate(r["families"]):
                if fm != fam:
                    continue
                if r["u"][k] > 0:
                    z.append(r["err"][k] / r["u"][k])
                if r.get("u_crb") and r["u_crb"][k] > 0:
                    ratio.append(r["u"][k] / r["u_crb"][k])
        z = np.array(z)
        z_all.append(z)
        out[fam] = {
            "n": z.size,
            "sd": float(np.std(z)) if z.size else float("nan"),
            "mean": float(np.mean(z)) if z.size else float("nan"),
            "max_abs": float(np.max(np.abs(z))) if z.size else float("nan"),
            "cover95": float(np.mean(np.abs(z) <= 1.959964)) if z.size else float("nan"),
            "n_over4": int(np.sum(np.abs(z) > 4.0)),
            "u_crb_max": float(np.max(ratio)) if ratio else float("nan"),
            "u_crb_median": float(np.median(ratio)) if ratio else float("nan"),
            "u_crb_min": float(np.min(ratio)) if ratio else float("nan"),
        }
    z = np.concatenate(z_all) if z_all else np.zeros(0)
    out["pooled"] = {
        "n": z.size,
        "sd": float(np.std(z)) if z.size else float("nan"),
        "cover95": float(np.mean(np.abs(z) <= 1.959964)) if z.size else float("nan"),
        "max_abs": float(np.max(np.abs(z))) if z.size else float("nan"),
    }
    excess = np.array(
        [(r["ssr_fit"] - r["ssr_true"]) / r["ssr_spread"] for r in acc if np.isfinite(r["ssr_fit"])]
    )
    sharp = [
        (r["ssr_excess_sigma2"], r["prior_penalty_true"] + 3.0, r["scan_id"])
        for r in acc
        if np.isfinite(r["ssr_fit"])
    ]
    out["wrong_minimum"] = {
        "checked": int(excess.size),
        "failed": int(np.sum(excess > 1.0)),
        "max_excess_in_spreads": float(excess.max()) if excess.size else float("nan"),
        "sharp_failed": sorted(sid for ex, lim, sid in sharp if ex > lim),
        "max_excess_sigma2": float(max(ex for ex, _, _ in sharp)) if sharp else float("nan"),
    }
    out["seconds"] = {
        "total": float(sum(r["seconds"] for r in rows)),
        "max": float(max(r["seconds"] for r in rows)) if rows else float("nan"),
    }
    return out


def _channel_of_row(k: int, families: list[str], c: int, f: int | None) -> int:
    """Channel index of row k of :func:`_compared` (betas of the non-fixed channels, rhos, d_bs)."""
    nb = sum(1 for x in families if x == "beta")
    if k < nb:
        return k + (1 if f is not None and k >= f else 0)
    return (k - nb) % c


def mirror_summary(rows: list[dict]) -> dict:
    """Return issue 36's figures for the resolved and the flagged beams.

    Resolved beams' z (SD, 95 % coverage, u / CRB in [0.9, 1.2]), the flagged count against Eq. (1)'s at the
    truth, and among flagged beams the observed wrong-sign rate against the stated probabilities (their mean).
    """
    z, ratio, e_crb, n_beams, n_flag, n_formula, p_stated, wrong, sign_err_resolved = (
        [],
        [],
        [],
        0,
        0,
        0,
        [],
        [],
        0,
    )
    for r in rows:
        if not r.get("accepted") or "mirror" not in r:
            continue
        fam, c = r["families"], len(r["mirror"])
        f = _fixed_channel(r["beta_reference"], [m["channel"] for m in r["mirror"]])
        flagged = {j for j, m in enumerate(r["mirror"]) if not m["resolved"]}
        for j, m in enumerate(r["mirror"]):
            n_beams += 1
            n_formula += int(m["formula_flagged"])
            k_rho = sum(1 for x in fam if x == "beta") + j
            u_crb_rho = (r.get("u_crb") or [0.0] * len(fam))[k_rho]
            if m["resolved"]:  # a gross error only where the sign means something: |rho| > 2 CRB
                sign_err_resolved += int(not m["sign_right"] and abs(r["rho_true_mm"][j]) > 2.0 * u_crb_rho)
            else:
                n_flag += 1
                p_stated.append(m["p_wrong_sign"])
                wrong.append(0.0 if m["sign_right"] else 1.0)
        for k in range(len(fam)):
            j = _channel_of_row(k, fam, c, f)
            if j in flagged or (fam[k] == "beta" and f is not None and f in flagged) or r["u"][k] <= 0:
                continue
            z.append(r["err"][k] / r["u"][k])
            if r.get("u_crb") and r["u_crb"][k] > 0:
                ratio.append(r["u"][k] / r["u_crb"][k])
                e_crb.append(r["err"][k] / r["u_crb"][k])
    z, ratio, e_crb = np.array(z), np.array(ratio), np.array(e_crb)
    return {
        "beams": n_beams,
        "flagged": n_flag,
        "formula_flagged": n_formula,
        "resolved_z_sd": float(np.std(z)) if z.size else float("nan"),
        "resolved_cover95": float(np.mean(np.abs(z) <= 1.959964)) if z.size else float("nan"),
        "resolved_u_crb_in_0.9_1.2": float(np.mean((ratio >= 0.9) & (ratio <= 1.2)))
        if ratio.size
        else float("nan"),
        "resolved_sign_errors": sign_err_resolved,
        "resolved_err_over_crb_rms": float(np.sqrt(np.mean(e_crb**2))) if e_crb.size else float("nan"),
        "flagged_wrong_sign_observed": float(np.mean(wrong)) if wrong else float("nan"),
        "flagged_wrong_sign_stated": float(np.mean(p_stated)) if p_stated else float("nan"),
    }


def _subset(rows, **want):
    return [r for r in rows if all(r.get(k) == v for k, v in want.items())]


def print_table(  # noqa: C901 (one line per table of the bench's printout)
    rows: list[dict],
) -> dict:
    """Print the acceptance table of the rows; return :func:`summarize` of them."""
    s = summarize(rows)
    print(f"scans {s['scans']}   accepted {s['accepted']}   refused {s['refused']}")
    for reason, k in s["reasons"].most_common():
        print(f"  refused x{k}: {reason}")
    print(
        f"{'family':8s} {'n':>5s} {'z mean':>7s} {'z SD':>6s} {'max|z|':>7s} {'|z|>4':>6s} {'cover95':>8s} "
        f"{'u/CRB med':>10s} {'u/CRB max':>10s}"
    )
    for fam in FAMILIES + ("pooled",):
        d = s[fam]
        extra = (
            (
                f"{d['mean']:7.2f} {d['sd']:6.3f} {d['max_abs']:7.2f} {d['n_over4']:6d} {d['cover95']:8.1%} "
                f"{d['u_crb_median']:10.3f} {d['u_crb_max']:10.3f}"
            )
            if fam != "pooled"
            else f"{'':7s} {d['sd']:6.3f} {d['max_abs']:7.2f} {'':6s} {d['cover95']:8.1%}"
        )
        print(f"{fam:8s} {d['n']:5d} {extra}")
    w = s["wrong_minimum"]
    print(
        f"wrong-minimum check: {w['failed']} of {w['checked']} fits with SSR_fit > SSR_truth + sigma^2 "
        "sqrt(2N); "
        f"largest (SSR_fit - SSR_truth) = {w['max_excess_in_spreads']:+.3f} spreads"
    )
    print(
        f"sharp check: {len(w['sharp_failed'])} fits with SSR_fit - SSR_truth > sigma^2 (P_truth + 3) "
        f"{w['sharp_failed'][:10]}; largest SSR_fit - SSR_truth = {w['max_excess_sigma2']:+.1f} sigma^2"
    )
    # rho is seen only through terms of order |o|^2 / R: where the bound itself exceeds |rho| / 2
    # the data cannot tell rho's sign, a calibration's linearised u does not hold there
    acc = [r for r in rows if r["accepted"]]
    ss = summarize([r for r in acc if not r.get("weak_rho")])
    print(
        f"without scans the calibration flags weak rho ({len(acc) - ss['accepted']} flagged): pooled z SD "
        f"{ss['pooled']['sd']:.3f}, max |z| {ss['pooled']['max_abs']:.2f}, cover95 "
        f"{ss['pooled']['cover95']:.1%}"
    )
    amb = []
    for r in acc:
        if not r.get("u_crb"):
            continue
        k_rho = [k for k, fm in enumerate(r["families"]) if fm == "rho"]
        if any(r["u_crb"][k] > abs(rt) / 2 for k, rt in zip(k_rho, r["rho_true_mm"])):
            amb.append(r)
    ss = summarize([r for r in acc if r not in amb])
    print(
        "scans where the truth's CRB of some rho exceeds |rho| / 2 (sign not fixed by the data): "
        f"{len(amb)}; "
        f"without them: pooled z SD {ss['pooled']['sd']:.3f}, max |z| {ss['pooled']['max_abs']:.2f}, "
        f"cover95 {ss['pooled']['cover95']:.1%}"
    )
    # where the z-scores come from: by angle source and position knowledge
    print("by case (scans accepted/total, pooled z SD, beta z SD, beta u/CRB max):")
    for src in ("encoder", "profile"):
        for known in (True, False):
            sub = _subset(rows, angle_source=src, position_known=known)
            if not sub:
                continue
            ss = summarize(sub)
            print(
                f"  {src:8s} positions {'known  ' if known else 'unknown'}: "
                f"{ss['accepted']:3d}/{ss['scans']:3d}  "
                f"pooled SD {ss['pooled']['sd']:.3f}  beta SD {ss['beta']['sd']:.3f}  "
                f"beta u/CRB max {ss['beta']['u_crb_max']:.3f}  rho u/CRB max {ss['rho']['u_crb_max']:.3f}"
            )
    for label, key in (("speed change", "speed_change"), ("out of range", "out_of_range")):
        ss = summarize(_subset(rows, **{key: True}))
        print(
            f"  {label:12s}: {ss['accepted']:3d}/{ss['scans']:3d}  pooled SD {ss['pooled']['sd']:.3f}  "
            f"cover95 {ss['pooled']['cover95']:.1%}"
        )
    worst = sorted(
        (r for r in rows if r["accepted"]),
        key=lambda r: -max(abs(e / u) if u > 0 else 0 for e, u in zip(r["err"], r["u"])),
    )[:3]
    for r in worst:
        zz = [e / u if u > 0 else float("nan") for e, u in zip(r["err"], r["u"])]
        print(
            f"  largest |z|: {r['scan_id']} ({r['angle_source']}, positions "
            f"{'known' if r['position_known'] else 'unknown'}, "
            f"{r['beta_reference']}, weak rho {r['weak_rho']}): z = {np.round(zz, 2).tolist()}"
        )
    ms = mirror_summary(rows)
    print(
        f"mirror check (issue 36): {ms['flagged']} of {ms['beams']} beams flagged (Eq. (1) at the truth: "
        f"{ms['formula_flagged']}); resolved beams: z SD {ms['resolved_z_sd']:.3f}, cover95 "
        f"{ms['resolved_cover95']:.1%}, u/CRB in [0.9, 1.2] "
        f"{ms['resolved_u_crb_in_0.9_1.2']:.1%}, errors/CRB rms "
        f"{ms['resolved_err_over_crb_rms']:.3f}, sign errors where |rho| > 2 CRB "
        f"{ms['resolved_sign_errors']}; flagged beams: wrong "
        f"sign kept {ms['flagged_wrong_sign_observed']:.3f} "
        f"observed vs {ms['flagged_wrong_sign_stated']:.3f} stated"
    )
    print(
        f"calibration time: {s['seconds']['total']:.0f} s summed "
        f"over scans, slowest {s['seconds']['max']:.1f} s"
    )
    return s


def main(argv: list[str] | None = None) -> None:
    """Draw the battery, calibrate it and print the contract's table (options: ``--help``)."""
    p = argparse.ArgumentParser(
        prog="python -m bench.bench_calibration_contract", description=__doc__.splitlines()[0]
    )
    p.add_argument("--n", type=int, default=N_SCANS, help=f"scans (default {N_SCANS})")
    p.add_argument("--seed", type=int, default=SEED, help=f"battery seed (default {SEED})")
    p.add_argument("--workers", type=int, default=None, help="processes (default min(2, cpus))")
    p.add_argument("--out", type=Path, default=None, help="keep the battery here instead of a temp folder")
    p.add_argument(
        "--only",
        type=str,
        default=None,
        metavar="I,J,...",
        help="calibrate only these scan indices of the battery (re-examine a few)",
    )
    p.add_argument("--rows", type=Path, default=None, help="write the per-scan rows here (JSON lines)")
    args = p.parse_args([] if argv is None else argv)
    if args.n < 1:
        p.error("--n must be >= 1")
    only = [int(x) for x in args.only.split(",")] if args.only else None
    rows = run(args.n, args.seed, args.workers, args.out, only=only)
    if args.rows is not None:
        args.rows.parent.mkdir(parents=True, exist_ok=True)
        with args.rows.open("w") as fh:
            for r in rows:
                fh.write(json.dumps(r, default=float) + "\n")
    print_table(rows)


if __name__ == "__main__":
    main(sys.argv[1:])
