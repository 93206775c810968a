"""Calibration records of the history: their ``calibrations`` rows, and which one a result may use.

A calibration is recorded as one row per channel (``calibrations`` table of ``outputs.md``); a
tri_lds row carries the whole :class:`~borescan.calibrate.result.TriCalibration` as
``calibration_json``, so a measurement rebuilds the exact object. A rod's layer geometry
(Wang 2017 calibrates nothing) is recorded as a calibration with method ``nominal`` so that its
diameters, too, name the geometry they used.

Which calibration applies (README "A measurement never uses a calibration that failed its
verification or has expired"): the device's latest calibration made on or before the night,
refused when it is older than the validity or has failed a verification, unless the config
allows unverified calibrations.

Drift (:func:`calibration_drift`): a change of a beam parameter between two consecutive
calibrations of a device larger than a multiple of their combined standard uncertainty is a
finding; whether a named effect explains it is the pooled examination's
(:func:`borescan.discrepancy.pooled.drift_explanations`).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math

import polars as pl

from borescan.calibrate.result import TriCalibration
from borescan.geometry import RodLayer
from borescan.mirror import mirror_checks_of

__all__ = [
    "choose_calibration",
    "choose_rod_calibration",
    "failed_calibration_ids",
    "days_between",
    "calibration_rows",
    "rod_nominal_calibration_rows",
    "tri_calibration",
    "order_calibrations",
    "calibration_roles",
    "rod_layers",
    "calibration_drift",
    "DRIFT_PARAMS",
]


def days_between(first_night: str, night: str) -> int:
    """Whole days from ``first_night`` to ``night`` (ISO dates)."""
    return (_dt.date.fromisoformat(night) - _dt.date.fromisoformat(first_night)).days


def failed_calibration_ids(verifications: pl.DataFrame) -> set[str]:
    """Calibration ids that failed a verification in ``verifications`` (rows with ``passed`` false)."""
    if verifications.height == 0:
        return set()
    return set(verifications.filter(~pl.col("passed"))["calibration_id"].drop_nulls())


def order_calibrations(calibrations: pl.DataFrame) -> pl.DataFrame:
    """Return the calibrations in the order of their validity, the current one last.

    By ``valid_from``; of two valid from the same night, a calibration on certified gauges after the design
    geometry (method ``nominal``: a rod's drawing values, used only while it has nothing better), then the
    later made (``started_at`` of its scan, when the frame has that column), then the calibration id.
    """
    if calibrations.height == 0:
        return calibrations
    keys = [pl.col("valid_from").cast(pl.Utf8)]
    if "method" in calibrations.columns:
        keys.append((pl.col("method").fill_null("") != "nominal").cast(pl.Int8))
    if "started_at" in calibrations.columns:
        keys.append(pl.col("started_at"))
    return calibrations.sort([*keys, pl.col("calibration_id")], nulls_last=False, maintain_order=True)


def calibration_roles(calibrations: pl.DataFrame, failed_ids: set[str]) -> dict[str, str]:
    """Return what each calibration of ``calibrations`` is in the history they make.

    ``calibrations`` holds rows of any devices; the roles come in :func:`order_calibrations`' order per
    device: ``failed verification``; ``superseded by <id>`` (a later calibration, of a rod a later gauge
    calibration); a rod's design geometry that a gauge calibration replaces, ``design geometry, replaced by
    <id>``; the device's last one ``latest`` (whether it is still valid depends on the date:
    ``recalibration_due``, ``borescan status``).
    """
    out: dict[str, str] = {}
    if calibrations.height == 0:
        return out
    per = order_calibrations(calibrations.unique("calibration_id", keep="first", maintain_order=True))
    for _dev, g in per.group_by("device_id", maintain_order=True):
        ids = g["calibration_id"].to_list()
        methods = g["method"].fill_null("").to_list() if "method" in g.columns else [""] * len(ids)
        gauge = [i for i, m in zip(ids, methods) if m != "nominal"]
        for k, (cal_id, method) in enumerate(zip(ids, methods)):
            later = (
                [i for i in ids[k + 1 :] if i in gauge]
                if method != "nominal"
                else [i for i in ids if i in gauge]
            )
            if cal_id in failed_ids:
                out[cal_id] = "failed verification"
            elif method == "nominal" and gauge:
                out[cal_id] = f"design geometry, replaced by {gauge[0]}" if later else "design geometry"
            elif later or (method == "nominal" and k < len(ids) - 1):
                out[cal_id] = f"superseded by {(later or ids[k + 1 :])[0]}"
            else:
                out[cal_id] = "latest"
    return out


def choose_calibration(
    calibrations: pl.DataFrame,
    failed_ids: set[str],
    device_id: str,
    night: str,
    validity_days: int,
    allow_unverified: bool,
) -> tuple[str | None, str | None]:
    """Return the calibration a device's result of ``night`` must use, or the reason there is none.

    The latest calibration of the device made on or before the night (same night included; ties broken as
    :func:`order_calibrations` breaks them), if it is at most ``validity_days`` old and has not failed a
    verification. A failed or expired latest calibration is refused (never silently replaced by an older
    one) unless ``allow_unverified``.

    Returns
    -------
    (calibration_id, None) or (None, reason)
    """
    none = f"no calibration of device {device_id} on or before night {night}"
    if calibrations.height == 0 or "device_id" not in calibrations.columns:
        return None, none
    c = calibrations.filter((pl.col("device_id") == device_id) & (pl.col("valid_from") <= night))
    if c.height == 0:
        return None, none
    c = order_calibrations(c)
    cal_id, valid_from = c["calibration_id"][-1], str(c["valid_from"][-1])
    if allow_unverified:
        return cal_id, None
    if cal_id in failed_ids:
        return None, f"latest calibration {cal_id} of device {device_id} failed its verification; recalibrate"
    age = days_between(valid_from, night)
    if age > validity_days:
        return (
            None,
            f"latest calibration {cal_id} of device {device_id} expired ({age} days old, validity "
            f"{validity_days} days)",
        )
    return cal_id, None


def choose_rod_calibration(
    calibrations: pl.DataFrame,
    failed_ids: set[str],
    device_id: str,
    night: str,
    validity_days: int,
    allow_unverified: bool,
    without_calibration: str = "measure_nominal",
) -> tuple[str | None, str | None]:
    """Return the calibration a rod's result of ``night`` must use, or the reason there is none.

    The rod's ring-gauge calibrations (method ``rod_gauge``) are chosen as a three-sensor device's
    (:func:`choose_calibration`: latest, refused when expired or failed unless ``allow_unverified``).
    A rod never calibrated on gauges on or before the night uses its design geometry (the latest
    ``nominal`` record) when ``without_calibration`` is ``measure_nominal``, else is refused
    (``measurement.rod_without_calibration``).
    """
    if without_calibration not in ("measure_nominal", "refuse"):
        raise ValueError(
            "measurement.rod_without_calibration must be measure_nominal or refuse, got "
            f"{without_calibration!r}"
        )
    has_method = calibrations.height > 0 and "method" in calibrations.columns
    method = pl.col("method").fill_null("") if has_method else pl.lit("")
    gauge = calibrations.filter(method != "nominal") if has_method else calibrations.clear()
    cal_id, why = choose_calibration(gauge, failed_ids, device_id, night, validity_days, allow_unverified)
    if cal_id is not None or not why.startswith("no calibration"):
        return cal_id, why
    if without_calibration == "refuse":
        return None, (
            f"rod {device_id} has no calibration on certified ring gauges on or before night {night} "
            "(measurement.rod_without_calibration: refuse); its design geometry is not traceable"
        )
    nominal = calibrations.filter(method == "nominal") if has_method else calibrations.clear()
    return choose_calibration(nominal, set(), device_id, night, 10**9, True)


def calibration_rows(
    cal: TriCalibration, device_type: str, night: str, certificate_path: str | None, raw_sha256: str
) -> list[dict]:
    """Return the ``calibrations`` rows of a three-sensor calibration.

    Return the ``calibrations`` rows of a three-sensor calibration: one per channel, valid from
    ``night``.
    """
    rows = []
    u_beta, u_rho, u_db = cal.u_beta_rad, cal.u_rho_mm, cal.u_d_b_mm
    cal_json = json.dumps(cal.to_dict(), sort_keys=True)
    checks = {m.channel: m for m in mirror_checks_of(cal.diagnostics)}
    for i, ch in enumerate(cal.beams.channels):
        rows.append(
            {
                "calibration_id": cal.calibration_id,
                "device_id": cal.device_id,
                "device_type": device_type,
                "scan_id": cal.scan_ids[0],
                "channel": int(ch),
                "rho_mm": float(cal.beams.rho_mm[i]),
                "d_b_mm": float(cal.beams.d_b_mm[i]),
                "beta_rad": float(cal.beams.beta_rad[i]),
                "u_rho_mm": float(u_rho[i]),
                "u_d_b_mm": float(u_db[i]),
                "u_beta_rad": float(u_beta[i]),
                "method": cal.method,
                "certificate_path": certificate_path,
                "night": night,
                "valid_from": night,
                "status": "valid",
                "raw_sha256": raw_sha256,
                "residual_rms_mm": float(cal.residual_rms_mm),
                "calibration_json": cal_json,
                **_mirror_columns(checks.get(int(ch))),
            }
        )
    return rows


def _mirror_columns(m) -> dict:
    """Return the ``calibrations`` columns of one beam's mirror check.

    See :class:`borescan.mirror.BeamMirror`; a calibration without one (e.g. yang2017) has nulls. A resolved
    beam has p_wrong_sign 0 and no valid range (every bore); ``valid_bore_max_mm`` null also where the range
    has no upper limit.
    """
    if m is None:
        return {}
    lo, hi = m.valid_bore_diameter_mm or (None, None)
    return {
        "rho_sign_resolved": bool(m.resolved),
        "mirror_delta_chi2": m.refit_delta_chi2,
        "mirror_depth_predicted": m.predicted_delta_chi2 if math.isfinite(m.predicted_delta_chi2) else None,
        "p_wrong_sign": float(m.p_wrong_sign),
        "valid_bore_min_mm": lo,
        "valid_bore_max_mm": hi if hi is not None and math.isfinite(hi) else None,
        "offset_to_resolve_mm": m.offset_to_resolve_mm if math.isfinite(m.offset_to_resolve_mm) else None,
        # what would resolve an undetermined sign within the sensors' range (BeamMirror.fix)
        "rho_sign_fix": None if m.sign_determined else m.fix(),
    }


def rod_nominal_calibration_rows(meta: dict, night: str, scan_id: str) -> list[dict]:
    """Return the rod's layer geometry from ``device.nominal`` as a calibration record (method ``nominal``).

    The id is ``<device>-nominal-<8 hex of the layers' SHA-256>``, so the same geometry on
    another night is the same calibration. [] when the device lists no layers.
    """
    layers = sorted(
        ((meta.get("device") or {}).get("nominal") or {}).get("layers") or [], key=lambda l: int(l["channel"])
    )
    if not layers:
        return []
    digest = hashlib.sha256(json.dumps(layers, sort_keys=True).encode()).hexdigest()[:8]
    cal_id = f"{meta['device']['id']}-nominal-{digest}"
    return [
        {
            "calibration_id": cal_id,
            "device_id": meta["device"]["id"],
            "device_type": "rod",
            "scan_id": scan_id,
            "channel": int(l["channel"]),
            "l0_mm": float(l["l0"]),
            "h_mm": float(l.get("h", float("nan"))),
            "phi_rad": float(l.get("phi", 0.0)),
            "d_mm": float(l.get("d", 0.0)),
            "gamma_rad": float(l.get("gamma", 0.0)),
            "method": "nominal",
            "certificate_path": None,
            "night": night,
            "valid_from": night,
            "status": "valid",
        }
        for l in layers
    ]


def tri_calibration(calibrations: pl.DataFrame, cal_id: str) -> TriCalibration:
    """Return the :class:`TriCalibration` recorded as ``cal_id`` in ``calibrations`` rows."""
    row = calibrations.filter(pl.col("calibration_id") == cal_id).row(0, named=True)
    return TriCalibration.from_dict(json.loads(row["calibration_json"]))


def rod_layers(layer_rows, channels) -> list[RodLayer]:
    """Return the rod layers of ``channels`` from a rod calibration's rows.

    Return the rod layers of ``channels`` from a rod calibration's rows (a polars frame or row dicts;
    missing or NaN phi, d, gamma, h: 0).
    """
    it = layer_rows.iter_rows(named=True) if isinstance(layer_rows, pl.DataFrame) else layer_rows
    rows = {int(r["channel"]): r for r in it}

    def num(r: dict, k: str) -> float:
        v = r.get(k)
        return float(v) if v is not None and math.isfinite(float(v)) else 0.0

    return [
        RodLayer(
            int(ch),
            num(rows[int(ch)], "h_mm"),
            float(rows[int(ch)]["l0_mm"]),
            num(rows[int(ch)], "phi_rad"),
            num(rows[int(ch)], "d_mm"),
            num(rows[int(ch)], "gamma_rad"),
        )
        for ch in channels
    ]


#: Beam parameters compared by :func:`calibration_drift`: (value column, standard uncertainty column).
DRIFT_PARAMS = (("beta_rad", "u_beta_rad"), ("rho_mm", "u_rho_mm"), ("d_b_mm", "u_d_b_mm"))
_DRIFT_SCHEMA = {
    "device_id": pl.String,
    "channel": pl.Int64,
    "parameter": pl.String,
    "calibration_id_before": pl.String,
    "calibration_id_after": pl.String,
    "valid_from_before": pl.String,
    "valid_from_after": pl.String,
    "value_before": pl.Float64,
    "value_after": pl.Float64,
    "change": pl.Float64,
    "u_before": pl.Float64,
    "u_after": pl.Float64,
    "u_combined": pl.Float64,
    "change_over_u": pl.Float64,
    "multiple": pl.Float64,
    "flagged": pl.Boolean,
}


def calibration_drift(  # noqa: C901 (input checks, then per device, channel, parameter and pair)
    calibrations: pl.DataFrame, multiple: float
) -> pl.DataFrame:
    """Return the changes of each beam parameter between consecutive calibrations of a three-sensor device.

    For every device and channel the calibrations (rows of the ``calibrations`` table with a
    ``beta_rad``; ``nominal`` records left out) are ordered as :func:`choose_calibration` orders
    them (``valid_from``, then ``calibration_id``); for each consecutive pair and each parameter
    of :data:`DRIFT_PARAMS`

        change = value_after - value_before   (beta wrapped to (-pi, pi]),
        u_combined = sqrt(u_before^2 + u_after^2)   (two calibrations from different scans: independent),

    and the pair is ``flagged`` when |change| > ``multiple`` u_combined (strictly). The standard
    uncertainties are the table's ``u_*`` columns (k = 1).

    Parameters
    ----------
    calibrations : rows of the ``calibrations`` table (any device types; polars frame)
    multiple : how many combined standard uncertainties a change must exceed [-] (> 0)

    Returns
    -------
    polars frame, one row per device, channel, parameter and consecutive pair, ordered by device,
    channel, parameter and time; columns device_id, channel, parameter, calibration_id_before,
    calibration_id_after, valid_from_before, valid_from_after, value_before, value_after, change,
    u_before, u_after, u_combined, change_over_u (change / u_combined, signed), multiple, flagged.
    Empty (with these columns) when no device has two calibrations.
    """
    if not (multiple > 0 and math.isfinite(multiple)):
        raise ValueError(f"drift multiple must be a positive number, got {multiple!r}")
    need = {"calibration_id", "device_id", "channel", "valid_from"} | {
        c for pair in DRIFT_PARAMS for c in pair
    }
    if calibrations.height == 0 or not need <= set(calibrations.columns):
        missing = sorted(need - set(calibrations.columns))
        if calibrations.height and missing:
            raise ValueError(f"calibrations table lacks the columns {missing} that calibration_drift reads")
        return pl.DataFrame(schema=_DRIFT_SCHEMA)
    c = calibrations.filter(pl.col("beta_rad").is_not_null())
    if "method" in c.columns:
        c = c.filter(pl.col("method").fill_null("") != "nominal")
    c = c.with_columns(pl.col("valid_from").cast(pl.String)).sort(
        "device_id", "channel", "valid_from", "calibration_id"
    )
    rows = []
    for (device, channel), g in c.group_by(["device_id", "channel"], maintain_order=True):
        recs = g.rows(named=True)
        for par, upar in DRIFT_PARAMS:
            for a, b in zip(recs, recs[1:]):
                va, vb, ua, ub = (
                    float(x) if x is not None else math.nan for x in (a[par], b[par], a[upar], b[upar])
                )
                d = vb - va
                if par == "beta_rad":
                    d = math.remainder(d, 2.0 * math.pi)
                uc = math.hypot(ua, ub)
                if not (math.isfinite(d) and math.isfinite(uc)):
                    ratio = math.nan  # a missing value or uncertainty: no judgement
                elif uc > 0:
                    ratio = d / uc
                else:
                    ratio = math.copysign(math.inf, d) if d else 0.0
                rows.append(
                    {
                        "device_id": device,
                        "channel": int(channel),
                        "parameter": par,
                        "calibration_id_before": a["calibration_id"],
                        "calibration_id_after": b["calibration_id"],
                        "valid_from_before": a["valid_from"],
                        "valid_from_after": b["valid_from"],
                        "value_before": va,
                        "value_after": vb,
                        "change": d,
                        "u_before": ua,
                        "u_after": ub,
                        "u_combined": uc,
                        "change_over_u": ratio,
                        "multiple": float(multiple),
                        "flagged": (not math.isnan(ratio)) and abs(d) > multiple * uc,
                    }
                )
    if not rows:
        return pl.DataFrame(schema=_DRIFT_SCHEMA)
    return pl.DataFrame(rows, schema=_DRIFT_SCHEMA, orient="row")
