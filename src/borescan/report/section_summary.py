"""The Summary (night by night, what needs a person) and Quarantine sections."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import polars as pl

from borescan.decision import CANNOT_DECIDE, DOES_NOT_CONFORM, split_verdict
from borescan.report.actions import _verdict_note, quarantine_action
from borescan.report.data import frame_fingerprint, group_fingerprints
from borescan.report.decisions import drift_items, pooled_items, refused_note
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


@dataclass(frozen=True)
class NightItems:
    """What one night of the summary lists, and whether it needs a person (``attention``)."""

    night: str
    quarantined: list[dict[str, Any]]
    made: pl.DataFrame
    superseded: pl.DataFrame
    expired: pl.DataFrame
    failed: pl.DataFrame
    out_of_tolerance: pl.DataFrame | None
    person: pl.DataFrame  # per-scan discrepancy verdicts for a person
    untraceable: pl.DataFrame | None
    undecided: list[dict[str, Any]]  # verdicts that cannot decide (U too large or in the guard band)
    pooled: list[str]  # the pooled verdicts (HTML items)
    drifts: list[tuple[bool, str]]  # flagged calibration drifts: (explained, HTML item)
    findings: pl.DataFrame  # the page's findings (a refused calibration's discrepancy verdict, by scan id)
    attention: bool


_EVENTS = {
    "night": pl.Utf8,
    "event": pl.Utf8,
    "calibration_id": pl.Utf8,
    "device_id": pl.Utf8,
    "other_id": pl.Utf8,
}


def _of(df: pl.DataFrame | None, night: str) -> pl.DataFrame | None:
    return df.filter(pl.col("night").cast(pl.Utf8) == night) if df is not None and df.height else df


def _night_items(page: Page, night: str, parts: pl.DataFrame | None, quarantined: list[dict]) -> NightItems:
    """Return what the summary lists for ``night`` (``parts``: :func:`part_rows` of the page)."""
    t = page.t
    ev = t.get("calibration_events")
    v_n, f_n = _of(t["verifications"], night), _of(t["findings"], night)
    e_n = _of(ev if ev is not None else pl.DataFrame(schema=_EVENTS), night)
    p_n = _of(parts, night)
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
    untraceable = (
        p_n.filter(pl.col("method").fill_null("").str.contains("NOT TRACEABLE"))
        if p_n is not None and p_n.height and "method" in p_n.columns
        else None
    )
    pooled = pooled_items(_of(t.get("pooled_findings"), night))
    drifts = drift_items(_of(t.get("calibration_drift"), night), t.get("calibrations"))
    q_n = [q for q in quarantined if q["night"] == night]
    attention = (
        bool(q_n)
        or failed.height > 0
        or (out_tol is not None and out_tol.height > 0)
        or person.height > 0
        or expired.height > 0
        or (untraceable is not None and untraceable.height > 0)
        or bool(undecided)
        or bool(pooled)
        or any(not explained for explained, _ in drifts)
    )
    return NightItems(
        night,
        q_n,
        made,
        superseded,
        expired,
        failed,
        out_tol,
        person,
        untraceable,
        undecided,
        pooled,
        drifts,
        t["findings"],
        attention,
    )


#: The catalog tables whose nights the summary lists (the quarantined scans' nights come with them).
_NIGHT_TABLES = (
    "scans",
    "verifications",
    "findings",
    "calibration_events",
    "pooled_findings",
    "calibration_drift",
)


def summary(page: Page) -> str:
    """Night by night, newest first: what came in and what needs a person."""
    t = page.t
    parts = part_rows(page) if t["diameters"].height else None
    quarantined = quarantined_scans(page)
    nights = set()
    for name in _NIGHT_TABLES:
        df = t.get(name)
        if df is not None and df.height and "night" in df.columns:
            nights |= {str(n) for n in df["night"].drop_nulls().to_list()}
    nights |= {q["night"] for q in quarantined if q["night"]}
    if not nights:
        return '<p class="empty">No nights in the catalog.</p>'
    keys = _night_keys(page, parts, quarantined)
    rows, classes, details = [], [], []
    for night in sorted(nights, reverse=True):
        row, cls, detail = page.piece(
            "summary night",
            f"{night} {keys.get(night)}",
            lambda night=night: _night_piece(page, night, parts, quarantined),
        )
        rows.append(row)
        classes.append(cls)
        details.append(detail)
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
        "pooled verdicts",
        "drifts flagged",
    ]
    return (
        '<p class="note">Newest night first: what each night asks of a person (red: something to decide), '
        "then the counts. Verdicts under the decision rule of the laboratory (laboratory.decision_rule); "
        "“cannot decide”: the expanded uncertainty is not below the tolerance, or the result lies in the "
        "guard band. “–”: no part tolerance recorded.</p>"
        + "".join(details)
        + _table(head, rows, classes, num_cols=set(range(3, 14)) | {1})
    )


#: The tables whose rows of a night the night's summary box and row show (besides ``parts``).
_NIGHT_SOURCES = (*_NIGHT_TABLES, "quarantine")


def _night_keys(page: Page, parts: pl.DataFrame | None, quarantined: list[dict]) -> dict[str, str]:
    """Return night -> digest of every row its summary box and row read.

    The night's rows of each table and of the parts; with its drifts, the page's calibrations
    valid from that night or before (which device-model effects the night's calibration entered);
    with its quarantines, the findings of those scans
    (a refused calibration's verdict is looked up by scan).
    """
    t = page.t
    per: dict[str, list] = {}
    for name, df in [(n, t.get(n)) for n in _NIGHT_SOURCES] + [("parts", parts)]:
        for night, fp in group_fingerprints(df, "night").items():
            per.setdefault(str(night), []).append((name, fp))
    drift = t.get("calibration_drift")
    if drift is not None and drift.height:
        # the device-model effects a night's calibration entered: its calibrations and the earlier ones
        cal = sorted((str(k), fp) for k, fp in group_fingerprints(t["calibrations"], "valid_from").items())
        for night in {str(n) for n in drift["night"].to_list()}:
            per.setdefault(night, []).append(("calibrations", [fp for k, fp in cal if k <= night]))
    fnd = t["findings"]
    for night in {q["night"] for q in quarantined if q["night"]}:
        ids = [q["scan_id"] for q in quarantined if q["night"] == night]
        mine = fnd.filter(pl.col("scan_id").is_in(ids)) if fnd.height else fnd
        per.setdefault(night, []).append(("findings of its quarantined scans", frame_fingerprint(mine)))
    return {night: json.dumps(sorted(v)) for night, v in per.items()}


def _night_piece(page: Page, night: str, parts: pl.DataFrame | None, quarantined: list[dict]) -> list:
    """Return the summary's row of ``night`` (cells), its class and its box (HTML)."""
    t = page.t
    n = _night_items(page, night, parts, quarantined)
    s_n, v_n, p_n = _of(t["scans"], night), _of(t["verifications"], night), _of(parts, night)
    kinds = s_n.group_by("kind").len().sort("kind").rows() if s_n.height else []
    known_tol = p_n is not None and p_n.height and p_n["tolerance_mm"].drop_nulls().len() > 0
    unexplained = sum(not e for e, _ in n.drifts)
    row = [
        f'<a href="#night-{night}">{_e(night)}</a>',
        str(s_n.height),
        _e(", ".join(f"{k} {c}" for k, c in kinds)),
        str(len(n.quarantined)),
        str(n.made.height),
        str(n.expired.height),
        str(n.superseded.height),
        str(v_n.height - n.failed.height),
        str(n.failed.height),
        str(0 if n.out_of_tolerance is None else n.out_of_tolerance.height) if known_tol else "–",
        str(len(n.undecided)),
        str(n.person["scan_id"].n_unique() if n.person.height else 0),
        str(len(n.pooled)),
        f"{len(n.drifts)}" + (f" ({unexplained} not explained)" if unexplained else ""),
    ]
    return [row, "fail" if n.attention else "", _night_detail(page, n)]


_UNDECIDED_ACTION = (
    '<br><span class="action">what to do: the uncertainty is too large for the tolerance or the result '
    "lies in the guard band: lower U (more poses, a better sensor, a recent calibration) or remeasure; a "
    "wider tolerance or another decision rule is the customer's decision, not the report's.</span>"
)


def _night_detail(page: Page, n: NightItems) -> str:  # noqa: C901 (one branch per kind of item)
    """Return the night's box: its decisions first (drifts not explained, pooled verdicts, quarantines)."""
    # the decisions first: drifts no verdict explains, the pooled verdicts and the drifts they explain
    items = [html for explained, html in n.drifts if not explained] + list(n.pooled)
    items += [html for explained, html in n.drifts if explained]
    for q in n.quarantined:
        rec = page.link(f"quarantine/{q['scan_id']}.json")
        refused = refused_note(q["scan_id"], n.findings) if q["class"] == "calibration refused" else ""
        items.append(
            f"<li><b>quarantined</b> {_link(rec, q['scan_id']) if rec else _e(q['scan_id'])}"
            f" ({_e(q['device_id'] or '?')}, {_e(q['kind'] or '?')}): {_e('; '.join(q['reasons']))}{refused}"
            f'<br><span class="action">{_e(q["class"])} — what to do: {_e(q["action"])}</span></li>'
        )
    for r in n.failed.iter_rows(named=True):
        items.append(
            f"<li><b>verification failed</b> {_e(r['scan_id'])} ({_e(r['device_id'])}"
            f"{', gauge ' + _e(r['artifact_id']) if r.get('artifact_id') else ''}): error "
            f"{_um(r.get('error_mm'))} µm, tolerance ±{_um(r.get('tolerance_mm'))} µm, calibration "
            f"{_e(r.get('calibration_id'))}"
            '<br><span class="action">what to do: recalibrate; the calibration is refused for later '
            "measurements, and the measurements made with it are listed under Verification as put in "
            "doubt.</span></li>"
        )
    for r in n.expired.iter_rows(named=True):
        items.append(
            f"<li><b>calibration expired</b> {_e(r['calibration_id'])} of {_e(r['device_id'])}"
            '<br><span class="action">what to do: recalibrate before the next measurement.</span></li>'
        )
    for r in n.out_of_tolerance.iter_rows(named=True) if n.out_of_tolerance is not None else []:
        items.append(
            f"<li><b>part out of tolerance</b> {_e(r['artifact_id'])} {_e(r.get('feature') or '')} "
            f"(scan {_e(r['scan_id'])}): deviation {_um(r['deviation_mm'])} µm, tolerance "
            f"±{_um(r['tolerance_mm'])} µm</li>"
        )
    for k, r in enumerate(n.undecided):
        what = (
            f"verification {_e(r['scan_id'])} ({_e(r.get('device_id'))}, gauge {_e(r.get('artifact_id'))})"
            if "certified_mm" in r
            else f"part {_e(r.get('artifact_id'))} {_e(r.get('feature') or '')} (scan {_e(r['scan_id'])})"
        )
        last = k == len(n.undecided) - 1  # what to do, once for all of them
        items.append(
            f"<li><b>cannot decide</b> {what}: {_e(split_verdict(r.get('conformity'))[1])}"
            + (
                f"; largest input {_e(r['dominant_input'])}: {_e(r['dominant_fix'])}"
                if r.get("dominant_fix")
                else ""
            )
            + (_UNDECIDED_ACTION if last else "")
            + "</li>"
        )
    for (sid,), grp in (
        n.untraceable.group_by("scan_id", maintain_order=True)
        if n.untraceable is not None and n.untraceable.height
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
    for (sid,), grp in n.person.group_by("scan_id", maintain_order=True) if n.person.height else []:
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
    for r in n.made.iter_rows(named=True):
        items.append(f"<li>calibration made: {_e(r['calibration_id'])} of {_e(r['device_id'])}</li>")
    for r in n.superseded.iter_rows(named=True):
        items.append(
            f"<li>calibration superseded: {_e(r['calibration_id'])} of {_e(r['device_id'])} by "
            f"{_e(r['other_id'])}</li>"
        )
    if not items:
        return ""
    cls = "night" if n.attention else "night quiet"
    return (
        f'<div class="{cls}" id="night-{_e(n.night)}"><h3>{_e(n.night)}</h3><ul>{"".join(items)}</ul></div>'
    )
