"""Pages 1-5 of a three-sensor certificate: administrative page, item, conditions, traceability, results."""

from __future__ import annotations

from borescan.certificate.admin import _decision_rule_text, _standard_statement, _traceability_text
from borescan.certificate.content import _METHOD_TEXT
from borescan.certificate.layout import (
    _date_range,
    _Doc,
    _dof_text,
    _dominant_label,
    _line,
    _num,
    _ppm,
    _scaled,
    _vu,
    _wrap,
)
from borescan.certificate.tri import device_model_text
from borescan.mirror import format_probability


def _page_admin(d: _Doc) -> None:
    c = d.cert
    lab, dates, dev = c["laboratory"], c["dates"], c["device"]
    d.fig.text(d.LEFT, d.y - 0.01, "Calibration certificate", fontsize=18, weight="bold")
    d.y -= 0.035
    d.fig.text(
        d.LEFT,
        d.y,
        f"Certificate number {c['administrativeData']['coreData']['uniqueIdentifier']}",
        fontsize=10,
    )
    d.y -= 0.03
    if c["administrativeData"]["placeholders"]:
        d.para(
            "NOTE: the laboratory settings "
            + ", ".join(c["administrativeData"]["placeholders"])
            + " are the "
            "defaults of workflow/schemas/config.schema.yaml, placeholders that name no real "
            "laboratory. Set the "
            "laboratory section of config/config.yaml before issuing this certificate to anyone.",
            color="firebrick",
            size=7.5,
        )
    sensors = dev.get("sensors") or []
    flags = []
    cond = c["conditions"]
    if (cond.get("temperature") or {}).get("assumed"):
        flags.append(
            "the gauge temperature was not recorded; 20 degC was ASSUMED with a wider uncertainty "
            "(uncertainty.missing_temperature)"
        )
    if (cond.get("gauge_cte") or {}).get("assumed"):
        flags.append(
            "the gauge's expansion coefficient was not stated; an assumed value with a wide bound was used"
        )
    d.kv(
        [
            ("Issuing laboratory", f"{lab.get('name')}, {lab.get('address')}"),
            ("Accreditation", str(lab.get("accreditation"))),
            ("Customer", str(lab.get("customer"))),
            (
                "Item calibrated",
                f"{c.get('item', 'three-sensor bore measuring device')} {dev.get('id', c['device_id'])} "
                f"(type {dev.get('type', 'tri_lds')}) with {len(sensors)} laser displacement sensors "
                "(table on page 2)",
            ),
            ("Place of calibration", str(lab.get("performance_location"))),
            ("Date(s) of calibration", _date_range(dates)),
            ("Date of issue", f"{dates.get('issue') or 'n/a'} ({dates.get('issue_rule', 'not stated')})"),
            *(
                [("Replaces", c["reissue"]["declaration"])]
                if (c.get("reissue") or {}).get("replaces")
                else []
            ),
            (
                "Recalibration due",
                f"{dates.get('recalibration_due') or 'n/a'} ({dates.get('recalibration_rule', '')})",
            ),
            ("Method", _METHOD_TEXT.get(c["method"], c["method"])),
            ("Calibration scans", ", ".join(c["scan_ids"])),
            ("Deviations from the method", "; ".join(flags) if flags else "none"),
            (
                "Traceability",
                c.get("traceability_summary")
                or f"reference ring gauge {c['artifact'].get('id')}, certificate "
                f"{c['artifact'].get('certificate')} (section 4)",
            ),
            ("Decision rule", _decision_rule_text(lab) + " (section 7)"),
            ("Conformity", c["conformity"]["text"]),
            (
                "Measurement uncertainty",
                f"Expanded uncertainties U = k u_c with a coverage probability of "
                f"{100 * c['coverage_probability']:.2f} % (about 95 %); k per result (page 3). "
                "Evaluated according to JCGM 100:2008 (GUM) and JCGM 101:2008 (GUM S1); the "
                "budget is on the following pages and in certificate.json.",
            ),
        ]
    )
    d.y -= 0.01
    d.para(
        _standard_statement(lab)
        + " The results relate only to the item calibrated, at the time of calibration. "
        "The user is responsible for arranging recalibration in due time."
    )
    d.y -= 0.03
    d.room(0.09)
    d.fig.text(d.LEFT, d.y, "Authorised signatory", fontsize=8, weight="bold")
    d.fig.text(0.55, d.y, "Date of issue", fontsize=8, weight="bold")
    d.y -= 0.045
    d.fig.add_artist(_line(d.fig, d.LEFT, 0.45, d.y))
    d.fig.add_artist(_line(d.fig, 0.55, 0.80, d.y))
    d.y -= 0.015
    d.fig.text(0.55, d.y, str(dates.get("issue") or "n/a"), fontsize=7.5)
    for line in _wrap(str(lab.get("signatory")), 60) + _wrap(str(lab.get("signatory_function")), 60):
        d.fig.text(d.LEFT, d.y, line, fontsize=7.5)
        d.y -= 0.013
    d.y -= 0.01


