"""``borescan status``: every device, its current calibration, whether it is valid, and its last verification.

Read-only, from the history catalog. "Current" is the calibration a measurement made on the
``--as-of`` date (default: today, UTC) would have to use, chosen by the pipeline's own rule
(:func:`borescan.calibrations.choose_calibration`: the device's latest calibration on or before
that date, refused when older than ``calibration.validity_days`` of the config or when it failed a
verification). A device is listed when it has a scan or a calibration in the catalog.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import sys
from pathlib import Path

from borescan.commands._common import CommandFailed, command_config, night_date, positive_int, utc_text
from borescan.decision import split_verdict

NAME = "status"
HELP = (
    "list the devices, their current calibration, its validity and their last verification (from the catalog)"
)

#: states of a device's calibration, as printed
VALID, EXPIRED, FAILED, NONE = "valid", "expired", "failed verification", "no calibration"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the command's options to ``parser``."""
    parser.add_argument(
        "--results",
        default="results",
        help="results folder holding catalog.duckdb, relative or absolute (default: results)",
    )
    parser.add_argument(
        "--as-of",
        type=night_date,
        default=None,
        metavar="YYYY-MM-DD",
        help="the date to judge validity on (default: today, UTC)",
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="pipeline config for calibration.validity_days (default: config/config.yaml "
        "when present, else the schema's default)",
    )
    parser.add_argument(
        "--validity-days", type=positive_int, default=None, help="override calibration.validity_days [days]"
    )
    parser.add_argument(
        "--format", choices=("text", "json"), default="text", help="output format (default text)"
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help="exit 1 when a device has no valid calibration (for scheduled checks)",
    )


def _validity_days(args: argparse.Namespace) -> tuple[int, str]:
    """calibration.validity_days and where it came from."""
    if args.validity_days is not None:
        return args.validity_days, "--validity-days"
    cfg, source = command_config(args.config)
    return int(cfg["calibration"]["validity_days"]), source


def _rows(con, sql: str, params: list | None = None) -> list[dict]:
    cur = con.execute(sql, params or [])
    cols = [d[0] for d in cur.description]
    return [dict(zip(cols, r, strict=True)) for r in cur.fetchall()]


def _day(v) -> str | None:
    return None if v is None else (v.isoformat() if isinstance(v, _dt.date) else str(v))


def device_status(results: str | Path, as_of: str, validity_days: int) -> list[dict]:
    """Return each device's status as of the date ``as_of``.

    One dict per device (sorted by id): its type, last scan night, current calibration and state,
    validity end, and last verification, as of the date ``as_of`` (``YYYY-MM-DD``).
    """
    import polars as pl

    from borescan import catalog
    from borescan.calibrations import (
        choose_calibration,
        choose_rod_calibration,
        failed_calibration_ids,
        order_calibrations,
    )

    con = catalog.open_catalog(results, read_only=True)
    try:
        devices = _rows(
            con,
            """
            SELECT device_id, any_value(device_type) AS device_type, max(night) AS last_scan_night,
                   max(started_at) AS last_scan_at, count(*) AS n_scans
            FROM scans WHERE device_id IS NOT NULL AND night <= ?::DATE GROUP BY device_id""",
            [as_of],
        )
        cals = _rows(
            con,
            """
            SELECT c.calibration_id, any_value(c.device_id) AS device_id, any_value(c.device_type) AS device_type,
                   any_value(c.method) AS method, min(c.valid_from) AS valid_from,
                   any_value(c.certificate_path) AS certificate_path, count(*) AS n_channels,
                   max(s.started_at) AS started_at
            FROM calibrations c LEFT JOIN scans s ON s.scan_id = c.scan_id AND s.night = c.night
            WHERE c.valid_from <= ?::DATE GROUP BY c.calibration_id""",  # noqa: E501 (SQL text)
            [as_of],
        )
        vers = _rows(
            con,
            """
            SELECT v.scan_id, v.night, v.device_id, v.calibration_id, v.error_mm, v.tolerance_mm, v.passed,
                   v.conformity
            FROM verifications v LEFT JOIN scans s ON s.scan_id = v.scan_id AND s.night = v.night
            WHERE v.night <= ?::DATE ORDER BY v.night, s.started_at NULLS FIRST, v.scan_id""",
            [as_of],
        )
    finally:
        con.close()
    for c in cals:
        c["valid_from"] = _day(c["valid_from"])
    for v in vers:
        v["night"] = _day(v["night"])
    keys = ("calibration_id", "device_id", "valid_from", "method")
    cal_df = pl.DataFrame({k: [c[k] for c in cals] for k in keys}, schema={k: pl.Utf8 for k in keys})
    cal_df = cal_df.with_columns(
        pl.Series("started_at", [c["started_at"] for c in cals], dtype=pl.Datetime("us", "UTC"))
    )
    ver_df = pl.DataFrame(
        {"calibration_id": [v["calibration_id"] for v in vers], "passed": [v["passed"] for v in vers]},
        schema={"calibration_id": pl.Utf8, "passed": pl.Boolean},
    )
    failed = failed_calibration_ids(ver_df)
    by_dev = {d["device_id"]: d for d in devices}
    for c in cals:
        by_dev.setdefault(
            c["device_id"],
            {
                "device_id": c["device_id"],
                "device_type": c["device_type"],
                "last_scan_night": None,
                "last_scan_at": None,
                "n_scans": 0,
            },
        )
    out = []
    for dev_id in sorted(by_dev):
        d = by_dev[dev_id]
        by_id = {c["calibration_id"]: c for c in cals if c["device_id"] == dev_id}
        order = order_calibrations(cal_df.filter(pl.col("device_id") == dev_id))["calibration_id"].to_list()
        if d["device_type"] == "rod":  # as the measure stage chooses: gauge calibrations, else the design
            cal_id, why = choose_rod_calibration(
                cal_df, failed, dev_id, as_of, validity_days, allow_unverified=False
            )
            gauge = [i for i in order if by_id[i]["method"] != "nominal"]
            order = gauge or order
        else:
            cal_id, why = choose_calibration(
                cal_df, failed, dev_id, as_of, validity_days, allow_unverified=False
            )
        latest = by_id[cal_id] if cal_id else by_id[order[-1]] if order else None
        state = (
            VALID
            if cal_id
            else NONE
            if latest is None
            else FAILED
            if latest["calibration_id"] in failed
            else EXPIRED
        )
        until = (
            (_dt.date.fromisoformat(latest["valid_from"]) + _dt.timedelta(days=validity_days)).isoformat()
            if latest
            else None
        )
        my_vers = [v for v in vers if v["device_id"] == dev_id]
        last_ver = my_vers[-1] if my_vers else None
        out.append(
            {
                "device_id": dev_id,
                "device_type": d["device_type"],
                "last_scan_night": _day(d["last_scan_night"]),
                "last_scan_at": utc_text(d["last_scan_at"])
                if isinstance(d["last_scan_at"], _dt.datetime)
                else None,
                "state": state,
                "reason": why,
                "calibration": None
                if latest is None
                else {
                    "calibration_id": latest["calibration_id"],
                    "method": latest["method"],
                    "valid_from": latest["valid_from"],
                    "valid_until": until,
                    "days_left": (_dt.date.fromisoformat(until) - _dt.date.fromisoformat(as_of)).days,
                    "certificate_path": latest["certificate_path"],
                    "channels": latest["n_channels"],
                },
                "last_verification": None
                if last_ver is None
                else {
                    "scan_id": last_ver["scan_id"],
                    "night": last_ver["night"],
                    "calibration_id": last_ver["calibration_id"],
                    "error_mm": last_ver["error_mm"],
                    "tolerance_mm": last_ver["tolerance_mm"],
                    "passed": last_ver["passed"],
                    "verdict": split_verdict(last_ver["conformity"])[0],
                },
            }
        )
    return out


