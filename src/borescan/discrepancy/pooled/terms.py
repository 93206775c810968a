"""The pooled set's inputs, effect terms and the registry's absorption conditions.

:class:`PooledScan`, :class:`PooledTerm`, :data:`CONDITIONS`; the model is
:mod:`borescan.discrepancy.pooled.model`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from borescan.discrepancy.examine import against_reference, scan_arrays
from borescan.discrepancy.terms import Term
from borescan.discrepancy.tri import TriData, tri_data_from_arrays
from borescan.discrepancy.tri_signals import SAME_WITHIN, relative_spread
from borescan.effects import device_effect_key

if TYPE_CHECKING:  # the conditions are asked of the model, which is built from these terms
    from borescan.discrepancy.pooled.model import PooledModel


#: Typical magnitudes of the pooled base parameters (finite-difference steps, starts).
BASE_SCALE = {
    "cx": 1e-2,
    "cy": 1e-2,
    "phase": 1e-3,
    "dR": 1e-3,
    "eps": 1e-4,
    "dpsi": 1e-4,
    "drho": 1e-2,
    "dg": 1e-3,
    "dbeta": 1e-4,
    "dd_b": 1e-3,
}


# ----------------------------------------------------------------------------------- inputs


@dataclass
class PooledScan:
    """One scan of the pooled set: its arrays (:class:`TriData`), night and artifact id."""

    data: TriData
    night: str
    artifact: str
    device_id: str = ""

    @property
    def scan_id(self) -> str:
        """The scan's id."""
        return self.data.scan_id


def pooled_scan(scan, max_samples: int | None = None, beams=None) -> PooledScan:
    """Return a three-sensor spindle scan as :class:`PooledScan`.

    The scan is a ``RawScan``-like object (``.meta``, ``.lds``, ``.spindle``); scans longer than
    ``max_samples`` are cut to four blocks, as one scan is. ``beams``: the reference calibration's, in place
    of ``device.nominal`` (which may be missing).
    """
    meta = against_reference(scan.meta, beams)
    sid = meta["scan_id"]
    if meta["device"]["type"] != "tri_lds":
        raise ValueError(
            f"{sid}: scan.json: the pooled examination takes tri_lds spindle scans, "
            f"not {meta['device']['type']!r}"
        )
    t_s, channels, vals, pose, spindle = scan_arrays(scan)
    if pose is not None:
        raise ValueError(f"{sid}: lds.parquet: a static scan (pose column) is not a spindle scan")
    data = tri_data_from_arrays(sid, meta, t_s, vals, channels, spindle, max_samples=max_samples)
    art = meta.get("artifact") or {}
    return PooledScan(
        data, str(meta.get("night", "")), str(art.get("id", "")), str(meta["device"].get("id", ""))
    )


# ----------------------------------------------------------------------------------- terms


@dataclass(frozen=True)
class PooledTerm(Term):
    """A :class:`~borescan.discrepancy.tri.Term` that acts on one group of the pooled scans.

    ``group`` None: every scan (the key is the registry's, ``sensor_gain@2``); otherwise the group
    label (a night, ``<artifact>@<night>``, a scan id) after ``#`` in the key.
    """

    group: str | None = None
    #: frames (a night, or a scan with its own angle origin) that see an effect with an
    #: ``orientation`` (registry) turned from the group's reference: parameter ``<key>.turn@<frame>`` [rad]
    turns: tuple[str, ...] = ()

    @property
    def key(self) -> str:
        """The term's key, with ``#group`` for a term of one group of scans."""
        k = super().key
        return k if self.group is None else f"{k}#{self.group}"

    def names(self) -> list[str]:
        """Return the term's parameter names, then one turn per scan of ``turns``."""
        return super().names() + [f"{self.key}.turn@{sid}" for sid in self.turns]

    def scales(self) -> list[float]:
        """Return the typical sizes of :meth:`names`' parameters."""
        return super().scales() + [1e-2] * len(self.turns)


_SPEED = Term("speed_error")  # the per-scan speed scale of a commanded angle (parameter <scan>:eps)


def parse_device_effect(key: str, channels: Sequence[int] | None = None, device: str = "") -> PooledTerm:
    """Return the term of a device-model entry (checked by :func:`borescan.effects.device_effect_key`)."""
    name, ch = device_effect_key(key, channels, device)
    return PooledTerm(name) if ch is None else PooledTerm(name, ch)


# ----------------------------------------------------------------------------------- conditions


@dataclass(frozen=True)
class Condition:
    """A condition under which a base parameter stops absorbing an effect.

    A condition of a set of scans under which a base parameter stops absorbing an effect
    (named by the registry's ``absorbed_unless``).

    holds : (model, scan indices) -> bool
    design : (model, scan indices) -> what the scans have, in words
    separated_by : the measurement that makes the condition hold
    """

    holds: Callable[["PooledModel", Sequence[int]], bool]
    design: Callable[["PooledModel", Sequence[int]], str]
    separated_by: str


CONDITIONS: dict[str, Condition] = {
    "speeds_differ": Condition(
        holds=lambda m, ks: relative_spread(np.concatenate([m.signed_speeds(k) for k in ks])) > SAME_WITHIN,
        design=lambda m, ks: (
            "signed speeds "
            + ", ".join(f"{m.scan_ids[k]} {np.median(m.signed_speeds(k)):+.3g}" for k in ks)
            + " rad/s"
        ),
        separated_by="a scan at another speed (or turning the other way)",
    ),
    "radii_differ": Condition(
        holds=lambda m, ks: relative_spread(np.array([m.scans[k].data.radius_mm for k in ks])) > SAME_WITHIN,
        design=lambda m, ks: (
            "gauge radii " + ", ".join(sorted({f"{m.scans[k].data.radius_mm:.3f}" for k in ks})) + " mm"
        ),
        separated_by="a scan of a gauge of another diameter",
    ),
}
