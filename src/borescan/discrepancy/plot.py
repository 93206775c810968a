"""gap.png: residuals before and after the named effect, against angle and time, and their spectrum."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from borescan.discrepancy.fitting import leading_block

__all__ = ["plot_gap"]


def _spectrum(r: np.ndarray, dt: float, rev_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude spectrum [mm] of each channel's residual against undulations per revolution."""
    z = np.where(np.isfinite(r), r, 0.0)
    z = z - z.mean(axis=0)
    n = z.shape[0]
    nfft = 1 << int(math.ceil(math.log2(max(n, 2) * 4)))
    amp = 2.0 * np.abs(np.fft.rfft(z, nfft, axis=0)) / n
    return np.fft.rfftfreq(nfft, dt) / rev_hz, amp


#: Blank figures of this process by layout (panels, channels, spectrum or pose rows, angle label):
#: a night's scans share a few layouts, and filling a drawn figure with the next scan's residuals
#: costs about half of building one (axes, ticks and legend are made once).
_FIGURES: dict[tuple, tuple] = {}


def _figure(n_panels: int, channels: tuple[int, ...], spectrum: bool, angle_label: str):
    """The figure of a layout, its axes (3, n_panels) and lines, built on first use (see :data:`_FIGURES`).

    Returns
    -------
    fig, axes, lines[(row, col, channel index)] -> Line2D, floor[(row, col, sign)] -> Line2D
    """
    from matplotlib import rcParams
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    key = (n_panels, channels, spectrum, angle_label)
    if key in _FIGURES:
        return _FIGURES[key]
    fig = Figure(figsize=(12 if n_panels == 2 else 7, 9.5))
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, n_panels, sharey="row", squeeze=False)
    colors = rcParams["axes.prop_cycle"].by_key()["color"]
    lines, floor = {}, {}
    for col in range(n_panels):
        for j, ch in enumerate(channels):
            color = colors[j % 10]
            lines[0, col, j], = axes[0, col].plot([], [], ".", ms=1.5, color=color, label=f"ch {ch}")
            style = "-" if spectrum else "."
            lines[1, col, j], = axes[1, col].plot([], [], style, lw=0.6, ms=2, color=color, label=f"ch {ch}")
        if spectrum:
            for j, ch in enumerate(channels):
                lines[2, col, j], = axes[2, col].plot([], [], lw=0.8, color=colors[j % 10], label=f"ch {ch}")
            axes[2, col].set_xlabel("undulations per revolution [UPR]")
        else:  # pose scans: no revolution; residual per sample index instead
            for j, ch in enumerate(channels):
                lines[2, col, j], = axes[2, col].plot([], [], ".", ms=2, color=colors[j % 10])
            axes[2, col].set_xlabel("sample (poses in order)")
        for row in (0, 1):
            for s in (-1.5, 1.5):
                floor[row, col, s] = axes[row, col].axhline(0.0, ls="--", lw=0.8, color="0.4")
        axes[0, col].set_xlabel(angle_label)
        axes[1, col].set_xlabel("time [s]")
    axes[0, 0].set_ylabel("residual [um]")
    axes[1, 0].set_ylabel("residual [um]")
    axes[2, 0].set_ylabel("amplitude [um]" if spectrum else "residual [um]")
    axes[0, 0].legend(loc="upper right", fontsize=8, markerscale=5)
    # fixed margins: tight_layout measures every tick label and costs about as much as the drawing
    fig.subplots_adjust(left=0.07 if n_panels == 2 else 0.11, right=0.98, bottom=0.06, top=0.92, hspace=0.32,
                        wspace=0.06)
    _FIGURES[key] = fig, axes, lines, floor
    return _FIGURES[key]


def plot_gap(examination, out_path: str | Path) -> Path:
    """Write gap.png for one :class:`~borescan.discrepancy.examine.Examination`.

    Rows: residual against device angle, against time, spectrum in undulations per revolution
    (UPR; pose scans: residual per sample); left column before (base model), right column after
    adding the named effect(s).
    Dashed lines mark +-1.5 noise floor. The figure of the layout is reused (:func:`_figure`).
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
    fig, axes, lines, floor = _figure(len(panels), tuple(ex.channels), bool(ex.rev_hz), ex.angle_label)
    # examined blocks of a long scan are separated in time: break the line there
    dt = np.diff(ex.t_s)
    cut = np.flatnonzero(dt > 5.0 * np.median(dt)) + 1 if dt.size else np.zeros(0, dtype=int)
    t_line = np.insert(ex.t_s, cut, np.nan)
    angle_deg = np.degrees(ex.angle_rad)
    upr_max = []
    for col, (r, label, gap) in enumerate(panels):
        for j in range(len(ex.channels)):
            y = r[:, j] * 1e3
            lines[0, col, j].set_data(angle_deg, y)
            lines[1, col, j].set_data(t_line, np.insert(y, cut, np.nan))
        if ex.rev_hz:
            nb = leading_block(ex.t_s)
            upr, amp = _spectrum(r[:nb], float(np.median(np.diff(ex.t_s[:nb]))), ex.rev_hz)
            for j in range(len(ex.channels)):
                lines[2, col, j].set_data(upr, amp[:, j] * 1e3)
            upr_max.append(min(30.0, float(upr.max()) if upr.size else 30.0))
        else:
            for j in range(len(ex.channels)):
                lines[2, col, j].set_data(np.arange(r.shape[0]), r[:, j] * 1e3)
        for row in (0, 1):
            for s in (-1.5, 1.5):
                floor[row, col, s].set_ydata([s * floor_um, s * floor_um])
        axes[0, col].set_title(f"{label}: rms {gap * 1e3:.2f} um" if gap is not None else label, fontsize=10)
    for ax in axes.flat:  # limits from this scan's data, as a new figure's would be
        ax.relim()
        ax.autoscale(True)
    for col in range(len(panels)):
        axes[0, col].set_xlim(0, 360)
        if ex.rev_hz:
            axes[2, col].set_xlim(0, upr_max[col])
    fig.suptitle(
        f"{f['scan_id']}: {f['verdict']} ({names}); noise floor {floor_um:.2f} um (dashed: +-1.5x)",
        fontsize=11,
    )
    # fast zlib level: one gap plot per scan; encoding at level 1 is ~3x faster, files ~10 % larger
    fig.savefig(out, dpi=100, metadata={"Software": None, "CreationDate": None}, pil_kwargs={"compress_level": 1})
    return out