def _mm(x) -> str:
    return "?" if x is None else f"{x:+.4f} mm"


def format_status(status: list[dict], as_of: str, validity_days: int, source: str) -> str:
    """Text of :func:`device_status`: a header, then a block per device."""
    lines = [f"status as of {as_of} (UTC); a calibration is valid for {validity_days} days ({source})"]
    if not status:
        lines.append(f"no device has a scan or a calibration on or before {as_of}")
    for d in status:
        seen = f"last scan {d['last_scan_at'] or d['last_scan_night'] or 'none'}"
        lines += ["", f"{d['device_id']} ({d['device_type'] or '?'})  {seen}"]
        c = d["calibration"]
        if c is None:
            lines.append(f"  calibration   none ({NONE.upper()})")
        else:
            left = c["days_left"]
            span = (
                f"valid until {c['valid_until']} ({left} days left)"
                if left >= 0
                else f"expired on {c['valid_until']} ({-left} days ago)"
            )
            lines.append(
                f"  calibration   {c['calibration_id']}  {c['method']}, from {c['valid_from']}, {span}  "
                f"{d['state'].upper()}"
            )
            if c["certificate_path"]:
                lines.append(f"  certificate   {c['certificate_path']}")
        if d["reason"] and d["state"] != VALID:
            lines.append(f"  measurements  refused: {d['reason']}")
        v = d["last_verification"]
        if v is None:
            lines.append("  verification  none")
        else:
            verdict = "passed" if v["passed"] else "FAILED"
            if v.get("verdict"):  # the statement under the decision rule
                verdict = v["verdict"] if v["verdict"] == "conforms" else v["verdict"].upper()
            note = (
                ""
                if c is None or v["calibration_id"] == c["calibration_id"]
                else f" (of {v['calibration_id']}; {c['calibration_id']} not verified yet)"
            )
            lines.append(
                f"  verification  {v['scan_id']} on {v['night']}: error {_mm(v['error_mm'])} "
                f"(tolerance {v['tolerance_mm']:g} mm) {verdict}{note}"
            )
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    """Print each device's calibration status as of a date; return the exit status."""
    as_of = args.as_of or _dt.datetime.now(_dt.timezone.utc).date().isoformat()
    validity_days, source = _validity_days(args)
    try:
        status = device_status(args.results, as_of, validity_days)
    except FileNotFoundError as err:
        raise CommandFailed(str(err)) from None
    if args.format == "json":
        print(json.dumps({"as_of": as_of, "validity_days": validity_days, "devices": status}, indent=2))
    else:
        sys.stdout.write(format_status(status, as_of, validity_days, source))
    if args.check and any(d["state"] != VALID for d in status):
        return 1
    return 0
