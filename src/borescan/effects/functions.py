"""The forward function of each named effect, and the fit parameterisations that differ from the spec's.

The registry (:data:`borescan.effects.EFFECTS`) names them; each is pure. The thermal factor 1 + cte (T - 20)
(:func:`thermal_expansion_factor`) is written here once.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from borescan.geometry import Bore, RodLayer

__all__ = ["REFERENCE_TEMPERATURE_C", "thermal_expansion_factor", "nonlinearity_bow"]


# --------------------------------------------------------------------------- forward functions


def channel_delay(t_s: np.ndarray, p: Mapping) -> np.ndarray:
    """Channel c at time t shows the reading of time t - tau: t' = t - tau."""
    return np.asarray(t_s, dtype=float) - p["tau_s"]


def speed_error(x_rad: np.ndarray, p: Mapping) -> np.ndarray:
    """Turn the spindle at (1 + eps) times the commanded profile.

    Spindle turns at (1 + eps) times the commanded profile: x' = (1 + eps) x, x = Phi(t) the commanded
    angle.
    """
    return np.asarray(x_rad, dtype=float) * (1.0 + p["eps"])


def speed_ripple(x_rad: np.ndarray, p: Mapping) -> np.ndarray:
    """phi(t) = omega t + a sin(omega t + phase): x' = x + a sin(x + phase)."""
    x = np.asarray(x_rad, dtype=float)
    return x + p["a_rad"] * np.sin(x + p["phase"])


def spindle_error_motion(S_xy_mm: np.ndarray, phi_rad: np.ndarray, p: Mapping) -> np.ndarray:
    """S(phi) = S0 + rho (cos(k phi + phase), sin(k phi + phase)), k >= 2."""
    if p["k"] < 2:
        raise ValueError(f"spindle_error_motion needs k >= 2, got {p['k']}")
    arg = p["k"] * np.asarray(phi_rad, dtype=float) + p["phase"]
    return np.asarray(S_xy_mm, dtype=float) + p["rho_mm"] * np.stack([np.cos(arg), np.sin(arg)], axis=-1)


#: The reference temperature of dimensional measurements (ISO 1) [degC].
REFERENCE_TEMPERATURE_C = 20.0


def thermal_expansion_factor(cte_per_k, temperature_c):
    """Return f = 1 + cte (T - 20), the factor of a length certified at 20 degC at temperature T.

    A length certified at 20 degC is f times itself at T (ISO 1); the one place of this formula (the
    ``thermal_expansion`` effect, a gauge at its temperature, a diameter brought to 20 degC, the budgets'
    sensitivities).

    Parameters
    ----------
    cte_per_k : linear expansion coefficient [1/K]; temperature_c : temperature [degC] (arrays broadcast).

    Returns
    -------
    f [-]
    """
    return 1.0 + cte_per_k * (temperature_c - REFERENCE_TEMPERATURE_C)


def thermal_expansion(bore: Bore, p: Mapping, cte_per_k: float) -> Bore:
    """R = R20 (1 + cte (T - 20)) (:func:`thermal_expansion_factor`)."""
    return replace(bore, radius_mm=bore.radius_mm * thermal_expansion_factor(cte_per_k, p["temperature_c"]))


def axis_tilt(bore: Bore, p: Mapping, cte_per_k: float = 0.0) -> Bore:
    """Ellipse with semi-axes R / cos(beta) along ``azimuth`` and R across."""
    if bore.tilt_rad != 0.0:
        raise ValueError("only one axis_tilt effect can act on a bore")
    return replace(bore, tilt_rad=p["beta_rad"], tilt_azimuth_rad=p["azimuth"])


def bore_lobing(bore: Bore, p: Mapping, cte_per_k: float = 0.0) -> Bore:
    """R(theta) = R + a cos(k (theta - phase))."""
    if p["k"] < 2:
        raise ValueError(f"bore_lobing needs k >= 2, got {p['k']}")
    return replace(bore, lobes=tuple(bore.lobes) + ((int(p["k"]), p["a_mm"], p["phase"]),))


