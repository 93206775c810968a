"""certificate.dcc.xml: valid against PTB's DCC 3.1.2 schema (shipped with the package, offline) and
read back, by an independent reader (tests/dcc_reader.py: xmlschema's decoder), equal to
certificate.json to its last printed digit: every number of certificate.json is found.
"""

from __future__ import annotations

import json
import math
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

import dcc_reader as rd

from borescan.certificate.dcc import DCC_FILE, validate_dcc
from borescan.certificate.dcc_elements import decimal_text, dsi_unit


def test_decimal_text_moves_the_exponent_and_keeps_every_digit():
    assert decimal_text(12.5, -3) == "12.5e-3"
    assert float(decimal_text(12.5, -3)) == 0.0125
    assert decimal_text(1.15e-05) == "1.15e-05"
    assert decimal_text(1e-06, -3) == "1e-9"
    assert decimal_text(-5.50141004239, -3) == "-5.50141004239e-3"
    assert decimal_text(60) == "60"
    # a value at 12 significant digits survives the shift, read as a double and scaled back
    x = 132.672104344
    assert float(f"{float(decimal_text(x, -3)) * 1e3:.12g}") == x
    for bad in (float("nan"), float("inf")):
        with pytest.raises(ValueError):
            decimal_text(bad)
    with pytest.raises(TypeError):
        decimal_text(True)


def test_dsi_units_of_products_and_ratios():
    assert dsi_unit("mm").text == "\\metre" and dsi_unit("mm").shift == -3
    assert dsi_unit("mm", times="mm").text == "\\metre\\tothe{2}" and dsi_unit("mm", times="mm").shift == -6
    assert dsi_unit("rad", times="mm").text == dsi_unit("mm", times="rad").text == "\\metre\\radian"
    s = dsi_unit("mm", "rad")  # a sensitivity mm/rad
    assert (s.text, s.shift) == ("\\metre\\radian\\tothe{-1}", -3)
    assert dsi_unit("-").text == "\\one" and dsi_unit("1/K").text == "\\kelvin\\tothe{-1}"
    with pytest.raises(ValueError, match="furlong"):
        dsi_unit("furlong")


def test_an_invalid_document_is_refused_with_the_reason(tmp_path):
    bad = tmp_path / DCC_FILE
    bad.write_text(
        '<?xml version="1.0"?><dcc:digitalCalibrationCertificate xmlns:dcc="https://ptb.de/dcc" '
        'schemaVersion="3.1.2"/>'
    )
    with pytest.raises(ValueError, match=f"{DCC_FILE}: not a valid DCC 3.1.2"):
        validate_dcc(bad)


# --------------------------------------------------------------------------- read back


class Checked:
    """Numbers of certificate.json compared with the DCC, by JSON path."""

    def __init__(self):
        self.paths: set[tuple] = set()

    def num(self, path: tuple, printed, read) -> None:
        assert isinstance(read, float | int), f"{path}: read {read!r}"
        assert rd.same(read, printed), f"{path}: certificate.json {printed!r}, DCC {read!r}"
        self.paths.add(path)

    def tree(  # noqa: C901 (one branch per JSON value type walked)
        self, path: tuple, printed, read
    ) -> None:
        """Compare ``printed`` (a certificate.json subtree) with the reader's tree of the same names."""
        if isinstance(printed, bool) or printed is None or isinstance(printed, str):
            if isinstance(printed, str):
                assert read == printed, f"{path}: {printed!r} != {read!r}"
            return
        if isinstance(printed, int | float):
            self.num(path, printed, read)
        elif isinstance(printed, dict):
            for k, v in printed.items():
                if _has_numbers(v):
                    assert k in read, f"{path}: {k} missing from the DCC"
                    self.tree(path + (k,), v, read[k])
        elif (
            isinstance(printed, list)
            and printed
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in printed)
        ):
            assert len(read) == len(printed), path
            for i, (a, b) in enumerate(zip(printed, read)):
                self.num(path + (i,), a, b)
        elif isinstance(printed, list):
            name = path[-1]
            for i, v in enumerate(printed):
                if _has_numbers(v):
                    self.tree(path + (i,), v, read[f"{name}[{i}]"])


