"""gap.png: residuals before and after the named effect, against angle and time, and their spectrum."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from borescan.discrepancy.fitting import leading_block
from borescan.png import rgb_png

__all__ = ["plot_gap", "nice_ceiling"]

#: Axis limits are rounded up to a value of this series (times a power of ten), so that the scans
#: of a night share a few limits per axis, and an axis's ticks and labels at a limit are drawn once
#: (:func:`_axis_strip`). A limit is at most 4/3 of the value rounded (the step from 3 to 4).
NICE_STEPS = (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0)

#: Extra room above the largest value before rounding up, so no marker sits on the frame.
HEADROOM = 1.05
#: Room left of 0 on the time and sample axes, as a share of the axis (the first marker whole).
MARGIN = 0.02


def nice_ceiling(value: float) -> float:
    """Return the smallest nice value at or above ``value``.

    Return the smallest value of :data:`NICE_STEPS` x 10^k at or above ``value`` (> 0); 1.0 for
    anything not positive and finite.
    """
    if not (math.isfinite(value) and value > 0.0):
        return 1.0
    k = math.floor(math.log10(value))
    for _ in range(2):  # log10 may round to the decade below or above
        for s in NICE_STEPS:
            v = float(f"{s}e{k}")
            if v >= value:
                return v
        k += 1
    return float(f"1e{k}")


def _spectrum(r: np.ndarray, dt: float, rev_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude spectrum [mm] of each channel's residual against undulations per revolution."""
    z = np.where(np.isfinite(r), r, 0.0)
    z = z - z.mean(axis=0)
    n = z.shape[0]
    nfft = 1 << int(math.ceil(math.log2(max(n, 2) * 4)))
    amp = 2.0 * np.abs(np.fft.rfft(z, nfft, axis=0)) / n
    return np.fft.rfftfreq(nfft, dt) / rev_hz, amp


#: Text drawn without the font's hinting: the glyphs' outlines as they are, about 12 % of a frame's drawing
#: less (its tick labels and titles), the same look at this size (matplotlib's default hints every glyph)
TEXT_RENDERING = {"text.hinting": "no_hinting"}

#: Figures of this process by layout (panels, channels, spectrum or pose rows, angle label): a
#: night's scans share a few layouts; axes, ticks and legend are made once per layout.
_FIGURES: dict[tuple, dict] = {}

#: Rendered axes (ticks, tick labels, axis label) by (layout, row, column, x or y, limits): the pixels drawn
#: over a layout's frame (:func:`_draw`). A night's scans rarely share all the limits of a figure
#: (117 sets for the contract night's 118 scans) but share most of each axis's (357 axes drawn instead
#: of 846). Tens of kB each (22 MB for that night).
_STRIPS: dict[tuple, tuple[int, int, np.ndarray] | None] = {}
MAX_STRIPS = 1024


def _column(
    ax, rows: dict, col: int, channels, colors, spectrum: bool, angle_label, lines: dict, floor: dict
):
    """Add one column's (empty) lines, noise-floor lines, labels and title to the axes ``ax`` of a layout."""
    from matplotlib.ticker import MultipleLocator

    residual_rows = [name for name in ("angle", "time") if name in rows]
    for j, ch in enumerate(channels):
        color = colors[j % 10]
        if "angle" in rows:
            (lines["angle", col, j],) = ax[rows["angle"]].plot(
                [], [], ".", ms=1.5, color=color, label=f"ch {ch}"
            )
        style = "-" if spectrum else "."
        (lines["time", col, j],) = ax[rows["time"]].plot(
            [], [], style, lw=0.6, ms=2, color=color, label=f"ch {ch}"
        )
    last = ax[rows["last"]]
    if spectrum:
        for j, ch in enumerate(channels):
            (lines["last", col, j],) = last.plot([], [], lw=0.8, color=colors[j % 10], label=f"ch {ch}")
        last.set_xlabel("undulations per revolution [UPR]")
    else:  # pose scans: no revolution; residual per sample index instead
        for j in range(len(channels)):
            (lines["last", col, j],) = last.plot([], [], ".", ms=2, color=colors[j % 10])
        last.set_xlabel("sample (poses in order)")
    for row in residual_rows:
        for s in (-1.5, 1.5):
            floor[row, col, s] = ax[rows[row]].axhline(0.0, ls="--", lw=0.8, color="0.4")
    if "angle" in rows:
        ax[rows["angle"]].set_xlabel(angle_label)
        ax[rows["angle"]].xaxis.set_major_locator(MultipleLocator(90.0))  # quarter turns: 0, 90, ..., 360
    ax[rows["time"]].set_xlabel("time [s]")
    ax[0].set_title(" ", fontsize=10, y=1.0)  # y given: not moved by the (hidden) title's own layout


