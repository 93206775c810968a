"""Numbers and words for people: quantities with their units, HTML cells, verdict cells."""

from __future__ import annotations

import base64
import html
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from borescan.decision import CANNOT_DECIDE, CONFORMS, DOES_NOT_CONFORM, split_verdict
from borescan.effects import EFFECTS

#: Display units: SI unit -> (smaller unit, factor) used when the value is small.
_SMALLER = {"mm": ("µm", 1e3), "s": ("ms", 1e3), "rad": ("mrad", 1e3), "mm/s": ("µm/s", 1e3)}


def format_quantity(value: float | None, u: float | None = None, unit: str = "") -> str:
    """Return a value with its uncertainty for people: ``1.200 ± 0.030 ms``.

    The uncertainty is rounded to two significant digits and the value to the same decimal
    place (GUM 7.2.6); without an uncertainty the value keeps four significant digits. Values
    below 0.1 of a unit in :data:`_SMALLER` are shown in the smaller unit (mm -> µm, s -> ms
    (and µs), rad -> mrad). Dimensionless (``"-"``) values carry no unit. "" for a missing value.
    """
    if value is None or not np.isfinite(value):
        return ""
    v = float(value)
    uu = float(u) if u is not None and np.isfinite(u) and u > 0 else None
    unit = "" if unit in ("-", None) else unit
    big = max(abs(v), uu or 0.0)
    if unit in _SMALLER and big < 0.1:
        unit, f = _SMALLER[unit]
        v, uu = v * f, (uu * f if uu else None)
        if unit == "ms" and max(abs(v), uu or 0.0) < 0.1:
            unit, v, uu = "µs", v * 1e3, (uu * 1e3 if uu else None)
    tail = f" {unit}" if unit else ""
    if uu is None:
        return f"{_significant(v, 4)}{tail}"
    dec = max(0, 1 - int(math.floor(math.log10(uu))))
    return f"{v:.{dec}f} ± {uu:.{dec}f}{tail}"


def _significant(v: float, digits: int) -> str:
    """Return ``v`` with ``digits`` significant digits in positional notation (never ``1.67e+03``)."""
    if v == 0.0:
        return "0"
    dec = max(0, digits - 1 - int(math.floor(math.log10(abs(v)))))
    return f"{round(v, dec):.{dec}f}"


def _mm(v_mm: Any, decimals: int = 4) -> str:
    """Return a length in mm with ``decimals`` decimals (4: to 0.1 µm; "" when missing)."""
    if v_mm is None or not np.isfinite(float(v_mm)):
        return ""
    return f"{float(v_mm):.{decimals}f}"


def _e(v: Any) -> str:
    return html.escape("" if v is None else str(v))


def _num(v: Any, digits: int = 6) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return ""
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def _um(v_mm: Any, decimals: int = 1) -> str:
    """Return a length in mm shown in µm with ``decimals`` decimals ("" when missing)."""
    if v_mm is None or not np.isfinite(float(v_mm)):
        return ""
    return f"{float(v_mm) * 1e3:.{decimals}f}"


def _temperature(t_c: Any, assumed: Any) -> str:
    """Return a temperature cell; an assumed one says so ("20 (assumed)")."""
    if assumed:
        base = "20" if t_c is None else _num(t_c, 4)
        return f'<span class="warn" title="no temperature recorded: 20 °C assumed">{base} (assumed)</span>'
    return _num(t_c, 4)


def _link(href: str | None, text: str) -> str:
    if not href:
        return _e(text)
    return f'<a href="{html.escape(href, quote=True)}">{_e(text)}</a>'


