"""The XML of a Digital Calibration Certificate: D-SI units and decimals, DCC element helpers.

Used by :mod:`borescan.certificate.dcc` and :mod:`borescan.certificate.dcc_results`.
A certificate.json unit (``mm``, ``rad``, ``degC``, ``1/K``,
...) becomes a D-SI unit and a decimal exponent (:func:`dsi_unit`); a number is written with the
JSON's digits, the unit prefix moved into the exponent (:func:`decimal_text`); a certificate.json
subtree becomes named ``dcc:list`` / ``dcc:quantity`` elements (:func:`record`).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Any

__all__ = [
    "NS_DCC",
    "NS_SI",
    "Unit",
    "d",
    "decimal_text",
    "dsi_unit",
    "expanded_unc",
    "is_num",
    "key_unit",
    "nested",
    "plain",
    "quantity",
    "real",
    "record",
    "s",
    "sub",
    "text",
]

NS_DCC = "https://ptb.de/dcc"
NS_SI = "https://ptb.de/si"
ET.register_namespace("dcc", NS_DCC)
ET.register_namespace("si", NS_SI)

#: unit of certificate.json -> (D-SI base units with powers, decimal exponent to SI)
_UNITS: dict[str, tuple[tuple[tuple[str, int], ...], int]] = {
    "mm": ((("metre", 1),), -3),
    "um": ((("metre", 1),), -6),
    "m": ((("metre", 1),), 0),
    "mm^2": ((("metre", 2),), -6),
    "rad": ((("radian", 1),), 0),
    "rad^2": ((("radian", 2),), 0),
    "degC": ((("degreecelsius", 1),), 0),
    "K": ((("kelvin", 1),), 0),
    "1/K": ((("kelvin", -1),), 0),
    "s": ((("second", 1),), 0),
    "rad/s": ((("radian", 1), ("second", -1)), 0),
    "-": ((), 0),
    "": ((), 0),
}


@dataclass(frozen=True)
class Unit:
    """A D-SI unit (``text``) and the decimal exponent that brings a value of certificate.json to it."""

    text: str
    shift: int


def dsi_unit(unit: str, per: str | None = None, times: str | None = None) -> Unit:
    r"""Return the D-SI unit of a certificate.json unit, of a ratio of units or of a product of units.

    ``mm`` -> ``\metre`` with shift -3; the ratio ``unit / per`` is a sensitivity coefficient, the product
    ``unit * times`` a covariance; base units in alphabetical order. An unknown unit raises ValueError naming
    it.
    """
    powers: dict[str, int] = {}
    shift = 0
    for u, sign in ((unit, 1), (per, -1), (times, 1)):
        if u is None:
            continue
        if u not in _UNITS:
            raise ValueError(
                f"certificate unit {u!r} has no D-SI form; known: {sorted(k for k in _UNITS if k)}"
            )
        parts, s = _UNITS[u]
        shift += sign * s
        for base, p in parts:
            powers[base] = powers.get(base, 0) + sign * p
    text = "".join(
        f"\\{b}" if p == 1 else f"\\{b}\\tothe{{{p}}}" for b, p in sorted(powers.items()) if p != 0
    )
    return Unit(text or "\\one", shift)


def key_unit(key: str) -> str:
    """Return the unit a certificate.json key names by its suffix.

    The suffixes are ``_mm``, ``_rad``, ``_c``, ``_per_k``, ...
    """
    tokens = key.lower().split("_")
    if key.endswith("_rad_s"):
        return "rad/s"
    if "per" in tokens and tokens[-1] == "k":
        return "1/K"
    for tok, unit in (("mm", "mm"), ("um", "um"), ("rad", "rad")):
        if tok in tokens:
            return unit
    if len(tokens) > 1 and tokens[-1] == "c":
        return "degC"
    if len(tokens) > 1 and tokens[-1] == "s":
        return "s"
    return "-"


def decimal_text(x: float, shift: int = 0) -> str:
    """Return ``x`` as printed by certificate.json, times 10**shift by moving the exponent.

    Printed as the shortest repr of its 12-digit float: the D-SI decimal carries exactly the JSON's digits.
    """
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise TypeError(f"not a number: {x!r}")
    if isinstance(x, float) and not math.isfinite(x):
        raise ValueError(f"not a finite number: {x!r}")
    s = str(int(x)) if isinstance(x, int) else repr(float(x))
    if shift == 0:
        return s
    mant, _, exp = s.partition("e")
    return f"{mant}e{(int(exp) if exp else 0) + shift}"


# --------------------------------------------------------------------------- element helpers


def d(tag: str) -> str:
    """Return ``tag`` qualified by the DCC namespace."""
    return f"{{{NS_DCC}}}{tag}"


def s(tag: str) -> str:
    """Return ``tag`` qualified by the D-SI namespace."""
    return f"{{{NS_SI}}}{tag}"


def sub(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    """Append a ``tag`` element to ``parent`` with ``text`` and the attributes that are not None."""
    el = ET.SubElement(parent, tag, {k.replace("_", ""): v for k, v in attrib.items() if v is not None})
    if text is not None:
        el.text = text
    return el


def text(parent: ET.Element, tag: str, *contents: str, ref_type: str | None = None) -> ET.Element:
    """Return a DCC ``textType`` / ``richContentType`` element with one ``content`` (lang en) per text."""
    el = sub(parent, d(tag), refType=ref_type) if ref_type else sub(parent, d(tag))
    for c in contents or ("",):
        sub(el, d("content"), str(c), lang="en")
    return el


def is_num(x: Any) -> bool:
    """Return whether ``x`` is a finite int or float (a bool is not a number)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def expanded_unc(parent: ET.Element, eu: dict, unit: Unit) -> None:
    """``si:expandedUnc`` of a certificate.json ``expandedUnc`` (U in the value's unit)."""
    if not all(is_num(eu.get(k)) for k in ("uncertainty", "coverageFactor", "coverageProbability")):
        return
    el = sub(parent, s("expandedUnc"))
    sub(el, s("uncertainty"), decimal_text(eu["uncertainty"], unit.shift))
    sub(el, s("coverageFactor"), decimal_text(eu["coverageFactor"]))
    sub(el, s("coverageProbability"), decimal_text(eu["coverageProbability"]))
    sub(el, s("distribution"), str(eu.get("distribution") or "normal"))


