"""The budget, verification and records pages of a certificate PDF (three-sensor and rod)."""

from __future__ import annotations

import math

from borescan.certificate.admin import _decision_rule_text, _ver_name
from borescan.certificate.layout import (
    _DIST,
    _Doc,
    _dof_text,
    _est_u_text,
    _label,
    _num,
    _scaled,
    _tiny,
    _sig,
)
from borescan.decision import split_verdict


def _budget_tables(  # noqa: C901 (one cell per budget row, parameter kind and held or tiny term)
    d: _Doc,
) -> None:
    c = d.cert
    budgets = c["measurementResults"][0]["uncertaintyBudget"]
    if not budgets:
        return
    d.new_page()
    d.heading("6  Uncertainty budget")
    d.para(
        "Per channel, every input x_i of the calibration with its estimate, standard uncertainty u(x_i), "
        "distribution and degrees of freedom nu_i, and for each result its sensitivity coefficient c_i and "
        "contribution u_i = |c_i| u(x_i) (GUM 5.1.3). The fit to the readings is a vector input (u(x_i): the "
        "residual standard deviation per reading); its contribution comes from its covariance. c: for "
        "beta in rad, "
        "for rho and d_b in mm, per unit of the input in certificate.json (mm, rad, degC, 1/K, s); "
        "contributions in mrad (beta) and um (rho, d_b); "
        "0: below "
        "1e-5 u_c; 'in Type A': a resolution dithered by the readings' noise (GUM F.2.2.1)."
    )
    fams = ("beta", "rho", "d_b")
    for prow in c["parameters"]:
        ch = prow["channel"]
        keys = [f"beta_rad[{ch}]", f"rho_mm[{ch}]", f"d_b_mm[{ch}]"]
        rows_by = [budgets[k]["rows"] for k in keys]
        comb = [budgets[k]["combined"] for k in keys]
        cols = [
            "input x_i",
            "estimate",
            "u(x_i)",
            "dist.",
            "nu_i",
            "c(beta)",
            "u_i(beta)",
            "c(rho)",
            "u_i(rho)",
            "c(d_b)",
            "u_i(d_b)",
        ]
        cells = []
        for i, row in enumerate(rows_by[0]):
            u_x = row["standard_uncertainty"]
            est, u_txt = _est_u_text(row["estimate"], u_x, row["unit"], row.get("key", ""))
            cell = [
                _label(row),
                est,
                "-" if not u_x else u_txt,
                _DIST.get(row["distribution"], row["distribution"]),
                _dof_text(row["degrees_of_freedom"]),
            ]
            for k, rows in enumerate(rows_by):
                r = rows[i]
                if prow[f"held_{fams[k]}"]:
                    cell += ["held", "-"]
                    continue
                if r.get("note") and not r["contribution"]:
                    cell += ["-", "in Type A"]
                    continue
                if _tiny(r, comb[k]["standard_uncertainty"]):
                    cell += ["0", "0"]
                    continue
                cc = r["sensitivity_coefficient"]
                cell.append("-" if cc is None else _sig(cc))
                cell.append(_sig(r["contribution"] * 1e3))  # beta: mrad, rho and d_b: um
            cells.append(cell)
        for label, field, scale_fn in (
            ("combined standard uncertainty u_c", "standard_uncertainty", True),
            ("effective degrees of freedom nu_eff", "effective_degrees_of_freedom", None),
            ("coverage factor k", "coverage_factor", False),
            ("expanded uncertainty U = k u_c", "expanded_uncertainty", True),
        ):
            last = [label, "", "", "", ""]
            for k, cb in enumerate(comb):
                if prow[f"held_{fams[k]}"]:
                    last += ["", "held"]
                    continue
                v = cb.get(field)
                if scale_fn is None:
                    txt = _dof_text(v)
                elif scale_fn:
                    txt = f"{_sig(v * 1e3)} {'mrad' if k == 0 else 'um'}"
                else:
                    txt = f"{v:.2f}" + ("" if cb.get("coverage_method") == "GUF" else " (S1)")
                last += ["", txt]
            cells.append(last)
        d.room(0.0128 * (len(cells) + 1) + 0.035)
        d.para(f"Channel {ch}", size=8.5)
        d.table(
            cols,
            cells,
            widths=[0.22, 0.09, 0.075, 0.07, 0.05, 0.06, 0.08, 0.06, 0.08, 0.06, 0.08],
            size=5.8,
            row_h=0.0128,
        )
    d.para(
        "k marked (S1): the t-based factor was not validated by GUM S1 (one rectangular input "
        "dominates); k is that "
        "of the propagated distribution. The gauge's expansion coefficient has no first-order effect "
        "at 20 degC. "
        "Sensor linearity is an error of every reading of a channel within the data sheet's bound, "
        "independent "
        "between the calibration and each later measurement. Reported positions that are the same for "
        "several "
        "scans are one input.",
        size=6.8,
    )


