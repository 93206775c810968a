"""The registry of the named effects: one :class:`~borescan.effects.spec.EffectSpec` per name of the spec.

The module doc of :mod:`borescan.effects` describes each field; :class:`Effect` is one effect with its
parameters, checked against the registry.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from borescan.effects import functions as fx
from borescan.effects.spec import ROD, TRI, DeviceFit, EffectSpec, FitParam

__all__ = [
    "Effect",
    "EFFECTS",
    "get_effect",
    "calibration_absorbers",
    "parse_effect",
    "effects_to_dicts",
    "effects_from_dicts",
    "as_effects",
]


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


def _reading(f):
    return {TRI: f, ROD: f}


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
            _reading(fx.sensor_offset),
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
            _reading(fx.sensor_gain),
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
            _reading(fx.sensor_nonlinearity),
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
            _reading(fx.sensor_drift),
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
            {TRI: fx.channel_delay},
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
            _reading(fx.quantization),
            "v' = lsb round(v / lsb)",
            candidate=_EVIDENCE,
            example={"channel": 2, "lsb_mm": 0.002},
        ),
        EffectSpec(
            "outliers",
            (TRI, ROD),
            {"channel": "channel", "rate": "-", "size_mm": "mm"},
            "output",
            _reading(fx.outliers),
            "a fraction rate of samples jumps by about +-size",
            candidate=_EVIDENCE,
            example={"channel": 2, "rate": 0.01, "size_mm": 0.05},
        ),
        EffectSpec(
            "vibration",
            (TRI,),
            {"f_hz": "Hz", "a_mm": "mm", "phase": "rad"},
            "reading",
            {TRI: fx.vibration},
            "v' = v + a sin(2 pi f t + phase)",
            fit=(FitParam("f_hz", "Hz", 1e-2), FitParam("A", "mm", 1e-3), FitParam("B", "mm", 1e-3)),
            to_internal=fx.VIBRATION[0],
            from_internal=fx.VIBRATION[1],
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
            {TRI: fx.speed_error},
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
            {TRI: fx.speed_ripple},
            "phi(t) = omega t + a sin(omega t + phase)",
            fit=(FitParam("A", "rad", 1e-3), FitParam("B", "rad", 1e-3)),
            to_internal=fx.RIPPLE[0],
            from_internal=fx.RIPPLE[1],
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
            {TRI: fx.spindle_error_motion},
            "S(phi) = S0 + rho (cos(k phi + phase), sin(k phi + phase))",
            fit=(FitParam("A", "mm", 1e-3), FitParam("B", "mm", 1e-3)),
            to_internal=fx.MOTION[0],
            from_internal=fx.MOTION[1],
            candidate={"tri_spindle": "screen"},
            scope="scan",
            example={"k": 3, "rho_mm": 0.006, "phase": 0.5},
        ),
        EffectSpec(
            "axis_tilt",
            (TRI,),
            {"beta_rad": "rad", "azimuth": "rad"},
            "bore",
            {TRI: fx.axis_tilt},
            "bore is an ellipse R / cos(beta) along azimuth, R across",
            fit=(FitParam("p", "rad^2", 1e-4), FitParam("q", "rad^2", 1e-4)),
            to_internal=fx.axis_tilt_to_internal,
            from_internal=fx.axis_tilt_from_internal,
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
            {TRI: fx.bore_lobing},
            "R(theta) = R + a cos(k (theta - phase))",
            fit=(FitParam("A", "mm", 1e-3), FitParam("B", "mm", 1e-3)),
            to_internal=fx.LOBING[0],
            from_internal=fx.LOBING[1],
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
            {TRI: fx.thermal_expansion, ROD: fx.thermal_expansion},
            "R = R20 (1 + cte (T - 20))",
            fit=(FitParam("dT", "K", 1.0),),
            to_internal=fx.thermal_to_internal,
            from_internal=fx.thermal_from_internal,
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
            {TRI: fx.beam_tilt_tri, ROD: fx.beam_tilt_rod},
            "reading = in-plane distance / cos(gamma)",
            fit=(FitParam("h", "-", 1e-4, 0.0),),
            to_internal=fx.beam_tilt_to_internal,
            from_internal=fx.beam_tilt_from_internal,
            # a rod layer's tilt adds to its own gamma0: the sign matters (first order in gamma0 gamma, and
            # with the axis deflected), so a rod fits the signed gamma itself
            device_fit={ROD: DeviceFit((FitParam("gamma_rad", "rad", 1e-2),))},
            candidate=_ALL_KINDS,
            absorbed_by={"rod": {"l0": "l0_mm of the layer (to first order)"}},
            example={"channel": 2, "gamma_rad": 0.06},
        ),
        EffectSpec(
            "beam_offset",
            (ROD,),
            {"channel": "channel", "d_mm": "mm"},
            "beam",
            {ROD: fx.beam_offset_rod},
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
