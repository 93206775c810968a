"""A device's model: the effects a user decided it has, with the values the evidence gives them.

The config names the effects (``devices: TRI-01: effects: [channel_delay@2]``, checked by
:func:`borescan.effects.device_model_effects`); their values and standard uncertainties come from the
device's pooled examinations (``pooled_findings`` rows: the effect fitted across the device's scans, named
as a finding or fitted as part of the model). A night's calibration carries each effect at the latest
estimate from an earlier night (the pooled examination of a night comes after its calibration): the
readings are corrected for a beam or reading effect (:func:`borescan.physics.tri.tri_correct_readings`), a
channel delay is carried by the time the channel's angle is taken at (:func:`channel_time_offsets`), and
its parameters' uncertainties enter the GUM budgets of the calibration and of every diameter measured with
it (one input per parameter, the same key in both). An effect listed without an estimate yet is recorded
as such and not corrected.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from borescan.effects import EFFECTS, Effect
from borescan.physics.tri import CORRECTABLE_STAGES, tri_correct_readings
from borescan.uncertainty import Input

__all__ = [
    "CORRECTABLE_STAGES",
    "DeviceEffect",
    "device_model_at",
    "carried_effects",
    "correct",
    "channel_time_offsets",
    "derivatives",
    "gum_input",
    "from_dicts",
    "input_key",
    "correct_inputs",
    "carry",
    "lookup",
    "auto_keys",
]

#: relative step of the central differences of the corrected readings in a carried parameter
_STEP = 1e-3


@dataclass(frozen=True)
class DeviceEffect:
    """One entry of a device model as a calibration carries it.

    key : the config's registry key (``channel_delay@2``, ``sensor_offset@all``)
    effects : the effect with its carried values, one per channel for ``@all``; () when no
        pooled examination has estimated it yet
    u : standard uncertainty per parameter name (the registry's names, e.g. ``tau_s``)
    night : night of the pooled examination that gave the values (None: not estimated)
    evidence_scans : the scans that examination fitted
    source : ``"config"`` (the user's decision) or ``"automatic"`` (:func:`auto_keys`)
    """

    key: str
    effects: tuple[Effect, ...] = ()
    u: Mapping[str, float] = field(default_factory=dict)
    night: str | None = None
    evidence_scans: tuple[str, ...] = ()
    source: str = "config"

    @property
    def estimated(self) -> bool:
        """Whether the entry carries an estimate (an effect with values)."""
        return bool(self.effects)

    def values(self) -> dict[str, float]:
        """Return the carried parameter values (the registry's names, without the channel)."""
        if not self.effects:
            return {}
        return {k: float(v) for k, v in self.effects[0].params.items() if k not in ("channel", "k")}

    def to_dict(self) -> dict:
        """Return the entry as JSON-ready data (:meth:`from_dict` reads it back)."""
        return {
            "key": self.key,
            "effect": self.key.split("@")[0],
            "estimated": self.estimated,
            "values": self.values(),
            "u": {k: float(v) for k, v in self.u.items()},
            "night": self.night,
            "evidence_scans": list(self.evidence_scans),
            "effects": [e.to_dict() for e in self.effects],
            "source": self.source,
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> "DeviceEffect":
        """Return the entry written by :meth:`to_dict`."""
        return cls(
            d["key"],
            tuple(Effect.from_dict(e) for e in d.get("effects") or ()),
            dict(d.get("u") or {}),
            d.get("night"),
            tuple(d.get("evidence_scans") or ()),
            d.get("source", "config"),
        )

    def with_value(self, name: str, value: float) -> "DeviceEffect":
        """Return the same entry with parameter ``name`` at ``value`` (every channel of an ``@all`` entry)."""
        return DeviceEffect(
            self.key,
            tuple(Effect(e.name, {**e.params, name: value}) for e in self.effects),
            self.u,
            self.night,
            self.evidence_scans,
            self.source,
        )


def from_dicts(items: Iterable[Mapping] | None) -> list[DeviceEffect]:
    """Return a calibration's recorded device model (``diagnostics["device_model"]``) as entries."""
    return [DeviceEffect.from_dict(d) for d in items or ()]


def input_key(device_id: str, entry: DeviceEffect, name: str) -> str:
    """Key of the GUM input of one carried parameter (the same in a calibration's and a diameter's budget)."""
    return f"device_model:{device_id}:{entry.key}:{name}@{entry.night}"


def _matches(row: Mapping, name: str, channel: str | None) -> bool:
    if row.get("effect") != name:
        return False
    ch = row.get("channel")
    if channel is None:
        return ch is None
    if channel == "all":
        return ch in (None, 0)
    return ch is not None and int(ch) == int(channel)


def device_model_at(
    device_id: str,
    keys: Sequence[str],
    pooled_rows: Iterable[Mapping],
    night: str,
    channels: Sequence[int],
    auto: Sequence[str] = (),
) -> list[DeviceEffect]:
    """Return the device model of ``device_id`` as a calibration on ``night`` carries it.

    Parameters
    ----------
    keys : the config's effects of the device (``devices.<id>.effects``)
    pooled_rows : ``pooled_findings`` rows (any nights, any devices); only this device's rows of
        nights before ``night`` that give the effect's parameters are used, the latest night's
    channels : the device's channels (an ``@all`` entry acts on each)
    auto : keys that entered automatically (:func:`auto_keys`), after ``keys`` unless listed there

    Returns
    -------
    list of :class:`DeviceEffect`, in the order of ``keys``.
    """
    rows = sorted(
        (
            r
            for r in pooled_rows
            if r.get("device_id") == device_id and str(r.get("night")) < str(night) and r.get("parameters")
        ),
        key=lambda r: str(r["night"]),
    )
    out = []
    listed = [(k, "config") for k in keys] + [(k, "automatic") for k in auto if k not in set(keys)]
    for key, source in listed:
        name, _, ch = str(key).partition("@")
        ch = ch or None
        spec = EFFECTS[name]
        wanted = [k for k in spec.params if k not in ("channel", "k")]
        hit = None
        for r in rows:
            p = json.loads(r["parameters"])
            if _matches(r, name, ch) and all(k in p for k in wanted):
                hit = (r, p)
        if hit is None:
            out.append(DeviceEffect(key, source=source))
            continue
        r, p = hit
        u_all = json.loads(r.get("uncertainties") or "{}")
        vals = {k: float(p[k]) for k in wanted}
        chans = [int(ch)] if ch not in (None, "all") else (list(channels) if ch == "all" else [None])
        effs = tuple(Effect(name, vals if c is None else {**vals, "channel": c}) for c in chans)
        u = {k: float(u_all.get(f"u_{k}", 0.0) or 0.0) for k in wanted}
        out.append(
            DeviceEffect(
                key,
                effs,
                u,
                str(r["night"]),
                tuple(s for s in (r.get("evidence_scans") or "").split(",") if s),
                source,
            )
        )
    return out


def auto_keys(device_id: str, pooled_rows: Iterable[Mapping], night: str, n_nights: int) -> list[str]:
    """Return the device effects that enter a device model automatically on ``night``.

    Device effects that enter a device model automatically on ``night``: named (not as part of the
    model) by the device's pooled examinations of each of its ``n_nights`` latest nights before
    ``night`` (same effect and channel; device-scope effects of the registry only). [] when
    ``n_nights`` is 0 (off) or the device has fewer pooled nights; an effect leaves as soon as one of
    those nights does not name it.
    """
    if n_nights <= 0:
        return []
    by_night: dict[str, set[str]] = {}
    for r in pooled_rows:
        if r.get("device_id") != device_id or str(r.get("night")) >= str(night):
            continue
        named = by_night.setdefault(str(r["night"]), set())
        spec = EFFECTS.get(r.get("effect") or "")
        if spec is None or spec.scope != "device" or r.get("in_device_model") or not spec.fit:
            continue
        ch = r.get("channel")
        named.add(r["effect"] + ("" if ch is None else "@all" if int(ch) == 0 else f"@{int(ch)}"))
    nights = sorted(by_night)[-n_nights:]
    if len(nights) < n_nights:
        return []
    keys = set.intersection(*(by_night[n] for n in nights))
    return sorted(keys)


def lookup(keys_of, pooled_rows: Iterable[Mapping], night: str, auto_nights: int = 0):
    """Return the device model a calibration on ``night`` carries, per device.

    (device id, channels) -> the device model a calibration on ``night`` carries
    (:func:`device_model_at`); ``keys_of(device id)`` gives the config's effects of the device, and
    with ``auto_nights`` > 0 :func:`auto_keys` adds those named night after night.
    """
    rows = list(pooled_rows)
    return lambda device_id, channels: device_model_at(
        device_id, keys_of(device_id), rows, night, channels, auto_keys(device_id, rows, night, auto_nights)
    )


def carried_effects(model: Iterable[DeviceEffect]) -> list[Effect]:
    """Return the effects of the device model with an estimate (every stage)."""
    return [e for entry in model for e in entry.effects]


def correct(t_s, readings_mm, channels, model: Iterable[DeviceEffect], range_mm) -> np.ndarray:
    """Return readings corrected for the device model's beam and reading effects.

    See :func:`borescan.physics.tri.tri_correct_readings`; time-base effects are carried by
    :func:`channel_time_offsets`. Unchanged when there are none.
    """
    effs = [e for e in carried_effects(model) if e.spec.stage in CORRECTABLE_STAGES]
    if not effs:
        return np.asarray(readings_mm, dtype=float)
    return tri_correct_readings(t_s, readings_mm, channels, effs, range_mm)


def channel_time_offsets(
    model: Iterable[DeviceEffect], channels: Sequence[int], *, zeros: bool = False
) -> np.ndarray | None:
    """Return the per-channel time offsets of the carried time-base effects.

    Per channel tau (c,) [s] of the carried time-base effects: channel c's reading at stamp t is the
    geometry of time t - tau_c (``channel_delay``; the registry's forward t' = t - tau at t = 0).
    None without any (a still scene ignores them: static poses need none), zeros when ``zeros``.
    """
    tau = np.zeros(len(channels))
    for e in carried_effects(model):
        if e.spec.stage == "time_base":
            tau[list(channels).index(e.channel)] += -float(
                e.spec.forward["tri_lds"](np.zeros(1), e.params)[0]
            )
    return tau if zeros or np.any(tau) else None


def derivatives(model: Sequence[DeviceEffect], f) -> dict[tuple[int, str], np.ndarray]:
    """Return d f(model) / d(each carried parameter) by central differences.

    d f(model) / d(each carried parameter) by central differences, the parameter moved by
    +-``_STEP`` of its size or its u, whichever is larger.

    ``f`` maps a device model to an array or a number (corrected readings, channel time offsets, a
    diameter). Returns {(index of the entry in ``model``, parameter name): derivative [f's unit per
    parameter unit]}; entries without an estimate or without uncertainty are skipped.
    """
    model = list(model)
    out = {}
    for i, entry in enumerate(model):
        if not entry.estimated:
            continue
        for name, u in entry.u.items():
            if not (u > 0):
                continue
            v0 = entry.values()[name]
            h = max(abs(v0), u) * _STEP
            up, dn = (
                [m if j != i else entry.with_value(name, v0 + s * h) for j, m in enumerate(model)]
                for s in (1.0, -1.0)
            )
            out[(i, name)] = (np.asarray(f(up), dtype=float) - np.asarray(f(dn), dtype=float)) / (2 * h)
    return out


def gum_input(device_id: str, entry: DeviceEffect, name: str) -> Input:
    """Return the GUM input of one carried parameter.

    Return the GUM input of one carried parameter (normal, the pooled fit's standard uncertainty); the same
    key (:func:`input_key`) in a calibration's budget and in a diameter's, so the two add.
    """
    return Input(
        input_key(device_id, entry, name),
        f"{entry.key} {name} (device model, readings corrected for it)",
        name,
        EFFECTS[entry.key.split("@")[0]].params.get(name, "-"),
        entry.values()[name],
        float(entry.u[name]),
        "normal",
        source=f"pooled examination of {device_id} on {entry.night} "
        f"({', '.join(entry.evidence_scans) or 'its scans'})",
    )


def correct_inputs(inputs: list, model) -> list:
    """Return a calibration's per-scan inputs with corrected readings.

    Per scan inputs of a calibration (:class:`borescan.stages.calibration_fit.SpindleInputs`) with the
    readings corrected for the model's beam and reading effects (:func:`correct`; a channel delay is
    carried by the fit's angles); the recorded readings are kept as ``readings_recorded_mm`` (the
    budget differentiates the correction there, :func:`derivatives`). Unchanged without such effects.
    """
    if not any(e.spec.stage in CORRECTABLE_STAGES for e in carried_effects(model)):
        return inputs
    return [
        replace(
            x,
            readings_recorded_mm=x.readings_mm,
            readings_mm=correct(x.t_s, x.readings_mm, x.channels, model, x.range_mm),
        )
        for x in inputs
    ]


def carry(model: Sequence[DeviceEffect], device_id: str, inputs: list, log=print) -> list:
    """Log what a calibration carries of its device model; return corrected inputs.

    Say in the log what a calibration of ``device_id`` carries of its ``model`` and return its inputs
    corrected for it (:func:`correct_inputs`).
    """
    for m in model:
        values = ", ".join(f"{k} = {v:.6g} +- {m.u.get(k, float('nan')):.2g}" for k, v in m.values().items())
        log(
            f"{device_id}: device model {m.key} ({m.source}) "
            + (
                f"carried at {values} (pooled examination of {m.night})"
                if m.estimated
                else "not estimated yet: not corrected"
            )
        )
    return correct_inputs(inputs, model)
