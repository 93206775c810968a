"""The Calibration and Verification sections."""

from __future__ import annotations


import polars as pl

from borescan import catalog
from borescan.calibrations import calibration_roles, failed_calibration_ids, order_calibrations
from borescan.mirror import format_probability
from borescan.report.page import Page, _EMPTY
from borescan.report.plots import ROD_PARAMS, TRI_PARAMS, plot_calibration_trends, plot_control_chart
from borescan.report.spc import MR_D2, RUN_RULES, control_limits, run_rules
from borescan.report.text import (
    _e,
    _link,
    _mm,
    _table,
    _temperature,
    _um,
    _unit_of,
    _verdict_cell,
    _without_unit,
    format_quantity,
)


def calibration(page: Page) -> str:
    """Return the Calibration section: per device its parameter trends and calibrations with certificates."""
    cal = page.t["calibrations"]
    if cal.height == 0:
        return _EMPTY["calibration"]
    out = []
    cs = page.t["calibration_scans"]
    scans_of = (
        {}
        if cs.height == 0
        else dict(cs.group_by("calibration_id", maintain_order=True).agg(pl.col("scan_id")).iter_rows())
    )
    scans = page.t.get("scans")
    if (
        scans is not None
        and {"scan_id", "started_at"} <= set(scans.columns)
        and "started_at" not in cal.columns
    ):
        cal = cal.join(
            scans.select("scan_id", "started_at").unique("scan_id", keep="first"),
            on="scan_id",
            how="left",
        )
    ver = page.t.get("verifications")
    failed = failed_calibration_ids(ver) if ver is not None and "passed" in ver.columns else set()
    roles = calibration_roles(cal, failed)  # the same order as the measure stage and `borescan status`
    for dev in sorted(cal["device_id"].drop_nulls().unique().to_list()):
        out.append(f"<h3>Device {_e(dev)}</h3>")
        mine = cal.filter(pl.col("device_id") == dev)
        fitted = mine.filter(pl.col("method") != "nominal")  # design geometry alone does not trend
        if fitted.height and mine["calibration_id"].n_unique() >= 2:
            out.append(
                page.figure(
                    plot_calibration_trends,
                    mine,
                    dev,
                    f"calibration_{dev}",
                    f"calibration parameters of {dev}",
                )
            )
        elif fitted.height:  # one calibration: its values, a trend from the second on
            out.append(_parameter_values(fitted))
        rows = []
        per = order_calibrations(mine.unique("calibration_id", keep="first", maintain_order=True))
        for r in per.iter_rows(named=True):
            scans = scans_of.get(r["calibration_id"], [])
            cert = r.get("certificate_path")
            pdf = page.link(cert)
            # as the catalog names it (relative to the results folder, or absolute): page.link makes it
            # relative to the page; joined to a relative results folder it was looked for under it twice
            cj = catalog.certificate_json_path("", cert) if cert else None
            json_link = page.link(str(cj)) if cj else None
            links = " ".join(
                x
                for x in (
                    _link(pdf, "certificate") if pdf else (_e(cert) + " (missing)" if cert else ""),
                    _link(json_link, "json") if json_link else "",
                )
                if x
            )
            rows.append(
                [
                    _e(r["calibration_id"]),
                    _e(r.get("valid_from")),
                    _e(r.get("recalibration_due")),
                    _e(r.get("method")),
                    _e(", ".join(scans)),
                    _e(roles.get(r["calibration_id"], "")),
                    links,
                    f"<code>{_e((r.get('certificate_sha256') or '')[:16])}</code>",
                ]
            )
        out.append(
            _table(
                [
                    "calibration",
                    "valid from",
                    "recalibration due",
                    "method",
                    "scans",
                    "in the history",
                    "certificate",
                    "certificate.json sha256",
                ],
                rows,
            )
        )
        out.append(_rho_sign_notes(mine))
    return "".join(out)


