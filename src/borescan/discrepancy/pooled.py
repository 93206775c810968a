"""Pooled examination of the spindle scans of one device (one night, or a window of nights).

One scan cannot tell some effects from the calibration parameters that absorb them (a
``channel_delay`` is a change of beta at one constant speed; a ``sensor_nonlinearity`` is an
offset on a centred bore); several scans of the same device, made at other speeds, other
eccentricities or in other gauges, can. This module examines K scans together with the
single-scan workflow's own search (:func:`borescan.discrepancy.examine.examine_model`: base fit,
outliers, quantisation, linear screen, exact refits, pairs, BIC with the same threshold), on a
model composed of K single-scan models (:class:`~borescan.discrepancy.tri.TriModel`, so the one
forward model :func:`borescan.physics.tri.tri_forward` of the twin), lmfit style:

- device parameters, shared by every scan and unprefixed: the beam geometry as offsets from a
  start (a calibration) in the calibration's straightened form (the quantities the data fix best,
  :func:`borescan.calibrate.full_fit.fit_full_calibration`): ``dpsi[j]`` of psi = beta + asin(rho / R)
  (every channel but the first: a common turn is each scan's centre), ``drho[j]``, ``dg[j]`` of
  g = d_b + rho^2 / (2 R) (j the channel's index, R the mean gauge radius); a weakly determined
  rho then moves along the valley instead of across it;
- per-scan nuisance parameters, prefixed by the scan id: the bore centre ``<scan>:cx``,
  ``<scan>:cy``; the start phase ``<scan>:phase`` when the spindle moves; the radius
  ``<scan>:dR`` when the artifact is not certified; the speed scale ``<scan>:eps`` when the angle
  is commanded, not measured (as the calibration fits it; the registry's ``speed_error`` is then
  that parameter);
- effect terms (:class:`PooledTerm`), one parameter set per group of scans that the registry's
  ``scope`` of the effect says shares it: ``device`` every scan, ``night`` the scans of one
  night, ``artifact`` the scans of one artifact on one night, ``scan`` one scan. A term shared by
  every scan has the registry key (``channel_delay@2``); one for a group carries the group after a
  ``#`` (``bore_lobing[k=3]#RG-275``). An effect fixed in the artifact (the registry's
  ``orientation``: a gauge's lobing, its tilt) is seen turned on another night (the gauge mounted
  again) and in a scan whose angle has its own origin (a commanded angle on a fixed spindle, where
  the phase is the direction of the centre offset): its term fits one turn per such frame
  (``<key>.turn@<night or scan>``) and shares the rest.

Absorption is decided on the pooled design from the registry: a base parameter of
``absorbed_by["tri_spindle"]`` absorbs a term when it is free for every scan the term covers (a
device parameter absorbs only terms that cover every scan), unless the condition the registry
names in ``absorbed_unless`` holds for those scans (:data:`CONDITIONS`: ``speeds_differ``,
``radii_differ``). Absorbed effects are not candidates; the verdict lists them with the
measurement that would separate them, taken from the condition (none for an offset, which is a
d_b whatever the scans).

Residuals are weighted per scan and channel by the scan's own noise floor, so that the BIC of the
pooled fit is the likelihood of K scans of different noise. Which scans carry the evidence: the
decrease of each scan's chi-square (residual over its noise floor, squared, summed) from the base
fit to the verdict's fit; the carriers are the fewest scans, largest decrease first, that hold 90 %
of the total decrease.

Calibration drift (:func:`borescan.calibrations.calibration_drift`): :func:`drift_explanations`
says which named effect a flagged change of a beam parameter is explained by (the registry's
absorbing parameter on that channel), with the change a calibration ignoring the effect would
make (:func:`calibration_equivalent`).

Entry points: :func:`examine_pooled` (findings of the device, ``findings.json``-like),
:func:`pooled_scan` (one ``RawScan``-like object to :class:`PooledScan`), :func:`drift_explanations`.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from types import SimpleNamespace
from typing import Any

import numpy as np

from borescan.discrepancy.examine import (
    Examination,
    _clean,
    _named_entry,
    against_reference,
    examine_model,
    scan_arrays,
)
from borescan.discrepancy.search import lstsq
from borescan.discrepancy.fitting import FitResult, dead_zone, fit_least_squares, noise_floor_mm, spike_mask
from borescan.discrepancy.tri_signals import (
    SAME_WITHIN,
    relative_spread,
    rotation_eps,
    signed_speeds,
    tilt_start,
)
from borescan.discrepancy.tri import (
    SCAN_KIND,
    Term,
    TriData,
    TriModel,
    registry_terms,
    term_parameters,
    term_values,
    tri_data_from_arrays,
)
from borescan.effects import EFFECTS, SCOPES, Effect, calibration_absorbers, device_effect_key
from borescan.geometry import Beams
from borescan.physics.tri_params import straighten, unstraighten

__all__ = [
    "PooledScan",
    "PooledTerm",
    "PooledData",
    "PooledModel",
    "PooledExamination",
    "CONDITIONS",
    "pooled_scan",
    "examine_pooled",
    "calibration_equivalent",
    "drift_explanations",
    "separation",
    "CARRIER_SHARE",
    "parse_device_effect",
]

#: Share of the total chi-square decrease that the scans named as carrying the evidence hold.
CARRIER_SHARE = 0.9
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


# ----------------------------------------------------------------------------------- model


class _ScanModel(TriModel):
    """One scan's :class:`TriModel` with moved beams.

    One scan's :class:`TriModel` whose beams move by ``dbeta[j]``, ``drho[j]``, ``dd_b[j]`` (every
    channel).
    """

    def base(self, p: dict[str, float]):
        b = super().base(p)
        c = len(self.data.channels)
        d = {n: np.array([p.get(f"{n}[{j}]", 0.0) for j in range(c)]) for n in ("dbeta", "drho", "dd_b")}
        if not any(v.any() for v in d.values()):
            return b
        bm = b.beams
        return replace(
            b,
            beams=Beams(bm.channels, bm.beta_rad + d["dbeta"], bm.rho_mm + d["drho"], bm.d_b_mm + d["dd_b"]),
        )


@dataclass
class PooledData:
    """The pooled scans' readings stacked (what the search reads): ``scan_id`` labels the set."""

    scan_id: str
    scan_ids: tuple[str, ...]
    t_s: np.ndarray
    values_mm: np.ndarray
    channels: tuple[int, ...]
    bounds: np.ndarray
    n_total: int


