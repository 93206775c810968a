"""What each device's model did to the gaps over the nights: the history and its plot."""

from __future__ import annotations

import html
import json
import re
from typing import Any

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from borescan.report.plots import _LABEL_BOX, _xticks
from borescan.report.text import _e, _parameters_text


#: How the calibrate stage states a refused channel's residual: "residual rms is 1.45 times the
#: readings' own noise floor".
_REFUSED_RATIO = re.compile(r"residual rms is ([0-9.]+) times the readings' own noise floor")


def refused_calibrations(scans: pl.DataFrame | None, quarantine: pl.DataFrame | None) -> pl.DataFrame:
    """Return the calibrations refused per device and night, from the quarantine records of the catalog.

    Columns ``night``, ``device_id``, ``scan_ids`` (comma-separated) and ``residual_to_noise``: the
    largest residual over the noise floor the refusal states (null when it states none). A calibration
    refused on several scans is one row.
    """
    schema = {"night": pl.Utf8, "device_id": pl.Utf8, "scan_ids": pl.Utf8, "residual_to_noise": pl.Float64}
    if scans is None or quarantine is None or quarantine.height == 0 or scans.height == 0:
        return pl.DataFrame(schema=schema)
    q = quarantine.filter(
        pl.col("reason").fill_null("").str.contains("calibration refused") & pl.col("night").is_not_null()
    )
    q = q.join(scans.select("scan_id", "device_id").unique("scan_id"), on="scan_id", how="left")
    rows: dict[tuple[str, str], dict] = {}
    for r in q.sort("night", "scan_id").iter_rows(named=True):
        x = rows.setdefault(
            (str(r["night"]), r["device_id"]),
            {
                "night": str(r["night"]),
                "device_id": r["device_id"],
                "scan_ids": [],
                "residual_to_noise": None,
            },
        )
        x["scan_ids"].append(r["scan_id"])
        ratios = [float(v) for v in _REFUSED_RATIO.findall(r["reason"])]
        if ratios:
            x["residual_to_noise"] = max(ratios + [x["residual_to_noise"] or 0.0])
    out = [{**x, "scan_ids": ",".join(x["scan_ids"])} for x in rows.values()]
    return pl.DataFrame(out, schema=schema)


def _largest_e_over_u(ver: pl.DataFrame | None, device_id: str) -> list[dict[str, Any]]:
    """Return per night the device's verification with the largest |error| / U (``e``), as rows."""
    if ver is None or ver.height == 0 or "expanded_u_error_mm" not in ver.columns:
        return []
    v = (
        ver.filter((pl.col("device_id") == device_id) & (pl.col("expanded_u_error_mm") > 0))
        .with_columns(e=pl.col("error_mm").abs() / pl.col("expanded_u_error_mm"))
        .sort("e", descending=True)
    )
    return v.unique("night", keep="first").to_dicts()


def device_model_history(
    pooled: pl.DataFrame | None,
    cal: pl.DataFrame | None,
    ver: pl.DataFrame | None,
    device_id: str,
    refused: pl.DataFrame | None = None,
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
    while the estimates follow each night); ``refused_residual_to_noise``: a calibration of the night
    that was refused (``refused``: :func:`refused_calibrations`), its worst residual over the noise
    floor (NaN when its reason states none). A night without a figure has null there.
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
                "refused_residual_to_noise": None,
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
    for r in _largest_e_over_u(ver, device_id):
        row(r["night"]).update(
            verification_e_over_u=float(r["e"]), verification_error_um=float(r["error_mm"]) * 1e3
        )
    if refused is not None and refused.height:
        for r in refused.filter(pl.col("device_id") == device_id).iter_rows(named=True):
            ratio = r["residual_to_noise"]
            row(r["night"])["refused_residual_to_noise"] = float("nan") if ratio is None else float(ratio)
    schema = {
        "night": pl.Utf8,
        "pooled_gap_to_noise": pl.Float64,
        "calibration_residual_to_noise": pl.Float64,
        "verification_e_over_u": pl.Float64,
        "verification_error_um": pl.Float64,
        "carried": pl.Utf8,
        "carried_keys": pl.Utf8,
        "refused_residual_to_noise": pl.Float64,
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
    if "refused_residual_to_noise" in hist.columns:
        refused = hist["refused_residual_to_noise"].cast(pl.Float64).to_numpy()
        known = ~np.isnan(refused)  # a null (no refusal) reads as NaN; a refusal without a ratio too
        if known.any():
            ax_g.plot(
                x[known],
                refused[known],
                "X",
                color="C3",
                ms=9,
                ls="none",
                label="calibration refused: residual / noise floor",
            )
        unknown = hist["refused_residual_to_noise"].is_nan().fill_null(False).to_numpy()
        for xi in x[unknown]:
            ax_g.annotate(
                "calibration refused",
                (xi, 0.5),
                xycoords=("data", "axes fraction"),
                fontsize=7,
                color="C3",
                ha="center",
                bbox=_LABEL_BOX,
            )
    ax_g.axhline(1.0, color="k", lw=1)
    ax_g.set_ylabel("rms / noise floor")
    ratios = hist.select(
        pl.col(
            c
            for c in ("pooled_gap_to_noise", "calibration_residual_to_noise", "refused_residual_to_noise")
            if c in hist.columns
        ).cast(pl.Float64)
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