def _figure(n_panels: int, channels: tuple[int, ...], spectrum: bool, angle_label: str | None) -> dict:
    """Return the figure of a layout, built on first use (see :data:`_FIGURES`).

    Returns a dict: ``fig``, ``axes`` (rows, n_panels), ``rows`` (row name -> index: ``angle`` unless
    ``angle_label`` is None, ``time``, ``last``), ``lines[(row name, col, channel index)]``,
    ``floor[(row name, col, sign)]`` (the dashed noise-floor lines), ``suptitle``, ``dynamic``: every
    artist that changes from scan to scan, in drawing order, and ``legend_artist`` (the same in every scan,
    drawn over the data). Once drawn, ``frame`` and ``legend`` hold their images (:func:`_frame`,
    :func:`_draw`).
    """
    from matplotlib import rcParams
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    key = (n_panels, channels, spectrum, angle_label)
    if key in _FIGURES:
        return _FIGURES[key]
    names = (["angle"] if angle_label is not None else []) + ["time", "last"]
    rows = {name: i for i, name in enumerate(names)}
    fig = Figure(figsize=(12 if n_panels == 2 else 7, 9.5 if len(rows) == 3 else 6.8))
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(rows), n_panels, sharey="row", squeeze=False)
    colors = rcParams["axes.prop_cycle"].by_key()["color"]
    lines, floor = {}, {}
    residual_rows = [name for name in ("angle", "time") if name in rows]
    for col in range(n_panels):
        _column(axes[:, col], rows, col, channels, colors, spectrum, angle_label, lines, floor)
    for row in residual_rows:
        axes[rows[row], 0].set_ylabel("residual [um]")
    axes[rows["last"], 0].set_ylabel("amplitude [um]" if spectrum else "residual [um]")
    legend = axes[0, 0].legend(loc="upper right", fontsize=8, markerscale=5)
    suptitle = fig.suptitle(" ", fontsize=10.5)  # two lines: the scan and verdict, the noise floor
    # fixed margins: tight_layout measures every tick label and costs about as much as the drawing
    fig.subplots_adjust(
        left=0.07 if n_panels == 2 else 0.11,
        right=0.98,
        bottom=0.06 if len(rows) == 3 else 0.085,
        top=0.9 if len(rows) == 3 else 0.86,
        hspace=0.32 if len(rows) == 3 else 0.36,
        wspace=0.06,
    )
    dynamic = [
        *lines.values(),
        *floor.values(),
        *(axes[0, c].title for c in range(n_panels)),
        suptitle,
    ]
    _FIGURES[key] = {
        "fig": fig,
        "axes": axes,
        "rows": rows,
        "lines": lines,
        "floor": floor,
        "suptitle": suptitle,
        "legend_artist": legend,
        "dynamic": dynamic,
        "key": key,
    }
    return _FIGURES[key]


def _frame(layout: dict):
    """Return the rendered frame of ``layout``: the figure and its axes without their axes and scan artists.

    Drawn once per layout (its :func:`_figure` ``dynamic`` artists, legend and every x and y axis hidden).
    """
    if "frame" not in layout:
        fig = layout["fig"]
        axes = (a for ax in layout["axes"].ravel() for a in (ax.xaxis, ax.yaxis))
        hidden = [*layout["dynamic"], layout["legend_artist"], *axes]
        for a in hidden:
            a.set_visible(False)
        fig.canvas.draw()
        for a in hidden:
            a.set_visible(True)
        layout["frame"] = fig.canvas.copy_from_bbox(fig.bbox)
    return layout["frame"]


