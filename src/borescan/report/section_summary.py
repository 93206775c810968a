"""The Summary (night by night, what needs a person) and Quarantine sections."""

from __future__ import annotations

from typing import Any

import polars as pl

from borescan.decision import CANNOT_DECIDE, DOES_NOT_CONFORM, split_verdict
from borescan.report.actions import _verdict_note, quarantine_action
from borescan.report.page import Page, _EMPTY
from borescan.report.section_parts import part_rows
from borescan.report.text import _e, _link, _table, _um, _verdict_is


def quarantined_scans(page: Page) -> list[dict[str, Any]]:
    """Return every quarantined scan of the page.

    Every quarantined scan of the page (``scans`` status or ``quarantine`` rows): scan_id,
    night, device_id, kind, stages, reasons, class and action, in night and scan order.
    """
    sc = page.t["scans"].filter(pl.col("status") == "quarantined")
    q = page.t["quarantine"]
    scan_row = {(r["scan_id"], str(r["night"])): r for r in sc.iter_rows(named=True)}
    q_rows: dict[tuple, list[dict]] = {}
    for r in q.iter_rows(named=True):
        q_rows.setdefault((r["scan_id"], str(r["night"])), []).append(r)
    out = []
    for key in sorted(set(scan_row) | set(q_rows), key=lambda k: (k[1], k[0])):
        srow, qq = scan_row.get(key, {}), q_rows.get(key, [])
        reasons = [srow["reason"]] if srow.get("reason") else []
        reasons += [f"{r['file']}: {r['reason']}" for r in qq if f"{r['file']}: {r['reason']}" not in reasons]
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


def quarantine(page: Page) -> str:
    """Return the Quarantine section: every quarantined scan with its reasons and what to do."""
    items = quarantined_scans(page)
    if not items:
        return _EMPTY["quarantine"]
    rows = []
    for it in items:
        rec = page.link(f"quarantine/{it['scan_id']}.json")
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


def summary(page: Page) -> str:
    """Night by night, newest first: what came in and what needs a person."""
    t = page.t
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
    parts = part_rows(page) if t["diameters"].height else None
    quarantined = quarantined_scans(page)

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
            e_n.filter(pl.col("event") == k) if e_n.height else e_n for k in ("made", "superseded", "expired")
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
        person = f_n.filter(pl.col("verdict").is_in(["missing_effect", "ambiguous"])) if f_n.height else f_n
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
            _night_detail(
                page,
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
    page,
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
        rec = page.link(f"quarantine/{q['scan_id']}.json")
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
            f"verification {_e(r['scan_id'])} ({_e(r.get('device_id'))}, gauge {_e(r.get('artifact_id'))})"
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
        gap = page.link(f"discrepancy/{sid}/gap.png")
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
    return f'<div class="{cls}" id="night-{_e(night)}"><h3>{_e(night)}</h3><ul>{"".join(items)}</ul></div>'
