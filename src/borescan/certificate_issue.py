"""Issues of a certificate: the record written with each one, and reissue from the history.

Every certificate the calibrate stage writes is recorded as one row of the stage table
``stage/certificate_issues/night=<night>.parquet`` (:func:`issue_row`): its document id, the
calibration, the issue number (0 the original), date of issue, the laboratory section's SHA-256,
the SHA-256 of each file written, the content of ``certificate.json`` and, for a three-sensor
certificate, the residual arrays its plot shows. A reissue (:func:`reissue`,
``borescan certificate ID``) renders the documents again from that record:

- with the same ``laboratory`` section: the latest issue again, byte-identical (the digests
  recorded at write time, and ``calibrations.certificate_sha256`` of the catalog, say whether
  they agree);
- with a changed one: a new document (ISO/IEC 17025:2017 7.8.8.2) with its own id
  ``<calibration_id>-R<n>``, the date of reissue, the new laboratory data and a reference to the
  certificate it replaces (its id and the SHA-256 of its ``certificate.json``); the results are the
  original's. Its record goes to ``stage/certificate_issues/reissues/<document_id>.parquet`` and its files
  to ``certificates/<calibration_id>/<document_id>/``. A changed decision rule changes verdicts: it
  is refused (recalibrate instead).
"""

from __future__ import annotations

import copy
import datetime as _dt
import hashlib
import json
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import polars as pl

from borescan import certificate
from borescan.certificate.admin import _administrative_data
from borescan.rawio import sha256_file

__all__ = [
    "FORMATS",
    "ISSUE_TABLE",
    "REISSUE_DIR",
    "CertificateIssue",
    "Reissued",
    "issue_frame",
    "issue_row",
    "issues_of",
    "laboratory_sha256",
    "read_issues",
    "reissue",
]

ISSUE_TABLE = "stage/certificate_issues"
REISSUE_DIR = "certificates"
#: --format -> files written
FORMATS = {
    "json": ("certificate.json",),
    "pdf": ("certificate.pdf", "residuals.png"),
    "dcc": ("certificate.dcc.xml",),
    "all": ("certificate.json", "certificate.dcc.xml", "certificate.pdf", "residuals.png"),
}
_SCHEMA = {
    "document_id": pl.Utf8,
    "calibration_id": pl.Utf8,
    "device_id": pl.Utf8,
    "night": pl.Utf8,
    "issue": pl.Int64,
    "issue_date": pl.Utf8,
    "replaces": pl.Utf8,
    "replaces_sha256": pl.Utf8,
    "laboratory_sha256": pl.Utf8,
    "folder": pl.Utf8,
    "files_sha256": pl.Utf8,
    "content_json": pl.Utf8,
    "residual_t_s": pl.List(pl.Float64),
    "residual_mm": pl.List(pl.Float64),
    "residual_channels": pl.Int64,
}
#: laboratory keys whose change changes a verdict, not only the letterhead
_VERDICT_KEYS = ("decision_rule", "guard_band_factor")


@dataclass(frozen=True)
class CertificateIssue:
    """One issued certificate document (the original or a reissue) as the history records it."""

    document_id: str
    calibration_id: str
    device_id: str
    night: str
    issue: int
    issue_date: str
    replaces: str | None
    replaces_sha256: str | None
    laboratory_sha256: str
    folder: str  # relative to results_root
    files_sha256: dict[str, str]
    content: dict
    residuals: dict | None  # t_s (n,) [s], residual_mm (n, c) [mm]; None for a rod


@dataclass(frozen=True)
class Reissued:
    """What :func:`reissue` did: the issue written, where, and each file's digest against the record."""

    issue: CertificateIssue
    out_dir: Path
    new_document: bool
    files: dict[str, str]  # file -> sha256 of what was written
    agree: dict[str, bool | None]  # file -> equals the recorded digest (None: nothing recorded)
    catalog_agree: bool | None  # certificate.json against calibrations.certificate_sha256


