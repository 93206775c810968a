"""`snakemake --report` on the demo run: every item the rules declare with report(...) is in it,
under the issue's categories, with its caption rendered (issue "The shop floor's morning", item 2).
"""

from __future__ import annotations

import ast
import hashlib
import json
import os
import re
import zipfile
from pathlib import Path

import duckdb
import pytest
from snakemake.io import regex_from_filepattern

from conftest import ROOT, run_snakemake

CATEGORIES = {"Calibration", "Verification", "Diameters", "Discrepancy", "Papers"}
MONTH_PLOT_CATEGORY = {
    "calibration": "Calibration",
    "control": "Verification",
    "diameters": "Diameters",
    "devicemodel": "Calibration",
}


# ------------------------------------------------------------------ what the rules declare


def _call_end(text: str, start: int) -> int:
    """Index just past the parenthesis closing the one at ``start`` (string literals skipped)."""
    depth, i = 0, start
    while i < len(text):
        c = text[i]
        if c in "\"'":
            j = i + 1
            while text[j] != c:
                j += 2 if text[j] == "\\" else 1
            i = j
        elif c in "([{":
            depth += 1
        elif c in ")]}":
            depth -= 1
            if depth == 0:
                return i + 1
        i += 1
    raise ValueError("unbalanced parentheses")


def _template(src: str, node: ast.expr) -> str:
    """Return the path of an output, ``{RES}`` and ``{night}`` left as such (f-string braces undone)."""
    seg = ast.get_source_segment(src, node)
    m = re.fullmatch(r'[rf]*"(.*)"', seg, re.S)
    return m.group(1).replace("{{", "{").replace("}}", "}")


def declared_report_items() -> list[dict]:
    """Every ``report(...)`` of rules/*.smk: rule, output name, path template, directory or not,
    patterns, caption, category/subcategory (a string, or the name of the function giving it).
    """
    items = []
    for smk in sorted((ROOT / "rules").glob("*.smk")):
        text = smk.read_text()
        for m in re.finditer(r"(?<![\w.])(\w+)\s*=\s*report\(", text):
            src = text[m.start(0) + len(m.group(0)) - len("report(") : _call_end(text, m.end(0) - 1)]
            call = ast.parse(src, mode="eval").body
            kw = {k.arg: k.value for k in call.keywords}
            arg, flags = call.args[0], set()
            while isinstance(arg, ast.Call):
                flags.add(arg.func.id)
                arg = arg.args[0]

            def value(node):
                if node is None:
                    return None
                return node.id if isinstance(node, ast.Name) else ast.literal_eval(node)

            items.append(
                {
                    "rule": re.findall(r"^rule (\w+):", text[: m.start(0)], re.M)[-1],
                    "name": m.group(1),
                    "smk": smk.name,
                    "template": _template(src, arg),
                    "directory": "directory" in flags,
                    "patterns": value(kw.get("patterns")) or [],
                    "caption": value(kw.get("caption")),
                    "category": value(kw.get("category")),
                    "subcategory": value(kw.get("subcategory")),
                }
            )
    return items


def expected_files(item: dict, results: Path, nights: list[str]) -> set[str]:
    """Return the files ``snakemake --report`` must show for one declared item, found here on disk."""
    paths = {item["template"].replace("{RES}", str(results)).replace("{night}", n) for n in nights}
    if not item["directory"]:
        assert all(Path(p).is_file() for p in paths), paths
        return paths
    found = set()
    for d in paths:
        assert Path(d).is_dir(), f"declared folder {d} of rule {item['rule']} missing"
        for pattern in item["patterns"]:
            rx = re.compile(regex_from_filepattern(os.path.normpath(os.path.join(d, pattern))))
            for dirpath, dirnames, filenames in os.walk(d):  # as Snakemake does: links not followed
                paths_here = (os.path.normpath(os.path.join(dirpath, f)) for f in filenames + dirnames)
                found |= {p for p in paths_here if rx.match(p)}
    return found


# ------------------------------------------------------------------ the report


