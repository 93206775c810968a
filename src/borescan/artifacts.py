"""Certified artifacts (ring gauges, parts) of a scan's ``scan.json``: size at temperature, catalog row.

A gauge is certified at 20 degC; at the scan's temperature its radius is the certified one
expanded by the ``thermal_expansion`` effect of :mod:`borescan.effects` (the one place that
formula lives), so the calibration and the digital twin see the same gauge.
"""

from __future__ import annotations

from borescan.effects import EFFECTS
from borescan.geometry import Bore

__all__ = ["radius_at_temperature_mm", "gauge_radius_mm", "artifact_row"]

#: temperature at which artifacts are certified [degC]
REFERENCE_TEMPERATURE_C = 20.0


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
    bore = expand(Bore((0.0, 0.0), float(radius_20_mm)), {"temperature_c": float(temperature_c)}, float(cte_per_k))
    return bore.radius_mm


def gauge_radius_mm(meta: dict) -> float:
    """Radius of a scan's ring gauge at the scan's temperature [mm].

    From ``artifact.certified_diameter_mm`` (else ``nominal_diameter_mm``), ``artifact.cte_per_k``
    (default 0) and ``environment.temperature_c`` (default 20 degC) of ``scan.json``.

    Raises
    ------
    ValueError
        The artifact has neither diameter.
    """
    art = meta.get("artifact") or {}
    d20 = art.get("certified_diameter_mm", art.get("nominal_diameter_mm"))
    if d20 is None:
        raise ValueError("artifact has neither certified_diameter_mm nor nominal_diameter_mm")
    temp = (meta.get("environment") or {}).get("temperature_c", REFERENCE_TEMPERATURE_C)
    return radius_at_temperature_mm(0.5 * float(d20), float(art.get("cte_per_k", 0.0)), float(temp))


def artifact_row(meta: dict) -> dict | None:
    """The ``artifacts`` row of a scan's artifact; None when it has no id."""
    art = meta.get("artifact") or {}
    if not art.get("id"):
        return None
    return {"artifact_id": art["id"], "type": art.get("type"), "certificate": art.get("certificate"),
            "nominal_diameter_mm": art.get("nominal_diameter_mm"), "certified_diameter_mm": art.get("certified_diameter_mm"),
            "u_diameter_mm": art.get("u_diameter_mm"), "k": art.get("k"), "cte_per_k": art.get("cte_per_k")}
