"""The report's first screen: each device's status and the decisions a night asks of a person.

- :func:`device_status`: per device, its current calibration, valid until and days left as of the
  last night of the catalog (the report depends on its data only, never on the day it is drawn).
- :func:`pooled_items`: the pooled verdicts of a night; an effect named that is not yet in the
  device model comes with the ``config/devices.yaml`` entry that adds it from the next night on.
- :func:`drift_items`: the flagged calibration drifts in combined standard uncertainties; one that
  no pooled verdict explains needs a person (the night is not green).
- :func:`refused_note`: what the discrepancy examination said of a scan whose calibration was refused.
"""

from __future__ import annotations

import datetime as _dt
import html
import math
from dataclasses import dataclass

import polars as pl

from borescan.calibrations import failed_calibration_ids, order_calibrations
from borescan.effects import DEVICE_MODEL_SCAN_KIND, EFFECTS, device_effect_key
from borescan.report.device_model import _calibration_models, _text_of
from borescan.report.text import _e, _parameters_text, _table, _uncertainties

#: Days before the end of its validity from which a calibration is shown as due soon.
DUE_SOON_DAYS = 7

#: Display unit of a drifting calibration parameter (by its name's unit suffix): (unit, factor).
_DRIFT_UNITS = {"_rad": ("mrad", 1e3), "_mm": ("µm", 1e3)}


@dataclass(frozen=True)
class DeviceStatus:
    """One device's calibration as of a night (``as_of``): what the report's first screen shows."""

    device_id: str
    calibration_id: str | None
    method: str | None
    valid_from: str | None
    valid_until: str | None  # the last night it may be used (``recalibration_due``); None: no end
    days_left: int | None  # valid_until - as_of in days; negative: expired
    state: str  # valid, due soon, expired, failed verification, design geometry, no calibration
    carried: str  # the device-model effects its calibration carries, with their estimates


def _day(v) -> str | None:
    return None if v is None else str(v)[:10]


def device_status(cal: pl.DataFrame, ver: pl.DataFrame | None, as_of: str) -> list[DeviceStatus]:
    """Return each device's current calibration and its state as of the night ``as_of``.

    The current calibration is the device's last in :func:`borescan.calibrations.order_calibrations`'
    order among those valid from ``as_of`` or earlier (a rod's gauge calibration before its design
    geometry); its state: ``failed verification``, ``expired`` (``as_of`` after ``recalibration_due``),
    ``due soon`` (at most :data:`DUE_SOON_DAYS` days left), ``design geometry`` (method ``nominal``: no
    traceable calibration) or ``valid``.
    """
    if cal.height == 0:
        return []
    failed = failed_calibration_ids(ver) if ver is not None and "passed" in ver.columns else set()
    mine_all = cal.filter(pl.col("valid_from").cast(pl.Utf8) <= as_of)
    models = _calibration_models(cal)
    out = []
    for dev in sorted(cal["device_id"].drop_nulls().unique().to_list()):
        mine = order_calibrations(
            mine_all.filter(pl.col("device_id") == dev).unique(
                "calibration_id", keep="first", maintain_order=True
            )
        )
        gauge = mine.filter(pl.col("method").fill_null("") != "nominal") if "method" in mine.columns else mine
        mine = gauge if gauge.height else mine
        if mine.height == 0:
            out.append(DeviceStatus(dev, None, None, None, None, None, "no calibration", ""))
            continue
        r = mine.row(-1, named=True)
        until = _day(r.get("recalibration_due"))
        left = None if until is None else (_dt.date.fromisoformat(until) - _dt.date.fromisoformat(as_of)).days
        if r["calibration_id"] in failed:
            state = "failed verification"
        elif r.get("method") == "nominal":
            state = "design geometry"
        elif left is not None and left < 0:
            state = "expired"
        elif left is not None and left <= DUE_SOON_DAYS:
            state = "due soon"
        else:
            state = "valid"
        entries = models.get((dev, _day(r["valid_from"])), ([], None))[0]
        carried = "; ".join(
            f"{m['key']} {_text_of(m)} (estimated {m.get('night')})" for m in entries if m.get("estimated")
        )
        out.append(
            DeviceStatus(
                dev, r["calibration_id"], r.get("method"), _day(r["valid_from"]), until, left, state, carried
            )
        )
    return out


