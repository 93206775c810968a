"""Certified artifacts (ring gauges, parts) of a scan's ``scan.json``.

Certified artifacts (ring gauges, parts) of a scan's ``scan.json``: temperature, size at temperature,
catalog row.

A gauge is certified at 20 degC (ISO 1, the reference temperature of dimensional
specifications); at the scan's temperature its radius is the certified one expanded by the
``thermal_expansion`` effect of :mod:`borescan.effects` (the one place that formula lives), so
the calibration and the digital twin see the same gauge. A diameter measured at temperature T
is brought to 20 degC by the inverse, D20 = D_T / (1 + alpha (T - 20)) (:func:`diameter_at_20`).

Temperature is never silent (:func:`scan_temperature`): a scan without
``environment.temperature_c`` is either refused or taken as "assumed 20 degC" with a larger
stated uncertainty and a flag, as the ``uncertainty`` section of the config says. Likewise an
artifact without ``cte_per_k`` gets the config's assumed expansion coefficient with its wide
bound and a flag (:func:`artifact_cte`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

from borescan.effects import EFFECTS, REFERENCE_TEMPERATURE_C, thermal_expansion_factor
from borescan.geometry import Bore
from borescan.uncertainty import Input

__all__ = [
    "REFERENCE_TEMPERATURE_C",
    "MissingTemperature",
    "ScanTemperature",
    "ArtifactCte",
    "scan_temperature",
    "artifact_cte",
    "artifact_key",
    "radius_at_temperature_mm",
    "gauge_radius_mm",
    "diameter_at_20",
    "artifact_row",
]

#: temperature at which artifacts are certified and results reported [degC] (ISO 1)
#: ``uncertainty.missing_temperature`` values
MISSING_TEMPERATURE = ("refuse", "assume_20c")


class MissingTemperature(ValueError):
    """A scan has no ``environment.temperature_c`` and the config refuses such scans."""


@dataclass(frozen=True)
class ScanTemperature:
    """The temperature a scan's results refer to.

    temperature_c : value [degC]; halfwidth_c : stated bound, rectangular [K];
    u_c : standard uncertainty halfwidth / sqrt 3 [K] (GUM 4.3.7); assumed : True when scan.json
    gives none and 20 degC was assumed; source : where value and bound come from (text).
    """

    temperature_c: float
    halfwidth_c: float
    u_c: float
    assumed: bool
    source: str

    def budget_input(self, key: str, quantity: str) -> Input:
        """Return this temperature as a GUM input (T, degC, rectangular) of a budget."""
        return Input(
            key, quantity, "T", "degC", self.temperature_c, self.u_c, "rectangular", source=self.source
        )


@dataclass(frozen=True)
class ArtifactCte:
    """An artifact's linear expansion coefficient with its uncertainty and source.

    An artifact's linear expansion coefficient alpha [1/K], its stated bound (rectangular
    half-width) and standard uncertainty [1/K], whether it was assumed, and the source.
    """

    cte_per_k: float
    halfwidth_per_k: float
    u_per_k: float
    assumed: bool
    source: str

    def budget_input(self, key: str, quantity: str) -> Input:
        """Return this coefficient as a GUM input (alpha, 1/K, rectangular) of a budget."""
        return Input(
            key, quantity, "alpha", "1/K", self.cte_per_k, self.u_per_k, "rectangular", source=self.source
        )


def scan_temperature(meta: dict, unc_cfg: dict) -> ScanTemperature:
    """Return the temperature of a scan with its uncertainty, by the config's policy.

    Parameters
    ----------
    meta : scan.json
    unc_cfg : the config's ``uncertainty`` section: ``temperature_accuracy_c`` (half-width of the
        thermometer's error [K]), ``missing_temperature`` (``"refuse"`` or ``"assume_20c"``),
        ``assumed_temperature_accuracy_c`` (half-width when 20 degC is assumed [K])

    Raises
    ------
    MissingTemperature
        ``environment.temperature_c`` is absent and ``missing_temperature`` is ``"refuse"``.
    """
    policy = unc_cfg["missing_temperature"]
    if policy not in MISSING_TEMPERATURE:
        raise ValueError(
            f"uncertainty.missing_temperature must be one of {MISSING_TEMPERATURE}, got {policy!r}"
        )
    value = (meta.get("environment") or {}).get("temperature_c")
    if value is not None:
        a = float(unc_cfg["temperature_accuracy_c"])
        return ScanTemperature(
            float(value),
            a,
            a / math.sqrt(3.0),
            False,
            f"scan.json environment.temperature_c; thermometer within +-{a:g} K "
            "(uncertainty.temperature_accuracy_c, rectangular)",
        )
    if policy == "refuse":
        raise MissingTemperature(
            f"{meta.get('scan_id', '<scan>')}: scan.json has no environment.temperature_c and "
            "uncertainty.missing_temperature is 'refuse' (set it to 'assume_20c' to accept such scans "
            "with the assumed temperature's uncertainty)"
        )
    a = float(unc_cfg["assumed_temperature_accuracy_c"])
    return ScanTemperature(
        REFERENCE_TEMPERATURE_C,
        a,
        a / math.sqrt(3.0),
        True,
        f"ASSUMED 20 degC: scan.json has no environment.temperature_c; taken within +-{a:g} K "
        "(uncertainty.assumed_temperature_accuracy_c, rectangular)",
    )


def artifact_cte(meta: dict, unc_cfg: dict) -> ArtifactCte:
    """Return the expansion coefficient of a scan's artifact with its uncertainty.

    ``artifact.cte_per_k`` of scan.json within +-``uncertainty.cte_accuracy_per_k``; without it,
    ``uncertainty.assumed_cte_per_k`` within +-``uncertainty.assumed_cte_accuracy_per_k`` (flagged).
    Both rectangular.
    """
    art = meta.get("artifact") or {}
    if art.get("cte_per_k") is not None:
        a = float(unc_cfg["cte_accuracy_per_k"])
        return ArtifactCte(
            float(art["cte_per_k"]),
            a,
            a / math.sqrt(3.0),
            False,
            f"scan.json artifact.cte_per_k, within +-{a:g} /K (uncertainty.cte_accuracy_per_k)",
        )
    a = float(unc_cfg["assumed_cte_accuracy_per_k"])
    v = float(unc_cfg["assumed_cte_per_k"])
    return ArtifactCte(
        v,
        a,
        a / math.sqrt(3.0),
        True,
        f"ASSUMED {v:g} /K within +-{a:g} /K: scan.json artifact has no cte_per_k "
        "(uncertainty.assumed_cte_per_k, assumed_cte_accuracy_per_k)",
    )


def artifact_key(art: dict | None) -> str:
    """Return the identity of a scan.json ``artifact`` for an uncertainty budget.

    Identity of a scan.json ``artifact`` for an uncertainty budget: ``<id>`` plus ``@<certificate>``
    if any (the same gauge under the same certificate is one physical quantity).
    """
    art = art or {}
    return f"{art.get('id')}" + (f"@{art['certificate']}" if art.get("certificate") else "")


def radius_at_temperature_mm(radius_20_mm: float, cte_per_k: float, temperature_c: float) -> float:
    """Radius of a bore certified at 20 degC, at ``temperature_c``: R = R20 (1 + cte (T - 20)).

    Parameters
    ----------
    radius_20_mm : radius at 20 degC [mm].
    cte_per_k : linear expansion coefficient of the artifact [1/K].
    temperature_c : temperature of the scan [degC].

    Returns
    -------
    float : the radius [mm], from the ``thermal_expansion`` effect's forward function.
    """
    expand = EFFECTS["thermal_expansion"].forward["tri_lds"]
    bore = expand(
        Bore((0.0, 0.0), float(radius_20_mm)), {"temperature_c": float(temperature_c)}, float(cte_per_k)
    )
    return bore.radius_mm


def gauge_radius_mm(meta: dict, temperature_c: float | None = None, cte_per_k: float | None = None) -> float:
    """Radius of a scan's ring gauge at the scan's temperature [mm].

    From ``artifact.certified_diameter_mm`` (else ``nominal_diameter_mm``) of ``scan.json``, at
    ``temperature_c`` with ``cte_per_k`` when given (the pipeline passes the values of
    :func:`scan_temperature` and :func:`artifact_cte`, which never default silently). Called
    without them, this bare helper reads ``environment.temperature_c`` (20 degC when absent) and
    ``artifact.cte_per_k`` (0 when absent); evaluation code that only needs the simulated gauge
    uses that.

    Raises
    ------
    ValueError
        The artifact has neither diameter.
    """
    art = meta.get("artifact") or {}
    d20 = art.get("certified_diameter_mm", art.get("nominal_diameter_mm"))
    if d20 is None:
        raise ValueError("artifact has neither certified_diameter_mm nor nominal_diameter_mm")
    if temperature_c is None:
        temperature_c = (meta.get("environment") or {}).get("temperature_c", REFERENCE_TEMPERATURE_C)
    if cte_per_k is None:
        cte_per_k = art.get("cte_per_k", 0.0)
    return radius_at_temperature_mm(0.5 * float(d20), float(cte_per_k or 0.0), float(temperature_c))


def diameter_at_20(
    diameter_mm: float, cte_per_k: float, temperature_c: float
) -> tuple[float, float, float, float]:
    """Return a diameter measured at ``temperature_c`` brought to 20 degC, with its first derivatives.

    D20 = D_T / (1 + alpha (T - 20)) (the inverse of :func:`radius_at_temperature_mm`).

    Returns
    -------
    (D20 [mm], dD20/dD_T [-], dD20/dT [mm/K], dD20/dalpha [mm K])
    """
    dT = float(temperature_c) - REFERENCE_TEMPERATURE_C
    f = thermal_expansion_factor(float(cte_per_k), float(temperature_c))
    d20 = float(diameter_mm) / f
    return d20, 1.0 / f, -float(diameter_mm) * float(cte_per_k) / f**2, -float(diameter_mm) * dT / f**2


def artifact_row(meta: dict) -> dict | None:
    """Return the ``artifacts`` row of a scan's artifact; None when it has no id."""
    art = meta.get("artifact") or {}
    if not art.get("id"):
        return None
    return {
        "artifact_id": art["id"],
        "type": art.get("type"),
        "certificate": art.get("certificate"),
        "nominal_diameter_mm": art.get("nominal_diameter_mm"),
        "certified_diameter_mm": art.get("certified_diameter_mm"),
        "u_diameter_mm": art.get("u_diameter_mm"),
        "k": art.get("k"),
        "cte_per_k": art.get("cte_per_k"),
    }


