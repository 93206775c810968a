"""The pooled model: K single-scan models with shared beams, per-scan nuisance and effect terms.

Each scan is a :class:`~borescan.discrepancy.tri.TriModel` (module doc of
:mod:`borescan.discrepancy.pooled`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from borescan.discrepancy.fitting import dead_zone, fit_least_squares
from borescan.discrepancy.pooled.beams import BeamsAndDesign
from borescan.discrepancy.pooled.candidates import CandidateSearch
from borescan.discrepancy.pooled.terms import _SPEED, BASE_SCALE, PooledScan, PooledTerm, parse_device_effect
from borescan.discrepancy.terms import Term
from borescan.discrepancy.tri import SCAN_KIND, TriModel
from borescan.discrepancy.tri_signals import rotation_eps, signed_speeds
from borescan.effects import EFFECTS, SCOPES, calibration_absorbers
from borescan.geometry import Beams


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


class PooledModel(CandidateSearch, BeamsAndDesign):
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