def laboratory_sha256(lab: dict) -> str:
    """SHA-256 of a ``laboratory`` config section (sorted JSON)."""
    return hashlib.sha256(json.dumps(lab, sort_keys=True).encode()).hexdigest()


def issue_row(
    cert_paths: dict[str, Path],
    results_root: Path | str,
    night: str,
    residuals: dict | None = None,
) -> dict:
    """Return the ``stage/certificate_issues`` row of a certificate just written.

    ``cert_paths``: the paths :func:`borescan.certificate.write_certificate_files` returned; ``residuals`` the
    plot's arrays.
    """
    cert = json.loads(Path(cert_paths["json"]).read_text())
    out_dir = Path(cert_paths["json"]).parent
    folder = Path("calibration") / cert["device_id"] / cert["calibration_id"]
    row = {
        "document_id": cert["administrativeData"]["coreData"]["uniqueIdentifier"],
        "calibration_id": cert["calibration_id"],
        "device_id": cert["device_id"],
        "night": night,
        "issue": int((cert.get("reissue") or {}).get("issue", 0)),
        "issue_date": cert["dates"].get("issue"),
        "replaces": None,
        "replaces_sha256": None,
        "laboratory_sha256": laboratory_sha256(cert["laboratory"]),
        "folder": str(folder),
        "files_sha256": json.dumps(
            {p.name: sha256_file(p) for p in sorted(out_dir.iterdir()) if p.is_file()}, sort_keys=True
        ),
        "content_json": Path(cert_paths["json"]).read_text(),
        "residual_t_s": None,
        "residual_mm": None,
        "residual_channels": None,
    }
    if residuals is not None and "png" in cert_paths:
        res = np.asarray(residuals["residual_mm"], dtype=float)
        res = res[:, None] if res.ndim == 1 else res
        row.update(
            residual_t_s=np.asarray(residuals["t_s"], dtype=float).tolist(),
            residual_mm=res.ravel().tolist(),
            residual_channels=int(res.shape[1]),
        )
    return row


def issue_frame(rows: list[dict]) -> pl.DataFrame:
    """Return the rows as a ``stage/certificate_issues`` table (empty with its schema when there are none)."""
    return pl.DataFrame(rows, schema=_SCHEMA, orient="row") if rows else pl.DataFrame(schema=_SCHEMA)


def _issue(r: dict) -> CertificateIssue:
    res = None
    if r.get("residual_channels"):
        t = np.asarray(r["residual_t_s"], dtype=float)
        res = {
            "t_s": t,
            "residual_mm": np.asarray(r["residual_mm"], dtype=float).reshape(t.size, r["residual_channels"]),
        }
    return CertificateIssue(
        document_id=r["document_id"],
        calibration_id=r["calibration_id"],
        device_id=r["device_id"],
        night=r["night"],
        issue=int(r["issue"]),
        issue_date=r["issue_date"],
        replaces=r["replaces"],
        replaces_sha256=r["replaces_sha256"],
        laboratory_sha256=r["laboratory_sha256"],
        folder=r["folder"],
        files_sha256=json.loads(r["files_sha256"]),
        content=json.loads(r["content_json"]),
        residuals=res,
    )


def read_issues(results_root: Path | str) -> list[CertificateIssue]:
    """Return every recorded issue, ordered by (calibration id, issue).

    A reissue takes its residuals from the original's record.
    """
    base = Path(results_root) / ISSUE_TABLE
    files = sorted(base.glob("night=*.parquet")) + sorted((base / "reissues").glob("*.parquet"))
    rows = [r for f in files for r in pl.read_parquet(f).to_dicts()]
    issues = sorted((_issue(r) for r in rows), key=lambda i: (i.calibration_id, i.issue))
    originals = {i.calibration_id: i for i in issues if i.issue == 0}
    return [
        i
        if i.residuals is not None or i.calibration_id not in originals
        else CertificateIssue(**{**i.__dict__, "residuals": originals[i.calibration_id].residuals})
        for i in issues
    ]