def _verification_pages(d: _Doc) -> None:
    c = d.cert
    ver = c["verifications"]
    d.new_page()
    d.heading("7  Verification, decision rule and conformity")
    d.para(_decision_rule_text(c["laboratory"]))
    if not ver:
        d.para(c["conformity"]["text"])
    else:
        d.para(
            "Each verification measures a certified ring gauge with this calibration in the same "
            "night. The measured "
            "diameter is brought to 20 degC (ISO 1) with the gauge's expansion coefficient and the recorded "
            "temperature; E = D20 (measured) - D20 (certified). Where the gauge is the calibration's "
            "own, its "
            "certified diameter enters both and largely cancels in U(E)."
        )
        cols = [
            "scan",
            "gauge",
            "T [degC]",
            "D(T) [mm]",
            "D20 [mm]",
            "cert. [mm]",
            "E [um]",
            "U(E) [um]",
            "k",
            "T_ol [um]",
            "A [um]",
            "verdict",
        ]
        cells = []
        for v in ver:
            tflag = " (assumed)" if v.get("temperature_assumed") else ""
            cells.append(
                [
                    str(v.get("scan_id")),
                    str(v.get("artifact_id")),
                    _num(v.get("temperature_c"), ".2f") + tflag,
                    _num(v.get("measured_at_t_mm"), ".5f"),
                    _num(v.get("measured_mm"), ".5f"),
                    _num(v.get("certified_mm"), ".4f"),
                    _num(1e3 * v["error_mm"], "+.2f"),
                    _num(_scaled(v.get("expanded_u_error_mm"), 1e3), ".2f"),
                    _num(v.get("k"), ".2f"),
                    _num(1e3 * v["tolerance_mm"], ".1f"),
                    _num(
                        1e3 * v["acceptance_limit_mm"] if v.get("acceptance_limit_mm") is not None else None,
                        ".2f",
                    ),
                    (
                        split_verdict(v.get("conformity"))[0]
                        or ("conforms" if v.get("passed") else "does not conform")
                    ),
                ]
            )
        d.table(
            cols,
            cells,
            widths=[0.2, 0.07, 0.08, 0.09, 0.1, 0.08, 0.06, 0.065, 0.04, 0.065, 0.06, 0.05],
            size=6,
        )
        d.para(
            "T: recorded temperature; D(T): as measured at T; D20: brought to 20 degC; cert.: certified D20; "
            "E = D20 - cert.; T_ol: tolerance; A: acceptance limit (T_ol minus the guard band).",
            size=6.8,
        )
        for v in ver:
            d.para(f"{_ver_name(v)}: {v.get('conformity', '')}", size=7)
        d.para("Conformity statement: " + c["conformity"]["text"], size=8)
        for v in ver:
            _verification_budget(d, v)


#: columns of a one-result budget table (a rod layer's l0, a verification's E); contributions in um
_CONTRIBUTION_COLS = ["input x_i", "estimate", "u(x_i)", "dist.", "nu_i", "c_i", "u_i [um]"]

#: layout of those tables: (column widths as fractions of the text width, font size [pt])
_ROD_LAYER_LAYOUT = ([0.4, 0.13, 0.1, 0.1, 0.07, 0.09, 0.11], 6.2)

_VERIFICATION_LAYOUT = ([0.42, 0.12, 0.1, 0.1, 0.06, 0.1, 0.1], 6)


def _input_cells(r: dict, dash_zero_u: bool) -> list[str]:
    """Return one budget row as table cells.

    One budget row as table cells: label, estimate, u(x_i), distribution, nu_i, c_i, u_i [um]
    (``contribution`` [mm] times 1e3). ``dash_zero_u``: a zero or missing u(x_i) shows as "-".
    """
    u_x = r["standard_uncertainty"]
    est, u_txt = _est_u_text(r["estimate"], u_x, r["unit"], r.get("key", ""))
    return [
        _label(r),
        est,
        "-" if dash_zero_u and not u_x else u_txt,
        _DIST.get(r["distribution"], r["distribution"]),
        _dof_text(r["degrees_of_freedom"]),
        "-" if r["sensitivity_coefficient"] is None else _sig(r["sensitivity_coefficient"]),
        _sig(1e3 * r["contribution"]),
    ]


