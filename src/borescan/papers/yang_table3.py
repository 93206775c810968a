"""Reproduction of Yang et al. 2017, Table 3: ten static diameters of a 275.029 mm ring gauge.

The diameters are recomputed from the printed readings with the exact static model
(``measure.static_diameter``: circumcircle of W_i = rho_i n_i + (d_b,i + v_i) u_i, i.e. Yang
Eqs. 3-7 in coordinate form), r and d_b from Table 1 and beam angles derived from Table 2
(Eqs. 12-15). The paper leaves conventions open, so every plausible alternative is computed
and none is fitted to Table 3:

- sign of rho per beam (8 combinations; a global sign flip is the mirror image, i.e. the other
  rotation direction, so the rotation direction needs no separate axis);
- theta_c mode: ``exact`` (beta_first - beta_later = theta_t + asin(rho_later/X) - asin(rho_first/X),
  the spec geometry with counter-clockwise rotation), ``eq14`` (Eq. 12 with Eq. 14 as printed,
  statuses 1 backward, 2 backward, 3 advanced), ``none`` (theta_c = 0);
- samples per revolution N: 625 (printed), the Table 2 period (mean minimum-to-minimum spacing,
  ~659.8), or 661 = 222 + 220 + 219 (the spacings close the revolution);
- which of the three spacings is dropped when they do not close (N != 661).

Separately, the two free beam angles (and a common diameter offset) are fitted to the printed
diameters and compared with the Table-2-derived angles.
"""

from __future__ import annotations

import csv
import itertools
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from borescan.discrepancy.table2 import TABLE2_NUMBERS
from borescan.geometry import Beams
from borescan.measure import static_diameter
from borescan.resources import shipped

__all__ = [
    "TABLE1",
    "SPACINGS",
    "TABLE2_MINIMA",
    "load_table3",
    "table2_period",
    "beams_for",
    "reproduce",
    "write_reproduction",
]

D_GAUGE_MM = 275.029
OE_MM = 2.3222  # printed (Eq. 9 on P1/P0 gives 2.3232)
TABLE1 = {"r_mm": np.array([5.5484, 2.5295, 1.5262]), "d_b_mm": np.array([132.6718, 132.8883, 134.1108])}
SPACINGS = {"2->1": 222, "1->3": 220, "3->2": 219}  # feature-point (minimum) spacings, samples
STATUSES = ("backward", "backward", "advanced")
# Table 2, sample numbers of each sensor's minima (feature points), 18 revolutions: the one transcription,
# borescan.discrepancy.table2.TABLE2_NUMBERS
TABLE2_MINIMA = {c: TABLE2_NUMBERS[(c, "min")] for c in (1, 2, 3)}


def _data_dir() -> Path:
    return shipped("papers")


def load_table3(path: Path | None = None) -> dict[str, np.ndarray]:
    """Read ``data/papers/yang2017_table3.csv`` -> readings (10, 3), diameter_mm, error_mm."""
    path = path or _data_dir() / "yang2017_table3.csv"
    rows = [
        r for r in csv.DictReader(line for line in path.read_text().splitlines() if not line.startswith("#"))
    ]
    return {
        "no": np.array([int(r["no"]) for r in rows]),
        "readings_mm": np.array([[float(r[f"sensor{i}_mm"]) for i in (1, 2, 3)] for r in rows]),
        "diameter_mm": np.array([float(r["diameter_mm"]) for r in rows]),
        "error_mm": np.array([float(r["error_mm"]) for r in rows]),
    }


def table2_period() -> float:
    """Return the samples per revolution implied by Table 2.

    Return samples per revolution implied by Table 2: least-squares slope of minimum sample vs
    revolution, pooled over the three sensors (``papers.yang_table2`` if available).
    """
    try:  # another module owns Table 2; prefer its number when it exists
        from borescan.papers import yang_table2  # type: ignore

        rep = yang_table2.reproduce()
        for key in ("samples_per_rev_measured", "samples_per_rev"):
            val = rep.get(key)
            if isinstance(val, dict):
                val = val.get("measured")
            if val is not None and np.isfinite(float(val)) and 600 < float(val) < 700:
                return float(val)
    except Exception:  # noqa: BLE001 - optional dependency, fall back to the printed numbers
        pass
    slopes = [np.polyfit(np.arange(len(v)), np.asarray(v, float), 1)[0] for v in TABLE2_MINIMA.values()]
    return float(np.mean(slopes))


