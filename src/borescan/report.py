"""The browsable report: ``<results_root>/report.html`` and one page per month of nights.

:func:`update_report` (:func:`write_report`) reads the history catalog and writes
self-contained HTML pages (inline CSS, no scripts, no network) whose every link is relative, so
the results folder can be moved or copied to shared storage and the pages still work. Each month
of nights has ``report/<YYYY-MM>/index.html`` with its plots beside it; ``report.html`` shows the
totals of the whole history, the latest month's sections (the same plots), the papers and a
link to every month. Sections:

- **Calibration**: parameter trends per device and channel with error bars (standard
  uncertainty, k=1), links to each certificate (PDF and JSON).
- **Verification**: per device an individuals and moving-range control chart of the
  verification error; limits (Montgomery, *Statistical Quality Control*, §6.4):
  centre line = mean, UCL/LCL = mean ± 2.66·MR̄, MR chart UCL = 3.267·MR̄, LCL = 0; plus the
  measurements a failed verification puts in doubt.
- **Diameters**: certified diameters per part and feature, each scan with its uncertainty.
- **Discrepancy**: findings with verdicts and links to ``discrepancy/<scan_id>/gap.png``.
- **Papers** (``report.html`` only): every PNG and CSV under ``papers/``.
- **Quarantine**: quarantined scans with their reasons.

Incremental: a month's page is rewritten only when a row it shows changed (one aggregate query
per table tells which months did: :func:`month_fingerprints`, which also covers this module's
code), and a plot is drawn only when its input rows changed (``report/<month>/plots.json``), so
a new night costs about one month's page however long the history; ``full=True`` redraws all.
A failed verification that puts an older month's measurement in doubt changes that month's rows
(the ``suspect_measurements`` view), so its page is rewritten too. Plots label at most
:data:`MAX_TICK_LABELS` ticks per axis.

Every plot function is pure: polars frames in, a :class:`matplotlib.figure.Figure` out (Agg,
no pyplot state). PNGs are written without time stamps, so reruns on the same catalog give the
same bytes.
"""

from __future__ import annotations

import contextlib
import functools
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
from borescan.tables import TABLES