def _table(
    headers: list[str],
    rows: list[list[str]],
    row_classes: list[str] | None = None,
    num_cols: set[int] | None = None,
) -> str:
    """Return an HTML table; cells are already-escaped HTML."""
    num_cols = num_cols or set()
    out = ["<table><thead><tr>", *(f"<th>{_e(h)}</th>" for h in headers), "</tr></thead><tbody>"]
    for i, r in enumerate(rows):
        cls = f' class="{row_classes[i]}"' if row_classes and row_classes[i] else ""
        cells = "".join(
            f'<td class="num">{c}</td>' if j in num_cols else f"<td>{c}</td>" for j, c in enumerate(r)
        )
        out.append(f"<tr{cls}>{cells}</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _img(href: str, png: bytes | str, alt: str) -> str:
    """Return a PNG embedded as a base64 ``data:`` image (the page stands alone), linked to its file.

    ``png``: the PNG's bytes, or already its base64 text.
    """
    data = png if isinstance(png, str) else base64.b64encode(png).decode("ascii")
    return (
        f'<a class="plot" href="{html.escape(href, quote=True)}">'
        f'<img src="data:image/png;base64,{data}" alt="{_e(alt)}"></a>'
    )


def _rel(results_root: Path, path: str | None) -> str | None:
    """Return a relative link to ``path`` (relative to results_root, or absolute inside it) if it exists."""
    if not path:
        return None
    if not os.path.isabs(path) and ".." not in path and "\\" not in path:  # the usual case, without pathlib
        return path if os.path.exists(os.path.join(results_root, path)) else None
    p = Path(path)
    full = p if p.is_absolute() else results_root / p
    if not full.exists():
        return None
    try:
        return full.resolve().relative_to(results_root.resolve()).as_posix()
    except ValueError:
        return None


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def _verdict_is(verdict: str) -> pl.Expr:
    """Return the rows whose ``conformity`` statement starts with ``verdict``.

    The statement is split by :func:`borescan.decision.split_verdict`.
    """
    return pl.col("conformity").fill_null("").str.to_lowercase().str.starts_with(verdict)


def _verdict_cell(
    conformity: str | None, passed: bool | None, labels: tuple[str, str] = ("passed", "FAILED")
) -> tuple[str, str]:
    """Return (HTML, row class) of a verdict.

    The stage's statement under the decision rule (``conformity``: "conforms", "does not conform" or "cannot
    decide", then U, T, the rule and its guard band); a row without one (an older catalog) falls back to its
    pass/fail, shown as ``labels``.
    """
    verdict, detail = split_verdict(conformity)
    if verdict is None:
        if passed is None:
            return "", ""
        return (
            (f'<span class="pass">{labels[0]}</span>', "")
            if passed
            else (f'<span class="fail">{labels[1]}</span>', "fail")
        )
    cls = {CONFORMS: "pass", DOES_NOT_CONFORM: "fail", CANNOT_DECIDE: "warn"}[verdict]
    html = f'<span class="{cls}">{_e(verdict.upper() if cls != "pass" else verdict)}</span>'
    return html + (f"<br><small>{_e(detail)}</small>" if detail else ""), ("" if cls == "pass" else cls)


def _uncertainties(u: Any) -> dict[str, float]:
    """Return a finding's uncertainties as {parameter: u}.

    Return a finding's uncertainties (a dict, or its JSON text) as {parameter: u}: ``u_`` prefixes dropped,
    non-numbers left out; {} for nothing readable.
    """
    if isinstance(u, str):
        try:
            u = json.loads(u)
        except ValueError:
            return {}
    if not isinstance(u, dict):
        return {}
    return {k.removeprefix("u_"): v for k, v in u.items() if isinstance(v, int | float)}


def _parameters_text(effect: str, parameters: str | None, u: dict[str, float]) -> str:
    """Return a finding's parameters in words.

    Return a finding's parameters (JSON text of the findings table) in words:
    ``tau = 1.200 ± 0.030 ms``: a name's unit suffix (``tau_s``) is left out, the unit shown is the
    value's (which may be a smaller one, ms for s).
    """
    if not parameters:
        return ""
    try:
        values = json.loads(parameters)
    except ValueError:
        return _e(parameters)
    if not isinstance(values, dict):
        return _e(parameters)
    units = dict(getattr(EFFECTS.get(effect), "params", {}) or {})
    out = []
    for name, v in sorted(values.items()):
        if isinstance(v, int) and not isinstance(v, bool):  # a count or an order (k = 2), not a measurement
            out.append(f"{_e(_without_unit(name))} = {v}")
        elif isinstance(v, float):
            unit = units.get(name) or _unit_of(name)
            shown = _without_unit(name)
            out.append(f"{_e(shown)} = {_e(format_quantity(float(v), u.get(name), unit))}")
        elif isinstance(v, dict):  # per-scan values (pooled findings): how many, not all of them
            out.append(f"{_e(name)}: {len(v)} values")
        else:
            out.append(f"{_e(name)} = {_e(v)}")
    return "; ".join(out)


#: Unit suffixes of parameter names and their units.
_UNIT_SUFFIXES = (
    ("_mm_per_s", "mm/s"),
    ("_mm", "mm"),
    ("_s", "s"),
    ("_rad", "rad"),
    ("_hz", "Hz"),
    ("_c", "°C"),
)


def _without_unit(name: str) -> str:
    """Return a parameter's name without its unit suffix (``b_mm`` -> ``b``), the name when it has none."""
    for suffix, _unit in _UNIT_SUFFIXES:
        if name.endswith(suffix) and len(name) > len(suffix):
            return name[: -len(suffix)]
    return name


def _unit_of(name: str) -> str:
    """Return the unit a parameter's name ends in (``_mm``, ``_s``, ``_rad``, ``_hz``), "-" otherwise."""
    for suffix, unit in _UNIT_SUFFIXES:
        if name.endswith(suffix):
            return unit
    return "-"