def issues_of(results_root: Path | str, ident: str) -> list[CertificateIssue]:
    """Return the issues of the calibration or document ``ident`` (every issue of its calibration)."""
    issues = read_issues(results_root)
    cal_ids = {i.calibration_id for i in issues if ident in (i.calibration_id, i.document_id)}
    return [i for i in issues if i.calibration_id in cal_ids]


def _catalog_sha256(results_root: Path, calibration_id: str) -> str | None:
    """``calibrations.certificate_sha256`` of the catalog (None without a catalog or a value)."""
    from borescan import catalog

    try:
        con = catalog.open_catalog(results_root, read_only=True)
    except FileNotFoundError:
        return None
    try:
        got = con.execute(
            "SELECT certificate_sha256 FROM calibrations WHERE calibration_id = ? AND "
            "certificate_sha256 IS NOT NULL LIMIT 1",
            [calibration_id],
        ).fetchall()
    finally:
        con.close()
    return got[0][0] if got else None


def _relabelled(latest: CertificateIssue, lab: dict, issue_date: str) -> dict:
    """Return the content of a new issue of ``latest`` under the laboratory section ``lab``.

    New document id, date of issue and laboratory data, the reference to the document replaced; results
    unchanged.
    """
    old = latest.content
    changed = sorted(k for k in set(lab) | set(old["laboratory"]) if lab.get(k) != old["laboratory"].get(k))
    verdict = [k for k in changed if k in _VERDICT_KEYS]
    if verdict:
        raise ValueError(
            f"certificate {latest.document_id}: laboratory.{', '.join(verdict)} changed; that changes the "
            "verifications' verdicts, which a reissue cannot restate: recalibrate (rerun the night) instead"
        )
    n = latest.issue + 1
    doc_id = f"{latest.calibration_id}-R{n}"
    dates = dict(
        old["dates"],
        issue=issue_date,
        issue_rule=f"date of this reissue ({issue_date}); the calibration, its data and results are those of "
        f"the certificate it replaces",
    )
    adm = old["administrativeData"]
    trace = next(
        (s["declaration"] for s in adm["statements"] if s.get("refType") == "basic_traceability"), ""
    )
    new = copy.deepcopy(old)
    new["administrativeData"] = _administrative_data(
        SimpleNamespace(calibration_id=doc_id),
        lab,
        dates,
        old["conformity"],
        adm["items"][0],
        trace,
        adm["dccSoftware"]["software"][0]["release"],
    )
    new.update(laboratory=lab, dates=dates)
    sha = latest.files_sha256.get("certificate.json")
    new["reissue"] = {
        "issue": n,
        "document_id": doc_id,
        "changed": changed,
        "replaces": {"document_id": latest.document_id, "sha256": sha, "issue_date": latest.issue_date},
        "declaration": f"This certificate {doc_id} replaces certificate {latest.document_id} issued "
        f"{latest.issue_date} (certificate.json SHA-256 {sha}), which is withdrawn. "
        f"Reason: the laboratory's data changed ({', '.join(changed)}); the "
        "calibration and its results are unchanged.",
    }
    return json.loads(json.dumps(new, sort_keys=True))