def number_or_none(v) -> float | None:
    """Return a scan.json number as float, or None.

    Return a scan.json number as float; None for a missing value or anything that is not a number (a bool
    is
    not).
    """
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def certificate_fields(meta: dict) -> dict:
    """Return the artifact certificate a scan's ``scan.json`` states.

    Return the artifact certificate a scan's ``scan.json`` states, as the ``scans`` table keeps it:
    ``artifact_certificate``, ``artifact_certified_diameter_mm``, ``artifact_u_diameter_mm`` (None where
    absent).
    """
    art = meta.get("artifact") if isinstance(meta.get("artifact"), dict) else {}
    cert = art.get("certificate")
    feats = {
        str(f.get("id")): number_or_none(f.get("certified_diameter_mm"))
        for f in (art.get("features") or [])
        if isinstance(f, dict) and f.get("id") is not None
    }
    feats = {k: v for k, v in sorted(feats.items()) if v is not None}
    return {
        "artifact_certificate": None if cert is None else str(cert),
        "artifact_certified_diameter_mm": number_or_none(art.get("certified_diameter_mm")),
        "artifact_u_diameter_mm": number_or_none(art.get("u_diameter_mm")),
        # a gauge set (a rod's rings): each feature's certified diameter, {feature: D20} as JSON
        "artifact_features_certified": json.dumps(feats, sort_keys=True) if feats else None,
    }