__all__ = [
    "MR_D2_FACTOR",
    "MR_D4",
    "control_limits",
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

TRI_PARAMS = (("beta_rad", "u_beta_rad"), ("rho_mm", "u_rho_mm"), ("d_b_mm", "u_d_b_mm"))
ROD_PARAMS = (("l0_mm", "u_l0_mm"), ("h_mm", "u_h_mm"), ("phi_rad", "u_phi_rad"), ("d_mm", "u_d_mm"),
              ("gamma_rad", "u_gamma_rad"))
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
    ax.set_xticklabels([labels[i] for i in pos], rotation=45 if slant else 0, ha="right" if slant else "center",
                       fontsize=7)


# --------------------------------------------------------------------------- plots (pure)


def plot_calibration_trends(cal: pl.DataFrame, device_id: str) -> Figure:
    """Calibration parameters of one device over its calibrations, one panel per parameter and channel.

    ``cal`` has the ``calibrations`` columns; rows of other devices are ignored. Error bars are
    the standard uncertainties (k=1) where present. The x axis lists the calibrations in
    ``valid_from`` order, labelled with night and calibration scan.
    """
    df = cal.filter(pl.col("device_id") == device_id).sort("valid_from", "calibration_id", "channel")
    params = [p for p in TRI_PARAMS + ROD_PARAMS if p[0] in df.columns and df[p[0]].drop_nulls().len() > 0]
    channels = sorted(df["channel"].drop_nulls().unique().to_list())
    cal_order = df.select("calibration_id", "valid_from", "scan_id").unique("calibration_id", keep="first").sort(
        "valid_from", "calibration_id")
    pos = {c: i for i, c in enumerate(cal_order["calibration_id"].to_list())}
    labels = [f"{v}\n{s}" for v, s in zip(cal_order["valid_from"].to_list(), cal_order["scan_id"].to_list(), strict=True)]
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
        err = sub[up].fill_null(0.0).to_numpy() if up in sub.columns else None
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
    fig.suptitle(f"{device_id}: calibration parameters (error bars: u, k=1)", fontsize=10)
    return fig


def plot_control_chart(ver: pl.DataFrame, device_id: str) -> Figure:
    """Individuals and moving-range chart of one device's verification errors.

    ``ver`` has the ``verifications`` columns (``night``, ``scan_id``, ``error_mm``, ``passed``,
    ``tolerance_mm``) in time order; other devices are ignored. Limits from
    :func:`control_limits`; failed verifications are drawn in red; ± tolerance dotted.
    """
    df = ver.filter(pl.col("device_id") == device_id)
    lim = control_limits(df["error_mm"].to_numpy())
    x = np.arange(df.height)
    y = df["error_mm"].to_numpy() * 1e3
    passed = df["passed"].fill_null(True).to_numpy().astype(bool)
    fig = Figure(figsize=(8.0, 5.5), layout="constrained")
    ax_i, ax_mr = fig.subplots(2, 1, sharex=True)
    ax_i.plot(x, y, "-", color="0.5", lw=1)
    ax_i.plot(x[passed], y[passed], "o", color="C0", label="passed")
    if (~passed).any():
        ax_i.plot(x[~passed], y[~passed], "s", color="C3", label="failed")
    for val, style, name in ((lim["mean"], "-", "mean"), (lim["ucl"], "--", "UCL"), (lim["lcl"], "--", "LCL")):
        if np.isfinite(val):
            ax_i.axhline(val * 1e3, ls=style, color="k" if name == "mean" else "C1", lw=1)
            ax_i.annotate(f"{name} {val * 1e3:.2f}", (1.0, val * 1e3), xycoords=("axes fraction", "data"),
                          fontsize=7, va="bottom", ha="right")
    tol = df["tolerance_mm"].drop_nulls()
    if tol.len():
        t = float(tol.max()) * 1e3
        for s in (t, -t):
            ax_i.axhline(s, ls=":", color="C3", lw=1)
        ax_i.annotate(f"tolerance ±{t:g}", (0.0, t), xycoords=("axes fraction", "data"), fontsize=7, va="bottom",
                      color="C3")
    ax_i.set_ylabel("error [µm]")
    ax_i.set_title(f"{device_id}: verification error, individuals chart", fontsize=10)
    ax_i.legend(fontsize=7, loc="best")
    ax_i.grid(alpha=0.3)
    mr = lim["mr"] * 1e3
    ax_mr.plot(x[1:], mr, "o-", color="C0")
    if np.isfinite(lim["mr_bar"]):
        ax_mr.axhline(lim["mr_bar"] * 1e3, color="k", lw=1)
        ax_mr.axhline(lim["mr_ucl"] * 1e3, ls="--", color="C1", lw=1)
        ax_mr.annotate(f"MR̄ {lim['mr_bar'] * 1e3:.2f}", (1.0, lim["mr_bar"] * 1e3),
                       xycoords=("axes fraction", "data"), fontsize=7, va="bottom", ha="right")
        ax_mr.annotate(f"UCL {lim['mr_ucl'] * 1e3:.2f}", (1.0, lim["mr_ucl"] * 1e3),
                       xycoords=("axes fraction", "data"), fontsize=7, va="bottom", ha="right")
    ax_mr.axhline(0.0, color="0.7", lw=0.8)
    ax_mr.set_ylabel("moving range [µm]")
    ax_mr.set_title("moving range chart", fontsize=10)
    ax_mr.grid(alpha=0.3)
    ax_mr.set_xlim(-0.5, max(df.height - 0.5, 0.5))
    _xticks(ax_mr, _labels(df))
    return fig


def plot_diameters(dia: pl.DataFrame, artifact_id: str) -> Figure:
    """Diameters of one part, one panel per feature: each scan with ± 2u error bars, mean line.

    ``dia`` has the ``diameters`` columns; rows of other parts are ignored. The x axis is the
    measurement order, labelled with night and scan.
    """
    df = dia.filter(pl.col("artifact_id") == artifact_id)
    features = sorted(df["feature"].fill_null("").unique().to_list())
    nc = min(len(features), 3) or 1
    nr = -(-max(len(features), 1) // nc)
    most = max([df.filter(pl.col("feature").fill_null("") == f).height for f in features] + [1])
    panel_w = min(max(3.8, 0.42 * most), 12.0 / nc)
    fig = Figure(figsize=(panel_w * nc + 0.8, 3.2 * nr + 0.8), layout="constrained")
    axes = fig.subplots(nr, nc, squeeze=False)
    for k, feat in enumerate(features):
        ax = axes[k // nc][k % nc]
        sub = df.filter(pl.col("feature").fill_null("") == feat)
        y = sub["diameter_mm"].to_numpy()
        u = sub["u_diameter_mm"].fill_null(0.0).to_numpy()
        x = np.arange(sub.height)
        ax.errorbar(x, y, yerr=2 * u, fmt="o", ms=4, capsize=3, color="C0")
        if sub.height:
            ax.axhline(float(np.nanmean(y)), color="k", lw=0.8)
        ax.set_title(f"feature {feat or '?'} (n={sub.height})", fontsize=9)
        ax.set_ylabel("diameter [mm]", fontsize=8)
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
        ax.tick_params(axis="y", labelsize=7)
        ax.grid(alpha=0.3)
        ax.set_xlim(-0.5, max(sub.height - 0.5, 0.5))
        _xticks(ax, _labels(sub))
    for k in range(len(features), nr * nc):
        axes[k // nc][k % nc].set_visible(False)
    fig.suptitle(f"part {artifact_id}: diameters (error bars: 2u)", fontsize=10)
    return fig


def _png_bytes(fig: Figure) -> bytes:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, metadata=PNG_META)
    return buf.getvalue()


# --------------------------------------------------------------------------- data


def load_tables(results_root: str | os.PathLike) -> dict[str, pl.DataFrame]:
    """The catalog tables (and the ``suspect_measurements`` view when present) as polars frames."""
    con = catalog.open_catalog(results_root, read_only=True)
    try:
        out = {}
        for t in catalog.SCHEMA:
            out[t] = con.sql(f"SELECT * FROM {t} ORDER BY {_ORDER.get(t, '1')}").pl()
        if "verifications" in out and "scans" in out:
            # time order within a night: by the scan's start
            out["verifications"] = (
                out["verifications"].join(out["scans"].select("scan_id", "started_at"), on="scan_id", how="left")
                .sort("device_id", "night", "started_at", "scan_id", nulls_last=True)
            )
        views = {r[0] for r in con.execute("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()}
        if "suspect_measurements" in views:
            out["suspect_measurements"] = con.sql("SELECT * FROM suspect_measurements").pl()
        return out
    finally:
        con.close()


# --------------------------------------------------------------------------- HTML

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:0;color:#222;background:#fafafa}
header{background:#1f3b57;color:#fff;padding:14px 24px}
header h1{margin:0;font-size:22px} header p{margin:4px 0 0;font-size:13px;opacity:.85}
nav{position:sticky;top:0;background:#e9eef3;padding:8px 24px;border-bottom:1px solid #ccd;font-size:14px;z-index:2}
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
"""


def _e(v: Any) -> str:
    return html.escape("" if v is None else str(v))


def _num(v: Any, digits: int = 6) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return ""
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def _link(href: str | None, text: str) -> str:
    if not href:
        return _e(text)
    return f'<a href="{html.escape(href, quote=True)}">{_e(text)}</a>'


def _table(headers: list[str], rows: list[list[str]], row_classes: list[str] | None = None,
           num_cols: set[int] | None = None) -> str:
    """An HTML table; cells are already-escaped HTML."""
    num_cols = num_cols or set()
    out = ["<table><thead><tr>", *(f"<th>{_e(h)}</th>" for h in headers), "</tr></thead><tbody>"]
    for i, r in enumerate(rows):
        cls = f' class="{row_classes[i]}"' if row_classes and row_classes[i] else ""
        cells = "".join(f'<td class="num">{c}</td>' if j in num_cols else f"<td>{c}</td>" for j, c in enumerate(r))
        out.append(f"<tr{cls}>{cells}</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _rel(results_root: Path, path: str | None) -> str | None:
    """A relative link to ``path`` (relative to results_root, or absolute inside it) if it exists."""
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
    """This module's source and the plotting libraries: a change re-renders every page and plot."""
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
    "calibration_scans": ("SELECT c._m, t.* FROM calibration_scans t JOIN (SELECT DISTINCT calibration_id, {mc} AS _m "
                          "FROM calibrations c) c USING (calibration_id) LEFT JOIN (SELECT scan_id, min({ms}) AS _sm "
                          "FROM scans s GROUP BY scan_id) s USING (scan_id) WHERE s._sm IS NULL OR s._sm = c._m"),
    "verifications": "SELECT {m} AS _m, t.* FROM verifications t",
    "diameters": "SELECT {m} AS _m, t.* FROM diameters t",
    "findings": "SELECT {m} AS _m, t.* FROM findings t",
    "quarantine": "SELECT {m} AS _m, t.* FROM quarantine t",
    "suspect_measurements": "SELECT {m} AS _m, t.* FROM suspect_measurements t",
}

#: Row order of each table on a page.
_ORDER = {
    "scans": "night, started_at, scan_id",
    "calibrations": "device_id, valid_from, calibration_id, channel",
    "calibration_scans": "calibration_id, scan_id",
    "diameters": "artifact_id, feature, night, scan_id",
    "verifications": "device_id, night, scan_id",
    "findings": "scan_id, effect, channel",
    "quarantine": "scan_id, stage",
    "suspect_measurements": "device_id, night, scan_id, feature",
    "artifacts": "artifact_id",
    "scan_files": "scan_id, file",
}


def _sources(con) -> list[str]:
    have = {r[0] for r in con.execute(
        "SELECT table_name FROM duckdb_tables() WHERE schema_name = 'main' UNION "
        "SELECT view_name FROM duckdb_views() WHERE NOT internal AND schema_name = 'main'").fetchall()}
    return [name for name in _MONTH_ROWS if name in have]


def month_fingerprints(con) -> dict[str, str]:
    """Month (``YYYY-MM`` of the night, or ``undated``) -> fingerprint of every row its page shows.

    One aggregate query per table (row count and the sum of DuckDB row hashes per month), so
    finding which months changed costs milliseconds even for years of nights.
    """
    parts: dict[str, list] = {}
    for name in _sources(con):
        sql = _MONTH_ROWS[name].format(m=_month_sql("t"), mc=_month_sql("c"), ms=_month_sql("s"))
        for m, n, h in con.execute(f"SELECT _m, count(*), sum(hash(q)::HUGEINT) FROM ({sql}) q GROUP BY _m").fetchall():
            parts.setdefault(m, []).append((name, n, str(h)))
    code = _code_fingerprint()
    return {m: hashlib.sha256(json.dumps([code, sorted(v)]).encode()).hexdigest()[:16] for m, v in sorted(parts.items())}


def _month_tables(con, month: str) -> dict[str, pl.DataFrame]:
    """The rows of one month, per table, in page order (verifications with their scan's start)."""
    out = {}
    srcs = _sources(con)
    for name in srcs:
        sql = _MONTH_ROWS[name].format(m=_month_sql("t"), mc=_month_sql("c"), ms=_month_sql("s"))
        order, drop = _ORDER[name], "_m"
        if name == "verifications" and "scans" in srcs:  # time order within a night: by the scan's start
            sql = ("SELECT " + _month_sql("t") + " AS _m, t.*, s.started_at AS _start FROM verifications t LEFT JOIN "
                   "(SELECT DISTINCT ON (scan_id, night) scan_id, night, started_at FROM scans) s "
                   "ON s.scan_id = t.scan_id AND s.night IS NOT DISTINCT FROM t.night")
            order, drop = "device_id, night, _start NULLS LAST, scan_id", "_m, _start"
        out[name] = con.sql(f"SELECT * EXCLUDE ({drop}) FROM ({sql}) q WHERE _m = ? ORDER BY {order}",
                                params=[month]).pl()
    return out


def _totals(con) -> dict[str, Any]:
    """Counts over the whole history for the page header."""
    first, last, n_scans, n_q = con.execute(
        "SELECT min(night)::VARCHAR, max(night)::VARCHAR, count(*), count(*) FILTER (status = 'quarantined') "
        "FROM scans").fetchone()
    return {
        "first": first, "last": last, "scans": n_scans, "quarantined": n_q,
        "calibrations": con.execute("SELECT count(DISTINCT calibration_id) FROM calibrations").fetchone()[0],
        "diameters": con.execute("SELECT count(*) FROM diameters").fetchone()[0],
        "verifications": con.execute("SELECT count(*) FROM verifications").fetchone()[0],
    }


def _counts(t: dict[str, pl.DataFrame]) -> dict[str, Any]:
    """The header's counts over one page's rows."""
    sc = t["scans"]
    nights = sorted({str(n) for n in sc["night"].drop_nulls().to_list()})
    return {"first": nights[0] if nights else None, "last": nights[-1] if nights else None, "scans": sc.height,
            "quarantined": sc.filter(pl.col("status") == "quarantined").height,
            "calibrations": t["calibrations"]["calibration_id"].drop_nulls().n_unique(),
            "diameters": t["diameters"].height, "verifications": t["verifications"].height}


def _month_summary(con) -> list[tuple[str, int, int, int]]:
    """(month, nights, scans, quarantined) of every month with scans."""
    return con.execute(
        f"SELECT {_month_sql()} AS m, count(DISTINCT night), count(*), count(*) FILTER (status = 'quarantined') "
        "FROM scans GROUP BY m ORDER BY m").fetchall()


def _memory_catalog(tables: dict[str, pl.DataFrame]):
    """An in-memory DuckDB with the given frames as catalog tables (missing ones empty, typed)."""
    con = duckdb.connect()
    con.execute("SET TimeZone = 'UTC'")
    for name, cols in catalog.SCHEMA.items():
        df = tables.get(name)
        if df is None or df.width == 0:
            con.execute(TABLES[name].ddl())
            continue
        con.register("_in", df)
        select = [f"CAST({catalog._q(c)} AS {t}) AS {catalog._q(c)}" if c in df.columns
                  else f"CAST(NULL AS {t}) AS {catalog._q(c)}" for c, t in cols.items()]
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

    def get(self, fname: str, key: str, draw) -> None:
        if self.old.get(fname) != key or not (self.folder / fname).is_file():
            atomic_write_bytes(self.folder / fname, _png_bytes(draw()))
            self.drawn += 1
        self.new[fname] = key

    def save(self) -> None:
        """Record the plots of the page just written and remove the ones it no longer shows."""
        for f in self.folder.glob("*.png"):
            if f.name not in self.new:
                f.unlink()
        atomic_write_text(self.file, json.dumps(self.new, indent=1, sort_keys=True) + "\n")


class _Builder:
    """The sections of one page over ``tables`` (a month's rows).

    ``up``: the page's path back to the results folder ("" for ``report.html``, ``"../../"`` for
    a month page); ``plots``: the month's plot folder as seen from the page.
    """

    def __init__(self, root: Path, tables: dict[str, pl.DataFrame], cache: _PlotCache, up: str = "",
                 plots: str = ""):
        self.root = root
        self.t = tables
        self.cache = cache
        self.up = up
        self.plots = plots
        self.code = _code_fingerprint()

    def link(self, path: str | None) -> str | None:
        rel = _rel(self.root, path)
        return None if rel is None else self.up + rel

    def figure(self, plot, data: pl.DataFrame, key: str, name: str, alt: str) -> str:
        """``plot(data, key)`` as ``<month>/<name>.png``, drawn only when its input changed."""
        fname = _safe(name) + ".png"
        fp = hashlib.sha256(f"{self.code} {plot.__name__} {key} {frame_fingerprint(data)}".encode()).hexdigest()[:16]
        self.cache.get(fname, fp, lambda: plot(data, key))
        return f'<img src="{html.escape(self.plots + fname, quote=True)}" alt="{_e(alt)}">'

    # ---------------------------------------------------------------- sections
    def calibration(self) -> str:
        cal = self.t["calibrations"]
        if cal.height == 0:
            return _EMPTY["calibration"]
        out = []
        cs = self.t["calibration_scans"]
        scans_of = {} if cs.height == 0 else dict(
            cs.group_by("calibration_id", maintain_order=True).agg(pl.col("scan_id")).iter_rows())
        for dev in sorted(cal["device_id"].drop_nulls().unique().to_list()):
            out.append(f"<h3>Device {_e(dev)}</h3>")
            mine = cal.filter(pl.col("device_id") == dev)
            if mine.filter(pl.col("method") != "nominal").height:  # design geometry does not trend: table only
                out.append(self.figure(plot_calibration_trends, mine, dev, f"calibration_{dev}",
                                       f"calibration parameters of {dev}"))
            rows = []
            per = mine.unique("calibration_id", keep="first").sort("valid_from", "calibration_id")
            for r in per.iter_rows(named=True):
                scans = scans_of.get(r["calibration_id"], [])
                cert = r.get("certificate_path")
                pdf = self.link(cert)
                cj = catalog.certificate_json_path(self.root, cert) if cert else None
                json_link = self.link(str(cj)) if cj else None
                links = " ".join(x for x in (
                    _link(pdf, "certificate") if pdf else (_e(cert) + " (missing)" if cert else ""),
                    _link(json_link, "json") if json_link else "",
                ) if x)
                rows.append([_e(r["calibration_id"]), _e(r.get("valid_from")), _e(r.get("method")),
                             _e(", ".join(scans)), _e(r.get("status")), links,
                             f"<code>{_e((r.get('certificate_sha256') or '')[:16])}</code>"])
            out.append(_table(["calibration", "valid from", "method", "scans", "status", "certificate",
                               "certificate.json sha256"], rows))
        return "".join(out)

    def verification(self) -> str:
        ver = self.t["verifications"]
        if ver.height == 0:
            return _EMPTY["verification"]
        out = [
            '<p class="note">Individuals chart of the verification error (measured − certified ring-gauge '
            "diameter) with limits mean ± 2.66·MR̄; moving-range chart with UCL = 3.267·MR̄.</p>"
        ]
        for dev in sorted(ver["device_id"].drop_nulls().unique().to_list()):
            sub = ver.filter(pl.col("device_id") == dev)
            lim = control_limits(sub["error_mm"].to_numpy())
            out.append(f"<h3>Device {_e(dev)}</h3>")
            out.append(self.figure(plot_control_chart, sub, dev, f"control_{dev}", f"control chart of {dev}"))
            out.append(_table(
                ["n", "mean [mm]", "MR̄ [mm]", "UCL [mm]", "LCL [mm]", "MR UCL [mm]"],
                [[str(sub.height), _num(lim["mean"]), _num(lim["mr_bar"]), _num(lim["ucl"]), _num(lim["lcl"]),
                  _num(lim["mr_ucl"])]], num_cols={0, 1, 2, 3, 4, 5}))
            rows, classes = [], []
            for r in sub.iter_rows(named=True):
                ok = r.get("passed")
                rows.append([_e(r.get("night")), _e(r["scan_id"]), _e(r.get("calibration_id")),
                             _num(r.get("measured_mm"), 9), _num(r.get("certified_mm"), 9), _num(r.get("error_mm")),
                             _num(r.get("tolerance_mm")),
                             '<span class="pass">passed</span>' if ok else '<span class="fail">FAILED</span>'])
                classes.append("" if ok else "fail")
            out.append(_table(["night", "scan", "calibration", "measured [mm]", "certified [mm]", "error [mm]",
                               "tolerance [mm]", "verdict"], rows, classes, num_cols={3, 4, 5, 6}))
        sus = self.t.get("suspect_measurements")
        out.append("<h3>Measurements put in doubt by a failed verification</h3>")
        if sus is None or sus.height == 0:
            out.append('<p class="empty">None: no measurement used a calibration that later failed verification.</p>')
        else:
            rows = [[_e(r["night"]), _e(r["scan_id"]), _e(r["artifact_id"]), _e(r["feature"]),
                     _num(r["diameter_mm"], 9), _e(r["calibration_id"]), _e(r["failed_verification_scan_id"]),
                     _e(r["failed_night"]), _num(r["failed_error_mm"])] for r in sus.iter_rows(named=True)]
            out.append(_table(["night", "scan", "part", "feature", "diameter [mm]", "calibration",
                               "failed verification", "on", "its error [mm]"], rows, ["fail"] * len(rows),
                              num_cols={4, 8}))
        return "".join(out)

    def diameters(self) -> str:
        dia = self.t["diameters"]
        if dia.height == 0:
            return _EMPTY["diameters"]
        out = []
        dia = dia.with_columns(pl.col("artifact_id").fill_null("?"))
        counts = dia.group_by("artifact_id", "feature").len().group_by("artifact_id").agg(pl.col("len").max())
        once = set(counts.filter(pl.col("len") < 2)["artifact_id"].to_list())
        if once:  # a single value per feature has no distribution: one table for all such parts
            single = dia.filter(pl.col("artifact_id").is_in(sorted(once))).sort("artifact_id", "feature", "scan_id")
            out.append(f"<h3>Parts measured once ({len(once)})</h3>")
            rows = [[_e(r["artifact_id"]), _e(r.get("feature")), _num(r["diameter_mm"], 9), _num(r.get("u_diameter_mm"), 3),
                     _e(r.get("scan_id")), _e(r.get("calibration_id"))] for r in single.iter_rows(named=True)]
            out.append(_table(["part", "feature", "diameter [mm]", "u [mm]", "scan", "calibration"], rows,
                              num_cols={2, 3}))
        for part in sorted(set(dia["artifact_id"].unique().to_list()) - once):
            sub = dia.filter(pl.col("artifact_id") == part)
            out.append(f"<h3>Part {_e(part)}</h3>")
            out.append(self.figure(plot_diameters, sub, part, f"diameters_{part}", f"diameters of {part}"))
            stats = (sub.group_by("feature").agg(pl.len().alias("n"), pl.col("diameter_mm").mean().alias("mean"),
                                                 pl.col("diameter_mm").std().alias("sd"),
                                                 pl.col("diameter_mm").min().alias("min"),
                                                 pl.col("diameter_mm").max().alias("max"),
                                                 pl.col("u_diameter_mm").mean().alias("u"))
                     .sort("feature"))
            rows = [[_e(r["feature"]), str(r["n"]), _num(r["mean"], 9), _num(r["sd"], 3), _num(r["min"], 9),
                     _num(r["max"], 9), _num(r["u"], 3)] for r in stats.iter_rows(named=True)]
            out.append(_table(["feature", "n", "mean [mm]", "sd [mm]", "min [mm]", "max [mm]", "mean u [mm]"], rows,
                              num_cols={1, 2, 3, 4, 5, 6}))
        return "".join(out)

    def discrepancy(self) -> str:
        fnd = self.t["findings"]
        if fnd.height == 0:
            return _EMPTY["discrepancy"]
        rows, classes, links_of = [], [], {}
        for r in fnd.iter_rows(named=True):
            sid = r["scan_id"]
            if sid not in links_of:  # a scan has one row per candidate effect
                gap = self.link(f"discrepancy/{sid}/gap.png")
                fj = self.link(f"discrepancy/{sid}/findings.json")
                links_of[sid] = " ".join(x for x in (_link(gap, "gap.png") if gap else "",
                                                     _link(fj, "findings.json") if fj else "") if x)
            links = links_of[sid]
            rows.append([_e(sid), _e(r.get("night")), _e(r["verdict"]), _e(r.get("effect")), _e(r.get("channel")),
                         f"<code>{_e(r.get('parameters'))}</code>" if r.get("parameters") else "",
                         _num(r.get("gap_before_mm"), 4), _num(r.get("gap_after_mm"), 4), links])
            classes.append("fail" if r["verdict"] == "missing_effect" else "")
        return _table(["scan", "night", "verdict", "effect", "channel", "parameters", "gap before [mm rms]",
                       "gap after [mm rms]", "plots"], rows, classes, num_cols={6, 7})

    def papers(self) -> str:
        pdir = self.root / "papers"
        files = sorted(p for p in pdir.rglob("*") if p.is_file() and p.suffix.lower() in (".png", ".csv")) \
            if pdir.is_dir() else []
        if not files:
            return '<p class="empty">No paper reproductions under papers/.</p>'
        out = []
        for f in files:
            rel = self.up + f.relative_to(self.root).as_posix()
            out.append(f"<h3>{_link(rel, f.relative_to(pdir).as_posix())}</h3>")
            if f.suffix.lower() == ".png":
                out.append(f'<img src="{html.escape(rel, quote=True)}" alt="{_e(f.name)}">')
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

    def quarantine(self) -> str:
        sc = self.t["scans"].filter(pl.col("status") == "quarantined")
        q = self.t["quarantine"]
        if sc.height == 0 and q.height == 0:
            return _EMPTY["quarantine"]
        scan_row = {r["scan_id"]: r for r in sc.iter_rows(named=True)}
        q_rows: dict[str, list[dict]] = {}
        for r in q.iter_rows(named=True):
            q_rows.setdefault(r["scan_id"], []).append(r)
        rows = []
        for sid in sorted(set(scan_row) | set(q_rows)):
            srow = scan_row.get(sid, {})
            qq = q_rows.get(sid, [])
            stages = ", ".join(sorted({r["stage"] for r in qq if r["stage"] is not None}))
            reasons = [srow.get("reason")] if srow.get("reason") else []
            reasons += [f"{r['file']}: {r['reason']}" for r in qq if f"{r['file']}: {r['reason']}" not in reasons]
            rec = self.link(f"quarantine/{sid}.json")
            rows.append([_e(sid), _e(srow.get("night") or (qq[0]["night"] if qq else None)),
                         _e(srow.get("device_id")), _e(srow.get("kind")), _e(stages),
                         "<br>".join(_e(r) for r in reasons), _link(rec, "record") if rec else ""])
        return _table(["scan", "night", "device", "kind", "stage", "reason", "record"], rows)


#: What a section says when the catalog holds no rows for it.
_EMPTY = {
    "calibration": '<p class="empty">No calibrations in the catalog.</p>',
    "verification": '<p class="empty">No verifications in the catalog.</p>',
    "diameters": '<p class="empty">No diameters in the catalog.</p>',
    "discrepancy": '<p class="empty">No findings in the catalog.</p>',
    "quarantine": '<p class="empty">No quarantined scans.</p>',
}

SECTIONS = (("calibration", "Calibration"), ("verification", "Verification"), ("diameters", "Diameters"),
            ("discrepancy", "Discrepancy"), ("papers", "Papers"), ("quarantine", "Quarantine"))

#: A month page has every section but the papers (they do not depend on the nights).
MONTH_SECTIONS = tuple(s for s in SECTIONS if s[0] != "papers")


def _page(title: str, header: str, nav: str, body: str, footer: str = "") -> str:
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>{_e(title)}</title><style>{CSS}</style></head><body>"
        f"{header}<nav>{nav}</nav><main>{body}{footer}</main></body></html>\n"
    )


def _header(totals: dict[str, Any], subtitle: str = "") -> str:
    span = f"{totals['first']} – {totals['last']}" if totals["first"] else "no nights"
    return (f"<header><h1>borescan report{_e(subtitle)}</h1><p>{_e(span)} · {totals['scans']} scans "
            f"({totals['quarantined']} quarantined) · {totals['calibrations']} calibrations · "
            f"{totals['diameters']} diameters · {totals['verifications']} verifications</p></header>")


#: Placeholders for the page's way back to the results folder and to the month's plots: a month's
#: sections are rendered once and placed on its own page and, for the latest month, on report.html.
_UP, _PLOTS = "@@UP@@", "@@PLOTS@@"


def _month_sections(root: Path, month: str, tables: dict[str, pl.DataFrame], cache: _PlotCache) -> dict[str, Any]:
    """A month's header counts and section bodies, with the link placeholders."""
    b = _Builder(root, tables, cache, up=_UP, plots=_PLOTS)
    return {"counts": _counts(tables), "sections": {sid: getattr(b, sid)() for sid, _title in MONTH_SECTIONS}}


def _place(fragment: str, up: str, plots: str) -> str:
    return fragment.replace(_UP, up).replace(_PLOTS, plots)


def _month_page(month: str, parts: dict[str, Any]) -> str:
    body = [f'<section id="{sid}"><h2>{title} · {_e(month)}</h2>{_place(parts["sections"][sid], "../../", "")}'
            "</section>" for sid, title in MONTH_SECTIONS]
    nav = '<a href="../../report.html">← report</a>' + "".join(
        f'<a href="#{sid}">{title}</a>' for sid, title in MONTH_SECTIONS)
    return _page(f"borescan report {month}", _header(parts["counts"], f" · {month}"), nav, "".join(body))


@dataclass(frozen=True)
class ReportUpdate:
    """What :func:`update_report` did: the page, the months whose page was (re)written, plots drawn."""

    path: Path
    months: tuple[str, ...]
    rendered: tuple[str, ...]
    plots_drawn: int


def update_report(results_root: str | os.PathLike, tables: dict[str, pl.DataFrame] | None = None,
                  full: bool = False) -> ReportUpdate:
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


def _update(root: Path, con, full: bool) -> ReportUpdate:
    report_dir = root / REPORT_DIR
    report_dir.mkdir(parents=True, exist_ok=True)
    for stray in report_dir.iterdir():  # plots of the single-page layout, month folders of gone months
        if stray.is_file():
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
        if not full and done.is_file() and (folder / "index.html").is_file() and \
                (folder / "sections.json").is_file():
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
    papers = _Builder(root, {}, _PlotCache(report_dir), up="").papers()
    body = []
    for sid, title in SECTIONS:
        if sid == "papers":
            body.append(f'<section id="{sid}"><h2>{title}</h2>{papers}</section>')
        elif month is None:
            body.append(f'<section id="{sid}"><h2>{title}</h2>{_EMPTY[sid]}</section>')
        else:
            fragment = _place(parts[month]["sections"][sid], "", f"{REPORT_DIR}/{month}/")
            body.append(f'<section id="{sid}"><h2>{title} · {_e(month)}</h2>{fragment}</section>')
    counts = {m: (n, s, q) for m, n, s, q in _month_summary(con)}
    rows = [[_link(f"{REPORT_DIR}/{m}/index.html", m), *(str(c) for c in counts.get(m, (0, 0, 0)))] for m in prints]
    body.append('<section id="months"><h2>Months</h2>'
                + (f'<p class="note">The sections above show the latest month, {_e(month)}; every month has its '
                   "own page.</p>" + _table(["month", "nights", "scans", "quarantined"], rows, num_cols={1, 2, 3})
                   if rows else '<p class="empty">No nights in the catalog.</p>') + "</section>")
    nav = "".join(f'<a href="#{sid}">{title}</a>' for sid, title in SECTIONS) + '<a href="#months">Months</a>'
    footer = ('<p class="note">History: <code>borescan sql "SELECT * FROM scans"</code> or '
              "<code>duckdb -readonly catalog.duckdb</code>; chain behind any number: <code>borescan trace ID</code>.</p>")
    page = atomic_write_text(root / "report.html", _page("borescan report", _header(totals), nav, "".join(body), footer))
    return ReportUpdate(page, tuple(prints), tuple(rendered), drawn)


def write_report(results_root: str | os.PathLike, tables: dict[str, pl.DataFrame] | None = None,
                 full: bool = False) -> Path:
    """Write ``<results_root>/report.html`` (and the month pages); return the page's path.

    See :func:`update_report`; ``tables`` defaults to the catalog's contents.
    """
    return update_report(results_root, tables, full).path
