"""Registry of the named effects of ``shared/spec/geometry-and-effects.md``.

One :class:`EffectSpec` per name of the spec's "Named effects" table, with exactly the
spec's parameter names (``channel`` is the spec's ``c``). Each spec carries the stage of
the forward model where it acts and one pure forward function per device type.

Stages, in the order the digital twin (:mod:`borescan.simulate`) composes them:

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
of the same name on different channels.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from borescan.geometry import Bore, RodLayer

__all__ = [
    "STAGES",
    "EffectSpec",
    "Effect",
    "EFFECTS",
    "get_effect",
    "parse_effect",
    "effects_from_dicts",
    "effects_to_dicts",
    "sort_effects",
    "apply_effects",
    "nonlinearity_bow",
]

STAGES: tuple[str, ...] = ("time_base", "kinematics", "spindle_position", "bore", "beam", "reading", "output")
TRI = "tri_lds"
ROD = "rod"


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
    """

    name: str
    device_types: tuple[str, ...]
    params: Mapping[str, str]
    stage: str
    forward: Mapping[str, Callable[..., Any]]
    definition: str

    @property
    def per_channel(self) -> bool:
        """True when the effect acts on one channel (has a ``channel`` parameter)."""
        return "channel" in self.params


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
            raise ValueError(
                f"effect {self.name!r} takes parameters {sorted(wanted)}, got {sorted(given)}"
            )
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
        return EFFECTS[self.name]

    @property
    def channel(self) -> int | None:
        return self.params.get("channel")

    def to_dict(self) -> dict:
        """``{"name": ..., "params": {...}}`` (JSON-ready)."""
        return {"name": self.name, "params": dict(self.params)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Effect":
        return cls(d["name"], dict(d["params"]))

    def __str__(self) -> str:
        return self.name + ":" + ",".join(f"{k}={v:g}" for k, v in self.params.items())


# --------------------------------------------------------------------------- forward functions


def _channel_delay(t_s: np.ndarray, p: Mapping) -> np.ndarray:
    """Channel c at time t shows the reading of time t - tau: t' = t - tau."""
    return np.asarray(t_s, dtype=float) - p["tau_s"]


def _speed_error(x_rad: np.ndarray, p: Mapping) -> np.ndarray:
    """Spindle turns at (1 + eps) times the commanded profile: x' = (1 + eps) x, x = Phi(t) the commanded angle."""
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


def _thermal_expansion(bore: Bore, p: Mapping, cte_per_k: float) -> Bore:
    """R = R20 (1 + cte (T - 20))."""
    return replace(bore, radius_mm=bore.radius_mm * (1.0 + cte_per_k * (p["temperature_c"] - 20.0)))


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
    """Reading = in-plane distance / cos(gamma): v' = v / cos(gamma)."""
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
    """The bow 4 u (1 - u), u = v / range_mm (1 at mid-range, 0 at both ends)."""
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
    """A fraction ``rate`` of samples jumps by +-size (sign random, magnitude size * U(0.75, 1.25))."""
    v = np.array(v_mm, dtype=float, copy=True)
    hit = rng.random(v.shape) < p["rate"]
    sign = np.where(rng.random(v.shape) < 0.5, -1.0, 1.0)
    mag = p["size_mm"] * rng.uniform(0.75, 1.25, v.shape)
    v[hit] += (sign * mag)[hit]
    return v


def _reading(f):
    return {TRI: f, ROD: f}


EFFECTS: dict[str, EffectSpec] = {
    s.name: s
    for s in [
        EffectSpec("sensor_offset", (TRI, ROD), {"channel": "channel", "b_mm": "mm"}, "reading",
                   _reading(_sensor_offset), "v' = v + b"),
        EffectSpec("sensor_gain", (TRI, ROD), {"channel": "channel", "g": "-"}, "reading",
                   _reading(_sensor_gain), "v' = v (1 + g)"),
        EffectSpec("sensor_nonlinearity", (TRI, ROD), {"channel": "channel", "a_mm": "mm"}, "reading",
                   _reading(_sensor_nonlinearity), "v' = v + a 4u(1 - u), u = v / range_mm"),
        EffectSpec("sensor_drift", (TRI, ROD), {"channel": "channel", "k_mm_per_s": "mm/s"}, "reading",
                   _reading(_sensor_drift), "v' = v + k t"),
        EffectSpec("channel_delay", (TRI,), {"channel": "channel", "tau_s": "s"}, "time_base",
                   {TRI: _channel_delay}, "channel c at time t shows the reading of time t - tau"),
        EffectSpec("quantization", (TRI, ROD), {"channel": "channel", "lsb_mm": "mm"}, "output",
                   _reading(_quantization), "v' = lsb round(v / lsb)"),
        EffectSpec("outliers", (TRI, ROD), {"channel": "channel", "rate": "-", "size_mm": "mm"}, "output",
                   _reading(_outliers), "a fraction rate of samples jumps by about +-size"),
        EffectSpec("vibration", (TRI,), {"f_hz": "Hz", "a_mm": "mm", "phase": "rad"}, "reading",
                   {TRI: _vibration}, "v' = v + a sin(2 pi f t + phase)"),
        EffectSpec("speed_error", (TRI,), {"eps": "-"}, "kinematics",
                   {TRI: _speed_error}, "the spindle turns at (1 + eps) times the commanded profile"),
        EffectSpec("speed_ripple", (TRI,), {"a_rad": "rad", "phase": "rad"}, "kinematics",
                   {TRI: _speed_ripple}, "phi(t) = omega t + a sin(omega t + phase)"),
        EffectSpec("spindle_error_motion", (TRI,), {"k": "-", "rho_mm": "mm", "phase": "rad"},
                   "spindle_position", {TRI: _spindle_error_motion},
                   "S(phi) = S0 + rho (cos(k phi + phase), sin(k phi + phase))"),
        EffectSpec("axis_tilt", (TRI,), {"beta_rad": "rad", "azimuth": "rad"}, "bore",
                   {TRI: _axis_tilt}, "bore is an ellipse R / cos(beta) along azimuth, R across"),
        EffectSpec("bore_lobing", (TRI,), {"k": "-", "a_mm": "mm", "phase": "rad"}, "bore",
                   {TRI: _bore_lobing}, "R(theta) = R + a cos(k (theta - phase))"),
        EffectSpec("thermal_expansion", (TRI, ROD), {"temperature_c": "degC"}, "bore",
                   {TRI: _thermal_expansion, ROD: _thermal_expansion}, "R = R20 (1 + cte (T - 20))"),
        EffectSpec("beam_tilt", (TRI, ROD), {"channel": "channel", "gamma_rad": "rad"}, "beam",
                   {TRI: _beam_tilt_tri, ROD: _beam_tilt_rod}, "reading = in-plane distance / cos(gamma)"),
        EffectSpec("beam_offset", (ROD,), {"channel": "channel", "d_mm": "mm"}, "beam",
                   {ROD: _beam_offset_rod}, "rod: layer c's beam misses the axis by d (Wang 2017 Eq. 5)"),
    ]
}
_ORDER = {name: i for i, name in enumerate(EFFECTS)}


def get_effect(name: str) -> EffectSpec:
    """The :class:`EffectSpec` of ``name``; unknown names raise ``ValueError`` listing the valid ones."""
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
    return [e.to_dict() for e in effects]


def effects_from_dicts(items: Iterable[Mapping]) -> list[Effect]:
    return [Effect.from_dict(d) for d in items]


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
    for e in sorted(effects, key=lambda e: _ORDER[e.name]):  # stable: same name keeps given order
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