def _has_numbers(x) -> bool:
    return bool(_numeric_paths(x, ()))


def _numeric_paths(x, path: tuple) -> set[tuple]:
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return set()
    if isinstance(x, int | float):
        return {path}
    if isinstance(x, dict):
        return set().union(*(_numeric_paths(v, path + (k,)) for k, v in x.items())) if x else set()
    return set().union(*(_numeric_paths(v, path + (i,)) for i, v in enumerate(x))) if x else set()


def _by_ref(items, ref: str) -> list[dict]:
    def refs(x) -> list[str]:
        r = x.get("@refType") or []
        return r.split() if isinstance(r, str) else list(r)

    return [x for x in rd.as_list(items) if ref in refs(x)]


def check_read_back(  # noqa: C901 (one check per element of the DCC read back)
    cert_dir: Path,
) -> int:
    """Validate ``cert_dir``'s DCC and find every number of its certificate.json in it; returns how
    many numbers were compared.
    """
    cert = json.loads((cert_dir / "certificate.json").read_text())
    doc = rd.decode(cert_dir / DCC_FILE)  # strict: raises when invalid
    seen = Checked()
    mr_in = cert["measurementResults"][0]
    mr = rd.measurement_result(doc)
    # results: value, U, k, p; u and nu_eff are the budgets' (below) and the parameters' (record)
    params, cov = rd.beam_parameters(doc)
    names = [r["name"] for r in mr_in["results"]]
    for i, r in enumerate(mr_in["results"]):
        v, U, k, p = params[r["name"]]
        base = ("measurementResults", 0, "results", i, "real")
        seen.num(base + ("value",), r["real"]["value"], v)
        eu = r["real"]["expandedUnc"]
        for key, got in (("uncertainty", U), ("coverageFactor", k), ("coverageProbability", p)):
            seen.num(base + ("expandedUnc", key), eu[key], got)
        budget = (
            rd.tree(_by_ref(mr["dcc:results"]["dcc:result"], "borescan_uncertaintyBudgets")[0]["dcc:data"])
            if mr_in.get("uncertaintyBudget")
            else {}
        )
        for key, comb_key in (
            ("standardUncertainty", "standard_uncertainty"),
            ("effectiveDegreesOfFreedom", "effective_degrees_of_freedom"),
        ):
            if eu.get(key) is not None:
                seen.num(base + ("expandedUnc", key), eu[key], budget[r["name"]]["combined"][comb_key])
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            seen.num(("covariance", i, j), cert["covariance"][i][j], cov[(a, b)])
    # budgets, record, verifications, conditions, equipment: by name
    if mr_in.get("uncertaintyBudget"):
        res = _by_ref(mr["dcc:results"]["dcc:result"], "borescan_uncertaintyBudgets")[0]
        seen.tree(
            ("measurementResults", 0, "uncertaintyBudget"),
            mr_in["uncertaintyBudget"],
            rd.tree(res["dcc:data"]),
        )
    record = rd.tree(_by_ref(mr["dcc:measurementMetaData"]["dcc:metaData"], "borescan_record")[0]["dcc:data"])
    for key in cert:
        if key not in (
            "administrativeData",
            "measurementResults",
            "covariance",
            "verifications",
            "conformity",
            "conditions",
        ):
            seen.tree((key,), cert[key], record[key])
    vers = _by_ref(mr["dcc:results"]["dcc:result"], "basic_verification")
    assert len(vers) == len(cert["verifications"])
    for i, (v_in, v_res) in enumerate(zip(cert["verifications"], vers)):
        lst = rd.as_list(v_res["dcc:data"]["dcc:list"])[0]
        read = rd.tree(lst)
        seen.tree(("verifications", i), v_in, read)
        conf = rd.as_list(lst["dcc:measurementMetaData"]["dcc:metaData"])[0]
        assert conf["dcc:conformity"] == ("pass" if v_in["passed"] else "fail")
    # the overall conformity statement
    stmts = doc["dcc:administrativeData"]["dcc:statements"]["dcc:statement"]
    conf = _by_ref(stmts, "basic_conformity")[0]
    if cert["conformity"]["conformity"] in ("pass", "fail", "conditionalPass", "conditionalFail"):
        # conditional: the rule cannot decide (U not below the tolerance), on the pass or the fail side
        assert conf["dcc:conformity"] == cert["conformity"]["conformity"]
    else:  # no verification: a statement without a verdict (the schema's values are verdicts)
        assert "dcc:conformity" not in conf and rd.text(conf["dcc:declaration"]) == cert["conformity"]["text"]
    cond_in = mr_in["influenceConditions"]
    assert cert["conditions"] == cond_in  # certificate.json states them twice
    conds = mr["dcc:influenceConditions"]["dcc:influenceCondition"]
    temp = _by_ref(conds, "basic_temperature")[0]["dcc:data"]
    tq = {rd.text(q["dcc:name"]): q for q in rd.as_list(temp["dcc:quantity"])}
    t_in = cond_in["temperature"]
    if isinstance(t_in.get("value_c"), float | int):
        v, U, k, _p = rd.real_value(tq["value_c"]["si:real"])
        for key, got in (("value_c", v), ("U_c", U), ("k", k)):
            seen.num(("measurementResults", 0, "influenceConditions", "temperature", key), t_in[key], got)
    for key in ("u_c", "halfwidth_c"):
        seen.num(
            ("measurementResults", 0, "influenceConditions", "temperature", key),
            t_in[key],
            rd.quantity_value(tq[key]),
        )
    other = rd.tree(_by_ref(conds, "borescan_calibrationConditions")[0]["dcc:data"])
    for key, v in cond_in.items():
        if key not in ("temperature", "scans"):
            seen.tree(("measurementResults", 0, "influenceConditions", key), v, other[key])
    if cond_in.get("scans"):
        scans = rd.tree(_by_ref(conds, "borescan_scans")[0]["dcc:data"])
        seen.tree(("measurementResults", 0, "influenceConditions", "scans"), cond_in["scans"], scans["scans"])
    eqs = rd.as_list(mr["dcc:measuringEquipments"]["dcc:measuringEquipment"])
    for i, (e_in, e) in enumerate(zip(mr_in["measuringEquipments"], eqs)):
        qs = rd.as_list(e["dcc:measuringEquipmentQuantities"]["dcc:measuringEquipmentQuantity"])
        cd = _by_ref(qs, "borescan_certifiedDiameter")
        base = ("measurementResults", 0, "measuringEquipments", i)
        if "certifiedDiameter" in e_in:
            v, U, k, p = rd.real_value(cd[0]["si:real"])
            seen.num(base + ("certifiedDiameter", "value"), e_in["certifiedDiameter"]["value"], v)
            seen.num(
                base + ("certifiedDiameter", "expandedUnc", "uncertainty"),
                e_in["certifiedDiameter"]["expandedUnc"]["uncertainty"],
                U,
            )
            seen.num(
                base + ("certifiedDiameter", "expandedUnc", "coverageFactor"),
                e_in["certifiedDiameter"]["expandedUnc"]["coverageFactor"],
                k,
            )
            assert p == pytest.approx(
                math.erf(k / math.sqrt(2)), abs=5e-5
            )  # p of k for a normal distribution
        named = {rd.text(q.get("dcc:name")): q for q in qs}
        for key, val in e_in.items():
            if key != "certifiedDiameter" and isinstance(val, float | int) and not isinstance(val, bool):
                seen.num(base + (key,), val, rd.real_value(named[key]["si:real"])[0])
    # the item: its sensors are the device's (record), their serials identifications of the item
    assert cert["administrativeData"]["items"][0]["sensors"] == cert["device"]["sensors"]
    item = rd.as_list(doc["dcc:administrativeData"]["dcc:items"]["dcc:item"])[0]
    serials = [
        i["dcc:value"]
        for i in _by_ref(item["dcc:identifications"]["dcc:identification"], "borescan_sensorSerial")
    ]
    assert serials == [s["serial"] for s in cert["device"]["sensors"]]
    twice = (
        "conditions",
        ("administrativeData", "items"),
    )  # stated twice in certificate.json, compared above
    missing = {p for p in _numeric_paths(cert, ()) if p[0] not in twice and p[:2] not in twice} - seen.paths
    assert not missing, (
        f"{cert_dir}: numbers of certificate.json not found in the DCC: {sorted(missing)[:10]}"
    )
    return len(seen.paths)


