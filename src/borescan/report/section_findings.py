"""The Discrepancy and Device model sections: findings, pooled verdicts, drifts."""

from __future__ import annotations

import json

import polars as pl

from borescan.config import schema_default
from borescan.report.actions import _verdict_note
from borescan.report.device_model import (
    _carried_by_calibrations,
    device_model_history,
    plot_device_model_gap,
    refused_calibrations,
)
from borescan.report.data import group_fingerprints
from borescan.report.page import Page, _EMPTY
from borescan.report.text import _e, _link, _parameters_text, _table, _um, _uncertainties


#: a gap before within this multiple of the noise floor is at the floor (schema discrepancy.floor_ratio)
_FLOOR_RATIO = float(schema_default("discrepancy", "floor_ratio"))


def discrepancy(page: Page) -> str:
    """Return the Discrepancy section: each scan's verdict, named effects with value ± u, gaps."""
    fnd = page.t["findings"]
    if fnd.height == 0:
        return _EMPTY["discrepancy"]
    out = [
        '<p class="note">Parameters: value ± u (standard uncertainty, k=1) in the effect\'s unit; '
        "gaps: rms "
        "of the residual before and after adding the named effect, against the readings' noise floor. "
        "<b>missing_effect</b>: the model misses the named effect (service the device if it persists); "
        "<b>ambiguous</b>: several named effects explain the data equally well, all listed; "
        "<b>no_missing_effect</b>: the residual is at the noise floor; "
        "<b>offset-like</b>: effects that shift readings alike (offsets, gains, bows, beams) tie; "
        "the statement gives what the data fix (a rod layer's reading shift, or a static set's "
        "combination of its channels' zeroes) and the calibration that absorbs it.</p>"
    ]
    rows, classes = [], []
    keys = group_fingerprints(fnd, "scan_id")  # a scan's row is rendered again only when its rows change
    recs_of: dict[str | None, list[dict]] | None = None  # the rows of each scan, converted when needed
    for sid in dict.fromkeys(fnd["scan_id"].to_list()):  # scans in first-seen order

        def render(sid=sid) -> list:
            nonlocal recs_of
            if recs_of is None:  # one conversion: a polars group per scan cost ~0.2 ms each
                recs_of = {}
                for r in fnd.to_dicts():
                    recs_of.setdefault(r["scan_id"], []).append(r)
            return _finding_row(page, sid, recs_of[sid])

        row, cls = page.piece("findings scan", f"{sid} {keys.get(sid)}", render)
        rows.append(row)
        classes.append(cls)
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


def _finding_row(page: Page, sid: str | None, recs: list[dict]) -> list:
    """Return a scan's row of the Discrepancy table (cells) and its class ("fail", "warn" or "")."""
    first = recs[0]
    uncertainties = _finding_uncertainties(page, sid, recs)
    gap = page.link(f"discrepancy/{sid}/gap.png")
    fj = page.link(f"discrepancy/{sid}/findings.json")
    links = " ".join(
        x for x in (_link(gap, "gap.png") if gap else "", _link(fj, "findings.json") if fj else "") if x
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
    row = [
        _e(sid),
        _e(first.get("night")),
        f"<b>{_e(verdict)}</b>" + (f"<br>{note}" if note else ""),
        "<br>".join(effects),
        _um(first.get("gap_before_mm"), 2),
        _um(first.get("gap_after_mm"), 2),
        _um(first.get("noise_floor_mm"), 2),
        links,
    ]
    # flagged for a person only where the gap before stands above the noise floor (floor_ratio)
    visible = (first.get("gap_before_mm") or 0.0) > _FLOOR_RATIO * (first.get("noise_floor_mm") or 0.0)
    flag = "fail" if verdict == "missing_effect" else "warn" if verdict == "ambiguous" else ""
    return [row, flag if visible else ""]


def pooled(  # noqa: C901 (one branch per optional column of the report's pooled table)
    page,
) -> str:
    """Return the pooled examinations per device and night.

    Per device and night: the spindle scans examined together (borescan.discrepancy.pooled), the
    device model's effects, what the night's calibration carried of it with its residual against the
    noise floor, the gap against the noise floor, and the calibration drifts flagged.
    """
    pf = page.t.get("pooled_findings")
    dr = page.t.get("calibration_drift")
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
        carried = _carried_by_calibrations(page.t.get("calibrations"))
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
        refused = refused_calibrations(page.t.get("scans"), page.t.get("quarantine"))
        for dev in sorted(pf["device_id"].drop_nulls().unique().to_list()):
            hist = device_model_history(
                pf, page.t.get("calibrations"), page.t.get("verifications"), dev, refused
            )
            if hist.height >= 2:
                out.append(
                    page.figure(
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
                        f"{r['change'] * f:+.2f} {name}",
                        f"{r['u_combined'] * f:.2f} {name}",
                        "" if r.get("change_over_u") is None else f"{r['change_over_u']:+.2f}",
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
            out.append('<p class="empty">No change between consecutive calibrations beyond its limit.</p>')
    return "".join(out)


def _finding_uncertainties(page: Page, scan_id: str, recs: list[dict] = ()) -> dict[tuple, dict[str, float]]:
    """Return the findings' uncertainties per (effect, channel).

    (effect, channel) -> {parameter: u}: the findings table's ``uncertainties`` column, else
    ``discrepancy/<scan>/findings.json`` (catalogs written before the column existed).
    """
    out = {
        (r.get("effect"), r.get("channel")): u for r in recs if (u := _uncertainties(r.get("uncertainties")))
    }
    if out:
        return out
    path = page.root / "discrepancy" / scan_id / "findings.json"
    try:
        named = json.loads(page.read_text(path)).get("named") or []
    except (OSError, ValueError, AttributeError):
        return {}
    return {
        (n.get("effect"), n.get("channel")): _uncertainties(n["uncertainties"])
        for n in named
        if isinstance(n, dict) and isinstance(n.get("uncertainties"), dict)
    }
