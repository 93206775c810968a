"""An independent reader of certificate.dcc.xml for the tests: xmlschema's decoder (against the
schema shipped with the package) into a dict, then the numbers by name, back in the units of
certificate.json (lengths in mm: the D-SI unit's power of the metre says by how much to scale).
Nothing here comes from the writer (borescan.certificate.dcc) but the schema's location.
"""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

import xmlschema

from borescan.certificate.dcc import schema_path


@lru_cache(maxsize=1)
def schema() -> xmlschema.XMLSchema:
    return xmlschema.XMLSchema(str(schema_path()))


def decode(path: Path) -> dict:
    """Return the DCC as a dict; raises xmlschema's validation error when it is not valid."""
    return schema().to_dict(str(path), validation="strict")


def metre_power(unit: str) -> int:
    m = re.search(r"\\metre(?:\\tothe\{(-?\d+)\})?", unit)
    return 0 if m is None else int(m.group(1) or 1)


def json_units(value: float, unit: str) -> float:
    """Return a D-SI value (SI units) in certificate.json's units (mm for lengths)."""
    return value * 10.0 ** (3 * metre_power(unit))


def same(read: float, printed: float) -> bool:
    """Return whether the read-back value equals the JSON's to its last printed digit (12 significant)."""
    return float(f"{read:.12g}") == float(printed)


def text(node) -> str:
    """Return the text of a dcc textType / richContentType (contents joined by newlines)."""
    if node is None:
        return ""
    contents = node.get("dcc:content", [])
    contents = contents if isinstance(contents, list) else [contents]
    return "\n".join(c.get("$", "") if isinstance(c, dict) else str(c) for c in contents)


def as_list(x) -> list:
    return [] if x is None else x if isinstance(x, list) else [x]


def real_value(real: dict) -> tuple[float, float | None, float | None, float | None]:
    """(value, U, k, p) of an si:real, value and U in certificate.json units."""
    unit = real["si:unit"]
    eu = real.get("si:expandedUnc")
    v = json_units(real["si:value"], unit)
    if eu is None:
        return v, None, None, None
    return v, json_units(eu["si:uncertainty"], unit), eu["si:coverageFactor"], eu["si:coverageProbability"]


def quantity_value(q: dict):
    """Return a dcc:quantity's content: a number or list of numbers, else its text.

    Numbers are in certificate.json units.
    """
    if "si:real" in q:
        return real_value(q["si:real"])[0]
    if "si:realListXMLList" in q:
        xl = q["si:realListXMLList"]
        units = as_list(xl["si:unitXMLList"])
        vals = as_list(xl["si:valueXMLList"])
        units = units * len(vals) if len(units) == 1 else units
        return [json_units(v, u) for v, u in zip(vals, units)]
    return text(q.get("dcc:noQuantity"))


def tree(node: dict) -> dict:
    """Return a dcc:list (or dcc:data) as {name: subtree or value}; a list of one quantity of its own name
    (how the writer keeps lists and quantities apart) read as that quantity.
    """
    out: dict = {}
    for q in as_list(node.get("dcc:quantity")):
        out[text(q.get("dcc:name"))] = quantity_value(q)
    for sub in as_list(node.get("dcc:list")):
        name = text(sub.get("dcc:name"))
        inner = tree(sub)
        out[name] = inner[name] if list(inner) == [name] and "dcc:list" not in sub else inner
    return out


def results(doc: dict) -> list[dict]:
    mr = doc["dcc:measurementResults"]["dcc:measurementResult"]
    return as_list(as_list(mr)[0]["dcc:results"]["dcc:result"])


def measurement_result(doc: dict) -> dict:
    return as_list(doc["dcc:measurementResults"]["dcc:measurementResult"])[0]


def beam_parameters(doc: dict) -> tuple[dict[str, tuple], dict[tuple[str, str], float]]:
    """Every parameter's (value, U, k, p) by label, and every covariance element by label pair, from
    the results' si:realList and si:ellipsoidalRegion (certificate.json units).
    """
    params: dict[str, tuple] = {}
    cov: dict[tuple[str, str], float] = {}
    for res in results(doc):
        q = res["dcc:data"].get("dcc:quantity")
        if not q or "si:list" not in as_list(q)[0]:
            continue
        rl = as_list(q)[0]["si:list"]["si:realList"]
        rl = as_list(rl)[0]
        labels = [r["si:label"] for r in as_list(rl["si:real"])]
        for r in as_list(rl["si:real"]):
            params[r["si:label"]] = real_value(r)
        reg = rl.get("si:ellipsoidalRegion")
        if reg:
            for a, col in enumerate(as_list(reg["si:covarianceMatrix"]["si:column"])):
                for b, c in enumerate(as_list(col["si:covariance"])):
                    cov[(labels[b], labels[a])] = json_units(c["si:value"], c["si:unit"])
    return params, cov