class PooledModel:
    """K spindle scans of one device: shared beams and effects, per-scan nuisance (module doc).

    Provides the interface of :func:`~borescan.discrepancy.examine.examine_model` (that of
    :class:`~borescan.discrepancy.tri.TriModel`) over the stacked samples.

    Parameters
    ----------
    scans : the scans (same channels), in any order
    beams : start of the shared beam geometry (a calibration); default the first scan's ``device.nominal``
    free_beams : beam parameters that are free and shared (``beta``, ``rho``, ``d_b``)
    label : name of the set in messages (default the device id)
    device_effects : registry keys of the device model (``channel_delay@2``,
        :func:`borescan.effects.device_model_effects`): terms of the base model, shared by every scan and
        fitted
        with it, never candidates
    """

    device_type = "tri_lds"
    angle_label = "device angle [deg]"
    scan_kind = SCAN_KIND

    @property
    def absorbed_by(self) -> dict[str, str]:
        """Effect -> the calibration parameters that absorb it (the registry's)."""
        return calibration_absorbers(self.scan_kind)

    def __init__(  # noqa: C901 (checks every input of the pooled set; pooled is to become an adapter of the device models)
        self,
        scans: Sequence[PooledScan],
        beams: Beams | None = None,
        free_beams: tuple[str, ...] = ("beta", "rho", "d_b"),
        label: str | None = None,
        device_effects: Sequence[str] = (),
    ):
        scans = list(scans)
        if not scans:
            raise ValueError("the pooled examination needs at least one scan")
        ids = [s.scan_id for s in scans]
        if len(set(ids)) != len(ids):
            raise ValueError(f"scan ids repeat in the pooled set: {ids}")
        bad = set(free_beams) - {"beta", "rho", "d_b"}
        if bad:
            raise ValueError(f"free_beams takes 'beta', 'rho' and/or 'd_b', got {sorted(bad)}")
        channels = scans[0].data.channels
        for s in scans:
            if s.data.channels != channels:
                raise ValueError(
                    f"{s.scan_id}: channels {s.data.channels} differ from {scans[0].scan_id}'s {channels}"
                )
        devices = {s.device_id for s in scans if s.device_id}
        if len(devices) > 1:
            raise ValueError(f"the pooled scans belong to several devices: {sorted(devices)}")
        self.scans = scans
        self.scan_ids = tuple(ids)
        self.free_beams = tuple(b for b in ("beta", "rho", "d_b") if b in free_beams)
        self.label = label or (next(iter(devices)) if devices else "pooled")
        if beams is None:
            beams = scans[0].data.beams
        if not set(channels) <= set(beams.channels):
            raise ValueError(
                f"{self.label}: the start beams have channels {beams.channels}, the scans {channels}"
            )
        idx = [beams.channels.index(ch) for ch in channels]
        self.start_beams = Beams(channels, beams.beta_rad[idx], beams.rho_mm[idx], beams.d_b_mm[idx])
        self.models = [_ScanModel(replace(s.data, beams=self.start_beams)) for s in scans]
        #: radius of the straightened beam parameters (psi, g) [mm]
        self.R_mm = float(np.mean([s.data.radius_mm for s in scans]))
        sizes = [s.data.t_s.size for s in scans]
        self.bounds = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        self.data = PooledData(
            scan_id=f"{self.label} ({len(scans)} scans)",
            scan_ids=self.scan_ids,
            t_s=np.concatenate([s.data.t_s for s in scans]),
            values_mm=np.vstack([s.data.values_mm for s in scans]),
            channels=channels,
            bounds=self.bounds,
            n_total=int(sum(s.data.n_total or s.data.t_s.size for s in scans)),
        )
        self.valid = np.isfinite(self.data.values_mm)
        self.mask = self.valid.copy()
        for k, m in enumerate(self.models):  # the single-scan models see the pooled mask (views)
            m.mask = self.mask[self._rows(k)]
        c = len(channels)
        self.weights = np.ones(c)
        self.dead_zone_mm: np.ndarray | None = None
        #: per scan and channel noise floor [mm] (set by :meth:`noise_floor`)
        self.scan_sigma = np.ones((len(scans), c))
        self._row_w = np.ones_like(self.data.values_mm)
        self.commanded = [not s.data.encoder for s in scans]
        #: effects the pooled design cannot see, with the reason (filled by :meth:`candidate_terms`)
        self.absorbed: list[dict] = []
        #: the terms of the named entries, in order (see :meth:`term_parameters`)
        self.reported: list[Term] = []
        #: the device model's terms (part of the base model)
        self.device_terms: list[PooledTerm] = [
            parse_device_effect(k, channels, self.label) for k in device_effects
        ]
        #: the base fit's parameters (see :meth:`base_summary`)
        self.base_values: dict[str, float] = {}
        #: device-model terms these scans cannot separate from a free base parameter (not fitted)
        self.device_absorbed: list[dict] = []
        every = list(range(len(scans)))
        for t in list(self.device_terms):
            why = self.absorption(t, every)
            if why is not None:
                self.device_terms.remove(t)
                self.device_absorbed.append(why)

    # ------------------------------------------------------------------ layout
    def _rows(self, k: int) -> slice:
        return slice(int(self.bounds[k]), int(self.bounds[k + 1]))

    def _nuisance(self, k: int) -> list[str]:
        d = self.scans[k].data
        return (
            ["cx", "cy"]
            + (["phase"] if d.free_phase else [])
            + (["dR"] if d.radius_free else [])
            + (["eps"] if self.commanded[k] else [])
        )

    def _shared_names(self) -> list[str]:
        c = len(self.data.channels)
        names = []
        if "beta" in self.free_beams:
            names += [f"dpsi[{j}]" for j in range(1, c)]
        if "rho" in self.free_beams:
            names += [f"drho[{j}]" for j in range(c)]
        if "d_b" in self.free_beams:
            names += [f"dg[{j}]" for j in range(c)]
        return names

    def _device_term_names(self) -> list[str]:
        return [n for t in self.device_terms for n in t.names()]

    def base_names(self) -> list[str]:
        """Return the base model's parameter names: shared, device terms, then per scan."""
        out = self._shared_names() + self._device_term_names()
        for k, sid in enumerate(self.scan_ids):
            out += [f"{sid}:{n}" for n in self._nuisance(k)]
        return out

    def base_scales(self) -> list[float]:
        """Return the typical sizes of :meth:`base_names`' parameters."""
        dev = dict(zip(self._device_term_names(), [s for t in self.device_terms for s in t.scales()]))
        return [
            dev[n] if n in dev else BASE_SCALE[n.rsplit(":", 1)[-1].split("[")[0]] for n in self.base_names()
        ]

    def base_start(self) -> dict[str, float]:
        """Return the pooled fit's start.

        Shared beams at the start geometry; per scan the centre from the first harmonic and, for a
        commanded angle, the speed scale: of 0 and the readings' spectral estimate (used when it says
        more than 0.2 %; a weak once-per-revolution line can mislead it), the one whose fit of that
        scan's nuisance alone (beams held) leaves the smaller residual.
        """
        out = {n: 0.0 for n in self._shared_names() + self._device_term_names()}
        for k, (m, sid) in enumerate(zip(self.models, self.scan_ids)):
            tries = [0.0]
            if self.commanded[k]:
                e0 = rotation_eps(m)
                if e0 is not None and abs(e0) > 2e-3:
                    tries.append(float(e0))
            best = None
            for eps in tries:
                st = self._scan_start(k, eps)
                if len(tries) > 1:
                    names = [f"{sid}:{n}" for n in self._nuisance(k)]
                    try:
                        fr = fit_least_squares(
                            lambda q, k=k: self._scan_residual(k, {**out, **q}),
                            names,
                            [st[n] for n in names],
                            [BASE_SCALE[n.rsplit(":", 1)[-1]] for n in names],
                            max_nfev=30,
                        )
                    except ValueError:
                        continue
                    if not np.isfinite(fr.rss) or (best is not None and fr.rss >= best[0]):
                        continue
                    st = fr.values()
                    best = (fr.rss, st)
                else:
                    best = (0.0, st)
            out.update(best[1] if best is not None else self._scan_start(k, 0.0))
        return out

    def _scan_start(self, k: int, eps: float) -> dict[str, float]:
        m, sid, d = self.models[k], self.scan_ids[k], self.scans[k].data
        C0 = m.initial_center(eps)
        st = {f"{sid}:cx": float(C0[0]), f"{sid}:cy": float(C0[1])}
        if d.free_phase:
            st[f"{sid}:phase"] = d.phase_rad
        if d.radius_free:
            st[f"{sid}:dR"] = 0.0
        if self.commanded[k]:
            st[f"{sid}:eps"] = eps
        return st

    def _scan_residual(self, k: int, p: dict[str, float]) -> np.ndarray:
        """Residual of scan ``k`` alone without effect terms, over its valid samples [mm]."""
        return (self.scans[k].data.values_mm - self.predict_scan(k, p, []))[self.valid[self._rows(k)]]

    def groups(self, scope: str) -> list[tuple[str | None, list[int]]]:
        """Return the groups of scans of a registry ``scope``.

        Return the groups of scans of a registry ``scope``: (label, scan indices); the label is None
        for a group of every scan.
        """
        if scope not in SCOPES:
            raise ValueError(f"unknown scope {scope!r}; valid: {SCOPES}")
        K = len(self.scans)
        if scope == "device":
            keys = [None] * K
        elif scope == "night":
            keys = [s.night for s in self.scans]
        elif scope == "artifact":
            keys = [s.artifact for s in self.scans]
        else:
            keys = list(self.scan_ids)
        out: dict[Any, list[int]] = {}
        for k, key in enumerate(keys):
            out.setdefault(key, []).append(k)
        return [(None if len(ks) == K else key, ks) for key, ks in out.items()]

    def frame_shared(self, k: int) -> bool:
        """Return whether scan ``k``'s device angle has the machine's origin.

        Scan ``k``'s device angle has the machine's origin: an encoder, or a moving spindle (whose
        phase the stream fixes). A commanded angle on a fixed spindle has its own origin (for a
        round bore the phase is the direction of the centre offset), so an effect fixed in the
        machine frame (a gauge's lobing, its tilt) appears turned by an angle of its own there.
        """
        d = self.scans[k].data
        return d.encoder or d.free_phase

    def frame_of(self, k: int) -> str:
        """Return the frame in which scan ``k`` sees an artifact's orientation.

        Return the frame in which scan ``k`` sees an artifact's orientation: its night (the artifact as
        mounted that night, in the machine's angle origin), or the scan itself when its angle has
        its own origin (:meth:`frame_shared`).
        """
        return self.scans[k].night if self.frame_shared(k) else self.scan_ids[k]

    def turns_of(self, ks: Sequence[int]) -> tuple[str, ...]:
        """Return the frames of a group's scans that see an oriented effect turned.

        Frames of a group's scans that see an oriented effect turned: every frame but the
        reference (the first frame with the machine's angle origin, else the first frame).
        """
        frames = list(dict.fromkeys(self.frame_of(k) for k in ks))
        absolute = [self.frame_of(k) for k in ks if self.frame_shared(k)]
        ref = absolute[0] if absolute else frames[0]
        return tuple(fr for fr in frames if fr != ref)

    def members(self, t: Term) -> list[int]:
        """Return indices of the scans a term acts on."""
        g = getattr(t, "group", None)
        if g is None:
            return list(range(len(self.scans)))
        for label, ks in self.groups(EFFECTS[t.effect].scope):
            if label == g:
                return ks
        raise ValueError(f"term {t.key}: no group {g!r} among the pooled scans")

    def signed_speeds(self, k: int) -> np.ndarray:
        """Signed angular speed of scan ``k`` at its samples (direction d(turned)/dt) [rad/s]."""
        return signed_speeds(self.scans[k].data)

    # ------------------------------------------------------------------ forward
    def _scan_params(self, k: int, p: dict[str, float], terms: list[Term]) -> tuple[dict, list[Term]]:
        sid = self.scan_ids[k]
        terms = [*self.device_terms, *terms]  # the device model is part of every prediction
        q = self._beam_deltas(p)
        for n in self._nuisance(k):
            if n != "eps":
                q[n] = p[f"{sid}:{n}"]
        own = [t for t in terms if getattr(t, "group", None) is None or k in self.members(t)]
        for t in own:
            for n in t.names():
                q[n] = p[n]
            frame = self.frame_of(k)
            if frame in getattr(t, "turns", ()):
                q.update(self._turned(t, p, p[f"{t.key}.turn@{frame}"]))
        if self.commanded[k]:
            q["speed_error.eps"] = p[f"{sid}:eps"]
            own = [_SPEED] + own
        return q, own

    @staticmethod
    def _turned(t: Term, p: dict[str, float], angle_rad: float) -> dict[str, float]:
        """Return the fitted values of term ``t`` with its orientation (registry) turned by ``angle_rad``."""
        spec = EFFECTS[t.effect]
        par, _ = spec.spec_params({q.name: p[f"{t.key}.{q.name}"] for q in spec.fit}, None, t.k)
        par[spec.orientation] = par[spec.orientation] + angle_rad
        return {f"{t.key}.{n}": v for n, v in spec.internal(par).items()}

    def predict_scan(self, k: int, p: dict[str, float], terms: list[Term]) -> np.ndarray:
        """Return readings (n_k, c) of scan ``k`` at pooled parameters ``p`` [mm]."""
        q, own = self._scan_params(k, p, terms)
        return self.models[k].predict(q, own)

    def residual_matrix(self, p: dict[str, float], terms: list[Term]) -> np.ndarray:
        """Unweighted residual (N, c) of the stacked scans [mm], NaN where a reading is null."""
        return np.vstack(
            [self.scans[k].data.values_mm - self.predict_scan(k, p, terms) for k in range(len(self.scans))]
        )

    def residual(self, p: dict[str, float], terms: list[Term]) -> np.ndarray:
        """Weighted residual over the unmasked samples (each scan and channel over its own noise floor)."""
        r = dead_zone(self.residual_matrix(p, terms), self.dead_zone_mm) * self.weights * self._row_w
        return r[self.mask]

    # ------------------------------------------------------------------ engine interface
    @property
    def base_description(self) -> str:
        """Return a sentence saying what the base model fits."""
        return (
            f"{len(self.scans)} scans of one device: beams ({', '.join(self.free_beams)}) shared and "
            "free from "
            "the start geometry; per scan bore centre, phase (moving spindle), radius (uncertified "
            "artifact), speed scale (commanded angle)"
        )

    @property
    def rev_hz(self) -> float:
        """Revolution frequency [Hz] of the first scan."""
        return self.models[0].rev_hz

    def noise_floor(self, r: np.ndarray) -> np.ndarray:
        """Return the per-channel floor of the pooled residual.

        Per-channel floor of the pooled residual (the scans' floors, root mean square by samples);
        also sets the per-scan weights (pooled floor / scan floor).
        """
        K, c = len(self.scans), len(self.data.channels)
        sig = np.zeros((K, c))
        cnt = np.zeros((K, c))
        for k in range(K):
            rk = r[self._rows(k)]
            sig[k] = noise_floor_mm(rk)
            cnt[k] = np.isfinite(rk).sum(axis=0)
        pooled = np.sqrt(np.sum(cnt * sig**2, axis=0) / np.maximum(cnt.sum(axis=0), 1))
        floor = np.where(sig > 0, sig, np.maximum(pooled, 1e-12))
        self.scan_sigma = floor
        for k in range(K):
            self._row_w[self._rows(k)] = pooled / floor[k]
        return pooled

    def spike_mask(self, r: np.ndarray, sigma: np.ndarray, k_sigma: float) -> np.ndarray:
        """Return the spike mask of the residuals ``r``, scan by scan with each scan's noise level."""
        return np.vstack(
            [
                spike_mask(r[self._rows(k)], self.scan_sigma[k], k_sigma=k_sigma)
                for k in range(len(self.scans))
            ]
        )

    def localise(self, r: np.ndarray, sigma: np.ndarray) -> dict:
        """Return the single-scan localisation of each scan (its own noise floor)."""
        return {
            "scans": {
                sid: m.localise(r[self._rows(k)], self.scan_sigma[k])
                for k, (m, sid) in enumerate(zip(self.models, self.scan_ids))
            }
        }

    def vibration_f(self, r: np.ndarray) -> float | None:
        """None: a vibration line belongs to one run (scope ``scan``) and is named per scan."""
        return None

    def candidate_terms(  # noqa: C901 (one branch per term scope and per base absorption)
        self, *, k_max: int | None = None, vibration_f_hz: float | None = None
    ) -> list[PooledTerm]:
        """Return the registry's candidates for every group of scans, less those the pooled base absorbs.

        The absorbed ones are recorded in :attr:`absorbed`. ``speed_error`` is the base's per-scan speed
        scale; ``vibration`` is left to the single-scan examination.
        """
        terms: list[PooledTerm] = []
        self.absorbed = []
        every = list(range(len(self.scans)))
        for scope in SCOPES:
            groups = self.groups(scope)
            if len(groups) > 1:  # the part of a group effect common to every group
                have = {
                    "commanded_angle": all(self.commanded),
                    "vibration_line": False,
                    "cte": all(bool(s.data.cte_per_k) for s in self.scans),
                }
                for t in registry_terms(SCAN_KIND, self.data.channels, have=have, k_max=k_max):
                    if EFFECTS[t.effect].scope == scope and t.effect != "speed_error":
                        why = self.absorption(PooledTerm(t.effect, t.channel, t.k), every)
                        if why is not None:
                            self.absorbed.append({**why, "common_to_groups": True})
            for label, ks in groups:
                have = {
                    "commanded_angle": all(self.commanded[k] for k in ks),
                    "vibration_line": False,
                    "cte": all(bool(self.scans[k].data.cte_per_k) for k in ks),
                }
                for t in registry_terms(SCAN_KIND, self.data.channels, have=have, k_max=k_max):
                    spec = EFFECTS[t.effect]
                    if spec.scope != scope or t.effect == "speed_error":
                        continue
                    turns = self.turns_of(ks) if spec.orientation else ()
                    pt = PooledTerm(t.effect, t.channel, t.k, label, turns)
                    if pt.key in {d.key for d in self.device_terms}:
                        continue  # in the device model: fitted with the base
                    why = self.absorption(pt, ks)
                    if why is not None:
                        self.absorbed.append(why)
                        continue
                    terms.append(pt)
        return terms

    def absorption(self, t: Term, ks: Sequence[int]) -> dict | None:
        """Why the pooled base absorbs term ``t`` acting on scans ``ks`` (None if it does not).

        A shared beam parameter absorbs a term that acts on every scan (per channel: the term's
        channel; a common term: any); a per-scan radius absorbs a common term when every scan of
        the term has it free; either unless the registry's ``absorbed_unless`` condition holds.
        """
        spec = EFFECTS[t.effect]
        every = len(ks) == len(self.scans)
        common = t.channel in (0, None)
        for par, text in spec.absorbers(SCAN_KIND).items():
            if par in ("beta", "rho", "d_b"):
                if par not in self.free_beams or not every:
                    continue
            elif par == "R":
                if not common or not all(self.scans[k].data.radius_free for k in ks):
                    continue
            else:
                continue
            cond = spec.absorbed_unless.get(SCAN_KIND, {}).get(par)
            if cond is not None and CONDITIONS[cond].holds(self, ks):
                continue
            entry = {"effect": t.effect, "term": t.key, "absorbed_by": text, "parameter": par}
            if cond is not None:
                entry["condition"] = cond
                entry["design"] = CONDITIONS[cond].design(self, ks)
                entry["separated_by"] = CONDITIONS[cond].separated_by
            else:
                entry["separated_by"] = None
            return entry
        return None

    def extra_starts(  # noqa: C901 (one branch per effect's extra starts; pooled is to become an adapter of the device models)
        self, screen: list, keys: set, t1: Term | None
    ) -> list:
        """Return the starts the linear screen cannot give.

        An oriented effect turned in some scans (:attr:`PooledTerm.turns`) is not linear in the
        turns at zero amplitude: each scan's own estimate (a linear fit of that scan alone) gives
        its orientation, and the turns start at the differences (the two best such terms whose
        estimates pay for their parameters). axis_tilt (not linear at zero tilt) starts from the
        k = 2 lobing of the same artifact group, oriented where it was; when that lobing leads the
        screen, both also start from the best set of the beams' mirror solutions (:meth:`_mirrored`).
        """
        out = []
        oriented: dict[str, dict] = {}
        n_res = max(int(self.mask.sum()), 2)
        scored = []
        for z in screen:
            t = z[1]
            if not getattr(t, "turns", ()) or (t1 is not None and t.key == t1.key):
                continue
            st0 = {n: v for n, v in z[2].items() if not n.startswith(t.key + ".")}
            st, gain = self._oriented_start(t, st0, t1)
            if st is not None:
                scored.append((gain, t.key, t, st))
        scored.sort(key=lambda g: -g[0])
        gains = {key: g for g, key, _, _ in scored}
        for gain, _, t, st in scored[:2]:
            if gain > len(t.names()) * math.log(n_res):
                out.append((0.0, t, st))
                oriented[t.key] = st
        if t1 is not None and t1.effect == "axis_tilt":
            return out
        for z in screen:
            t = z[1]
            if (
                t.effect != "bore_lobing"
                or t.k != 2
                or not ("*" in keys or t.key in keys or t.key in oriented)
            ):
                continue
            start = oriented.get(t.key, z[2])
            out.append((0.0, *self._tilt_from_lobing(t, start)))
            if t1 is None and "rho" in self.free_beams and self._form_leads(screen, t, gains.get(t.key)):
                # a k = 2 form is what tells a beam's mirror solution (rho of the other sign, the same
                # psi and g) from the right one: without the form in the model the base fit (and a
                # calibration) may take mirrors to imitate it. So the form is also fitted from every
                # set of mirrored beams (briefly; the best one polished), which starts the form and the tilt
                names = self.base_names() + t.names()
                scales = self.base_scales() + t.scales()
                c = len(self.data.channels)
                best = None
                for r in range(c, 0, -1):
                    for combo in itertools.combinations(range(c), r):
                        st = start
                        for j in combo:
                            st = self._mirrored(st, j)
                        try:
                            fr = fit_least_squares(
                                lambda q, t=t: self.residual(q, [t]),
                                names,
                                [st.get(n, 0.0) for n in names],
                                scales,
                                max_nfev=15,
                            )
                        except ValueError:
                            continue
                        if np.isfinite(fr.rss) and (best is None or fr.rss < best.rss):
                            best = fr
                if best is not None:
                    v = best.values()
                    try:
                        fr = fit_least_squares(
                            lambda q, t=t: self.residual(q, [t]),
                            names,
                            [v[n] for n in names],
                            scales,
                            max_nfev=100,
                        )
                        v = fr.values() if np.isfinite(fr.rss) and fr.rss <= best.rss else v
                    except ValueError:
                        pass
                    out.append((0.0, t, v))
                    out.append((0.0, *self._tilt_from_lobing(t, v)))
        return out

    def _tilt_from_lobing(self, t: PooledTerm, start: dict[str, float]) -> tuple[PooledTerm, dict]:
        """axis_tilt of the artifact group of a k = 2 lobing term, started from that lobing."""
        ks = self.members(t)
        R = float(np.mean([self.scans[k].data.radius_mm for k in ks]))
        lob = {"bore_lobing[k=2].A": start[f"{t.key}.A"], "bore_lobing[k=2].B": start[f"{t.key}.B"]}
        tilt = PooledTerm("axis_tilt", None, None, t.group, t.turns)
        st = {n: v for n, v in start.items() if not n.startswith(t.key + ".")}
        for n, v in tilt_start(lob, SimpleNamespace(radius_mm=R)).items():
            st[f"{tilt.key}.{n.split('.', 1)[1]}"] = v
        for sid in t.turns:  # the ellipse turns with the k = 2 form
            st[f"{tilt.key}.turn@{sid}"] = start.get(f"{t.key}.turn@{sid}", 0.0)
        return tilt, st

    def _form_leads(self, screen: list, t: PooledTerm, gain: float | None) -> bool:
        """Return whether the k = 2 lobing ``t`` leads.

        Return the k = 2 lobing ``t`` leads: first in the screen, or (turned) its per-scan estimates
        explain more than those of the screen's first candidate.
        """
        top = screen[0][1]
        if top.key == t.key:
            return True
        if gain is None:
            return False
        st0 = {n: v for n, v in screen[0][2].items() if not n.startswith(top.key + ".")}
        _, g_top = self._per_scan_estimates(top, st0, None)
        return gain > g_top

    def _mirrored(self, start: dict[str, float], j: int) -> dict[str, float]:
        """Return ``start`` with channel j's rho mirrored.

        ``start`` with channel j's rho of the other sign at the same psi and g (the calibration's
        mirror solution of that beam).
        """
        out = dict(start)
        rho = self.start_beams.rho_mm[j] + start.get(f"drho[{j}]", 0.0)
        out[f"drho[{j}]"] = -rho - self.start_beams.rho_mm[j]
        return out

    def _per_scan_estimates(
        self, t: Term, start: dict[str, float], t1: Term | None
    ) -> tuple[dict | None, float]:
        """Return term ``t`` fitted linearly to each scan alone.

        Term ``t`` fitted linearly to each scan alone (with that scan's centre, at ``start`` with
        ``t1``): the values of each frame's first scan (:meth:`frame_of`), and the chi-square the
        per-scan estimates explain in all (None, 0 where the model is undefined).
        """
        spec = EFFECTS[t.effect]
        fit_names = [f"{t.key}.{q.name}" for q in spec.fit]
        fit_scales = [q.scale for q in spec.fit]
        terms = [t1] if t1 is not None else []
        est, gain = {}, 0.0
        for k in self.members(t):
            q, own = self._scan_params(k, start, terms)
            w = 1.0 / self.scan_sigma[k]
            ok = self.mask[self._rows(k)]
            f0 = self.models[k].predict(q, own)
            r0 = ((self.scans[k].data.values_mm - f0) * w)[ok]
            cols = []
            for n, sc in zip(fit_names, fit_scales):
                qq = {**q, **{m: 0.0 for m in fit_names}, n: sc}
                cols.append(((self.models[k].predict(qq, own + [t]) - f0) / sc * w)[ok])
            for n in ("cx", "cy"):
                qq = dict(q)
                qq[n] += BASE_SCALE[n]
                cols.append(((self.models[k].predict(qq, own) - f0) / BASE_SCALE[n] * w)[ok])
            J = np.stack(cols, axis=1)
            coef = lstsq(J, r0)
            if coef is None:
                return None, 0.0
            res = r0 - J @ coef
            gain += float(r0 @ r0 - res @ res)
            est.setdefault(self.frame_of(k), {n: float(a) for n, a in zip(fit_names, coef[: len(fit_names)])})
        return est, gain

    def _oriented_start(
        self, t: PooledTerm, start: dict[str, float], t1: Term | None
    ) -> tuple[dict | None, float]:
        """Return the start of a turned term from each scan's own estimate.

        Start of a turned term from each scan's own linear estimate of it (at ``start``, with ``t1``):
        the reference frame's values and each turned frame's orientation difference (a frame's first
        scan); and the chi-square the per-scan estimates explain.
        """
        spec = EFFECTS[t.effect]
        est, gain = self._per_scan_estimates(t, start, t1)
        if est is None:
            return None, 0.0
        ref = next(fr for fr in est if fr not in t.turns)
        out = dict(start)
        out.update(est[ref])

        def orient(x: dict) -> float:
            par, _ = spec.spec_params({q.name: x[f"{t.key}.{q.name}"] for q in spec.fit}, None, t.k)
            return float(par[spec.orientation])

        for fr in t.turns:
            out[f"{t.key}.turn@{fr}"] = orient(est[fr]) - orient(est[ref])
        return out, gain

    def term_parameters(self, term: Term, x: dict, u: dict) -> tuple[dict, dict]:
        """Return the spec's parameters of a fitted term.

        Return the spec's parameters of a fitted term (the examination asks once per named entry, in
        the entries' order: the terms are kept in :attr:`reported`).
        """
        self.reported.append(term)
        par, unc = term_parameters(term, x, u)
        turns = getattr(term, "turns", ())
        if turns:  # the orientation is the reference frame's; the others see it turned
            par["turned_rad"] = {fr: float(x[f"{term.key}.turn@{fr}"]) for fr in turns}
            unc["turned_rad"] = {fr: float(u.get(f"{term.key}.turn@{fr}", math.nan)) for fr in turns}
        return par, unc

    def plot_angle(self) -> np.ndarray:
        """Return the plotting angle [rad] of every sample, the scans one after the other."""
        return np.concatenate([m.plot_angle() for m in self.models])

    def beams_at(self, p: dict[str, float]) -> Beams:
        """Return the shared beam geometry at pooled parameters ``p`` (module doc: psi, rho, g)."""
        c = len(self.data.channels)
        b = self.start_beams
        R = self.R_mm
        rho = b.rho_mm + np.array([p.get(f"drho[{j}]", 0.0) for j in range(c)])
        psi, g = straighten(b.beta_rad, b.rho_mm, b.d_b_mm, R)
        psi = psi + np.array([0.0] + [p.get(f"dpsi[{j}]", 0.0) for j in range(1, c)])
        g = g + np.array([p.get(f"dg[{j}]", 0.0) for j in range(c)])
        beta, d_b = unstraighten(psi, rho, g, R)
        return Beams(
            b.channels,
            beta if "beta" in self.free_beams else b.beta_rad.copy(),
            rho,
            d_b if "d_b" in self.free_beams else b.d_b_mm.copy(),
        )

    def _beam_deltas(self, p: dict[str, float]) -> dict[str, float]:
        """Return the single-scan models' beam offsets ``dbeta[j]``, ``drho[j]``, ``dd_b[j]`` at ``p``."""
        b, s = self.beams_at(p), self.start_beams
        out = {}
        for j in range(len(self.data.channels)):
            out[f"dbeta[{j}]"] = float(b.beta_rad[j] - s.beta_rad[j])
            out[f"drho[{j}]"] = float(b.rho_mm[j] - s.rho_mm[j])
            out[f"dd_b[{j}]"] = float(b.d_b_mm[j] - s.d_b_mm[j])
        return out

    def beam_covariance(self, p: dict[str, float], names: Sequence[str], cov: np.ndarray) -> np.ndarray:
        """Return the covariance of (beta, rho, d_b) per channel.

        Covariance (3c, 3c) of (beta, rho, d_b) per channel (the calibration's order) from the
        covariance ``cov`` of the fitted parameters ``names`` (linear propagation).
        """
        idx = [i for i, n in enumerate(names) if n in set(self._shared_names())]
        c = len(self.data.channels)

        def vec(q: dict) -> np.ndarray:
            b = self.beams_at(q)
            return np.column_stack([b.beta_rad, b.rho_mm, b.d_b_mm]).ravel()

        v0 = vec(p)
        A = np.zeros((3 * c, len(idx)))
        for col, i in enumerate(idx):
            h = BASE_SCALE[names[i].split("[")[0]] * 1e-3
            q = dict(p)
            q[names[i]] = q.get(names[i], 0.0) + h
            A[:, col] = (vec(q) - v0) / h
        C = np.asarray(cov)[np.ix_(idx, idx)]
        return A @ C @ A.T

    def base_summary(self, p: dict[str, float]) -> dict:
        """Return the base fit's beams and per-scan nuisance.

        Return the base fit's beams and per-scan nuisance (the examination asks once, at its base fit:
        the values are kept in :attr:`base_values`).
        """
        self.base_values = dict(p)
        b = self.beams_at(p)
        out = {
            "beams": b.to_nominal(),
            "beta_minus_start_rad": [float(x) for x in b.beta_rad - self.start_beams.beta_rad],
            "rho_minus_start_mm": [float(x) for x in b.rho_mm - self.start_beams.rho_mm],
            "d_b_minus_start_mm": [float(x) for x in b.d_b_mm - self.start_beams.d_b_mm],
            "scans": {},
        }
        for k, sid in enumerate(self.scan_ids):
            d = self.scans[k].data
            e = {
                "center_xy_mm": [p[f"{sid}:cx"], p[f"{sid}:cy"]],
                "radius_mm": d.radius_mm + p.get(f"{sid}:dR", 0.0),
            }
            if self.commanded[k]:
                e["speed_scale"] = 1.0 + p[f"{sid}:eps"]
            out["scans"][sid] = e
        return out

    def design(self, p: dict[str, float] | None = None) -> dict:
        """Return what distinguishes the scans.

        Return what distinguishes the scans: night, artifact, radius, signed speed, angle source and,
        with parameters ``p``, the eccentricity |S - C| of the fit.
        """
        out = {}
        for k, s in enumerate(self.scans):
            d = s.data
            w = self.signed_speeds(k)
            e = {
                "night": s.night,
                "artifact": s.artifact,
                "radius_mm": d.radius_mm,
                "speed_rad_s": [float(np.min(w)), float(np.max(w))],
                "angle": "encoder" if d.encoder else "commanded",
                "samples": int(d.t_s.size),
            }
            if p is not None:
                S = np.asarray(d.spindle_xy_mm, dtype=float)
                S0 = S.mean(axis=0) if S.ndim == 2 else S
                e["eccentricity_mm"] = float(
                    np.hypot(S0[0] - p[f"{s.scan_id}:cx"], S0[1] - p[f"{s.scan_id}:cy"])
                )
            out[s.scan_id] = e
        return out


