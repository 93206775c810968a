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
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from pathlib import Path

from borescan.atomic import atomic_write_bytes
from borescan.certificate.dcc_elements import d as _d
from borescan.certificate.dcc_elements import plain as _plain
from borescan.certificate.dcc_elements import sub as _sub
from borescan.certificate.dcc_elements import text as _text
from borescan.certificate.dcc_results import _measurement_results

DCC_FILE = "certificate.dcc.xml"

DCC_SCHEMA_VERSION = "3.1.2"


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


#: the declaration ElementTree writes for encoding="UTF-8"
_XML_DECLARATION = "<?xml version='1.0' encoding='UTF-8'?>\n"


def dcc_bytes(cert: dict) -> bytes:
    """Return the DCC of the certificate whose ``certificate.json`` content is ``cert`` (UTF-8 XML bytes)."""
    cert = copy.deepcopy(cert)  # the caller's content stays as it is (it is also written as certificate.json)
    root = ET.Element(_d("digitalCalibrationCertificate"), {"schemaVersion": DCC_SCHEMA_VERSION})
    _administrative(root, cert)
    _measurement_results(root, cert)
    ET.indent(root, space=" ")
    # ET.tostring(root, encoding="UTF-8", xml_declaration=True), byte for byte: serialised to text and encoded
    # once (the bytes path pushes each of the document's ~40 000 pieces through an encoding text wrapper)
    return (_XML_DECLARATION + ET.tostring(root, encoding="unicode") + "\n").encode("utf-8")


def write_dcc(cert: dict, out_dir: Path | str) -> Path:
    """Write ``certificate.dcc.xml`` of ``cert`` into ``out_dir`` (atomic); same content, same bytes."""
    path = Path(out_dir) / DCC_FILE
    atomic_write_bytes(path, dcc_bytes(cert))
    return path


def schema_path() -> Path:
    """Return the DCC 3.1.2 schema shipped with the package (it imports the D-SI 2.1.0 schema beside it)."""
    return Path(__file__).resolve().parents[1] / "schemas" / "dcc" / "dcc-3.1.2.xsd"


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
