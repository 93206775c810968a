"""Certificates: ISO/IEC 17025 7.8 content, GUM budget, DCC-like JSON, layout and byte-identical
regeneration.
"""

import json
import re

import numpy as np
import pytest

from borescan.calibrate.sensitivities import full_residuals
from borescan.calibrate.yang import yang_calibration
from borescan.certificate import PLACEHOLDER, certificate_dir, write_certificate
from borescan.certificate.write import _pages
from borescan.config import schema_defaults
from borescan.uncertainty import Budget

R_MM = 275.029 / 2
LAB = {
    "name": "Metrology Lab Example GmbH",
    "address": "Example Street 1, 12345 Example Town",
    "country_code": "DE",
    "performance_location": "at the customer's boring mill",
    "accreditation": "Accredited by EXAMPLE AB, D-K-00000-00",
    "customer": "Example Machine Works",
    "signatory": "A. Example",
    "signatory_function": "Head of laboratory",
    "decision_rule": "guard_band",
    "guard_band_factor": 1.0,
}


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """Return a simulated calibration scan through the pipeline's own path: fit, GUM budget, certificate
    inputs.
    """
    from borescan import rawio
    from borescan.synthetic import scenes, simulate
    from borescan.stages.calibration_fit import calibrate_raw_scans, spindle_inputs
    from borescan.certificate import certificate_dates

    tmp = tmp_path_factory.mktemp("cal")
    scene = scenes.default_tri_scene()
    sim = simulate.simulate_tri_spindle(
        scene,
        scan_id="N20261121-TRI01-CAL-P1",
        night="2026-11-21",
        n_rev=5,
        noise_mm=0.002,
        seed=11,
        center_xy_mm=scene.bore_center_xy_mm,
    )
    scan = rawio.read_scan(simulate.write_simulated(sim, tmp / "raw", tmp / "truth"))
    cfg = schema_defaults()
    cal = calibrate_raw_scans([scan], cfg["calibration"], uncertainty=cfg["uncertainty"])
    x = spindle_inputs(scan, cfg["uncertainty"])
    dates = certificate_dates([scan.meta], "2026-11-21", 30, "2026-11-22")
    kw = dict(
        device={"id": "TRI-01", "type": "tri_lds", "sensors": scan.meta["sensors"]},
        artifact=dict(scan.meta["artifact"]),
        conditions={
            "temperature": {
                "value_c": 20.0,
                "u_c": 0.0577,
                "U_c": 0.0953,
                "k": 1.65,
                "assumed": False,
                "source": "scan.json",
            },
            "gauge_radius_at_temperature_mm": x.radius_mm,
            "position_accuracy_mm": 0.002,
            "scans": [
                {
                    "scan_id": scan.scan_id,
                    "spindle_position": scan.meta["spindle"]["position"],
                    "center": scan.meta["center"],
                    "rpm": 60.0,
                    "angle_source": "encoder",
                    "revolutions_recorded": 5.0,
                    "revolutions_with_extrema": 4,
                }
            ],
        },
        residuals={
            "t_s": x.t_s,
            "residual_mm": full_residuals(
                cal, x.t_s, x.readings_mm, x.radius_mm, scan.scan_id, angle_model=x.angle_model
            ),
        },
        raw_files={"scan.json": "b" * 64, "lds.parquet": "a" * 64},
        software_version="0.1.0",
        config_hash="c0ffee12",
        dates=dates,
    )
    return cal, kw


def _verification(passed: bool) -> dict:
    return {
        "scan_id": "N20261121-TRI01-VER-RG275",
        "artifact_id": "RG-275",
        "measured_mm": 275.0292,
        "measured_at_t_mm": 275.0292,
        "certified_mm": 275.029,
        "error_mm": 0.0002 if passed else 0.02,
        "expanded_u_error_mm": 0.0189,
        "k": 1.98,
        "tolerance_mm": 0.015,
        "acceptance_limit_mm": 0.015,
        "passed": passed,
        "temperature_c": 20.0,
        "conformity": "PASS" if passed else "FAIL",
        "budget": [],
    }


