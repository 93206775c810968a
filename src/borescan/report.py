"""The browsable report: ``<results_root>/report.html``, one page per month of nights, the papers.

:func:`update_report` (:func:`write_report`) reads the history catalog and writes
self-contained HTML pages (inline CSS, plots embedded as base64 ``data:`` images, a print
stylesheet, no scripts, no network) whose every link is relative, so the results folder can be
moved or copied to shared storage and the pages still work. Each month of nights has
``report/<YYYY-MM>/index.html`` with its plots beside it (the PNG files are kept and linked from
each embedded image); ``report.html`` shows the totals of the whole history, the latest month's
sections and a link to every month; the paper reproductions have their own page,
``report/papers.html``. Sections:

- **Summary** (first): one row per night, newest first: scans in, quarantined, calibrations
  made / expired / superseded, verifications passed / failed, parts out of tolerance, discrepancy
  verdicts that need a person; below it, night by night, every quarantined scan with its reason
  and what to do (:func:`quarantine_action`, the README's "When something needs attention"),
  every failed verification, part out of tolerance and verdict to look at.
- **Calibration**: parameter trends per device and channel with error bars U (k=2), links to
  each certificate (PDF and JSON), the date recalibration is due.
- **Verification**: per device and ring gauge an individuals and moving-range control chart of
  the verification error; limits (Montgomery, *Statistical Quality Control*, §6.4):
  centre line = mean, UCL/LCL = mean ± 2.66·MR̄ (= ± 3σ̂, σ̂ = MR̄/1.128), MR chart UCL = 3.267·MR̄,
  LCL = 0; points that break the Western Electric run rules 1, 2 and 4 (:func:`run_rules`) are
  marked; plus the measurements a failed verification puts in doubt.
- **Parts**: every diameter at the measured temperature and at 20 °C, its expanded uncertainty U
  with k and coverage probability, "temperature assumed" flagged, the deviation from the nominal
  where the catalog knows one and pass/fail where it knows a tolerance; plots of the parts
  measured more than once.
- **Discrepancy**: findings in words: effect, channel, each parameter as value ± u with its unit,
  verdict, gap before and after; an ambiguous verdict names its candidates and why one scan
  cannot tell them apart; links to ``discrepancy/<scan_id>/gap.png``.
- **Quarantine**: quarantined scans with their reasons and what to do.

Incremental: a month's page is rewritten only when a row it shows changed (one aggregate query
per source tells which months did: :func:`month_fingerprints`, which also covers this module's
code), and a plot is drawn only when its input rows changed (``report/<month>/plots.json``), so
a new night costs about one month's page however long the history; ``full=True`` redraws all.
A failed verification that puts an older month's measurement in doubt changes that month's rows
(the ``suspect_measurements`` view), so its page is rewritten too; a calibration superseded or
expiring in a later month is an event of that later month. Plots label at most
:data:`MAX_TICK_LABELS` ticks per axis.

Every plot function is pure: polars frames in, a :class:`matplotlib.figure.Figure` out (Agg,
no pyplot state). PNGs are written without time stamps, so reruns on the same catalog give the
same bytes.
"""

from __future__ import annotations

import base64
import contextlib
import functools
import math
import hashlib
import html
import io
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import duckdb
import numpy as np
import polars as pl
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from borescan import catalog
from borescan.atomic import atomic_write_bytes, atomic_write_text
from borescan.calibrations import calibration_roles, failed_calibration_ids, order_calibrations
from borescan.decision import CANNOT_DECIDE, CONFORMS, DOES_NOT_CONFORM, split_verdict
from borescan.config import schema_default
from borescan.effects import EFFECTS
from borescan.tables import TABLES

__all__ = [
    "MR_D2_FACTOR",
    "MR_D4",
    "control_limits",
    "run_rules",
    "RUN_RULES",
    "quarantine_action",
    "format_quantity",
    "plot_calibration_trends",
    "plot_control_chart",
    "plot_diameters",
    "load_tables",
    "month_fingerprints",
    "frame_fingerprint",
    "ReportUpdate",
    "update_report",
    "write_report",
]

#: Individuals chart: limits at mean ± 3 MR̄/d2 with d2 = 1.128 (n = 2), i.e. ± 2.66 MR̄.
MR_D2_FACTOR = 2.66
#: Moving-range chart: UCL = D4 MR̄ with D4 = 3.267 (n = 2).
MR_D4 = 3.267
#: d2 of moving ranges of two (Montgomery, Appendix VI): σ̂ = MR̄ / d2.
MR_D2 = 1.128

TRI_PARAMS = (("beta_rad", "u_beta_rad"), ("rho_mm", "u_rho_mm"), ("d_b_mm", "u_d_b_mm"))
ROD_PARAMS = (
    ("l0_mm", "u_l0_mm"),
    ("h_mm", "u_h_mm"),
    ("phi_rad", "u_phi_rad"),
    ("d_mm", "u_d_mm"),
    ("gamma_rad", "u_gamma_rad"),
)
PNG_META = {"Software": None}
REPORT_DIR = "report"


# --------------------------------------------------------------------------- numbers


