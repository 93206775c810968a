"""The DCC's measurement results: methods, equipment, conditions, results with U, budgets, verifications."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

from borescan.certificate.dcc_elements import Unit, decimal_text, dsi_unit
from borescan.certificate.dcc_elements import d as _d
from borescan.certificate.dcc_elements import is_num as _is_num
from borescan.certificate.dcc_elements import key_unit as _key_unit
from borescan.certificate.dcc_elements import plain as _plain
from borescan.certificate.dcc_elements import quantity as _quantity
from borescan.certificate.dcc_elements import real as _real
from borescan.certificate.dcc_elements import record as _record
from borescan.certificate.dcc_elements import s as _s
from borescan.certificate.dcc_elements import sub as _sub
from borescan.certificate.dcc_elements import text as _text
from borescan.uncertainty.coverage import chi2_quantile


def _methods(mr: ET.Element, cert: dict, m_in: dict) -> None:
    methods = _sub(mr, _d("usedMethods"))
    for m in m_in.get("usedMethods") or []:
        el = _sub(methods, _d("usedMethod"), refType=f"borescan_{m['name']}")
        _text(el, "name", m["name"])
        if m.get("description"):
            _text(el, "description", m["description"])
        if m.get("norm"):
            _sub(el, _d("norm"), m["norm"])
    lab = cert.get("laboratory") or {}
    el = _sub(methods, _d("usedMethod"), refType="basic_decisionRule")
    _text(el, "name", f"decision rule: {lab.get('decision_rule')}")
    for st in cert["administrativeData"].get("statements") or []:
        if st.get("refType") == "basic_decisionRule":
            _text(el, "description", st["declaration"])
    _sub(el, _d("norm"), "ILAC-G8:09/2019")
    sw = _sub(mr, _d("usedSoftware"))
    s = _sub(sw, _d("software"))
    _text(s, "name", "borescan")
    _sub(s, _d("release"), str(cert.get("software_version")))


def _equipment(mr: ET.Element, m_in: dict, p: float) -> None:
    eqs = [e for e in m_in.get("measuringEquipments") or [] if isinstance(e, dict)]
    if not eqs:
        return
    lst = _sub(mr, _d("measuringEquipments"))
    for e in eqs:
        el = _sub(lst, _d("measuringEquipment"), refType=e.get("refType"))
        _text(el, "name", f"{e.get('name')} {e.get('id')}")
        ids = _sub(el, _d("identifications"))
        for value, what in ((e.get("id"), "gauge id"), (e.get("certificate"), "gauge certificate number")):
            ident = _sub(ids, _d("identification"))
            _sub(ident, _d("issuer"), "owner")
            _sub(ident, _d("value"), str(value))
            _text(ident, "name", what)
        qs = _sub(el, _d("measuringEquipmentQuantities"))
        _gauge_quantities(qs, e)


def _gauge_quantities(qs: ET.Element, e: dict) -> None:
    """Return a reference gauge's certified diameter and the rest of its record.

    The diameter has the U and k of its certificate; when the certificate gives only k, the coverage
    probability of k for a normal distribution.
    """
    cd = e.get("certifiedDiameter") or {
        "value": e.get("certified_diameter_mm"),
        "expandedUnc": {"uncertainty": e.get("u_diameter_mm"), "coverageFactor": e.get("k")},
    }
    if _is_num(cd.get("value")):
        eu = dict(cd.get("expandedUnc") or {})
        if eu.get("coverageProbability") is None and _is_num(eu.get("coverageFactor")):
            eu["coverageProbability"] = float(f"{math.erf(eu['coverageFactor'] / math.sqrt(2.0)):.4g}")
        q = _sub(qs, _d("measuringEquipmentQuantity"), refType="borescan_certifiedDiameter")
        _text(
            q,
            "name",
            "certified diameter at 20 degC (coverage probability: that of k for a normal distribution "
            "where the gauge certificate states only k)",
        )
        _real(q, _s("real"), cd["value"], dsi_unit("mm"), expanded=eu)
    for k in sorted(e):
        if k in ("certifiedDiameter", "refType", "name") or not _is_num(e[k]):
            continue
        q = _sub(qs, _d("measuringEquipmentQuantity"))
        _text(q, "name", k)
        _real(q, _s("real"), e[k], dsi_unit(_key_unit(k)))


def _conditions(mr: ET.Element, cond: dict, p: float) -> None:
    """Return the influence conditions of the calibration.

    The gauge temperature (U for the certificate's coverage probability ``p``), the gauge and machine
    (expansion coefficient, radius at temperature, position accuracy) and the calibration scans.
    """
    lst = _sub(mr, _d("influenceConditions"))
    t = cond.get("temperature") or {}
    el = _sub(lst, _d("influenceCondition"), refType="basic_temperature")
    _text(el, "name", "temperature of the reference gauge")
    _text(
        el,
        "description",
        f"{t.get('source')}; assumed: {_plain(t.get('assumed'))}; u_c {t.get('u_c')} K, "
        f"half-width {t.get('halfwidth_c')} K ({t.get('distribution')})",
    )
    data = _sub(el, _d("data"))
    if _is_num(t.get("value_c")):
        q = _sub(data, _d("quantity"))
        _text(q, "name", "value_c")
        _real(
            q,
            _s("real"),
            t["value_c"],
            dsi_unit("degC"),
            expanded={
                "uncertainty": t.get("U_c"),
                "coverageFactor": t.get("k"),
                "coverageProbability": p,
                "distribution": t.get("distribution"),
            },
        )
    else:
        _quantity(data, "value_c", t.get("value_c"))
    for k in ("u_c", "halfwidth_c"):
        _quantity(data, k, t.get(k), dsi_unit("K"))
    others = {k: v for k, v in cond.items() if k not in ("temperature", "scans")}
    el = _sub(lst, _d("influenceCondition"), refType="borescan_calibrationConditions")
    _text(el, "name", "reference gauge and machine")
    data = _sub(el, _d("data"))
    for k in sorted(others):
        _record(data, k, others[k])
    if cond.get("scans"):
        el = _sub(lst, _d("influenceCondition"), refType="borescan_scans")
        _text(el, "name", "calibration scans (spindle and centre positions, speed, revolutions)")
        _record(_sub(el, _d("data")), "scans", cond["scans"])


def _beam_blocks(results: list[dict]) -> list[tuple[str, list[int]]]:
    """Results grouped per beam / layer: ``name[ch]`` -> (ch, indices)."""
    groups: dict[str, list[int]] = {}
    for i, r in enumerate(results):
        ch = r["name"].rsplit("[", 1)[-1].rstrip("]")
        groups.setdefault(ch, []).append(i)
    return list(groups.items())


def _result_unit(r: dict) -> Unit:
    return dsi_unit(_key_unit(r["name"].split("[", 1)[0]))


def _parameter_list(
    parent: ET.Element, label: str, results: list[dict], idx: list[int], cov: list[list] | None, p: float
) -> None:
    """Return the ``si:list`` of the results ``idx`` with their U and their joint ellipsoidal region.

    It is ``si:list`` > ``si:realList``; the region, from ``cov``, is a ``si:ellipsoidalRegion`` (SI units,
    coverage factor of the region).
    """
    sl = _sub(parent, _s("list"))
    rl = _sub(sl, _s("realList"))
    _sub(rl, _s("label"), label)
    for i in idx:
        r = results[i]
        _real(
            rl,
            _s("real"),
            r["real"]["value"],
            _result_unit(r),
            label=r["name"],
            expanded=r["real"]["expandedUnc"],
        )
    if cov is None:
        return
    reg = _sub(rl, _s("ellipsoidalRegion"))
    mat = _sub(reg, _s("covarianceMatrix"))
    units = [_key_unit(results[i]["name"].split("[", 1)[0]) for i in idx]
    for a, ia in enumerate(idx):
        col = _sub(mat, _s("column"))
        for b, ib in enumerate(idx):
            u = dsi_unit(units[b], times=units[a])
            c = _sub(col, _s("covariance"))
            _sub(c, _s("value"), decimal_text(cov[ib][ia], u.shift))
            _sub(c, _s("unit"), u.text)
    _sub(reg, _s("coverageFactor"), decimal_text(float(f"{math.sqrt(chi2_quantile(p, len(idx))):.6g}")))
    _sub(reg, _s("coverageProbability"), decimal_text(p))
    _sub(reg, _s("distribution"), "normal")


def _budget(parent: ET.Element, name: str, entry: dict) -> None:
    """Return one result's GUM budget.

    Rows (estimate and u in the input's unit, sensitivity, contribution in the result's unit) and the
    combination.
    """
    lst = _sub(parent, _d("list"), refType="borescan_uncertaintyBudget")
    _text(lst, "name", name)
    out_unit = entry.get("unit") or "-"
    _record(lst, "unit", out_unit, wrap=True)
    if entry.get("rows"):
        rows = _sub(lst, _d("list"))
        _text(rows, "name", "rows")
        for i, row in enumerate(entry["rows"]):
            _budget_row(rows, f"rows[{i}]", row, out_unit)
    _record(
        lst,
        "combined",
        entry.get("combined") or {},
        lambda k: dsi_unit(out_unit) if k in ("standard_uncertainty", "expanded_uncertainty") else None,
    )


def _budget_row(parent: ET.Element, name: str, row: dict, out_unit: str) -> None:
    in_unit = row.get("unit") or "-"
    units = {
        "estimate": dsi_unit(in_unit),
        "standard_uncertainty": dsi_unit(in_unit),
        "contribution": dsi_unit(out_unit),
        "sensitivity_coefficient": dsi_unit(out_unit, in_unit),
        "degrees_of_freedom": dsi_unit("-"),
    }
    _record(parent, name, row, units.get)


def _results(mr: ET.Element, cert: dict, m_in: dict, p: float) -> None:
    results = m_in["results"]
    lst = _sub(mr, _d("results"))
    cov = cert.get("covariance")
    rod = any(r.get("refType") == "borescan_rodBaseLength" for r in results)
    for ch, idx in _beam_blocks(results):
        res = _sub(lst, _d("result"), refType="borescan_layer" if rod else "borescan_beam")
        what = f"layer {ch}" if rod else f"beam of channel {ch}"
        held = [results[i]["name"] for i in idx if results[i].get("held_at_design_value")]
        _text(res, "name", what)
        _text(
            res,
            "description",
            ("base length l0" if rod else "direction beta [rad], offset rho [m], base length d_b [m]")
            + "; held at design value: "
            + (", ".join(held) or "none"),
        )
        q = _sub(_sub(res, _d("data")), _d("quantity"))
        _parameter_list(q, what, results, idx, cov, p)
    if cov and len(results) > 1:
        res = _sub(lst, _d("result"), refType="borescan_jointCovariance")
        _text(res, "name", "all parameters with their joint covariance")
        q = _sub(_sub(res, _d("data")), _d("quantity"))
        _parameter_list(q, "all parameters", results, list(range(len(results))), cov, p)
    budgets = m_in.get("uncertaintyBudget") or {}
    if budgets:
        res = _sub(lst, _d("result"), refType="borescan_uncertaintyBudgets")
        _text(res, "name", "uncertainty budgets (GUM, JCGM 100:2008)")
        data = _sub(res, _d("data"))
        for name in sorted(budgets):
            _budget(data, name, budgets[name])
    for v in cert.get("verifications") or []:
        _verification(lst, v)


def _verification(parent: ET.Element, v: dict) -> None:
    """Return a verification on a certified gauge: its numbers and its conformity.

    The numbers are the budget rows in their units.
    """
    res = _sub(parent, _d("result"), refType="basic_verification")
    feat = f" {v['feature']}" if v.get("feature") else ""
    _text(res, "name", f"verification {v.get('scan_id')}{feat} on {v.get('artifact_id')}")
    data = _sub(res, _d("data"))
    lst = _sub(data, _d("list"))
    _text(lst, "name", "verification")
    for k in sorted(v):
        if k == "budget" and v[k]:
            blst = _sub(lst, _d("list"), refType="borescan_uncertaintyBudget")
            _text(blst, "name", "budget")
            for i, row in enumerate(v[k]):
                _budget_row(blst, f"budget[{i}]", row, "mm")
        else:
            _record(lst, k, v[k], wrap=True)
    meta = _sub(lst, _d("measurementMetaData"))
    md = _sub(meta, _d("metaData"), refType="basic_conformity")
    _text(md, "declaration", str(v.get("conformity")))
    _sub(md, _d("conformity"), "pass" if v.get("passed") else "fail")


#: certificate.json keys the DCC states in its own elements; every other key goes into the record
_STATED = (
    "administrativeData",
    "measurementResults",
    "covariance",
    "verifications",
    "conformity",
    "conditions",
    "dates",
)


def _measurement_results(root: ET.Element, cert: dict) -> None:
    p = float(cert["coverage_probability"])
    mrs = _sub(root, _d("measurementResults"))
    for m_in in cert["measurementResults"]:
        mr = _sub(mrs, _d("measurementResult"))
        _text(mr, "name", m_in["name"])
        _methods(mr, cert, m_in)
        _equipment(mr, m_in, p)
        _conditions(mr, m_in.get("influenceConditions") or {}, p)
        _results(mr, cert, m_in, p)
        meta = _sub(mr, _d("measurementMetaData"))
        md = _sub(meta, _d("metaData"), refType="basic_conformity")
        _text(md, "declaration", (cert.get("conformity") or {}).get("text", ""))
        if (cert.get("conformity") or {}).get("conformity") in ("pass", "fail"):
            _sub(md, _d("conformity"), cert["conformity"]["conformity"])
        md = _sub(meta, _d("metaData"), refType="borescan_record")
        _text(
            md,
            "declaration",
            "the rest of certificate.json (fit, parameters, device, raw file digests, ...), "
            "each number in the unit its name gives",
        )
        data = _sub(md, _d("data"))
        for k in sorted(k for k in cert if k not in _STATED):
            _record(data, k, cert[k], _record_unit(k, cert))
        _record(data, "dates", cert.get("dates") or {})


def _record_unit(key: str, cert: dict):
    """Return the units of a record section whose numbers the key suffix does not name.

    A covariance has its parameters' units, a correlation is dimensionless.
    """
    if key == "correlation":
        return lambda _k: dsi_unit("-")
    return None