def beam_tilt_tri(v_mm: np.ndarray, p: Mapping) -> np.ndarray:
    """Return reading = in-plane distance / cos(gamma): v' = v / cos(gamma)."""
    return np.asarray(v_mm, dtype=float) / math.cos(p["gamma_rad"])


def beam_tilt_rod(layer: RodLayer, p: Mapping) -> RodLayer:
    """Rod layer beam leaves the rotation plane by gamma (Wang 2017 Eq. 6)."""
    return replace(layer, gamma_rad=layer.gamma_rad + p["gamma_rad"])


def beam_offset_rod(layer: RodLayer, p: Mapping) -> RodLayer:
    """Rod layer beam misses the axis by d (Wang 2017 Eq. 5)."""
    return replace(layer, d_mm=layer.d_mm + p["d_mm"])


def sensor_offset(v_mm, t_s, p, range_mm):
    """v' = v + b."""
    return np.asarray(v_mm, dtype=float) + p["b_mm"]


def sensor_gain(v_mm, t_s, p, range_mm):
    """v' = v (1 + g)."""
    return np.asarray(v_mm, dtype=float) * (1.0 + p["g"])


def nonlinearity_bow(v_mm: np.ndarray, range_mm: float) -> np.ndarray:
    """Return the bow 4 u (1 - u), u = v / range_mm (1 at mid-range, 0 at both ends)."""
    u = np.asarray(v_mm, dtype=float) / range_mm
    return 4.0 * u * (1.0 - u)


def sensor_nonlinearity(v_mm, t_s, p, range_mm):
    """v' = v + a 4u(1 - u), u = v / range_mm."""
    v = np.asarray(v_mm, dtype=float)
    return v + p["a_mm"] * nonlinearity_bow(v, range_mm)


def sensor_drift(v_mm, t_s, p, range_mm):
    """v' = v + k t."""
    return np.asarray(v_mm, dtype=float) + p["k_mm_per_s"] * np.asarray(t_s, dtype=float)


def vibration(v_mm, t_s, p, range_mm):
    """v' = v + a sin(2 pi f t + phase)."""
    t = np.asarray(t_s, dtype=float)
    return np.asarray(v_mm, dtype=float) + p["a_mm"] * np.sin(2.0 * np.pi * p["f_hz"] * t + p["phase"])


def quantization(v_mm, p, rng=None):
    """v' = lsb round(v / lsb) (NaN passes through)."""
    lsb = p["lsb_mm"]
    return lsb * np.round(np.asarray(v_mm, dtype=float) / lsb)


def outliers(v_mm, p, rng: np.random.Generator):
    """Return a fraction ``rate`` of samples jumps by +-size (sign random, magnitude size * U(0.75, 1.25))."""
    v = np.array(v_mm, dtype=float, copy=True)
    hit = rng.random(v.shape) < p["rate"]
    sign = np.where(rng.random(v.shape) < 0.5, -1.0, 1.0)
    mag = p["size_mm"] * rng.uniform(0.75, 1.25, v.shape)
    v[hit] += (sign * mag)[hit]
    return v


# --------------------------------------------------------------------------- fit parameterisations


def _polar(A: float, B: float, uA: float, uB: float) -> tuple[float, float, float, float]:
    """Amplitude m = hypot(A, B), angle atan2(B, A) and their linear standard uncertainties."""
    m = math.hypot(A, B)
    if math.isnan(uA) and math.isnan(uB):  # no uncertainties asked for (a forward evaluation)
        return m, math.atan2(B, A), math.nan, math.nan
    um = math.sqrt((A * uA) ** 2 + (B * uB) ** 2) / max(m, 1e-300)
    ua = math.sqrt((B * uA) ** 2 + (A * uB) ** 2) / (m * m) if m > 0 else math.nan
    return m, math.atan2(B, A), um, ua


