"""Calibration certificates: ``certificate.json``, ``certificate.pdf`` and ``residuals.png``.

Written into ``results_root/calibration/<device_id>/<calibration_id>/`` (``outputs.md``).
Regenerating from the same inputs gives byte-identical files: JSON with sorted keys and floats
rounded to 12 significant digits; PDF without CreationDate/ModDate/Producer/Creator; PNG without
the Software key; figures built on fresh ``matplotlib.figure.Figure`` objects (no pyplot state).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure

from borescan.calibration import TriCalibration

__all__ = ["CERTIFICATE_FORMAT", "K_EXPANDED", "certificate_dir", "certificate_dict", "write_certificate"]

CERTIFICATE_FORMAT = "borescan-certificate/1"
K_EXPANDED = 2.0
_PDF_METADATA = {"Creator": None, "Producer": None, "CreationDate": None, "ModDate": None}
_RC = {"font.family": "DejaVu Sans", "font.size": 8, "svg.hashsalt": "borescan", "pdf.compression": 6}


def certificate_dir(results_root: Path | str, cal: TriCalibration) -> Path:
    """``results_root/calibration/<device_id>/<calibration_id>`` (``outputs.md``)."""
    return Path(results_root) / "calibration" / cal.device_id / cal.calibration_id


def _fixed(x: Any) -> Any:
    """JSON-safe copy with floats rounded to 12 significant digits (NaN/inf -> None)."""
    if isinstance(x, dict):
        return {str(k): _fixed(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_fixed(v) for v in x]
    if isinstance(x, np.ndarray):
        return _fixed(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return float(f"{x:.12g}") if np.isfinite(x) else None
    return x


def _residual_arrays(residuals: dict) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(residuals["t_s"], dtype=float)
    res = np.asarray(residuals["residual_mm"], dtype=float)
    if res.ndim == 1:
        res = res[:, None]
    if res.shape[0] != t.size:
        raise ValueError(f"residuals: t_s has {t.size} samples, residual_mm {res.shape[0]}")
    return t, res


def _parameter_rows(cal: TriCalibration) -> list[dict]:
    b = cal.beams
    rows = []
    for j, ch in enumerate(b.channels):
        rows.append(
            {
                "channel": int(ch),
                "beta_rad": b.beta_rad[j],
                "u_beta_rad": cal.u_beta_rad[j],
                "U_beta_rad": K_EXPANDED * cal.u_beta_rad[j],
                "rho_mm": b.rho_mm[j],
                "u_rho_mm": cal.u_rho_mm[j],
                "U_rho_mm": K_EXPANDED * cal.u_rho_mm[j],
                "d_b_mm": b.d_b_mm[j],
                "u_d_b_mm": cal.u_d_b_mm[j],
                "U_d_b_mm": K_EXPANDED * cal.u_d_b_mm[j],
            }
        )
    return rows


def certificate_dict(
    cal: TriCalibration,
    *,
    device: dict,
    artifact: dict,
    conditions: dict,
    residuals: dict,
    raw_files: dict[str, str],
    software_version: str,
    config_hash: str,
) -> dict:
    """The content of ``certificate.json`` (JSON-safe, floats rounded to 12 significant digits)."""
    t, res = _residual_arrays(residuals)
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.nanmean(res**2, axis=0)) if res.size else np.array([])
    keys = ("gauge", "beta_reference", "acceptance", "n_obs", "n_params", "n_params_all_free", "rank_all_free", "weak_rho_channels", "g_mm", "u_g_mm")
    diag = {k: cal.diagnostics[k] for k in keys if k in cal.diagnostics}
    return _fixed(
        {
            "format": CERTIFICATE_FORMAT,
            "calibration_id": cal.calibration_id,
            "device_id": cal.device_id,
            "method": cal.method,
            "scan_ids": list(cal.scan_ids),
            "coverage_factor_k": K_EXPANDED,
            "parameters": _parameter_rows(cal),
            "covariance": cal.cov,
            "correlation": cal.correlation,
            "fit": {
                "residual_rms_mm": cal.residual_rms_mm,
                "dof": cal.dof,
                "rank": cal.rank,
                "condition": cal.condition,
                "converged": cal.converged,
                "nuisance": cal.nuisance,
                **diag,
            },
            "residuals": {"n_samples": int(t.size), "rms_mm_per_channel": rms},
            "device": device,
            "artifact": artifact,
            "conditions": conditions,
            "raw_files": dict(sorted(raw_files.items())),
            "raw_sha256": dict(sorted(cal.raw_sha256.items())),
            "software_version": software_version,
            "config_hash": config_hash,
        }
    )


def _fmt(x: Any, spec: str) -> str:
    try:
        x = float(x)
    except (TypeError, ValueError):
        return str(x)
    return format(x, spec) if np.isfinite(x) else "n/a"


def _page1(cert: dict) -> Figure:
    """Parameter table with U (k = 2), device, artifact, conditions, hashes, software."""
    fig = Figure(figsize=(8.27, 11.69))
    fig.text(0.06, 0.955, "Calibration certificate", fontsize=16, weight="bold")
    fig.text(0.06, 0.935, f"{cert['calibration_id']}   (method {cert['method']})", fontsize=10)
    y = 0.905
    dev, art, cond = cert["device"], cert["artifact"], cert["conditions"]
    pos = cond.get("spindle_position", "?")
    if isinstance(pos, dict):
        xy = f"({_fmt(pos.get('x_mm'), '.3f')}, {_fmt(pos.get('y_mm'), '.3f')}) mm"
        pos = f"{pos.get('label', '')} {xy}".strip()
    lines = [
        ("Device", f"{dev.get('id', cert['device_id'])}  type {dev.get('type', 'tri_lds')}"
         + (f"  sensors {dev['sensors']}" if "sensors" in dev else "")),
        ("Artifact", f"{art.get('id', '?')}  certificate {art.get('certificate', '?')}"),
        ("", f"certified diameter {_fmt(art.get('certified_diameter_mm'), '.4f')} mm, "
             f"uncertainty {_fmt(art.get('u_diameter_mm'), '.4f')} mm (k = {art.get('k', '?')})"),
        ("Conditions", f"temperature {_fmt(cond.get('temperature_c'), '.2f')} degC, "
                       f"spindle position {pos}"),
        ("", f"speed {_fmt(cond.get('rpm'), '.1f')} rpm, revolutions {cond.get('revolutions', '?')}"),
        ("Scans", ", ".join(cert["scan_ids"])),
        ("Software", f"borescan {cert['software_version']}, config hash {cert['config_hash']}"),
    ]
    for head, text in lines:
        fig.text(0.06, y, head, weight="bold")
        fig.text(0.20, y, text)
        y -= 0.018
    y -= 0.01
    k_exp = cert["coverage_factor_k"]
    fig.text(0.06, y, f"Calibrated parameters: value and expanded uncertainty U (k = {k_exp:g})",
             weight="bold", fontsize=10)
    cols = ["channel", "beta [rad]", "U(beta) [rad]", "rho [mm]", "U(rho) [mm]", "d_b [mm]", "U(d_b) [mm]"]
    cells = [
        [str(p["channel"]), _fmt(p["beta_rad"], ".6f"),
         _fmt(p["U_beta_rad"], ".2e") if p["U_beta_rad"] else "0 (gauge)", _fmt(p["rho_mm"], ".4f"),
         _fmt(p["U_rho_mm"], ".4f"), _fmt(p["d_b_mm"], ".4f"), _fmt(p["U_d_b_mm"], ".4f")]
        for p in cert["parameters"]
    ]
    h = 0.022 * (len(cells) + 1)
    ax = fig.add_axes([0.06, y - 0.01 - h, 0.88, h])
    ax.axis("off")
    tab = ax.table(cellText=cells, colLabels=cols, loc="upper center", cellLoc="center")
    tab.auto_set_font_size(False)
    tab.set_fontsize(8)
    tab.scale(1.0, 1.3)
    y = y - 0.03 - h
    fit = cert["fit"]
    notes = [
        f"Residual rms {_fmt(fit.get('residual_rms_mm'), '.5f')} mm, dof {fit.get('dof')}, "
        f"Jacobian rank {fit.get('rank')}, condition {_fmt(fit.get('condition'), '.3g')}, "
        f"converged {fit.get('converged')}.",
    ]
    if fit.get("g_mm") is not None:
        pairs = zip(fit["g_mm"], fit["u_g_mm"])
        g = ", ".join(f"{_fmt(v, '.4f')} +- {_fmt(K_EXPANDED * u, '.4f')}" for v, u in pairs)
        notes.append(f"Effective base length g = d_b + rho^2/(2R), the combination the data fix best, "
                     f"with U (k = 2) per channel [mm]: {g}. rho and d_b are strongly correlated "
                     "(correlation matrix in certificate.json).")
    if fit.get("gauge"):
        notes.append("Gauge: " + fit["gauge"] + ".")
    acc = fit.get("acceptance")
    if acc:
        notes.append(f"Accepted: largest ratio of a channel's residual rms to its readings' own noise floor "
                     f"{_fmt(acc.get('residual_to_noise_max'), '.3f')} (limit {_fmt(acc.get('max_residual_to_noise'), 'g')}); "
                     f"|rho| within the head radius {_fmt(acc.get('head_radius_mm'), 'g')} mm; centre and spindle position "
                     f"taken within +-{_fmt(1e3 * acc['position_accuracy_mm'], 'g')} um per coordinate (rectangular).")
    if fit.get("weak_rho_channels"):
        notes.append(f"Channels {fit['weak_rho_channels']}: |rho| < 2 u(rho), rho is not distinguished from 0; "
                     "U(d_b) of these channels includes the second-order term of d_b = g - rho^2/(2R).")
    import textwrap

    for note in notes:
        for line in textwrap.wrap(note, 115):
            fig.text(0.06, y, line)
            y -= 0.016
    y -= 0.01
    fig.text(0.06, y, "Raw files (sha256)", weight="bold", fontsize=10)
    y -= 0.018
    for name, digest in cert["raw_files"].items():
        fig.text(0.06, y, name, family="monospace", fontsize=7)
        fig.text(0.40, y, digest, family="monospace", fontsize=7)
        y -= 0.014
        if y < 0.04:
            fig.text(0.06, y, "... (list continues in certificate.json)", fontsize=7)
            break
    return fig


def _residual_figure(cal: TriCalibration, t: np.ndarray, res: np.ndarray, size=(8.27, 5.0)) -> Figure:
    fig = Figure(figsize=size)
    n_ch = res.shape[1]
    axes = fig.subplots(n_ch, 1, sharex=True, squeeze=False)[:, 0]
    chans = list(cal.beams.channels) if len(cal.beams.channels) == n_ch else list(range(1, n_ch + 1))
    for ax, j, ch in zip(axes, range(n_ch), chans):
        ax.plot(t, res[:, j] * 1e3, lw=0.5, color=f"C{j}")
        ax.axhline(0.0, color="k", lw=0.5)
        with np.errstate(invalid="ignore"):
            rms = float(np.sqrt(np.nanmean(res[:, j] ** 2))) * 1e3 if res.size else float("nan")
        ax.set_ylabel(f"ch {ch} [um]")
        ax.set_title(f"channel {ch}: rms {rms:.2f} um", fontsize=8, loc="left")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"Residuals (model - reading), {cal.calibration_id}", fontsize=9)
    fig.tight_layout()
    return fig


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
) -> dict[str, Path]:
    """Write ``certificate.json``, ``certificate.pdf`` and ``residuals.png`` into ``out_dir``.

    Parameters
    ----------
    cal : TriCalibration
    out_dir : results_root/calibration/<device_id>/<calibration_id>/ (see :func:`certificate_dir`)
    device : dict, e.g. {"id", "type", "sensors"}
    artifact : dict with id, certificate, certified_diameter_mm, u_diameter_mm, k
    conditions : dict with temperature_c, spindle_position, rpm, revolutions
    residuals : dict with t_s (n,) [s] and residual_mm (n, c) [mm] (model - reading)
    raw_files : file name -> sha256 hex digest
    software_version, config_hash : str

    Returns
    -------
    dict with keys json, pdf, png -> paths. Same inputs give byte-identical files.
    """
    import matplotlib

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cert = certificate_dict(
        cal, device=device, artifact=artifact, conditions=conditions, residuals=residuals,
        raw_files=raw_files, software_version=software_version, config_hash=config_hash,
    )
    t, res = _residual_arrays(residuals)
    paths = {
        "json": out_dir / "certificate.json",
        "pdf": out_dir / "certificate.pdf",
        "png": out_dir / "residuals.png",
    }
    text = json.dumps(cert, sort_keys=True, indent=2, allow_nan=False) + "\n"
    tmp = paths["json"].with_suffix(".json.tmp")
    tmp.write_text(text)
    tmp.replace(paths["json"])
    with matplotlib.rc_context(_RC):
        fig = _residual_figure(cal, t, res)
        FigureCanvasAgg(fig)
        tmp = out_dir / "residuals.png.tmp"
        fig.savefig(tmp, dpi=110, format="png", metadata={"Software": None})
        tmp.replace(paths["png"])
        tmp = out_dir / "certificate.pdf.tmp"
        meta = dict(_PDF_METADATA, Title=f"Calibration certificate {cal.calibration_id}")
        with PdfPages(tmp, metadata=meta) as pdf:
            pdf.savefig(_page1(cert))
            pdf.savefig(_residual_figure(cal, t, res, size=(8.27, 11.69)))
        tmp.replace(paths["pdf"])
    return paths