def _alone(fig, artist) -> tuple[int, int, np.ndarray] | None:
    """Return ``artist`` drawn alone on ``fig``'s cleared canvas: (x, y, RGBA rows bottom up), or None.

    The pixels it covered, with their coverage (alpha), and where they go (x, y from the bottom left
    [pixels]), for the renderer's ``draw_image``; None where it drew nothing.
    """
    renderer = fig.canvas.get_renderer()
    renderer.clear()  # transparent: each pixel keeps its coverage, to be drawn over other pixels
    artist.draw(renderer)
    buf = np.asarray(renderer.buffer_rgba())
    drawn = buf[..., 3] > 0
    rows, cols = np.flatnonzero(drawn.any(axis=1)), np.flatnonzero(drawn.any(axis=0))
    if not rows.size:
        return None
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    # draw_image takes rows bottom up (the buffer's are top down)
    return int(c0), int(buf.shape[0] - r1), np.ascontiguousarray(buf[r0:r1, c0:c1][::-1])


def _axis_strip(layout: dict, row: int, col: int, axis) -> tuple[int, int, np.ndarray] | None:
    """Return ``axis`` (ticks, tick labels, label) of the axes at (``row``, ``col``) at its limits, alone.

    :func:`_alone`'s image, cached by (layout, row, column, axis, limits).
    """
    lim = tuple(axis.axes.get_xlim() if axis.axis_name == "x" else axis.axes.get_ylim())
    key = (layout["key"], row, col, axis.axis_name, lim)
    if key not in _STRIPS:
        if len(_STRIPS) >= MAX_STRIPS:
            _STRIPS.pop(next(iter(_STRIPS)))
        _STRIPS[key] = _alone(layout["fig"], axis)
    return _STRIPS[key]


def _draw_images(renderer, images) -> None:
    gc = renderer.new_gc()
    for image in images:
        if image is not None:
            renderer.draw_image(gc, *image)
    gc.restore()


def _draw(layout: dict) -> None:
    """Render ``layout`` at the axes' limits and with the scan's artists already set.

    The frame (:func:`_frame`) restored, every axis's image (:func:`_axis_strip`) and the scan's artists
    drawn over it, then the legend (the same in every scan of a layout: its image, drawn alone once). The
    pixels of a whole-figure draw to within two levels: the legend's alpha blended in one step instead of
    two, and a tick meeting a spine drawn in the other order (the axes over the spines, not under them).
    """
    strips = [
        _axis_strip(layout, row, col, axis)
        for (row, col), ax in np.ndenumerate(layout["axes"])
        for axis in (ax.xaxis, ax.yaxis)
    ]
    if "legend" not in layout:
        layout["legend"] = _alone(layout["fig"], layout["legend_artist"])
    canvas = layout["fig"].canvas
    canvas.restore_region(_frame(layout))
    renderer = canvas.get_renderer()
    _draw_images(renderer, strips)
    for a in layout["dynamic"]:
        a.draw(renderer)
    _draw_images(renderer, [layout["legend"]])


def _abs_max(*arrays: np.ndarray) -> float:
    vals = [np.nanmax(np.abs(a)) for a in arrays if a.size and np.isfinite(a).any()]
    return float(max(vals)) if vals else 0.0


