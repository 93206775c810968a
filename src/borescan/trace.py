"""Traceability: the chain behind a diameter, scan, part, calibration or certificate.

``trace(results_root, ident)`` looks ``ident`` up in the history catalog and returns the chain

    diameter(s) of the scan -> calibration used -> its certificate (and certificate.json's
    SHA-256, recomputed and compared with the catalog) -> the calibration scan(s) -> the ring
    gauge artifact and its certificate id -> the raw files and their SHA-256

as nested dictionaries; ``format_trace`` renders it as indented text (``borescan trace ID``).
``ident`` may be a diameter id (``<scan_id>/<feature>``), a scan id (measurement, verification
or calibration scan), a part (artifact) id, a calibration id, a certificate path (the PDF, the
JSON or their folder, relative to the results folder or absolute) or an artifact certificate id.
An id found nowhere raises :class:`UnknownId`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import duckdb

from borescan import catalog, rawio

__all__ = ["UnknownId", "trace", "format_trace"]


class UnknownId(LookupError):
    """The id is not a diameter, scan, part, calibration or certificate of the catalog."""


def _rows(con: duckdb.DuckDBPyConnection, sql: str, params: list | tuple = ()) -> list[dict[str, Any]]:
    cur = con.execute(sql, list(params))
    cols = [d[0] for d in cur.description]
    return [dict(zip(cols, r, strict=True)) for r in cur.fetchall()]


class _Tracer:
    def __init__(self, con: duckdb.DuckDBPyConnection, results_root: Path):
        self.con = con
        self.root = results_root

    # ---------------------------------------------------------------- leaves
    def scan(self, scan_id: str) -> dict[str, Any]:
        rows = _rows(self.con, "SELECT * FROM scans WHERE scan_id = ?", [scan_id])
        node: dict[str, Any] = {"scan_id": scan_id}
        if not rows:
            node["missing"] = True
            return node
        s = rows[0]
        node.update(
            {
                k: s.get(k)
                for k in (
                    "night",
                    "kind",
                    "device_id",
                    "device_type",
                    "artifact_id",
                    "started_at",
                    "status",
                    "reason",
                    "raw_path",
                    "raw_sha256",
                    "artifact_certificate",
                    "artifact_certified_diameter_mm",
                    "artifact_u_diameter_mm",
                )
            }
        )
        node["files"] = _rows(
            self.con, "SELECT file, sha256, bytes FROM scan_files WHERE scan_id = ? ORDER BY file", [scan_id]
        )
        return node

    def artifact(self, artifact_id: str | None) -> dict[str, Any] | None:
        if artifact_id is None:
            return None
        rows = _rows(self.con, "SELECT * FROM artifacts WHERE artifact_id = ?", [artifact_id])
        return rows[0] if rows else {"artifact_id": artifact_id, "missing": True}

    def scan_artifact(self, sn: dict[str, Any]) -> dict[str, Any] | None:
        """Return the artifact as the scan used it.

        Return the artifact as the scan used it: its own certificate id and certified value (kept in
        ``scans`` per scan, so a later scan naming the artifact cannot rewrite them); ``latest``
        holds the artifacts table's record when that differs (a recertified gauge).
        """
        art = self.artifact(sn.get("artifact_id"))
        keys = ("certificate", "certified_diameter_mm", "u_diameter_mm")
        own = {k: sn.get(f"artifact_{k}") for k in keys}
        if art is None or all(v is None for v in own.values()):
            return art  # a catalog written before scans kept the certificate
        out = dict(art, **own, as_used=True)
        latest = {k: art.get(k) for k in keys}
        if not art.get("missing") and latest != own:
            out["latest"] = latest
        return out

    def certificate(self, cal: dict[str, Any]) -> dict[str, Any] | None:
        path = cal.get("certificate_path")
        if not path:
            return None
        cj = catalog.certificate_json_path(self.root, path)
        node: dict[str, Any] = {
            "path": path,
            "json_path": os.path.relpath(cj, self.root),
            "catalog_sha256": cal.get("certificate_sha256"),
        }
        node["json_sha256"] = rawio.sha256_file(cj) if cj.is_file() else None
        node["issues"] = self.issues(cal["calibration_id"])
        return node

    def issues(self, calibration_id: str) -> list[dict[str, Any]]:
        """Return every issue of the calibration's certificate.

        See :mod:`borescan.certificate_issue`: document id, issue number and date, the document it replaces,
        its folder and certificate.json's SHA-256 as recorded and as on disk.
        """
        from borescan.certificate_issue import issues_of

        out = []
        for i in issues_of(self.root, calibration_id):
            cj = self.root / i.folder / "certificate.json"
            out.append(
                {
                    "document_id": i.document_id,
                    "issue": i.issue,
                    "issue_date": i.issue_date,
                    "replaces": i.replaces,
                    "folder": i.folder,
                    "recorded_sha256": i.files_sha256.get("certificate.json"),
                    "json_sha256": rawio.sha256_file(cj) if cj.is_file() else None,
                }
            )
        return out

    def calibration(self, calibration_id: str) -> dict[str, Any]:
        rows = _rows(
            self.con, "SELECT * FROM calibrations WHERE calibration_id = ? ORDER BY channel", [calibration_id]
        )
        if not rows:
            return {"calibration_id": calibration_id, "missing": True}
        first = rows[0]
        node: dict[str, Any] = {
            k: first.get(k) for k in ("calibration_id", "device_id", "method", "valid_from", "status")
        }
        # the lifecycle as of the newest night (saved query calibration_lifecycle), when the catalog has it
        try:
            life = _rows(
                self.con,
                "SELECT status, valid_until, status_night, reason FROM calibration_lifecycle "
                "WHERE calibration_id = ?",
                [calibration_id],
            )
        except duckdb.Error:
            life = []
        if life:
            node.update(
                status=life[0]["status"],
                valid_until=life[0]["valid_until"],
                status_reason=life[0]["reason"] if life[0]["status"] != "valid" else None,
            )
        node["channels"] = [r["channel"] for r in rows]
        node["certificate"] = self.certificate(first)
        scan_ids = [
            r["scan_id"]
            for r in _rows(
                self.con,
                "SELECT scan_id FROM calibration_scans WHERE calibration_id = ? ORDER BY scan_id",
                [calibration_id],
            )
        ]
        if not scan_ids:
            scan_ids = sorted({r["scan_id"] for r in rows if r["scan_id"]})
        scans = []
        for sid in scan_ids:
            sn = self.scan(sid)
            sn["artifact"] = self.scan_artifact(sn)
            scans.append(sn)
        node["scans"] = scans
        node["gauges"] = _layer_gauges(first)
        node["verifications"] = _rows(
            self.con,
            "SELECT v.scan_id, v.night, v.error_mm, v.tolerance_mm, "
            "v.passed, v.feature, v.artifact_id, v.conformity "
            "FROM verifications v "
            "LEFT JOIN scans s USING (scan_id) WHERE v.calibration_id "
            "= ? ORDER BY v.night, s.started_at, v.scan_id, v.feature",
            [calibration_id],
        )
        return node

    def diameter(self, d: dict[str, Any]) -> dict[str, Any]:
        node = {
            k: d.get(k)
            for k in (
                "diameter_id",
                "feature",
                "diameter_mm",
                "u_diameter_mm",
                "method",
                "calibration_id",
                "temperature_c",
                "diameter_20_mm",
                "expanded_u_diameter_20_mm",
                "k",
                "nominal_diameter_mm",
                "tolerance_mm",
                "conformity",
            )
        }
        node["scan"] = self.scan(d["scan_id"])
        node["calibration"] = self.calibration(d["calibration_id"]) if d.get("calibration_id") else None
        return node

    # ---------------------------------------------------------------- resolution
    def resolve(self, ident: str) -> dict[str, Any]:
        con = self.con
        dia = _rows(con, "SELECT * FROM diameters WHERE diameter_id = ? ORDER BY method", [ident])
        if dia:
            return {"kind": "diameter", "id": ident, "diameters": [self.diameter(d) for d in dia]}
        if _rows(con, "SELECT 1 FROM scans WHERE scan_id = ?", [ident]):
            return self.scan_chain(ident)
        if _rows(con, "SELECT 1 FROM calibrations WHERE calibration_id = ?", [ident]):
            return {"kind": "calibration", "id": ident, "calibration": self.calibration(ident)}
        cert = self.certificate_match(ident) or self.document_match(ident)
        if cert:
            return {"kind": "certificate", "id": ident, "calibrations": [self.calibration(c) for c in cert]}
        dia = _rows(
            con,
            "SELECT d.* FROM diameters d LEFT JOIN scans s USING (scan_id) WHERE d.artifact_id = ? "
            "ORDER BY d.night, s.started_at, d.scan_id, d.feature, d.method",
            [ident],
        )
        if dia:
            return {"kind": "part", "id": ident, "diameters": [self.diameter(d) for d in dia]}
        arts = _rows(
            con,
            "SELECT artifact_id FROM artifacts WHERE certificate = ? OR artifact_id = ? ORDER BY artifact_id",
            [ident, ident],
        )
        if arts:
            ids = [a["artifact_id"] for a in arts]
            cals = _rows(
                con,
                "SELECT DISTINCT cs.calibration_id FROM calibration_scans cs JOIN scans s USING (scan_id) "
                f"WHERE s.artifact_id IN ({', '.join('?' * len(ids))}) ORDER BY 1",
                ids,
            )
            return {
                "kind": "artifact",
                "id": ident,
                "artifacts": [self.artifact(i) for i in ids],
                "calibrations": [self.calibration(c["calibration_id"]) for c in cals],
            }
        raise UnknownId(
            f"unknown id {ident!r}: not a diameter, scan, part, calibration or certificate in "
            f"{catalog.catalog_path(self.root)}"
        )

    def scan_chain(self, scan_id: str) -> dict[str, Any]:
        dia = _rows(self.con, "SELECT * FROM diameters WHERE scan_id = ? ORDER BY feature, method", [scan_id])
        out: dict[str, Any] = {"kind": "scan", "id": scan_id, "scan": self.scan(scan_id)}
        out["diameters"] = [self.diameter(d) for d in dia]
        ver = _rows(self.con, "SELECT * FROM verifications WHERE scan_id = ?", [scan_id])
        out["verification"] = ver[0] if ver else None
        cal_ids = [
            r["calibration_id"]
            for r in _rows(
                self.con,
                "SELECT DISTINCT calibration_id FROM calibration_scans WHERE scan_id = ? ORDER BY 1",
                [scan_id],
            )
        ]
        if ver and ver[0].get("calibration_id") and ver[0]["calibration_id"] not in cal_ids:
            out["verification_calibration"] = self.calibration(ver[0]["calibration_id"])
        out["calibrations"] = [self.calibration(c) for c in cal_ids]
        return out

    def document_match(self, ident: str) -> list[str]:
        """Return the calibration of a certificate number (a reissue's ``<calibration_id>-R<n>``)."""
        from borescan.certificate_issue import issues_of

        return sorted({i.calibration_id for i in issues_of(self.root, ident) if i.document_id == ident})

    def certificate_match(self, ident: str) -> list[str]:
        p = Path(ident)
        candidates = {p}
        if p.is_absolute():
            try:
                candidates.add(p.resolve().relative_to(self.root.resolve()))
            except ValueError:
                pass
        folders = {c if c.suffix == "" else c.parent for c in candidates}
        out = []
        for r in _rows(
            self.con,
            "SELECT DISTINCT calibration_id, certificate_path FROM calibrations "
            "WHERE certificate_path IS NOT NULL ORDER BY 1",
        ):
            cp = Path(r["certificate_path"])
            if cp in candidates or (cp if cp.suffix == "" else cp.parent) in folders:
                out.append(r["calibration_id"])
        return sorted(set(out))


def trace(results_root: str | os.PathLike, ident: str) -> dict[str, Any]:
    """Return the chain behind ``ident`` as nested dictionaries (see the module docstring).

    Raises :class:`UnknownId` when the id is nowhere in the catalog and ``FileNotFoundError``
    when the catalog has not been built.
    """
    root = Path(results_root)
    con = catalog.open_catalog(root, read_only=True)
    try:
        return _Tracer(con, root).resolve(ident.strip())
    finally:
        con.close()


# --------------------------------------------------------------------------- text


def _fmt(v: Any, unit: str = "") -> str:
    if v is None:
        return "?"
    if isinstance(v, float):
        return f"{v:.10g}{unit}"
    return f"{v}{unit}"


def _scan_lines(s: dict[str, Any], ind: str, label: str = "scan") -> list[str]:
    if s.get("missing"):
        return [f"{ind}{label} {s['scan_id']}  (NOT IN CATALOG)"]
    head = (
        f"{ind}{label} {s['scan_id']}  night {_fmt(s.get('night'))}, {_fmt(s.get('kind'))}, "
        f"device {_fmt(s.get('device_id'))}, artifact {_fmt(s.get('artifact_id'))}, status {s.get('status')}"
    )
    lines = [head]
    if s.get("reason"):
        lines.append(f"{ind}  reason: {s['reason']}")
    art = s.get("artifact")
    if art:
        if art.get("missing"):
            lines.append(f"{ind}  artifact {art['artifact_id']}  (no artifacts row)")
        else:
            lines.append(
                f"{ind}  artifact {art['artifact_id']} ({_fmt(art.get('type'))}), certificate "
                f"{_fmt(art.get('certificate'))}, "
                f"certified {_fmt(art.get('certified_diameter_mm'), ' mm')} "
                f"(u {_fmt(art.get('u_diameter_mm'), ' mm')}, k={_fmt(art.get('k'))})"
                + (" as this scan used it" if art.get("as_used") else "")
            )
            if art.get("latest"):
                lt = art["latest"]
                lines.append(
                    f"{ind}  NOTE: the artifact's latest record differs: certificate "
                    f"{_fmt(lt.get('certificate'))}, "
                    f"certified {_fmt(lt.get('certified_diameter_mm'), ' mm')}"
                )
    lines.append(f"{ind}  raw {_fmt(s.get('raw_path'))}")
    lines.append(f"{ind}  raw_sha256 {_fmt(s.get('raw_sha256'))}")
    for f in s.get("files", []):
        lines.append(f"{ind}    {f['file']:<16s} sha256 {f['sha256']}  ({_fmt(f.get('bytes'))} bytes)")
    return lines


def _cert_lines(c: dict[str, Any] | None, ind: str) -> list[str]:
    if not c:
        return [f"{ind}certificate: none recorded"]
    lines = [f"{ind}certificate {c['path']}"]
    if c["json_sha256"] is None:
        lines.append(f"{ind}  {c['json_path']}: MISSING on disk (catalog sha256 {_fmt(c['catalog_sha256'])})")
    else:
        status = (
            "matches catalog"
            if c["catalog_sha256"] == c["json_sha256"]
            else "not in catalog"
            if c["catalog_sha256"] is None
            else f"DIFFERS from catalog {c['catalog_sha256']}"
        )
        lines.append(f"{ind}  {c['json_path']} sha256 {c['json_sha256']} ({status})")
    for i in c.get("issues") or []:
        state = (
            "MISSING on disk"
            if i["json_sha256"] is None
            else "matches its record"
            if i["json_sha256"] == i["recorded_sha256"]
            else f"DIFFERS from its record {i['recorded_sha256']}"
        )
        replaces = f", replaces {i['replaces']}" if i["replaces"] else ""
        lines.append(
            f"{ind}  issue {i['issue']}: {i['document_id']} of {_fmt(i['issue_date'])}{replaces}; "
            f"{i['folder']}/certificate.json {state}"
        )
    return lines


def _cal_lines(c: dict[str, Any] | None, ind: str) -> list[str]:
    if c is None:
        return [f"{ind}calibration: none recorded"]
    if c.get("missing"):
        return [f"{ind}calibration {c['calibration_id']}  (NOT IN CATALOG)"]
    lines = [
        f"{ind}calibration {c['calibration_id']}  device {_fmt(c['device_id'])}, method {_fmt(c['method'])}, "
        f"valid from {_fmt(c['valid_from'])}"
        + (f" until {_fmt(c['valid_until'])}" if c.get("valid_until") else "")
        + f", status {_fmt(c['status'])}"
        + (f" ({c['status_reason']})" if c.get("status_reason") else "")
        + f", channels {c['channels']}"
    ]
    lines += _cert_lines(c["certificate"], ind + "  ")
    for s in c["scans"]:
        lines += _scan_lines(s, ind + "  ", "calibration scan")
    for g in c.get("gauges") or []:
        lines.append(
            f"{ind}  layer {g.get('channel')} ({_fmt(g.get('feature'))}): ring gauge "
            f"{_fmt(g.get('id'))}, certificate "
            f"{_fmt(g.get('certificate'))}, certified {_fmt(g.get('certified_diameter_mm'), ' mm')} "
            f"(U {_fmt(g.get('u_diameter_mm'), ' mm')}, k={_fmt(g.get('k'))})"
        )
    for v in c["verifications"]:
        verdict = _verdict(v)
        layer = f" layer {v['feature']} ({_fmt(v.get('artifact_id'))})" if v.get("feature") else ""
        lines.append(
            f"{ind}  verified by {v['scan_id']}{layer} on {_fmt(v['night'])}: error "
            f"{_fmt(v['error_mm'], ' mm')} "
            f"(tolerance {_fmt(v['tolerance_mm'], ' mm')}) {verdict}"
        )
    return lines


def _layer_gauges(row: dict[str, Any]) -> list[dict[str, Any]]:
    """Return the certified gauge each layer of a rod calibration was calibrated in.

    Return the certified gauge each layer of a rod calibration was calibrated in (its calibration_json); []
    for other calibrations.
    """
    if row.get("method") != "rod_gauge" or not row.get("calibration_json"):
        return []
    try:
        return list(json.loads(row["calibration_json"]).get("gauges") or [])
    except (ValueError, TypeError):
        return []


def _verdict(v: dict[str, Any]) -> str:
    """Return a verification's verdict under the decision rule (its statement), else its pass/fail."""
    if v.get("conformity"):
        return v["conformity"]
    return "passed" if v.get("passed") else "FAILED"


def _dia_lines(d: dict[str, Any], ind: str) -> list[str]:
    if d.get("diameter_20_mm") is not None:  # the certified value: at 20 degC with U (ISO 1)
        value = (
            f"D20 {_fmt(d['diameter_20_mm'], ' mm')} (U {_fmt(d.get('expanded_u_diameter_20_mm'), ' mm')}, "
            f"k={_fmt(d.get('k'))}); at {_fmt(d.get('temperature_c'))} degC {_fmt(d['diameter_mm'], ' mm')}"
        )
    else:
        value = f"{_fmt(d['diameter_mm'], ' mm')} (u {_fmt(d['u_diameter_mm'], ' mm')}, k=1)"
    # a ring gauge (scan.json lists no feature) is one bore
    feature = "the bore" if d.get("feature") is None else f"feature {d['feature']}"
    lines = [f"{ind}diameter {d['diameter_id']}  {value}, {feature}, method {_fmt(d['method'])}"]
    if d.get("conformity"):
        lines.append(
            f"{ind}  against nominal {_fmt(d.get('nominal_diameter_mm'), ' mm')} +- "
            f"{_fmt(d.get('tolerance_mm'), ' mm')}: {d['conformity']}"
        )
    lines += _scan_lines(d["scan"], ind + "  ")
    lines += _cal_lines(d["calibration"], ind + "  ")
    return lines


def format_trace(  # noqa: C901 (one branch per kind of fact of the trace)
    chain: dict[str, Any],
) -> str:
    """Indented text of a :func:`trace` result, one fact per line."""
    kind = chain["kind"]
    lines = [f"trace {chain['id']} ({kind})"]
    if kind in ("diameter", "part"):
        for d in chain["diameters"]:
            lines += _dia_lines(d, "  ")
    elif kind == "scan":
        lines += _scan_lines(chain["scan"], "  ")
        for d in chain["diameters"]:
            lines += _dia_lines(d, "  ")
        v = chain.get("verification")
        if v:
            verdict = _verdict(v)
            lines.append(
                f"  verification: measured {_fmt(v['measured_mm'], ' mm')}, certified "
                f"{_fmt(v['certified_mm'], ' mm')}, error {_fmt(v['error_mm'], ' mm')} {verdict}, "
                f"calibration {_fmt(v.get('calibration_id'))}"
            )
        if chain.get("verification_calibration"):
            lines += _cal_lines(chain["verification_calibration"], "  ")
        for c in chain["calibrations"]:
            lines += _cal_lines(c, "  ")
    elif kind == "calibration":
        lines += _cal_lines(chain["calibration"], "  ")
    elif kind == "certificate":
        for c in chain["calibrations"]:
            lines += _cal_lines(c, "  ")
    elif kind == "artifact":
        for a in chain["artifacts"]:
            lines.append(
                f"  artifact {a['artifact_id']} ({_fmt(a.get('type'))}), certificate "
                f"{_fmt(a.get('certificate'))}"
            )
        for c in chain["calibrations"]:
            lines += _cal_lines(c, "  ")
    return "\n".join(lines) + "\n"
