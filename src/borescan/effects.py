"""Registry of the named effects of ``shared/spec/geometry-and-effects.md``.

One :class:`EffectSpec` per name of the spec's "Named effects" table, with exactly the
spec's parameter names (``channel`` is the spec's ``c``). Each spec carries the stage of
the forward model where it acts and one pure forward function per device type.

Stages, in the order the digital twin (:mod:`borescan.synthetic.simulate`) composes them:

``time_base``
    ``f(t_s, p) -> t_s`` on one channel's times (``channel_delay``).
``kinematics``
    ``f(x_rad, p) -> x_rad`` on the turned angle x = omega t that the nominal model assumes
    (``speed_error`` first, then ``speed_ripple``); the device angle is phi = phase + x
    (ccw) or phase - x (cw).
``spindle_position``
    ``f(S_xy_mm (..., 2), phi_rad (...), p) -> S_xy_mm`` (``spindle_error_motion``).
``bore``
    ``f(bore: Bore, p, cte_per_k) -> Bore`` (``thermal_expansion``, ``axis_tilt``,
    ``bore_lobing``).
``beam``
    tri_lds: ``f(v_mm, p) -> v_mm`` on one channel (``beam_tilt``);
    rod: ``f(layer: RodLayer, p) -> RodLayer`` (``beam_tilt``, ``beam_offset``).
``reading``
    ``f(v_mm, t_s, p, range_mm) -> v_mm`` on one channel (or every channel when the
    effect has no ``channel``): offset, gain, nonlinearity, drift, vibration.
``output``
    ``f(v_mm, p, rng) -> v_mm``, after the noise: quantization, outliers.

Within a stage, effects act in the order of the spec's table (the order of :data:`EFFECTS`)
and effects of the same name in the order given. Effects compose freely, including several
of the same name on different channels. :mod:`borescan.physics.tri` composes them into the one
forward model of a spindle scan that the digital twin and the discrepancy workflow share.

The registry is also the vocabulary of the fits (lmfit style: an effect adds prefixed
parameters, e.g. ``sensor_gain@2.g``). Each spec carries

- ``fit``: the parameters a fit varies (:class:`FitParam`: name, unit, typical scale, bounds),
  with ``to_internal`` / ``from_internal`` beside the effect where they differ from the
  spec's parameters for conditioning (an amplitude and phase as A = a cos(phase),
  B = a sin(phase); ``beam_tilt`` as h = 1 / cos(gamma) - 1; ``axis_tilt`` as
  p + i q = beta^2 exp(2 i azimuth); ``thermal_expansion`` as dT = T - 20);
- ``absorbed_by``: per scan kind (:data:`SCAN_KINDS`), the base parameters that absorb the
  effect, with the text a finding reports (``"R"``: the bore radius, which absorbs only the
  form common to every channel);
- ``candidate``: per scan kind, how the discrepancy workflow looks for it: ``"screen"`` (a
  term of the linear screen), ``"start"`` (not linear at zero: only from a start another
  term's screen gives), ``"evidence"`` (named by its own test, not fitted);
  ``needs``: what a scan must have for the term to be tried (``"commanded_angle"``: no
  encoder, ``"vibration_line"``: a residual line off the rotation harmonics, ``"cte"``: the
  artifact's expansion coefficient); ``common``: a per-channel effect also tried as one
  value on every channel;
- ``scope``: what the effect belongs to when several scans are examined together
  (:mod:`borescan.discrepancy.pooled`): ``"device"`` (the sensors, the electronics: one value in
  every scan of the device), ``"night"`` (the environment of one night), ``"artifact"`` (one
  artifact: its form, its tilt) or ``"scan"`` (one run of the spindle);
- ``absorbed_unless``: per scan kind, base parameter -> the condition of a set of scans under
  which that parameter no longer absorbs the effect (``"speeds_differ"``: a delay is a change
  of beta only at one signed speed; ``"radii_differ"``: a thermal change of the radius is a
  common offset only for one gauge radius); the conditions are evaluated by the pooled examination;
- ``orientation``: for an effect fixed in the machine frame (a gauge's form, its tilt), the spec
  parameter that turns with it (``phase``, ``azimuth``): scans whose angle origins differ see it
  turned by the difference.

Adding a reading effect is one :class:`EffectSpec` here (plus its row in the spec).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from borescan.geometry import Bore, RodLayer

__all__ = [
    "STAGES",
    "SCAN_KINDS",
    "SCOPES",
    "FitParam",
    "EffectSpec",
    "Effect",
    "EFFECTS",
    "get_effect",
    "calibration_absorbers",
    "parse_effect",
    "effects_from_dicts",
    "as_effects",
    "effects_to_dicts",
    "sort_effects",
    "device_effect_key",
    "device_model_effects",
    "apply_effects",
    "nonlinearity_bow",
    "REFERENCE_TEMPERATURE_C",
    "thermal_expansion_factor",
]

STAGES: tuple[str, ...] = ("time_base", "kinematics", "spindle_position", "bore", "beam", "reading", "output")
TRI = "tri_lds"
ROD = "rod"
#: Scan kinds the registry describes absorption and candidacy for.
SCAN_KINDS: tuple[str, ...] = ("tri_spindle", "tri_static", "rod")
#: What an effect belongs to when scans are examined together (``EffectSpec.scope``).
SCOPES: tuple[str, ...] = ("device", "night", "artifact", "scan")


@dataclass(frozen=True)
class FitParam:
    """One parameter a fit varies for an effect (its internal parameterisation).

    Attributes
    ----------
    name : internal name, e.g. ``"A"``; a fit prefixes it with the term, ``bore_lobing[k=3].A``.
    unit : unit of the value (``"-"`` dimensionless).
    scale : typical magnitude, for step sizes and starting values [unit].
    lower, upper : bounds of the physical domain [unit]; the forward model clips to them.
    """

    name: str
    unit: str
    scale: float
    lower: float = -math.inf
    upper: float = math.inf


@dataclass(frozen=True)
class EffectSpec:
    """One named effect of the spec.

    Attributes
    ----------
    name : spec name, e.g. ``"channel_delay"``.
    device_types : device types it applies to (``"tri_lds"``, ``"rod"``).
    params : parameter name -> unit (``"-"`` for dimensionless, ``"channel"`` for the 1-based channel).
    stage : one of :data:`STAGES`.
    forward : device type -> pure forward function (signature per stage, see module doc).
    definition : the spec's definition, for messages and reports.
    fit : the parameters a fit varies (empty: not fitted).
    to_internal : spec parameters -> ``{fit name: value}``; None: the same names and values.
    from_internal : ``(x, u, k) -> (parameters, uncertainties)``, the inverse with linear
        propagation of standard uncertainties ``u`` (may be None); ``k`` the harmonic of a
        term; None: the same names and values.
    absorbed_by : scan kind -> {base parameter: what a finding reports}.
    candidate : scan kind -> ``"screen"``, ``"start"`` or ``"evidence"`` (module doc).
    needs : conditions a scan must meet for the term to be tried (module doc).
    common : a per-channel effect is also tried as one value on every channel.
    scope : ``"device"``, ``"night"``, ``"artifact"`` or ``"scan"`` (module doc).
    absorbed_unless : scan kind -> {base parameter: condition that breaks the absorption} (module doc).
    orientation : the spec parameter that turns with the artifact (module doc), or None.
    separated_by : what another scan must differ in to tell the effect from its look-alikes, as the
        report advises it (README "When something needs attention"); "" when no such advice.
    example : sensible parameter values (spec names; channel 2 for channel effects), for tests,
        demos and docs.
    """

    name: str
    device_types: tuple[str, ...]
    params: Mapping[str, str]
    stage: str
    forward: Mapping[str, Callable[..., Any]]
    definition: str
    fit: tuple[FitParam, ...] = ()
    to_internal: Callable[[Mapping[str, float]], dict] | None = None
    from_internal: Callable[..., tuple[dict, dict]] | None = None
    absorbed_by: Mapping[str, Mapping[str, str]] = field(default_factory=dict)
    candidate: Mapping[str, str] = field(default_factory=dict)
    needs: tuple[str, ...] = ()
    common: bool = False
    example: Mapping[str, Any] = field(default_factory=dict)
    scope: str = "device"
    absorbed_unless: Mapping[str, Mapping[str, str]] = field(default_factory=dict)
    orientation: str | None = None
    separated_by: str = ""

    @property
    def per_channel(self) -> bool:
        """True when the effect acts on one channel (has a ``channel`` parameter)."""
        return "channel" in self.params

    @property
    def harmonic(self) -> bool:
        """True when the effect has a whole-number harmonic ``k`` (one term per k)."""
        return "k" in self.params

    def internal(self, params: Mapping[str, float]) -> dict[str, float]:
        """Return the fit's values ``{fit name: value}`` of the spec's ``params`` (``to_internal``)."""
        if self.to_internal is not None:
            return self.to_internal(params)
        return {q.name: float(params[q.name]) for q in self.fit}

    def spec_params(
        self, x: Mapping[str, float], u: Mapping[str, float] | None = None, k: int | None = None
    ) -> tuple[dict[str, Any], dict[str, float]]:
        """Return the spec's parameters of fitted values ``x``.

        Return the spec's parameters (and their standard uncertainties when ``u`` is given) of
        fitted values ``x`` (``{fit name: value}``), clipped to the fit's bounds first;
        ``channel`` is not included, ``k`` is for harmonic effects.
        """
        x = {q.name: min(max(float(x[q.name]), q.lower), q.upper) for q in self.fit}
        if self.from_internal is not None:
            par, unc = self.from_internal(x, u, k)
        else:
            par = dict(x)
            unc = {} if u is None else {q.name: u.get(q.name, math.nan) for q in self.fit}
        if self.harmonic:
            par = {"k": k, **par}
        return par, unc

    def absorbers(self, scan_kind: str) -> Mapping[str, str]:
        """Return base parameters that absorb the effect in scans of ``scan_kind`` (may be empty)."""
        return self.absorbed_by.get(scan_kind, {})


@dataclass(frozen=True)
class Effect:
    """A named effect with its parameters, e.g. ``Effect("channel_delay", {"channel": 2, "tau_s": 0.0012})``.

    The name and the parameter names are checked against :data:`EFFECTS` on construction.
    """

    name: str
    params: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        spec = get_effect(self.name)
        given, wanted = set(self.params), set(spec.params)
        if given != wanted:
            raise ValueError(f"effect {self.name!r} takes parameters {sorted(wanted)}, got {sorted(given)}")
        clean = {}
        for k, v in self.params.items():
            if k in ("channel", "k"):
                if float(v) != int(v):
                    raise ValueError(f"effect {self.name!r}: {k} must be an integer, got {v!r}")
                clean[k] = int(v)
            else:
                clean[k] = float(v)
        object.__setattr__(self, "params", clean)

    def __hash__(self) -> int:
        return hash((self.name, tuple(sorted(self.params.items()))))

    @property
    def spec(self) -> EffectSpec:
        """The effect's registry entry."""
        return EFFECTS[self.name]

    @property
    def channel(self) -> int | None:
        """The channel the effect applies to, or None for all."""
        return self.params.get("channel")

    def to_dict(self) -> dict:
        """``{"name": ..., "params": {...}}`` (JSON-ready)."""
        return {"name": self.name, "params": dict(self.params)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Effect":
        """Return the effect written by :meth:`to_dict`."""
        return cls(d["name"], dict(d["params"]))

    def __str__(self) -> str:
        return self.name + ":" + ",".join(f"{k}={v:g}" for k, v in self.params.items())


# --------------------------------------------------------------------------- forward functions


def _channel_delay(t_s: np.ndarray, p: Mapping) -> np.ndarray:
    """Channel c at time t shows the reading of time t - tau: t' = t - tau."""
    return np.asarray(t_s, dtype=float) - p["tau_s"]


def _speed_error(x_rad: np.ndarray, p: Mapping) -> np.ndarray:
    """Turn the spindle at (1 + eps) times the commanded profile.

    Spindle turns at (1 + eps) times the commanded profile: x' = (1 + eps) x, x = Phi(t) the commanded
    angle.
    """
    return np.asarray(x_rad, dtype=float) * (1.0 + p["eps"])


def _speed_ripple(x_rad: np.ndarray, p: Mapping) -> np.ndarray:
    """phi(t) = omega t + a sin(omega t + phase): x' = x + a sin(x + phase)."""
    x = np.asarray(x_rad, dtype=float)
    return x + p["a_rad"] * np.sin(x + p["phase"])


def _spindle_error_motion(S_xy_mm: np.ndarray, phi_rad: np.ndarray, p: Mapping) -> np.ndarray:
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


def _thermal_expansion(bore: Bore, p: Mapping, cte_per_k: float) -> Bore:
    """R = R20 (1 + cte (T - 20)) (:func:`thermal_expansion_factor`)."""
    return replace(bore, radius_mm=bore.radius_mm * thermal_expansion_factor(cte_per_k, p["temperature_c"]))


def _axis_tilt(bore: Bore, p: Mapping, cte_per_k: float = 0.0) -> Bore:
    """Ellipse with semi-axes R / cos(beta) along ``azimuth`` and R across."""
    if bore.tilt_rad != 0.0:
        raise ValueError("only one axis_tilt effect can act on a bore")
    return replace(bore, tilt_rad=p["beta_rad"], tilt_azimuth_rad=p["azimuth"])


def _bore_lobing(bore: Bore, p: Mapping, cte_per_k: float = 0.0) -> Bore:
    """R(theta) = R + a cos(k (theta - phase))."""
    if p["k"] < 2:
        raise ValueError(f"bore_lobing needs k >= 2, got {p['k']}")
    return replace(bore, lobes=tuple(bore.lobes) + ((int(p["k"]), p["a_mm"], p["phase"]),))


def _beam_tilt_tri(v_mm: np.ndarray, p: Mapping) -> np.ndarray:
    """Return reading = in-plane distance / cos(gamma): v' = v / cos(gamma)."""
    return np.asarray(v_mm, dtype=float) / math.cos(p["gamma_rad"])


def _beam_tilt_rod(layer: RodLayer, p: Mapping) -> RodLayer:
    """Rod layer beam leaves the rotation plane by gamma (Wang 2017 Eq. 6)."""
    return replace(layer, gamma_rad=layer.gamma_rad + p["gamma_rad"])


def _beam_offset_rod(layer: RodLayer, p: Mapping) -> RodLayer:
    """Rod layer beam misses the axis by d (Wang 2017 Eq. 5)."""
    return replace(layer, d_mm=layer.d_mm + p["d_mm"])


def _sensor_offset(v_mm, t_s, p, range_mm):
    """v' = v + b."""
    return np.asarray(v_mm, dtype=float) + p["b_mm"]


def _sensor_gain(v_mm, t_s, p, range_mm):
    """v' = v (1 + g)."""
    return np.asarray(v_mm, dtype=float) * (1.0 + p["g"])


def nonlinearity_bow(v_mm: np.ndarray, range_mm: float) -> np.ndarray:
    """Return the bow 4 u (1 - u), u = v / range_mm (1 at mid-range, 0 at both ends)."""
    u = np.asarray(v_mm, dtype=float) / range_mm
    return 4.0 * u * (1.0 - u)


def _sensor_nonlinearity(v_mm, t_s, p, range_mm):
    """v' = v + a 4u(1 - u), u = v / range_mm."""
    v = np.asarray(v_mm, dtype=float)
    return v + p["a_mm"] * nonlinearity_bow(v, range_mm)


def _sensor_drift(v_mm, t_s, p, range_mm):
    """v' = v + k t."""
    return np.asarray(v_mm, dtype=float) + p["k_mm_per_s"] * np.asarray(t_s, dtype=float)


def _vibration(v_mm, t_s, p, range_mm):
    """v' = v + a sin(2 pi f t + phase)."""
    t = np.asarray(t_s, dtype=float)
    return np.asarray(v_mm, dtype=float) + p["a_mm"] * np.sin(2.0 * np.pi * p["f_hz"] * t + p["phase"])


def _quantization(v_mm, p, rng=None):
    """v' = lsb round(v / lsb) (NaN passes through)."""
    lsb = p["lsb_mm"]
    return lsb * np.round(np.asarray(v_mm, dtype=float) / lsb)


def _outliers(v_mm, p, rng: np.random.Generator):
    """Return a fraction ``rate`` of samples jumps by +-size (sign random, magnitude size * U(0.75, 1.25))."""
    v = np.array(v_mm, dtype=float, copy=True)
    hit = rng.random(v.shape) < p["rate"]
    sign = np.where(rng.random(v.shape) < 0.5, -1.0, 1.0)
    mag = p["size_mm"] * rng.uniform(0.75, 1.25, v.shape)
    v[hit] += (sign * mag)[hit]
    return v


def _reading(f):
    return {TRI: f, ROD: f}


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


def _beam_tilt_to_internal(p: Mapping) -> dict:
    """h = 1 / cos(gamma) - 1 (linear in the reading, >= 0)."""
    return {"h": 1.0 / math.cos(p["gamma_rad"]) - 1.0}


def _beam_tilt_from_internal(x: Mapping, u: Mapping | None, k=None) -> tuple[dict, dict]:
    """gamma = acos(1 / (1 + h)), u(gamma) = u(h) / ((1 + h)^2 sin gamma)."""
    h = x["h"]
    gam = math.acos(1.0 / (1.0 + h)) if h > 0 else 0.0
    ug = _u(u, "h") / ((1.0 + h) ** 2 * math.sin(gam)) if gam > 0 else math.nan
    return {"gamma_rad": gam}, {"gamma_rad": ug}


def _axis_tilt_to_internal(p: Mapping) -> dict:
    """p + i q = beta^2 exp(2 i azimuth) (the ellipse's k = 2 content, linear near a circle)."""
    b2 = p["beta_rad"] ** 2
    return {"p": b2 * math.cos(2.0 * p["azimuth"]), "q": b2 * math.sin(2.0 * p["azimuth"])}


def _axis_tilt_from_internal(x: Mapping, u: Mapping | None, k=None) -> tuple[dict, dict]:
    """beta = |p + i q|^(1/2), azimuth = arg(p + i q) / 2 (mod pi)."""
    m, ang, um, ua = _polar(x["p"], x["q"], _u(u, "p"), _u(u, "q"))
    beta = math.sqrt(m)
    return (
        {"beta_rad": beta, "azimuth": _wrap(0.5 * ang, math.pi)},
        {"beta_rad": um / (2.0 * max(beta, 1e-300)), "azimuth": 0.5 * ua},
    )


def _thermal_to_internal(p: Mapping) -> dict:
    """dT = T - 20 degC."""
    return {"dT": p["temperature_c"] - REFERENCE_TEMPERATURE_C}


def _thermal_from_internal(x: Mapping, u: Mapping | None, k=None) -> tuple[dict, dict]:
    return {"temperature_c": REFERENCE_TEMPERATURE_C + x["dT"]}, {"temperature_c": _u(u, "dT")}


_RIPPLE = _phase_type("a_rad")
_MOTION = _phase_type("rho_mm")
_LOBING = _phase_type("a_mm", k_divides=True)
_VIBRATION = _phase_type("a_mm")
_ALL_KINDS = {"tri_spindle": "screen", "tri_static": "screen", "rod": "screen"}
_EVIDENCE = {"tri_spindle": "evidence", "tri_static": "evidence", "rod": "evidence"}


EFFECTS: dict[str, EffectSpec] = {
    s.name: s
    for s in [
        EffectSpec(
            "sensor_offset",
            (TRI, ROD),
            {"channel": "channel", "b_mm": "mm"},
            "reading",
            _reading(_sensor_offset),
            "v' = v + b",
            fit=(FitParam("b_mm", "mm", 1e-3),),
            candidate=_ALL_KINDS,
            common=True,
            separated_by="another eccentricity",
            absorbed_by={
                "tri_spindle": {
                    "d_b": "d_b_mm of the channel (every d_b when common)",
                    "R": "the bore radius (when common)",
                },
                "tri_static": {"d_b": "d_b_mm of the channel", "R": "the bore radius (when common)"},
                "rod": {"l0": "l0_mm of the layer", "R": "the hole radius, when free"},
            },
            example={"channel": 2, "b_mm": 0.012},
        ),
        EffectSpec(
            "sensor_gain",
            (TRI, ROD),
            {"channel": "channel", "g": "-"},
            "reading",
            _reading(_sensor_gain),
            "v' = v (1 + g)",
            fit=(FitParam("g", "-", 1e-4),),
            candidate=_ALL_KINDS,
            example={"channel": 2, "g": -0.004},
        ),
        EffectSpec(
            "sensor_nonlinearity",
            (TRI, ROD),
            {"channel": "channel", "a_mm": "mm"},
            "reading",
            _reading(_sensor_nonlinearity),
            "v' = v + a 4u(1 - u), u = v / range_mm",
            fit=(FitParam("a_mm", "mm", 1e-3),),
            candidate=_ALL_KINDS,
            separated_by="another eccentricity",
            example={"channel": 2, "a_mm": 0.01},
        ),
        EffectSpec(
            "sensor_drift",
            (TRI, ROD),
            {"channel": "channel", "k_mm_per_s": "mm/s"},
            "reading",
            _reading(_sensor_drift),
            "v' = v + k t",
            fit=(FitParam("k_mm_per_s", "mm/s", 1e-5),),
            candidate=_ALL_KINDS,
            example={"channel": 2, "k_mm_per_s": 0.0015},
        ),
        EffectSpec(
            "channel_delay",
            (TRI,),
            {"channel": "channel", "tau_s": "s"},
            "time_base",
            {TRI: _channel_delay},
            "channel c at time t shows the reading of time t - tau",
            fit=(FitParam("tau_s", "s", 1e-4),),
            candidate={"tri_spindle": "screen"},
            absorbed_by={"tri_spindle": {"beta": "beta_rad of the channel (at constant speed)"}},
            absorbed_unless={"tri_spindle": {"beta": "speeds_differ"}},
            separated_by="another spindle speed",
            example={"channel": 2, "tau_s": 0.0012},
        ),
        EffectSpec(
            "quantization",
            (TRI, ROD),
            {"channel": "channel", "lsb_mm": "mm"},
            "output",
            _reading(_quantization),
            "v' = lsb round(v / lsb)",
            candidate=_EVIDENCE,
            example={"channel": 2, "lsb_mm": 0.002},
        ),
        EffectSpec(
            "outliers",
            (TRI, ROD),
            {"channel": "channel", "rate": "-", "size_mm": "mm"},
            "output",
            _reading(_outliers),
            "a fraction rate of samples jumps by about +-size",
            candidate=_EVIDENCE,
            example={"channel": 2, "rate": 0.01, "size_mm": 0.05},
        ),
        EffectSpec(
            "vibration",
            (TRI,),
            {"f_hz": "Hz", "a_mm": "mm", "phase": "rad"},
            "reading",
            {TRI: _vibration},
            "v' = v + a sin(2 pi f t + phase)",
            fit=(FitParam("f_hz", "Hz", 1e-2), FitParam("A", "mm", 1e-3), FitParam("B", "mm", 1e-3)),
            to_internal=_VIBRATION[0],
            from_internal=_VIBRATION[1],
            candidate={"tri_spindle": "screen"},
            needs=("vibration_line",),
            scope="scan",
            example={"f_hz": 7.3, "a_mm": 0.004, "phase": 0.4},
        ),
        EffectSpec(
            "speed_error",
            (TRI,),
            {"eps": "-"},
            "kinematics",
            {TRI: _speed_error},
            "the spindle turns at (1 + eps) times the commanded profile",
            fit=(FitParam("eps", "-", 1e-4),),
            candidate={"tri_spindle": "screen"},
            needs=("commanded_angle",),
            scope="scan",
            separated_by="another spindle speed",
            example={"eps": 0.002},
        ),
        EffectSpec(
            "speed_ripple",
            (TRI,),
            {"a_rad": "rad", "phase": "rad"},
            "kinematics",
            {TRI: _speed_ripple},
            "phi(t) = omega t + a sin(omega t + phase)",
            fit=(FitParam("A", "rad", 1e-3), FitParam("B", "rad", 1e-3)),
            to_internal=_RIPPLE[0],
            from_internal=_RIPPLE[1],
            candidate={"tri_spindle": "screen"},
            needs=("commanded_angle",),
            scope="scan",
            example={"a_rad": 0.006, "phase": 1.0},
        ),
        EffectSpec(
            "spindle_error_motion",
            (TRI,),
            {"k": "-", "rho_mm": "mm", "phase": "rad"},
            "spindle_position",
            {TRI: _spindle_error_motion},
            "S(phi) = S0 + rho (cos(k phi + phase), sin(k phi + phase))",
            fit=(FitParam("A", "mm", 1e-3), FitParam("B", "mm", 1e-3)),
            to_internal=_MOTION[0],
            from_internal=_MOTION[1],
            candidate={"tri_spindle": "screen"},
            scope="scan",
            example={"k": 3, "rho_mm": 0.006, "phase": 0.5},
        ),
        EffectSpec(
            "axis_tilt",
            (TRI,),
            {"beta_rad": "rad", "azimuth": "rad"},
            "bore",
            {TRI: _axis_tilt},
            "bore is an ellipse R / cos(beta) along azimuth, R across",
            fit=(FitParam("p", "rad^2", 1e-4), FitParam("q", "rad^2", 1e-4)),
            to_internal=_axis_tilt_to_internal,
            from_internal=_axis_tilt_from_internal,
            candidate={"tri_spindle": "start"},
            scope="artifact",
            orientation="azimuth",
            example={"beta_rad": 0.02, "azimuth": 0.6},
        ),
        EffectSpec(
            "bore_lobing",
            (TRI,),
            {"k": "-", "a_mm": "mm", "phase": "rad"},
            "bore",
            {TRI: _bore_lobing},
            "R(theta) = R + a cos(k (theta - phase))",
            fit=(FitParam("A", "mm", 1e-3), FitParam("B", "mm", 1e-3)),
            to_internal=_LOBING[0],
            from_internal=_LOBING[1],
            candidate={"tri_spindle": "screen"},
            scope="artifact",
            orientation="phase",
            example={"k": 3, "a_mm": 0.005, "phase": 0.4},
        ),
        EffectSpec(
            "thermal_expansion",
            (TRI, ROD),
            {"temperature_c": "degC"},
            "bore",
            {TRI: _thermal_expansion, ROD: _thermal_expansion},
            "R = R20 (1 + cte (T - 20))",
            fit=(FitParam("dT", "K", 1.0),),
            to_internal=_thermal_to_internal,
            from_internal=_thermal_from_internal,
            candidate=_ALL_KINDS,
            needs=("cte",),
            absorbed_by={
                "tri_spindle": {"d_b": "every d_b_mm (a common offset)", "R": "the bore radius"},
                "tri_static": {"d_b": "every d_b_mm (a common offset)", "R": "the bore radius"},
                "rod": {"R": "the hole radius, when free"},
            },
            absorbed_unless={"tri_spindle": {"d_b": "radii_differ"}},
            scope="night",
            example={"temperature_c": 24.0},
        ),
        EffectSpec(
            "beam_tilt",
            (TRI, ROD),
            {"channel": "channel", "gamma_rad": "rad"},
            "beam",
            {TRI: _beam_tilt_tri, ROD: _beam_tilt_rod},
            "reading = in-plane distance / cos(gamma)",
            fit=(FitParam("h", "-", 1e-4, 0.0),),
            to_internal=_beam_tilt_to_internal,
            from_internal=_beam_tilt_from_internal,
            candidate=_ALL_KINDS,
            absorbed_by={"rod": {"l0": "l0_mm of the layer (to first order)"}},
            example={"channel": 2, "gamma_rad": 0.06},
        ),
        EffectSpec(
            "beam_offset",
            (ROD,),
            {"channel": "channel", "d_mm": "mm"},
            "beam",
            {ROD: _beam_offset_rod},
            "rod: layer c's beam misses the axis by d (Wang 2017 Eq. 5)",
            fit=(FitParam("d_mm", "mm", 1e-2),),
            candidate={"rod": "start"},
            absorbed_by={
                "rod": {
                    "l0": "l0_mm of the layer (acts as a constant -d^2 / (2 r))",
                    "R": "the hole radius, when free",
                }
            },
            example={"channel": 2, "d_mm": 0.3},
        ),
    ]
}


def calibration_absorbers(scan_kind: str) -> dict[str, str]:
    """Return, per effect, the calibration parameters that absorb it in scans of ``scan_kind``.

    As a finding reports them: the registry's ``absorbed_by`` less the bore radius ``"R"`` (a measurand), for
    the effects some calibration parameter absorbs; read from the registry as it is now.
    """
    return {
        name: "; ".join(text for par, text in spec.absorbers(scan_kind).items() if par != "R")
        for name, spec in EFFECTS.items()
        if any(par != "R" for par in spec.absorbers(scan_kind))
    }


def get_effect(name: str) -> EffectSpec:
    """Return the :class:`EffectSpec` of ``name``.

    Return the :class:`EffectSpec` of ``name``; unknown names raise ``ValueError`` listing the valid
    ones.
    """
    try:
        return EFFECTS[name]
    except KeyError:
        raise ValueError(f"unknown effect {name!r}; valid effects: {', '.join(EFFECTS)}") from None


def parse_effect(text: str) -> Effect:
    """Parse ``"channel_delay:channel=2,tau_s=0.0012"`` into an :class:`Effect`."""
    name, _, rest = text.strip().partition(":")
    params: dict[str, float] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq:
            raise ValueError(f"effect {text!r}: expected key=value, got {item!r}")
        params[key.strip()] = float(val)
    return Effect(name.strip(), params)


def effects_to_dicts(effects: Iterable[Effect]) -> list[dict]:
    """Return the effects as JSON-ready data (:func:`effects_from_dicts` reads them back)."""
    return [e.to_dict() for e in effects]


def effects_from_dicts(items: Iterable[Mapping]) -> list[Effect]:
    """Return the effects written by :func:`effects_to_dicts`."""
    return [Effect.from_dict(d) for d in items]


def as_effects(effects: Iterable[Effect | Mapping] | None) -> list[Effect]:
    """Return the effects as :class:`Effect` objects: each given as one, or as its dict (``None``: none)."""
    return [e if isinstance(e, Effect) else Effect.from_dict(e) for e in (effects or ())]


def sort_effects(
    effects: Iterable[Effect], device_type: str, channels: Sequence[int]
) -> dict[str, list[Effect]]:
    """Check effects against the device and group them by stage, in composition order.

    Raises ``ValueError`` for an effect that does not apply to ``device_type`` or names a
    channel the device does not have.
    """
    out: dict[str, list[Effect]] = {s: [] for s in STAGES}
    effects = [e if isinstance(e, Effect) else Effect.from_dict(e) for e in effects]
    for e in effects:
        spec = e.spec
        if device_type not in spec.device_types:
            raise ValueError(
                f"effect {e.name!r} does not apply to a {device_type} device (only {spec.device_types})"
            )
        if spec.per_channel and e.channel not in channels:
            raise ValueError(
                f"effect {e.name!r} names channel {e.channel}, device has channels {tuple(channels)}"
            )
    order = {
        name: i for i, name in enumerate(EFFECTS)
    }  # the registry as it is now (an entry added later counts)
    for e in sorted(effects, key=lambda e: order[e.name]):  # stable: same name keeps given order
        out[e.spec.stage].append(e)
    return out


def _columns(e: Effect, channels: Sequence[int]) -> list[int]:
    return [list(channels).index(e.channel)] if e.spec.per_channel else list(range(len(channels)))


def apply_effects(
    readings_mm: np.ndarray,
    t_s: np.ndarray,
    channels: Sequence[int],
    effects: Iterable[Effect],
    *,
    device_type: str = TRI,
    range_mm: Sequence[float] | float = 10.0,
    stages: Sequence[str] = ("beam", "reading"),
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Apply the array-level effects (stages ``beam`` (tri_lds), ``reading``, ``output``) to readings.

    Parameters
    ----------
    readings_mm : ndarray (n, c) readings v of a model without these effects [mm].
    t_s : ndarray (n,) or (n, c) time since scan start of each reading [s] (per channel when
        ``channel_delay`` shifted it).
    channels : the 1-based channels of the columns.
    effects : effects; those of other stages are ignored.
    range_mm : sensor range per channel (or one for all) [mm], for ``sensor_nonlinearity``.
    stages : which of ``beam``, ``reading``, ``output`` to apply, in composition order.
    rng : required for ``outliers``.

    Returns
    -------
    ndarray (n, c) [mm]; NaN passes through.
    """
    v = np.array(readings_mm, dtype=float, copy=True)
    t = np.broadcast_to(np.asarray(t_s, dtype=float).reshape(v.shape[0], -1), v.shape)
    rng_arr = np.broadcast_to(np.asarray(range_mm, dtype=float), (v.shape[1],))
    by_stage = sort_effects(effects, device_type, channels)
    for stage in STAGES:
        if stage not in stages or stage not in ("beam", "reading", "output"):
            continue
        for e in by_stage[stage]:
            f = e.spec.forward[device_type]
            for j in _columns(e, channels):
                if stage == "beam":
                    if device_type != TRI:
                        continue  # rod beam effects act on the layer geometry
                    v[:, j] = f(v[:, j], e.params)
                elif stage == "reading":
                    v[:, j] = f(v[:, j], t[:, j], e.params, rng_arr[j])
                else:
                    if e.name == "outliers" and rng is None:
                        raise ValueError("the outliers effect needs a numpy Generator (rng)")
                    v[:, j] = f(v[:, j], e.params, rng)
    return v


# --------------------------------------------------------------------------- a device's model in the config

#: the scan kind a device model is fitted on (the pooled examination of three-sensor spindle scans)
DEVICE_MODEL_SCAN_KIND = "tri_spindle"
_KEY = re.compile(r"^(?P<effect>[a-z_]+)(?:@(?P<channel>all|\d+))?(?:\[k=(?P<k>\d+)\])?$")
_NIGHT = re.compile(r"\d{4}-\d{2}-\d{2}")


def device_effect_key(  # noqa: C901 (checks every part of a device-model key, each with its message)
    key: str, channels: Sequence[int] | None = None, device: str = ""
) -> tuple[str, int | None]:
    """Return (effect name, channel) of a device-model entry.

    (effect name, channel) of a device-model entry (a registry key as the findings write it:
    ``channel_delay@2``, ``sensor_offset@all``, ``sensor_nonlinearity@1``); channel 0 for ``@all``,
    None for an effect that acts on every channel at once.

    The effect must be in the registry, act on three-sensor spindle scans and belong to the
    device (``scope`` ``"device"``: a night's temperature or a gauge's form is not a property of
    the device); a per-channel effect names a channel of ``channels`` (or ``all`` where the
    registry tries it as one value on every channel), any other names none.

    Raises
    ------
    ValueError naming the device, the entry and what is wrong (unknown effects list the valid ones).
    """
    where = f"devices.{device}.effects: " if device else "device model: "
    m = _KEY.match(str(key).strip())
    if m is None:
        raise ValueError(f"{where}{key!r} is not an effect key (effect, effect@<channel> or effect@all)")
    name, ch, k = m["effect"], m["channel"], m["k"]
    valid = sorted(
        n
        for n, e in EFFECTS.items()
        if e.scope == "device" and DEVICE_MODEL_SCAN_KIND in e.candidate and e.fit
    )
    if name not in EFFECTS:
        raise ValueError(f"{where}unknown effect {name!r} in {key!r}; valid: {valid}")
    spec = EFFECTS[name]
    if name not in valid:
        why = (
            f"belongs to the {spec.scope}, not to the device"
            if spec.scope != "device"
            else "is not a fitted effect of three-sensor spindle scans"
        )
        raise ValueError(f"{where}{name!r} {why}; a device model lists: {valid}")
    if k is not None:
        raise ValueError(f"{where}{key!r}: a device effect has no harmonic [k=...]")
    if not spec.per_channel:
        if ch is not None:
            raise ValueError(f"{where}{key!r}: {name} acts on every channel at once; write {name!r}")
        return name, None
    if ch is None:
        raise ValueError(
            f"{where}{key!r}: {name} acts on one channel; write {name}@<channel>"
            + (" or {name}@all".format(name=name) if spec.common else "")
        )
    if ch == "all":
        if not spec.common:
            raise ValueError(
                f"{where}{key!r}: {name} is not tried as one value on every channel; name a channel"
            )
        return name, 0
    if channels is not None and int(ch) not in channels:
        raise ValueError(f"{where}{key!r}: channel {ch} is not one of the scans' channels {tuple(channels)}")
    return name, int(ch)


def device_model_effects(devices: dict | None, device_id: str, night: str | None = None) -> tuple[str, ...]:
    """Return the device model of ``device_id`` on ``night`` from the config.

    Return the device model of ``device_id`` on ``night`` from the config's ``devices`` section (its
    ``effects``), each entry checked by :func:`device_effect_key` (channels not checked here); ()
    when the device has none. Light on purpose: the workflow checks the section when it starts.

    An entry is a registry key (the device has the effect on every night) or a mapping
    ``{effect: <key>, from: YYYY-MM-DD}``: the user's decision takes effect from that night on;
    before it the effect is a candidate like any other. ``night`` None: every entry.
    """
    entry = (devices or {}).get(device_id) or {}
    where = f"devices.{device_id}.effects"
    keys, since = [], {}
    for item in entry.get("effects") or ():
        if isinstance(item, dict):
            if set(item) - {"effect", "from"} or "effect" not in item:
                raise ValueError(
                    f"{where}: {item!r}: an entry is an effect key or {{effect: <key>, from: YYYY-MM-DD}}"
                )
            key, frm = str(item["effect"]), str(item.get("from") or "")
            if frm and not _NIGHT.fullmatch(frm):
                raise ValueError(f"{where}: {key!r}: from {frm!r} is not a night (YYYY-MM-DD)")
        else:
            key, frm = str(item), ""
        device_effect_key(key, None, device_id)
        keys.append(key)
        since[key] = frm
    if len(set(keys)) != len(keys):
        raise ValueError(f"{where}: an effect is listed twice: {keys}")
    return tuple(k for k in keys if night is None or not since[k] or since[k] <= str(night))