def _page_item_conditions(d: _Doc) -> None:
    c = d.cert
    dev = c["device"]
    d.new_page()
    d.heading("1  Item calibrated")
    _sensor_table(d, dev, c["device_id"])
    _page_conditions_traceability(d)


def _sensor_table(d: _Doc, dev: dict, device_id: str) -> None:
    """Write the device's sensors as recorded in scan.json, as a table."""
    d.para(
        f"Device {dev.get('id', device_id)}, type {dev.get('type', 'tri_lds')}; sensors as recorded in "
        "scan.json:"
    )
    cols = [
        "channel",
        "model",
        "serial",
        "range [mm]",
        "linearity [% FS]",
        "linearity +- [um]",
        "repeatab. [um]",
        "resolution [um]",
    ]
    cells = []
    for s in dev.get("sensors") or []:
        lin = s.get("linearity_fs")
        rng = s.get("range_mm")
        lin_um = lin * rng * 1e3 if lin is not None and rng is not None else None
        cells.append(
            [
                str(s.get("channel")),
                str(s.get("model", "")),
                str(s.get("serial", "")),
                _num(rng, "g"),
                _num(None if lin is None else 100 * lin, "g"),
                _num(lin_um, ".1f"),
                _num(None if s.get("repeatability_mm") is None else 1e3 * s["repeatability_mm"], "g"),
                _num(
                    None if s.get("resolution_mm") is None else 1e3 * s["resolution_mm"],
                    "g",
                    none="not stated",
                ),
            ]
        )
    if cells:
        d.table(cols, cells, widths=[0.08, 0.13, 0.15, 0.1, 0.13, 0.14, 0.12, 0.15], size=6.8)