def _certificate_dirs(results: Path) -> list[Path]:
    return sorted(p.parent for p in (results / "calibration").glob("night=*/*/*/certificate.json"))


@pytest.mark.slow
def test_every_demo_certificate_has_a_valid_dcc_read_back_equal_to_its_json(pipeline_run):
    dirs = _certificate_dirs(pipeline_run["results"])
    kinds = {json.loads((d / "certificate.json").read_text())["device"]["type"] for d in dirs}
    assert kinds == {"tri_lds", "rod"}, kinds
    for d in dirs:
        assert (d / DCC_FILE).is_file(), d
        validate_dcc(d / DCC_FILE)
        assert check_read_back(d) > 200, d
        # the bytes ElementTree's own UTF-8 writer gives (declaration and all): dcc_bytes serialises to text
        # and encodes once, the same document
        data = (d / DCC_FILE).read_bytes()
        assert ET.tostring(ET.fromstring(data), encoding="UTF-8", xml_declaration=True) + b"\n" == data, d


@pytest.mark.slow
def test_every_certificate_of_a_40_scan_contract_battery_has_a_valid_dcc_read_back_equal(
    tmp_path, monkeypatch
):
    """A 40-scan contract battery of rod scans (borescan simulate contract --kinds rod): each scan of the
    rod in a certified ring-gauge set is calibrated by the stage's own path (its layers' l0 from the
    gauges) and certified. The PDF is not under test here (tests/test_certificate*.py): its rendering
    is replaced by empty bytes to keep the battery fast.
    """
    import polars as pl

    from borescan import night_config, rawio
    from borescan.certificate import write
    from borescan.config import schema_defaults
    from borescan.stages.calibrate_jobs import CalibrationOutcome, RodCalibrationContext
    from borescan.stages.calibrate_rod import calibrate_rod_scan
    from borescan.synthetic import battery

    monkeypatch.setattr(write, "_pdf_bytes", lambda pages, title: b"")
    paths = battery.write_battery(tmp_path, 40, 0, kinds=("rod",))
    assert len(paths) == 40
    dflt = schema_defaults()
    ctx = RodCalibrationContext(
        dflt["uncertainty"],
        dflt["laboratory"],
        dflt["verification"],
        pl.DataFrame(schema={"scan_id": pl.Utf8, "status": pl.Utf8, "kind": pl.Utf8, "device_id": pl.Utf8}),
    )
    in_gauges = [s for s in map(rawio.read_scan, paths) if s.meta["kind"] == "verification"]
    night_config.settle(tmp_path / "results", sorted({s.night for s in in_gauges}), dflt)  # as the workflow
    made = CalibrationOutcome()
    for scan in in_gauges:
        made = made + calibrate_rod_scan(
            scan, scan.night, tmp_path / "results", ctx, dflt["calibration"], lambda _m: None
        )
    issued, bad = list(made.certificate_rows), list(made.quarantined)
    assert len(issued) + len(bad) == len(in_gauges) and len(issued) >= 12, (
        len(issued),
        [q.reason for q in bad],
    )
    dirs = sorted(p.parent for p in (tmp_path / "results" / "calibration").glob("*/*/*/certificate.json"))
    assert len(dirs) == len(issued)
    for d in dirs:
        validate_dcc(d / DCC_FILE)
        assert check_read_back(d) > 150, d
