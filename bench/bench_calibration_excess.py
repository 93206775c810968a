"""Where a contract scan's calibration error beyond its Cramer-Rao bound comes from (issue 36).

For each chosen scan of the contract battery (:mod:`bench.bench_calibration_contract`, same seed) the
scan is calibrated by the pipeline's path and compared with its truth, then four figures are printed:

- **model vs twin**: the calibration's forward model (the scan's own angle model, encoder spline or rpm
  profile with the phase and speed scale that best match the simulator's angle, the gauge radius the
  calibration uses) at the TRUE beams and offset, minus the simulator's noise-free readings, in noise
  sigmas (rms, max). Zero means the fit and the simulator describe the same scan.
- **SSR_t - SSR_f + P_t - P_f**: how much better the fit explains the readings than the truth does,
  prior on the offset included (sigma^2 units; about chi2 with p dof for an efficient fit), and
  **q**, the errors' quadratic form in the stated covariance of the compared quantities (the bench's
  beta differences, rho, d_b). q above the SSR difference means a curved valley (the linear
  covariance does not describe the way from the fit to the truth), not a model mismatch.
- **common rho^2 mode**: d(rho_j^2) = rho_fit^2 - rho_true^2 per channel, their correlation in the
  stated covariance, and their generalised-least-squares common value delta with its u: when the
  channels' rho^2 errors are one shared shift (correlation near 1, rest chi2 ~ c - 1 dof) a single
  excursion of delta puts every channel's beta, rho and d_b at the same number of standard errors.
- **profile**: for the channel whose rho has the largest |z|, the profile chi2 (SSR + prior minimised
  over every other parameter, on the readings the censoring guard keeps) at the true rho, against
  z^2 of the stated u: equal means the stated u is the data's own curvature and the truth is that far
  from what the data say.

Run: ``python -m bench.bench_calibration_excess --n 40 --only 8,12,17,28,33 [--workers 2]`` (or
``python -m bench calibration_excess``).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.bench_calibration_contract import (
    SEED,
    _compared,
    default_calibration_config,
    evaluate_scan_with_calibration,
)
from bench.calibration_contract_tables import fixed_channel

from borescan.parallel import map_in_order

#: several minutes (a full calibration and a profile per scan): runs only when named
RUN_BY_DEFAULT = False
#: the scans of the 40-scan battery whose errors were 2-3 Cramer-Rao standard errors on every channel
WORST_OF_40 = "8,12,17,28,33"


@dataclass(frozen=True)
class ScanExcess:
    """The four figures of one scan (module doc)."""

    scan_id: str
    angle_source: str
    n_params: int
    twin_rms_sigma: float
    twin_max_sigma: float
    ssr_gain_sigma2: float
    q_stated: float
    n_compared: int
    z_max: float
    rho2_corr_min: float
    delta_rho2_mm2: float
    u_delta_rho2_mm2: float
    rho2_rest_chi2: float
    profile_channel: int
    profile_z: float
    profile_dchi2_at_truth: float


@dataclass(frozen=True)
class _Fit:
    """One scan's readings and the calibration's forward model over its full parameter vector."""

    y: np.ndarray
    mask: np.ndarray
    sigma_mm: float
    x_fit: np.ndarray
    x_true: np.ndarray
    held: tuple[int, ...]
    o_reported: np.ndarray | None
    prior_sigma_mm: float
    offset_at: int  # index of o_x in the parameter vector (3 c)
    model: Callable[[np.ndarray], np.ndarray]  # parameters -> readings (n, c)

    def residuals(self, x: np.ndarray, mask: np.ndarray) -> np.ndarray:
        r = (self.y[mask] - self.model(x)[mask]) / self.sigma_mm
        if self.o_reported is None:
            return r
        o = x[self.offset_at : self.offset_at + 2]
        return np.concatenate([r, (o - self.o_reported) / self.prior_sigma_mm])


def _fit_of(scan, truth: dict, cal, cal_cfg: dict) -> _Fit:
    """Return the calibration's model of ``scan`` and its fitted and true parameter vectors."""
    from borescan import kinematics, rawio
    from borescan.artifacts import gauge_radius_mm
    from borescan.geometry import Beams, Bore, tri_spindle_readings
    from borescan.synthetic import scenes

    ct = truth["contract"]
    scene = scenes.TriScene.from_dict(truth["scene"])
    mat = rawio.lds_matrix(scan)
    t = np.asarray(mat.t_s, dtype=float)
    y = np.asarray(mat.values_mm, dtype=float)
    am = kinematics.angle_model_of_scan(scan.meta, scan.spindle)
    enc = am.source == "encoder"
    big_phi = am.commanded_rad(t)
    radius = gauge_radius_mm(scan.meta)
    ch = scene.beams.channels
    c = len(ch)

    def model(x):
        b = x[: 3 * c].reshape(c, 3)
        phi = big_phi if enc else x[3 * c + 2] + x[3 * c + 3] * big_phi
        beams = Beams(ch, b[:, 0], b[:, 1], b[:, 2])
        return tri_spindle_readings(phi, x[3 * c : 3 * c + 2], beams, Bore((0.0, 0.0), radius))

    tb = scene.beams
    o_true = np.subtract(scene.spindle_xy_mm, scene.bore_center_xy_mm)
    x_true = np.concatenate([np.stack([tb.beta_rad, tb.rho_mm, tb.d_b_mm], 1).ravel(), o_true])
    nu = cal.nuisance[scan.scan_id]
    x_fit = np.concatenate([cal.params, [nu["offset_x_mm"], nu["offset_y_mm"]]])
    if not enc:  # the simulator's angle as phase + scale * Phi (exact for an effect-free scan)
        a = np.stack([np.ones_like(big_phi), big_phi], 1)
        coef = np.linalg.lstsq(a, scenes.tri_phi(scene, t), rcond=None)[0]
        x_true = np.concatenate([x_true, coef])
        phase = coef[0] + (nu["phase0_rad"] - coef[0] + math.pi) % (2 * math.pi) - math.pi
        x_fit = np.concatenate([x_fit, [phase, nu["speed_scale"]]])
    for j in range(c):  # the fit's betas on the truth's branch of 2 pi
        x_fit[3 * j] = x_true[3 * j] + (x_fit[3 * j] - x_true[3 * j] + math.pi) % (2 * math.pi) - math.pi
    f = fixed_channel(cal.diagnostics.get("beta_reference", "absolute"), cal.beams.channels)
    o_rep = None
    if ct["position_known"]:
        o_rep = np.subtract(ct["spindle_reported_xy_mm"], ct["center_reported_xy_mm"])
    return _Fit(
        y=y,
        mask=np.isfinite(y),
        sigma_mm=float(ct["noise_mm"]),
        x_fit=x_fit,
        x_true=x_true,
        held=() if f is None else (3 * f,),
        o_reported=o_rep,
        prior_sigma_mm=float(cal_cfg["position_accuracy_mm"]) * math.sqrt(2.0 / 3.0),
        offset_at=3 * c,
        model=model,
    )