def test_regeneration_is_byte_identical(calibrated, tmp_path):
    cal, kw = calibrated
    a = write_certificate(cal, certificate_dir(tmp_path / "a", cal), **kw)
    first = {k: p.read_bytes() for k, p in a.items()}
    b = write_certificate(cal, certificate_dir(tmp_path / "b", cal), **kw)
    again = write_certificate(cal, certificate_dir(tmp_path / "a", cal), **kw)  # overwrite in place
    for k in ("json", "dcc", "pdf", "png"):
        assert b[k].read_bytes() == first[k], k
        assert again[k].read_bytes() == first[k], k
    assert sorted(p.name for p in a["json"].parent.iterdir()) == [
        "certificate.dcc.xml",
        "certificate.json",
        "certificate.pdf",
        "residuals.png",
    ]


def test_layout_metadata_and_page_x_of_y(calibrated, tmp_path):
    cal, kw = calibrated
    paths = write_certificate(cal, certificate_dir(tmp_path, cal), **kw, verifications=[_verification(True)])
    assert paths["pdf"].parent == tmp_path / "calibration" / "TRI-01" / cal.calibration_id
    pdf = paths["pdf"].read_bytes()
    assert pdf.startswith(b"%PDF")
    for key in (b"/CreationDate", b"/ModDate", b"/Producer", b"/Creator"):
        assert key not in pdf
    n_pdf = len(re.findall(rb"/Type /Page\b(?!s)", pdf))
    # administrative page, item/conditions/traceability, results, budget, verification, records, residuals
    assert n_pdf >= 7
    cert = json.loads(paths["json"].read_text())
    t, res = np.asarray(kw["residuals"]["t_s"]), np.asarray(kw["residuals"]["residual_mm"])
    pages = _pages(cert, t, res)
    assert len(pages) == n_pdf
    for i, fig in enumerate(pages):
        texts = [x.get_text() for x in fig.texts]
        assert texts.count(f"Page {i + 1} of {n_pdf}") == 2, i  # header and footer
        assert f"No. {cal.calibration_id}" in texts
    png = paths["png"].read_bytes()
    assert png.startswith(b"\x89PNG") and b"Software" not in png and b"matplotlib" not in png


def test_json_content_and_budget(calibrated, tmp_path):
    cal, kw = calibrated
    text = write_certificate(cal, tmp_path, **kw)["json"].read_text()
    cert = json.loads(text)
    assert text == json.dumps(cert, sort_keys=True, indent=2) + "\n"  # sorted keys, no NaN
    assert cert["calibration_id"] == cal.calibration_id and cert["method"] == "full_lsq"
    assert list(cert["raw_files"]) == ["lds.parquet", "scan.json"]
    budget = Budget.from_dict(cal.diagnostics["budget"])
    p = cert["coverage_probability"]
    assert p == schema_defaults()["uncertainty"]["coverage_probability"]
    for j, row in enumerate(cert["parameters"]):
        assert row["channel"] == j + 1
        for k, name in enumerate(("beta_rad", "rho_mm", "d_b_mm")):
            comb = budget.combined(3 * j + k, p)
            assert row[f"u_{name}"] == pytest.approx(np.sqrt(cal.cov[3 * j + k, 3 * j + k]), rel=1e-9)
            assert row[f"U_{name}"] == pytest.approx(comb.k * comb.u, rel=1e-11)
        assert row["d_b_mm"] == pytest.approx(cal.beams.d_b_mm[j], rel=1e-11)
        # the reference standard and the sensors are in: U(d_b) is at least the linearity's 95 % bound
        lin = kw["device"]["sensors"][j]["linearity_fs"] * kw["device"]["sensors"][j]["range_mm"]
        assert row["U_d_b_mm"] > 0.9 * lin
    assert np.array(cert["covariance"]).shape == (9, 9)
    assert np.allclose(cert["covariance"], budget.covariance(), rtol=1e-10, atol=1e-20)
    assert np.allclose(cert["covariance_fit"], cal.diagnostics["cov_fit"])
    # the budget table: quantity, estimate, standard uncertainty, distribution, sensitivity, contribution
    mr = cert["measurementResults"][0]
    rows = {r["key"]: r for r in mr["uncertaintyBudget"]["d_b_mm[2]"]["rows"]}
    g = rows["gauge:RG-275@RG-275/2026-03:D20"]
    assert g["estimate"] == 275.029 and g["standard_uncertainty"] == pytest.approx(0.00075)
    assert g["distribution"] == "normal" and g["sensitivity_coefficient"] == pytest.approx(0.5, abs=0.01)
    assert g["contribution"] == pytest.approx(0.5 * 0.00075, rel=0.02)
    lin = rows["linearity:" + cal.calibration_id + ":ch2"]
    assert lin["distribution"] == "rectangular" and lin["sensitivity_coefficient"] == pytest.approx(
        -1.0, abs=1e-6
    )
    assert {"fit:" + cal.calibration_id + ":readings", "temperature:N20261121-TRI01-CAL-P1"} <= set(rows)
    for r in mr["results"]:
        eu = r["real"]["expandedUnc"]
        assert {"uncertainty", "coverageFactor", "coverageProbability", "distribution"} <= set(eu)
    # effective base length with its U (it was printed "+- 0.0000")
    assert all(r["expandedUnc"]["uncertainty"] > 1e-3 for r in cert["effective_base_length"])
    assert (
        cert["artifact"]["certified_diameter_mm"] == 275.029
        and cert["conditions"]["temperature"]["value_c"] == 20.0
    )
    assert cert["software_version"] == "0.1.0" and cert["config_hash"] == "c0ffee12"