def _page_conditions_traceability(d: _Doc) -> None:
    c = d.cert
    art, cond = c["artifact"], c["conditions"]
    d.heading("2  Method")
    d.para(_METHOD_TEXT.get(c["method"], c["method"]))
    fit = c["fit"]
    if fit.get("gauge"):
        d.para("Reference direction: " + fit["gauge"] + ".")
    if fit.get("device_model"):
        d.para(device_model_text(fit["device_model"]))
    d.heading("3  Conditions of calibration")
    temp = cond.get("temperature") or {}
    cte = cond.get("gauge_cte") or {}
    rows = [
        (
            "Gauge temperature",
            (
                f"{_num(temp.get('value_c'), '.2f')} degC, standard uncertainty "
                f"{_num(temp.get('u_c'), '.3f')} K, U = {_num(temp.get('U_c'), '.3f')} K "
                f"(k = {_num(temp.get('k'), '.2f')}, p = {100 * c['coverage_probability']:.2f} %); "
                f"{temp.get('source', 'not stated')}"
            )
            if temp
            else "not recorded",
        )
    ]
    if cte:
        rows.append(
            (
                "Gauge expansion coeff.",
                f"{_ppm(cte.get('value_per_k'))} +- {_ppm(cte.get('halfwidth_per_k'))} "
                f"(rectangular); {cte.get('source', '')}",
            )
        )
    if cond.get("gauge_radius_at_temperature_mm") is not None:
        rows.append(
            (
                "Gauge radius at T",
                f"{_num(cond['gauge_radius_at_temperature_mm'], '.5f')} mm "
                "(R = D20/2 (1 + alpha (T - 20 degC)))",
            )
        )
    for sc in cond.get("scans") or []:
        pos = sc.get("spindle_position") or {}
        cen = sc.get("center") or {}
        acc = cond.get("position_accuracy_mm")
        acc_t = f" (each coordinate +-{_num(1e3 * acc, 'g')} um, machine's stated accuracy)" if acc else ""
        rows.append(
            (
                "Calibration scan",
                f"{sc.get('scan_id')}: spindle at ({_num(pos.get('x_mm'), '.3f')}, "
                f"{_num(pos.get('y_mm'), '.3f')}) mm, gauge centre "
                f"({_num(cen.get('x_mm'), '.3f')}, {_num(cen.get('y_mm'), '.3f')}) mm{acc_t}; "
                f"{_num(sc.get('rpm'), '.1f')} rpm ({sc.get('angle_source', '')}); "
                f"{_num(sc.get('revolutions_recorded'), '.1f')} revolutions recorded, "
                f"{sc.get('revolutions_with_extrema', 'n/a')} complete with both extrema per channel",
            )
        )
    rows.append(
        (
            "Other conditions",
            "humidity, pressure and vibration are not recorded in scan.json; they enter no result",
        )
    )
    d.kv(rows, key_w=0.21, width=96)
    d.heading("4  Traceability")
    d.para(_traceability_text(art))
    issuer = art.get("certificate_issuer")
    valid = art.get("certificate_valid_until")
    chain = [
        ("Reference standard", f"ring gauge {art.get('id')}"),
        (
            "Its certificate",
            f"{art.get('certificate')}, "
            + (
                f"issued by {issuer}"
                if issuer
                else "issuer NOT STATED (scan.json artifact.certificate_issuer)"
            ),
        ),
        ("Valid until", str(valid or "NOT STATED (scan.json artifact.certificate_valid_until)")),
        (
            "Certified diameter",
            f"{_num(art.get('certified_diameter_mm'), '.4f')} mm at 20 degC, U = "
            f"{_num(_scaled(art.get('u_diameter_mm'), 1e3), 'g')} um "
            f"(k = {art.get('k')})",
        ),
    ]
    if valid and c["dates"].get("end") and str(valid) < str(c["dates"]["end"]):
        chain.append(
            (
                "WARNING",
                f"the gauge certificate expired on {valid}, before this calibration: traceability is "
                "not established",
            )
        )
    d.kv(chain, key_w=0.21, width=96)


