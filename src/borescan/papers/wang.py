"""Reproduction of Wang et al. 2017 (coaxial-hole measuring rod) by simulation.

- Eq. 7: manufacturing error dl = sqrt((l cos gamma)^2 + d^2) - l for d = 0.5 mm,
  gamma = 0.5 deg, l ~ r < 80 mm (paper: < 1.5 um), and the same from the exact forward model
  (``geometry.rod_readings``, centred rod: the reading error is l - r).
- Eq. 15: sqrt(20^2 + 10.2^2 + 1.5^2 + 10^2 + 3^2) against the printed 24.8 um.
- Fig. 9: radius error of the front hole vs eccentricity (0-3 mm) and deflection (0-1.5 deg),
  d = 0.5 mm, gamma = 0.5 deg, 500 mm rod, two 150 mm holes (paper: < 10 um). Two versions:
  the paper's procedure (spot trajectory, least-squares plane, rotation into the xy plane,
  Delta_r = sqrt(Delta_round^2 + Delta_flat^2), Eq. 14) and the error of the Eq. 16 circle
  actually fitted to the readings (angles known), i.e. the bias of the joint solve.
- Fig. 11: diameter error vs number of rotations 6-30 with 20 um linearity sensors (uniform
  +-20 um), Monte Carlo with ``rod.solve_rod`` (paper: settles near 28 um after ~18).

How many Fig. 11 trials (:data:`FIG11_TRIALS`, :data:`FIG11_ROTATIONS`): the figure's conclusions
are (a) from about 16 rotations on the RMS diameter error follows 2 x the Cramer-Rao bound, (b) the
95th percentile there is near the paper's ~28 um, (c) below about 12 rotations the solve is
unstable (heavy tails, refusals). Each n gives M = 2 N errors (two holes). The relative standard
error of an RMS from M normal errors is 1 / sqrt(2 M), of a 95th percentile
sqrt(0.95 * 0.05 / M) / (1.645 phi(1.645)) = 1.18 / sqrt(M): with N = 80, 5.6 % and 9.3 % (the
earlier N = 200: 3.5 % and 5.9 % at 2.5x the solves per n). The errors have heavier tails than
normal (an occasional poor solve), so the spread was also measured: at n = 18, N = 40 gave a
95th percentile of 37.9 um for one seed (outside (b)), N = 80 gave RMS / 2 CRB 0.97-1.19 and 95th
percentiles 23-30 um over seeds 10-13 (tests/test_wang.py checks one). (c) rests on refusals and
maxima of hundreds of um at n <= 10, far beyond the sampling error. The maximum grows with N (an
extreme value): the largest of the N trials. Six rotation counts (6, 10, 14, 18, 24, 30) keep the
curve's shape where it bends: 480 solves instead of 2 600.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from borescan.circlefit import fit_circle_ls
from borescan.geometry import Hole, RodAxis, RodLayer, rod_axis_rotation, rod_readings
from borescan.rod import RodSolveError, solve_rod

__all__ = [
    "eq7_manufacturing_error_um",
    "eq7_simulated_error_um",
    "eq15_total_um",
    "fig9_radius_error_um",
    "fig11_error_vs_rotations",
    "reproduce",
    "write_reproduction",
]

R_HOLE_MM = 75.0
H_HOLES_MM = (150.0, 450.0)  # two holes on the 500 mm rod; 450 mm is the front hole
L0_MM = 71.0
SIGMA_LIN_MM = 0.02 / np.sqrt(3.0)  # 20 um linearity as a uniform +-20 um error
#: Monte Carlo trials per rotation count of Fig. 11 and the rotation counts (module docstring: why)
FIG11_TRIALS = 80
FIG11_ROTATIONS = (6, 10, 14, 18, 24, 30)


def eq7_manufacturing_error_um(l_mm, d_mm=0.5, gamma_rad=np.deg2rad(0.5)):
    """Wang 2017 Eq. 7: dl = sqrt((l cos gamma)^2 + d^2) - l [um]."""
    l = np.asarray(l_mm, dtype=float)
    return (np.sqrt((l * np.cos(gamma_rad)) ** 2 + d_mm**2) - l) * 1e3


def eq7_simulated_error_um(r_mm, d_mm=0.5, gamma_rad=np.deg2rad(0.5)):
    """Return the reading error [um] of a centred rod with beam offset and tilt.

    Return reading error of a centred rod with beam offset d and tilt gamma (exact forward model):
    (l0 + v) - r, where the nominal model reads l = r [um]; to first order equal to -Eq. 7.
    """
    r = np.atleast_1d(np.asarray(r_mm, dtype=float))
    out = np.empty_like(r)
    for i, rr in enumerate(r):
        lay = RodLayer(1, 100.0, 0.0, d_mm=d_mm, gamma_rad=gamma_rad)
        out[i] = rod_readings(np.array([0.3]), [lay], [Hole((0.0, 0.0), rr)])[0, 0] - rr
    return out * 1e3


def eq15_total_um(sen=20.0, tr=10.2, dl=1.5, dr=10.0, hole=3.0) -> float:
    """Wang 2017 Eq. 15: sqrt(D_sen^2 + D_TR^2 + dl^2 + dr^2 + D_Hole^2) [um]."""
    return float(np.sqrt(sen**2 + tr**2 + dl**2 + dr**2 + hole**2))


def _spots(alpha, lay: RodLayer, hole: Hole, axis: RodAxis) -> np.ndarray:
    """Laser spots in the part frame (exact ray-cylinder), (n, 3)."""
    v = rod_readings(alpha, [lay], [hole], axis)[:, 0]
    l = lay.l0_mm + v
    a = alpha + lay.phi_rad
    u = np.stack([np.cos(a), np.sin(a), 0 * a], -1)
    nvec = np.stack([-np.sin(a), np.cos(a), 0 * a], -1)
    spot = (
        lay.d_mm * nvec
        + (l * np.cos(lay.gamma_rad))[:, None] * u
        + (lay.h_mm + l * np.sin(lay.gamma_rad))[:, None] * np.array([0, 0, 1.0])
    )
    return spot @ rod_axis_rotation(axis).T + np.array([axis.dx_mm, axis.dy_mm, 0.0])


def fig9_radius_error_um(
    ecc_mm,
    omega_rad,
    *,
    d_mm=0.5,
    gamma_rad=np.deg2rad(0.5),
    h_mm=H_HOLES_MM[1],
    ecc_az_rad=0.0,
    omega_az_rad=np.pi / 2,
    n_alpha=360,
) -> dict[str, float]:
    """Radius error of one hole for eccentricity ``ecc_mm`` and deflection ``omega_rad``.

    Returns
    -------
    dict: paper_um (Eq. 14 procedure), round_um, flat_um, model_um (LS circle of l u(alpha),
    Eq. 16 with the angles known: what the joint solve converges to), ellipse_um (closed form
    r (1/cos omega - 1) / 2 of a circle fitted to the tilted cross-section).
    """
    alpha = np.linspace(0, 2 * np.pi, n_alpha, endpoint=False)
    lay = RodLayer(1, h_mm, L0_MM, d_mm=d_mm, gamma_rad=gamma_rad)
    hole = Hole((0.0, 0.0), R_HOLE_MM)
    axis = RodAxis(ecc_mm * np.cos(ecc_az_rad), ecc_mm * np.sin(ecc_az_rad), omega_rad, omega_az_rad)
    P = _spots(alpha, lay, hole, axis)
    c = P.mean(axis=0)
    _, _, Vt = np.linalg.svd(P - c)
    nrm = Vt[2] * np.sign(Vt[2, 2])
    # Rodrigues rotation taking the LS plane normal onto z (axis = plane ∩ xy direction)
    k = np.cross(nrm, [0, 0, 1.0])
    s, cth = np.linalg.norm(k), nrm[2]
    if s > 0:
        k = k / s
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        Rr = np.eye(3) + s * K + (1 - cth) * K @ K
    else:
        Rr = np.eye(3)
    Q = (P - c) @ Rr.T
    flat = float(np.ptp(Q[:, 2]))
    fit = fit_circle_ls(Q[:, 0], Q[:, 1])
    rnd = float(abs(fit.radius_mm - R_HOLE_MM))
    v = rod_readings(alpha, [lay], [hole], axis)[:, 0]
    l = L0_MM + v
    mfit = fit_circle_ls(l * np.cos(alpha), l * np.sin(alpha))
    return {
        "paper_um": float(np.hypot(rnd, flat) * 1e3),
        "round_um": rnd * 1e3,
        "flat_um": flat * 1e3,
        "model_um": float((mfit.radius_mm - R_HOLE_MM) * 1e3),
        "ellipse_um": float(R_HOLE_MM * (1 / np.cos(omega_rad) - 1) / 2 * 1e3),
    }


def _fig11_scene():
    layers = [RodLayer(1, H_HOLES_MM[0], L0_MM), RodLayer(2, H_HOLES_MM[1], L0_MM)]
    holes = [Hole((0.0, 0.0), R_HOLE_MM), Hole((0.01, -0.02), R_HOLE_MM + 0.012)]
    # rod ends within 2.5 mm of the centreline (paper 3.4), axis skew to the holes' axis
    axis = RodAxis(1.0, 0.5, np.deg2rad(0.2), np.deg2rad(120.0))
    return layers, holes, axis


def fig11_error_vs_rotations(
    n_rot=FIG11_ROTATIONS, n_trials: int = FIG11_TRIALS, seed: int = 0, progress=None
) -> dict[str, np.ndarray]:
    """Monte Carlo diameter error of ``solve_rod`` vs number of rod rotations (poses).

    Poses at uniformly random angles, readings + uniform +-20 um. Returns per n: rms_um, p95_um,
    max_um of |D - D_true| over both holes, crb_um = 2 * mean CRB of r (Gaussian sigma = 11.5 um),
    refused (fraction of scans the solver refused as degenerate). ``progress(text)``, when given,
    is called after each rotation count.
    """
    layers, holes, axis = _fig11_scene()
    r_true = np.array([h.radius_mm for h in holes])
    rng = np.random.default_rng(seed)
    out = {k: [] for k in ("n", "rms_um", "p95_um", "max_um", "crb_um", "refused")}
    for n in n_rot:
        errs, crbs, refused = [], [], 0
        for _ in range(n_trials):
            alpha = rng.uniform(0, 2 * np.pi, n)
            v0 = rod_readings(alpha, layers, holes, axis)
            v = v0 + rng.uniform(-0.02, 0.02, v0.shape)
            try:
                sol = solve_rod(
                    v, [L0_MM, L0_MM], u_reading_mm=SIGMA_LIN_MM, deflection="none"
                )  # the paper's Eq. 16
            except RodSolveError:
                refused += 1
                continue
            errs.append(2 * (sol.radius_mm - r_true))
            crbs.append(2 * np.mean(sol.u_radius_mm))
        e = np.abs(np.array(errs)).ravel() * 1e3
        out["n"].append(n)
        out["rms_um"].append(float(np.sqrt(np.mean(e**2))))
        out["p95_um"].append(float(np.percentile(e, 95)))
        out["max_um"].append(float(e.max()))
        out["crb_um"].append(float(np.mean(crbs) * 1e3))
        out["refused"].append(refused / n_trials)
        if progress is not None:
            progress(
                f"Wang Fig. 11: {n} rotations, {n_trials} trials, RMS {out['rms_um'][-1]:.1f} um "
                f"({len(out['n'])} of {len(n_rot)} rotation counts)"
            )
    return {k: np.array(v) for k, v in out.items()}


def reproduce(fig9_steps: int = 7, fig11_trials: int = FIG11_TRIALS, progress=None) -> dict:
    """All reproductions with their printed counterparts (see module docstring)."""
    from scipy.optimize import brentq

    l = np.linspace(20.0, 80.0, 61)
    eq7 = eq7_manufacturing_error_um(l)
    crossing = float(brentq(lambda x: eq7_manufacturing_error_um(x) - 1.5, 20.0, 60.0))
    eq7_sim = eq7_simulated_error_um(np.array([75.0, 80.0]))
    eccs = np.linspace(0.0, 3.0, fig9_steps)
    omegas = np.deg2rad(np.linspace(0.0, 1.5, fig9_steps))
    grid = {
        k: np.empty((eccs.size, omegas.size))
        for k in ("paper_um", "round_um", "flat_um", "model_um", "ellipse_um")
    }
    for i, e in enumerate(eccs):
        for j, w in enumerate(omegas):
            res = fig9_radius_error_um(e, w)
            for k in grid:
                grid[k][i, j] = res[k]
    f11 = fig11_error_vs_rotations(n_trials=fig11_trials, progress=progress)
    return {
        "eq7": {
            "l_mm": l,
            "dl_um": eq7,
            "max_abs_70_80_um": float(np.max(np.abs(eq7_manufacturing_error_um(np.linspace(70, 80, 11))))),
            "exceeds_1_5_below_mm": crossing,
            "at_80_um": float(eq7_manufacturing_error_um(80.0)),
            "printed_bound_um": 1.5,
            "simulated_r75_um": float(eq7_sim[0]),
            "simulated_r80_um": float(eq7_sim[1]),
            "at_10_um": float(eq7_manufacturing_error_um(10.0)),
        },
        "eq15": {"computed_um": eq15_total_um(), "printed_um": 24.8},
        "fig9": {"ecc_mm": eccs, "omega_deg": np.rad2deg(omegas), **grid, "printed_bound_um": 10.0},
        "fig11": {**f11, "printed_settled_um": 28.0, "printed_settle_n": 18},
    }


def write_reproduction(out_dir, fig11_trials: int = FIG11_TRIALS, progress=None) -> dict[str, Path]:
    """Write ``wang_*.csv`` and ``wang.png`` (all panels beside the paper's statements)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rep = reproduce(fig11_trials=fig11_trials, progress=progress)
    paths = {}
    p = out / "wang_statements.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["item", "paper", "reproduced", "note"])
        e7, e15, f9, f11 = rep["eq7"], rep["eq15"], rep["fig9"], rep["fig11"]
        w.writerow(
            [
                "Eq. 7 |dl| for l < 80 mm (d 0.5 mm, gamma 0.5 deg)",
                "< 1.5 um",
                f"{e7['max_abs_70_80_um']:.3f} um for 70 <= l <= 80 mm; exceeds 1.5 um for l < "
                f"{e7['exceeds_1_5_below_mm']:.1f} mm",
                f"dl(80) = {e7['at_80_um']:.3f} um; exact forward model r=75: "
                f"{e7['simulated_r75_um']:+.3f} um, "
                f"r=80: {e7['simulated_r80_um']:+.3f} um; dl(10 mm) = {e7['at_10_um']:+.2f} um",
            ]
        )
        w.writerow(
            ["Eq. 15 total", "24.8 um", f"{e15['computed_um']:.3f} um", "sqrt(20^2+10.2^2+1.5^2+10^2+3^2)"]
        )
        w.writerow(
            [
                "Fig. 9 max radius error, ecc <= 3 mm, omega <= 1.5 deg",
                "< 10 um",
                f"paper procedure {np.max(f9['paper_um']):.2f} um; Eq. 16 fit "
                f"{np.max(np.abs(f9['model_um'])):.2f} um",
                "front hole h = 450 mm, ecc along x, deflection towards y",
            ]
        )
        i18 = list(f11["n"]).index(18) if 18 in list(f11["n"]) else -1
        w.writerow(
            [
                "Fig. 11 diameter error after >= 18 rotations",
                "~28 um",
                f"RMS {f11['rms_um'][i18]:.1f} um, 95% {f11['p95_um'][i18]:.1f} "
                f"um, max {f11['max_um'][i18]:.1f} um at n = {f11['n'][i18]}",
                f"sensor noise only (uniform +-20 um); paper includes run-out, install and hole form; "
                f"{fig11_trials} trials per n (RMS to about "
                f"{100 / np.sqrt(4 * fig11_trials):.0f} %, 95% to about "
                f"{118 / np.sqrt(2 * fig11_trials):.0f} %)",
            ]
        )
    paths["statements"] = p
    p = out / "wang_fig9.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["ecc_mm", "omega_deg", "paper_um", "round_um", "flat_um", "model_um", "ellipse_um"])
        for i, e in enumerate(f9["ecc_mm"]):
            for j, om in enumerate(f9["omega_deg"]):
                w.writerow(
                    [f"{e:.3f}", f"{om:.3f}"]
                    + [
                        f"{f9[k][i, j]:.4f}"
                        for k in ("paper_um", "round_um", "flat_um", "model_um", "ellipse_um")
                    ]
                )
    paths["fig9"] = p
    p = out / "wang_fig11.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["n_rotations", "rms_um", "p95_um", "max_um", "crb_um", "refused_fraction"])
        for k in range(len(f11["n"])):
            w.writerow(
                [int(f11["n"][k])]
                + [f"{f11[c][k]:.3f}" for c in ("rms_um", "p95_um", "max_um", "crb_um", "refused")]
            )
    paths["fig11"] = p
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.3))
    a = ax[0]
    a.plot(e7["l_mm"], e7["dl_um"], label="Eq. 7, d = 0.5 mm, gamma = 0.5 deg")
    a.set_ylim(-3, 15)
    a.axhline(-1.5, ls="--", color="r", label="paper: |dl| < 1.5 um")
    a.axhline(1.5, ls="--", color="r")
    a.set_xlabel("l [mm]")
    a.set_ylabel("dl [um]")
    a.set_title(f"Eq. 7 (Eq. 15 total: {e15['computed_um']:.2f} vs printed 24.8 um)")
    a.legend(fontsize=7)
    a = ax[1]
    for j, om in enumerate(f9["omega_deg"]):
        a.plot(f9["ecc_mm"], f9["paper_um"][:, j], "o-", ms=3, label=f"omega {om:.2f} deg (paper proc.)")
    a.plot(f9["ecc_mm"], np.abs(f9["model_um"][:, -1]), "k--", label="Eq. 16 fit bias, omega 1.5 deg")
    a.axhline(10, color="r", ls=":", label="paper: < 10 um")
    a.set_xlabel("eccentricity [mm]")
    a.set_ylabel("radius error [um]")
    a.set_title("Fig. 9: front hole, 500 mm rod")
    top = float(np.nanmax(f9["paper_um"]))
    a.set_ylim(-0.5, 1.75 * top)  # head room for the legend above the curves
    a.legend(fontsize=6, ncol=2, loc="upper left")
    a = ax[2]
    a.plot(f11["n"], f11["rms_um"], "o-", label="RMS |D error|")
    a.plot(f11["n"], f11["p95_um"], "s-", label="95th percentile")
    a.plot(f11["n"], f11["crb_um"], "k--", label="2 x CRB(r), k=1")
    a.axhline(28, color="r", ls=":", label="paper: ~28 um after 18")
    a.set_xlabel("number of rotations")
    a.set_ylabel("diameter error [um]")
    a.set_title("Fig. 11: 20 um linearity sensors")
    a.legend(fontsize=7)
    fig.tight_layout()
    p = out / "wang.png"
    fig.savefig(p, dpi=110, metadata={"Software": None})
    plt.close(fig)
    paths["png"] = p
    return paths
