"""Write a certificate's documents: certificate.json, certificate.dcc.xml, certificate.pdf, residuals.png."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure

from borescan.atomic import atomic_write_bytes, atomic_write_text
from borescan.calibrate.result import TriCalibration
from borescan.certificate.budget_pages import _budget_tables, _page_records, _verification_pages
from borescan.certificate.content import _residual_arrays
from borescan.certificate.dcc import write_dcc
from borescan.certificate.layout import _A4, _PDF_METADATA, _RC, _Doc, _fixed_title, _pdf_context
from borescan.certificate.pages import _page_admin, _page_item_conditions, _page_results
from borescan.certificate.rod import _rod_pages, _rod_residual_figure, rod_certificate_dict
from borescan.certificate.tri import certificate_dict
from borescan.uncertainty import Budget


#: runs of samples a residual trace is drawn with: its minimum and maximum in each run, in time order. The
#: first calibration scan's 20 000-95 000 samples a channel took 40 % of the certificate's drawing (PNG and
#: PDF); 2000 runs over the page's 6.5 in axis (300 an inch, the PNG's 110 dpi axis about 800 pixels)
#: still draw every extreme reading where it is, and the trace looks the same
TRACE_RUNS = 2000


def trace_envelope(t: np.ndarray, y: np.ndarray, runs: int = TRACE_RUNS) -> tuple[np.ndarray, np.ndarray]:
    """Return the samples of ``y(t)`` that draw its trace: each run's minimum and maximum, in time order.

    The samples are cut into ``runs`` runs of equal length; where a run is that short or shorter
    (two samples or fewer) every sample is returned. NaN samples (no reading) are passed over; a
    run with nothing else gives NaN, which breaks the line as the samples did.
    """
    n = y.size
    per = -(-n // max(int(runs), 1))
    if per <= 2:
        return t, y
    pad = -n % per
    tt = np.concatenate([t, np.full(pad, np.nan)]).reshape(-1, per)
    yy = np.concatenate([y, np.full(pad, np.nan)]).reshape(-1, per)
    missing = np.isnan(yy)
    lo = np.argmin(np.where(missing, np.inf, yy), axis=1)
    hi = np.argmax(np.where(missing, -np.inf, yy), axis=1)
    rows = np.arange(yy.shape[0])[:, None]
    at = np.stack([np.minimum(lo, hi), np.maximum(lo, hi)], axis=1)
    return tt[rows, at].ravel(), yy[rows, at].ravel()


def _residual_figure(
    cert: dict, t: np.ndarray, res: np.ndarray, size=(8.27, 5.0), page: bool = False
) -> Figure:
    fig = Figure(figsize=size)
    n_ch = res.shape[1]
    axes = fig.subplots(n_ch, 1, sharex=True, squeeze=False)[:, 0]
    channels = [int(r["channel"]) for r in cert["parameters"]]
    chans = channels if len(channels) == n_ch else list(range(1, n_ch + 1))
    for ax, j, ch in zip(axes, range(n_ch), chans):
        ax.plot(*trace_envelope(t, res[:, j] * 1e3), lw=0.5, color=f"C{j}")
        ax.axhline(0.0, color="k", lw=0.5)
        with np.errstate(invalid="ignore"):
            rms = float(np.sqrt(np.nanmean(res[:, j] ** 2))) * 1e3 if res.size else float("nan")
        ax.set_ylabel(f"ch {ch} [um]")
        _fixed_title(ax, f"channel {ch}: rms {rms:.2f} um")
    axes[-1].set_xlabel("t [s]")
    if page:
        fig.text(
            _Doc.LEFT,
            0.885,
            "9  Residuals of the fit (model - reading), first calibration scan",
            fontsize=10.5,
            weight="bold",
        )
        fig.subplots_adjust(left=0.12, right=0.94, top=0.84, bottom=0.1, hspace=0.35)
    else:
        fig.suptitle(f"Residuals (model - reading), {cert['calibration_id']}", fontsize=9)
        # fixed margins (tight_layout measured every label: a third of the PNG's time); room for
        # tick labels of four digits and the channel's label
        fig.subplots_adjust(left=0.1, right=0.98, top=0.88, bottom=0.1, hspace=0.5 if n_ch > 1 else 0.2)
    return fig


def _png_bytes(fig: Figure) -> bytes:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, dpi=110, format="png", metadata={"Software": None})
    return buf.getvalue()


def _pages(cert: dict, t: np.ndarray, res: np.ndarray) -> list[Figure]:
    d = _Doc(cert)
    _page_admin(d)
    _page_item_conditions(d)
    _page_results(d)
    _budget_tables(d)
    _verification_pages(d)
    _page_records(d)
    d.pages.append(_residual_figure(cert, t, res, size=_A4, page=True))
    return d.finish()


def write_certificate(
    cal: TriCalibration,
    out_dir: Path | str,
    *,
    device: dict,
    artifact: dict,
    conditions: dict,
    residuals: dict,
    raw_files: dict[str, str],
    software_version: str,
    config_hash: str,
    budget: Budget | None = None,
    laboratory: dict | None = None,
    coverage_probability: float | None = None,
    dates: dict | None = None,
    verifications: list[dict] | None = None,
) -> dict[str, Path]:
    """Write ``certificate.json``, ``certificate.pdf`` and ``residuals.png`` into ``out_dir``.

    Parameters
    ----------
    cal : TriCalibration (``cov`` the combined covariance of its budget)
    out_dir : results_root/calibration/<device_id>/<calibration_id>/ (see :func:`certificate_dir`)
    device : dict, e.g. {"id", "type", "sensors" (scan.json sensor entries)}
    artifact : scan.json artifact of the gauge (id, certificate, certified_diameter_mm, u_diameter_mm,
        k, cte_per_k; certificate_issuer and certificate_valid_until when known)
    conditions : influence conditions: ``temperature`` {value_c, u_c, U_c, k, source, assumed},
        ``gauge_cte``, ``gauge_radius_at_temperature_mm``, ``position_accuracy_mm``, ``scans`` (per
        scan: scan_id, spindle_position, center, rpm, angle_source, revolutions_recorded,
        revolutions_with_extrema)
    residuals : dict with t_s (n,) [s] and residual_mm (n, c) [mm] (model - reading)
    raw_files : file name -> sha256 hex digest
    software_version, config_hash : str
    budget : the calibration's GUM budget (default: ``cal.diagnostics["budget"]``)
    laboratory : the config's ``laboratory`` section (default: its schema defaults, placeholders)
    coverage_probability : of every U (None: the schema's uncertainty.coverage_probability)
    dates : ``begin``, ``end`` (dates of calibration), ``issue``, ``issue_rule``,
        ``recalibration_due``, ``recalibration_rule`` (ISO dates and the text saying how each was derived)
    verifications : rows of the night's verifications with this calibration
        (:func:`borescan.measure.verification_row` plus ``budget``: its budget rows)

    Returns
    -------
    dict with keys json, dcc, pdf, png -> paths. Same inputs give byte-identical files.
    """
    cert = certificate_dict(
        cal,
        device=device,
        artifact=artifact,
        conditions=conditions,
        residuals=residuals,
        raw_files=raw_files,
        software_version=software_version,
        config_hash=config_hash,
        budget=budget,
        laboratory=laboratory,
        coverage_probability=coverage_probability,
        dates=dates,
        verifications=verifications,
    )
    return write_certificate_files(cert, out_dir, residuals)


def write_certificate_files(
    cert: dict, out_dir: Path | str, residuals: dict | None = None
) -> dict[str, Path]:
    """Write the documents of the certificate whose content is ``cert`` into ``out_dir``.

    ``certificate.json``, ``certificate.dcc.xml`` (:mod:`borescan.certificate.dcc`), ``certificate.pdf`` and,
    for a three-sensor certificate, ``residuals.png`` (``residuals``: t_s [s], residual_mm [mm]). Returns the
    paths by key (json, dcc, pdf, png); the same content gives the same bytes.
    """
    import matplotlib

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    title = f"Calibration certificate {cert['administrativeData']['coreData']['uniqueIdentifier']}"
    paths = {"json": out_dir / "certificate.json", "pdf": out_dir / "certificate.pdf"}
    # unique temporary names (atomic.py): two runs writing the same certificate never meet
    atomic_write_text(paths["json"], json.dumps(cert, sort_keys=True, indent=2, allow_nan=False) + "\n")
    paths["dcc"] = write_dcc(cert, out_dir)
    rod = (cert.get("device") or {}).get("type") == "rod"
    if not rod:
        t, res = _residual_arrays(residuals)
    # the PNG in DejaVu Sans (_RC); the PDF's pages drawn and written in their own settings (_pdf_rc)
    with matplotlib.rc_context(_RC):
        if not rod:
            paths["png"] = out_dir / "residuals.png"
            atomic_write_bytes(paths["png"], _png_bytes(_residual_figure(cert, t, res)))
        elif (cert.get("fit") or {}).get("pose_residuals") is not None:
            paths["png"] = out_dir / "residuals.png"
            atomic_write_bytes(paths["png"], _png_bytes(_rod_residual_figure(cert)))
    with _pdf_context(cert):
        pages = _rod_pages(cert) if rod else _pages(cert, t, res)
        atomic_write_bytes(paths["pdf"], _pdf_bytes(pages, title))
    return paths


def _pdf_bytes(pages: list[Figure], title: str) -> bytes:
    buf = io.BytesIO()
    with PdfPages(buf, metadata=dict(_PDF_METADATA, Title=title)) as pdf:
        for page in pages:
            pdf.savefig(page)
    return buf.getvalue()


def write_rod_certificate(cal, out_dir: Path | str, **kw) -> dict[str, Path]:
    """Write ``certificate.json``, ``certificate.dcc.xml`` and ``certificate.pdf`` of a rod calibration.

    Into ``out_dir``, from the arguments of :func:`rod_certificate_dict`. Same inputs give byte-identical
    files.
    """
    return write_certificate_files(rod_certificate_dict(cal, **kw), out_dir)
