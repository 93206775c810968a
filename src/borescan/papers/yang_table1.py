"""Reproduction of Yang 2017 Table 1 (base radius d_b and tangential radius r) from its printed inputs.

Inputs: the printed mean extremes d_max, d_min per sensor (``data/papers/yang2017_table1.csv``),
R = 275.029 / 2 mm (§3.1 step 1) and oe both as printed (2.3222 mm, step 5) and as Eq. 9 gives on
the printed spindle coordinates P1 = (262.955, -275.502), P0 = (262.833, -273.182) (2.3232 mm).
Closed forms: :func:`borescan.calibrate.yang.yang_d_b_r` (Eqs. 8, 10, 11).

r = sqrt((R - oe)^2 - (d_b + d_min)^2) subtracts two numbers near 135 mm, so the printed inputs'
rounding moves r by tens to hundreds of micrometres: the sensitivities and the spread of r under
+-half-LSB rounding of every input are part of the reproduction.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from borescan.calibrate.yang import yang_d_b_r, yang_oe, yang_sensitivities
from borescan.resources import shipped

__all__ = [
    "TABLE1_CSV",
    "P1_XY_MM",
    "P0_XY_MM",
    "R_MM",
    "OE_PRINTED_MM",
    "load_table1",
    "reproduce",
    "write_reproduction",
]

TABLE1_CSV = shipped("papers", "yang2017_table1.csv")
P1_XY_MM = (262.955, -275.502)
P0_XY_MM = (262.833, -273.182)
R_MM = 275.029 / 2.0
OE_PRINTED_MM = 2.3222
# half of the last printed digit: d_max/d_min 0.1 um (sensor 3's d_min "1.073": 1 um), oe 0.1 um,
# the diameter 275.029 1 um (R: 0.5 um / 2), the spindle coordinates 1 um
HALF_LSB_DIAMETER_MM = 0.0005
HALF_LSB_COORD_MM = 0.0005


def _decimals(text: str) -> int:
    return len(text.split(".")[1]) if "." in text else 0


def load_table1(path: Path | str = TABLE1_CSV) -> list[dict]:
    """Rows of the transcription with values [mm] and the half-LSB of each printed input [mm]."""
    rows = []
    with open(path, newline="") as fh:
        for rec in csv.DictReader(fh):
            row = {"sensor": int(rec["sensor"]), "note": rec.get("note", "")}
            for key in ("d_max_mm", "d_min_mm", "r_mm", "d_b_mm"):
                row[key] = float(rec[key])
                row["half_lsb_" + key] = 0.5 * 10.0 ** (-_decimals(rec[key]))
            rows.append(row)
    return rows


def _mc_spread(row: dict, oe_mm: float, half_lsb_oe: float, n: int, seed: int) -> dict:
    """Distribution of (r, d_b) with every input uniform within +-half LSB (seeded)."""
    rng = np.random.default_rng(seed)
    d_max = row["d_max_mm"] + rng.uniform(-1, 1, n) * row["half_lsb_d_max_mm"]
    d_min = row["d_min_mm"] + rng.uniform(-1, 1, n) * row["half_lsb_d_min_mm"]
    oe = oe_mm + rng.uniform(-1, 1, n) * half_lsb_oe
    R = R_MM + rng.uniform(-1, 1, n) * HALF_LSB_DIAMETER_MM / 2.0
    d_b, r = yang_d_b_r(d_max, d_min, R, oe)
    ok = np.isfinite(r)
    q = np.percentile(r[ok], [2.5, 50.0, 97.5]) if ok.any() else np.full(3, np.nan)
    return {
        "r_p2.5_mm": float(q[0]),
        "r_p50_mm": float(q[1]),
        "r_p97.5_mm": float(q[2]),
        "r_imaginary_fraction": float(1.0 - ok.mean()),
        "d_b_std_um": float(np.std(d_b) * 1e3),
    }


def reproduce(n_mc: int = 200_000, seed: int = 2017) -> dict:
    """Table 1 recomputed from its printed inputs, differences and rounding sensitivity.

    Returns
    -------
    dict with ``R_mm``, ``oe_printed_mm``, ``oe_computed_mm`` (Eq. 9 on P1, P0),
    ``oe_from_printed_d_b_mm`` (the oe that reproduces each printed d_b exactly) and ``rows``:
    per sensor the printed values, the computed r and d_b for both oe with differences
    (computed - printed) in um, the analytic partial derivatives (Eqs. 10-11, um/um), the
    worst-case linear rounding bound of r and d_b [um] and a Monte-Carlo spread of r under
    uniform +-half-LSB rounding of d_max, d_min, oe and R.
    """
    oe_comp = yang_oe(P1_XY_MM, P0_XY_MM)
    # Eq. 9 with each coordinate +-half LSB: range of oe
    dx, dy = P1_XY_MM[0] - P0_XY_MM[0], P1_XY_MM[1] - P0_XY_MM[1]
    corners = [
        np.hypot(dx + a, dy + b)
        for a in (-2 * HALF_LSB_COORD_MM, 2 * HALF_LSB_COORD_MM)
        for b in (-2 * HALF_LSB_COORD_MM, 2 * HALF_LSB_COORD_MM)
    ]
    rows = []
    for row in load_table1():
        out = dict(row)
        for tag, oe in (("oe_printed", OE_PRINTED_MM), ("oe_computed", oe_comp)):
            d_b, r = yang_d_b_r(row["d_max_mm"], row["d_min_mm"], R_MM, oe)
            out[f"d_b_{tag}_mm"] = float(d_b)
            out[f"r_{tag}_mm"] = float(r)
            out[f"diff_d_b_{tag}_um"] = float((d_b - row["d_b_mm"]) * 1e3)
            out[f"diff_r_{tag}_um"] = float((r - row["r_mm"]) * 1e3)
        sens = yang_sensitivities(row["d_max_mm"], row["d_min_mm"], R_MM, OE_PRINTED_MM)
        out.update({k: float(v) for k, v in sens.items()})
        h = {
            "d_max": row["half_lsb_d_max_mm"],
            "d_min": row["half_lsb_d_min_mm"],
            "oe": 0.5e-4,
            "R": HALF_LSB_DIAMETER_MM / 2.0,
        }
        out["r_round_bound_um"] = 1e3 * float(sum(abs(sens[f"dr_d{k}"]) * v for k, v in h.items()))
        out["d_b_round_bound_um"] = 1e3 * float(sum(abs(sens[f"dd_b_d{k}"]) * v for k, v in h.items()))
        out["oe_from_printed_d_b_mm"] = float(
            (row["d_b_mm"] + 0.5 * (row["d_max_mm"] + row["d_min_mm"]))
            * (row["d_max_mm"] - row["d_min_mm"])
            / (2.0 * R_MM)
        )
        mc = _mc_spread(row, OE_PRINTED_MM, 0.5e-4, n_mc, seed + row["sensor"])
        out.update({f"mc_{k}": v for k, v in mc.items()})
        rows.append(out)
    return {
        "R_mm": R_MM,
        "oe_printed_mm": OE_PRINTED_MM,
        "oe_computed_mm": oe_comp,
        "oe_computed_range_mm": (float(min(corners)), float(max(corners))),
        "oe_from_printed_d_b_mm": [r["oe_from_printed_d_b_mm"] for r in rows],
        "rows": rows,
    }


CSV_COLUMNS = [
    "sensor",
    "d_max_mm",
    "d_min_mm",
    "r_mm",
    "d_b_mm",
    "r_oe_printed_mm",
    "diff_r_oe_printed_um",
    "d_b_oe_printed_mm",
    "diff_d_b_oe_printed_um",
    "r_oe_computed_mm",
    "diff_r_oe_computed_um",
    "d_b_oe_computed_mm",
    "diff_d_b_oe_computed_um",
    "dr_dd_max",
    "dr_dd_min",
    "dr_doe",
    "dr_dR",
    "dd_b_dd_max",
    "dd_b_dd_min",
    "dd_b_doe",
    "dd_b_dR",
    "r_round_bound_um",
    "d_b_round_bound_um",
    "mc_r_p2.5_mm",
    "mc_r_p50_mm",
    "mc_r_p97.5_mm",
    "mc_r_imaginary_fraction",
    "oe_from_printed_d_b_mm",
]


def _fmt(x) -> str:
    """Ten significant digits; NaN (no real r) as an empty field."""
    if isinstance(x, float):
        return f"{x:.10g}" if np.isfinite(x) else ""
    return str(x)


def write_reproduction(out_dir: Path | str) -> dict[str, Path]:
    """Write ``yang2017_table1.csv`` (computed vs printed) and ``yang2017_table1.png`` into ``out_dir``.

    Returns the paths written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rep = reproduce()
    csv_path = out_dir / "yang2017_table1.csv"
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(CSV_COLUMNS)
        for row in rep["rows"]:
            w.writerow([_fmt(row[k]) for k in CSV_COLUMNS])

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    oe_grid = np.linspace(2.3215, 2.3240, 501)
    colors = ["C0", "C1", "C2"]
    for row, col in zip(rep["rows"], colors):
        _, r = yang_d_b_r(row["d_max_mm"], row["d_min_mm"], R_MM, oe_grid)
        axes[0].plot(oe_grid, r, color=col, label=f"sensor {row['sensor']} (printed r = {row['r_mm']:.4f})")
        axes[0].plot([OE_PRINTED_MM], [row["r_mm"]], "o", color=col)
    axes[0].axvline(OE_PRINTED_MM, color="k", ls="--", lw=0.8)
    axes[0].axvline(rep["oe_computed_mm"], color="k", ls=":", lw=0.8)
    axes[0].axvspan(*rep["oe_computed_range_mm"], color="0.85", zorder=0)
    axes[0].text(OE_PRINTED_MM, 0.2, " oe printed", fontsize=8)
    axes[0].text(rep["oe_computed_mm"], 0.6, " oe Eq. 9", fontsize=8)
    axes[0].set_xlabel("oe [mm]  (grey: Eq. 9 with the printed P1, P0 rounded to 1 um)")
    axes[0].set_ylabel("r [mm] (Eq. 11)")
    axes[0].set_title("r against oe: 1 um in oe moves r by 1.5-5 mm")
    axes[0].legend(fontsize=8)
    x = np.arange(len(rep["rows"]))
    for row, xi, col in zip(rep["rows"], x, colors):
        lo, mid, hi = row["mc_r_p2.5_mm"], row["mc_r_p50_mm"], row["mc_r_p97.5_mm"]
        axes[1].errorbar(
            [xi - 0.1],
            [mid],
            yerr=[[mid - lo], [hi - mid]],
            fmt="s",
            color=col,
            capsize=4,
            label="computed, 95% range under input rounding" if xi == 0 else None,
        )
        axes[1].plot([xi + 0.1], [row["r_mm"]], "k^", label="printed" if xi == 0 else None)
    axes[1].set_xticks(x, [f"sensor {r['sensor']}" for r in rep["rows"]])
    axes[1].set_ylabel("r [mm]")
    axes[1].set_title("r from printed inputs (oe = 2.3222 mm)")
    axes[1].legend(fontsize=8)
    fig.suptitle("Yang 2017 Table 1 reproduced from its printed inputs")
    fig.tight_layout()
    png_path = out_dir / "yang2017_table1.png"
    fig.savefig(png_path, dpi=110, metadata={"Software": None})
    plt.close(fig)
    return {"csv": csv_path, "png": png_path}
