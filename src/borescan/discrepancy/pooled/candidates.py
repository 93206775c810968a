"""The examination engine's side of the pooled model.

Noise floors, spikes, candidate terms, their absorption and extra starts (a mixin of
:class:`~borescan.discrepancy.pooled.model.PooledModel`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from types import SimpleNamespace

import numpy as np

from borescan.discrepancy.fitting import fit_least_squares, noise_floor_mm, spike_mask
from borescan.discrepancy.pooled.terms import BASE_SCALE, CONDITIONS, PooledTerm
from borescan.discrepancy.search import lstsq
from borescan.discrepancy.terms import Term, registry_terms, term_parameters
from borescan.discrepancy.tri import SCAN_KIND
from borescan.discrepancy.tri_signals import tilt_start
from borescan.effects import EFFECTS, SCOPES


class CandidateSearch:
    """What the examination engine asks of the pooled model besides its forward model.

    Noise, spikes, localisation, candidate terms and their starts
    (:func:`~borescan.discrepancy.examine.examine_model`).
    """

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