# ----------------------------------------------------------------------------------- verdict


@dataclass
class PooledExamination:
    """The pooled findings and the examination behind them.

    The pooled findings and the examination behind them (arrays stacked over the scans); ``fit``
    is the verdict's fit (base and ``terms``; the base alone when nothing is named).
    """

    findings: dict
    examination: Examination
    model: PooledModel
    fit: FitResult | None = None
    terms: list[Term] = field(default_factory=list)


def _chi2_by_scan(model: PooledModel, r_mm: np.ndarray) -> np.ndarray:
    """Sum over each scan of (residual / the scan's noise floor)^2 over finite entries (K,)."""
    out = np.zeros(len(model.scans))
    for k in range(len(model.scans)):
        rk = r_mm[model._rows(k)] / model.scan_sigma[k]
        out[k] = float(np.nansum(rk**2))
    return out


def _carriers(model: PooledModel, gain: np.ndarray, ks: Sequence[int] | None = None) -> list[str]:
    """Return the fewest scans holding most of the chi-square decrease.

    Return the fewest scans (largest chi-square decrease first) holding :data:`CARRIER_SHARE` of the
    decrease.
    """
    ks = list(range(len(model.scans))) if ks is None else list(ks)
    pos = [(float(gain[k]), k) for k in ks if gain[k] > 0]
    pos.sort(reverse=True)
    total = sum(g for g, _ in pos)
    out, acc = [], 0.0
    for g, k in pos:
        if total <= 0 or acc >= CARRIER_SHARE * total:
            break
        out.append(model.scan_ids[k])
        acc += g
    return out