def table2_spacings() -> dict[str, float]:
    """Mean feature-point spacings computed from the Table 2 minima (not the printed 222/220/219)."""
    m1, m2, m3 = (np.asarray(TABLE2_MINIMA[c], float) for c in (1, 2, 3))
    return {
        "2->1": float(np.mean(m1 - m2)),
        "1->3": float(np.mean(m3 - m1)),
        "3->2": float(np.mean(m2[1:] - m3[:-1])),
    }


def _feature_samples(N: float, drop: str, spacings: dict | None = None) -> np.ndarray:
    """Feature-point sample of sensors (1, 2, 3) relative to sensor 2, from two spacings."""
    sp = SPACINGS if spacings is None else spacings
    a, b, c = sp["2->1"], sp["1->3"], sp["3->2"]
    if drop == "3->2":
        n1, n3 = a, a + b
    elif drop == "1->3":
        n1, n3 = a, N - c
    else:  # drop 2->1
        n3, n1 = N - c, N - c - b
    return np.array([n1, 0.0, n3], dtype=float)


def beams_for(
    signs,
    theta_c_mode: str,
    N: float,
    drop: str = "3->2",
    X_mm: float | None = None,
    spacings: dict | None = None,
) -> Beams:
    """Beams of one alternative (beta_1 = 0; beam angles from Eqs. 12-15).

    Counter-clockwise rotation: a beam reaching the feature point theta_t later sits theta_t
    behind, beta_later = beta_first - theta_t - corr, corr per ``theta_c_mode``:
    exact: asin(rho_later/X) - asin(rho_first/X); eq14: Eq. 14 as printed (Line 1 = later beam);
    none: 0.
    """
    r, d_b = TABLE1["r_mm"], TABLE1["d_b_mm"]
    X = D_GAUGE_MM / 2 - OE_MM if X_mm is None else X_mm
    rho = np.asarray(signs, dtype=float) * r
    n = _feature_samples(N, drop, spacings)
    theta_t = 2 * np.pi * (n - n[1]) / N  # rotation from sensor 2's feature point
    if theta_c_mode == "exact":
        corr = np.arcsin(rho / X) - np.arcsin(rho[1] / X)
    elif theta_c_mode == "eq14":
        a = np.arcsin(r / X)
        sgn = np.array([1.0 if s == "backward" else -1.0 for s in STATUSES])
        # Eq. 14 for (Line 2 = sensor 2, Line 1 = sensor c): s1 a_c - s2 a_2 (same status) or s1 (a_c + a_2)
        corr = np.array(
            [
                sgn[c] * (a[c] - a[1]) if STATUSES[c] == STATUSES[1] else sgn[c] * (a[c] + a[1])
                for c in range(3)
            ]
        )
        corr[1] = 0.0  # beta_later = beta_first - (theta_t + theta_c), Eq. 12
    elif theta_c_mode == "none":
        corr = np.zeros(3)
    else:
        raise ValueError(f"theta_c_mode must be exact, eq14 or none, got {theta_c_mode!r}")
    beta = -theta_t - corr
    beta = beta - beta[0]
    return Beams((1, 2, 3), np.mod(beta, 2 * np.pi), rho, d_b)


def _diameters(readings, beams) -> np.ndarray:
    return np.asarray(static_diameter(readings, beams).diameter_mm)


def _error_column_check(t: dict) -> list[dict]:
    """Return, per row, whether the printed Error is Diameter - 275.029 within Diameter's rounding."""
    implied = t["diameter_mm"] - D_GAUGE_MM
    # printed Error vs Diameter - 275.029: equal within the 3-decimal rounding of Diameter?
    mismatch = np.abs(t["error_mm"] - implied)
    check = [
        {
            "no": int(n),
            "error_mm": float(e),
            "diameter_minus_gauge_mm": float(i),
            "consistent": bool(m <= 0.0005 + 1e-12),
            "on_rounding_boundary": bool(abs(m - 0.0005) < 1e-12),
        }
        for n, e, i, m in zip(t["no"], t["error_mm"], implied, mismatch)
    ]
    return check


