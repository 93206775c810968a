"""The pages: report.html, one page per month, the papers' page; incremental update."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import polars as pl

from borescan import catalog
from borescan.atomic import atomic_write_text
from borescan.report.data import (
    _counts,
    _memory_catalog,
    _month_summary,
    _month_tables,
    _totals,
    month_fingerprints,
)
from borescan.report.section_calibration import calibration, verification
from borescan.report.section_findings import discrepancy, pooled
from borescan.report.section_parts import diameters
from borescan.report.section_summary import quarantine, summary
from borescan.report.decisions import device_status, device_status_html
from borescan.report.papers_table import papers_rows
from borescan.report.page import Page, _EMPTY, _PieceCache, _PlotCache, fill_plots
from borescan.report.text import _e, _img, _link, _table

REPORT_DIR = "report"

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


def _papers_headline(page: Page, pdir: Path) -> str:
    """Return the printed | ours | why table of the reproductions in ``pdir`` (HTML; "" without one)."""
    rows = papers_rows(pdir)
    if not rows:
        return ""
    cells = [
        [
            _e(r.paper),
            _e(r.printed),
            _e(r.ours),
            _e(r.why),
            _link(page.up + (pdir / r.source).relative_to(page.root).as_posix(), r.source),
        ]
        for r in rows
    ]
    return (
        '<h3 class="headline">What the papers print and what their reproduction here gives</h3>'
        '<p class="note">"ours" is read from this results folder\'s reproductions (papers/); the '
        "arguments behind each difference are in docs/papers.md.</p>"
        + _table(["paper", "printed", "ours", "why", "from"], cells)
    )


def papers(page: Page) -> str:
    """Return the papers' page body: every PNG and CSV under ``papers/`` (CSV tables up to 200 rows)."""
    pdir = page.root / "papers"
    files = (
        sorted(p for p in pdir.rglob("*") if p.is_file() and p.suffix.lower() in (".png", ".csv"))
        if pdir.is_dir()
        else []
    )
    if not files:
        return '<p class="empty">No paper reproductions under papers/.</p>'
    out = [_papers_headline(page, pdir)]
    for f in files:
        rel = page.up + f.relative_to(page.root).as_posix()
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

#: The function that writes each section of a month's page.
BUILDERS = {
    "summary": summary,
    "calibration": calibration,
    "verification": verification,
    "diameters": diameters,
    "discrepancy": discrepancy,
    "pooled": pooled,
    "quarantine": quarantine,
}

#: A month page has every section but the papers (they do not depend on the nights; their own page).
MONTH_SECTIONS = tuple(s for s in SECTIONS if s[0] != "papers")

#: The papers' page, under the report folder.
PAPERS_PAGE = "papers.html"


def _devices(con, as_of: str) -> str:
    """Return the status table of every device of the catalog as of the night ``as_of`` (HTML).

    Reads only the rows :func:`device_status` can pick as a device's current calibration: per
    device, those valid from its last night with a calibration on gauges (or, without one, its
    last night with any) up to ``as_of``, and those valid after it (they name the device); and
    the verifications of those calibrations. So the table costs the same after a year of nights:
    a calibration's record (``calibration_json``, about 24 kB, compressed with its neighbours) is
    read for the rows valid by ``as_of`` alone, by row id, after the rows are picked without it.
    """
    cur = con.cursor()  # a result of another query may be open on con (DuckDB 2)
    records = "calibration_json" in {r[0] for r in cur.execute("DESCRIBE calibrations").fetchall()}
    cal = cur.sql(
        "WITH last AS (SELECT device_id, coalesce(max(CAST(valid_from AS VARCHAR)) FILTER "
        "(coalesce(method, '') <> 'nominal'), max(CAST(valid_from AS VARCHAR))) AS since FROM calibrations "
        "WHERE CAST(valid_from AS VARCHAR) <= ? GROUP BY device_id), "
        f"k AS (SELECT c.*{' EXCLUDE (calibration_json)' if records else ''}, c.rowid AS _row "
        "FROM calibrations c LEFT JOIN last USING (device_id) "
        "WHERE last.since IS NULL OR CAST(c.valid_from AS VARCHAR) >= last.since) "
        "SELECT k.*, s.started_at FROM k LEFT JOIN (SELECT DISTINCT ON (scan_id) scan_id, started_at "
        "FROM scans WHERE scan_id IN (SELECT scan_id FROM k) ORDER BY scan_id, night) s "
        "ON s.scan_id = k.scan_id",
        params=[as_of],
    ).pl()
    if records:
        current = cal.filter(pl.col("valid_from").cast(pl.Utf8) <= as_of)["_row"].to_list()
        cal = cal.join(
            cur.sql(
                "SELECT rowid AS _row, calibration_json FROM calibrations WHERE rowid IN "
                "(SELECT UNNEST(?::BIGINT[]))",
                params=[current],
            ).pl(),
            on="_row",
            how="left",
        )
    cal = cal.drop("_row")
    ver = cur.sql(
        "SELECT calibration_id, passed FROM verifications WHERE calibration_id IN "
        "(SELECT UNNEST(?::VARCHAR[]))",
        params=[cal["calibration_id"].drop_nulls().unique().to_list()],
    ).pl()
    return device_status_html(device_status(cal, ver, as_of), as_of)


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
    root: Path,
    month: str,
    tables: dict[str, pl.DataFrame],
    cache: _PlotCache,
    pieces: _PieceCache,
    workers: int = 1,
) -> dict[str, Any]:
    """Return a month's header counts and section bodies, with the link placeholders.

    Its plots that changed are drawn on up to ``workers`` processes.
    """
    page = Page(root, tables, cache, up=_UP, plots=_PLOTS, pieces=pieces)
    sections = {sid: BUILDERS[sid](page) for sid, _title in MONTH_SECTIONS}
    drawn = cache.draw(workers)  # the month's changed plots, together on the job's processes
    return {
        "counts": _counts(tables),
        "sections": {sid: fill_plots(body, drawn) for sid, body in sections.items()},
    }


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
    """What :func:`update_report` did: the page, the months whose page was (re)written, plots drawn.

    ``pieces_rendered``: the month pages' pieces (a night's summary box, a scan's findings row)
    rendered rather than reused from ``pieces.json``.
    """

    path: Path
    months: tuple[str, ...]
    rendered: tuple[str, ...]
    plots_drawn: int
    pieces_rendered: int = 0