def _absorbed_summary(model: PooledModel) -> list[dict]:
    """Return the absorbed terms grouped by effect and absorbing parameter.

    Return the absorbed terms grouped by effect and absorbing parameter (one line each; for an
    effect of several groups, its part common to every group).
    """
    out: dict[tuple, dict] = {}
    for a in model.absorbed:
        key = (a["effect"], a["parameter"])
        e = out.setdefault(key, {k: v for k, v in a.items() if k != "term"} | {"terms": []})
        e["terms"].append(a["term"])
    for e in out.values():
        e["advice"] = f"{e['effect']} cannot be told from {e['absorbed_by']} by these scans" + (
            f" ({e['design']}); {e['separated_by']} separates them"
            if e.get("separated_by")
            else "; no scan separates them: a calibration includes it"
        )
    return sorted(out.values(), key=lambda e: (e["effect"], e["parameter"]))


#: Registry base parameter -> column of the calibrations table.
_CAL_COLUMN = {"beta": "beta_rad", "rho": "rho_mm", "d_b": "d_b_mm"}


def calibration_equivalent(model: PooledModel, p: dict[str, float], terms: list[Term], t: Term) -> dict:
    """Return what a calibration that ignores term ``t`` would put into the beams, scan by scan.

    For each scan the term acts on, the term's signature (readings with every term less readings
    without ``t``) is fitted, linearised and weighted by the scan's noise floor, by changes of the
    beam parameters the registry says absorb the effect (``absorbed_by``: beta, d_b) on the term's
    channel (every channel for a common term) and of the scan's nuisance other than the centre (a
    calibration knows the centre and spindle position). Only those: rho, weakly determined, would
    otherwise trade with beta along a nearly flat valley. Returns, per scan id, those changes
    (``beta_rad``, ``d_b_mm``; one value, or one per channel for a common term) and
    ``absorbed_share``: the part of the signature's chi-square they take up (1 when the registry's
    absorption is exact in that scan, e.g. a delay at constant speed).
    """
    spec = EFFECTS[t.effect]
    pars = [b for b in spec.absorbers(SCAN_KIND) if b in _CAL_COLUMN]
    if not pars:
        return {}
    c = len(model.data.channels)
    js = list(range(c)) if t.channel in (None, 0) else [model.data.channels.index(int(t.channel))]
    others = [x for x in terms if x.key != t.key]
    out = {}
    prefixes = {"beta": "dbeta", "rho": "drho", "d_b": "dd_b"}
    for k in model.members(t):
        sid = model.scan_ids[k]
        m = model.models[k]
        q, own = model._scan_params(k, p, terms)
        q0, own0 = model._scan_params(k, p, others)
        sig = m.predict(q, own) - m.predict(q0, own0)
        w = 1.0 / model.scan_sigma[k]
        ok = model.mask[model._rows(k)] & np.isfinite(sig)
        # the beams of the absorbing parameters, and the scan's nuisance other than the centre
        names = [f"{prefixes[b]}[{j}]" for b in pars for j in js]
        nuis = [n for n in model._nuisance(k) if n not in ("cx", "cy")]
        f0 = m.predict(q0, own0)
        cols = []
        for n in names + nuis:
            key = "speed_error.eps" if n == "eps" else n
            h = BASE_SCALE[n.split("[")[0]] * 1e-2
            qq = dict(q0)
            qq[key] = qq.get(key, 0.0) + h
            cols.append((((m.predict(qq, own0) - f0) / h) * w)[ok])
        J = np.stack(cols, axis=1)
        y = (sig * w)[ok]
        coef = np.linalg.lstsq(J, y, rcond=None)[0]
        chi_sig = float(y @ y)
        res = y - J @ coef
        entry = {"absorbed_share": float(1.0 - (res @ res) / chi_sig) if chi_sig > 0 else 0.0}
        for b in pars:
            vals = [float(coef[names.index(f"{prefixes[b]}[{j}]")]) for j in js]
            entry[_CAL_COLUMN[b]] = vals[0] if len(vals) == 1 else vals
        out[sid] = entry
    return out