def device_status_html(status: list[DeviceStatus], as_of: str) -> str:
    """Return the devices' status table (HTML): a row per device, red when it cannot be used."""
    if not status:
        return ""
    rows, classes = [], []
    for s in status:
        bad = s.state in ("expired", "failed verification", "no calibration")
        warn = s.state in ("due soon", "design geometry")
        cls = "fail" if bad else "warn" if warn else "pass"
        rows.append(
            [
                f"<b>{_e(s.device_id)}</b>",
                f'<span class="{cls}">{_e(s.state)}</span>',
                _e(s.calibration_id or "–"),
                _e(s.valid_until or ("no end" if s.calibration_id else "–")),
                "" if s.days_left is None else str(s.days_left),
                _e(s.carried or "–"),
            ]
        )
        classes.append("fail" if bad else "warn" if warn else "")
    return f"<h3>Devices as of {_e(as_of)} (the last night)</h3>" + _table(
        ["device", "status", "current calibration", "valid until", "days left", "its device model"],
        rows,
        classes,
        num_cols={4},
    )


def _next_night(night: str) -> str:
    return (_dt.date.fromisoformat(str(night)[:10]) + _dt.timedelta(days=1)).isoformat()


def devices_yaml(device_id: str, term: str, night: str, value: str = "") -> str | None:
    """Return the ``config/devices.yaml`` entry that adds ``term`` to a device from the night after ``night``.

    ``value``: the estimate named that night, written as a comment (the device model takes the latest
    estimate of the pooled examination, not a value from the file).

    None when ``term`` is not an effect a device model may hold (:func:`borescan.effects.device_effect_key`:
    a night's temperature or one scan's spindle error is not a property of the device).
    """
    try:
        device_effect_key(term, None, device_id)
    except ValueError:
        return None
    note = f"  # {value}, named on {night}" if value else f"  # named on {night}"
    entry = f'{{effect: "{term}", from: "{_next_night(night)}"}}'
    return f"devices:\n  {device_id}:\n    effects:\n      - {entry}{note}"


def pooled_items(pf: pl.DataFrame | None) -> list[str]:
    """Return a night's pooled verdicts as summary items (HTML ``<li>``), one per device.

    ``missing_effect``: each named effect with value ± u and its evidence scans, and for an effect not
    in the device model the ``config/devices.yaml`` entry to paste; ``ambiguous``: the candidates and
    what would separate them; ``failed``: the reason. A device whose scans show nothing missing gives none.
    """
    if pf is None or pf.height == 0:
        return []
    items = []
    for (dev,), grp in pf.group_by("device_id", maintain_order=True):
        recs = [r for r in grp.iter_rows(named=True)]
        verdict = recs[0].get("verdict") or ""
        named = [r for r in recs if r.get("effect") and not r.get("in_device_model")]
        if verdict == "failed":
            items.append(
                f"<li><b>pooled examination failed</b> {_e(dev)}: {_e(recs[0].get('reason') or '')}</li>"
            )
            continue
        if verdict not in ("missing_effect", "ambiguous") or not named:
            continue
        texts, yaml = [], []
        for r in named:
            pars = _parameters_text(r["effect"], r.get("parameters"), _uncertainties(r.get("uncertainties")))
            where = f" on channel {r['channel']}" if r.get("channel") is not None else ""
            ev = f" (evidence: {_e(r['evidence_scans'])})" if r.get("evidence_scans") else ""
            texts.append(f"<b>{_e(r['effect'])}</b>{_e(where)}" + (f": {pars}" if pars else "") + ev)
            line = (
                devices_yaml(dev, r.get("term") or r["effect"], str(r["night"]), html.unescape(pars))
                if verdict == "missing_effect"
                else None
            )
            if line:
                yaml.append(line)
        gap = recs[0].get("gap_before_mm"), recs[0].get("gap_after_mm"), recs[0].get("noise_floor_mm")
        gap_text = (
            f" (gap {gap[0] * 1e3:.2f} → {gap[1] * 1e3:.2f} µm rms, noise floor {gap[2] * 1e3:.2f} µm)"
            if None not in gap
            else ""
        )
        if verdict == "missing_effect":
            action = (
                "what to do: if the device has this effect, add it to its device model in "
                "<code>config/devices.yaml</code> (from the next night on; nights already processed keep "
                "theirs unless <code>borescan recompute --from NIGHT</code>):"
                + "".join(f"<pre>{_e(y)}</pre>" for y in yaml)
                if yaml
                else "what to do: service the device if it persists (the effect is not a property of the "
                "device: no device model holds it)."
            )
        else:
            hints = sorted(
                {
                    EFFECTS[r["effect"]].separated_by
                    for r in named
                    if r["effect"] in EFFECTS and EFFECTS[r["effect"]].separated_by
                }
            )
            action = "what to do: nothing to add yet; " + (
                "a scan at " + " or ".join(hints) + " separates them."
                if hints
                else "another scan separates them."
            )
        items.append(
            f"<li><b>pooled verdict {_e(verdict)}</b> {_e(dev)}{_e(gap_text)}: "
            + "; ".join(texts)
            + f'<br><span class="action">{action}</span></li>'
        )
    return items