#: Two certified values of one certificate that differ by more than this are a conflict [mm].
CONFLICT_TOLERANCE_MM = 1e-9


def certificate_conflicts(earlier: list[dict], tonight: list[dict]) -> dict[str, str]:
    """Return scans whose artifact certificate contradicts an earlier record of the same certificate.

    A certificate (``artifact_id``, ``artifact_certificate``) states one certified diameter and
    one uncertainty for ever: a recertified gauge gets a new certificate id, and a scan that
    gives another value under a known certificate id is a typo or a mix-up that would rewrite
    history. The first record of a certificate (earlier nights first, then the night's scans in
    ``started_at``, ``scan_id`` order) is its value; every later scan that contradicts it is
    returned with the reason, both values and the scan that recorded the first one named.

    Parameters
    ----------
    earlier : ``scans`` rows of earlier nights (only ``ok`` rows are taken as records)
    tonight : the night's ``scans`` rows (``ok`` ones are checked)

    Rows carry ``scan_id``, ``night``, ``status``, ``artifact_id``, ``artifact_certificate``,
    ``artifact_certified_diameter_mm``, ``artifact_u_diameter_mm``; rows without a certificate
    id or a certified diameter are not checked.

    Returns
    -------
    {scan_id: reason} of the scans to set aside.
    """
    first: dict[tuple[str, str], dict] = {}

    def key(r):
        if (
            r.get("status") != "ok"
            or not r.get("artifact_id")
            or not r.get("artifact_certificate")
            or (r.get("artifact_certified_diameter_mm") is None and not r.get("artifact_features_certified"))
        ):
            return None
        return str(r["artifact_id"]), str(r["artifact_certificate"])

    for r in sorted(
        earlier, key=lambda r: (str(r.get("night")), str(r.get("started_at") or ""), str(r["scan_id"]))
    ):
        k = key(r)
        if k is not None:
            first.setdefault(k, r)
    out: dict[str, str] = {}
    for r in sorted(tonight, key=lambda r: (str(r.get("started_at") or ""), str(r["scan_id"]))):
        k = key(r)
        if k is None:
            continue
        f = first.setdefault(k, r)
        if f is r:
            continue
        diffs = [
            f"{name} {r.get(col)!r} here, {f.get(col)!r} in scan {f['scan_id']} (night {f.get('night')})"
            for col, name in (
                ("artifact_certified_diameter_mm", "certified_diameter_mm"),
                ("artifact_u_diameter_mm", "u_diameter_mm"),
            )
            if _differ(r.get(col), f.get(col))
        ]
        mine, theirs = _features(r), _features(f)
        diffs += [
            f"feature {feat} certified_diameter_mm {mine[feat]!r} here, {theirs[feat]!r} in scan "
            f"{f['scan_id']} "
            f"(night {f.get('night')})"
            for feat in sorted(set(mine) & set(theirs))
            if _differ(mine[feat], theirs[feat])
        ]
        if diffs:
            out[str(r["scan_id"])] = (
                f"artifact {k[0]}, certificate {k[1]}: "
                + "; ".join(diffs)
                + ". One certificate states one value: a recertified gauge needs its new "
                "certificate id in scan.json; correct the scan under a new scan id"
            )
    return out


def _features(r: dict) -> dict[str, float]:
    """{feature: certified D20} a scans row keeps for a gauge set ({} for none)."""
    text = r.get("artifact_features_certified")
    try:
        return {str(k): float(v) for k, v in json.loads(text).items()} if text else {}
    except (ValueError, TypeError, AttributeError):
        return {}


def _differ(a, b) -> bool:
    if a is None or b is None:
        return (a is None) != (b is None)
    return abs(float(a) - float(b)) > CONFLICT_TOLERANCE_MM