def _parameter_values(cal: pl.DataFrame) -> str:
    """Return one calibration's parameters, a row per channel: value ± U (k = 2), as a trend's error bars.

    A plot of one point a panel showed the same numbers less legibly (and took half the report's
    drawing on a night of new devices); a value without ± was held, not fitted.
    """
    present = [(p, up) for p, up in TRI_PARAMS + ROD_PARAMS if p in cal.columns and cal[p].drop_nulls().len()]
    rows = [
        [_e(r["channel"])]
        + [format_quantity(r[p], 2.0 * r[up] if r.get(up) else None, _unit_of(p)) for p, up in present]
        for r in cal.sort("channel").iter_rows(named=True)
    ]
    return (
        '<p class="note">One calibration so far: its parameters (± U, k = 2; a value without ± was held, '
        "not fitted). The trend over calibrations is drawn from the second on.</p>"
        + _table(
            ["channel", *(_without_unit(p) for p, _ in present)],
            rows,
            num_cols=set(range(1, len(present) + 1)),
        )
    )


#: verifications of one device and gauge (on one page) from which a control chart is drawn: one point has
#: no moving range, so no limits (a contract night verifies most rod gauges once: 40 empty charts, half
#: the report's CPU)
MIN_CHART_POINTS = 2


def verification(page: Page) -> str:
    """Return the Verification section: control charts per device and gauge, and the measurements in doubt."""
    ver = page.t["verifications"]
    if ver.height == 0:
        return _EMPTY["verification"]
    out = [
        '<p class="note">Individuals chart of the verification error (measured − certified ring-gauge '
        "diameter), one per device and gauge, with limits mean ± 2.66·MR̄ (± 3σ̂, σ̂ = MR̄/1.128); "
        "moving-range chart with UCL = 3.267·MR̄. Ringed points break a Western Electric run rule: "
        + "; ".join(f"rule {k}, {v}" for k, v in RUN_RULES.items())
        + ". Error bars U (k=2).</p>"
    ]
    if "artifact_id" not in ver.columns:
        ver = ver.with_columns(pl.lit(None, dtype=pl.Utf8).alias("artifact_id"))
    for dev in sorted(ver["device_id"].drop_nulls().unique().to_list()):
        mine = ver.filter(pl.col("device_id") == dev)
        gauges = sorted(mine["artifact_id"].fill_null("").unique().to_list())
        for gauge in gauges:
            sub = mine.filter(pl.col("artifact_id").fill_null("") == gauge)
            out.append(_gauge_chart(page, dev, gauge or None, sub, several=len(gauges) > 1))
    return "".join(out) + _suspect(page)


def _gauge_chart(page: Page, dev: str, gauge: str | None, sub: pl.DataFrame, several: bool) -> str:
    lim = control_limits(sub["error_mm"].to_numpy())
    out = [f"<h3>Device {_e(dev)}" + (f" · gauge {_e(gauge)}" if gauge else "") + "</h3>"]
    name = f"control_{dev}_{gauge}" if several and gauge else f"control_{dev}"
    if sub.height < MIN_CHART_POINTS:  # no moving range, no limits: the table below says it all
        out.append(
            f'<p class="note">One verification: no control chart until there are {MIN_CHART_POINTS} '
            "(its limits come from the moving ranges of successive verifications).</p>"
        )
    elif gauge:
        out.append(
            page.figure(plot_control_chart, sub, dev, name, f"control chart of {dev} on {gauge}", gauge)
        )
    else:
        out.append(page.figure(plot_control_chart, sub, dev, name, f"control chart of {dev}"))
    out.append(
        _table(
            ["n", "mean [µm]", "MR̄ [µm]", "UCL [µm]", "LCL [µm]", "MR UCL [µm]"],
            [
                [
                    str(sub.height),
                    _um(lim["mean"], 2),
                    _um(lim["mr_bar"], 2),
                    _um(lim["ucl"], 2),
                    _um(lim["lcl"], 2),
                    _um(lim["mr_ucl"], 2),
                ]
            ],
            num_cols={0, 1, 2, 3, 4, 5},
        )
    )
    rules = run_rules(sub["error_mm"].to_numpy(), lim["mean"], lim["mr_bar"] / MR_D2)
    rows, classes = [], []
    for i, r in enumerate(sub.iter_rows(named=True)):
        ok = r.get("passed")
        verdict_html, verdict_class = _verdict_cell(r.get("conformity"), ok)
        broke = ", ".join(str(k) for k in RUN_RULES if rules[k][i])
        u = r.get("u_error_mm")
        rows.append(
            [
                _e(r.get("night")),
                _e(r["scan_id"]),
                _e(r.get("calibration_id")),
                _mm(r.get("measured_mm")),
                _mm(r.get("certified_mm")),
                _um(r.get("error_mm")),
                _um(2.0 * u if u is not None else None),
                _um(r.get("tolerance_mm")),
                _temperature(r.get("temperature_c"), r.get("temperature_assumed")),
                _e(broke),
                verdict_html,
            ]
        )
        classes.append(verdict_class or ("warn" if broke else ""))
    out.append(
        _table(
            [
                "night",
                "scan",
                "calibration",
                "measured at 20 °C [mm]",
                "certified [mm]",
                "error [µm]",
                "U (k=2) [µm]",
                "tolerance ± [µm]",
                "temperature [°C]",
                "run rules broken",
                "verdict",
            ],
            rows,
            classes,
            num_cols={3, 4, 5, 6, 7, 8},
        )
    )
    return "".join(out)