def _entered(cal: pl.DataFrame | None) -> dict[tuple[str, str], list[str]]:
    """Return (device, night) -> the device-model keys its calibration carried, its previous did not."""
    out: dict[tuple[str, str], list[str]] = {}
    last: dict[str, set[str]] = {}
    for (dev, night), (entries, _ratio) in sorted(_calibration_models(cal).items()):
        keys = {m["key"] for m in entries if m.get("estimated")}
        new = sorted(keys - last.get(dev, set()))
        if new:
            out[(dev, night)] = new
        last[dev] = keys
    return out


def _absorbs(key: str, parameter: str) -> bool:
    """Whether the device-model effect ``key`` is absorbed by the calibration parameter ``parameter``."""
    spec = EFFECTS.get(key.split("@")[0])
    if spec is None:
        return False
    return any(
        parameter == p or parameter.startswith(p + "_") for p in spec.absorbers(DEVICE_MODEL_SCAN_KIND)
    )


def _signed(v: float | None, factor: float = 1.0, sign: str = "+") -> str:
    """Return ``v * factor`` with two decimals (a sign with ``sign="+"``), "n/a" when missing."""
    if v is None or not math.isfinite(v):
        return "n/a"
    return f"{v * factor:{sign}.2f}"


def drift_items(dr: pl.DataFrame | None, cal: pl.DataFrame | None = None) -> list[tuple[bool, str]]:
    """Return a night's flagged calibration drifts as summary items: (explained?, HTML ``<li>``).

    Each: device, channel, parameter, the change in mrad or µm and in combined standard uncertainties
    against the limit, and what explains it (a pooled verdict) or "not explained". When the night's
    calibration started to carry a device-model effect that this parameter absorbs, the item says so:
    the parameter no longer holds that effect, a step is expected (the drift stays flagged).
    """
    if dr is None or dr.height == 0:
        return []
    flagged = dr.filter(pl.col("flagged").fill_null(False))
    entered = _entered(cal)
    items = []
    for r in flagged.sort("device_id", "channel", "parameter").iter_rows(named=True):
        unit, f = next((u for s, u in _DRIFT_UNITS.items() if r["parameter"].endswith(s)), ("", 1.0))
        explained = r.get("explained_by")
        limit = f", limit {r['multiple']:.0f} u" if r.get("multiple") is not None else ""
        text = (
            f"<b>drift{'' if explained else ' NOT EXPLAINED'}</b> {_e(r['device_id'])} "
            f"channel {_e(r['channel'])} "
            f"{_e(r['parameter'])}: {_signed(r['change'], f)} {unit} = {_signed(r['change_over_u'])} u "
            f"(u combined {_signed(r['u_combined'], f, '')} {unit}{limit}) since the previous calibration"
        )
        model = [k for k in entered.get((r["device_id"], str(r["night"])), []) if _absorbs(k, r["parameter"])]
        if explained:
            action = f"explained by the pooled verdict {_e(explained)} of the night."
        else:
            action = (
                "not explained by a pooled verdict: check the device (sensor, cabling, mounting) before "
                "trusting its measurements; recalibrate if it persists."
            )
            if model:
                action += (
                    f" This night's calibration started to carry {_e(', '.join(model))}, which "
                    f"{_e(r['parameter'])} absorbed before: a step of this parameter is expected once."
                )
        items.append((bool(explained), f'<li>{text}<br><span class="action">{action}</span></li>'))
    return items


def refused_note(scan_id: str, findings: pl.DataFrame | None) -> str:
    """Return the discrepancy verdict of a scan whose calibration was refused (HTML), "" without one."""
    if findings is None or findings.height == 0:
        return ""
    mine = findings.filter(pl.col("scan_id") == scan_id)
    if mine.height == 0:
        return ""
    named = ", ".join(
        f"{e}" + (f" (channel {c})" if c is not None else "")
        for e, c in mine.select("effect", "channel").rows()
        if e
    )
    return f"<br>discrepancy verdict: <b>{_e(mine['verdict'][0])}</b>" + (f": {_e(named)}" if named else "")
