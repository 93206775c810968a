"""The browsable report: ``<results_root>/report.html`` with its plots in ``<results_root>/report/``.

:func:`write_report` reads the history catalog and writes one self-contained HTML page (inline
CSS, no scripts, no network) whose every link is relative to the results folder, so the folder
can be moved or copied to shared storage and the page still works. Sections:

- **Calibration**: parameter trends per device and channel with error bars (standard
  uncertainty, k=1), links to each certificate (PDF and JSON).
- **Verification**: per device an individuals and moving-range control chart of the
  verification error; limits (Montgomery, *Statistical Quality Control*, §6.4):
  centre line = mean, UCL/LCL = mean ± 2.66·MR̄, MR chart UCL = 3.267·MR̄, LCL = 0; plus the
  measurements a failed verification puts in doubt.
- **Diameters**: certified diameters per part and feature, each scan with its uncertainty.
- **Discrepancy**: findings with verdicts and links to ``discrepancy/<scan_id>/gap.png``.
- **Papers**: every PNG and CSV under ``papers/``.
- **Quarantine**: quarantined scans with their reasons.

Every plot function is pure: polars frames in, a :class:`matplotlib.figure.Figure` out (Agg,
no pyplot state). PNGs are written without time stamps, so reruns on the same catalog give the
same bytes.
"""

from __future__ import annotations

import html
import io
import os
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from borescan import catalog
from borescan.atomic import atomic_dir, atomic_write_text

