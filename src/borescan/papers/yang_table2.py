"""Reproduction of Yang 2017 Table 2 (extreme-point sample numbers) and what follows from it.

Input: ``data/papers/yang2017_table2.csv``, the printed sample numbers ("Number") of each
sensor's minima and maxima and the printed "Difference" cells, transcribed exactly from the OCR
text (blank cells and the row "Mean" kept as they are, marked in ``note``).

Reading of the table (checked cell by cell against the Numbers): in every sensor block the
Differences are the successive intervals of the time-ordered extremum sequence, printed next to
the extremum each interval starts from in row order. Sensors 1 and 2 start with a minimum, so
their first Difference column is n (minimum -> maximum) and the second m (maximum -> minimum).
Sensor 3 starts with a maximum (its d_max Number 199 < d_min Number 531): its d_min-side column
holds min_i - max_i (maximum -> minimum = m) and its d_max-side column max_{i+1} - min_i (n).

Computed here (Yang 2017, §2.3, §3.2, Eq. 15):

- per-sensor period [samples/rev] from consecutive minima (and from all extrema jointly) with
  standard uncertainty (least-squares slope of position vs revolution index);
- mean n and m with standard uncertainties, and the status (n < m -> backward, ccw);
- feature-point (minimum) spacings 2->1, 1->3, 3->2 vs the printed 222, 220, 219;
- theta_t = spacing * 2 pi / P with the paper's P = 625 and with the measured P;
- every printed Difference cell that disagrees with the difference of the printed Numbers, and
  every printed "Mean" that is not the rounded mean of its column;
- the n - m asymmetry that the beam offsets r of Table 1 can produce (exact geometry:
  n - m = 2 delta P / 2 pi, delta = atan(r / (d_b + d_min)) - atan(r / (d_b + d_max))).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from borescan.resources import shipped
from borescan.signal import beam_status, n_m_counts, theta_t_rad

__all__ = [
    "TABLE2_CSV",
    "TABLE1_CSV",
    "SAMPLES_PER_REV_PRINTED",
    "SPACINGS_PRINTED",
    "STATUS_PRINTED",
    "load_table2",
    "reproduce",
    "write_reproduction",
]

TABLE2_CSV = shipped("papers", "yang2017_table2.csv")
TABLE1_CSV = shipped("papers", "yang2017_table1.csv")
SAMPLES_PER_REV_PRINTED = 625.0  # §3.2: "the number of sampling points per circle is 625"
# §3.2 text below Table 2: (from sensor, to sensor) -> printed mean spacing of the minima
SPACINGS_PRINTED = {(2, 1): 222.0, (1, 3): 220.0, (3, 2): 219.0}
STATUS_PRINTED = {1: "backward", 2: "backward", 3: "advanced"}
# printed mean n (min -> max) and m (max -> min) as the text reads them: sensor 1 "328 ... less than
# ... 332"; sensors 2 and 3 by column position (the text gives no numbers for them)
MEANS_BY_COLUMN = {1: (328.0, 332.0), 2: (329.0, 331.0), 3: (331.0, 329.0)}


def load_table2(path: Path | str = TABLE2_CSV) -> dict:
    """Transcription as {channel: {"min": numbers, "max": numbers, "diff": {...}, "mean": {...}}}.

    ``diff[(kind, row)]`` is the printed Difference next to that Number (None when blank);
    ``mean[kind]`` the printed "Mean" under the Difference column next to ``kind``.
    """
    out: dict = {}
    with open(path, newline="") as fh:
        for rec in csv.DictReader(fh):
            ch = int(rec["channel"])
            d = out.setdefault(ch, {"min": {}, "max": {}, "diff": {}, "mean": {}})
            kind = rec["kind"]
            if rec["row"] == "":
                d["mean"][kind] = float(rec["difference_printed"])
                continue
            row = int(rec["row"])
            d[kind][row] = int(rec["number"])
            d["diff"][(kind, row)] = int(rec["difference_printed"]) if rec["difference_printed"] else None
    for d in out.values():
        for kind in ("min", "max"):
            rows = sorted(d[kind])
            d[kind] = np.array([d[kind][r] for r in rows], dtype=float)
    return out


def _slope(pos: list[np.ndarray]) -> tuple[float, float]:
    """Return common slope (samples/rev) of several position sequences vs their index, own intercepts.

    u from the residual scatter (s^2 / sum (i - mean_i)^2).
    """
    num = den = 0.0
    res = []
    for p in pos:
        i = np.arange(p.size, dtype=float)
        ic = i - i.mean()
        num += float(ic @ (p - p.mean()))
        den += float(ic @ ic)
    b = num / den
    for p in pos:
        i = np.arange(p.size, dtype=float)
        res.append(p - p.mean() - b * (i - i.mean()))
    r = np.concatenate(res)
    dof = r.size - len(pos) - 1
    return b, math.sqrt(float(r @ r) / dof / den)


def _mean_u(a: np.ndarray) -> tuple[float, float]:
    return float(a.mean()), float(a.std(ddof=1) / math.sqrt(a.size))


def _table1(path: Path | str) -> dict[int, dict]:
    out = {}
    try:
        with open(path, newline="") as fh:
            for rec in csv.DictReader(fh):
                keys = ("d_max_mm", "d_min_mm", "r_mm", "d_b_mm")
                out[int(rec["sensor"])] = {k: float(rec[k]) for k in keys}
    except (OSError, KeyError, ValueError):
        return {}
    return out


def reproduce(path: Path | str = TABLE2_CSV, table1_path: Path | str = TABLE1_CSV) -> dict:
    """Everything Table 2 implies, computed from the transcription, next to the printed values.

    Returns
    -------
    dict with keys
        ``samples_per_rev`` (printed 625, measured from all extrema with u, per-channel from minima),
        ``channels`` {ch: n/m means with u, printed means by column, status computed/printed,
        the status one gets reading the d_min-side column as n regardless of which extremum
        comes first (``status_if_columns_read_by_position``), period from minima},
        ``spacings`` [{from, to, printed, computed, u, theta_t_deg at 625 and
        at the measured P, difference}], ``difference_mismatches`` [every printed Difference cell
        that differs from the Numbers], ``geometry_n_minus_m`` (largest |n - m| the Table 1 beam
        offsets allow), ``mean_mismatches`` [printed "Mean" cells that are not the rounded mean
        of the cells above them].
    """
    t = load_table2(path)
    p_all, u_all = _slope([t[ch][k] for ch in sorted(t) for k in ("min", "max")])
    period = {
        "printed": SAMPLES_PER_REV_PRINTED,
        "measured": p_all,
        "u_measured": u_all,
        "ratio_measured_to_printed": p_all / SAMPLES_PER_REV_PRINTED,
    }
    out: dict = {"samples_per_rev": period, "channels": {}, "spacings": [], "difference_mismatches": []}
    for ch in sorted(t):
        mn, mx = t[ch]["min"], t[ch]["max"]
        n, m = n_m_counts(mn, mx)
        n_mean, u_n = _mean_u(n)
        m_mean, u_m = _mean_u(m)
        p_min, u_p_min = _slope([mn])
        first = "min" if mn[0] < mx[0] else "max"
        # printed Difference columns: which one is n
        col_next_to_min = t[ch]["mean"]["min"]
        col_next_to_max = t[ch]["mean"]["max"]
        printed_n, printed_m = (
            (col_next_to_min, col_next_to_max) if first == "min" else (col_next_to_max, col_next_to_min)
        )
        st = beam_status(n_mean, m_mean, "ccw")["status"]
        # n - m per revolution pair, with u from its own scatter
        k = min(n.size, m.size)
        nm = n[:k] - m[:k]
        out["channels"][ch] = {
            "first_extremum": first,
            "n_mean": n_mean,
            "u_n_mean": u_n,
            "m_mean": m_mean,
            "u_m_mean": u_m,
            "n_minus_m": float(nm.mean()),
            "u_n_minus_m": float(nm.std(ddof=1) / math.sqrt(k)),
            "n_count": int(n.size),
            "m_count": int(m.size),
            "printed_mean_next_to_min": col_next_to_min,
            "printed_mean_next_to_max": col_next_to_max,
            "printed_n": printed_n,
            "printed_m": printed_m,
            "status_computed": st,
            "status_printed": STATUS_PRINTED[ch],
            "status_agrees": st == STATUS_PRINTED[ch],
            "samples_per_rev_from_minima": p_min,
            "u_samples_per_rev_from_minima": u_p_min,
            "sd_n_samples": float(n.std(ddof=1)),
        }
        out["channels"][ch]["status_if_columns_read_by_position"] = beam_status(
            col_next_to_min, col_next_to_max, "ccw"
        )["status"]
        # printed Difference cells vs differences of the printed Numbers: read row by row
        # (d_min-side cell, then d_max-side cell), the cells are the successive intervals of the
        # time-ordered extremum sequence
        seq = sorted(
            [(p, "min", i + 1) for i, p in enumerate(mn)] + [(p, "max", i + 1) for i, p in enumerate(mx)]
        )
        intervals = [(int(b[0] - a[0]), a, b) for a, b in zip(seq, seq[1:])]
        cells = sorted(t[ch]["diff"].items(), key=lambda kv: (kv[0][1], kv[0][0] != "min"))
        for (kind, row), printed in cells:
            k = 2 * (row - 1) + (0 if kind == "min" else 1)
            computed = intervals[k][0] if k < len(intervals) else None
            if printed != computed:
                out["difference_mismatches"].append(
                    {
                        "channel": ch,
                        "kind": kind,
                        "row": row,
                        "printed": printed,
                        "computed": computed,
                        "interval": None
                        if computed is None
                        else f"{intervals[k][1][0]:.0f} -> {intervals[k][2][0]:.0f}",
                    }
                )
    # the printed "Mean" row vs the mean of the printed cells above it
    out["mean_mismatches"] = []
    for ch in sorted(t):
        for kind in ("min", "max"):
            cells = [v for (k, _), v in t[ch]["diff"].items() if k == kind and v is not None]
            mean = float(np.mean(cells))
            printed = t[ch]["mean"][kind]
            if round(mean) != printed:
                out["mean_mismatches"].append(
                    {
                        "channel": ch,
                        "column_next_to": kind,
                        "printed": printed,
                        "computed": mean,
                        "cells": len(cells),
                    }
                )
    for (a, b), printed in SPACINGS_PRINTED.items():
        pa, pb = t[a]["min"], t[b]["min"]
        i = np.searchsorted(pb, pa, side="right")
        ok = i < pb.size
        d = pb[i[ok]] - pa[ok]
        mean, u = _mean_u(d)
        th625 = math.degrees(float(theta_t_rad(mean, SAMPLES_PER_REV_PRINTED)))
        thp = math.degrees(float(theta_t_rad(mean, p_all)))
        u_thp = thp * math.hypot(u / mean, u_all / p_all)
        out["spacings"].append(
            {
                "from_channel": a,
                "to_channel": b,
                "printed": printed,
                "computed": mean,
                "u_computed": u,
                "count": int(d.size),
                "theta_t_deg_at_625": th625,
                "theta_t_deg_at_measured": thp,
                "u_theta_t_deg_at_measured": u_thp,
                "theta_t_error_deg": th625 - thp,
            }
        )
    out["spacings_sum"] = {
        "printed": sum(SPACINGS_PRINTED.values()),
        "computed": sum(s["computed"] for s in out["spacings"]),
    }
    t1 = _table1(table1_path)
    geo = {}
    for ch, row in t1.items():
        delta = abs(
            math.atan(row["r_mm"] / (row["d_b_mm"] + row["d_min_mm"]))
            - math.atan(row["r_mm"] / (row["d_b_mm"] + row["d_max_mm"]))
        )
        geo[ch] = {"n_minus_m_abs_at_measured_P": 2 * delta * p_all / (2 * math.pi)}
    out["geometry_n_minus_m"] = geo
    return out


def _fmt(x) -> str:
    if x is None:
        return ""
    if isinstance(x, float):
        return f"{x:.4f}"
    return str(x)


def _channel_rows(rep: dict, ch, c: dict) -> list[list]:
    """Return the rows of one channel: P from its minima, n, m, n - m and the status."""
    sp = rep["samples_per_rev"]
    rows = []
    p_min = c["samples_per_rev_from_minima"]
    rows.append(
        [
            "samples_per_rev_from_minima",
            ch,
            sp["printed"],
            p_min,
            c["u_samples_per_rev_from_minima"],
            p_min - sp["printed"],
            "",
        ]
    )
    rows.append(
        [
            "n_mean_samples",
            ch,
            c["printed_n"],
            c["n_mean"],
            c["u_n_mean"],
            c["n_mean"] - c["printed_n"],
            "minimum -> next maximum",
        ]
    )
    rows.append(
        [
            "m_mean_samples",
            ch,
            c["printed_m"],
            c["m_mean"],
            c["u_m_mean"],
            c["m_mean"] - c["printed_m"],
            "maximum -> next minimum",
        ]
    )
    geo = rep["geometry_n_minus_m"].get(ch, {}).get("n_minus_m_abs_at_measured_P", float("nan"))
    printed_nm = c["printed_n"] - c["printed_m"]
    rows.append(
        [
            "n_minus_m_samples",
            ch,
            printed_nm,
            c["n_minus_m"],
            c["u_n_minus_m"],
            c["n_minus_m"] - printed_nm,
            f"geometry (Table 1 r) allows |n-m| = {geo:.2f}",
        ]
    )
    rows.append(
        [
            "status",
            ch,
            c["status_printed"],
            c["status_computed"],
            "",
            "agrees" if c["status_agrees"] else "DISAGREES",
            "n < m -> backward (ccw); reading the d_min-side column as n gives "
            + c["status_if_columns_read_by_position"],
        ]
    )
    return rows


def _reproduction_rows(rep: dict) -> list[list]:
    """Return the csv rows: quantity, channel, printed, computed, u, difference, note."""
    rows = []
    sp = rep["samples_per_rev"]
    rows.append(
        [
            "samples_per_rev",
            "",
            sp["printed"],
            sp["measured"],
            sp["u_measured"],
            sp["measured"] - sp["printed"],
            "P from all 108 extrema (common slope); paper says 625",
        ]
    )
    for ch, c in rep["channels"].items():
        rows.extend(_channel_rows(rep, ch, c))
    for s in rep["spacings"]:
        pair = f"{s['from_channel']}->{s['to_channel']}"
        rows.append(
            [
                "spacing_samples",
                pair,
                s["printed"],
                s["computed"],
                s["u_computed"],
                s["computed"] - s["printed"],
                "minimum of first to next minimum of second",
            ]
        )
        rows.append(
            [
                "theta_t_deg",
                pair,
                s["theta_t_deg_at_625"],
                s["theta_t_deg_at_measured"],
                s["u_theta_t_deg_at_measured"],
                s["theta_t_error_deg"],
                "printed column: Eq. 15 with P = 625; computed: with measured P",
            ]
        )
    for mm in rep["difference_mismatches"]:
        rows.append(
            [
                "difference_cell",
                f"{mm['channel']}/{mm['kind']}/row {mm['row']}",
                mm["printed"],
                mm["computed"],
                "",
                "" if mm["printed"] is None or mm["computed"] is None else mm["computed"] - mm["printed"],
                f"interval {mm['interval']}",
            ]
        )
    for mm in rep["mean_mismatches"]:
        rows.append(
            [
                "mean_cell",
                f"{mm['channel']}/next to {mm['column_next_to']}",
                mm["printed"],
                mm["computed"],
                "",
                mm["computed"] - mm["printed"],
                f"printed Mean vs mean of the {mm['cells']} printed cells",
            ]
        )
    return rows


def _plot_extrema(ax, rep: dict) -> None:
    """Draw n and m per channel, printed and computed, with each status."""
    chs = sorted(rep["channels"])
    x = np.arange(len(chs))
    bars = ((-0.3, "n_mean", "printed_n", "C0", "n"), (0.1, "m_mean", "printed_m", "C1", "m"))
    for off, key, pkey, col, lab in bars:
        ax.bar(
            x + off,
            [rep["channels"][c][pkey] for c in chs],
            0.18,
            color=col,
            alpha=0.45,
            label=f"{lab} printed",
        )
        ax.bar(
            x + off + 0.2,
            [rep["channels"][c][key] for c in chs],
            0.18,
            color=col,
            yerr=[rep["channels"][c]["u_" + key] for c in chs],
            capsize=3,
            label=f"{lab} computed",
        )
    for i, c in enumerate(chs):
        cc = rep["channels"][c]
        geo = rep["geometry_n_minus_m"].get(c, {}).get("n_minus_m_abs_at_measured_P", float("nan"))
        ax.text(
            i,
            333.3,
            f"printed: {cc['status_printed']}\ncomputed: {cc['status_computed']}\n"
            f"n-m = {cc['n_minus_m']:.1f} +- {cc['u_n_minus_m']:.1f}\ngeometry: |n-m| <= {geo:.2f}",
            ha="center",
            va="bottom",
            fontsize=8,
            color="k" if cc["status_agrees"] else "red",
        )
    ax.set_ylim(325, 337)
    ax.set_xticks(x, [f"sensor {c}" for c in chs])
    ax.set_ylabel("mean samples between extrema")
    ax.set_title("n (min->max), m (max->min), status")
    ax.legend(fontsize=7, ncol=2, loc="lower right")


def _plot_spacings(ax, rep: dict) -> None:
    """Draw the minimum spacings, printed and computed from the Numbers."""
    labs = [f"{s['from_channel']}->{s['to_channel']}" for s in rep["spacings"]]
    xx = np.arange(len(labs))
    ax.bar(xx - 0.2, [s["printed"] for s in rep["spacings"]], 0.4, alpha=0.45, label="printed")
    ax.bar(
        xx + 0.2,
        [s["computed"] for s in rep["spacings"]],
        0.4,
        yerr=[s["u_computed"] for s in rep["spacings"]],
        capsize=3,
        label="computed from Numbers",
    )
    for i, s in enumerate(rep["spacings"]):
        ax.text(i, 224.3, f"{s['printed']:.0f} / {s['computed']:.2f}", ha="center", fontsize=8)
    ax.set_ylim(214, 226)
    ax.set_xticks(xx, labs)
    ax.set_ylabel("feature-point spacing [samples]")
    ax.set_title("minimum spacings (printed 222, 220, 219)")
    ax.legend(fontsize=8, loc="lower right")


def _plot_theta(ax, rep: dict) -> None:
    """Draw Eq. 15's theta_t with the printed and with the measured period."""
    sp = rep["samples_per_rev"]
    labs = [f"{s['from_channel']}->{s['to_channel']}" for s in rep["spacings"]]
    xx = np.arange(len(labs))
    ax.bar(
        xx - 0.2, [s["theta_t_deg_at_625"] for s in rep["spacings"]], 0.4, alpha=0.45, label="P = 625 (paper)"
    )
    ax.bar(
        xx + 0.2,
        [s["theta_t_deg_at_measured"] for s in rep["spacings"]],
        0.4,
        label=f"P = {sp['measured']:.2f} +- {sp['u_measured']:.2f} (measured)",
    )
    for i, s in enumerate(rep["spacings"]):
        ax.text(
            i, s["theta_t_deg_at_625"] + 0.5, f"+{s['theta_t_error_deg']:.2f} deg", ha="center", fontsize=8
        )
    ax.set_ylim(110, 135)
    ax.set_xticks(xx, labs)
    ax.set_ylabel("theta_t = spacing x 360 / P [deg]")
    ax.set_title("Eq. 15 with the printed vs the measured period")
    ax.legend(fontsize=8, loc="lower right")


