"""A device's model in the config (``devices: <id>: effects``): its keys checked against the registry."""

from __future__ import annotations

import re
from collections.abc import Sequence

from borescan.effects.registry import EFFECTS

__all__ = ["DEVICE_MODEL_SCAN_KIND", "device_effect_key", "device_model_effects"]

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