def drift_explanations(drift, findings: dict) -> list[dict]:
    """Whether a named effect of a pooled examination explains the flagged calibration drifts of its device.

    Parameters
    ----------
    drift : :func:`borescan.calibrations.calibration_drift` of the calibrations table (polars frame)
    findings : :attr:`PooledExamination.findings` of the device

    Returns
    -------
    list of dicts, one per flagged row of the device: the row's device_id, channel, parameter,
    calibration ids, change and u_combined, ``explained_by`` (the named terms the registry says that
    parameter absorbs on that channel; empty when none), ``equivalent_change`` (term -> scan ->
    the change a calibration ignoring the term would make, :func:`calibration_equivalent`) and
    ``explanation`` in words.
    """
    out = []
    col_par = {v: k for k, v in _CAL_COLUMN.items()}
    for row in drift.iter_rows(named=True):
        if not row["flagged"] or row["device_id"] != findings["device_id"]:
            continue
        par = col_par.get(row["parameter"])
        hits = []
        for n in findings["named"]:
            spec = EFFECTS.get(n["effect"])
            if spec is None or par not in spec.absorbers(SCAN_KIND):
                continue
            if n.get("channel") not in (None, row["channel"]):
                continue
            hits.append(n)
        eq = {
            n.get("term", n["effect"]): {
                sid: e.get(row["parameter"]) for sid, e in (n.get("calibration_equivalent") or {}).items()
            }
            for n in hits
        }
        change = (
            f"{row['parameter']} of channel {row['channel']} moved by {row['change']:+.4g} "
            f"({row['change_over_u']:+.1f} combined u) from {row['calibration_id_before']} "
            f"to {row['calibration_id_after']}"
        )
        if hits:
            words = "; ".join(
                f"{n.get('term', n['effect'])} is absorbed by {spec_text(n['effect'], par)}"
                + (
                    ": a calibration ignoring it moves it by "
                    + ", ".join(
                        f"{v:+.4g} ({sid})"
                        for sid, v in eq[n.get("term", n["effect"])].items()
                        if isinstance(v, float)
                    )
                    if eq[n.get("term", n["effect"])]
                    else ""
                )
                for n in hits
            )
            text = f"{change}; explained by the pooled examination: {words}"
        else:
            text = (
                f"{change}; no effect named by the pooled examination of {', '.join(findings['scan_ids'])} "
                "is absorbed by it"
            )
        out.append(
            {
                "device_id": row["device_id"],
                "channel": row["channel"],
                "parameter": row["parameter"],
                "calibration_id_before": row["calibration_id_before"],
                "calibration_id_after": row["calibration_id_after"],
                "change": row["change"],
                "u_combined": row["u_combined"],
                "explained_by": [n.get("term", n["effect"]) for n in hits],
                "equivalent_change": eq,
                "explanation": text,
            }
        )
    return out