def test_iso17025_administrative_data_and_placeholders(calibrated, tmp_path):
    cal, kw = calibrated
    cert = json.loads(write_certificate(cal, tmp_path / "d", **kw)["json"].read_text())
    adm = cert["administrativeData"]
    core = adm["coreData"]
    assert core["uniqueIdentifier"] == cal.calibration_id
    assert core["beginPerformanceDate"] == core["endPerformanceDate"] == "2026-11-21"
    assert core["issueDate"] == "2026-11-22" and "first processed" in cert["dates"]["issue_rule"]
    assert cert["dates"]["recalibration_due"] == "2026-12-21"
    # the defaults are placeholders and the certificate says which
    assert set(adm["placeholders"]) >= {"name", "address", "accreditation", "customer", "signatory"}
    assert PLACEHOLDER in adm["calibrationLaboratory"]["contact"]["name"]
    kinds = {s.get("refType", s.get("reference")): s for s in adm["statements"]}
    assert "RG-275/2026-03" in kinds["basic_traceability"]["declaration"]
    assert "issuer not stated" in kinds["basic_traceability"]["declaration"]
    assert kinds["basic_conformity"]["conformity"] == "noStatement"
    assert kinds["basic_recalibration"]["date"] == "2026-12-21"
    # a configured laboratory, a traceable gauge, a failed verification
    art = dict(kw["artifact"], certificate_issuer="Example NMI", certificate_valid_until="2027-03-31")
    kw2 = dict(kw, laboratory=LAB, artifact=art, verifications=[_verification(True), _verification(False)])
    cert = json.loads(write_certificate(cal, tmp_path / "e", **kw2)["json"].read_text())
    adm = cert["administrativeData"]
    assert adm["placeholders"] == []
    assert (
        adm["respPersons"][0]["person"]["name"] == "A. Example" and adm["customer"]["name"] == LAB["customer"]
    )
    kinds = {s.get("refType", s.get("reference")): s for s in adm["statements"]}
    trace = kinds["basic_traceability"]["declaration"]
    assert "Example NMI" in trace and "2027-03-31" in trace
    assert kinds["basic_conformity"]["conformity"] == "fail"
    assert "Guarded acceptance" in kinds["basic_decisionRule"]["declaration"]
    assert mr_equipment(cert)["issuer"] == "Example NMI"


def mr_equipment(cert):
    return cert["measurementResults"][0]["measuringEquipments"][0]


def test_certificate_dates_come_from_the_scans_and_the_night_record():
    from borescan.certificate import certificate_dates

    d = certificate_dates(
        [{"started_at": "2026-11-20T22:14:03Z"}, {"started_at": "2026-11-20T23:50:00Z"}],
        "2026-11-20",
        30,
        "2026-11-27",
    )
    assert (d["begin"], d["end"], d["issue"], d["recalibration_due"]) == (
        "2026-11-20",
        "2026-11-20",
        "2026-11-27",
        "2026-12-20",
    )
    assert "first processed" in d["issue_rule"]
    d = certificate_dates([{"started_at": "2026-11-20T23:30:00-02:00"}], "2026-11-20", 7, "2026-11-21")
    assert d["begin"] == "2026-11-21" and d["recalibration_due"] == "2026-11-27"  # 01:30 UTC next day