def _profile_dchi2(fit: _Fit, k: int, rho_mm: float, keep: np.ndarray) -> float:
    """Profile chi2 of rho_k at ``rho_mm`` above the free minimum, both started at the fit."""
    from scipy.optimize import least_squares

    def minimum(held: tuple[int, ...], x0: np.ndarray) -> float:
        free = [i for i in range(len(x0)) if i not in held]

        def rr(z):
            x = x0.copy()
            x[free] = z
            return fit.residuals(x, keep)

        sol = least_squares(rr, x0[free], method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12)
        return 2.0 * float(sol.cost)

    x0 = fit.x_fit.copy()
    x0[3 * k + 1] = rho_mm
    return minimum(fit.held + (3 * k + 1,), x0) - minimum(fit.held, fit.x_fit.copy())


def diagnose(job: tuple) -> ScanExcess:
    """Calibrate one scan of the battery and return its :class:`ScanExcess`."""
    from borescan import rawio
    from borescan.calibrate.censoring import censoring_keep
    from borescan.synthetic import scenes, simulate

    path, truth_root, cal_cfg = job
    row, cal = evaluate_scan_with_calibration(job)
    if cal is None:
        raise RuntimeError(f"{row['scan_id']}: refused ({row['reason']}), nothing to diagnose")
    scan = rawio.read_scan(Path(path))
    truth = simulate.load_truth(truth_root, scan.scan_id)
    fit = _fit_of(scan, truth, cal, cal_cfg)
    c = len(cal.beams.channels)
    v_true = fit.model(fit.x_true)
    twin = scenes.tri_readings(
        scenes.TriScene.from_dict(truth["scene"]), np.asarray(rawio.lds_matrix(scan).t_s)
    )
    d = (v_true - twin)[fit.mask] / fit.sigma_mm
    ssr = [float(np.sum(fit.residuals(x, fit.mask) ** 2)) for x in (fit.x_true, fit.x_fit)]
    a, _ = _compared(cal.params, fixed_channel(row["beta_reference"], cal.beams.channels), c)
    err = np.asarray(row["err"])
    cov_c = a @ cal.cov @ a.T
    z = err / np.sqrt(np.diag(cov_c))
    # the channels' rho^2 errors and their common part
    rho_t, rho_f = fit.x_true[1 : 3 * c : 3], np.asarray(cal.beams.rho_mm)
    g = np.zeros((c, 3 * c))
    g[np.arange(c), 3 * np.arange(c) + 1] = 2.0 * rho_t
    cq = g @ cal.cov @ g.T
    s = np.sqrt(np.diag(cq))
    w = np.linalg.inv(cq)
    one = np.ones(c)
    u_delta = 1.0 / math.sqrt(one @ w @ one)
    d2 = rho_f**2 - rho_t**2
    delta = float(one @ w @ d2) * u_delta**2
    rest = d2 - delta
    # the profile of the rho with the largest |z|, on the readings the censoring guard keeps
    u_rho = np.sqrt(np.diag(cal.cov)[1::3])
    k = int(np.argmax(np.abs(rho_f - rho_t) / u_rho))
    keep, _ = censoring_keep(
        fit.model(fit.x_fit), fit.y, np.asarray(truth["scene"]["range_mm"]), np.full(c, fit.sigma_mm)
    )
    return ScanExcess(
        scan_id=scan.scan_id,
        angle_source=row["angle_source"],
        n_params=len(fit.x_fit) - len(fit.held),
        twin_rms_sigma=float(np.sqrt(np.mean(d**2))),
        twin_max_sigma=float(np.max(np.abs(d))),
        ssr_gain_sigma2=ssr[0] - ssr[1],
        q_stated=float(err @ np.linalg.solve(cov_c, err)),
        n_compared=len(err),
        z_max=float(np.max(np.abs(z))),
        rho2_corr_min=float(np.min((cq / np.outer(s, s))[np.triu_indices(c, 1)])),
        delta_rho2_mm2=delta,
        u_delta_rho2_mm2=u_delta,
        rho2_rest_chi2=float(rest @ w @ rest),
        profile_channel=int(cal.beams.channels[k]),
        profile_z=float((rho_f[k] - rho_t[k]) / u_rho[k]),
        profile_dchi2_at_truth=_profile_dchi2(fit, k, float(rho_t[k]), fit.mask & keep),
    )