def spec_text(effect: str, par: str) -> str:
    """Return the registry's words for the base parameter ``par`` absorbing ``effect`` in a spindle scan."""
    return EFFECTS[effect].absorbers(SCAN_KIND).get(par, par)


#: What a scan must change to vary an effect of each registry scope (the other scopes' stay).
_SCOPE_CHANGE = {
    "scan": "another scan",
    "night": "a scan on another night",
    "artifact": "a scan of another artifact",
    "device": "a scan with another device",
}


def separation(a: Term, b: Term) -> str | None:
    """Return the measurement that separates two tied terms, from the registry.

    Return the measurement that separates two tied terms, from the registry: effects of different
    ``scope`` part when the narrower one's unit changes (another run, night or artifact) and the
    other's does not; None when the registry knows none (the same scope: a spec look-alike).
    """
    sa, sb = EFFECTS[a.effect].scope, EFFECTS[b.effect].scope
    if sa == sb:
        return None
    narrow, wide = (a, b) if SCOPES.index(sa) > SCOPES.index(sb) else (b, a)
    return (
        f"{_SCOPE_CHANGE[EFFECTS[narrow.effect].scope]} of the same device: {narrow.effect} belongs to the "
        f"{EFFECTS[narrow.effect].scope}, {wide.effect} to the {EFFECTS[wide.effect].scope}"
    )