def test_yang_certificate_without_fit_diagnostics(tmp_path):
    cal = yang_calibration(
        [7.0549, 6.9256, 5.7177],
        [2.4067, 2.2804, 1.073],
        ["backward", "backward", "advanced"],
        [312.0, 88.0, 199.0],
        660.0,
        R_MM,
        2.3222,
        device_id="TRI-01",
        scan_ids=["N20170205-P1"],
        u_d_max_mm=1e-4,
        u_d_min_mm=1e-4,
    )
    t = np.arange(5) * 0.1
    paths = write_certificate(
        cal,
        tmp_path,
        device={"id": "TRI-01"},
        artifact={"id": "RG-275"},
        conditions={},
        residuals={"t_s": t, "residual_mm": np.zeros((5, 3))},
        raw_files={},
        software_version="0.1.0",
        config_hash="x",
    )
    cert = json.loads(paths["json"].read_text())
    assert cert["method"] == "yang2017" and cert["fit"]["residual_rms_mm"] is None
    assert cert["parameters"][2]["rho_mm"] == pytest.approx(1.5627026, abs=1e-6)
    # no budget recorded: U from the covariance alone, k for a normal output
    assert cert["parameters"][2]["U_rho_mm"] == pytest.approx(2.0 * np.sqrt(cal.cov[7, 7]), rel=1e-4)


def test_no_iso_17025_claim_without_an_accreditation():
    """Issue 37 item 10: "issued in accordance with ISO/IEC 17025" only under a stated accreditation."""
    from borescan.certificate.admin import _standard_statement
    from borescan.config import schema_defaults

    placeholder = schema_defaults()["laboratory"]
    assert "claims no accreditation" in _standard_statement(placeholder)
    assert "in accordance" not in _standard_statement(placeholder)
    text = _standard_statement({"accreditation": "DAkkS D-K-12345-01-00"})
    assert (
        text
        == "This certificate is issued in accordance with ISO/IEC 17025:2017 7.8 (DAkkS D-K-12345-01-00)."
    )


def test_table_cells_sit_where_matplotlibs_table_puts_them():
    """The PDF's tables (drawn straight on the page) put every cell's text where ``Axes.table`` with the
    same rectangle, column widths and centred cells puts it: the layout the pages had before.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from borescan.certificate.layout import _Doc

    cols, cells, widths = ["a", "bb", "ccc"], [["1", "22", "333"], ["4", "55", "666"]], [0.2, 0.5, 0.3]
    doc = _Doc({"laboratory": {}})
    top, row_h = doc.y, 0.02
    doc.table(cols, cells, widths=widths, size=7, row_h=row_h, bold_last=True)
    h = row_h * 3
    assert doc.y == pytest.approx(top - h - 0.012, abs=1e-12)
    texts = {t.get_text(): t for t in doc.fig.texts}
    assert {t.get_weight() for s, t in texts.items() if s in ("a", "4", "666")} == {"bold"}
    assert texts["1"].get_weight() == "normal"

    ref = Figure(figsize=doc.fig.get_size_inches())
    ax = ref.add_axes([_Doc.LEFT, top - h, _Doc.RIGHT - _Doc.LEFT, h])
    tab = ax.table(cellText=cells, colLabels=cols, colWidths=widths, bbox=[0, 0, 1, 1], cellLoc="center")
    tab.auto_set_font_size(False)
    tab.set_fontsize(7)
    for (r, _c), cell in tab.get_celld().items():  # the old code's bold header and last row
        if r in (0, 2):
            cell.get_text().set_weight("bold")
    renderer = FigureCanvasAgg(ref).get_renderer()
    tab.draw(renderer)  # places the cells
    mine = FigureCanvasAgg(doc.fig).get_renderer()
    for (r, c), cell in tab.get_celld().items():
        want = cell.get_text().get_window_extent(renderer)
        got = texts[cell.get_text().get_text()].get_window_extent(mine)
        # the same text at the same size: the same box, to well under a pixel at the figure's dpi
        np.testing.assert_allclose(got.get_points(), want.get_points(), atol=1e-6, err_msg=f"cell {r},{c}")


def _pdf_streams(pdf: bytes) -> bytes:
    """Return the PDF's streams, inflated (matplotlib compresses each with zlib), joined."""
    import zlib

    out = []
    for m in re.finditer(rb"stream\r?\n(.*?)\r?\nendstream", pdf, re.S):
        try:
            out.append(zlib.decompress(m.group(1)))
        except zlib.error:
            out.append(m.group(1))
    return b"\n".join(out)


