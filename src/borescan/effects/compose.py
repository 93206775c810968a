"""Effects composed on readings: grouped by stage in the registry's order, applied stage by stage."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from borescan.effects.registry import EFFECTS, Effect
from borescan.effects.spec import STAGES, TRI

__all__ = ["sort_effects", "apply_effects"]


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