def _wrap(a: float, period: float = 2.0 * math.pi) -> float:
    return float(np.mod(a, period))


def _u(u: Mapping | None, name: str) -> float:
    return math.nan if u is None else u.get(name, math.nan)


def _phase_type(amp: str, k_divides: bool = False):
    """Return the conversions of an amplitude and phase fitted as A, B.

    (to_internal, from_internal) of an amplitude ``amp`` and ``phase`` fitted as
    A = amp cos(k phase), B = amp sin(k phase) (k = 1 unless ``k_divides``: ``bore_lobing``
    has cos(k (theta - phase)) = cos(k theta - k phase)).
    """

    def to_internal(p: Mapping) -> dict:
        arg = (p["k"] if k_divides else 1) * p["phase"]
        out = {"A": p[amp] * math.cos(arg), "B": p[amp] * math.sin(arg)}
        if "f_hz" in p:
            out = {"f_hz": float(p["f_hz"]), **out}
        return out

    def from_internal(x: Mapping, u: Mapping | None, k: int | None) -> tuple[dict, dict]:
        m, ph, um, uph = _polar(x["A"], x["B"], _u(u, "A"), _u(u, "B"))
        kk = k if k_divides else 1
        par = {amp: m, "phase": _wrap(ph / kk, 2.0 * math.pi / kk)}
        unc = {amp: um, "phase": uph / kk}
        if "f_hz" in x:
            par, unc = {"f_hz": x["f_hz"], **par}, {"f_hz": _u(u, "f_hz"), **unc}
        return par, unc

    return to_internal, from_internal


def beam_tilt_to_internal(p: Mapping) -> dict:
    """h = 1 / cos(gamma) - 1 (linear in the reading, >= 0)."""
    return {"h": 1.0 / math.cos(p["gamma_rad"]) - 1.0}


def beam_tilt_from_internal(x: Mapping, u: Mapping | None, k=None) -> tuple[dict, dict]:
    """gamma = acos(1 / (1 + h)), u(gamma) = u(h) / ((1 + h)^2 sin gamma)."""
    h = x["h"]
    gam = math.acos(1.0 / (1.0 + h)) if h > 0 else 0.0
    ug = _u(u, "h") / ((1.0 + h) ** 2 * math.sin(gam)) if gam > 0 else math.nan
    return {"gamma_rad": gam}, {"gamma_rad": ug}


def axis_tilt_to_internal(p: Mapping) -> dict:
    """p + i q = beta^2 exp(2 i azimuth) (the ellipse's k = 2 content, linear near a circle)."""
    b2 = p["beta_rad"] ** 2
    return {"p": b2 * math.cos(2.0 * p["azimuth"]), "q": b2 * math.sin(2.0 * p["azimuth"])}


def axis_tilt_from_internal(x: Mapping, u: Mapping | None, k=None) -> tuple[dict, dict]:
    """beta = |p + i q|^(1/2), azimuth = arg(p + i q) / 2 (mod pi)."""
    m, ang, um, ua = _polar(x["p"], x["q"], _u(u, "p"), _u(u, "q"))
    beta = math.sqrt(m)
    return (
        {"beta_rad": beta, "azimuth": _wrap(0.5 * ang, math.pi)},
        {"beta_rad": um / (2.0 * max(beta, 1e-300)), "azimuth": 0.5 * ua},
    )


def thermal_to_internal(p: Mapping) -> dict:
    """dT = T - 20 degC."""
    return {"dT": p["temperature_c"] - REFERENCE_TEMPERATURE_C}


def thermal_from_internal(x: Mapping, u: Mapping | None, k=None) -> tuple[dict, dict]:
    return {"temperature_c": REFERENCE_TEMPERATURE_C + x["dT"]}, {"temperature_c": _u(u, "dT")}


RIPPLE = _phase_type("a_rad")
MOTION = _phase_type("rho_mm")
LOBING = _phase_type("a_mm", k_divides=True)
VIBRATION = _phase_type("a_mm")