def _sum_row(label: str, value_mm: float, dof: str = "") -> list[str]:
    """Return a summary line of a budget table.

    Return a summary line of a budget table: ``label``, ``dof`` in the nu_i column, ``value_mm`` [mm] in
    um.
    """
    return [label, "", "", "", dof, "", _sig(1e3 * value_mm)]


def _contribution_table(
    d: _Doc,
    title: str,
    rows: list[dict],
    sums: list[list[str]],
    layout: tuple[list[float], float],
    dash_zero_u: bool,
) -> None:
    """Write the budget table of one result.

    Write the budget of one result: ``title``, one line per input row (:func:`_input_cells`), then the
    ``sums`` lines (:func:`_sum_row`, the last one bold); ``layout``: (column widths, font size).
    """
    cells = [_input_cells(r, dash_zero_u) for r in rows] + sums
    widths, size = layout
    d.room(0.013 * (len(cells) + 1) + 0.03)
    d.para(title, size=7.5)
    d.table(_CONTRIBUTION_COLS, cells, widths=widths, size=size, row_h=0.013, bold_last=True)


def _verification_budget(d: _Doc, v: dict) -> None:
    """Write the budget of a verification's error E.

    Write the budget of a verification's error E: inputs of at least 5 % of u_c(E) one by one, the
    others folded into one line (root sum of squares), then u_c(E) (contributions in um).
    """
    rows = v.get("budget") or []
    if not rows:
        return
    uc = math.sqrt(sum((r.get("contribution") or 0.0) ** 2 for r in rows))
    big = [r for r in rows if (r.get("contribution") or 0.0) >= 0.05 * uc]
    rest = math.sqrt(max(sum((r.get("contribution") or 0.0) ** 2 for r in rows if r not in big), 0.0))
    sums = [
        _sum_row(f"{len(rows) - len(big)} further inputs (each < 5 % of u_c), combined", rest),
        _sum_row("combined standard uncertainty u_c(E)", uc),
    ]
    _contribution_table(
        d,
        f"Budget of E, {_ver_name(v)} (contributions in um):",
        big,
        sums,
        _VERIFICATION_LAYOUT,
        dash_zero_u=False,
    )


def _rod_layer_budget(d: _Doc, channel: int, budget: dict) -> None:
    """Write the budget of one layer's l0.

    Write the budget of one layer's l0 (``budget``: rows and combined of certificate.json): inputs
    below 1e-5 u_c left out, then u_c with nu_eff and U with k (contributions in um).
    """
    comb = budget["combined"]
    rows = [r for r in budget["rows"] if not _tiny(r, comb["standard_uncertainty"])]
    sums = [
        _sum_row(
            "combined standard uncertainty u_c",
            comb["standard_uncertainty"],
            _dof_text(comb.get("effective_degrees_of_freedom")),
        ),
        _sum_row(f"expanded uncertainty U (k = {comb['coverage_factor']:.2f})", comb["expanded_uncertainty"]),
    ]
    _contribution_table(
        d,
        f"Layer {channel} (contributions in um; inputs below 1e-5 u_c left out):",
        rows,
        sums,
        _ROD_LAYER_LAYOUT,
        dash_zero_u=True,
    )


def _page_records(d: _Doc) -> None:
    c = d.cert
    d.new_page()
    d.heading("8  Records")
    d.kv(
        [
            ("Software", f"borescan {c['software_version']}, configuration hash {c['config_hash']}"),
            ("Date of issue", f"{c['dates'].get('issue') or 'n/a'}: {c['dates'].get('issue_rule', '')}"),
            ("Raw data", "SHA-256 of every raw file the calibration used:"),
        ]
    )
    for name, digest in c["raw_files"].items():
        d.room(0.013)
        d.fig.text(d.LEFT, d.y, name, family="monospace", fontsize=6.5)
        d.fig.text(0.42, d.y, digest, family="monospace", fontsize=6.5)
        d.y -= 0.012
    ver_files = {k: h for v in c["verifications"] for k, h in sorted((v.get("raw_files") or {}).items())}
    if ver_files:
        d.y -= 0.006
        d.para("SHA-256 of the raw files of the verifications reported in section 7:")
        for name, digest in ver_files.items():
            d.room(0.013)
            d.fig.text(d.LEFT, d.y, name, family="monospace", fontsize=6.5)
            d.fig.text(0.42, d.y, digest, family="monospace", fontsize=6.5)
            d.y -= 0.012
    d.y -= 0.01
    rod = (c.get("device") or {}).get("type") == "rod"
    if not rod or (c.get("fit") or {}).get("pose_residuals") is not None:
        d.para("Residuals of the fit: residuals.png beside this certificate, and the last page.")