#: Most function evaluations of the fits that check a pair verdict (the search's own fits stop at 60).
POLISH_NFEV = 200


def _entry_start(model: PooledModel, t: Term, n: dict) -> dict[str, float]:
    """Return the fitted values of term ``t`` from its named entry ``n`` (spec parameters, turns)."""
    spec = EFFECTS[t.effect]
    par = {k: v for k, v in n["parameters"].items() if k in spec.params}
    if spec.per_channel:
        par["channel"] = int(t.channel) if t.channel not in (None, 0) else int(model.data.channels[0])
    out = term_values(t, Effect(t.effect, par))
    for sid, a in (n["parameters"].get("turned_rad") or {}).items():
        out[f"{t.key}.turn@{sid}"] = a
    return out


def _fit_terms(
    model: PooledModel, terms: list[Term], start: dict[str, float], max_nfev: int = 60
) -> FitResult | None:
    names = model.base_names() + [nm for t in terms for nm in t.names()]
    scales = model.base_scales() + [s for t in terms for s in t.scales()]
    try:
        fr = fit_least_squares(
            lambda p: model.residual(p, terms),
            names,
            [start.get(nm, 0.0) for nm in names],
            scales,
            max_nfev=max_nfev,
        )
    except ValueError:
        return None
    return fr if np.isfinite(fr.rss) else None


def _check_pair(model: PooledModel, f: dict, terms: list[Term], entries: list[dict]) -> dict | None:
    """Return a pair verdict checked with fits run to convergence (:data:`POLISH_NFEV` evaluations).

    The search prefers a pair to the best single only when it beats it by more than the
    threshold; but the pair's fit starts where the single's stopped, so a single that its
    evaluation limit stopped early can lose to a pair whose second term is nothing. Here the pair
    and each of its terms alone are refitted from the pair's values; when a single comes within the
    threshold of the pair (and beats the base by more), the examination's own rule names that
    single. Returns the replacing single (term, fit, pair fit) or None.
    """
    T = float(f["threshold_delta_bic"])
    start = dict(model.base_values)
    for t, n in zip(terms, entries):
        start.update(_entry_start(model, t, n))
    pair = _fit_terms(model, terms, start, POLISH_NFEV)
    if pair is None:
        return None
    singles = []
    for t in terms:
        st = {
            k: v
            for k, v in pair.values().items()
            if not any(k.startswith(o.key + ".") for o in terms if o is not t)
        }
        fr = _fit_terms(model, [t], st, POLISH_NFEV)
        if fr is not None:
            singles.append((fr.bic, t.key, t, fr))
    if not singles:
        return None
    singles.sort(key=lambda z: z[:2])
    bic1, _, t1, fr1 = singles[0]
    if bic1 - pair.bic > T or f["base_model"]["bic"] - bic1 <= T:
        return None
    return {"term": t1, "fit": fr1, "pair": pair}