def write_reproduction(out_dir: Path | str, path: Path | str = TABLE2_CSV) -> list[Path]:
    """Write the reproduction of Yang 2017 Table 2; return the paths.

    Write ``yang2017_table2.csv`` (quantity, printed, computed, u, difference) and
    ``yang2017_table2.png`` (computed next to printed) into ``out_dir``; returns the paths.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rep = reproduce(path)
    csv_path = out_dir / "yang2017_table2.csv"
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["quantity", "channel", "printed", "computed", "u_computed", "difference", "note"])
        for r in _reproduction_rows(rep):
            w.writerow([_fmt(x) for x in r])

    fig, axes = plt.subplots(1, 3, figsize=(16, 5.2), gridspec_kw={"width_ratios": [1.35, 1, 1]})
    _plot_extrema(axes[0], rep)
    _plot_spacings(axes[1], rep)
    _plot_theta(axes[2], rep)
    nmis = len(rep["difference_mismatches"])
    mm = "; ".join(
        f"sensor {m['channel']} Mean printed {m['printed']:.0f}, computed {m['computed']:.2f}"
        for m in rep["mean_mismatches"]
    )
    fig.suptitle(
        f"Yang 2017 Table 2 reproduced: {nmis} printed Difference cells disagree with the Numbers; "
        f"{len(rep['mean_mismatches'])} printed Mean disagrees ({mm})",
        fontsize=11,
    )
    fig.tight_layout()
    png_path = out_dir / "yang2017_table2.png"
    fig.savefig(png_path, dpi=110, metadata={"Software": None, "CreationDate": None})
    plt.close(fig)
    return [csv_path, png_path]
