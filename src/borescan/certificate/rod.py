"""Rod certificates: ``certificate.json`` of a rod calibration, its residuals per pose and its PDF pages."""

from __future__ import annotations

import math

import numpy as np
from matplotlib.figure import Figure

from borescan.certificate.admin import _measurement_results, _shared_part, _traceability_text
from borescan.certificate.budget_pages import _page_records, _rod_layer_budget, _verification_pages
from borescan.certificate.content import _METHOD_TEXT, _budget_entry, _fixed, _result, calibration_conditions
from borescan.certificate.layout import _A4, _Doc, _dominant_label, _fixed_title, _num, _ppm, _scaled, _vu
from borescan.certificate.pages import _page_admin, _sensor_table
from borescan.config import schema_default


def _rod_residual_figure(cert: dict, size=(8.27, 5.0), page: bool = False) -> Figure:
    """Residuals (model - reading) of the rod solve per layer against the pose angle [deg], in um."""
    pr = cert["fit"]["pose_residuals"]
    alpha = np.degrees(np.asarray([np.nan if a is None else a for a in pr["pose_angle_rad"]], dtype=float))
    res = np.asarray([[np.nan if x is None else x for x in row] for row in pr["residual_mm"]], dtype=float)
    fig = Figure(figsize=size)
    axes = fig.subplots(res.shape[1], 1, sharex=True, squeeze=False)[:, 0]
    for j, (ax, prow) in enumerate(zip(axes, cert["parameters"])):
        ok = np.isfinite(res[:, j]) & np.isfinite(alpha)
        ax.plot(alpha[ok], res[ok, j] * 1e3, "o", ms=3, color=f"C{j}")
        ax.axhline(0.0, color="k", lw=0.5)
        rms = float(np.sqrt(np.mean(res[ok, j] ** 2))) * 1e3 if ok.any() else float("nan")
        ax.set_ylabel(f"layer {prow['channel']} [um]")
        layer = f"layer {prow['channel']} ({prow.get('feature')})"
        _fixed_title(ax, f"{layer}: rms {rms:.2f} um over {int(ok.sum())} poses")
    axes[-1].set_xlabel("pose angle [deg]")
    if page:
        fig.text(
            _Doc.LEFT, 0.885, "9  Residuals of the rod solve (model - reading)", fontsize=10.5, weight="bold"
        )
        fig.subplots_adjust(left=0.12, right=0.94, top=0.84, bottom=0.1, hspace=0.35)
    else:
        fig.suptitle(f"Residuals of the rod solve (model - reading), {cert['calibration_id']}", fontsize=9)
        fig.tight_layout()
    return fig


def _rod_results(cal, p: float) -> tuple[list[dict], dict]:
    """DCC results (l0 [mm] per layer, U for coverage probability ``p``) and each one's budget."""
    results, budgets = [], {}
    for j, lay in enumerate(cal.layers):
        name = f"l0_mm[{int(lay.channel)}]"
        comb = cal.budget.combined(j, p)
        results.append(_result(name, "borescan_rodBaseLength", False, float(lay.l0_mm), "mm", comb))
        budgets[name] = _budget_entry("mm", cal.budget.rows(j), comb)
    return results, budgets


def _rod_parameters(cal) -> list[dict]:
    """Return the calibrated and design parameters of each layer.

    Per layer: l0 (calibrated and design) and u(l0) [mm], the layer's fixed geometry (h, d [mm],
    phi, gamma [rad]) and its ring gauge (certified D20, radius at temperature [mm]).
    """
    params = []
    for j, lay in enumerate(cal.layers):
        g = cal.gauges[j]
        params.append(
            {
                "channel": int(lay.channel),
                "feature": g.get("feature"),
                "l0_mm": float(lay.l0_mm),
                "l0_nominal_mm": float(cal.l0_nominal_mm[j]),
                "u_l0_mm": float(cal.u_l0_mm[j]),
                "h_mm": float(lay.h_mm),
                "phi_rad": float(lay.phi_rad),
                "d_mm": float(lay.d_mm),
                "gamma_rad": float(lay.gamma_rad),
                "gauge_id": g.get("id"),
                "gauge_certificate": g.get("certificate"),
                "gauge_certified_diameter_mm": g.get("certified_diameter_mm"),
                "gauge_radius_at_temperature_mm": g.get("radius_at_t_mm"),
            }
        )
    return params