def _page_results(d: _Doc) -> None:
    c = d.cert
    p = c["coverage_probability"]
    d.new_page()
    d.heading("5  Results")
    d.para(
        "Calibrated beam geometry per channel: direction beta of the beam, its offset rho from the "
        "rotation axis "
        "and its base length d_b (the distance from the foot point to the sensor's measuring start). "
        "Expanded "
        f"uncertainty U = k u_c for a coverage probability of {100 * p:.2f} %; k from the effective "
        "degrees of "
        "freedom (Welch-Satterthwaite) where the GUM S1 check validates it, else from the propagated "
        "distribution."
    )
    cols = ["channel", "quantity", "value", "U", "unit", "k", "nu_eff", "dominant input"]
    cells = []
    results = {r["name"]: r for r in c["measurementResults"][0]["results"]}
    budgets = c["measurementResults"][0]["uncertaintyBudget"]
    for prow in c["parameters"]:
        ch = prow["channel"]
        for name, unit, label in (
            ("beta_rad", "rad", "beta"),
            ("rho_mm", "mm", "rho"),
            ("d_b_mm", "mm", "d_b"),
        ):
            key = f"{name}[{ch}]"
            r = results[key]
            eu = r["real"]["expandedUnc"]
            if r["held_at_design_value"]:
                cells.append(
                    [
                        str(ch),
                        label,
                        _num(r["real"]["value"], ".6f"),
                        "held",
                        unit,
                        "-",
                        "-",
                        "reference direction (held at design value)",
                    ]
                )
                continue
            v, U = _vu(r["real"]["value"], eu["uncertainty"])
            dom = (budgets.get(key, {}).get("combined") or {}).get("dominant_input", "")
            cells.append(
                [
                    str(ch),
                    label,
                    v,
                    U,
                    unit,
                    _num(eu["coverageFactor"], ".2f"),
                    _dof_text(eu["effectiveDegreesOfFreedom"]),
                    _dominant_label(dom),
                ]
            )
    d.table(cols, cells, widths=[0.07, 0.08, 0.14, 0.1, 0.05, 0.06, 0.08, 0.42], size=7)
    fit = c["fit"]
    if c.get("effective_base_length"):
        g = "; ".join(
            f"channel {r['channel']}: "
            + " +- ".join(_vu(r["value_mm"], r["expandedUnc"]["uncertainty"]))
            + " mm"
            f" (k = {r['expandedUnc']['coverageFactor']:.2f})"
            for r in c["effective_base_length"]
        )
        d.para(
            "Effective base length g = d_b + rho^2/(2R) (R the gauge radius at its temperature), the "
            "combination the "
            f"data fix best, with U: {g}. rho and d_b of a channel are correlated; certificate.json "
            "gives the full "
            "covariance (combined and of the fit alone) and the correlation matrix."
        )
    acc = fit.get("acceptance")
    d.para(
        f"Fit: residual rms {_num(_scaled(fit.get('residual_rms_mm'), 1e3), '.2f')} um, "
        f"{_num(fit.get('n_obs'), 'g')} readings, {fit.get('dof')} degrees of freedom, Jacobian rank "
        f"{fit.get('rank')}, "
        f"condition {_num(fit.get('condition'), '.3g')}; the optimiser "
        f"{'converged' if fit.get('converged') else 'did NOT converge'}."
    )
    if acc:
        d.para(
            f"Acceptance: largest ratio of a channel's residual rms to its readings' own noise floor "
            f"{_num(acc.get('residual_to_noise_max'), '.3f')} (limit "
            f"{_num(acc.get('max_residual_to_noise'), 'g')}); "
            f"|rho| within the head radius {_num(acc.get('head_radius_mm'), 'g')} mm."
        )
    if fit.get("weak_rho_channels"):
        d.para(
            f"Channels {fit['weak_rho_channels']}: |rho| < 2 u(rho), rho is not distinguished from 0; "
            "U(d_b) of "
            "these channels includes the second-order term of d_b = g - rho^2/(2R)."
        )
    if fit.get("rho_profiled_channels"):
        d.para(
            f"Channels {fit['rho_profiled_channels']}: the cost along rho is not the linear one (rho "
            "enters the "
            "readings mostly through rho^2); their uncertainties come from the profile of the cost "
            "along rho, "
            "every other parameter refitted, not from the linearisation alone."
        )
    _rho_sign_paragraphs(d, c)


def _rho_sign_paragraphs(d: _Doc, c: dict) -> None:
    """Return section 5 of the certificate: each beam's mirror check (certificate.json ``rho_sign``).

    The flagged beams' statement, both solutions, the bore range and the fix; one line for the resolved ones.
    """
    rs = c.get("rho_sign") or {}
    checks = rs.get("beams") or []
    if not checks:
        return
    flagged = [m for m in checks if not m["resolved"]]
    # one rule (borescan.mirror.BeamMirror.sign_determined): a beam in one valley through both signs is not
    # resolved either; its statement says so
    resolved = [str(m["channel"]) for m in checks if m.get("sign_determined", m["resolved"])]
    for m in checks:
        if m.get("one_valley"):
            d.para(m["statement"].replace("the sign", "The sign", 1) + ".")
    if resolved:
        d.para(
            f"Sign of rho resolved for channel(s) {', '.join(resolved)} (no mirror solution, or one at least "
            f"{rs['resolved_delta_chi2']:g} in chi^2 above the "
            "solution): their uncertainties are the fit's own."
        )
    for m in flagged:
        d.para(m["statement"].replace("the sign", "The sign", 1) + ".")
        alt = m["alternative"]
        u_main = m["u_main"]
        d.para(
            f"Channel {m['channel']}, solution 1 (weight "
            f"{format_probability(m['weight_main'])}): beta {u_main['beta_rad']:.6f} rad, "
            f"rho {u_main['rho_mm']:+.4f} mm, d_b {u_main['d_b_mm']:.4f} "
            f"mm; solution 2 (weight {format_probability(alt['weight'])}, "
            f"delta chi^2 {alt['delta_chi2']:.2f}): beta "
            f"{alt['beta_rad']:.6f} rad, rho {alt['rho_mm']:+.4f} mm, "
            f"d_b {alt['d_b_mm']:.4f} mm. Both solutions' covariances are in certificate.json (rho_sign). "
            "A diameter measured with this calibration carries both (Monte Carlo, JCGM 101) and is refused "
            "outside the bore range above."
        )