def control_limits(values: np.ndarray | list[float]) -> dict[str, Any]:
    """Individuals / moving-range control-chart limits of a series.

    Parameters
    ----------
    values
        The individual values in time order (here: verification errors [mm]). NaN are dropped.

    Returns
    -------
    dict
        ``mean``, ``mr`` (moving ranges ``|x_i - x_{i-1}|``, length n-1), ``mr_bar`` (their mean),
        ``ucl = mean + 2.66 mr_bar``, ``lcl = mean - 2.66 mr_bar``, ``mr_ucl = 3.267 mr_bar``,
        ``mr_lcl = 0``. With fewer than two values the MR-based limits are NaN.
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    mean = float(x.mean()) if x.size else float("nan")
    mr = np.abs(np.diff(x))
    mr_bar = float(mr.mean()) if mr.size else float("nan")
    return {
        "mean": mean,
        "mr": mr,
        "mr_bar": mr_bar,
        "ucl": mean + MR_D2_FACTOR * mr_bar,
        "lcl": mean - MR_D2_FACTOR * mr_bar,
        "mr_ucl": MR_D4 * mr_bar,
        "mr_lcl": 0.0,
    }


#: The Western Electric run rules this report applies (Western Electric, *Statistical Quality
#: Control Handbook*, 1956; Montgomery §5.3.6): rule number -> what breaks it.
RUN_RULES = {
    1: "a point beyond 3σ",
    2: "2 of 3 in a row beyond 2σ on one side",
    4: "8 in a row on one side of the centre line",
}


def run_rules(values: np.ndarray | list[float], centre: float, sigma: float) -> dict[int, np.ndarray]:
    """Return the points of a series that break Western Electric run rules 1, 2 and 4.

    Parameters
    ----------
    values
        The individual values in time order [any unit]. NaN never counts and breaks a run.
    centre
        Centre line [same unit] (the chart's mean).
    sigma
        Standard deviation of one value [same unit]; for an individuals chart σ̂ = MR̄ / 1.128.

    Returns
    -------
    dict
        Rule number -> boolean array (one per value), True where the value takes part in a
        breach: rule 1, ``|x - centre| > 3 sigma``; rule 2, two of three consecutive values beyond
        ``2 sigma`` on the same side (the values beyond, in every such window); rule 4, eight or
        more consecutive values strictly on one side of the centre line (every value of the run).
        All False when ``sigma`` or ``centre`` is not finite or ``sigma`` <= 0.
    """
    x = np.asarray(values, dtype=float)
    n = x.size
    out = {r: np.zeros(n, dtype=bool) for r in RUN_RULES}
    if not (np.isfinite(centre) and np.isfinite(sigma) and sigma > 0):
        return out
    z = (x - centre) / sigma
    fin = np.isfinite(z)
    out[1] = fin & (np.abs(z) > 3.0)
    for sign in (1.0, -1.0):
        beyond = fin & (sign * z > 2.0)
        for i in range(max(n - 2, 0)):
            if beyond[i : i + 3].sum() >= 2:
                out[2][i : i + 3] |= beyond[i : i + 3]
        side = fin & (sign * z > 0.0)
        run = 0
        for i in range(n):
            run = run + 1 if side[i] else 0
            if run >= 8:
                out[4][i - run + 1 : i + 1] = True
    return out


#: Quarantine reasons by class (first match of a lower-case fragment of the reason wins):
#: (class, fragments, what an operator does), after the README's "When something needs attention".
QUARANTINE_ACTIONS = (
    (
        "scan id reused",
        ("already used", "unique across nights"),
        "Write the scan under a new scan id (ids are unique across nights) and rerun.",
    ),
    (
        "calibration refused",
        ("calibration refused",),
        "Read discrepancy/<scan>/findings.json of these scans: it names what the model misses. Check that "
        "sensor or its cabling, recalibrate. Measurements keep the last valid calibration until it expires.",
    ),
    (
        "calibration failed verification",
        ("failed its verification",),
        "Recalibrate the device; its measurements are refused until a new calibration passes verification.",
    ),
    ("calibration expired", ("expired",), "Recalibrate the device, then rerun the night."),
    (
        "design geometry missing",
        ("device.nominal",),
        "Write the scan again under a new scan id with device.nominal "
        "(the design beams of a three-sensor device, the "
        "layers of a rod; optional in the raw format) or calibrate "
        "the device from a scan that has it: scans of a "
        "calibrated device are measured and examined against its calibration.",
    ),
    (
        "no calibration",
        ("no calibration",),
        "Calibrate the device (a calibration scan on or before the night), then rerun the night.",
    ),
    (
        "too few revolutions or poses",
        ("too few", "revolutions", "poses"),
        "Rescan with more whole revolutions (or poses), the spindle at the gauge centre, under a new "
        "scan id.",
    ),
    (
        "scan metadata",
        ("needs a ring_gauge",),
        "Correct scan.json (kind, artifact, certificate) in a new scan id and rerun; never edit the "
        "raw folder in place.",
    ),
    (
        "processing error",
        ("stage failed", "measurement failed", "examination failed", "calibration failed"),
        "Read the stage's log under logs/ and quarantine/<scan>.json; if borescan validate passes on "
        "the scan, "
        "report it with the record.",
    ),
)
#: A reason that matches no class: the raw file itself is broken.
BROKEN_FILE_ACTION = (
    "broken file",
    "Fix the export or rescan under a new scan id (never edit the raw folder in place); "
    "borescan validate RAW_ROOT shows the same verdict before a run.",
)


def quarantine_action(reason: str | None) -> tuple[str, str]:
    """(class, what to do) of a quarantine reason (README "When something needs attention").

    Reasons that name no processing class (truncated file, wrong types, clock jump, readings
    out of range, non-monotonic samples, ...) are a broken raw file.
    """
    text = (reason or "").lower()
    for cls, fragments, action in QUARANTINE_ACTIONS:
        if any(f in text for f in fragments):
            return cls, action
    return BROKEN_FILE_ACTION


#: Display units: SI unit -> (smaller unit, factor) used when the value is small.
_SMALLER = {"mm": ("µm", 1e3), "s": ("ms", 1e3), "rad": ("mrad", 1e3), "mm/s": ("µm/s", 1e3)}


def format_quantity(value: float | None, u: float | None = None, unit: str = "") -> str:
    """Return a value with its uncertainty for people: ``1.200 ± 0.030 ms``.

    The uncertainty is rounded to two significant digits and the value to the same decimal
    place (GUM 7.2.6); without an uncertainty the value keeps four significant digits. Values
    below 0.1 of a unit in :data:`_SMALLER` are shown in the smaller unit (mm -> µm, s -> ms
    (and µs), rad -> mrad). Dimensionless (``"-"``) values carry no unit. "" for a missing value.
    """
    if value is None or not np.isfinite(value):
        return ""
    v = float(value)
    uu = float(u) if u is not None and np.isfinite(u) and u > 0 else None
    unit = "" if unit in ("-", None) else unit
    big = max(abs(v), uu or 0.0)
    if unit in _SMALLER and big < 0.1:
        unit, f = _SMALLER[unit]
        v, uu = v * f, (uu * f if uu else None)
        if unit == "ms" and max(abs(v), uu or 0.0) < 0.1:
            unit, v, uu = "µs", v * 1e3, (uu * 1e3 if uu else None)
    tail = f" {unit}" if unit else ""
    if uu is None:
        return f"{v:.4g}{tail}"
    dec = max(0, 1 - int(math.floor(math.log10(uu))))
    return f"{v:.{dec}f} ± {uu:.{dec}f}{tail}"


def _labels(df: pl.DataFrame, id_col: str = "scan_id") -> list[str]:
    nights = df["night"].to_list() if "night" in df.columns else [None] * df.height
    ids = df[id_col].to_list()
    return [f"{'' if n is None else n}\n{i}" for n, i in zip(nights, ids, strict=True)]


#: At most this many labelled ticks per axis: a month of nights stays readable, and drawing
#: text is what a plot's cost grows with.
MAX_TICK_LABELS = 8


def _xticks(ax, labels: list[str], most: int = MAX_TICK_LABELS) -> None:
    """Label the x positions 0..n-1; with more than ``most`` labels, every k-th."""
    step = -(-len(labels) // most) if labels else 1
    pos = list(range(0, len(labels), step))
    ax.set_xticks(pos)
    slant = len(pos) > max(2, most // 2)  # a narrow panel slants its labels sooner
    ax.set_xticklabels(
        [labels[i] for i in pos], rotation=45 if slant else 0, ha="right" if slant else "center", fontsize=7
    )


# --------------------------------------------------------------------------- plots (pure)


def plot_calibration_trends(cal: pl.DataFrame, device_id: str) -> Figure:
    """Calibration parameters of one device over its calibrations, one panel per parameter and channel.

    ``cal`` has the ``calibrations`` columns; rows of other devices are ignored. Error bars are
    U (k=2) = 2·u of the standard uncertainties where present. The x axis lists the calibrations in
    ``valid_from`` order, labelled with night and calibration scan.
    """
    df = cal.filter(pl.col("device_id") == device_id).sort("valid_from", "calibration_id", "channel")
    params = [p for p in TRI_PARAMS + ROD_PARAMS if p[0] in df.columns and df[p[0]].drop_nulls().len() > 0]
    channels = sorted(df["channel"].drop_nulls().unique().to_list())
    cal_order = (
        df.select("calibration_id", "valid_from", "scan_id")
        .unique("calibration_id", keep="first")
        .sort("valid_from", "calibration_id")
    )
    pos = {c: i for i, c in enumerate(cal_order["calibration_id"].to_list())}
    labels = [
        f"{v}\n{s}"
        for v, s in zip(cal_order["valid_from"].to_list(), cal_order["scan_id"].to_list(), strict=True)
    ]
    if len(channels) <= 1:  # one channel (a one-layer rod): parameters side by side, three to a row
        nc = min(max(len(params), 1), 3)
        nr = -(-max(len(params), 1) // nc)
        cells = [(k // nc, k % nc, p, channels[0] if channels else None) for k, p in enumerate(params)]
    else:
        nr, nc = max(len(params), 1), len(channels)
        cells = [(i, j, p, ch) for i, p in enumerate(params) for j, ch in enumerate(channels)]
    fig = Figure(figsize=(3.2 * nc + 1.0, 2.2 * nr + 1.0), layout="constrained")
    axes = fig.subplots(nr, nc, squeeze=False, sharex=True)
    used = set()
    for i, j, (p, up), ch in cells:
        ax = axes[i][j]
        used.add((i, j))
        sub = df.filter(pl.col("channel") == ch).drop_nulls(p)
        x = [pos[c] for c in sub["calibration_id"].to_list()]
        y = sub[p].to_numpy()
        err = 2.0 * sub[up].fill_null(0.0).to_numpy() if up in sub.columns else None
        ax.errorbar(x, y, yerr=err, fmt="o-", ms=4, capsize=3, color="C0")
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
        ax.grid(alpha=0.3)
        if len(channels) <= 1:
            ax.set_title(f"{p} (channel {ch})", fontsize=9)
        elif i == 0:
            ax.set_title(f"channel {ch}", fontsize=9)
        if j == 0 or len(channels) <= 1:
            ax.set_ylabel(p, fontsize=8)
        ax.tick_params(axis="y", labelsize=7)
    for i in range(nr):
        for j in range(nc):
            if (i, j) not in used:
                axes[i][j].set_visible(False)
            else:
                _xticks(axes[i][j], labels, most=4)  # a 3.2 in panel holds a few two-line labels
                axes[i][j].tick_params(axis="x", labelbottom=i == nr - 1 or (i + 1, j) not in used)
    fig.suptitle(f"{device_id}: calibration parameters (error bars: U (k=2))", fontsize=10)
    return fig


#: A label drawn over data stays legible.
_LABEL_BOX = {"boxstyle": "square,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.75}


def _night_ticks(ax, nights: list, ids: list, most: int = MAX_TICK_LABELS) -> None:
    """Return the axis ticks that label points by night.

    Label points 0..n-1 by night: every point as "night / scan" when there are at most ``most``,
    else at most ``most`` nights (the first point of every k-th night), a minor tick per night.
    """
    n = len(nights)
    if n <= most:
        _xticks(ax, [f"{'' if d is None else d}\n{i}" for d, i in zip(nights, ids, strict=True)], most)
        return
    firsts = [i for i in range(n) if i == 0 or nights[i] != nights[i - 1]]
    step = -(-len(firsts) // most)
    pos = firsts[::step]
    ax.set_xticks(pos)
    ax.set_xticklabels([str(nights[i]) for i in pos], rotation=30, ha="right", fontsize=7)
    if len(firsts) <= 120:  # a minor tick per night while they stay apart
        ax.set_xticks(firsts, minor=True)


def plot_control_chart(  # noqa: C901 (one branch per optional element of the chart)
    ver: pl.DataFrame, device_id: str, artifact_id: str | None = None
) -> Figure:
    """Individuals and moving-range chart of one device's verification errors on one ring gauge.

    ``ver`` has the ``verifications`` columns (``night``, ``scan_id``, ``error_mm``, ``passed``,
    ``tolerance_mm``, optionally ``u_error_mm``) in time order; rows of other devices are ignored,
    and of other gauges when ``artifact_id`` is given (a chart pools one gauge only: two gauges
    differ by their certificates' errors). Limits from :func:`control_limits`; points that break
    the run rules (:func:`run_rules`, σ̂ = MR̄/1.128) are ringed and numbered; failed verifications
    red squares; ± tolerance dotted; error bars U (k=2) = 2·u_error_mm where given. The x axis is
    the verification order, labelled by night (thinned to :data:`MAX_TICK_LABELS`).
    """
    df = ver.filter(pl.col("device_id") == device_id)
    if artifact_id is not None and "artifact_id" in df.columns:
        df = df.filter(pl.col("artifact_id") == artifact_id)
    lim = control_limits(df["error_mm"].to_numpy())
    x = np.arange(df.height)
    y = df["error_mm"].cast(pl.Float64).to_numpy() * 1e3
    passed = df["passed"].fill_null(True).to_numpy().astype(bool)
    rules = run_rules(y, lim["mean"] * 1e3, lim["mr_bar"] * 1e3 / MR_D2)
    small = df.height > 60
    ms = 2.5 if small else 4.5
    fig = Figure(figsize=(8.0, 5.8), layout="constrained")
    ax_i, ax_mr = fig.subplots(2, 1, sharex=True, height_ratios=(3, 2))
    ax_i.plot(x, y, "-", color="0.6", lw=0.8 if small else 1)
    if "u_error_mm" in df.columns and df["u_error_mm"].drop_nulls().len():
        big_u = 2.0 * df["u_error_mm"].cast(pl.Float64).fill_null(float("nan")).to_numpy() * 1e3
        ax_i.errorbar(
            x,
            y,
            yerr=big_u,
            fmt="none",
            ecolor="C0",
            alpha=0.5,
            lw=0.8,
            capsize=0 if small else 2,
            label="U (k=2)",
        )
    ax_i.plot(x[passed], y[passed], "o", color="C0", ms=ms, label="passed")
    if (~passed).any():
        ax_i.plot(x[~passed], y[~passed], "s", color="C3", ms=ms + 1, label="failed")
    broken = rules[1] | rules[2] | rules[4]
    if broken.any():
        ax_i.plot(
            x[broken],
            y[broken],
            "o",
            mfc="none",
            mec="C1",
            mew=1.5,
            ms=ms + 5,
            label="breaks run rule " + ", ".join(str(r) for r in RUN_RULES if rules[r].any()),
        )
        if broken.sum() <= 40:  # numbers stay legible
            for i in np.nonzero(broken)[0]:
                ax_i.annotate(
                    ",".join(str(r) for r in RUN_RULES if rules[r][i]),
                    (x[i], y[i]),
                    fontsize=7,
                    color="C1",
                    fontweight="bold",
                    xytext=(3 + ms, 3 + ms),
                    textcoords="offset points",
                    ha="left",
                    va="bottom",
                )
    lo, hi = (float(np.nanmin(y)), float(np.nanmax(y))) if np.isfinite(y).any() else (-1.0, 1.0)
    for val, style, name in (
        (lim["mean"], "-", "mean"),
        (lim["ucl"], "--", "UCL"),
        (lim["lcl"], "--", "LCL"),
    ):
        if np.isfinite(val):
            ax_i.axhline(val * 1e3, ls=style, color="k" if name == "mean" else "C1", lw=1)
            ax_i.annotate(
                f"{name} {val * 1e3:.2f}",
                (0.995, val * 1e3),
                xycoords=("axes fraction", "data"),
                fontsize=7,
                va="bottom",
                ha="right",
                bbox=_LABEL_BOX,
            )
            lo, hi = min(lo, val * 1e3), max(hi, val * 1e3)
    tol = df["tolerance_mm"].drop_nulls() if "tolerance_mm" in df.columns else pl.Series([], dtype=pl.Float64)
    if tol.len():
        t = float(tol.max()) * 1e3
        for s in (t, -t):
            ax_i.axhline(s, ls=":", color="C3", lw=1)
        # inside the axes: a little right of the left edge, just above the line
        ax_i.annotate(
            f"tolerance ±{t:g} µm",
            (0.01, t),
            xycoords=("axes fraction", "data"),
            fontsize=7,
            va="bottom",
            ha="left",
            color="C3",
            bbox=_LABEL_BOX,
        )
        lo, hi = min(lo, -t), max(hi, t)
    span = hi - lo or 1.0
    ax_i.set_ylim(lo - 0.2 * span, hi + 0.12 * span)  # below: room for the legend, above: for the labels
    ax_i.set_ylabel("error [µm]")
    gauge = f", gauge {artifact_id}" if artifact_id else ""
    ax_i.set_title(f"{device_id}{gauge}: verification error, individuals chart", fontsize=10)
    ax_i.legend(fontsize=7, loc="lower left", ncols=4, framealpha=0.85)
    ax_i.grid(alpha=0.3)
    mr = lim["mr"] * 1e3
    ax_mr.plot(x[1:], mr, "o-", color="C0", ms=ms - 1, lw=0.8 if small else 1)
    if np.isfinite(lim["mr_bar"]):
        ax_mr.axhline(lim["mr_bar"] * 1e3, color="k", lw=1)
        ax_mr.axhline(lim["mr_ucl"] * 1e3, ls="--", color="C1", lw=1)
        ax_mr.annotate(
            f"MR̄ {lim['mr_bar'] * 1e3:.2f}",
            (0.995, lim["mr_bar"] * 1e3),
            xycoords=("axes fraction", "data"),
            fontsize=7,
            va="bottom",
            ha="right",
            bbox=_LABEL_BOX,
        )
        ax_mr.annotate(
            f"UCL {lim['mr_ucl'] * 1e3:.2f}",
            (0.995, lim["mr_ucl"] * 1e3),
            xycoords=("axes fraction", "data"),
            fontsize=7,
            va="bottom",
            ha="right",
            bbox=_LABEL_BOX,
        )
        ax_mr.set_ylim(0.0, max(float(np.nanmax(mr)) if mr.size else 0.0, lim["mr_ucl"] * 1e3) * 1.15 or 1.0)
    ax_mr.axhline(0.0, color="0.7", lw=0.8)
    ax_mr.set_ylabel("moving range [µm]")
    ax_mr.set_title("moving range chart", fontsize=10)
    ax_mr.grid(alpha=0.3)
    ax_mr.set_xlim(-0.5, max(df.height - 0.5, 0.5))
    _night_ticks(
        ax_mr,
        df["night"].cast(pl.Utf8).to_list() if "night" in df.columns else [None] * df.height,
        df["scan_id"].to_list(),
    )
    return fig


def device_model_history(
    pooled: pl.DataFrame | None, cal: pl.DataFrame | None, ver: pl.DataFrame | None, device_id: str
) -> pl.DataFrame:
    """Per night of one device, what its device model did to the gaps (issue 22, "gap shown over time").

    Columns: ``night``; ``pooled_gap_to_noise`` (the pooled examination's rms residual of base +
    device model before any named effect, over its noise floor); ``calibration_residual_to_noise``
    (the night's calibration: its worst channel's residual rms over that channel's noise floor);
    ``verification_e_over_u`` (the night's largest |error| / U of a ring-gauge verification) and
    ``verification_error_um`` (that verification's error at 20 degC);
    ``carried`` (what the night's calibration carried of the device model with an estimate, e.g.
    ``channel_delay@2 tau_s = 1.19 ± 0.02 ms (2026-11-23)``; "" when nothing) and ``carried_keys``
    (its effects, ``channel_delay@2``: the model's composition, which changes only by a decision,
    while the estimates follow each night). A night without a figure has null there.
    """
    rows: dict[str, dict[str, Any]] = {}

    def row(night) -> dict[str, Any]:
        return rows.setdefault(
            str(night),
            {
                "night": str(night),
                "pooled_gap_to_noise": None,
                "calibration_residual_to_noise": None,
                "verification_e_over_u": None,
                "verification_error_um": None,
                "carried": "",
                "carried_keys": "",
            },
        )

    if pooled is not None and pooled.height:
        for r in (
            pooled.filter(pl.col("device_id") == device_id)
            .unique(["night"], keep="first")
            .iter_rows(named=True)
        ):
            if r.get("gap_before_mm") is not None and r.get("noise_floor_mm"):
                row(r["night"])["pooled_gap_to_noise"] = float(r["gap_before_mm"]) / float(
                    r["noise_floor_mm"]
                )
    for (dev, night), (entries, ratio) in _calibration_models(cal).items():
        if dev == device_id:
            x = row(night)
            x["calibration_residual_to_noise"] = ratio
            est = [m for m in entries if m.get("estimated")]
            x["carried"] = "; ".join(f"{m['key']} {_text_of(m)} ({m.get('night')})" for m in est)
            x["carried_keys"] = ", ".join(m["key"] for m in est)
    if ver is not None and ver.height and "expanded_u_error_mm" in ver.columns:
        v = (
            ver.filter((pl.col("device_id") == device_id) & (pl.col("expanded_u_error_mm") > 0))
            .with_columns(e=pl.col("error_mm").abs() / pl.col("expanded_u_error_mm"))
            .sort("e", descending=True)
        )
        for r in v.unique("night", keep="first").iter_rows(named=True):
            row(r["night"]).update(
                verification_e_over_u=float(r["e"]), verification_error_um=float(r["error_mm"]) * 1e3
            )
    schema = {
        "night": pl.Utf8,
        "pooled_gap_to_noise": pl.Float64,
        "calibration_residual_to_noise": pl.Float64,
        "verification_e_over_u": pl.Float64,
        "verification_error_um": pl.Float64,
        "carried": pl.Utf8,
        "carried_keys": pl.Utf8,
    }
    return pl.DataFrame([rows[k] for k in sorted(rows)], schema=schema)


def _text_of(entry: dict) -> str:
    """Return a carried device-model entry's values in plain words: ``tau_s = 1.19 ± 0.02 ms``."""
    return html.unescape(
        _parameters_text(
            entry["key"].split("@")[0], json.dumps(entry.get("values") or {}), entry.get("u") or {}
        )
    )


def _wrap_carried(entry: str) -> str:
    """``channel_delay@2 tau_s = 1.19 ± 0.02 ms (2026-11-23)`` on three lines (key, values, night)."""
    key, _, rest = entry.partition(" ")
    values, _, night = rest.rpartition(" (")
    return f"{key}\n{values}\n(estimated {night}" if night else entry


def plot_device_model_gap(hist: pl.DataFrame, device_id: str) -> Figure:
    """Plot the gaps of one device over its nights.

    Return the gaps of one device over its nights (:func:`device_model_history`), the nights from which
    its calibrations carried other effects marked by a dashed line and what they carried there (a
    new estimate of the same effects is no change of the model).

    Top: the pooled examination's gap and the calibration's residual, each over its noise floor
    (1 = the noise). Bottom: the largest |verification error| / U of the night (1 = at the limit
    of its expanded uncertainty).
    """
    nights = hist["night"].to_list()
    x = np.arange(len(nights))
    fig = Figure(figsize=(8.0, 5.0), layout="constrained")
    ax_g, ax_v = fig.subplots(2, 1, sharex=True, height_ratios=(3, 2))
    for col, mk, name in (
        ("pooled_gap_to_noise", "o", "pooled examination: gap / noise floor"),
        ("calibration_residual_to_noise", "s", "calibration: residual / noise floor"),
    ):
        y = hist[col].cast(pl.Float64).fill_null(float("nan")).to_numpy()
        ax_g.plot(x, y, mk + "-", ms=6, label=name)
    ax_g.axhline(1.0, color="k", lw=1)
    ax_g.set_ylabel("rms / noise floor")
    ratios = hist.select(
        pl.col("pooled_gap_to_noise", "calibration_residual_to_noise").cast(pl.Float64)
    ).to_numpy()
    top = float(np.nanmax(np.r_[1.0, ratios.astype(float).ravel()]))
    ax_g.set_ylim(0.0, 1.45 * top)  # room above the points for the legend; the model's labels sit low
    ax_g.grid(alpha=0.3)
    e = hist["verification_e_over_u"].cast(pl.Float64).fill_null(float("nan")).to_numpy()
    ax_v.plot(x, e, "D", color="C2", ms=6, label="largest |E| / U of the night's verifications (label: E)")
    for xi, ei, err in zip(x, e, hist["verification_error_um"].to_list()):
        if np.isfinite(ei) and err is not None:
            ax_v.annotate(
                f"{err:+.2f} µm", (xi, ei), xytext=(6, 4), textcoords="offset points", fontsize=7, color="C2"
            )
    ax_v.axhline(1.0, color="C3", ls=":", lw=1)
    ax_v.set_ylabel("|E| / U")
    ax_v.set_ylim(bottom=0.0, top=max(1.3, float(np.nanmax(e)) * 1.15 if np.isfinite(e).any() else 1.3))
    ax_v.grid(alpha=0.3)
    carried, keys = hist["carried"].fill_null("").to_list(), hist["carried_keys"].fill_null("").to_list()
    for i in range(len(nights)):
        if keys[i] != (keys[i - 1] if i else ""):
            for ax in (ax_g, ax_v):
                ax.axvline(i - 0.5, color="C1", ls="--", lw=1.2)
            right = i >= len(nights) / 2  # the label on the side with room
            text = "device model from here:\n" + (
                "\n".join(_wrap_carried(c) for c in carried[i].split("; ")) or "none"
            )
            ax_g.annotate(
                text,
                (i - 0.55 if right else i - 0.45, 0.04),
                xycoords=("data", "axes fraction"),
                fontsize=7,
                va="bottom",
                ha="right" if right else "left",
                color="C1",
                bbox=_LABEL_BOX,
            )
    ax_g.legend(fontsize=7, loc="upper left", framealpha=0.85, ncols=2)
    ax_v.legend(fontsize=7, loc="upper right", framealpha=0.85)
    ax_v.set_xlim(-0.5, max(len(nights) - 0.5, 0.5))
    _xticks(ax_v, nights)
    ax_g.set_title(f"{device_id}: gaps against the noise, and the device model carried", fontsize=10)
    return fig


def _part_values(df: pl.DataFrame) -> tuple[np.ndarray, np.ndarray, bool]:
    """(diameter [mm], U (k=2) = 2u [mm], at 20 degC?) of diameter rows: at 20 °C where the row has it."""
    d = df["diameter_mm"].cast(pl.Float64)
    u = (
        df["u_diameter_mm"].cast(pl.Float64)
        if "u_diameter_mm" in df.columns
        else pl.Series([None] * df.height, dtype=pl.Float64)
    )
    at20 = "diameter_20_mm" in df.columns and df["diameter_20_mm"].drop_nulls().len() == df.height > 0
    if at20:
        d = df["diameter_20_mm"].cast(pl.Float64)
        if "u_diameter_20_mm" in df.columns:
            u = df["u_diameter_20_mm"].cast(pl.Float64)
    return d.fill_null(float("nan")).to_numpy(), 2.0 * u.fill_null(0.0).to_numpy(), at20


def plot_diameters(dia: pl.DataFrame, artifact_id: str) -> Figure:
    """Diameters of one part, one panel per feature: each scan with U (k=2) error bars, mean line.

    ``dia`` has the ``diameters`` columns; rows of other parts are ignored. Diameters at 20 °C
    (``diameter_20_mm``, ``u_diameter_20_mm``) where every row has them, else as measured; error
    bars U = 2u. The nominal (``nominal_mm``, see :func:`update_report`) is a dashed line and the
    tolerance band (``tolerance_mm``) shaded where known. The x axis is the measurement order,
    labelled with night and scan.
    """
    df = dia.filter(pl.col("artifact_id") == artifact_id)
    features = sorted(df["feature"].fill_null("").unique().to_list())
    nc = min(len(features), 3) or 1
    nr = -(-max(len(features), 1) // nc)
    most = max([df.filter(pl.col("feature").fill_null("") == f).height for f in features] + [1])
    panel_w = min(max(3.8, 0.42 * most), 12.0 / nc)
    fig = Figure(figsize=(panel_w * nc + 0.8, 3.2 * nr + 0.8), layout="constrained")
    axes = fig.subplots(nr, nc, squeeze=False)
    where = "as measured"
    for k, feat in enumerate(features):
        ax = axes[k // nc][k % nc]
        sub = df.filter(pl.col("feature").fill_null("") == feat)
        y, big_u, at20 = _part_values(sub)
        where = "at 20 °C" if at20 else where
        x = np.arange(sub.height)
        ax.errorbar(x, y, yerr=big_u, fmt="o", ms=4, capsize=3, color="C0", label="U (k=2)")
        if sub.height:
            ax.axhline(float(np.nanmean(y)), color="k", lw=0.8, label="mean")
        nom = (
            sub["nominal_mm"].drop_nulls() if "nominal_mm" in sub.columns else pl.Series([], dtype=pl.Float64)
        )
        if nom.len():
            n0 = float(nom[0])
            ax.axhline(n0, color="C2", ls="--", lw=1, label="nominal")
            tol = sub["tolerance_mm"].drop_nulls() if "tolerance_mm" in sub.columns else nom.clear()
            if tol.len():
                ax.axhspan(n0 - float(tol[0]), n0 + float(tol[0]), color="C2", alpha=0.12, label="tolerance")
        ax.set_title(f"feature {feat or '?'} (n={sub.height})", fontsize=9)
        ax.set_ylabel(f"diameter {where} [mm]", fontsize=8)
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
        ax.tick_params(axis="y", labelsize=7)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, loc="best")
        ax.set_xlim(-0.5, max(sub.height - 0.5, 0.5))
        _xticks(ax, _labels(sub))
    for k in range(len(features), nr * nc):
        axes[k // nc][k % nc].set_visible(False)
    fig.suptitle(f"part {artifact_id}: diameters {where} (error bars: U (k=2))", fontsize=10)
    return fig


def _png_bytes(fig: Figure) -> bytes:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, metadata=PNG_META)
    return buf.getvalue()


# --------------------------------------------------------------------------- data


def load_tables(results_root: str | os.PathLike) -> dict[str, pl.DataFrame]:
    """Return the catalog tables (and the ``suspect_measurements`` view when present) as polars frames."""
    con = catalog.open_catalog(results_root, read_only=True)
    try:
        out = {}
        for t in catalog.SCHEMA:
            out[t] = con.sql(f"SELECT * FROM {t} ORDER BY {_ORDER.get(t, '1')}").pl()
        if "verifications" in out and "scans" in out:
            # time order within a night: by the scan's start
            out["verifications"] = (
                out["verifications"]
                .join(out["scans"].select("scan_id", "started_at"), on="scan_id", how="left")
                .sort("device_id", "night", "started_at", "scan_id", nulls_last=True)
            )
        views = {
            r[0] for r in con.execute("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()
        }
        if "suspect_measurements" in views:
            out["suspect_measurements"] = con.sql("SELECT * FROM suspect_measurements").pl()
        return out
    finally:
        con.close()


# --------------------------------------------------------------------------- HTML

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;
     margin:0;color:#222;background:#fafafa}
header{background:#1f3b57;color:#fff;padding:14px 24px}
header h1{margin:0;font-size:22px} header p{margin:4px 0 0;font-size:13px;opacity:.85}
nav{position:sticky;top:0;background:#e9eef3;padding:8px 24px;border-bottom:1px solid #ccd;
    font-size:14px;z-index:2}
nav a{margin-right:16px;color:#1f3b57;text-decoration:none;font-weight:600}
main{padding:0 24px 40px;max-width:1300px}
section{margin-top:28px} h2{border-bottom:2px solid #1f3b57;padding-bottom:4px} h3{margin-bottom:6px}
table{border-collapse:collapse;font-size:12px;margin:8px 0 16px;background:#fff}
th,td{border:1px solid #ccd;padding:3px 7px;text-align:left;vertical-align:top}
th{background:#eef2f6} td.num{text-align:right;font-variant-numeric:tabular-nums}
tr.fail td{background:#fde8e8} .pass{color:#1a7f37;font-weight:600} .fail{color:#c62828;font-weight:600}
img{max-width:100%;border:1px solid #dde;background:#fff;margin:6px 0}
.empty{color:#777;font-style:italic} .note{font-size:13px;color:#444}
code{background:#eef;padding:0 3px}
tr.warn td{background:#fff6dd} .warn{color:#8a5a00;font-weight:600}
.night{background:#fff;border:1px solid #ccd;border-left:4px solid #c62828;padding:4px 14px 8px;margin:10px 0}
.night.quiet{border-left-color:#1a7f37} .night h3{margin:6px 0} .night ul{margin:4px 0 6px;padding-left:20px}
.night li{margin:3px 0;font-size:13px} .action{color:#444;font-size:12px}
a.plot{display:inline-block}
@media print{
 body{background:#fff;color:#000;font-size:10pt} nav{display:none}
 header{background:none;color:#000;border-bottom:2px solid #000;padding:0 0 6px}
 main{padding:0;max-width:none} section{break-before:auto} h2,h3{break-after:avoid}
 table{font-size:8pt;break-inside:auto} tr,img,.night{break-inside:avoid}
 img{max-width:100%;border:none} a{color:#000;text-decoration:none}
 tr.fail td{background:#fde8e8 !important;-webkit-print-color-adjust:exact;print-color-adjust:exact}
}
"""


def _e(v: Any) -> str:
    return html.escape("" if v is None else str(v))


def _num(v: Any, digits: int = 6) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return ""
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def _um(v_mm: Any, decimals: int = 1) -> str:
    """Return a length in mm shown in µm with ``decimals`` decimals ("" when missing)."""
    if v_mm is None or not np.isfinite(float(v_mm)):
        return ""
    return f"{float(v_mm) * 1e3:.{decimals}f}"


def _temperature(t_c: Any, assumed: Any) -> str:
    """Return a temperature cell; an assumed one says so ("20 (assumed)")."""
    if assumed:
        base = "20" if t_c is None else _num(t_c, 4)
        return f'<span class="warn" title="no temperature recorded: 20 °C assumed">{base} (assumed)</span>'
    return _num(t_c, 4)


def _link(href: str | None, text: str) -> str:
    if not href:
        return _e(text)
    return f'<a href="{html.escape(href, quote=True)}">{_e(text)}</a>'


def _table(
    headers: list[str],
    rows: list[list[str]],
    row_classes: list[str] | None = None,
    num_cols: set[int] | None = None,
) -> str:
    """Return an HTML table; cells are already-escaped HTML."""
    num_cols = num_cols or set()
    out = ["<table><thead><tr>", *(f"<th>{_e(h)}</th>" for h in headers), "</tr></thead><tbody>"]
    for i, r in enumerate(rows):
        cls = f' class="{row_classes[i]}"' if row_classes and row_classes[i] else ""
        cells = "".join(
            f'<td class="num">{c}</td>' if j in num_cols else f"<td>{c}</td>" for j, c in enumerate(r)
        )
        out.append(f"<tr{cls}>{cells}</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _img(href: str, png: bytes, alt: str) -> str:
    """Return a PNG embedded as a base64 ``data:`` image (the page stands alone), linked to its file."""
    data = base64.b64encode(png).decode("ascii")
    return (
        f'<a class="plot" href="{html.escape(href, quote=True)}">'
        f'<img src="data:image/png;base64,{data}" alt="{_e(alt)}"></a>'
    )


def _rel(results_root: Path, path: str | None) -> str | None:
    """Return a relative link to ``path`` (relative to results_root, or absolute inside it) if it exists."""
    if not path:
        return None
    if not os.path.isabs(path) and ".." not in path and "\\" not in path:  # the usual case, without pathlib
        return path if os.path.exists(os.path.join(results_root, path)) else None
    p = Path(path)
    full = p if p.is_absolute() else results_root / p
    if not full.exists():
        return None
    try:
        return full.resolve().relative_to(results_root.resolve()).as_posix()
    except ValueError:
        return None


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


# --------------------------------------------------------------------------- what changed


@functools.lru_cache(maxsize=1)
def _code_fingerprint() -> str:
    """Return the digest of this module's source and the plotting libraries.

    Return the digest of this module's source and the plotting libraries (a change re-renders every
    page).
    """
    import matplotlib

    h = hashlib.sha256(Path(__file__).read_bytes())
    h.update(f"matplotlib {matplotlib.__version__} polars {pl.__version__}".encode())
    return h.hexdigest()[:16]


def frame_fingerprint(df: pl.DataFrame) -> str:
    """SHA-256 (16 hex) of a frame's columns, types and rows in order (same polars version)."""
    h = hashlib.sha256(repr([(c, str(t)) for c, t in df.schema.items()]).encode())
    if df.height and df.width:
        h.update(df.hash_rows().to_numpy().tobytes())
    return h.hexdigest()[:16]


_MONTH = "coalesce(strftime(CAST({t}night AS DATE), '%Y-%m'), 'undated')"


def _month_sql(alias: str = "") -> str:
    return _MONTH.format(t=f"{alias}." if alias else "")


#: What a month's page shows, per source: (SQL of its rows with a ``_m`` month column).
_MONTH_ROWS = {
    "scans": "SELECT {m} AS _m, t.* FROM scans t",
    "calibrations": "SELECT {m} AS _m, t.* FROM calibrations t",
    # a calibration's links to scans of its own month (a rod's nominal geometry is linked to the
    # rod's scans of every later night: those would make its month's page change every night)
    "calibration_scans": (
        "SELECT c._m, t.* FROM calibration_scans t JOIN (SELECT DISTINCT calibration_id, {mc} AS _m "
        "FROM calibrations c) c USING (calibration_id) LEFT JOIN (SELECT scan_id, min({ms}) AS _sm "
        "FROM scans s GROUP BY scan_id) s USING (scan_id) WHERE s._sm IS NULL OR s._sm = c._m"
    ),
    "verifications": "SELECT {m} AS _m, t.* FROM verifications t",
    "pooled_findings": "SELECT {m} AS _m, t.* FROM pooled_findings t",
    "calibration_drift": "SELECT {m} AS _m, t.* FROM calibration_drift t",
    # with the part's nominal (artifacts.nominal_diameter_mm) when the part has one feature:
    # the catalog does not hold feature nominals
    "diameters": (
        "SELECT {m} AS _m, t.*, a.nominal_mm AS artifact_nominal_mm FROM diameters t LEFT JOIN "
        "(SELECT artifact_id, any_value(nominal_diameter_mm) AS nominal_mm FROM artifacts "
        "WHERE artifact_id IN (SELECT artifact_id FROM diameters GROUP BY artifact_id "
        "HAVING count(DISTINCT feature) <= 1) GROUP BY artifact_id) a ON a.artifact_id = t.artifact_id"
    ),
    # the lifecycle's events of measured calibrations (saved query calibration_status_history: one
    # definition for the report, `borescan trace` and the user's queries); valid -> "made"
    "calibration_events": (
        "SELECT {m} AS _m, t.night, CASE t.status WHEN 'valid' THEN 'made' ELSE t.status END AS event, "
        "t.calibration_id, t.device_id, t.other_id FROM calibration_status_history t "
        "WHERE t.calibration_id IS NOT NULL AND coalesce(t.method, '') <> 'nominal' "
        "AND t.status IN ('valid', 'superseded', 'expired')"
    ),
    "findings": "SELECT {m} AS _m, t.* FROM findings t",
    "quarantine": "SELECT {m} AS _m, t.* FROM quarantine t",
    "suspect_measurements": "SELECT {m} AS _m, t.* FROM suspect_measurements t",
}

#: Row order of each table on a page.
_ORDER = {
    "scans": "night, started_at, scan_id",
    "calibration_events": "night, device_id, event, calibration_id",
    "calibrations": "device_id, valid_from, calibration_id, channel",
    "calibration_scans": "calibration_id, scan_id",
    "diameters": "artifact_id, feature, night, scan_id",
    "verifications": "device_id, night, scan_id",
    "findings": "scan_id, effect, channel",
    "pooled_findings": "device_id, night, term",
    "calibration_drift": "device_id, night, channel, parameter",
    "quarantine": "scan_id, stage",
    "suspect_measurements": "device_id, night, scan_id, feature",
    "artifacts": "artifact_id",
    "scan_files": "scan_id, file",
}


def _sources(con) -> dict[str, str]:
    """Source name -> SQL of its rows with a ``_m`` month column, for the sources the catalog has."""
    have = {
        r[0]
        for r in con.execute(
            "SELECT table_name FROM duckdb_tables() WHERE schema_name = 'main' UNION "
            "SELECT view_name FROM duckdb_views() WHERE NOT internal AND schema_name = 'main'"
        ).fetchall()
    }
    needs = {"calibration_events": {"calibration_status_history"}, "diameters": {"diameters", "artifacts"}}
    return {
        name: sql.format(m=_month_sql("t"), mc=_month_sql("c"), ms=_month_sql("s"))
        for name, sql in _MONTH_ROWS.items()
        if needs.get(name, {name}) <= have
    }


def month_fingerprints(con) -> dict[str, str]:
    """Month (``YYYY-MM`` of the night, or ``undated``) -> fingerprint of every row its page shows.

    One aggregate query per table (row count and the sum of DuckDB row hashes per month), so
    finding which months changed costs milliseconds even for years of nights.
    """
    parts: dict[str, list] = {}
    for name, sql in _sources(con).items():
        for m, n, h in con.execute(
            f"SELECT _m, count(*), sum(hash(q)::HUGEINT) FROM ({sql}) q GROUP BY _m"
        ).fetchall():
            parts.setdefault(m, []).append((name, n, str(h)))
    code = _code_fingerprint()
    return {
        m: hashlib.sha256(json.dumps([code, sorted(v)]).encode()).hexdigest()[:16]
        for m, v in sorted(parts.items())
    }


def _month_tables(con, month: str) -> dict[str, pl.DataFrame]:
    """Return the rows of one month, per table, in page order (verifications with their scan's start)."""
    out = {}
    srcs = _sources(con)
    for name, sql in srcs.items():
        order, drop = _ORDER[name], "_m"
        if name == "verifications" and "scans" in srcs:  # time order within a night: by the scan's start
            sql = (
                "SELECT "
                + _month_sql("t")
                + " AS _m, t.*, s.started_at AS _start FROM verifications t LEFT JOIN "
                "(SELECT DISTINCT ON (scan_id, night) scan_id, night, started_at FROM scans) s "
                "ON s.scan_id = t.scan_id AND s.night IS NOT DISTINCT FROM t.night"
            )
            order, drop = "device_id, night, _start NULLS LAST, scan_id", "_m, _start"
        out[name] = con.sql(
            f"SELECT * EXCLUDE ({drop}) FROM ({sql}) q WHERE _m = ? ORDER BY {order}", params=[month]
        ).pl()
    return out


def _totals(con) -> dict[str, Any]:
    """Return counts over the whole history for the page header."""
    first, last, n_scans, n_q = con.execute(
        "SELECT min(night)::VARCHAR, max(night)::VARCHAR, count(*), count(*) FILTER (status = 'quarantined') "
        "FROM scans"
    ).fetchone()
    return {
        "first": first,
        "last": last,
        "scans": n_scans,
        "quarantined": n_q,
        "calibrations": con.execute("SELECT count(DISTINCT calibration_id) FROM calibrations").fetchone()[0],
        "diameters": con.execute("SELECT count(*) FROM diameters").fetchone()[0],
        "verifications": con.execute("SELECT count(*) FROM verifications").fetchone()[0],
    }


def _counts(t: dict[str, pl.DataFrame]) -> dict[str, Any]:
    """Return the header's counts over one page's rows."""
    sc = t["scans"]
    nights = sorted({str(n) for n in sc["night"].drop_nulls().to_list()})
    return {
        "first": nights[0] if nights else None,
        "last": nights[-1] if nights else None,
        "scans": sc.height,
        "quarantined": sc.filter(pl.col("status") == "quarantined").height,
        "calibrations": t["calibrations"]["calibration_id"].drop_nulls().n_unique(),
        "diameters": t["diameters"].height,
        "verifications": t["verifications"].height,
    }


def _month_summary(con) -> list[tuple[str, int, int, int]]:
    """(month, nights, scans, quarantined) of every month with scans."""
    return con.execute(
        f"SELECT {_month_sql()} AS m, count(DISTINCT night), count(*), count(*) FILTER (status = "
        "'quarantined') "
        "FROM scans GROUP BY m ORDER BY m"
    ).fetchall()


def _memory_catalog(tables: dict[str, pl.DataFrame]):
    """Return an in-memory DuckDB with the given frames as catalog tables (missing ones empty, typed)."""
    con = duckdb.connect()
    con.execute("SET TimeZone = 'UTC'")
    for name, cols in catalog.SCHEMA.items():
        df = tables.get(name)
        if df is None or df.width == 0:
            con.execute(TABLES[name].ddl())
            continue
        con.register("_in", df)
        select = [
            f"CAST({catalog._q(c)} AS {t}) AS {catalog._q(c)}"
            if c in df.columns
            else f"CAST(NULL AS {t}) AS {catalog._q(c)}"
            for c, t in cols.items()
        ]
        select += [catalog._q(c) for c in df.columns if c not in cols]
        con.execute(f"CREATE TABLE {name} AS SELECT {', '.join(select)} FROM _in")
        con.unregister("_in")
    for name, df in tables.items():
        if name not in catalog.SCHEMA and df is not None:
            con.register("_in", df)
            con.execute(f"CREATE TABLE {catalog._q(name)} AS SELECT * FROM _in")
            con.unregister("_in")
    for qname, (_desc, sql) in catalog.saved_queries().items():
        if qname not in tables:
            with contextlib.suppress(duckdb.Error):  # a query over tables not given: no view
                con.execute(f"CREATE VIEW {catalog._q(qname)} AS {catalog._view_sql(sql)}")
    return con


# --------------------------------------------------------------------------- HTML


class _PlotCache:
    """Plots of one month folder: file name -> fingerprint of its input (``plots.json``).

    A plot whose input and code are unchanged is not drawn again.
    """

    def __init__(self, folder: Path, use: bool = True):
        self.folder = folder
        self.file = folder / "plots.json"
        self.old: dict[str, str] = {}
        if use and self.file.is_file():
            with contextlib.suppress(ValueError):
                self.old = json.loads(self.file.read_text())
        self.new: dict[str, str] = {}
        self.drawn = 0

    def get(self, fname: str, key: str, draw) -> bytes:
        """Return the PNG ``fname``: drawn when its key changed or the file is gone, else read back."""
        if self.old.get(fname) != key or not (self.folder / fname).is_file():
            png = _png_bytes(draw())
            atomic_write_bytes(self.folder / fname, png)
            self.drawn += 1
        else:
            png = (self.folder / fname).read_bytes()
        self.new[fname] = key
        return png

    def save(self) -> None:
        """Record the plots of the page just written and remove the ones it no longer shows."""
        for f in self.folder.glob("*.png"):
            if f.name not in self.new:
                f.unlink()
        atomic_write_text(self.file, json.dumps(self.new, indent=1, sort_keys=True) + "\n")


def _verdict_is(verdict: str) -> pl.Expr:
    """Return the rows whose ``conformity`` statement starts with ``verdict``.

    The statement is split by :func:`borescan.decision.split_verdict`.
    """
    return pl.col("conformity").fill_null("").str.to_lowercase().str.starts_with(verdict)


def _verdict_cell(
    conformity: str | None, passed: bool | None, labels: tuple[str, str] = ("passed", "FAILED")
) -> tuple[str, str]:
    """Return (HTML, row class) of a verdict.

    The stage's statement under the decision rule (``conformity``: "conforms", "does not conform" or "cannot
    decide", then U, T, the rule and its guard band); a row without one (an older catalog) falls back to its
    pass/fail, shown as ``labels``.
    """
    verdict, detail = split_verdict(conformity)
    if verdict is None:
        if passed is None:
            return "", ""
        return (
            (f'<span class="pass">{labels[0]}</span>', "")
            if passed
            else (f'<span class="fail">{labels[1]}</span>', "fail")
        )
    cls = {CONFORMS: "pass", DOES_NOT_CONFORM: "fail", CANNOT_DECIDE: "warn"}[verdict]
    html = f'<span class="{cls}">{_e(verdict.upper() if cls != "pass" else verdict)}</span>'
    return html + (f"<br><small>{_e(detail)}</small>" if detail else ""), ("" if cls == "pass" else cls)


class _Builder:
    """The sections of one page over ``tables`` (a month's rows).

    ``up``: the page's path back to the results folder ("" for ``report.html``, ``"../../"`` for
    a month page); ``plots``: the month's plot folder as seen from the page.
    """

    def __init__(
        self, root: Path, tables: dict[str, pl.DataFrame], cache: _PlotCache, up: str = "", plots: str = ""
    ):
        self.root = root
        self.t = tables
        self.cache = cache
        self.up = up
        self.plots = plots
        self.code = _code_fingerprint()

    def link(self, path: str | None) -> str | None:
        rel = _rel(self.root, path)
        return None if rel is None else self.up + rel

    def figure(self, plot, data: pl.DataFrame, key: str, name: str, alt: str, *args) -> str:
        """Draw ``plot(data, key, *args)`` as ``<month>/<name>.png`` when its input changed.

        ``plot(data, key, *args)`` as ``<month>/<name>.png``, drawn only when its input changed;
        embedded in the page as a ``data:`` image that links to the PNG file.
        """
        fname = _safe(name) + ".png"
        fp = hashlib.sha256(
            f"{self.code} {plot.__name__} {key} {args} {frame_fingerprint(data)}".encode()
        ).hexdigest()[:16]
        png = self.cache.get(fname, fp, lambda: plot(data, key, *args))
        return _img(self.plots + fname, png, alt)

    # ---------------------------------------------------------------- sections
    def calibration(self) -> str:
        cal = self.t["calibrations"]
        if cal.height == 0:
            return _EMPTY["calibration"]
        out = []
        cs = self.t["calibration_scans"]
        scans_of = (
            {}
            if cs.height == 0
            else dict(cs.group_by("calibration_id", maintain_order=True).agg(pl.col("scan_id")).iter_rows())
        )
        scans = self.t.get("scans")
        if (
            scans is not None
            and {"scan_id", "started_at"} <= set(scans.columns)
            and "started_at" not in cal.columns
        ):
            cal = cal.join(
                scans.select("scan_id", "started_at").unique("scan_id", keep="first"),
                on="scan_id",
                how="left",
            )
        ver = self.t.get("verifications")
        failed = failed_calibration_ids(ver) if ver is not None and "passed" in ver.columns else set()
        roles = calibration_roles(cal, failed)  # the same order as the measure stage and `borescan status`
        for dev in sorted(cal["device_id"].drop_nulls().unique().to_list()):
            out.append(f"<h3>Device {_e(dev)}</h3>")
            mine = cal.filter(pl.col("device_id") == dev)
            if mine.filter(
                pl.col("method") != "nominal"
            ).height:  # design geometry does not trend: table only
                out.append(
                    self.figure(
                        plot_calibration_trends,
                        mine,
                        dev,
                        f"calibration_{dev}",
                        f"calibration parameters of {dev}",
                    )
                )
            rows = []
            per = order_calibrations(mine.unique("calibration_id", keep="first", maintain_order=True))
            for r in per.iter_rows(named=True):
                scans = scans_of.get(r["calibration_id"], [])
                cert = r.get("certificate_path")
                pdf = self.link(cert)
                cj = catalog.certificate_json_path(self.root, cert) if cert else None
                json_link = self.link(str(cj)) if cj else None
                links = " ".join(
                    x
                    for x in (
                        _link(pdf, "certificate") if pdf else (_e(cert) + " (missing)" if cert else ""),
                        _link(json_link, "json") if json_link else "",
                    )
                    if x
                )
                rows.append(
                    [
                        _e(r["calibration_id"]),
                        _e(r.get("valid_from")),
                        _e(r.get("recalibration_due")),
                        _e(r.get("method")),
                        _e(", ".join(scans)),
                        _e(roles.get(r["calibration_id"], "")),
                        links,
                        f"<code>{_e((r.get('certificate_sha256') or '')[:16])}</code>",
                    ]
                )
            out.append(
                _table(
                    [
                        "calibration",
                        "valid from",
                        "recalibration due",
                        "method",
                        "scans",
                        "in the history",
                        "certificate",
                        "certificate.json sha256",
                    ],
                    rows,
                )
            )
            out.append(_rho_sign_notes(mine))
        return "".join(out)

    def verification(self) -> str:
        ver = self.t["verifications"]
        if ver.height == 0:
            return _EMPTY["verification"]
        out = [
            '<p class="note">Individuals chart of the verification error (measured − certified ring-gauge '
            "diameter), one per device and gauge, with limits mean ± 2.66·MR̄ (± 3σ̂, σ̂ = MR̄/1.128); "
            "moving-range chart with UCL = 3.267·MR̄. Ringed points break a Western Electric run rule: "
            + "; ".join(f"rule {k}, {v}" for k, v in RUN_RULES.items())
            + ". Error bars U (k=2).</p>"
        ]
        if "artifact_id" not in ver.columns:
            ver = ver.with_columns(pl.lit(None, dtype=pl.Utf8).alias("artifact_id"))
        for dev in sorted(ver["device_id"].drop_nulls().unique().to_list()):
            mine = ver.filter(pl.col("device_id") == dev)
            gauges = sorted(mine["artifact_id"].fill_null("").unique().to_list())
            for gauge in gauges:
                sub = mine.filter(pl.col("artifact_id").fill_null("") == gauge)
                out.append(self._gauge_chart(dev, gauge or None, sub, several=len(gauges) > 1))
        return "".join(out) + self._suspect()

    def _gauge_chart(self, dev: str, gauge: str | None, sub: pl.DataFrame, several: bool) -> str:
        lim = control_limits(sub["error_mm"].to_numpy())
        out = [f"<h3>Device {_e(dev)}" + (f" · gauge {_e(gauge)}" if gauge else "") + "</h3>"]
        name = f"control_{dev}_{gauge}" if several and gauge else f"control_{dev}"
        if gauge:
            out.append(
                self.figure(plot_control_chart, sub, dev, name, f"control chart of {dev} on {gauge}", gauge)
            )
        else:
            out.append(self.figure(plot_control_chart, sub, dev, name, f"control chart of {dev}"))
        out.append(
            _table(
                ["n", "mean [mm]", "MR̄ [mm]", "UCL [mm]", "LCL [mm]", "MR UCL [mm]"],
                [
                    [
                        str(sub.height),
                        _num(lim["mean"]),
                        _num(lim["mr_bar"]),
                        _num(lim["ucl"]),
                        _num(lim["lcl"]),
                        _num(lim["mr_ucl"]),
                    ]
                ],
                num_cols={0, 1, 2, 3, 4, 5},
            )
        )
        rules = run_rules(sub["error_mm"].to_numpy(), lim["mean"], lim["mr_bar"] / MR_D2)
        rows, classes = [], []
        for i, r in enumerate(sub.iter_rows(named=True)):
            ok = r.get("passed")
            verdict_html, verdict_class = _verdict_cell(r.get("conformity"), ok)
            broke = ", ".join(str(k) for k in RUN_RULES if rules[k][i])
            u = r.get("u_error_mm")
            rows.append(
                [
                    _e(r.get("night")),
                    _e(r["scan_id"]),
                    _e(r.get("calibration_id")),
                    _num(r.get("measured_mm"), 9),
                    _num(r.get("certified_mm"), 9),
                    _um(r.get("error_mm")),
                    _um(2.0 * u if u is not None else None),
                    _um(r.get("tolerance_mm")),
                    _temperature(r.get("temperature_c"), r.get("temperature_assumed")),
                    _e(broke),
                    verdict_html,
                ]
            )
            classes.append(verdict_class or ("warn" if broke else ""))
        out.append(
            _table(
                [
                    "night",
                    "scan",
                    "calibration",
                    "measured at 20 °C [mm]",
                    "certified [mm]",
                    "error [µm]",
                    "U (k=2) [µm]",
                    "tolerance ± [µm]",
                    "temperature [°C]",
                    "run rules broken",
                    "verdict",
                ],
                rows,
                classes,
                num_cols={3, 4, 5, 6, 7, 8},
            )
        )
        return "".join(out)

    def _suspect(self) -> str:
        out = []
        sus = self.t.get("suspect_measurements")
        out.append("<h3>Measurements put in doubt by a failed verification</h3>")
        if sus is None or sus.height == 0:
            out.append(
                '<p class="empty">None: no measurement used a calibration that later failed verification.</p>'
            )
        else:
            rows = [
                [
                    _e(r["night"]),
                    _e(r["scan_id"]),
                    _e(r["artifact_id"]),
                    _e(r["feature"]),
                    _num(r["diameter_mm"], 9),
                    _e(r["calibration_id"]),
                    _e(r["failed_verification_scan_id"]),
                    _e(r["failed_night"]),
                    _num(r["failed_error_mm"]),
                ]
                for r in sus.iter_rows(named=True)
            ]
            out.append(
                _table(
                    [
                        "night",
                        "scan",
                        "part",
                        "feature",
                        "diameter [mm]",
                        "calibration",
                        "failed verification",
                        "on",
                        "its error [mm]",
                    ],
                    rows,
                    ["fail"] * len(rows),
                    num_cols={4, 8},
                )
            )
        return "".join(out)

    def parts(self) -> pl.DataFrame:
        """Return the month's diameter rows with nominal, tolerance and verdict.

        Return the month's diameter rows with ``nominal_mm`` (the row's ``nominal_diameter_mm``, else the
        part's from ``artifacts``), ``tolerance_mm`` (the row's, when the measure stage records one),
        ``deviation_mm`` (at 20 °C where known, else as measured, minus the nominal) and
        ``in_tolerance`` (|deviation| <= tolerance; null without a tolerance).
        """
        dia = self.t["diameters"]
        cols = set(dia.columns)
        nominal = [
            pl.col(c).cast(pl.Float64) for c in ("nominal_diameter_mm", "artifact_nominal_mm") if c in cols
        ]
        value = pl.col("diameter_mm").cast(pl.Float64)
        if "diameter_20_mm" in cols:
            value = pl.coalesce(pl.col("diameter_20_mm").cast(pl.Float64), value)
        dia = dia.with_columns(
            (pl.coalesce(nominal) if nominal else pl.lit(None, dtype=pl.Float64)).alias("nominal_mm"),
            (
                pl.col("tolerance_mm").cast(pl.Float64)
                if "tolerance_mm" in cols
                else pl.lit(None, dtype=pl.Float64)
            ).alias("tolerance_mm"),
            value.alias("_value_mm"),
        )
        return dia.with_columns(
            (pl.col("_value_mm") - pl.col("nominal_mm")).alias("deviation_mm")
        ).with_columns((pl.col("deviation_mm").abs() <= pl.col("tolerance_mm")).alias("in_tolerance"))

    def _parts_table(self, df: pl.DataFrame) -> str:
        rows, classes = [], []
        for r in df.iter_rows(named=True):
            big_u, k = r.get("expanded_u_diameter_20_mm"), r.get("k")
            if big_u is None and r.get("u_diameter_mm") is not None:
                big_u, k = 2.0 * r["u_diameter_mm"], 2.0
            ok = r.get("in_tolerance")
            verdict, verdict_class = _verdict_cell(
                r.get("conformity"), ok, ("in tolerance", "OUT OF TOLERANCE")
            )
            rows.append(
                [
                    _e(r.get("night")),
                    _e(r.get("scan_id")),
                    _e(r["artifact_id"]),
                    _e(r.get("feature")),
                    _num(r.get("diameter_mm"), 9),
                    _temperature(r.get("temperature_c"), r.get("temperature_assumed")),
                    _num(r.get("diameter_20_mm"), 9),
                    _um(big_u, 2),
                    _num(k, 3),
                    _num(r.get("coverage_probability"), 4),
                    _num(r.get("nominal_mm"), 9),
                    _um(r.get("deviation_mm")),
                    _um(r.get("tolerance_mm")),
                    verdict,
                    _e(r.get("calibration_id")),
                ]
            )
            classes.append(verdict_class or ("warn" if r.get("temperature_assumed") else ""))
        return _table(
            [
                "night",
                "scan",
                "part",
                "feature",
                "diameter at T [mm]",
                "T [°C]",
                "diameter at 20 °C [mm]",
                "U [µm]",
                "k",
                "coverage",
                "nominal [mm]",
                "deviation [µm]",
                "tolerance ± [µm]",
                "verdict",
                "calibration",
            ],
            rows,
            classes,
            num_cols={4, 5, 6, 7, 8, 9, 10, 11, 12},
        )

    def diameters(self) -> str:
        dia = self.t["diameters"]
        if dia.height == 0:
            return _EMPTY["diameters"]
        dia = self.parts().with_columns(pl.col("artifact_id").fill_null("?"))
        out = [
            '<p class="note">Diameters as measured at the temperature T and brought to 20 °C (ISO 1); '
            "U is the "
            "expanded uncertainty of the diameter at 20 °C with its coverage factor k and coverage "
            "probability "
            '(U = 2u, k = 2 where the catalog has no budget). "(assumed)": no temperature was recorded, '
            "20 °C assumed. Deviation = diameter at 20 °C − nominal; the verdict needs a part tolerance.</p>"
        ]
        if dia["nominal_mm"].drop_nulls().len() == 0:
            out.append(
                '<p class="note">No nominal diameter in the catalog for these parts (feature nominals of '
                "scan.json are not recorded in the diameters table).</p>"
            )
        counts = dia.group_by("artifact_id", "feature").len().group_by("artifact_id").agg(pl.col("len").max())
        once = set(counts.filter(pl.col("len") < 2)["artifact_id"].to_list())
        if once:  # a single value per feature has no distribution: one table for all such parts
            single = dia.filter(pl.col("artifact_id").is_in(sorted(once))).sort(
                "artifact_id", "feature", "scan_id"
            )
            out.append(f"<h3>Parts measured once ({len(once)})</h3>")
            out.append(self._parts_table(single))
        for part in sorted(set(dia["artifact_id"].unique().to_list()) - once):
            sub = dia.filter(pl.col("artifact_id") == part)
            out.append(f"<h3>Part {_e(part)}</h3>")
            out.append(self.figure(plot_diameters, sub, part, f"diameters_{part}", f"diameters of {part}"))
            stats = (
                sub.group_by("feature")
                .agg(
                    pl.len().alias("n"),
                    pl.col("_value_mm").mean().alias("mean"),
                    pl.col("_value_mm").std().alias("sd"),
                    pl.col("_value_mm").min().alias("min"),
                    pl.col("_value_mm").max().alias("max"),
                )
                .sort("feature")
            )
            rows = [
                [
                    _e(r["feature"]),
                    str(r["n"]),
                    _num(r["mean"], 9),
                    _um(r["sd"], 2),
                    _num(r["min"], 9),
                    _num(r["max"], 9),
                ]
                for r in stats.iter_rows(named=True)
            ]
            out.append(
                _table(
                    ["feature", "n", "mean [mm]", "sd [µm]", "min [mm]", "max [mm]"],
                    rows,
                    num_cols={1, 2, 3, 4, 5},
                )
            )
            out.append(self._parts_table(sub))
        return "".join(out)

    def discrepancy(self) -> str:
        fnd = self.t["findings"]
        if fnd.height == 0:
            return _EMPTY["discrepancy"]
        out = [
            '<p class="note">Parameters: value ± u (standard uncertainty, k=1) in the effect\'s unit; '
            "gaps: rms "
            "of the residual before and after adding the named effect, against the readings' noise floor. "
            "<b>missing_effect</b>: the model misses the named effect (service the device if it persists); "
            "<b>ambiguous</b>: several named effects explain the data equally well, all listed; "
            "<b>no_missing_effect</b>: the residual is at the noise floor.</p>"
        ]
        rows, classes = [], []
        for (sid,), grp in fnd.group_by("scan_id", maintain_order=True):
            recs = grp.to_dicts()
            first = recs[0]
            uncertainties = self._finding_uncertainties(sid, recs)
            gap = self.link(f"discrepancy/{sid}/gap.png")
            fj = self.link(f"discrepancy/{sid}/findings.json")
            links = " ".join(
                x
                for x in (_link(gap, "gap.png") if gap else "", _link(fj, "findings.json") if fj else "")
                if x
            )
            verdict = first["verdict"]
            effects = []
            for r in recs:
                if not r.get("effect"):
                    continue
                where = f" on channel {r['channel']}" if r.get("channel") is not None else ""
                pars = _parameters_text(
                    r["effect"], r.get("parameters"), uncertainties.get((r["effect"], r.get("channel")), {})
                )
                effects.append(f"<b>{_e(r['effect'])}</b>{_e(where)}" + (f": {pars}" if pars else ""))
            note = _e(first.get("statement") or "") or _verdict_note(
                verdict, [r["effect"] for r in recs if r.get("effect")]
            )
            rows.append(
                [
                    _e(sid),
                    _e(first.get("night")),
                    f"<b>{_e(verdict)}</b>" + (f"<br>{note}" if note else ""),
                    "<br>".join(effects),
                    _um(first.get("gap_before_mm"), 2),
                    _um(first.get("gap_after_mm"), 2),
                    _um(first.get("noise_floor_mm"), 2),
                    links,
                ]
            )
            # flagged for a person only where the gap before stands above the noise floor (floor_ratio)
            visible = (first.get("gap_before_mm") or 0.0) > _FLOOR_RATIO * (
                first.get("noise_floor_mm") or 0.0
            )
            classes.append(
                ""
                if not visible
                else "fail"
                if verdict == "missing_effect"
                else "warn"
                if verdict == "ambiguous"
                else ""
            )
        out.append(
            _table(
                [
                    "scan",
                    "night",
                    "verdict",
                    "named effect, channel, parameters",
                    "gap before [µm rms]",
                    "gap after [µm rms]",
                    "noise floor [µm]",
                    "plots",
                ],
                rows,
                classes,
                num_cols={4, 5, 6},
            )
        )
        return "".join(out)

    def pooled(  # noqa: C901 (one branch per optional column of the report's pooled table)
        self,
    ) -> str:
        """Return the pooled examinations per device and night.

        Per device and night: the spindle scans examined together (borescan.discrepancy.pooled), the
        device model's effects, what the night's calibration carried of it with its residual against the
        noise floor, the gap against the noise floor, and the calibration drifts flagged.
        """
        pf = self.t.get("pooled_findings")
        dr = self.t.get("calibration_drift")
        if (pf is None or pf.height == 0) and (dr is None or dr.height == 0):
            return _EMPTY["pooled"]
        out = [
            '<p class="note">Each device\'s spindle scans of the night examined together: an effect one scan '
            "cannot separate (a delay at two speeds, an offset at two eccentricities) is named with "
            "the scans "
            "that carry it; effects of the device model (config <code>devices:</code>) are fitted with "
            "the base. "
            "Gap: rms residual before and after the named effects, against the noise floor. "
            "Parameters: value "
            "± u (k=1).</p>"
        ]
        if pf is not None and pf.height:
            rows, classes = [], []
            carried = _carried_by_calibrations(self.t.get("calibrations"))
            for (dev, night), grp in pf.group_by("device_id", "night", maintain_order=True):
                recs = grp.to_dicts()
                first = recs[0]
                named, model = [], []
                for r in recs:
                    if not r.get("effect"):
                        continue
                    u = _uncertainties(r.get("uncertainties"))
                    where = f" on channel {r['channel']}" if r.get("channel") is not None else ""
                    pars = _parameters_text(r["effect"], r.get("parameters"), u)
                    ev = f" (evidence: {_e(r['evidence_scans'])})" if r.get("evidence_scans") else ""
                    text = f"<b>{_e(r['effect'])}</b>{_e(where)}" + (f": {pars}" if pars else "")
                    (model if r.get("in_device_model") else named).append(
                        text + ("" if r.get("in_device_model") else ev)
                    )
                verdict = first.get("verdict") or ""
                absorbed = first.get("absorbed")
                note = f"<br>{_e(first['reason'])}" if verdict == "failed" and first.get("reason") else ""
                rows.append(
                    [
                        _e(night),
                        _e(dev),
                        f"<b>{_e(verdict)}</b>{note}",
                        "<br>".join(named) or "–",
                        "<br>".join(model) or "–",
                        carried.get((dev, str(night)), "–"),
                        _e(absorbed) if absorbed else "",
                        _um(first.get("gap_before_mm"), 2),
                        _um(first.get("gap_after_mm"), 2),
                        _um(first.get("noise_floor_mm"), 2),
                    ]
                )
                classes.append(
                    "fail"
                    if verdict in ("missing_effect", "failed")
                    else "warn"
                    if verdict == "ambiguous"
                    else ""
                )
            out.append(
                _table(
                    [
                        "night",
                        "device",
                        "verdict",
                        "named (value ± u)",
                        "in the device model",
                        "the night's calibration carried",
                        "what these scans cannot separate",
                        "gap before [µm rms]",
                        "gap after [µm rms]",
                        "noise floor [µm]",
                    ],
                    rows,
                    classes,
                    num_cols={7, 8, 9},
                )
            )
            for dev in sorted(pf["device_id"].drop_nulls().unique().to_list()):
                hist = device_model_history(pf, self.t.get("calibrations"), self.t.get("verifications"), dev)
                if hist.height >= 2:
                    out.append(
                        self.figure(
                            plot_device_model_gap,
                            hist,
                            dev,
                            f"devicemodel_{dev}",
                            f"gaps of {dev} against the noise and its device model over the nights",
                        )
                    )
        if dr is not None and dr.height:
            flagged = dr.filter(pl.col("flagged").fill_null(False))
            out.append(f"<h3>Calibration drift ({flagged.height} flagged of {dr.height} changes)</h3>")
            if flagged.height:
                unit = {"beta_rad": ("mrad", 1e3), "rho_mm": ("µm", 1e3), "d_b_mm": ("µm", 1e3)}
                rows = []
                for r in flagged.iter_rows(named=True):
                    name, f = unit.get(r["parameter"], ("", 1.0))
                    rows.append(
                        [
                            _e(r.get("night")),
                            _e(r["device_id"]),
                            _e(r["channel"]),
                            _e(r["parameter"]),
                            f"{r['change'] * f:+.3g} {name}",
                            f"{r['u_combined'] * f:.2g} {name}",
                            _num(r.get("change_over_u"), 3),
                            _e(r.get("explained_by") or "not explained"),
                            _e(r.get("calibration_id_after")),
                        ]
                    )
                out.append(
                    _table(
                        [
                            "night",
                            "device",
                            "channel",
                            "parameter",
                            "change",
                            "u (combined)",
                            "change / u",
                            "explained by",
                            "calibration",
                        ],
                        rows,
                        ["warn"] * len(rows),
                        num_cols={4, 5, 6},
                    )
                )
            else:
                out.append(
                    '<p class="empty">No change between consecutive calibrations beyond its limit.</p>'
                )
        return "".join(out)

    def _finding_uncertainties(self, scan_id: str, recs: list[dict] = ()) -> dict[tuple, dict[str, float]]:
        """Return the findings' uncertainties per (effect, channel).

        (effect, channel) -> {parameter: u}: the findings table's ``uncertainties`` column, else
        ``discrepancy/<scan>/findings.json`` (catalogs written before the column existed).
        """
        out = {
            (r.get("effect"), r.get("channel")): u
            for r in recs
            if (u := _uncertainties(r.get("uncertainties")))
        }
        if out:
            return out
        path = self.root / "discrepancy" / scan_id / "findings.json"
        try:
            named = json.loads(path.read_text()).get("named") or []
        except (OSError, ValueError, AttributeError):
            return {}
        return {
            (n.get("effect"), n.get("channel")): _uncertainties(n["uncertainties"])
            for n in named
            if isinstance(n, dict) and isinstance(n.get("uncertainties"), dict)
        }

    def papers(self) -> str:
        pdir = self.root / "papers"
        files = (
            sorted(p for p in pdir.rglob("*") if p.is_file() and p.suffix.lower() in (".png", ".csv"))
            if pdir.is_dir()
            else []
        )
        if not files:
            return '<p class="empty">No paper reproductions under papers/.</p>'
        out = []
        for f in files:
            rel = self.up + f.relative_to(self.root).as_posix()
            out.append(f"<h3>{_link(rel, f.relative_to(pdir).as_posix())}</h3>")
            if f.suffix.lower() == ".png":
                out.append(_img(rel, f.read_bytes(), f.name))
            else:
                try:
                    df = pl.read_csv(f, infer_schema_length=0)
                except Exception as err:  # a malformed CSV is shown as a note, not a crash
                    out.append(f'<p class="empty">unreadable CSV: {_e(err)}</p>')
                    continue
                shown = df.head(200)
                rows = [[_e(v) for v in r] for r in shown.iter_rows()]
                out.append(_table(list(df.columns), rows))
                if df.height > shown.height:
                    out.append(f'<p class="note">first {shown.height} of {df.height} rows</p>')
        return "".join(out)

    def quarantined(self) -> list[dict[str, Any]]:
        """Return every quarantined scan of the page.

        Every quarantined scan of the page (``scans`` status or ``quarantine`` rows): scan_id,
        night, device_id, kind, stages, reasons, class and action, in night and scan order.
        """
        sc = self.t["scans"].filter(pl.col("status") == "quarantined")
        q = self.t["quarantine"]
        scan_row = {(r["scan_id"], str(r["night"])): r for r in sc.iter_rows(named=True)}
        q_rows: dict[tuple, list[dict]] = {}
        for r in q.iter_rows(named=True):
            q_rows.setdefault((r["scan_id"], str(r["night"])), []).append(r)
        out = []
        for key in sorted(set(scan_row) | set(q_rows), key=lambda k: (k[1], k[0])):
            srow, qq = scan_row.get(key, {}), q_rows.get(key, [])
            reasons = [srow["reason"]] if srow.get("reason") else []
            reasons += [
                f"{r['file']}: {r['reason']}" for r in qq if f"{r['file']}: {r['reason']}" not in reasons
            ]
            cls, action = quarantine_action(reasons[0] if reasons else None)  # the stage that set it aside
            out.append(
                {
                    "scan_id": key[0],
                    "night": None if key[1] == "None" else key[1],
                    "device_id": srow.get("device_id"),
                    "kind": srow.get("kind"),
                    "stages": ", ".join(sorted({r["stage"] for r in qq if r["stage"] is not None})),
                    "reasons": reasons,
                    "class": cls,
                    "action": action,
                }
            )
        return out

    def quarantine(self) -> str:
        items = self.quarantined()
        if not items:
            return _EMPTY["quarantine"]
        rows = []
        for it in items:
            rec = self.link(f"quarantine/{it['scan_id']}.json")
            rows.append(
                [
                    _e(it["scan_id"]),
                    _e(it["night"]),
                    _e(it["device_id"]),
                    _e(it["kind"]),
                    _e(it["stages"]),
                    "<br>".join(_e(r) for r in it["reasons"]),
                    _e(it["class"]),
                    _e(it["action"]),
                    _link(rec, "record") if rec else "",
                ]
            )
        return _table(
            ["scan", "night", "device", "kind", "stage", "reason", "class", "what to do", "record"], rows
        )

    def summary(self) -> str:
        """Night by night, newest first: what came in and what needs a person."""
        t = self.t
        sc, ver, fnd = t["scans"], t["verifications"], t["findings"]
        ev = t.get("calibration_events")
        ev = (
            ev
            if ev is not None
            else pl.DataFrame(
                schema={
                    "night": pl.Utf8,
                    "event": pl.Utf8,
                    "calibration_id": pl.Utf8,
                    "device_id": pl.Utf8,
                    "other_id": pl.Utf8,
                }
            )
        )
        parts = self.parts() if t["diameters"].height else None
        quarantined = self.quarantined()

        def of(df, night):
            return df.filter(pl.col("night").cast(pl.Utf8) == night) if df is not None and df.height else df

        nights = set()
        for df in (sc, ver, fnd, ev, parts):
            if df is not None and df.height and "night" in df.columns:
                nights |= {str(n) for n in df["night"].drop_nulls().to_list()}
        nights |= {q["night"] for q in quarantined if q["night"]}
        if not nights:
            return '<p class="empty">No nights in the catalog.</p>'
        rows, classes, details = [], [], []
        for night in sorted(nights, reverse=True):
            s_n, v_n, f_n, e_n = of(sc, night), of(ver, night), of(fnd, night), of(ev, night)
            p_n = of(parts, night)
            q_n = [q for q in quarantined if q["night"] == night]
            kinds = s_n.group_by("kind").len().sort("kind").rows() if s_n.height else []
            made, superseded, expired = (
                e_n.filter(pl.col("event") == k) if e_n.height else e_n
                for k in ("made", "superseded", "expired")
            )
            failed = v_n.filter(~pl.col("passed").fill_null(True)) if v_n.height else v_n
            out_tol = p_n.filter(~pl.col("in_tolerance")) if p_n is not None and p_n.height else None
            if out_tol is not None and "conformity" in p_n.columns:  # the stage's verdict under the rule
                out_tol = p_n.filter(
                    _verdict_is(DOES_NOT_CONFORM)
                    | (~pl.col("in_tolerance").fill_null(True) & pl.col("conformity").is_null())
                )
            # in the order of the scans and their gauges or features, whatever the catalog's row order
            # (a night appended to the catalog and a rebuilt catalog give the same page)
            undecided = [
                r
                for df in (v_n, p_n)
                if df is not None and df.height and "conformity" in df.columns
                for r in sorted(
                    df.filter(_verdict_is(CANNOT_DECIDE)).iter_rows(named=True),
                    key=lambda r: (str(r.get("scan_id")), str(r.get("artifact_id")), str(r.get("feature"))),
                )
            ]
            person = (
                f_n.filter(pl.col("verdict").is_in(["missing_effect", "ambiguous"])) if f_n.height else f_n
            )
            person_scans = person["scan_id"].unique(maintain_order=True).to_list() if person.height else []
            untraceable = (
                p_n.filter(pl.col("method").fill_null("").str.contains("NOT TRACEABLE"))
                if p_n is not None and p_n.height and "method" in p_n.columns
                else None
            )
            n_out = 0 if out_tol is None else out_tol.height
            known_tol = p_n is not None and p_n.height and p_n["tolerance_mm"].drop_nulls().len() > 0
            attention = (
                bool(q_n)
                or failed.height > 0
                or n_out > 0
                or bool(person_scans)
                or expired.height > 0
                or (untraceable is not None and untraceable.height > 0)
                or bool(undecided)
            )
            rows.append(
                [
                    f'<a href="#night-{night}">{_e(night)}</a>',
                    str(s_n.height),
                    _e(", ".join(f"{k} {n}" for k, n in kinds)),
                    str(len(q_n)),
                    str(made.height),
                    str(expired.height),
                    str(superseded.height),
                    str(v_n.height - failed.height),
                    str(failed.height),
                    str(n_out) if known_tol else "–",
                    str(len(undecided)),
                    str(len(person_scans)),
                ]
            )
            classes.append("fail" if attention else "")
            details.append(
                self._night_detail(
                    night,
                    q_n,
                    made,
                    superseded,
                    expired,
                    failed,
                    out_tol,
                    person,
                    attention,
                    untraceable,
                    undecided,
                )
            )
        head = [
            "night",
            "scans in",
            "by kind",
            "quarantined",
            "calibrations made",
            "expired",
            "superseded",
            "verifications passed",
            "failed",
            "parts out of tolerance",
            "cannot decide (U too large)",
            "verdicts for a person",
        ]
        return (
            '<p class="note">Newest night first. A red row needs attention; its details follow the table. '
            "“–”: no part tolerance recorded. Verdicts under the decision rule of the laboratory "
            "(laboratory.decision_rule); “cannot decide”: the expanded uncertainty is not below the "
            "tolerance, or the result lies in the guard band.</p>"
            + _table(head, rows, classes, num_cols=set(range(3, 12)) | {1})
            + "".join(details)
        )

    def _night_detail(  # noqa: C901 (one branch per kind of item a night can list)
        self,
        night,
        q_n,
        made,
        superseded,
        expired,
        failed,
        out_tol,
        person,
        attention,
        untraceable=None,
        undecided=(),
    ) -> str:
        items = []
        for q in q_n:
            rec = self.link(f"quarantine/{q['scan_id']}.json")
            items.append(
                f"<li><b>quarantined</b> {_link(rec, q['scan_id']) if rec else _e(q['scan_id'])}"
                f" ({_e(q['device_id'] or '?')}, {_e(q['kind'] or '?')}): {_e('; '.join(q['reasons']))}"
                f'<br><span class="action">{_e(q["class"])} — what to do: {_e(q["action"])}</span></li>'
            )
        for r in failed.iter_rows(named=True):
            items.append(
                f"<li><b>verification failed</b> {_e(r['scan_id'])} ({_e(r['device_id'])}"
                f"{', gauge ' + _e(r['artifact_id']) if r.get('artifact_id') else ''}): error "
                f"{_um(r.get('error_mm'))} µm, tolerance ±{_um(r.get('tolerance_mm'))} µm, calibration "
                f"{_e(r.get('calibration_id'))}"
                '<br><span class="action">what to do: recalibrate; the calibration is refused for later '
                "measurements, and the measurements made with it are listed under Verification as put in "
                "doubt.</span></li>"
            )
        for r in expired.iter_rows(named=True):
            items.append(
                f"<li><b>calibration expired</b> {_e(r['calibration_id'])} of {_e(r['device_id'])}"
                '<br><span class="action">what to do: recalibrate before the next measurement.</span></li>'
            )
        for r in out_tol.iter_rows(named=True) if out_tol is not None else []:
            items.append(
                f"<li><b>part out of tolerance</b> {_e(r['artifact_id'])} {_e(r.get('feature') or '')} "
                f"(scan {_e(r['scan_id'])}): deviation {_um(r['deviation_mm'])} µm, tolerance "
                f"±{_um(r['tolerance_mm'])} µm</li>"
            )
        for r in undecided:
            what = (
                f"verification {_e(r['scan_id'])} ({_e(r.get('device_id'))}, "
                f"gauge {_e(r.get('artifact_id'))})"
                if "certified_mm" in r
                else f"part {_e(r.get('artifact_id'))} {_e(r.get('feature') or '')} (scan {_e(r['scan_id'])})"
            )
            items.append(
                f"<li><b>cannot decide</b> {what}: {_e(split_verdict(r.get('conformity'))[1])}"
                '<br><span class="action">what to do: the uncertainty is too large for the tolerance or '
                "the result lies in the guard band: lower U (more poses, a better sensor, a recent "
                "calibration) or remeasure; a wider tolerance or another decision rule is the "
                "customer's decision, not the report's.</span></li>"
            )
        for (sid,), grp in (
            untraceable.group_by("scan_id", maintain_order=True)
            if untraceable is not None and untraceable.height
            else []
        ):
            items.append(
                f"<li><b>not traceable</b> {_e(sid)} ({_e(grp['device_id'][0])}): "
                f"{_e(', '.join(str(f) for f in grp['feature'].to_list()))} measured with the rod's design "
                "base lengths"
                '<br><span class="action">what to do: calibrate the rod in its certified ring gauges '
                "(a rod calibration scan); until then these diameters carry no traceability "
                "(measurement.rod_without_calibration: refuse sets such scans aside).</span></li>"
            )
        for (sid,), grp in person.group_by("scan_id", maintain_order=True) if person.height else []:
            verdict = grp["verdict"][0]
            named = ", ".join(
                f"{e}" + (f" (channel {c})" if c is not None else "")
                for e, c in grp.select("effect", "channel").rows()
                if e
            )
            gap = self.link(f"discrepancy/{sid}/gap.png")
            items.append(
                f"<li><b>discrepancy {_e(verdict)}</b> {_e(sid)}: {_e(named)}"
                + (f" ({_link(gap, 'gap.png')})" if gap else "")
                + f'<br><span class="action">{_verdict_note(verdict, grp["effect"].drop_nulls().to_list())}'
                "</span></li>"
            )
        for r in made.iter_rows(named=True):
            items.append(f"<li>calibration made: {_e(r['calibration_id'])} of {_e(r['device_id'])}</li>")
        for r in superseded.iter_rows(named=True):
            items.append(
                f"<li>calibration superseded: {_e(r['calibration_id'])} of {_e(r['device_id'])} by "
                f"{_e(r['other_id'])}</li>"
            )
        if not items:
            return ""
        cls = "night" if attention else "night quiet"
        return (
            f'<div class="{cls}" id="night-{_e(night)}"><h3>{_e(night)}</h3><ul>{"".join(items)}</ul></div>'
        )


def _uncertainties(u: Any) -> dict[str, float]:
    """Return a finding's uncertainties as {parameter: u}.

    Return a finding's uncertainties (a dict, or its JSON text) as {parameter: u}: ``u_`` prefixes dropped,
    non-numbers left out; {} for nothing readable.
    """
    if isinstance(u, str):
        try:
            u = json.loads(u)
        except ValueError:
            return {}
    if not isinstance(u, dict):
        return {}
    return {k.removeprefix("u_"): v for k, v in u.items() if isinstance(v, int | float)}


def _rho_sign_notes(cal: pl.DataFrame) -> str:
    """Return the beams of a device's calibrations whose sign of rho their scan did not determine.

    Read from the ``calibrations`` columns of the mirror check (issue 36): both solutions' weight, the bore
    range where the calibration may be used and the scan that would fix it (HTML; "" when none).
    """
    if "rho_sign_resolved" not in cal.columns:
        return ""
    flagged = cal.filter(pl.col("rho_sign_resolved").fill_null(True).not_()).sort(
        "valid_from", "calibration_id", "channel"
    )
    items = []
    for r in flagged.iter_rows(named=True):
        hi = r.get("valid_bore_max_mm")
        rng = (
            f"{r['valid_bore_min_mm']:.1f} mm to " + ("no upper limit" if hi is None else f"{hi:.1f} mm")
            if r.get("valid_bore_min_mm") is not None
            else "n/a"
        )
        fix = r.get("offset_to_resolve_mm")
        items.append(
            f"<li><b>{_e(r['calibration_id'])}</b>: the sign of rho of channel {r['channel']} is not "
            f"determined by its scan (two solutions, probability of the wrong sign "
            f"{r['p_wrong_sign']:.3f}, the mirror {r['mirror_delta_chi2']:.2f} in chi² above); diameters "
            f"carry both solutions and are measured only for bores of {rng}"
            f'<br><span class="action">what to do: recalibrate with the spindle at least '
            f"{'n/a' if fix is None else f'{fix:.2f}'} mm from the gauge centre (borescan plan predicts "
            "the scan)</span></li>"
        )
    return f'<ul class="notes">{"".join(items)}</ul>' if items else ""


def _calibration_models(cal: pl.DataFrame | None) -> dict[tuple[str, str], tuple[list[dict], float | None]]:
    """Return what each night's calibration carried per device.

    (device, night) -> (the device-model entries the night's calibration carried, from its
    calibration_json diagnostics; its worst residual over the noise floor, None if not stated).
    Of several calibrations of a device in a night, one that carried a device model.
    """
    out: dict[tuple[str, str], tuple[list[dict], float | None]] = {}
    if cal is None or cal.height == 0 or "calibration_json" not in cal.columns:
        return out
    for r in cal.unique("calibration_id", keep="first").iter_rows(named=True):
        try:
            d = json.loads(r["calibration_json"] or "{}")
        except ValueError:
            continue
        ratios = [
            max(x for x in (nu.get("residual_to_noise") or [0.0]) if x is not None)
            for nu in (d.get("nuisance") or {}).values()
        ]
        model = (d.get("diagnostics") or {}).get("device_model") or []
        key = (r["device_id"], str(r["valid_from"]))
        if model or key not in out:  # of two calibrations of a night, the one that carried a model
            out[key] = (model, max(ratios) if ratios else None)
    return out


def _carried_by_calibrations(cal: pl.DataFrame | None) -> dict[tuple[str, str], str]:
    """Return what each night's calibration carried and its residual.

    (device, night) -> what the night's calibration carried of its device model (each entry with
    value ± u and the night it came from, or "not estimated") and its residual against the readings'
    noise floor: when an effect entered the model and what it did to the calibration's gap (HTML).
    """
    out: dict[tuple[str, str], str] = {}
    for key, (model, ratio) in _calibration_models(cal).items():
        if not model:
            continue
        parts = []
        for m in model:
            if m.get("estimated"):
                vals = _parameters_text(
                    m["key"].split("@")[0], json.dumps(m.get("values") or {}), m.get("u") or {}
                )
                parts.append(
                    f"<b>{_e(m['key'])}</b>: {vals} (from {_e(m.get('night'))}"
                    + (", automatic" if m.get("source") == "automatic" else "")
                    + ")"
                )
            else:
                parts.append(f"<b>{_e(m['key'])}</b>: not estimated yet")
        tail = f"<br>residual {ratio:.2f} × noise floor" if ratio is not None else ""
        out[key] = "<br>".join(parts) + tail
    return out


def _parameters_text(effect: str, parameters: str | None, u: dict[str, float]) -> str:
    """Return a finding's parameters in words.

    Return a finding's parameters (JSON text of the findings table) in words:
    ``tau_s = 1.200 ± 0.030 ms``.
    """
    if not parameters:
        return ""
    try:
        values = json.loads(parameters)
    except ValueError:
        return _e(parameters)
    if not isinstance(values, dict):
        return _e(parameters)
    units = dict(getattr(EFFECTS.get(effect), "params", {}) or {})
    out = []
    for name, v in sorted(values.items()):
        if isinstance(v, int | float) and not isinstance(v, bool):
            unit = units.get(name) or _unit_of(name)
            out.append(f"{_e(name)} = {_e(format_quantity(float(v), u.get(name), unit))}")
        elif isinstance(v, dict):  # per-scan values (pooled findings): how many, not all of them
            out.append(f"{_e(name)}: {len(v)} values")
        else:
            out.append(f"{_e(name)} = {_e(v)}")
    return "; ".join(out)


def _unit_of(name: str) -> str:
    """Return the unit a parameter's name ends in (``_mm``, ``_s``, ``_rad``, ``_hz``), "-" otherwise."""
    for suffix, unit in (
        ("_mm_per_s", "mm/s"),
        ("_mm", "mm"),
        ("_s", "s"),
        ("_rad", "rad"),
        ("_hz", "Hz"),
        ("_c", "degC"),
    ):
        if name.endswith(suffix):
            return unit
    return "-"


#: a gap before within this multiple of the noise floor is at the floor (schema discrepancy.floor_ratio)
_FLOOR_RATIO = float(schema_default("discrepancy", "floor_ratio"))


def _verdict_note(verdict: str, effects: list[str]) -> str:
    """Return what a verdict means for the person reading it (HTML)."""
    if verdict == "ambiguous":
        names = ", ".join(dict.fromkeys(effects))
        hints = sorted({EFFECTS[e].separated_by for e in effects if e in EFFECTS and EFFECTS[e].separated_by})
        how = (
            " A scan at " + " or ".join(hints) + " separates them."
            if hints
            else " A scan that differs in what separates them does."
        )
        return _e(
            f"Ambiguous between {names}: they explain this scan's data equally well (outputs.md lists every "
            "such candidate); one scan cannot tell them apart, nothing is wrong with the software." + how
        )
    if verdict == "missing_effect":
        return _e(
            "The model misses this effect; if it persists over scans, service the device (sensor, cabling, "
            "spindle)."
        )
    return ""


#: What a section says when the catalog holds no rows for it.
_EMPTY = {
    "calibration": '<p class="empty">No calibrations in the catalog.</p>',
    "verification": '<p class="empty">No verifications in the catalog.</p>',
    "diameters": '<p class="empty">No diameters in the catalog.</p>',
    "discrepancy": '<p class="empty">No findings in the catalog.</p>',
    "pooled": '<p class="empty">No pooled examination in the catalog.</p>',
    "quarantine": '<p class="empty">No quarantined scans.</p>',
    "summary": '<p class="empty">No nights in the catalog.</p>',
}

SECTIONS = (
    ("summary", "Summary"),
    ("calibration", "Calibration"),
    ("verification", "Verification"),
    ("diameters", "Parts"),
    ("discrepancy", "Discrepancy"),
    ("pooled", "Device model"),
    ("papers", "Papers"),
    ("quarantine", "Quarantine"),
)

#: A month page has every section but the papers (they do not depend on the nights; their own page).
MONTH_SECTIONS = tuple(s for s in SECTIONS if s[0] != "papers")

#: The papers' page, under the report folder.
PAPERS_PAGE = "papers.html"


def _page(title: str, header: str, nav: str, body: str, footer: str = "") -> str:
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{_e(title)}</title><style>{CSS}</style></head><body>"
        f"{header}<nav>{nav}</nav><main>{body}{footer}</main></body></html>\n"
    )


def _header(totals: dict[str, Any], subtitle: str = "") -> str:
    span = f"{totals['first']} – {totals['last']}" if totals["first"] else "no nights"
    return (
        f"<header><h1>borescan report{_e(subtitle)}</h1><p>{_e(span)} · {totals['scans']} scans "
        f"({totals['quarantined']} quarantined) · {totals['calibrations']} calibrations · "
        f"{totals['diameters']} diameters · {totals['verifications']} verifications</p></header>"
    )


#: Placeholders for the page's way back to the results folder and to the month's plots: a month's
#: sections are rendered once and placed on its own page and, for the latest month, on report.html.
_UP, _PLOTS = "@@UP@@", "@@PLOTS@@"


def _month_sections(
    root: Path, month: str, tables: dict[str, pl.DataFrame], cache: _PlotCache
) -> dict[str, Any]:
    """Return a month's header counts and section bodies, with the link placeholders."""
    b = _Builder(root, tables, cache, up=_UP, plots=_PLOTS)
    return {"counts": _counts(tables), "sections": {sid: getattr(b, sid)() for sid, _title in MONTH_SECTIONS}}


def _place(fragment: str, up: str, plots: str) -> str:
    return fragment.replace(_UP, up).replace(_PLOTS, plots)


def _month_page(month: str, parts: dict[str, Any]) -> str:
    body = [
        f'<section id="{sid}"><h2>{title} · {_e(month)}</h2>{_place(parts["sections"][sid], "../../", "")}'
        "</section>"
        for sid, title in MONTH_SECTIONS
    ]
    nav = '<a href="../../report.html">← report</a>' + "".join(
        f'<a href="#{sid}">{title}</a>' for sid, title in MONTH_SECTIONS
    )
    return _page(f"borescan report {month}", _header(parts["counts"], f" · {month}"), nav, "".join(body))


@dataclass(frozen=True)
class ReportUpdate:
    """What :func:`update_report` did: the page, the months whose page was (re)written, plots drawn."""

    path: Path
    months: tuple[str, ...]
    rendered: tuple[str, ...]
    plots_drawn: int


def update_report(
    results_root: str | os.PathLike, tables: dict[str, pl.DataFrame] | None = None, full: bool = False
) -> ReportUpdate:
    """Write ``<results_root>/report.html`` and the month pages ``report/<YYYY-MM>/index.html``.

    Each month of nights has its page and plots in ``report/<YYYY-MM>/``; ``report.html`` shows
    the header over the whole history, the latest month's sections (the same plots), the papers,
    and links to every month. A month's page is rewritten only when a row it shows changed
    (:func:`month_fingerprints`) and a plot is drawn only when its input changed, so a new night
    costs about one month's page whatever the length of the history; ``full=True`` redraws all.
    ``tables`` (name -> polars frame, as :func:`load_tables` returns) replaces the catalog.
    Every file is written atomically; links are relative to where the page is.
    """
    root = Path(results_root)
    if tables is None:
        con = catalog.open_catalog(root, read_only=True)
    else:
        con = _memory_catalog({k: v for k, v in tables.items() if v is not None})
    try:
        return _update(root, con, full)
    finally:
        con.close()


def _update(  # noqa: C901 (one branch per page, month and section of the report)
    root: Path, con, full: bool
) -> ReportUpdate:
    report_dir = root / REPORT_DIR
    report_dir.mkdir(parents=True, exist_ok=True)
    for stray in report_dir.iterdir():  # plots of the single-page layout, month folders of gone months
        if stray.is_file() and stray.name != PAPERS_PAGE:
            stray.unlink()
    prints = month_fingerprints(con)
    for d in report_dir.iterdir():
        if d.is_dir() and d.name not in prints:
            shutil.rmtree(d)
    totals = _totals(con)
    rendered, drawn = [], 0
    parts: dict[str, Any] = {}
    for month, fp in prints.items():
        # page.json: the fingerprint the page was written for (small: read for every month);
        # sections.json: its sections, for report.html when it is the latest month
        folder = report_dir / month
        done = folder / "page.json"
        if (
            not full
            and done.is_file()
            and (folder / "index.html").is_file()
            and (folder / "sections.json").is_file()
        ):
            with contextlib.suppress(ValueError):
                if json.loads(done.read_text()).get("fingerprint") == fp:
                    continue
        cache = _PlotCache(folder, use=not full)
        parts[month] = _month_sections(root, month, _month_tables(con, month), cache)
        atomic_write_text(folder / "index.html", _month_page(month, parts[month]))
        cache.save()
        atomic_write_text(folder / "sections.json", json.dumps(parts[month], sort_keys=True) + "\n")
        atomic_write_text(done, json.dumps({"fingerprint": fp}) + "\n")
        rendered.append(month)
        drawn += cache.drawn
    dated = [m for m in prints if m != "undated"] or list(prints)
    month = dated[-1] if dated else None
    if month is not None and month not in parts:
        parts[month] = json.loads((report_dir / month / "sections.json").read_text())
    papers = _Builder(root, {}, _PlotCache(report_dir), up="../").papers()
    atomic_write_text(
        report_dir / PAPERS_PAGE,
        _page(
            "borescan report · papers",
            "<header><h1>borescan report · papers</h1><p>published results reproduced, "
            "beside the printed values (papers/)</p></header>",
            '<a href="../report.html">← report</a>',
            f'<section id="papers"><h2>Papers</h2>{papers}</section>',
        ),
    )
    n_papers = papers.count("<h3>")
    body = []
    for sid, title in SECTIONS:
        if sid == "papers":
            body.append(
                f'<section id="{sid}"><h2>{title}</h2><p>'
                + (
                    f"{_link(f'{REPORT_DIR}/{PAPERS_PAGE}', 'The reproduced papers')} ({n_papers} tables "
                    "and plots beside the published values) are on a page of their own."
                    if n_papers
                    else '<span class="empty">No paper reproductions under papers/.</span>'
                )
                + "</p></section>"
            )
        elif month is None:
            body.append(f'<section id="{sid}"><h2>{title}</h2>{_EMPTY[sid]}</section>')
        else:
            fragment = _place(parts[month]["sections"][sid], "", f"{REPORT_DIR}/{month}/")
            body.append(f'<section id="{sid}"><h2>{title} · {_e(month)}</h2>{fragment}</section>')
    counts = {m: (n, s, q) for m, n, s, q in _month_summary(con)}
    rows = [
        [_link(f"{REPORT_DIR}/{m}/index.html", m), *(str(c) for c in counts.get(m, (0, 0, 0)))]
        for m in prints
    ]
    body.append(
        '<section id="months"><h2>Months</h2>'
        + (
            f'<p class="note">The sections above show the latest month, {_e(month)}; every month has its '
            "own page.</p>" + _table(["month", "nights", "scans", "quarantined"], rows, num_cols={1, 2, 3})
            if rows
            else '<p class="empty">No nights in the catalog.</p>'
        )
        + "</section>"
    )
    nav = "".join(f'<a href="#{sid}">{title}</a>' for sid, title in SECTIONS) + '<a href="#months">Months</a>'
    footer = (
        '<p class="note">History: <code>borescan sql "SELECT * FROM scans"</code> or '
        "<code>duckdb -readonly catalog.duckdb</code>; chain behind any number: <code>borescan trace "
        "ID</code>.</p>"
    )
    page = atomic_write_text(
        root / "report.html", _page("borescan report", _header(totals), nav, "".join(body), footer)
    )
    return ReportUpdate(page, tuple(prints), tuple(rendered), drawn)


def write_report(
    results_root: str | os.PathLike, tables: dict[str, pl.DataFrame] | None = None, full: bool = False
) -> Path:
    """Write ``<results_root>/report.html`` (and the month pages); return the page's path.

    See :func:`update_report`; ``tables`` defaults to the catalog's contents.
    """
    return update_report(results_root, tables, full).path