def update_report(
    results_root: str | os.PathLike,
    tables: dict[str, pl.DataFrame] | None = None,
    full: bool = False,
    workers: int = 1,
) -> ReportUpdate:
    """Write ``<results_root>/report.html`` and the month pages ``report/<YYYY-MM>/index.html``.

    Each month of nights has its page and plots in ``report/<YYYY-MM>/``; ``report.html`` shows
    the header over the whole history, the latest month's sections (the same plots), the papers,
    and links to every month. A month's page is rewritten only when a row it shows changed
    (:func:`month_fingerprints`) and a plot is drawn only when its input changed, so a new night
    costs about one month's page whatever the length of the history; ``full=True`` redraws all.
    ``tables`` (name -> polars frame, as :func:`load_tables` returns) replaces the catalog.
    Every file is written atomically; links are relative to where the page is. The plots to draw
    are drawn on up to ``workers`` processes (the same bytes on any number).
    """
    root = Path(results_root)
    if tables is None:
        con = catalog.open_catalog(root, read_only=True)
    else:
        con = _memory_catalog({k: v for k, v in tables.items() if v is not None})
    try:
        return _update(root, con, full, workers)
    finally:
        con.close()


def _update(  # noqa: C901 (one branch per page, month and section of the report)
    root: Path, con, full: bool, workers: int = 1
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
    rendered, drawn, n_pieces = [], 0, 0
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
        cache, pieces = _PlotCache(folder, use=not full), _PieceCache(folder, use=not full)
        parts[month] = _month_sections(root, month, _month_tables(con, month), cache, pieces, workers)
        atomic_write_text(folder / "index.html", _month_page(month, parts[month]))
        cache.save()
        pieces.save()
        atomic_write_text(folder / "sections.json", json.dumps(parts[month], sort_keys=True) + "\n")
        atomic_write_text(done, json.dumps({"fingerprint": fp}) + "\n")
        rendered.append(month)
        drawn += cache.drawn
        n_pieces += pieces.rendered
    dated = [m for m in prints if m != "undated"] or list(prints)
    month = dated[-1] if dated else None
    if month is not None and month not in parts:
        parts[month] = json.loads((report_dir / month / "sections.json").read_text())
    papers_html = papers(Page(root, {}, _PlotCache(report_dir), up="../"))
    atomic_write_text(
        report_dir / PAPERS_PAGE,
        _page(
            "borescan report · papers",
            "<header><h1>borescan report · papers</h1><p>published results reproduced, "
            "beside the printed values (papers/)</p></header>",
            '<a href="../report.html">← report</a>',
            f'<section id="papers"><h2>Papers</h2>{papers_html}</section>',
        ),
    )
    n_papers = papers_html.count("<h3>")
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
            if sid == "summary" and totals["last"]:  # the whole history's devices, before the nights
                fragment = _devices(con, str(totals["last"])) + fragment
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
    return ReportUpdate(page, tuple(prints), tuple(rendered), drawn, n_pieces)


def write_report(
    results_root: str | os.PathLike, tables: dict[str, pl.DataFrame] | None = None, full: bool = False
) -> Path:
    """Write ``<results_root>/report.html`` (and the month pages); return the page's path.

    See :func:`update_report`; ``tables`` defaults to the catalog's contents.
    """
    return update_report(results_root, tables, full).path