def plot_gap(  # noqa: C901 (one branch per scan kind and panel of the plot)
    examination, out_path: str | Path
) -> Path:
    """Write gap.png for one :class:`~borescan.discrepancy.examine.Examination`.

    Rows: residual against device angle (left out where every sample has the same angle, as the
    poses of a static scan), against time, spectrum in undulations per revolution (UPR; pose scans:
    residual per sample); left column before (base model), right column after adding the named
    effect(s). The title's two lines: the scan and its verdict, the noise floor.
    Dashed lines mark +-1.5 noise floor. Residual axes are symmetric, +-L with L the largest
    residual (or 1.5 noise floors) rounded up by :func:`nice_ceiling`; time, sample and
    amplitude axes run from 0 to their largest value rounded up alike. So scans of a night
    share limits, the figure of a layout is reused (:func:`_figure`), its frame is drawn once and each
    axis's ticks and labels once per limit (:func:`_draw`); only the scan's own lines and
    titles are drawn for each scan. The file depends on the scan only.
    """
    ex = examination
    f = ex.findings
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    floor_um = (f.get("noise_floor_mm") or 0.0) * 1e3
    labels = [
        n["effect"] + (f" ch{n['channel']}" if n.get("channel") is not None else "") for n in f["named"]
    ]
    names = ", ".join(labels) or "none"
    if len(labels) > 2:
        names = f"{labels[0]}, {labels[1]} +{len(labels) - 2} more"
    if labels:
        panels = [
            (ex.residual_before_mm, "before (base model)", f["gap_before"]["rms_mm"]),
            (ex.residual_after_mm, f"after (+ {names})", f["gap_after"]["rms_mm"]),
        ]
    else:  # nothing added: "after" would repeat "before"
        panels = [(ex.residual_before_mm, "base model (nothing added)", f["gap_before"]["rms_mm"])]
    angle_deg = np.degrees(ex.angle_rad)
    seen = angle_deg[np.isfinite(angle_deg)]
    # a static scan's poses share one angle: a panel against it would be one vertical stripe
    has_angle = bool(seen.size) and float(np.ptp(seen)) > 0.0
    layout = _figure(len(panels), tuple(ex.channels), bool(ex.rev_hz), ex.angle_label if has_angle else None)
    fig, axes, lines, floor = layout["fig"], layout["axes"], layout["lines"], layout["floor"]
    rows = layout["rows"]
    # examined blocks of a long scan are separated in time: break the line there
    dt = np.diff(ex.t_s)
    cut = np.flatnonzero(dt > 5.0 * np.median(dt)) + 1 if dt.size else np.zeros(0, dtype=int)
    t_line = np.insert(ex.t_s, cut, np.nan)
    upr_max, amp_max = 30.0, 0.0
    for col, (r, label, gap) in enumerate(panels):
        for j in range(len(ex.channels)):
            y = r[:, j] * 1e3
            if has_angle:
                lines["angle", col, j].set_data(angle_deg, y)
            lines["time", col, j].set_data(t_line, np.insert(y, cut, np.nan))
        if ex.rev_hz:
            nb = leading_block(ex.t_s)
            upr, amp = _spectrum(r[:nb], float(np.median(np.diff(ex.t_s[:nb]))), ex.rev_hz)
            for j in range(len(ex.channels)):
                lines["last", col, j].set_data(upr, amp[:, j] * 1e3)
            upr_max = min(upr_max, float(upr.max()) if upr.size else 30.0)
            amp_max = max(amp_max, _abs_max(amp[upr <= 30.0] * 1e3))
        else:
            for j in range(len(ex.channels)):
                lines["last", col, j].set_data(np.arange(r.shape[0]), r[:, j] * 1e3)
        for (_row, c, s), line in floor.items():
            if c == col:
                line.set_ydata([s * floor_um, s * floor_um])
        axes[0, col].title.set_text(f"{label}: rms {gap * 1e3:.2f} um" if gap is not None else label)
    res_lim = nice_ceiling(HEADROOM * max(_abs_max(*(r * 1e3 for r, _, _ in panels)), 1.5 * floor_um))
    t_lim = nice_ceiling(HEADROOM * float(np.nanmax(ex.t_s))) if ex.t_s.size else 1.0
    if ex.rev_hz:
        row2 = ((0.0, upr_max), (0.0, nice_ceiling(HEADROOM * amp_max)))
    else:
        n_lim = nice_ceiling(HEADROOM * max(panels[0][0].shape[0] - 1, 1))
        row2 = ((-MARGIN * n_lim, n_lim), (-res_lim, res_lim))
    limits = ((-res_lim, res_lim), (-MARGIN * t_lim, t_lim), *row2)
    for col in range(len(panels)):
        if has_angle:
            axes[rows["angle"], col].set_xlim(0, 360)
            axes[rows["angle"], col].set_ylim(*limits[0])
        axes[rows["time"], col].set_xlim(*limits[1])
        axes[rows["time"], col].set_ylim(*limits[0])
        axes[rows["last"], col].set_xlim(*limits[2])
        axes[rows["last"], col].set_ylim(*limits[3])
    layout["suptitle"].set_text(
        f"{f['scan_id']}: {f['verdict']} ({names})\nnoise floor {floor_um:.2f} um (dashed: +-1.5x)"
    )
    from matplotlib import rc_context

    canvas = fig.canvas
    with rc_context(TEXT_RENDERING):
        _draw(layout)
    # RGB (the figure is opaque: its alpha channel carries nothing), rows unfiltered at zlib level 1
    out.write_bytes(rgb_png(np.asarray(canvas.buffer_rgba()), dpi=fig.dpi))
    return out