@pytest.fixture(scope="module")
def snakemake_report(pipeline_run, tmp_path_factory):
    """``snakemake --report report.zip`` over the demo run, unzipped; its results and categories."""
    assert pipeline_run["proc"].returncode == 0, pipeline_run["proc"].stderr[-3000:]
    out = tmp_path_factory.mktemp("snakemake_report")
    proc = run_snakemake(pipeline_run["raw"], pipeline_run["results"], "--report", str(out / "report.zip"))
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    with zipfile.ZipFile(out / "report.zip") as z:
        members = set(z.namelist())
        z.extractall(out / "unzipped")
    page = (out / "unzipped" / "report" / "report.html").read_text()

    def var(script_id, name):  # <script id="results"> var results = {...}; </script>
        m = re.search(rf'<script id="{script_id}">\s*var {name} = ', page)
        return json.JSONDecoder().raw_decode(page, m.end())[0]

    return {
        "dir": out / "unzipped" / "report",
        "members": members,
        "page": page,
        "results": var("results", "results"),
        "categories": var("categories", "categories"),
        "description": var("workflow-desc", "workflow_desc"),
        "log": proc.stdout + proc.stderr,
    }


def _nights(run) -> list[str]:
    return sorted(p.name.removeprefix("night=") for p in run["raw"].glob("night=*"))


def test_every_declared_item_is_in_the_report(pipeline_run, snakemake_report):
    items = declared_report_items()
    # the rules declare the papers, the per-scan and pooled findings, the report page and its month pages
    assert {(i["rule"], i["name"]) for i in items} >= {
        ("reproduce_papers", "yang_table1"),
        ("reproduce_papers", "wang_png"),
        ("discrepancy_night", "scans"),
        ("pooled_night", "json"),
        ("write_report", "html"),
        ("write_report", "pages"),
    }
    results, nights = pipeline_run["results"], _nights(pipeline_run)
    shown = set(snakemake_report["results"])
    expected: set[str] = set()
    for item in items:
        files, what = expected_files(item, results, nights), f"{item['rule']}.{item['name']}"
        assert files, f"{what}: nothing on disk for {item['template']} {item['patterns']}"
        assert files <= shown, f"{what}: not in the report: {sorted(files - shown)[:5]}"
        assert {snakemake_report["results"][f]["job_properties"]["rule"] for f in files} == {item["rule"]}
        expected |= files
    assert shown == expected  # nothing else
    # 3 nights x their examined scans x 2 files, the pooled devices, 8 paper items, report.html,
    # the month plots and pages and papers.html: the number Snakemake logs while adding them
    assert len(re.findall(r"^Adding .+\(", snakemake_report["log"], re.M)) == len(shown)
    # every file is in the zip, byte for byte, where the page links it
    for path, entry in snakemake_report["results"].items():
        member = f"report/{entry['data_uri']}"
        assert member in snakemake_report["members"], member
        got = hashlib.sha256((snakemake_report["dir"] / entry["data_uri"]).read_bytes()).hexdigest()
        assert got == hashlib.sha256(Path(path).read_bytes()).hexdigest(), path


def test_discrepancy_findings_of_every_scan_per_night(pipeline_run, snakemake_report):
    res = pipeline_run["results"]
    con = duckdb.connect(str(res / "catalog.duckdb"), read_only=True)
    rows = con.execute("SELECT DISTINCT night, scan_id FROM findings").fetchall()
    examined = {(str(n), s) for n, s in rows}
    pooled = {
        (str(n), p)
        for n, p in con.execute(
            "SELECT DISTINCT night, findings_path FROM pooled_findings WHERE findings_path IS NOT NULL"
        ).fetchall()
    }
    con.close()
    assert len(examined) >= 18 and len(pooled) >= 2  # demo nights: 9 or more scans each, TRI-01 pooled
    cats = snakemake_report["categories"]["Discrepancy"]
    assert set(cats) == {n for n, _ in examined}  # one subcategory per night
    results = snakemake_report["results"]
    for night, sid in examined:
        for name in ("gap.png", "findings.json"):
            path = str(res / "discrepancy" / f"night={night}" / sid / name)
            assert path in cats[night], path
            assert results[path]["labels"] == {"scan or device": sid, "file": name}
            assert f"scan {sid} (night {night})" in results[path]["caption"]
        # the path the report page, README and people use is a link into the night's folder
        link = res / "discrepancy" / sid
        assert link.is_symlink() and os.readlink(link) == f"night={night}/{sid}"
        assert (link / "findings.json").is_file()
    for night, rel in pooled:
        path = str(res / rel)
        assert path in cats[night] and results[path]["mime_type"] == "application/json"
        device = Path(rel).stem
        assert results[path]["labels"] == {"scan or device": f"{device} (pooled)", "file": f"{device}.json"}
        assert f"Pooled findings of device {device} on night {night}" in results[path]["caption"]
    assert sum(len(v) for v in cats.values()) == 2 * len(examined) + len(pooled)