__all__ = [
    "MR_D2_FACTOR",
    "MR_D4",
    "control_limits",
    "plot_calibration_trends",
    "plot_control_chart",
    "plot_diameters",
    "load_tables",
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


def _xticks(ax, labels: list[str]) -> None:
    ax.set_xticks(range(len(labels)))
    ax.set_xticklabels(labels, rotation=45 if len(labels) > 4 else 0, ha="right" if len(labels) > 4 else "center",
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
                _xticks(axes[i][j], labels)
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
        order = {
            "scans": "night, started_at, scan_id",
            "calibrations": "device_id, valid_from, calibration_id, channel",
            "calibration_scans": "calibration_id, scan_id",
            "diameters": "artifact_id, feature, night, scan_id",
            "verifications": "device_id, night, scan_id",
            "findings": "scan_id, effect, channel",
            "quarantine": "scan_id, stage",
            "artifacts": "artifact_id",
            "scan_files": "scan_id, file",
        }
        for t in catalog.SCHEMA:
            out[t] = con.sql(f"SELECT * FROM {t} ORDER BY {order.get(t, '1')}").pl()
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


class _Builder:
    def __init__(self, root: Path, tables: dict[str, pl.DataFrame], plot_dir: Path):
        self.root = root
        self.t = tables
        self.plot_dir = plot_dir
        self.pngs: list[str] = []

    def figure(self, fig: Figure, name: str, alt: str) -> str:
        fname = _safe(name) + ".png"
        (self.plot_dir / fname).write_bytes(_png_bytes(fig))
        self.pngs.append(fname)
        return f'<img src="{REPORT_DIR}/{html.escape(fname, quote=True)}" alt="{_e(alt)}">'

    # ---------------------------------------------------------------- sections
    def calibration(self) -> str:
        cal = self.t["calibrations"]
        if cal.height == 0:
            return '<p class="empty">No calibrations in the catalog.</p>'
        out = []
        cs = self.t["calibration_scans"]
        for dev in sorted(cal["device_id"].drop_nulls().unique().to_list()):
            out.append(f"<h3>Device {_e(dev)}</h3>")
            measured = cal.filter((pl.col("device_id") == dev) & (pl.col("method") != "nominal"))
            if measured.height:  # design geometry (method "nominal") does not trend: table only
                out.append(self.figure(plot_calibration_trends(cal, dev), f"calibration_{dev}",
                                       f"calibration parameters of {dev}"))
            rows = []
            per = cal.filter(pl.col("device_id") == dev).unique("calibration_id", keep="first").sort(
                "valid_from", "calibration_id")
            for r in per.iter_rows(named=True):
                scans = cs.filter(pl.col("calibration_id") == r["calibration_id"])["scan_id"].to_list()
                cert = r.get("certificate_path")
                pdf = _rel(self.root, cert)
                cj = catalog.certificate_json_path(self.root, cert) if cert else None
                json_link = _rel(self.root, str(cj)) if cj else None
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
            return '<p class="empty">No verifications in the catalog.</p>'
        out = [
            '<p class="note">Individuals chart of the verification error (measured − certified ring-gauge '
            "diameter) with limits mean ± 2.66·MR̄; moving-range chart with UCL = 3.267·MR̄.</p>"
        ]
        for dev in sorted(ver["device_id"].drop_nulls().unique().to_list()):
            sub = ver.filter(pl.col("device_id") == dev)
            lim = control_limits(sub["error_mm"].to_numpy())
            out.append(f"<h3>Device {_e(dev)}</h3>")
            out.append(self.figure(plot_control_chart(ver, dev), f"control_{dev}", f"control chart of {dev}"))
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
            return '<p class="empty">No diameters in the catalog.</p>'
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
            out.append(self.figure(plot_diameters(dia, part),
                                   f"diameters_{part}", f"diameters of {part}"))
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
            return '<p class="empty">No findings in the catalog.</p>'
        rows, classes = [], []
        for r in fnd.iter_rows(named=True):
            sid = r["scan_id"]
            gap = _rel(self.root, f"discrepancy/{sid}/gap.png")
            fj = _rel(self.root, f"discrepancy/{sid}/findings.json")
            links = " ".join(x for x in (_link(gap, "gap.png") if gap else "", _link(fj, "findings.json") if fj else "")
                             if x)
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
            rel = f.relative_to(self.root).as_posix()
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
            return '<p class="empty">No quarantined scans.</p>'
        ids = sorted(set(sc["scan_id"].to_list()) | set(q["scan_id"].to_list()))
        rows = []
        for sid in ids:
            s = sc.filter(pl.col("scan_id") == sid)
            qq = q.filter(pl.col("scan_id") == sid)
            srow = s.row(0, named=True) if s.height else {}
            stages = ", ".join(sorted(set(qq["stage"].drop_nulls().to_list())))
            reasons = [srow.get("reason")] if srow.get("reason") else []
            reasons += [f"{r['file']}: {r['reason']}" for r in qq.iter_rows(named=True)
                        if f"{r['file']}: {r['reason']}" not in reasons]
            rec = _rel(self.root, f"quarantine/{sid}.json")
            rows.append([_e(sid), _e(srow.get("night") or (qq["night"][0] if qq.height else None)),
                         _e(srow.get("device_id")), _e(srow.get("kind")), _e(stages),
                         "<br>".join(_e(r) for r in reasons), _link(rec, "record") if rec else ""])
        return _table(["scan", "night", "device", "kind", "stage", "reason", "record"], rows)

    def header(self) -> str:
        sc = self.t["scans"]
        nights = sorted({str(n) for n in sc["night"].drop_nulls().to_list()})
        span = f"{nights[0]} – {nights[-1]}" if nights else "no nights"
        nq = sc.filter(pl.col("status") == "quarantined").height
        return (f"<header><h1>borescan report</h1><p>{_e(span)} · {sc.height} scans ({nq} quarantined) · "
                f"{self.t['calibrations']['calibration_id'].n_unique()} calibrations · "
                f"{self.t['diameters'].height} diameters · {self.t['verifications'].height} verifications</p>"
                "</header>")


SECTIONS = (("calibration", "Calibration"), ("verification", "Verification"), ("diameters", "Diameters"),
            ("discrepancy", "Discrepancy"), ("papers", "Papers"), ("quarantine", "Quarantine"))


def write_report(results_root: str | os.PathLike, tables: dict[str, pl.DataFrame] | None = None) -> Path:
    """Write ``<results_root>/report.html`` and its plots ``<results_root>/report/*.png``; return the page's path.

    ``tables`` (name -> polars frame, as :func:`load_tables` returns) defaults to the catalog's
    contents. The plot folder is rebuilt atomically, then the page is written atomically; all
    links are relative to ``results_root``.
    """
    root = Path(results_root)
    t = load_tables(root) if tables is None else dict(tables)
    for name, cols in catalog.SCHEMA.items():
        if name not in t or t[name] is None:
            t[name] = pl.DataFrame(schema={c: pl.Utf8 for c in cols})
    with atomic_dir(root / REPORT_DIR) as plot_dir:
        b = _Builder(root, t, plot_dir)
        body = [f'<section id="{sid}"><h2>{title}</h2>{getattr(b, sid)()}</section>' for sid, title in SECTIONS]
    nav = "".join(f'<a href="#{sid}">{title}</a>' for sid, title in SECTIONS)
    page = (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>borescan report</title><style>{CSS}</style></head><body>"
        f"{b.header()}<nav>{nav}</nav><main>{''.join(body)}"
        '<p class="note">History: <code>borescan sql "SELECT * FROM scans"</code> or '
        "<code>duckdb -readonly catalog.duckdb</code>; chain behind any number: <code>borescan trace ID</code>.</p>"
        "</main></body></html>\n"
    )
    return atomic_write_text(root / "report.html", page)
