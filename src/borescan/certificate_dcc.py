"""``certificate.dcc.xml``: a calibration certificate as a PTB Digital Calibration Certificate.

The document follows the DCC schema 3.1.2 (``https://ptb.de/dcc``) with quantities in the D-SI
format 2.1.0 (``https://ptb.de/si``); both schemas ship with the package
(``borescan/schemas/dcc/``, LGPL v3, see its README) so that a certificate validates offline
(:func:`validate_dcc`). It is built from the content of ``certificate.json``
(:func:`borescan.certificate.certificate_dict` / ``rod_certificate_dict``), so the two documents
say the same thing:

- ``administrativeData``: the software, the core data (country, languages, the certificate's
  unique identifier, dates of calibration; a reissue's ``previousReport`` names the certificate it
  replaces with the SHA-256 of its ``certificate.json``), the item (the device with its sensors'
  serials), the laboratory, the signatory, the customer and the statements (reproduction clause,
  traceability, decision rule, conformity, recalibration due date, date of issue, accreditation,
  weak or two-solution parameters, device-model effects carried).
- one ``measurementResult``: the methods (calibration, uncertainty evaluation, decision rule), the
  reference standards, the influence conditions (gauge temperature with U, k and p, its expansion
  coefficient, radius at temperature, the machine's position accuracy), the results and the
  certificate's supporting record in ``measurementMetaData``.
- results: per beam (three-sensor) a ``si:list`` of beta [rad], rho [m] and d_b [m], each with
  its ``si:expandedUnc``, and the beam's 3x3 covariance as ``si:ellipsoidalRegion`` /
  ``si:covarianceMatrix`` (coverage factor of the region: sqrt of the chi-squared quantile with 3
  degrees of freedom at the coverage probability); the joint covariance of all parameters the
  same way; per layer (rod) l0 [m]; each result's GUM budget; each verification with its
  conformity (``pass``/``fail``).

Numbers are written as the JSON prints them (12 significant digits), a unit prefix moved into the
decimal exponent (``12.5`` mm -> ``12.5e-3`` m), so a reader recovers every digit. The bytes depend
only on the certificate's content: no clock, attributes and children in a fixed order.
"""

from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from pathlib import Path


from borescan.atomic import atomic_write_bytes
from borescan.dcc_elements import NS_DCC, NS_SI, Unit, decimal_text, dsi_unit
from borescan.dcc_elements import d as _d
from borescan.dcc_elements import is_num as _is_num
from borescan.dcc_elements import key_unit as _key_unit
from borescan.dcc_elements import plain as _plain
from borescan.dcc_elements import quantity as _quantity
from borescan.dcc_elements import real as _real
from borescan.dcc_elements import record as _record
from borescan.dcc_elements import s as _s
from borescan.dcc_elements import sub as _sub
from borescan.dcc_elements import text as _text

__all__ = [
    "DCC_FILE",
    "DCC_SCHEMA_VERSION",
    "NS_DCC",
    "NS_SI",
    "dcc_bytes",
    "decimal_text",
    "dsi_unit",
    "schema_path",
    "validate_dcc",
    "write_dcc",
]

DCC_FILE = "certificate.dcc.xml"
DCC_SCHEMA_VERSION = "3.1.2"

# --------------------------------------------------------------------------- administrative data


def _core_data(adm: ET.Element, cert: dict) -> None:
    core_in = cert["administrativeData"]["coreData"]
    core = _sub(adm, _d("coreData"))
    _sub(core, _d("countryCodeISO3166_1"), str(core_in.get("countryCodeISO3166_1") or "XX"))
    for lang in core_in.get("usedLangCodeISO639_1") or ["en"]:
        _sub(core, _d("usedLangCodeISO639_1"), lang)
    for lang in core_in.get("mandatoryLangCodeISO639_1") or ["en"]:
        _sub(core, _d("mandatoryLangCodeISO639_1"), lang)
    _sub(core, _d("uniqueIdentifier"), str(core_in["uniqueIdentifier"]))
    ids = _sub(core, _d("identifications"))
    ident = _sub(ids, _d("identification"), refType="borescan_calibrationId")
    _sub(ident, _d("issuer"), "calibrationLaboratory")
    _sub(ident, _d("value"), str(cert["calibration_id"]))
    _text(ident, "name", "calibration id (the calibration this certificate reports)")
    _sub(core, _d("beginPerformanceDate"), str(core_in["beginPerformanceDate"]))
    _sub(core, _d("endPerformanceDate"), str(core_in["endPerformanceDate"]))
    # the schema's performanceLocation is a code; the laboratory's words are in the location statement
    _sub(core, _d("performanceLocation"), "laboratory")
    prev = (cert.get("reissue") or {}).get("replaces")
    if prev:
        h = _sub(core, _d("previousReport"))
        _text(
            h,
            "referral",
            f"certificate {prev['document_id']}, replaced by this one (ISO/IEC 17025:2017 7.8.8.2)",
        )
        _sub(h, _d("referralID"), str(prev["document_id"]))
        _sub(h, _d("procedure"), "SHA-256 of its certificate.json")
        _sub(h, _d("value"), str(prev["sha256"]))


