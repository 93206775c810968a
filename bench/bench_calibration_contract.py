"""Three-sensor calibration over the whole contract: >= 200 effect-free scans of borescan.synthetic.

Every scan of a fixed-seed contract battery (:func:`borescan.synthetic.battery.write_battery`, written to a
temporary folder) is calibrated by the pipeline's own path,
``borescan.stages.calibration_fit.calibrate_raw_scans([rawio.read_scan(path)], cfg["calibration"])`` with the
validated default config (config/config.yaml, schema defaults filled in). Printed, against the
acceptance of the issue "A battery over the whole contract":

- scans, accepted, refused (with the reasons);
- per parameter family (beta, rho, d_b) the z-scores (estimate - truth) / u: SD and max |z|;
  the pooled SD; the coverage of the 95 % intervals (|z| <= 1.96). Where the calibration holds
  the first channel's beta (``diagnostics["beta_reference"] == "channel <c> fixed"``) the
  compared quantity is beta_c - beta_<c> (its variance from ``cov``); with ``"absolute"`` beta itself;
- u / CRB, the Cramer-Rao bound sigma^2 (J^T J + prior)^-1 of the exact model at the truth (for d_b
  plus the second-order term 3 CRB(rho)^4 / (4 R^2) of d_b = g - rho^2 / (2R), R the gauge radius at the
  scan's temperature: the mean square error of d_b from an efficient (g, rho), which the CRB of d_b alone
  understates where rho is weak and no estimator reaches there; J by
  central differences of :func:`borescan.synthetic.scenes.tri_readings` over the beams and the
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
from pathlib import Path

import numpy as np

from bench.calibration_contract_tables import fixed_channel, print_table

from borescan.parallel import map_in_order

N_SCANS = 200
SEED = 20270611
ROOT = Path(__file__).resolve().parents[1]


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
    differences of :func:`borescan.synthetic.scenes.tri_readings` (d_b analytically: -1) on the samples
    ``mask`` (n, c); information J^T J / sigma^2 plus 1 / prior_sigma^2 on o when given.
    Gauge-fixed betas get zero rows/columns.
    """
    from dataclasses import replace

    from borescan.effects import Effect
    from borescan.geometry import Beams
    from borescan.synthetic.scenes import tri_readings

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


def crb_compared(scene, scan, cal, ct: dict, A: np.ndarray, families: list[str]) -> np.ndarray:
    """Return the Cramer-Rao u of the compared quantities ``A`` at the point ``scene``, in ``cal``'s gauge.

    :func:`crb_cov` on the readings written, the nuisance the calibration frees (phase where it frees it,
    the speed scale without an encoder), the prior on o the scenario draws; for d_b plus the second-order
    term 3 CRB(rho)^4 / (4 R^2) of d_b = g - rho^2 / (2R) (module doc). ``scene`` is the truth for the
    bench's bound; :mod:`bench.bench_calibration_band` passes the fit's beams to get the bound at the fit.
    """
    from borescan import rawio
    from borescan.artifacts import gauge_radius_mm

    c = len(scene.beams.channels)
    f = fixed_channel(cal.diagnostics.get("beta_reference", "absolute"), cal.beams.channels)
    mat = rawio.lds_matrix(scan)
    t_s = np.asarray(mat.t_s, dtype=float)
    mask = np.isfinite(np.asarray(mat.values_mm, dtype=float))
    nu = cal.nuisance.get(scan.scan_id, {})
    encoder = ct["angle_source"] == "encoder"
    prior = ct["position_error_mm"] * math.sqrt(2.0 / 3.0) if ct["position_known"] else None
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
    var_crb = np.einsum("ij,jk,ik->i", A, crb, A)
    # d_b = g - rho^2 / (2R) from an efficient (g, rho): its mean square error carries the second-order
    # term 3 u(rho)^4 / (4 R^2) (rho_hat^2 has mean rho^2 + u^2 and variance 4 rho^2 u^2 + 2 u^4), which
    # no estimator of d_b avoids where rho is weak (at rho = 0 the CRB of d_b is u(g)'s)
    rho_var = np.diag(crb)[1::3]
    R = gauge_radius_mm(scan.meta)
    for k, fm in enumerate(families):
        if fm == "d_b":
            j = int(np.argmax(A[k, 2::3]))
            var_crb[k] += 3.0 * rho_var[j] ** 2 / (4.0 * R**2)
    return np.sqrt(np.clip(var_crb, 0.0, None))


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
    return evaluate_scan_with_calibration(job)[0]


def evaluate_scan_with_calibration(job: tuple):  # noqa: C901 (one block per figure of the row)
    """Return the row of :func:`evaluate_scan` and the calibration it compared (None when refused)."""
    path, truth_root, cal_cfg = job
    from borescan import rawio
    from borescan.calibrate.result import CalibrationError
    from borescan.synthetic import scenes, simulate
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
        return row, None
    except Exception as e:  # noqa: BLE001 - a crash is a refusal of another kind; the table says which
        row.update(accepted=False, reason=f"{type(e).__name__}: {e}", seconds=time.perf_counter() - t0)
        return row, None
    row["seconds"] = time.perf_counter() - t0
    row["accepted"] = True
    scene = scenes.TriScene.from_dict(truth["scene"])
    c = len(scene.beams.channels)
    tb = scene.beams
    true_p = np.stack([tb.beta_rad, tb.rho_mm, tb.d_b_mm], axis=1).ravel()
    est_p = cal.params
    ref = cal.diagnostics.get("beta_reference", "absolute")
    f = fixed_channel(ref, cal.beams.channels)
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
            # the certificate's rule (borescan.mirror): a mirror possible at the fit and its depth < 25
            "sign_determined": bool(checks[ch].sign_determined) if ch in checks else True,
            "formula_at_fit": bool(
                ch in checks and checks[ch].mirror_possible and checks[ch].predicted_delta_chi2 < 25.0
            ),
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
    try:
        row["u_crb"] = crb_compared(scene, scan, cal, ct, A, fam).tolist()
    except np.linalg.LinAlgError as e:
        row["u_crb"] = None
        row["crb_error"] = str(e)
    # wrong-minimum check over every reading written
    R = gauge_radius_mm(scan.meta)
    v_true = scenes.tri_readings(scene, t_s)
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
    return row, cal


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
    from borescan.synthetic import battery

    workers = workers or min(2, os.cpu_count() or 1)
    cal_cfg = default_calibration_config()
    with tempfile.TemporaryDirectory(prefix="contract-") as tmp:
        base = Path(out_dir) if out_dir else Path(tmp)
        t0 = time.perf_counter()
        paths = battery.write_battery(base, n, seed, only=only)
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