def examine_pooled(  # noqa: C901 (pooled is to become an adapter of the device models)
    scans: Sequence[PooledScan],
    beams: Beams | None = None,
    *,
    free_beams: tuple[str, ...] = ("beta", "rho", "d_b"),
    label: str | None = None,
    device_effects: Sequence[str] = (),
    **cfg,
) -> PooledExamination:
    """Examine the spindle scans of one device together (module doc).

    Parameters
    ----------
    scans : :class:`PooledScan` of one device (:func:`pooled_scan` of each raw scan)
    beams : start of the shared beams, the device's latest calibration (default ``device.nominal``
        of the first scan)
    free_beams : shared beam parameters that are free
    label : name of the set (default the device id)
    device_effects : the device model (registry keys, :func:`borescan.effects.device_model_effects`): fitted
        as part
        of the base model, never candidates; reported under ``device_model``
    **cfg : the settings of :func:`~borescan.discrepancy.examine.examine_model`
        (:func:`~borescan.discrepancy.examine.discrepancy_settings` of the config's section)

    Returns
    -------
    PooledExamination; ``findings`` holds ``verdict`` (``missing_effect``, ``ambiguous``,
    ``no_missing_effect``), ``named`` (effect, channel, group, parameters, uncertainties,
    evidence, ``scans``: the scans carrying the evidence), ``evidence_by_scan`` (chi-square
    decrease per scan), ``absorbed`` (effects these scans cannot separate from a calibration
    parameter, and the measurement that would), ``beams`` (the pooled fit's shared beams with
    standard uncertainties), ``design``, the gaps and noise floors, candidates and base model.
    """
    model = PooledModel(scans, beams, free_beams=free_beams, label=label, device_effects=device_effects)
    cfg = {k: v for k, v in cfg.items() if k not in ("beams", "layers", "free_beams")}
    ex = examine_model(model, **cfg)
    f = ex.findings
    # the named terms, in the order of the named entries (term_parameters is asked once per entry)
    named_terms = [t for t in model.reported if t is not None]
    effect_entries = [n for n in f["named"] if n["effect"] not in ("outliers", "quantization")]
    if len(named_terms) != len(effect_entries) or any(
        t.effect != n["effect"] for t, n in zip(named_terms, effect_entries)
    ):
        raise RuntimeError(f"{model.label}: the named effects and the reported terms disagree")
    for t, n in zip(named_terms, effect_entries):
        n["term"] = t.key
        n["group"] = getattr(t, "group", None)
        shared = [v for b, v in EFFECTS[t.effect].absorbers(SCAN_KIND).items() if b in model.free_beams]
        if n["group"] is not None and shared:
            n["note"] = "relative to the other pooled scans: a part common to every scan is " + "; ".join(
                shared
            )
    if f["verdict"] == "missing_effect" and len(named_terms) == 2:
        single = _check_pair(model, f, named_terms, effect_entries)
        if single is not None:
            t1 = single["term"]
            entry = _named_entry(t1, single["fit"], SimpleNamespace(bic=f["base_model"]["bic"]), None, model)
            entry.update(
                {
                    "term": t1.key,
                    "group": getattr(t1, "group", None),
                    "pair_checked": {
                        "terms": [t.key for t in named_terms],
                        "delta_bic_pair_over_single": float(single["fit"].bic - single["pair"].bic),
                        "note": "the pair's second term is not needed once the single is fitted "
                        f"to convergence ({POLISH_NFEV} evaluations)",
                    },
                }
            )
            f["named"] = [n for n in f["named"] if n["effect"] in ("outliers", "quantization")] + [entry]
            named_terms, effect_entries = [t1], [entry]
            r_after = model.residual_matrix(single["fit"].values(), [t1])
            ex.residual_after_mm = np.where(model.mask, r_after, np.nan)
            f["gap_after"] = {"rms_mm": float(np.sqrt(np.nanmean(ex.residual_after_mm**2)))}
    # the verdict's fit once more (the examination keeps only its findings; the base fit when nothing
    # is named): the beams with their u
    chosen = list(named_terms) if f["verdict"] == "missing_effect" else named_terms[:1]
    start = dict(model.base_values)
    for t, n in zip(named_terms, effect_entries):
        if t in chosen:
            start.update(_entry_start(model, t, n))
    fit = _fit_terms(model, chosen, start)
    # evidence by scan: the chi-square decrease from the base fit to the verdict's fit
    r_before = np.where(model.mask, ex.residual_before_mm, np.nan)
    gain = _chi2_by_scan(model, r_before) - _chi2_by_scan(model, ex.residual_after_mm)
    for n in f["named"]:
        t = next((x for x in named_terms if x.key == n.get("term")), None)
        n["scans"] = _carriers(model, gain, model.members(t) if t is not None else None)
    final_values = fit.values() if fit is not None else dict(model.base_values)
    if fit is not None and chosen:
        for t, n in zip(named_terms, effect_entries):
            if t in chosen:
                eq = calibration_equivalent(model, final_values, chosen, t)
                if eq:
                    n["calibration_equivalent"] = eq
    b = model.beams_at(final_values)
    if fit is not None:
        ub = np.sqrt(
            np.clip(np.diag(model.beam_covariance(final_values, fit.names, fit.cov)), 0, None)
        ).reshape(-1, 3)
    else:
        ub = np.full((len(b.channels), 3), math.nan)
    beams = {
        "channels": list(b.channels),
        "beta_rad": [float(x) for x in b.beta_rad],
        "rho_mm": [float(x) for x in b.rho_mm],
        "d_b_mm": [float(x) for x in b.d_b_mm],
        "u_beta_rad": [float(x) for x in ub[:, 0]],
        "u_rho_mm": [float(x) for x in ub[:, 1]],
        "u_d_b_mm": [float(x) for x in ub[:, 2]],
        "with_terms": [t.key for t in chosen] if fit is not None else None,
        "note": f"psi = beta + asin(rho / R) of channel {model.data.channels[0]} held at the start (a common "
        "turn is each scan's centre): its beta moves only with its rho",
    }
    in_model = []
    for t in model.device_terms:
        par, unc = term_parameters(t, final_values, fit.uncertainties() if fit is not None else {})
        in_model.append(
            {
                "effect": t.effect,
                "channel": t.channel,
                "term": t.key,
                "parameters": par,
                "uncertainties": {f"u_{k}": v for k, v in unc.items()},
                "note": "in the device model (fitted with the base model, not a candidate)",
            }
        )
    for a in model.device_absorbed:
        in_model.append(
            {
                "effect": a["effect"],
                "channel": parse_device_effect(a["term"]).channel,
                "term": a["term"],
                "parameters": None,
                "uncertainties": None,
                "note": f"in the device model; not fitted: these scans cannot tell it from {a['absorbed_by']}"
                + (
                    f" ({a['design']}; {a['separated_by']} would)"
                    if a.get("separated_by")
                    else ", which a calibration fits with it"
                ),
            }
        )
    out = {
        "device_id": model.label,
        "device_model": [t["term"] for t in in_model],
        "in_device_model": in_model,
        "scan_ids": list(model.scan_ids),
        "nights": sorted({s.night for s in model.scans}),
        "verdict": f["verdict"],
        "named": f["named"],
        "evidence_by_scan": {sid: float(g) for sid, g in zip(model.scan_ids, gain)},
        "absorbed": _absorbed_summary(model),
        "separation": [
            {
                "terms": [named_terms[0].key, t.key],
                "separated_by": separation(named_terms[0], t) or "no measurement the registry knows of",
            }
            for t in named_terms[1:]
        ]
        if f["verdict"] == "ambiguous"
        else [],
        "beams": beams,
        "design": model.design(model.base_values),
        "gap_before": f["gap_before"],
        "gap_after": f["gap_after"],
        "noise_floor_mm": f["noise_floor_mm"],
        "noise_floor_by_channel_mm": f["noise_floor_by_channel_mm"],
        "noise_floor_by_scan_mm": {
            sid: [float(x) for x in model.scan_sigma[k]] for k, sid in enumerate(model.scan_ids)
        },
        "threshold_delta_bic": f["threshold_delta_bic"],
        "candidates": f["candidates"],
        "screen": f["screen"],
        "base_model": f["base_model"],
        "localisation": f["localisation"],
        "config": f["config"],
        "samples_used": f["samples_used"],
        "samples_total": f["samples_total"],
    }
    return PooledExamination(findings=_clean(out), examination=ex, model=model, fit=fit, terms=chosen)