def rod_pose_residuals(sol, pose_means_mm) -> dict:
    """Return the rod solve's residuals (model - reading) per pose and layer, for ``residuals.png``.

    ``sol``: the :class:`borescan.rod.RodSolution` the calibration settled at; ``pose_means_mm``: the (n, m)
    mean readings it solved. Returns ``pose_angle_rad`` (n,) and ``residual_mm`` (n, m) [mm], NaN where
    the solve used no reading (a pose it dropped, a missing reading). Raises ValueError for a solve
    without a least-squares fit (``centred``, ``pso``) or whose residuals do not match the readings.
    """
    if sol is None or sol.fit is None:
        raise ValueError("the rod solve has no least-squares fit: no residuals per pose")
    v = np.asarray(pose_means_mm, dtype=float)
    keep = np.isfinite(sol.alpha_rad)  # the poses the solve kept (the others have no angle)
    mask = np.isfinite(v[keep])
    e = np.asarray(sol.fit.residual, dtype=float)  # reading - model over the kept readings, pose-major
    if v.ndim != 2 or keep.size != v.shape[0] or e.size != int(mask.sum()):
        raise ValueError(
            f"rod residuals: {e.size} residuals for {int(mask.sum())} readings of "
            f"{int(keep.sum())} poses kept of {v.shape}"
        )
    kept = np.full(mask.shape, np.nan)
    kept[mask] = -e
    out = np.full(v.shape, np.nan)
    out[keep] = kept
    return {"pose_angle_rad": np.asarray(sol.alpha_rad, dtype=float), "residual_mm": out}


def _rod_fit(cal) -> dict:
    """Return the summary of the rod solve at the calibrated l0.

    Return the rod solve at the calibrated l0: residual rms [mm], solves to settle l0, method, rank,
    condition, number of poses, axis deflection [rad] and eccentricity [mm] (None without a solve).
    """
    sol = cal.solution
    return {
        "residual_rms_mm": cal.residual_rms_mm,
        "iterations": cal.iterations,
        "solve_method": None if sol is None else sol.method,
        "rank": None if sol is None else sol.rank,
        "condition": None if sol is None else sol.condition,
        "n_poses": None if sol is None else int(np.size(sol.alpha_rad)),
        "deflection_rad": None if sol is None else sol.deflection_rad,
        "eccentricity_mm": None if sol is None or sol.eccentricity_mm is None else sol.eccentricity_mm,
    }


def rod_certificate_dict(
    cal,
    *,
    device: dict,
    artifact: dict,
    temperature,
    cte,
    raw_files: dict[str, str],
    software_version: str,
    config_hash: str,
    laboratory: dict | None = None,
    coverage_probability: float | None = None,
    dates: dict | None = None,
    verifications: list[dict] | None = None,
    residuals: dict | None = None,
) -> dict:
    """Return the ``certificate.json`` of a rod calibration.

    ``certificate.json`` of a rod calibration (:class:`borescan.rod_calibration.RodCalibration`):
    the same administrative part as a three-sensor certificate, results l0 per layer with U and k,
    the budget per layer, each layer's gauge and the solve's diagnostics, with its residuals per pose
    and layer (``residuals``: :func:`rod_pose_residuals`; ``fit.pose_residuals``, drawn as
    ``residuals.png``).
    """
    p = float(
        schema_default("uncertainty", "coverage_probability")
        if coverage_probability is None
        else coverage_probability
    )
    results, budgets = _rod_results(cal, p)
    conditions = calibration_conditions(temperature, cte, None, None, p, [])
    gauges_text = "; ".join(
        f"layer {g['channel']}: ring gauge {g['id']}, certificate {g.get('certificate')}" for g in cal.gauges
    )
    shared = _shared_part(
        cal,
        item_name="measuring rod (rod)",
        item_id=device.get("id"),
        traceability=" ".join(_traceability_text(g) for g in _unique_gauges(cal)),
        device=device,
        artifact=artifact,
        conditions=conditions,
        raw_files=raw_files,
        software_version=software_version,
        config_hash=config_hash,
        laboratory=laboratory,
        coverage_probability=p,
        dates=dates,
        verifications=verifications,
    )
    return _fixed(
        {
            **shared,
            "item": "measuring rod",
            "traceability_summary": gauges_text + " (section 4)",
            "measurementResults": _measurement_results(
                "calibrated rod base lengths",
                cal.method,
                _METHOD_TEXT[cal.method],
                "JCGM 100:2008 (GUM)",
                [dict(g, refType="basic_normalUsed", name="ring gauge") for g in cal.gauges],
                conditions,
                results,
                budgets,
            ),
            "parameters": _rod_parameters(cal),
            "covariance": cal.budget.covariance(),
            "fit": dict(
                _rod_fit(cal),
                pose_residuals=None
                if residuals is None
                else {
                    "pose_angle_rad": residuals["pose_angle_rad"],
                    "residual_mm": residuals["residual_mm"],
                },
            ),
            "gauges": list(cal.gauges),
        }
    )


def _unique_gauges(cal) -> list[dict]:
    seen, out = set(), []
    for g in cal.gauges:
        key = (g.get("id"), g.get("certificate"))
        if key not in seen:
            seen.add(key)
            out.append(g)
    return out