def _pdf_string(text: str) -> bytes:
    """Return ``text`` as a PDF string literal in WinAnsi, escaped as matplotlib writes it."""
    esc = text.replace("\\", "\\\\").replace("(", "\\(").replace(")", "\\)").replace("\r", "\\r")
    return b"(" + esc.encode("cp1252") + b")"


def test_pdf_text_is_written_whole_in_the_core_helvetica(calibrated, tmp_path):
    """Every string the pages draw is one text show of a core font, nothing embedded (issue 38's cost)."""
    cal, kw = calibrated
    paths = write_certificate(cal, tmp_path / "c", **kw, verifications=[_verification(True)])
    pdf = paths["pdf"].read_bytes()
    assert b"/BaseFont /Helvetica" in pdf and b"/BaseFont /Helvetica-Bold" in pdf
    assert b"/CharProcs" not in pdf and b"/FontFile" not in pdf  # no Type 3 glyphs, no embedded font
    content = _pdf_streams(pdf)
    cert = json.loads(paths["json"].read_text())
    t, res = np.asarray(kw["residuals"]["t_s"]), np.asarray(kw["residuals"]["residual_mm"])
    texts = [x.get_text() for fig in _pages(cert, t, res) for x in fig.texts if x.get_text()]
    assert len(texts) > 300
    missing = [s for s in texts if _pdf_string(s) not in content]
    assert missing == []
    assert b"\xe2\x88\x92" not in content  # the residual axes' minus is WinAnsi's hyphen-minus


def test_core_font_metrics_are_parsed_once_and_the_pdf_is_the_same(calibrated, tmp_path, monkeypatch):
    """The PDF writer gets each core font's AFM parsed once per process (layout._core_font_metrics): two
    certificates parse each file once, the documents are byte for byte those of matplotlib's own parse, and
    the writer's parser is matplotlib's again after the certificate.
    """
    import matplotlib._afm
    from matplotlib.backends import backend_pdf

    from borescan.certificate import layout

    cal, kw = calibrated
    parsed: list[str] = []

    class CountingAFM(matplotlib._afm.AFM):
        def __init__(self, fh):
            parsed.append(fh.name)
            super().__init__(fh)

    monkeypatch.setattr(matplotlib._afm, "AFM", CountingAFM)
    monkeypatch.setattr(layout, "_AFM_BY_FILE", {})
    own = backend_pdf.AFM
    a = write_certificate(cal, tmp_path / "a", **kw)["pdf"].read_bytes()
    b = write_certificate(cal, tmp_path / "b", **kw)["pdf"].read_bytes()
    assert backend_pdf.AFM is own
    assert a == b and len(parsed) >= 2 and len(parsed) == len(set(parsed))  # Helvetica, Helvetica-Bold, ...
    # matplotlib's own parse for every document: the same bytes
    monkeypatch.setattr(layout, "_core_font_metrics", lambda fh: CountingAFM(fh))
    parsed.clear()
    c = write_certificate(cal, tmp_path / "c", **kw)["pdf"].read_bytes()
    assert c == a and len(parsed) >= 2


def test_pdf_beyond_winansi_keeps_the_embedded_font(calibrated, tmp_path):
    """A laboratory named in Polish: Helvetica's WinAnsi has no L-stroke, so the PDF embeds DejaVu Sans."""
    from borescan.certificate.layout import _pdf_rc

    cal, kw = calibrated
    lab = dict(schema_defaults()["laboratory"], name="Laboratorium Metrologii \u0141\u00f3d\u017a")
    paths = write_certificate(cal, tmp_path / "c", **kw, laboratory=lab)
    cert = json.loads(paths["json"].read_text())
    assert cert["laboratory"]["name"] == lab["name"]
    assert _pdf_rc(cert)["font.family"] == "DejaVu Sans" and "pdf.use14corefonts" not in _pdf_rc(cert)
    pdf = paths["pdf"].read_bytes()
    assert b"/BaseFont /Helvetica" not in pdf
    assert b"/CharProcs" in pdf and b"DejaVuSans" in pdf  # Type 3 glyphs of the embedded DejaVu Sans