def _alternatives(v: np.ndarray, target: np.ndarray, N_meas: float, sp_meas: dict) -> list[dict]:
    """Return Table 3 under every alternative reading (signs, theta_c, N, spacings, dropped), by RMS."""
    N_close_meas = sum(sp_meas.values())
    combos = [
        ("printed", None, 625.0, "625 printed"),
        ("printed", None, N_meas, "Table 2 period"),
        ("printed", None, 661.0, "661 closure"),
        ("Table 2", sp_meas, 625.0, "625 printed"),
        ("Table 2", sp_meas, N_meas, "Table 2 period"),
        ("Table 2", sp_meas, N_close_meas, "closure"),
    ]
    alts = []
    for signs in itertools.product((1, -1), repeat=3):
        for mode in ("exact", "eq14", "none"):
            for sp_label, sp, N, N_label in combos:
                closes = N_label.endswith("closure")
                for drop in ("3->2", "1->3", "2->1") if not closes else ("3->2",):
                    b = beams_for(signs, mode, N, drop, spacings=sp)
                    D = _diameters(v, b)
                    diff = D - target
                    alts.append(
                        {
                            "signs": tuple(int(s) for s in signs),
                            "theta_c": mode,
                            "N": float(N),
                            "N_label": N_label,
                            "spacings": sp_label,
                            "dropped": drop if not closes else "none",
                            "beta21_deg": float(np.rad2deg(b.beta_rad[1])),
                            "beta31_deg": float(np.rad2deg(b.beta_rad[2])),
                            "diameter_mm": D,
                            "diff_um": diff * 1e3,
                            "rms_um": float(np.sqrt(np.mean(diff**2)) * 1e3),
                        }
                    )
    alts.sort(key=lambda a: a["rms_um"])
    return alts


def _diameters_at(v: np.ndarray, rho: np.ndarray, beta21_rad: float, beta31_rad: float) -> np.ndarray:
    """Return the ten diameters with beta_1 = 0 and the given angles of beams 2 and 3 (Table 1's d_b)."""
    return _diameters(v, Beams((1, 2, 3), np.array([0.0, beta21_rad, beta31_rad]), rho, TABLE1["d_b_mm"]))


def _sign_fits(v: np.ndarray, target: np.ndarray) -> list[dict]:
    """Return, per rho-sign pattern, beta_2 - beta_1 and beta_3 - beta_1 fitted to Table 3, by RMS."""
    fits = []
    for signs in itertools.product((1, -1), repeat=3):
        rho = np.asarray(signs, float) * TABLE1["r_mm"]
        # start from the Table-2 angles of the same signs (N = 661, no theta_c), both mirror images
        b0 = beams_for(signs, "none", 661.0)
        best = None
        for start in (b0.beta_rad[1:], 2 * np.pi - b0.beta_rad[1:]):

            def f(p, rho=rho):
                return _diameters_at(v, rho, p[0], p[1]) - target

            sol = least_squares(f, start, x_scale=1e-3, xtol=1e-15, ftol=1e-15, gtol=1e-15)
            if best is None or sol.cost < best.cost:
                best = sol
        fits.append(
            {
                "signs": tuple(int(s) for s in signs),
                "beta21_deg": float(np.rad2deg(best.x[0])),
                "beta31_deg": float(np.rad2deg(best.x[1])),
                "rms_um": float(np.sqrt(2 * best.cost / v.shape[0]) * 1e3),
                "diff_um": best.fun * 1e3,
            }
        )
    fits.sort(key=lambda f: f["rms_um"])
    return fits