def _suspect(page: Page) -> str:
    out = []
    sus = page.t.get("suspect_measurements")
    out.append("<h3>Measurements put in doubt by a failed verification</h3>")
    if sus is None or sus.height == 0:
        out.append(
            '<p class="empty">None: no measurement used a calibration that later failed verification.</p>'
        )
    else:
        rows = [
            [
                _e(r["night"]),
                _e(r["scan_id"]),
                _e(r["artifact_id"]),
                _e(r["feature"]),
                _mm(r["diameter_mm"]),
                _e(r["calibration_id"]),
                _e(r["failed_verification_scan_id"]),
                _e(r["failed_night"]),
                _um(r["failed_error_mm"]),
            ]
            for r in sus.iter_rows(named=True)
        ]
        out.append(
            _table(
                [
                    "night",
                    "scan",
                    "part",
                    "feature",
                    "diameter [mm]",
                    "calibration",
                    "failed verification",
                    "on",
                    "its error [µm]",
                ],
                rows,
                ["fail"] * len(rows),
                num_cols={4, 8},
            )
        )
    return "".join(out)


def _rho_sign_notes(cal: pl.DataFrame) -> str:
    """Return the beams of a device's calibrations whose sign of rho their scan did not determine.

    Read from the ``calibrations`` columns of the mirror check (issue 36): both solutions' weight, the bore
    range where the calibration may be used and the scan that would fix it (HTML; "" when none).
    """
    if "rho_sign_resolved" not in cal.columns:
        return ""
    flagged = cal.filter(pl.col("rho_sign_resolved").fill_null(True).not_()).sort(
        "valid_from", "calibration_id", "channel"
    )
    items = []
    for r in flagged.iter_rows(named=True):
        hi = r.get("valid_bore_max_mm")
        rng = (
            f"{r['valid_bore_min_mm']:.1f} mm to " + ("no upper limit" if hi is None else f"{hi:.1f} mm")
            if r.get("valid_bore_min_mm") is not None
            else "n/a"
        )
        fix = r.get("offset_to_resolve_mm")
        items.append(
            f"<li><b>{_e(r['calibration_id'])}</b>: the sign of rho of channel {r['channel']} is not "
            f"determined by its scan (two solutions, probability of the wrong sign "
            f"{format_probability(r['p_wrong_sign'])}, "
            f"the mirror {r['mirror_delta_chi2']:.2f} in chi² above); diameters "
            f"carry both solutions and are measured only for bores of {rng}"
            f'<br><span class="action">what to do: recalibrate: '
            + (
                _e(r["rho_sign_fix"])
                if r.get("rho_sign_fix")
                else f"the spindle at least {'n/a' if fix is None else f'{fix:.2f}'} mm from the gauge centre"
            )
            + "; borescan plan predicts the scan</span></li>"
        )
    return f'<ul class="notes">{"".join(items)}</ul>' if items else ""