def real(
    parent: ET.Element,
    tag: str,
    value: float,
    unit: Unit,
    label: str | None = None,
    expanded: dict | None = None,
) -> ET.Element:
    """Append an ``si:real`` (label, value in ``unit``, optional expanded uncertainty) to ``parent``."""
    el = sub(parent, tag)
    if label is not None:
        sub(el, s("label"), label)
    sub(el, s("value"), decimal_text(value, unit.shift))
    sub(el, s("unit"), unit.text)
    if expanded:
        expanded_unc(el, expanded, unit)
    return el


def quantity(
    parent: ET.Element,
    name: str,
    value: Any,
    unit: Unit | None = None,
    *,
    ref_type: str | None = None,
    expanded: dict | None = None,
) -> ET.Element:
    """Return a ``dcc:quantity`` named ``name`` for a number, a list of numbers or anything else.

    A number as ``si:real`` (in ``unit``, default by the name's suffix), a list of numbers as
    ``si:realListXMLList``, anything else as ``dcc:noQuantity`` text.
    """
    q = sub(parent, d("quantity"), refType=ref_type)
    text(q, "name", name)
    if is_num(value):
        real(q, s("real"), value, unit or dsi_unit(key_unit(name)), expanded=expanded)
    elif isinstance(value, list) and value and all(is_num(v) for v in value):
        u = unit or dsi_unit(key_unit(name))
        xl = sub(q, s("realListXMLList"))
        sub(xl, s("valueXMLList"), " ".join(decimal_text(v, u.shift) for v in value))
        sub(xl, s("unitXMLList"), u.text)
    else:
        text(q, "noQuantity", plain(value))
    return q


def plain(value: Any) -> str:
    """Return ``value`` as the plain text of a ``dcc:noQuantity`` (null, true/false, a list comma-joined)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return "[]" if not value else ", ".join(plain(v) for v in value)
    return str(value)


def nested(value: Any) -> bool:
    """Whether ``value`` becomes a ``dcc:list`` (a non-empty dict, or a list holding dicts or lists)."""
    return (isinstance(value, dict) and bool(value)) or (
        isinstance(value, list) and bool(value) and any(isinstance(v, (dict, list)) for v in value)
    )


def record(parent: ET.Element, name: str, value: Any, unit_of=None, wrap: bool = False) -> None:
    """Return ``value`` (a certificate.json subtree) as nested ``dcc:list`` / ``dcc:quantity``.

    Named by its keys (list items ``name[i]``), numbers with the unit their key names (``unit_of(key)``
    overrides). A ``dcc:list`` holds lists or quantities, not both: with ``wrap`` a scalar becomes a list of
    one.
    """
    if nested(value):
        items = (
            sorted(value.items())
            if isinstance(value, dict)
            else [(f"{name}[{i}]", v) for i, v in enumerate(value)]
        )
        lst = sub(parent, d("list"))
        text(lst, "name", name)
        mixed = any(nested(v) for _, v in items)
        for k, v in items:
            record(lst, str(k), v, unit_of, wrap=mixed)
        return
    if wrap:
        parent = sub(parent, d("list"))
        text(parent, "name", name)
    quantity(parent, name, value, unit_of(name) if unit_of else None)