def print_rows(rows: list[ScanExcess]) -> None:
    """One line per scan (module doc)."""
    print(
        "scan              angle    p  twin rms/max [sigma]  SSR_t-SSR_f+dP  q (m)       max|z|"
        "  rho^2 corr  delta rho^2 [mm^2] (z)  rest chi2  profile: ch  z^2    dchi2"
    )
    for r in rows:
        print(
            f"{r.scan_id}  {r.angle_source:7s} {r.n_params:2d}"
            f"  {r.twin_rms_sigma:8.1e} {r.twin_max_sigma:8.1e}"
            f"  {r.ssr_gain_sigma2:12.1f}  {r.q_stated:6.1f} ({r.n_compared})  {r.z_max:6.2f}"
            f"  {r.rho2_corr_min:10.3f}  {r.delta_rho2_mm2:7.2f} +- {r.u_delta_rho2_mm2:5.2f}"
            f" ({r.delta_rho2_mm2 / r.u_delta_rho2_mm2:5.2f})  {r.rho2_rest_chi2:9.1f}"
            f"  {r.profile_channel:11d}  {r.profile_z**2:5.2f}  {r.profile_dchi2_at_truth:6.2f}"
        )


def main(argv: list[str] | None = None) -> None:
    """Write the chosen scans of the battery, diagnose each, print the table (options: ``--help``)."""
    from borescan.synthetic import battery

    p = argparse.ArgumentParser(
        prog="python -m bench.bench_calibration_excess", description=__doc__.splitlines()[0]
    )
    p.add_argument("--n", type=int, default=40, help="battery size the indices refer to (default 40)")
    p.add_argument("--seed", type=int, default=SEED, help=f"battery seed (default {SEED})")
    p.add_argument(
        "--only",
        type=str,
        default=WORST_OF_40,
        metavar="I,J,...",
        help=f"scan indices (default {WORST_OF_40})",
    )
    p.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    args = p.parse_args([] if argv is None else argv)
    cal_cfg = default_calibration_config()
    with tempfile.TemporaryDirectory(prefix="excess-") as tmp:
        paths = battery.write_battery(
            Path(tmp), args.n, args.seed, only=[int(x) for x in args.only.split(",")]
        )
        jobs = [(str(q), str(Path(tmp) / "truth"), cal_cfg) for q in paths]
        print_rows(list(map_in_order(diagnose, jobs, args.workers)))


if __name__ == "__main__":
    main(sys.argv[1:])