def _item(adm: ET.Element, cert: dict) -> None:
    item_in = cert["administrativeData"]["items"][0]
    items = _sub(adm, _d("items"))
    item = _sub(items, _d("item"))
    _text(item, "name", item_in.get("name") or "")
    sensors = item_in.get("sensors") or []
    _text(
        item,
        "description",
        *(
            [
                f"channel {s.get('channel')}: laser displacement "
                f"sensor {s.get('model')}, serial {s.get('serial')}, "
                f"range {s.get('range_mm')} mm, linearity "
                f"{s.get('linearity_fs')} of full scale, repeatability "
                f"{s.get('repeatability_mm')} mm"
                for s in sensors
            ]
            or ["no sensors listed in scan.json"]
        ),
    )
    man = _sub(item, _d("manufacturer"))
    models = sorted({str(s.get("model")) for s in sensors if s.get("model")})
    _text(
        man, "name", "not stated in scan.json" + (f" (sensor models {', '.join(models)})" if models else "")
    )
    ids = _sub(item, _d("identifications"))
    for ident_in in item_in.get("identifications") or []:
        ident = _sub(ids, _d("identification"), refType="borescan_deviceId")
        _sub(ident, _d("issuer"), str(ident_in.get("issuer") or "customer"))
        _sub(ident, _d("value"), str(ident_in.get("value")))
        _text(ident, "name", "device id")
    for s in sensors:
        ident = _sub(ids, _d("identification"), refType="borescan_sensorSerial")
        _sub(ident, _d("issuer"), "manufacturer")
        _sub(ident, _d("value"), str(s.get("serial")))
        _text(ident, "name", f"serial of the sensor of channel {s.get('channel')}")


def _contact(parent: ET.Element, tag: str, name: str, email: str | None, address: str | None) -> None:
    c = _sub(parent, _d(tag))
    _text(c, "name", name or "")
    _sub(c, _d("eMail"), email or "")
    loc = _sub(c, _d("location"))
    _text(loc, "further", address or "not stated")


def _statement(parent: ET.Element, st: dict) -> None:
    el = _sub(parent, _d("statement"), refType=st.get("refType"))
    for tag in ("norm", "reference"):
        if st.get(tag):
            _sub(el, _d(tag), str(st[tag]))
    if st.get("declaration") is not None:
        _text(el, "declaration", st["declaration"])
    if st.get("date"):
        _sub(el, _d("date"), str(st["date"]))
    if st.get("conformity") in ("pass", "fail", "conditionalPass", "conditionalFail", "noPass", "noFail"):
        _sub(el, _d("conformity"), st["conformity"])


def _statements(cert: dict) -> list[dict]:
    """Return the certificate's statements plus those the DCC states in its own words.

    Date of issue, accreditation, place of calibration, weak or two-solution parameters, device-model effects.
    """
    adm, lab, fit = cert["administrativeData"], cert.get("laboratory") or {}, cert.get("fit") or {}
    out = [dict(st) for st in adm.get("statements") or []]  # copies: the content is not changed
    for st in out:  # the issue date of the certificate (DCC 3.1.2 has no coreData element for it)
        if st.get("refType") == "borescan_issueDate":
            st.setdefault("date", adm["coreData"].get("issueDate"))
    out.append(
        {"refType": "basic_accreditation", "declaration": adm["calibrationLaboratory"].get("accreditation")}
    )
    out.append({"refType": "basic_performanceLocation", "declaration": lab.get("performance_location")})
    weak = [f"rho of channel {ch} weakly determined" for ch in fit.get("weak_rho_channels") or []]
    weak += [
        f"rho of channel {ch}: cost along rho not linear (profiled)"
        for ch in fit.get("rho_profiled_channels") or []
    ]
    if fit.get("n_minima") is not None:
        weak.append(
            f"{fit.get('n_minima')} minima of the cost found; "
            f"ambiguous: {_plain(fit.get('ambiguous_minima'))}"
        )
    if weak:
        out.append({"refType": "borescan_weakParameters", "declaration": "; ".join(weak)})
    model = fit.get("device_model") or []
    out.append(
        {
            "refType": "borescan_deviceModel",
            "declaration": "device-model effects carried: "
            + ("; ".join(_model_text(m) for m in model) if model else "none"),
        }
    )
    reissue = cert.get("reissue")
    if reissue and reissue.get("replaces"):
        out.append(
            {
                "refType": "borescan_reissue",
                "norm": "ISO/IEC 17025:2017",
                "reference": "7.8.8.2",
                "date": adm["coreData"].get("issueDate"),
                "declaration": reissue.get("declaration", ""),
            }
        )
    return out


