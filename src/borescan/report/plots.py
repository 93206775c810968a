"""The report's plots (pure: polars frames in, a matplotlib Figure out; Agg, no pyplot state)."""

from __future__ import annotations

import textwrap

import matplotlib as mpl
import numpy as np
import polars as pl
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import TICKDOWN, Line2D

from borescan.decision import CANNOT_DECIDE
from borescan.png import rgb_png
from borescan.report.spc import MR_D2, RUN_RULES, control_limits, run_rules

TRI_PARAMS = (("beta_rad", "u_beta_rad"), ("rho_mm", "u_rho_mm"), ("d_b_mm", "u_d_b_mm"))
ROD_PARAMS = (
    ("l0_mm", "u_l0_mm"),
    ("h_mm", "u_h_mm"),
    ("phi_rad", "u_phi_rad"),
    ("d_mm", "u_d_mm"),
    ("gamma_rad", "u_gamma_rad"),
)
#: the report plots' resolution
PNG_DPI = 100


def _labels(df: pl.DataFrame, id_col: str = "scan_id") -> list[str]:
    nights = df["night"].to_list() if "night" in df.columns else [None] * df.height
    ids = df[id_col].to_list()
    return [f"{'' if n is None else n}\n{i}" for n, i in zip(nights, ids, strict=True)]


#: At most this many labelled ticks per axis: a month of nights stays readable, and drawing
#: text is what a plot's cost grows with.
MAX_TICK_LABELS = 8


#: More points than this on a panel are drawn small, without caps and with thin lines (their
#: error bars' caps would merge).
_DENSE_POINTS = 30


#: Error bars of a few points, and of more than :data:`_DENSE_POINTS`.
_POINT_STYLE = {"ms": 4, "capsize": 3}
_DENSE_STYLE = {"ms": 2.5, "capsize": 0, "lw": 0.8, "elinewidth": 0.8}


#: Width of one character of a 7 pt tick label [in], with room between labels (DejaVu Sans averages
#: about 0.55 em a character).
_CHAR_WIDTH_IN = 0.075