def _rod_page_item_conditions(d: _Doc) -> None:
    """Write sections 1-4 of a rod certificate.

    Sections 1-4 of a rod certificate: item, method, conditions (temperature [degC], expansion
    coefficient [1/K]) and traceability (each layer's ring gauge).
    """
    c = d.cert
    d.new_page()
    d.heading("1  Item calibrated")
    _sensor_table(d, c["device"], c["device_id"])
    d.heading("2  Method")
    d.para(_METHOD_TEXT.get(c["method"], c["method"]))
    d.heading("3  Conditions of calibration")
    temp = c["conditions"].get("temperature") or {}
    cte = c["conditions"].get("gauge_cte") or {}
    d.kv(
        [
            (
                "Gauge temperature",
                f"{_num(temp.get('value_c'), '.2f')} degC, standard uncertainty "
                f"{_num(temp.get('u_c'), '.3f')} K (rectangular); {temp.get('source', 'not stated')}",
            ),
            (
                "Gauge expansion coeff.",
                f"{_ppm(cte.get('value_per_k'))} +- {_ppm(cte.get('halfwidth_per_k'))} "
                f"(rectangular); {cte.get('source', '')}",
            ),
            ("Calibration scans", ", ".join(c["scan_ids"])),
            (
                "Other conditions",
                "humidity, pressure and vibration are not recorded in scan.json; they enter no result",
            ),
        ],
        key_w=0.21,
        width=96,
    )
    d.heading("4  Traceability")
    cells = [
        [
            str(g["channel"]),
            str(g.get("feature")),
            str(g.get("id")),
            str(g.get("certificate")),
            _num(g.get("certified_diameter_mm"), ".4f"),
            _num(_scaled(g.get("u_diameter_mm"), 1e3), "g"),
            str(g.get("k")),
            _num(g.get("radius_at_t_mm"), ".5f"),
        ]
        for g in c["gauges"]
    ]
    d.table(
        ["layer", "feature", "ring gauge", "certificate", "D20 [mm]", "U [um]", "k", "R at T [mm]"],
        cells,
        widths=[0.07, 0.09, 0.17, 0.2, 0.12, 0.08, 0.06, 0.13],
        size=6.8,
    )
    for st in c["administrativeData"]["statements"]:
        if st.get("refType") == "basic_traceability":
            d.para(st["declaration"])


def _rod_page_results(d: _Doc) -> None:
    """Write section 5 of a rod certificate.

    Section 5 of a rod certificate: l0 per layer [mm] with U and k, its change from the design
    value [um], and the rod solve's summary.
    """
    c = d.cert
    d.new_page()
    d.heading("5  Results")
    p = c["coverage_probability"]
    d.para(
        "Calibrated base length l0 of each layer (axis foot to the sensor's measuring start), at which "
        "the rod solve "
        "returns the gauge's radius at its temperature. Expanded uncertainty U = k u_c for a coverage "
        "probability of "
        f"{100 * p:.2f} %. A rod diameter measured with this calibration moves by 2 (l0 - l0 true): its "
        "budget takes "
        "this one with sensitivity 2."
    )
    res = {r["name"]: r for r in c["measurementResults"][0]["results"]}
    budgets = c["measurementResults"][0]["uncertaintyBudget"]
    cells = []
    for prow in c["parameters"]:
        key = f"l0_mm[{prow['channel']}]"
        eu = res[key]["real"]["expandedUnc"]
        v, U = _vu(prow["l0_mm"], eu["uncertainty"])
        dom = (budgets.get(key, {}).get("combined") or {}).get("dominant_input", "")
        cells.append(
            [
                str(prow["channel"]),
                _num(prow["l0_nominal_mm"], ".4f"),
                v,
                U,
                _num(1e3 * (prow["l0_mm"] - prow["l0_nominal_mm"]), "+.2f"),
                _num(eu["coverageFactor"], ".2f"),
                _dominant_label(dom),
            ]
        )
    d.table(
        ["layer", "design l0 [mm]", "l0 [mm]", "U [mm]", "l0 - design [um]", "k", "dominant input"],
        cells,
        widths=[0.07, 0.13, 0.14, 0.1, 0.13, 0.06, 0.37],
        size=7,
    )
    fit = c["fit"]
    d.para(
        f"Rod solve at the calibrated l0 ({fit.get('solve_method')}): residual rms "
        f"{_num(_scaled(fit.get('residual_rms_mm'), 1e3), '.2f')} um over {fit.get('n_poses')} poses, "
        "Jacobian rank "
        f"{fit.get('rank')}, condition {_num(fit.get('condition'), '.3g')}; rod axis deflection "
        f"{_num(_scaled(fit.get('deflection_rad'), 180 / math.pi), '.3f')} deg; {fit.get('iterations')} "
        "solves to "
        "settle l0."
    )


def _rod_pages(cert: dict) -> list[Figure]:
    """Return the pages of a rod certificate's PDF (content: ``cert``, see :func:`rod_certificate_dict`)."""
    d = _Doc(cert)
    _page_admin(d)
    _rod_page_item_conditions(d)
    _rod_page_results(d)
    d.heading("6  Uncertainty budget")
    budgets = cert["measurementResults"][0]["uncertaintyBudget"]
    for prow in cert["parameters"]:
        _rod_layer_budget(d, prow["channel"], budgets[f"l0_mm[{prow['channel']}]"])
    _verification_pages(d)
    _page_records(d)
    if (cert.get("fit") or {}).get("pose_residuals") is not None:
        d.pages.append(_rod_residual_figure(cert, size=_A4, page=True))
    return d.finish()