def reissue(
    results_root: Path | str,
    ident: str,
    laboratory: dict,
    *,
    fmt: str = "all",
    out_dir: Path | str | None = None,
    issue_date: str | None = None,
) -> Reissued:
    """Reissue the certificate of calibration (or document) ``ident`` from the history.

    The laboratory data come from the config's ``laboratory`` section (see the module docstring). ``fmt``: a
    key of :data:`FORMATS`; ``out_dir``: where to write (default: the issue's own folder: an original's night
    folder, whose link ``calibration/<device>/<id>`` the caller restores); ``issue_date``: of a new document
    (default: today, UTC). Raises ValueError naming the certificate when it cannot.
    """
    root = Path(results_root)
    issues = issues_of(root, ident)
    if not issues:
        raise ValueError(
            f"certificate {ident!r}: no issue recorded in {root / ISSUE_TABLE} (a calibration id or "
            "certificate number; run the pipeline first)"
        )
    if fmt not in FORMATS:
        raise ValueError(f"format {fmt!r}: valid {sorted(FORMATS)}")
    latest = issues[-1]
    new_doc = laboratory_sha256(laboratory) != latest.laboratory_sha256
    if new_doc:
        content = _relabelled(latest, laboratory, issue_date or _dt.datetime.now(_dt.UTC).date().isoformat())
        doc_id = content["reissue"]["document_id"]
        folder = Path(REISSUE_DIR) / latest.calibration_id / doc_id
    else:
        content, doc_id, folder = latest.content, latest.document_id, Path(latest.folder)
    target = Path(out_dir) if out_dir is not None else _default_dir(root, latest, folder, new_doc)
    with tempfile.TemporaryDirectory(prefix=".reissue-", dir=root) as tmp:
        paths = certificate.write_certificate_files(content, tmp, latest.residuals)
        written = {p.name: sha256_file(p) for p in paths.values()}
        target.mkdir(parents=True, exist_ok=True)
        for name in FORMATS[fmt]:
            if name in written:
                shutil.copyfile(Path(tmp) / name, target / name)
    record = latest
    if new_doc:
        row = {
            **_row_of(latest),
            "document_id": doc_id,
            "issue": content["reissue"]["issue"],
            "issue_date": content["dates"]["issue"],
            "replaces": latest.document_id,
            "replaces_sha256": latest.files_sha256.get("certificate.json"),
            "laboratory_sha256": laboratory_sha256(laboratory),
            "folder": str(folder),
            "files_sha256": json.dumps(written, sort_keys=True),
            "content_json": json.dumps(content, sort_keys=True, indent=2) + "\n",
            "residual_t_s": None,
            "residual_mm": None,
            "residual_channels": None,
        }
        rec = root / ISSUE_TABLE / "reissues" / f"{doc_id}.parquet"
        rec.parent.mkdir(parents=True, exist_ok=True)
        issue_frame([row]).write_parquet(rec)
        record = _issue(row)
    agree = {
        n: (record.files_sha256.get(n) == h if n in record.files_sha256 else None)
        for n, h in written.items()
        if n in FORMATS[fmt]
    }
    cat = _catalog_sha256(root, latest.calibration_id) if record.issue == 0 else None
    cat_agree = None if cat is None or "certificate.json" not in agree else cat == written["certificate.json"]
    return Reissued(
        issue=record,
        out_dir=target,
        new_document=new_doc,
        files={n: written[n] for n in agree},
        agree=agree,
        catalog_agree=cat_agree,
    )


def _default_dir(root: Path, latest: CertificateIssue, folder: Path, new_doc: bool) -> Path:
    """Return the folder a reissue writes to by default.

    An original's night folder (its ``calibration/<device>/<id>`` link is restored), a reissue's own folder.
    """
    if new_doc or latest.issue > 0:
        return root / folder
    return root / "calibration" / f"night={latest.night}" / latest.device_id / latest.calibration_id


def _row_of(i: CertificateIssue) -> dict:
    return {
        "document_id": i.document_id,
        "calibration_id": i.calibration_id,
        "device_id": i.device_id,
        "night": i.night,
        "issue": i.issue,
        "issue_date": i.issue_date,
        "replaces": i.replaces,
        "replaces_sha256": i.replaces_sha256,
        "laboratory_sha256": i.laboratory_sha256,
        "folder": i.folder,
        "files_sha256": json.dumps(i.files_sha256, sort_keys=True),
        "content_json": json.dumps(i.content),
        "residual_t_s": None,
        "residual_mm": None,
        "residual_channels": None,
    }