def test_categories_and_captions(pipeline_run, snakemake_report):
    items = declared_report_items()
    literal = {i["category"] for i in items if i["category"] in CATEGORIES}
    # the others come from report_page_category; Calibration both ways (certificates, month plots)
    assert literal == {"Papers", "Discrepancy", "Diameters", "Calibration"}
    cats = snakemake_report["categories"]
    assert set(cats) == CATEGORIES
    res = pipeline_run["results"]
    results = snakemake_report["results"]
    # the month plots: under the category of what they show, one subcategory per month
    plots = sorted(res.glob("report/*/*.png"))
    assert len(plots) >= 6  # demo: calibration of TRI-01, 2 control charts, 3 parts' diameters
    for p in plots:
        kind, subject = p.stem.split("_", 1)
        month = p.parent.name
        assert str(p) in cats[MONTH_PLOT_CATEGORY[kind]][month], p
        cap = results[str(p)]["caption"]
        assert subject in cap and f"month {month}" in cap, cap
    plot_months = {p.parent.name for p in plots}
    for cat, prefix in (("Calibration", ("calibration_", "devicemodel_")), ("Verification", ("control_",))):
        assert sum(len(v) for m, v in cats[cat].items() if m in plot_months) == len(
            [p for p in plots if p.stem.startswith(prefix)]
        )
    assert any(p.stem == "devicemodel_TRI-01" for p in plots)  # the device model's nights (demo loop)
    # the certificates: every file of every calibration of a night, under Calibration / the night,
    # read where outputs.md puts them (a link into the night's folder)
    certs = sorted(res.glob("calibration/night=*/*/*/certificate.pdf"))
    # demo: TRI-01 and ROD-01 calibrated on the first night (the second refused), TRI-01 on both loop nights
    assert len(certs) == 4
    for pdf in certs:
        night = pdf.parts[-4].removeprefix("night=")
        device, cal_id = pdf.parts[-3], pdf.parts[-2]
        assert (
            str(pdf) in cats["Calibration"][night]
            and str(pdf.with_suffix(".json")) in cats["Calibration"][night]
        )
        assert cal_id in results[str(pdf)]["caption"] and "What to do" in results[str(pdf)]["caption"]
        assert (res / "calibration" / device / cal_id / "certificate.pdf").read_bytes() == pdf.read_bytes()
    months = sorted(p.parent.name for p in res.glob("report/*/index.html"))
    assert months == ["2026-11"]
    assert sorted(cats["Diameters"]["Report pages"]) == sorted(
        [str(res / "report.html")] + [str(res / "report" / m / "index.html") for m in months]
    )
    assert cats["Papers"]["All papers (page)"] == [str(res / "report" / "papers.html")]
    assert {s: len(v) for s, v in cats["Papers"].items() if s != "All papers (page)"} == {
        "Yang 2017 Table 1": 2,
        "Yang 2017 Table 2": 2,
        "Yang 2017 Table 3": 2,
        "Wang 2017": 2,
    }
    # every caption rendered: reStructuredText to HTML, its jinja filled in, no docutils complaint
    for path, entry in results.items():
        cap = entry["caption"]
        assert cap.startswith("<p>") and len(cap) > 150, (path, cap)
        assert "{{" not in cap and "{%" not in cap and "system-message" not in cap, (path, cap)
    assert "What to do" in results[str(res / "report.html")]["caption"]
    # the landing page says where to start and links report.html and the categories
    desc = snakemake_report["description"]
    assert f"app.showResultInfo('{res / 'report.html'}')" in desc
    for c in CATEGORIES:
        assert f"app.showCategory('{c}')" in desc
    assert "system-message" not in desc