def _xticks(ax, labels: list[str], most: int = MAX_TICK_LABELS, width_in: float | None = None) -> None:
    """Label the x positions 0..n-1; with more than ``most`` labels, every k-th.

    The labels are slanted when there are many of them, or, given the axes' width ``width_in`` [in],
    when their longest lines side by side would not fit in it (long scan ids would overlap).
    """
    step = -(-len(labels) // most) if labels else 1
    pos = list(range(0, len(labels), step))
    ax.set_xticks(pos)
    slant = len(pos) > max(2, most // 2)  # a narrow panel slants its labels sooner
    if width_in is not None and pos:
        longest = max(len(line) for i in pos for line in labels[i].split("\n"))
        slant = slant or len(pos) * longest * _CHAR_WIDTH_IN > width_in
    ax.set_xticklabels(
        [labels[i] for i in pos], rotation=45 if slant else 0, ha="right" if slant else "center", fontsize=7
    )


def _held(df: pl.DataFrame, p: str, up: str) -> bool:
    """Whether ``p`` has one value in every row and no uncertainty (held, not fitted: a flat panel)."""
    per_channel = df.drop_nulls(p).group_by("channel").agg(pl.col(p).n_unique().alias("n"))
    u = df[up].fill_null(0.0).abs().max() if up in df.columns else 0.0
    return bool((per_channel["n"] == 1).all()) and not u


#: Labelled calibrations on a trend panel (3.2 in: a few two-line labels).
_TREND_LABELS = 4


def _trend_xaxis(axes, used: set, labels: list[str], nights: list[str], ids: list[str]) -> None:
    """Label the shared x axis of a trend grid on its bottom panels; hide the unused panels.

    Up to :data:`_TREND_LABELS` calibrations each as "night / scan" (a 3.2 in panel holds a few
    two-line labels), more by night as the control charts (:func:`_night_ticks`).
    """
    for i, row in enumerate(axes):
        for j, ax in enumerate(row):
            if (i, j) not in used:
                ax.set_visible(False)
                continue
            if len(labels) <= _TREND_LABELS:
                _xticks(ax, labels, most=_TREND_LABELS)
            else:
                _night_ticks([ax], nights, ids, most=_TREND_LABELS)
            ax.tick_params(axis="x", labelbottom=i == len(axes) - 1 or (i + 1, j) not in used)


def plot_calibration_trends(cal: pl.DataFrame, device_id: str) -> Figure:
    """Calibration parameters of one device over its calibrations, one panel per parameter and channel.

    ``cal`` has the ``calibrations`` columns; rows of other devices are ignored. Error bars are
    U (k=2) = 2·u of the standard uncertainties where present. The x axis lists the calibrations in
    ``valid_from`` order, labelled with night and calibration scan; beyond four calibrations by
    night (thinned, a mark per night), and beyond 30 drawn small, without caps.
    """
    df = cal.filter(pl.col("device_id") == device_id).sort("valid_from", "calibration_id", "channel")
    present = [p for p in TRI_PARAMS + ROD_PARAMS if p[0] in df.columns and df[p[0]].drop_nulls().len() > 0]
    held = [p for p, up in present if _held(df, p, up)]
    params = [p for p in present if p[0] not in held] or present
    channels = sorted(df["channel"].drop_nulls().unique().to_list())
    cal_order = (
        df.select("calibration_id", "valid_from", "scan_id")
        .unique("calibration_id", keep="first")
        .sort("valid_from", "calibration_id")
    )
    pos = {c: i for i, c in enumerate(cal_order["calibration_id"].to_list())}
    design = (
        set(df.filter(pl.col("method") == "nominal")["calibration_id"]) if "method" in df.columns else set()
    )
    nights = [str(v) for v in cal_order["valid_from"].to_list()]
    labels = [
        f"{v}\n{'design geometry' if c in design else s}"
        for v, s, c in zip(
            cal_order["valid_from"].to_list(),
            cal_order["scan_id"].to_list(),
            cal_order["calibration_id"].to_list(),
            strict=True,
        )
    ]
    if len(channels) <= 1:  # one channel (a one-layer rod): parameters side by side, three to a row
        nc = min(max(len(params), 1), 3)
        nr = -(-max(len(params), 1) // nc)
        cells = [(k // nc, k % nc, p, channels[0] if channels else None) for k, p in enumerate(params)]
    else:
        nr, nc = max(len(params), 1), len(channels)
        cells = [(i, j, p, ch) for i, p in enumerate(params) for j, ch in enumerate(channels)]
    dense = len(labels) > _DENSE_POINTS
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
        ax.errorbar(x, y, yerr=err, fmt="o-", color="C0", **(_DENSE_STYLE if dense else _POINT_STYLE))
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
        ax.grid(alpha=0.3)
        if len(channels) <= 1:
            ax.set_title(f"{p} (channel {ch})", fontsize=9)
        elif i == 0:
            ax.set_title(f"channel {ch}", fontsize=9)
        if j == 0 or len(channels) <= 1:
            ax.set_ylabel(p, fontsize=8)
        ax.tick_params(axis="y", labelsize=7)
    _trend_xaxis(axes, used, labels, nights, cal_order["scan_id"].to_list())
    values = "; ".join(
        f"{p} " + ", ".join(f"{df.filter(pl.col('channel') == ch)[p].drop_nulls()[0]:g}" for ch in channels)
        for p in held
    )
    fixed = (
        "\n"
        + textwrap.fill(  # wrapped to the figure's width (about 12 characters an inch at 10 pt)
            f"not fitted (the same in every calibration, no uncertainty; channel "
            f"{', '.join(map(str, channels))}): {values}",
            width=int(12 * fig.get_figwidth()),
        )
        if held and params != present
        else ""
    )
    fig.suptitle(f"{device_id}: calibration parameters (error bars: U (k=2)){fixed}", fontsize=10)
    return fig


#: A label drawn over data stays legible.
_LABEL_BOX = {"boxstyle": "square,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.75}


def _night_marks(axes: list, at: list[int]) -> None:
    """Mark x positions ``at`` below each of ``axes`` as matplotlib draws a minor x tick there.

    One artist per axes for all the marks (minor ticks are an artist set each, laid out and drawn
    one by one): the same marker, size, width and colour as the ``xtick.minor`` style, kept out of
    the layout as tick marks are.
    """
    if not at:
        return
    for ax in axes:
        ax.add_artist(
            Line2D(
                at,
                [0.0] * len(at),
                transform=ax.get_xaxis_transform(),
                linestyle="none",
                marker=TICKDOWN,
                markersize=mpl.rcParams["xtick.minor.size"],
                markeredgewidth=mpl.rcParams["xtick.minor.width"],
                color=mpl.rcParams["xtick.color"],
                markeredgecolor=mpl.rcParams["xtick.color"],
                clip_on=False,
                in_layout=False,
            )
        )


def _night_ticks(axes: list, nights: list, ids: list, most: int = MAX_TICK_LABELS) -> None:
    """Label points 0..n-1 on the shared x axis of ``axes`` (the last one shows the labels) by night.

    Every point as "night / scan" when there are at most ``most``, else at most ``most`` nights
    (the first point of every k-th night) and a short mark per night (:func:`_night_marks`).
    """
    ax = axes[-1]
    n = len(nights)
    if n <= most:
        _xticks(ax, [f"{'' if d is None else d}\n{i}" for d, i in zip(nights, ids, strict=True)], most)
        return
    firsts = [i for i in range(n) if i == 0 or nights[i] != nights[i - 1]]
    step = -(-len(firsts) // most)
    pos = firsts[::step]
    ax.set_xticks(pos)
    ax.set_xticklabels([str(nights[i]) for i in pos], rotation=30, ha="right", fontsize=7)
    if len(firsts) <= 120:  # a mark per night while they stay apart; a labelled night has its tick
        labelled = set(pos)
        _night_marks(axes, [i for i in firsts if i not in labelled])


def _moving_range_panel(ax_mr, lim: dict, x: np.ndarray, ms: float, small: bool) -> None:
    """Draw the moving-range chart of :func:`plot_control_chart`: MR [µm], MR̄ and its UCL."""
    mr = lim["mr"] * 1e3
    ax_mr.plot(x[1:], mr, "o-", color="C0", ms=ms - 1, lw=0.8 if small else 1)
    if np.isfinite(lim["mr_bar"]):
        ax_mr.axhline(lim["mr_bar"] * 1e3, color="k", lw=1)
        ax_mr.axhline(lim["mr_ucl"] * 1e3, ls="--", color="C1", lw=1)
        for label, key in (("MR̄", "mr_bar"), ("UCL", "mr_ucl")):
            ax_mr.annotate(
                f"{label} {lim[key] * 1e3:.2f}",
                (0.995, lim[key] * 1e3),
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
    bars = np.full(df.height, np.nan)  # U (k=2) [µm] where the rows give it
    if "u_error_mm" in df.columns and df["u_error_mm"].drop_nulls().len():
        big_u = 2.0 * df["u_error_mm"].cast(pl.Float64).fill_null(float("nan")).to_numpy() * 1e3
        bars = big_u
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
    # each point by its verdict under the decision rule; rows without one by the acceptance alone
    verdict = (
        df["conformity"].cast(pl.Utf8).fill_null("").to_numpy()
        if "conformity" in df.columns
        else np.full(df.height, "")
    )
    undecided = verdict == CANNOT_DECIDE
    shown_pass = passed & ~undecided
    ax_i.plot(
        x[shown_pass],
        y[shown_pass],
        "o",
        color="C0",
        ms=ms,
        label="conforms" if "conformity" in df.columns else "passed",
    )
    if undecided.any():
        ax_i.plot(x[undecided], y[undecided], "D", color="C1", ms=ms, label="cannot decide (U too large)")
    if (~passed & ~undecided).any():
        ax_i.plot(
            x[~passed & ~undecided],
            y[~passed & ~undecided],
            "s",
            color="C3",
            ms=ms + 1,
            label="does not conform",
        )
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
    if np.isfinite(y - bars).any():  # the error bars whole, not cut at the axes
        lo, hi = min(lo, float(np.nanmin(y - bars))), max(hi, float(np.nanmax(y + bars)))
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
    _moving_range_panel(ax_mr, lim, x, ms, small)
    ax_mr.set_xlim(-0.5, max(df.height - 0.5, 0.5))
    _night_ticks(
        [ax_i, ax_mr],
        df["night"].cast(pl.Utf8).to_list() if "night" in df.columns else [None] * df.height,
        df["scan_id"].to_list(),
    )
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


#: A part's panel: width per measurement [in] and the figure's widest [in].
_PART_POINT_IN, _PART_MAX_IN = 0.06, 8.0


def plot_diameters(dia: pl.DataFrame, artifact_id: str) -> Figure:
    """Diameters of one part, one panel per feature: each scan with U (k=2) error bars, mean line.

    ``dia`` has the ``diameters`` columns; rows of other parts are ignored. Diameters at 20 °C
    (``diameter_20_mm``, ``u_diameter_20_mm``) where every row has them, else as measured; error
    bars U = 2u. The nominal (``nominal_mm``, see :func:`update_report`) is a dashed line and the
    tolerance band (``tolerance_mm``) shaded where known. The x axis is the measurement order,
    labelled with night and scan; beyond :data:`MAX_TICK_LABELS` measurements by night (thinned, a
    mark per night, as the control charts).
    """
    df = dia.filter(pl.col("artifact_id") == artifact_id)
    features = sorted(df["feature"].fill_null("").unique().to_list())
    nc = min(len(features), 3) or 1
    nr = -(-max(len(features), 1) // nc)
    most = max([df.filter(pl.col("feature").fill_null("") == f).height for f in features] + [1])
    # a few points: room for every "night / scan" label; more: labelled by night (thinned), so the
    # width follows the points up to a page's width, and dense points lose their caps
    panel_w = min(max(3.8, _PART_POINT_IN * most), max(3.8, _PART_MAX_IN / nc))
    style = _DENSE_STYLE if most > _DENSE_POINTS else _POINT_STYLE
    fig = Figure(figsize=(panel_w * nc + 0.8, 3.2 * nr + 0.8), layout="constrained")
    axes = fig.subplots(nr, nc, squeeze=False)
    where = "as measured"
    for k, feat in enumerate(features):
        ax = axes[k // nc][k % nc]
        sub = df.filter(pl.col("feature").fill_null("") == feat)
        y, big_u, at20 = _part_values(sub)
        where = "at 20 °C" if at20 else where
        x = np.arange(sub.height)
        ax.errorbar(x, y, yerr=big_u, fmt="o", color="C0", label="U (k=2)", **style)
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
        ax.set_title(f"feature {feat} (n={sub.height})" if feat else f"the bore (n={sub.height})", fontsize=9)
        ax.set_ylabel(f"diameter {where} [mm]", fontsize=8)
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
        ax.tick_params(axis="y", labelsize=7)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, loc="best")
        ax.set_xlim(-0.5, max(sub.height - 0.5, 0.5))
        if sub.height <= MAX_TICK_LABELS or "night" not in sub.columns:
            _xticks(ax, _labels(sub), width_in=panel_w)
        else:
            _night_ticks([ax], sub["night"].cast(pl.Utf8).to_list(), sub["scan_id"].to_list())
    for k in range(len(features), nr * nc):
        axes[k // nc][k % nc].set_visible(False)
    fig.suptitle(f"part {artifact_id}: diameters {where} (error bars: U (k=2))", fontsize=10)
    return fig


def _png_bytes(fig: Figure) -> bytes:
    """Return the PNG of ``fig`` at 100 dpi: the pixels savefig draws, written by :mod:`borescan.png`."""
    canvas = FigureCanvasAgg(fig)
    fig.set_dpi(PNG_DPI)
    canvas.draw()
    return rgb_png(np.asarray(canvas.buffer_rgba()), dpi=PNG_DPI)
