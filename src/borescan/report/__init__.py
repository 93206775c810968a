"""The browsable report: ``<results_root>/report.html``, one page per month of nights, the papers.

Modules: :mod:`.pages` (``update_report``, ``write_report``: the pages and what changed, with
:mod:`.data`), :mod:`.page` (one page's links and plot cache), one module per section
(:mod:`.section_summary`, :mod:`.section_calibration`, :mod:`.section_parts`,
:mod:`.section_findings`; :mod:`.decisions` builds the first screen's devices and decisions,
:mod:`.papers_table` the papers' printed | ours | why), :mod:`.plots` and :mod:`.device_model`
(pure plots), :mod:`.spc` (control limits, run rules), :mod:`.text` (numbers with units, HTML
cells), :mod:`.actions` (what a person does).

:func:`update_report` (:func:`write_report`) reads the history catalog and writes
self-contained HTML pages (inline CSS, plots embedded as base64 ``data:`` images, a print
stylesheet, no scripts, no network) whose every link is relative, so the results folder can be
moved or copied to shared storage and the pages still work. Each month of nights has
``report/<YYYY-MM>/index.html`` with its plots beside it (the PNG files are kept and linked from
each embedded image); ``report.html`` shows the totals of the whole history, the latest month's
sections and a link to every month; the paper reproductions have their own page,
``report/papers.html``. Sections:

- **Summary** (first): on ``report.html`` each device's current calibration, valid until and days
  left as of the last night; then night by night, newest first, what it asks of a person: its
  decisions first (a drift no pooled verdict explains, a pooled verdict with the
  ``config/devices.yaml`` entry to paste, refused calibrations with their discrepancy verdict),
  every quarantined scan with its reason and what to do (:func:`quarantine_action`, the README's
  "When something needs attention"), failed verifications, parts out of tolerance, verdicts that
  cannot decide with their rule and guard band, discrepancy verdicts to look at; then a table with
  one row per night (scans in, quarantined, calibrations made / expired / superseded,
  verifications passed / failed, parts out of tolerance, cannot decide, verdicts for a person,
  pooled verdicts, drifts flagged).
- **Calibration**: parameter trends per device and channel with error bars U (k=2), links to
  each certificate (PDF and JSON), the date recalibration is due.
- **Verification**: per device and ring gauge an individuals and moving-range control chart of
  the verification error; limits (Montgomery, *Statistical Quality Control*, §6.4):
  centre line = mean, UCL/LCL = mean ± 2.66·MR̄ (= ± 3σ̂, σ̂ = MR̄/1.128), MR chart UCL = 3.267·MR̄,
  LCL = 0; points that break the Western Electric run rules 1, 2 and 4 (:func:`run_rules`) are
  marked; plus the measurements a failed verification puts in doubt.
- **Parts**: every diameter at the measured temperature and at 20 °C, its expanded uncertainty U
  with k and coverage probability, "temperature assumed" flagged, the deviation from the nominal
  where the catalog knows one and pass/fail where it knows a tolerance; plots of the parts
  measured more than once.
- **Discrepancy**: findings in words: effect, channel, each parameter as value ± u with its unit,
  verdict, gap before and after; an ambiguous verdict names its candidates and why one scan
  cannot tell them apart; links to ``discrepancy/<scan_id>/gap.png``.
- **Quarantine**: quarantined scans with their reasons and what to do.

Incremental: a month's page is rewritten only when a row it shows changed (one aggregate query
per source tells which months did: :func:`month_fingerprints`, which also covers this module's
code), and a plot is drawn only when its input rows changed (``report/<month>/plots.json``), so
a new night costs about one month's page however long the history; ``full=True`` redraws all.
A failed verification that puts an older month's measurement in doubt changes that month's rows
(the ``suspect_measurements`` view), so its page is rewritten too; a calibration superseded or
expiring in a later month is an event of that later month. Plots label at most
:data:`MAX_TICK_LABELS` ticks per axis.

Every plot function is pure: polars frames in, a :class:`matplotlib.figure.Figure` out (Agg,
no pyplot state). PNGs are written without time stamps, so reruns on the same catalog give the
same bytes.
"""