def _fit_with_offset(v: np.ndarray, target: np.ndarray, fb: dict) -> tuple[dict, np.ndarray]:
    """Return the best pattern's fit with a common diameter offset, and its solution (angles, offset)."""
    rho = np.asarray(fb["signs"], float) * TABLE1["r_mm"]

    def f3(p):
        return _diameters_at(v, rho, p[0], p[1]) + p[2] - target

    sol = least_squares(
        f3,
        [np.deg2rad(fb["beta21_deg"]), np.deg2rad(fb["beta31_deg"]), 0.0],
        x_scale=1e-3,
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    J = sol.jac
    s2 = 2 * sol.cost / (v.shape[0] - 3)
    cov = s2 * np.linalg.inv(J.T @ J)
    fit_offset = {
        "signs": fb["signs"],
        "beta21_deg": float(np.rad2deg(sol.x[0])),
        "beta31_deg": float(np.rad2deg(sol.x[1])),
        "offset_um": float(sol.x[2] * 1e3),
        "u_offset_um": float(np.sqrt(cov[2, 2]) * 1e3),
        "u_beta21_deg": float(np.rad2deg(np.sqrt(cov[0, 0]))),
        "u_beta31_deg": float(np.rad2deg(np.sqrt(cov[1, 1]))),
        "rms_um": float(np.sqrt(2 * sol.cost / v.shape[0]) * 1e3),
    }

    return fit_offset, sol.x


def _fit_to_gauge(v: np.ndarray, fb: dict, start_rad: np.ndarray) -> dict:
    """Return the angles with which the ten printed readings give the gauge diameter (self-calibration)."""
    rho = np.asarray(fb["signs"], float) * TABLE1["r_mm"]

    def fg(p):
        return _diameters_at(v, rho, p[0], p[1]) - D_GAUGE_MM

    sg = least_squares(fg, start_rad, x_scale=1e-3, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    cg = (2 * sg.cost / (v.shape[0] - 2)) * np.linalg.inv(sg.jac.T @ sg.jac)
    fit_gauge = {
        "signs": fb["signs"],
        "beta21_deg": float(np.rad2deg(sg.x[0])),
        "beta31_deg": float(np.rad2deg(sg.x[1])),
        "u_beta21_deg": float(np.rad2deg(np.sqrt(cg[0, 0]))),
        "u_beta31_deg": float(np.rad2deg(np.sqrt(cg[1, 1]))),
        "rms_um": float(np.sqrt(2 * sg.cost / v.shape[0]) * 1e3),
        "diff_um": sg.fun * 1e3,
    }
    return fit_gauge


def reproduce() -> dict:
    """Compute Table 3 under every alternative and fit the angles that explain it.

    Returns
    -------
    dict with keys: table (printed columns), target_mm (275.029 + Error, 0.1 um digits),
    error_column_check, N_table2, alternatives (list of dicts, sorted by RMS), best, paper_literal,
    fits (per rho-sign pattern: fitted beta_2 - beta_1, beta_3 - beta_1 [deg], RMS [um]),
    fit_with_offset (best pattern with a common diameter offset), fit_to_gauge (angles that make
    the printed readings give 275.029 mm: a self-calibration on Table 3's own data).
    """
    t = load_table3()
    v = t["readings_mm"]
    target = D_GAUGE_MM + t["error_mm"]
    N_meas = table2_period()
    sp_meas = table2_spacings()
    alts = _alternatives(v, target, N_meas, sp_meas)
    literal = [
        a
        for a in alts
        if a["signs"] == (-1, -1, 1)
        and a["N"] == 625.0
        and a["dropped"] == "3->2"
        and a["theta_c"] in ("exact", "eq14")
        and a["spacings"] == "printed"
    ]
    fits = _sign_fits(v, target)
    fit_offset, x_offset = _fit_with_offset(v, target, fits[0])
    return {
        "fit_to_gauge": _fit_to_gauge(v, fits[0], x_offset[:2]),
        "table": t,
        "target_mm": target,
        "error_column_check": _error_column_check(t),
        "N_table2": N_meas,
        "spacings_table2": sp_meas,
        "alternatives": alts,
        "best": alts[0],
        "paper_literal": literal,
        "fits": fits,
        "fit_with_offset": fit_offset,
    }


def write_reproduction(out_dir) -> dict[str, Path]:
    """Write the reproduction of Yang 2017 Table 3; return the paths.

    Write ``yang_table3.csv`` (row by row), ``yang_table3_alternatives.csv`` and
    ``yang_table3.png`` into ``out_dir``; returns the paths.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rep = reproduce()
    t = rep["table"]
    best, lit, fit = rep["best"], rep["paper_literal"], rep["fits"][0]
    p_rows = out / "yang_table3.csv"
    with p_rows.open("w", newline="") as fh:
        w = csv.writer(fh)
        cols = [
            "no",
            "sensor1_mm",
            "sensor2_mm",
            "sensor3_mm",
            "printed_diameter_mm",
            "printed_error_mm",
            "target_mm",
            "best_alternative_mm",
            "best_diff_um",
        ]
        cols += [f"literal_{a['theta_c']}_mm" for a in lit] + [f"literal_{a['theta_c']}_diff_um" for a in lit]
        cols += ["fitted_angles_diff_um"]
        w.writerow(cols)
        for i in range(len(t["no"])):
            row = [
                int(t["no"][i]),
                *[f"{x:.4f}" for x in t["readings_mm"][i]],
                f"{t['diameter_mm'][i]:.3f}",
                f"{t['error_mm'][i]:.4f}",
                f"{rep['target_mm'][i]:.4f}",
                f"{best['diameter_mm'][i]:.5f}",
                f"{best['diff_um'][i]:.2f}",
            ]
            row += [f"{a['diameter_mm'][i]:.5f}" for a in lit] + [f"{a['diff_um'][i]:.1f}" for a in lit]
            row += [f"{fit['diff_um'][i]:.3f}"]
            w.writerow(row)
    p_alt = out / "yang_table3_alternatives.csv"
    with p_alt.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "rho_signs",
                "theta_c",
                "spacings",
                "N",
                "N_label",
                "dropped_spacing",
                "beta21_deg",
                "beta31_deg",
                "rms_um",
            ]
            + [f"diff_no{i}_um" for i in t["no"]]
        )
        for a in rep["alternatives"]:
            w.writerow(
                [
                    "".join("+" if s > 0 else "-" for s in a["signs"]),
                    a["theta_c"],
                    a["spacings"],
                    f"{a['N']:.3f}",
                    a["N_label"],
                    a["dropped"],
                    f"{a['beta21_deg']:.4f}",
                    f"{a['beta31_deg']:.4f}",
                    f"{a['rms_um']:.3f}",
                ]
                + [f"{d:.2f}" for d in a["diff_um"]]
            )
    p_png = out / "yang_table3.png"
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    no = t["no"]
    ax = axes[0]
    ax.axhline(0, color="k", lw=0.6)
    ax.plot(
        no,
        best["diff_um"],
        "o-",
        label=f"best: signs {best['signs']}, theta_c={best['theta_c']}, N={best['N']:.0f} "
        f"(RMS {best['rms_um']:.2f} um)",
    )
    for a in lit:
        ax.plot(
            no,
            a["diff_um"],
            "s--",
            label=f"literal: N=625, theta_c={a['theta_c']} (RMS {a['rms_um']:.0f} um)",
        )
    ax.set_yscale("symlog", linthresh=1.0)
    ax.set_xlabel("Table 3 row")
    ax.set_ylabel("computed - printed diameter [um]")
    ax.set_title("Yang 2017 Table 3: recomputed from Tables 1-2")
    ax.legend(fontsize=7)
    ax = axes[1]
    rms = np.array([a["rms_um"] for a in rep["alternatives"]])
    labels = [a["N_label"] for a in rep["alternatives"]]
    for lab, mk in (("625 printed", "v"), ("Table 2 period", "o"), ("661 closure", "*"), ("closure", "P")):
        idx = [i for i, L in enumerate(labels) if L == lab]
        ax.semilogy(
            idx,
            rms[idx],
            mk,
            ls="none",
            label=f"N = {lab}" if lab != "closure" else "N = sum of Table 2 spacings",
        )
    ax.set_xlabel("alternative (sorted by RMS)")
    ax.set_ylabel("RMS vs printed [um]")
    ax.set_title(f"{len(rms)} convention alternatives")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(p_png, dpi=110, metadata={"Software": None})
    plt.close(fig)
    return {"rows": p_rows, "alternatives": p_alt, "png": p_png}