def _model_text(m: dict) -> str:
    """One device-model effect in words: its values with their standard uncertainties, the pooled night."""
    if not m.get("estimated"):
        return f"{m.get('key')} listed, not estimated by any earlier pooled examination (not corrected)"
    vals = ", ".join(
        f"{k} = {v} (u {(m.get('u') or {}).get(k)})" for k, v in sorted((m.get("values") or {}).items())
    )
    return f"{m.get('key')}: {vals}, from the pooled examination of {m.get('night')}"


def _administrative(root: ET.Element, cert: dict) -> None:
    a_in, lab = cert["administrativeData"], cert.get("laboratory") or {}
    adm = _sub(root, _d("administrativeData"))
    sw = _sub(adm, _d("dccSoftware"))
    for s in a_in["dccSoftware"]["software"]:
        el = _sub(sw, _d("software"))
        _text(el, "name", s["name"])
        _sub(el, _d("release"), str(s["release"]))
    _core_data(adm, cert)
    _item(adm, cert)
    cl = _sub(adm, _d("calibrationLaboratory"))
    c_in = a_in["calibrationLaboratory"]["contact"]
    _contact(cl, "contact", c_in.get("name"), lab.get("email"), (c_in.get("location") or {}).get("further"))
    persons = _sub(adm, _d("respPersons"))
    for p in a_in["respPersons"]:
        el = _sub(persons, _d("respPerson"))
        person = _sub(el, _d("person"))
        _text(person, "name", p["person"]["name"] or "")
        if p.get("role"):
            _sub(el, _d("role"), str(p["role"]))
        _sub(el, _d("mainSigner"), "true" if p.get("mainSigner") else "false")
    _contact(
        adm, "customer", a_in["customer"]["name"], lab.get("customer_email"), lab.get("customer_address")
    )
    sts = _sub(adm, _d("statements"))
    for st in _statements(cert):
        _statement(sts, st)


# --------------------------------------------------------------------------- measurement results


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
    from scipy.stats import chi2  # here, not at the top: a worker that measures scans never loads scipy.stats

    _sub(reg, _s("coverageFactor"), decimal_text(float(f"{math.sqrt(chi2.ppf(p, len(idx))):.6g}")))
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


# --------------------------------------------------------------------------- document


def dcc_bytes(cert: dict) -> bytes:
    """Return the DCC of the certificate whose ``certificate.json`` content is ``cert`` (UTF-8 XML bytes)."""
    cert = copy.deepcopy(cert)  # the caller's content stays as it is (it is also written as certificate.json)
    root = ET.Element(_d("digitalCalibrationCertificate"), {"schemaVersion": DCC_SCHEMA_VERSION})
    _administrative(root, cert)
    _measurement_results(root, cert)
    ET.indent(root, space=" ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def write_dcc(cert: dict, out_dir: Path | str) -> Path:
    """Write ``certificate.dcc.xml`` of ``cert`` into ``out_dir`` (atomic); same content, same bytes."""
    path = Path(out_dir) / DCC_FILE
    atomic_write_bytes(path, dcc_bytes(cert))
    return path


def schema_path() -> Path:
    """Return the DCC 3.1.2 schema shipped with the package (it imports the D-SI 2.1.0 schema beside it)."""
    return Path(__file__).resolve().parent / "schemas" / "dcc" / "dcc-3.1.2.xsd"


_SCHEMA = None


def validate_dcc(source: Path | str | bytes) -> None:
    """Validate a DCC (a path or the bytes) against the shipped schema, offline (``xmlschema``).

    Raise ValueError naming the document and the first problem.
    """
    try:
        import xmlschema
    except ImportError:  # the pipeline writes DCCs without it; only validation needs it
        raise ImportError(
            "validate_dcc needs xmlschema (in borescan's test extra: pip install xmlschema)"
        ) from None

    global _SCHEMA
    if _SCHEMA is None:
        _SCHEMA = xmlschema.XMLSchema(str(schema_path()))
    name = "<bytes>" if isinstance(source, bytes) else str(source)
    doc = source.decode("utf-8") if isinstance(source, bytes) else str(source)
    errors: Iterable = _SCHEMA.iter_errors(doc)
    first = next(iter(errors), None)
    if first is not None:
        raise ValueError(f"{name}: not a valid DCC {DCC_SCHEMA_VERSION}: {first.reason} at {first.path}")
