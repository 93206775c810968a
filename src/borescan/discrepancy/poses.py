"""Scans made of stationary poses: measuring-rod scans and static three-sensor sets.

Both share the pose structure (``pose`` column): the noise floor comes from sample-to-sample
differences within a pose (1.4826 MAD / sqrt 2), outliers are jumps away from the pose median,
and the base model has per-pose nuisance parameters.

Rod (Wang 2017, spec "Measuring rod"): layer m at pose angle alpha_p sees hole m, a cylinder
of nominal radius r_m (feature ``nominal_diameter_mm``); the readings are the shared exact
forward model :class:`borescan.physics.rod.RodDevice` (the twin's) with the rod solve's unknowns
(:func:`borescan.physics.rod.rod_section_geometry`): centre c_m relative to the axis at the spot height
and the axis deflection w = omega (cos omega_az, sin omega_az) (a hand-held rod is never
aligned: base geometry, not an effect). Base: nominal layers (l0, phi, d, gamma) fixed; free the
pose angles (alpha_0 = 0: a common rotation is the centres' business), the centres (2 per
layer), the deflection (2, started from ``rod.solve_rod``) and, for a hole without a
certified diameter (a part: its diameter is the measurand), the radius. A free radius absorbs
every offset-like effect of its layer (``sensor_offset``, ``beam_offset``, ``thermal_expansion``):
those are then a calibration matter and are not tried. ``beam_offset`` then acts only
to second order (its first-order part, a phase shift d / r, is absorbed by the free centre):
a constant -d^2 / (2 r), the look-alike of ``sensor_offset`` and ``beam_tilt`` on that layer.

Static set (tri_lds without spindle stream): pose p puts the device at S_p relative to the bore
centre, device angle 0 (for a round bore only S_p in the device frame matters). Base: nominal
beams, R20 (free for a part without certified diameter); free S_p (2 per pose). Three
channels leave one degree of freedom per pose, so the
per-channel offset-like effects and ``thermal_expansion`` mostly look alike: the workflow then
says "ambiguous" and lists them.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from borescan.discrepancy.fitting import dead_zone
from borescan.noise import noise_floor_mm
from borescan.discrepancy.terms import Term, registry_terms, term_effects, term_parameters
from borescan.effects import calibration_absorbers
from borescan.geometry import Beams, Bore, RodLayer, centred_beam_length_mm
from borescan.physics.rod import RodDevice, RodState
from borescan.physics.tri import TriDevice, TriStaticState
from borescan.preconditions import EXAMINATION_NEEDS_GEOMETRY, MissingScanKey, design_beams, design_layers

__all__ = ["PoseData", "RodModel", "StaticModel", "pose_data_from_arrays"]


#: a rod layer's terms that screen level with its offset (the offset-like class and the bow)
LOOKALIKE_TERMS = ("sensor_offset", "sensor_gain", "sensor_nonlinearity", "beam_tilt")
#: a static set's zero members, refitted together (:meth:`StaticModel.extra_starts`)
ZERO_MEMBERS = ("sensor_offset", "thermal_expansion")
#: evaluations per unknown of each LM of the pose-means solve that starts a rod's base fit
#: (``rod.solve_rod``'s ``nfev_per_par``; a solve's own is 100): a start, finished by the base fit.
#: On a part whose deflection the poses do not separate from the radii (condition ~1e8) every LM
#: crawled to 100 per unknown (rod 284 of the battery, seed 2: 6 LMs of 2700 evaluations, 14 of the
#: examination's 15 CPU s)
START_NFEV_PER_PAR = 10
#: degrees of freedom of a MAD noise estimate per difference (its asymptotic efficiency, Gaussian noise)
MAD_DOF_PER_DIFF = 0.37


def _median_of_others(x: np.ndarray) -> np.ndarray:
    """Return, for each reading of ``x`` (finite, at least 2), the median of the other readings."""
    order = np.argsort(x, kind="stable")
    xs, rank = x[order], np.empty(x.size, dtype=int)
    rank[order] = np.arange(x.size)
    m = x.size - 1

    def qth(q: int) -> np.ndarray:  # the q-th smallest of the others: one rank up where it was removed
        return np.where(rank > q, xs[q], xs[q + 1])

    return qth(m // 2) if m % 2 else 0.5 * (qth(m // 2 - 1) + qth(m // 2))


class PoseData:
    """Readings of a pose scan with the metadata the models need."""

    def __init__(self, scan_id, meta, t_s, values_mm, channels, pose):
        self.scan_id = scan_id
        self.meta = meta
        self.t_s = np.asarray(t_s, dtype=float)
        self.values_mm = np.asarray(values_mm, dtype=float)
        self.channels = tuple(int(c) for c in channels)
        pose = np.asarray(pose)
        keep = pose >= 0
        self.t_s, self.values_mm, pose = self.t_s[keep], self.values_mm[keep], pose[keep]
        self.poses, self.pose_index = np.unique(pose, return_inverse=True)
        sensors = {int(s["channel"]): s for s in meta.get("sensors", [])}
        self.range_mm = np.array(
            [float(sensors.get(c, {}).get("range_mm", 10.0) or 10.0) for c in self.channels]
        )
        art = meta.get("artifact", {}) or {}
        self.cte_per_k = None if art.get("cte_per_k") is None else float(art["cte_per_k"])


def pose_data_from_arrays(scan_id, meta, t_s, values_mm, channels, pose) -> PoseData:
    """Build :class:`PoseData` (samples without a pose are dropped)."""
    return PoseData(scan_id, meta, t_s, values_mm, channels, pose)


class _PoseModel:
    """Shared engine interface of the pose models (see ``TriModel`` for the contract)."""

    angle_label = "pose angle [deg]"
    rev_hz = None

    def __init__(self, data: PoseData):
        self.data = data
        self.valid = np.isfinite(data.values_mm)
        self.mask = self.valid.copy()
        self.weights = np.ones(len(data.channels))
        self.dead_zone_mm: np.ndarray | None = None
        self._last = None

    def residual(self, p, terms):
        return self.weighted(self.predict(p, terms))

    def weighted(self, predicted: np.ndarray) -> np.ndarray:
        """Return the weighted residual vector over the unmasked samples of predicted readings (n, m)."""
        return (dead_zone(self.data.values_mm - predicted, self.dead_zone_mm) * self.weights)[self.mask]

    def residual_matrix(self, p, terms):
        return self.data.values_mm - self.predict(p, terms)

    def noise_floor(self, r: np.ndarray) -> np.ndarray:
        """Return the white-noise floor of sample-to-sample differences within poses, per channel.

        By :func:`borescan.noise.noise_floor_mm` of the first differences.
        """
        return noise_floor_mm(r, order=1, keep=self.data.pose_index[1:] == self.data.pose_index[:-1])

    #: a pose scan names a single jump: its leave-one-out test (:meth:`spike_mask`) holds a channel's
    #: chance of a false jump at the examination's ``outlier_false_rate`` (Bonferroni), so a second jump
    #: is not needed to tell a jump from noise (at rate x readings ~ 1, most rod outliers are one jump)
    min_spikes = 1

    def spike_mask(self, r: np.ndarray, sigma: np.ndarray, k_sigma: float) -> np.ndarray:
        """Return readings further than ``k_sigma`` (its tail probability) from their pose's other readings.

        Robust with few readings per pose (5-30): each reading is compared with the median of the other
        m = n - 1 readings of its pose (a jump does not pull its own reference), the difference scaled by
        its standard deviation under Gaussian noise, sigma sqrt(1 + pi / (2 m)) (a median of m readings
        has variance about pi sigma^2 / (2 m)). sigma is itself estimated, from the within-pose
        differences (:meth:`noise_floor`, a MAD: about 0.37 degrees of freedom per difference), so the
        threshold is the Student t quantile with those degrees of freedom at the tail probability
        ``k_sigma`` has under the normal law: the false-alarm rate ``k_sigma`` was chosen for holds when
        a scan of 50 readings per channel estimates its noise from 40 differences. A pose with fewer than
        4 finite readings is not tested.
        """
        from scipy.special import ndtr, stdtrit  # the normal tail and Student's t quantile

        out = np.zeros(r.shape, dtype=bool)
        idx = self.data.pose_index
        finite = np.isfinite(r)
        n_diff = finite.sum(axis=0) - np.array([len(np.unique(idx[finite[:, j]])) for j in range(r.shape[1])])
        tail = float(ndtr(-k_sigma))
        k_t = [-float(stdtrit(max(MAD_DOF_PER_DIFF * n, 1.0), tail)) for n in n_diff]
        for p in range(len(self.data.poses)):
            rows = np.flatnonzero(idx == p)
            for j in range(r.shape[1]):
                x = r[rows, j]
                ok = np.flatnonzero(np.isfinite(x))
                m = ok.size - 1
                if m < 3:
                    continue
                scale = max(float(sigma[j]), 1e-12) * math.sqrt(1.0 + math.pi / (2.0 * m))
                out[rows[ok], j] = np.abs(x[ok] - _median_of_others(x[ok])) > k_t[j] * scale
        return out

    def localise(self, r: np.ndarray, sigma: np.ndarray) -> dict:
        d = self.data
        out = {"channels": {}, "poses": {}}
        for j, ch in enumerate(d.channels):
            ok = np.isfinite(r[:, j]) & self.mask[:, j]
            x = r[ok, j]
            tt, vv = d.t_s[ok], d.values_mm[ok, j]
            out["channels"][str(ch)] = {
                "rms_mm": float(np.sqrt(np.mean(x**2))) if x.size else None,
                "mean_mm": float(np.mean(x)) if x.size else None,
                "noise_mm": float(sigma[j]),
                "excess": float(np.sqrt(np.mean(x**2)) / max(sigma[j], 1e-12)) if x.size else None,
                "trend_mm_per_s": float(np.polyfit(tt, x, 1)[0]) if x.size > 2 and np.ptp(tt) > 0 else 0.0,
                "trend_per_mm_reading": (
                    float(np.polyfit(vv, x, 1)[0]) if x.size > 2 and np.ptp(vv) > 0 else 0.0
                ),
            }
        rr = np.where(self.mask, r, np.nan)
        for k, p in enumerate(d.poses):
            seg = rr[d.pose_index == k]
            seg = seg[np.isfinite(seg)]
            out["poses"][str(int(p))] = float(np.sqrt(np.mean(seg**2))) if seg.size else None
        return out

    def vibration_f(self, r):
        return None

    @property
    def absorbed_by(self) -> dict[str, str]:
        """Effect -> the calibration parameters that absorb it (the registry's, for :attr:`scan_kind`)."""
        return calibration_absorbers(self.scan_kind)

    def base_scales(self):
        return [self._scale(n) for n in self.base_names()]

    def term_parameters(self, term: Term, x: dict, u: dict):
        if term.effect == "beam_offset":  # the rod's own term; the rest convert as on the spindle
            return {"d_mm": abs(x[f"{term.key}.d_mm"])}, {"d_mm": u.get(f"{term.key}.d_mm", float("nan"))}
        return term_parameters(term, x, u)

    def plot_angle(self) -> np.ndarray:
        return np.zeros(self.data.t_s.size) if self._last is None else self._last


# ---------------------------------------------------------------------------- rod


class RodModel(_PoseModel):
    """Measuring-rod scan (Wang 2017 Eq. 16 with the spec's beam geometry); see the module doc."""

    device_type = "rod"
    base_description = "device.nominal layers (l0, phi, d, gamma), feature nominal radii"
    scan_kind = "rod"
    #: the search's base fit gets its larger budget and a capped candidate fit is refitted from
    #: :meth:`base_start` (``search.Fitter``): the pose angles, centres and deflection mimic an effect along a
    #: long valley, where a base fit stopped at 60 evaluations is far from its minimum and a candidate from
    #: there does not land (battery seed 2 rod 282, a gain of layer 1: the base 30312 sigma^2 at 60
    #: evaluations, 18541 at its minimum after 868; the gain from the base fit stopped at 2449-6883, from
    #: the pose-means start at the noise, 1562, in 26)
    flat_valley = True

    def __init__(self, data: PoseData):
        super().__init__(data)
        meta = data.meta
        layers = {int(lay["channel"]): lay for lay in design_layers(meta, EXAMINATION_NEEDS_GEOMETRY)}
        get = lambda c, k, dflt=0.0: float(layers[c].get(k, dflt) or dflt)  # noqa: E731
        self.l0 = np.array([get(c, "l0") for c in data.channels])
        self.phi = np.array([get(c, "phi") for c in data.channels])
        self.d = np.array([get(c, "d") for c in data.channels])
        self.gamma = np.array([get(c, "gamma") for c in data.channels])
        self.h = np.array([get(c, "h") for c in data.channels])
        art = meta.get("artifact", {}) or {}
        feats = {f["id"]: f for f in art.get("features", []) or []}
        rod_layers = {int(lay["channel"]): lay for lay in (meta.get("rod", {}) or {}).get("layers", [])}
        default_dia = art.get("certified_diameter_mm") or art.get("nominal_diameter_mm")
        radii, free = [], []
        for c in data.channels:
            f = feats.get(rod_layers.get(c, {}).get("feature"))
            cert = (f or {}).get("certified_diameter_mm") if f else art.get("certified_diameter_mm")
            dia = cert or (f or {}).get("nominal_diameter_mm") or default_dia
            if dia is None:
                raise MissingScanKey(
                    f"no certified or nominal diameter for rod layer {c} (artifact.features)"
                )
            radii.append(float(dia) / 2.0)
            free.append(cert is None)
        self.radius = np.array(radii)
        #: layers whose hole radius is a free base parameter (no certified diameter: it is the measurand)
        self.radius_free = np.array(free)
        self.n_pose = len(data.poses)
        self._start: dict[str, float] | None = None
        #: the rod's model (:mod:`borescan.physics.rod`), the digital twin's
        self.device = RodDevice(tuple(self.layers()), data.cte_per_k or 0.0, tuple(data.range_mm))

    def base_names(self):
        """Return the base model's parameter names (per layer, per pose, the deflection)."""
        m = len(self.data.channels)
        return (
            [f"alpha[{k}]" for k in range(1, self.n_pose)]
            + [f"cx[{j}]" for j in range(m)]
            + [f"cy[{j}]" for j in range(m)]
            + ["wx", "wy"]
            + [f"dr[{j}]" for j in range(m) if self.radius_free[j]]
        )

    def _scale(self, n):
        return 1e-3 if n.startswith(("alpha", "dr", "w")) else 1e-2

    def layers(self) -> list[RodLayer]:
        """Nominal layer geometry (h, l0, phi, d, gamma) of the channels."""
        return [
            RodLayer(int(c), float(h), float(l0), float(ph), float(dd), float(g))
            for c, h, l0, ph, dd, g in zip(self.data.channels, self.h, self.l0, self.phi, self.d, self.gamma)
        ]

    def base_start(self):
        """Return the rod model's start from the pose means.

        Pose means solved by ``rod.solve_rod`` (deflection free, maximum likelihood); on refusal
        the closed-form Eq. 16 start with w = 0. Solved once (the pose means do not change); a copy
        is returned.
        """
        if self._start is None:
            self._start = self._pose_means_start()
        return dict(self._start)

    def _pose_means_start(self) -> dict[str, float]:
        """Return :meth:`base_start`'s start, solved from the pose means."""
        from borescan.rod import RodSolveError, solve_rod
        from borescan.rod_eq16 import rod_start

        d = self.data
        m = len(d.channels)
        V = np.full((self.n_pose, m), np.nan)
        for k in range(self.n_pose):
            V[k] = np.nanmean(np.where(self.valid, d.values_mm, np.nan)[d.pose_index == k], axis=0)
        L = V + self.l0
        mask = np.isfinite(L)
        w = np.zeros(2)
        try:
            sol = solve_rod(
                V,
                layers=self.layers(),
                deflection="mle",
                max_deflection_ratio=np.inf,
                max_u_ratio=np.inf,
                nfev_per_par=START_NFEV_PER_PAR,
            )
            a = np.nan_to_num(sol.alpha_rad)
            c, w, r = sol.center_xy_mm, sol.deflection_xy_rad, sol.radius_mm
        except (RodSolveError, np.linalg.LinAlgError, ValueError):
            try:
                p0, _ = rod_start(np.where(mask, L, 0.0), mask, 0)
                x, y, a = p0[m : 2 * m], p0[2 * m : 3 * m], np.insert(p0[3 * m :], 0, 0.0)
                c = np.column_stack([-x, -y])  # rod.py's (x, y) is the axis minus the centre
            except (RodSolveError, np.linalg.LinAlgError, ValueError):
                c, a = np.zeros((m, 2)), np.linspace(0, 2 * np.pi, self.n_pose, endpoint=False)
            r = np.nanmean(L, axis=0)
        #: the holes' radii solved free from the pose means [mm] (:meth:`extra_starts`' thermal start)
        self.solved_radius_mm = np.asarray(r, dtype=float)
        out = {f"alpha[{k}]": float(a[k]) for k in range(1, self.n_pose)}
        out["wx"], out["wy"] = float(w[0]), float(w[1])
        for j in range(m):
            out[f"cx[{j}]"], out[f"cy[{j}]"] = float(c[j, 0]), float(c[j, 1])
            if self.radius_free[j]:
                out[f"dr[{j}]"] = float(r[j] - self.radius[j])
        return out

    def base_summary(self, p):
        """Return the base fit's geometry at ``p`` (pose angles, deflection); keep the angles to plot."""
        alpha = np.array([0.0] + [p[f"alpha[{k}]"] for k in range(1, self.n_pose)])
        self._last = np.mod(alpha[self.data.pose_index], 2 * np.pi)
        m = len(self.data.channels)
        return {
            "hole_center_mm": [[float(p[f"cx[{j}]"]), float(p[f"cy[{j}]"])] for j in range(m)],
            "hole_radius_mm": [float(self.radius[j] + p.get(f"dr[{j}]", 0.0)) for j in range(m)],
            "radius_free": [bool(f) for f in self.radius_free],
            "deflection_rad": float(np.hypot(p.get("wx", 0.0), p.get("wy", 0.0))),
            "deflection_az_rad": float(np.arctan2(p.get("wy", 0.0), p.get("wx", 0.0))),
            "pose_angle_rad": [float(a) for a in alpha],
        }

    def state(self, p) -> RodState:
        """Return the device's base unknowns at base parameters ``p`` (pose 0 at alpha = 0)."""
        m = len(self.data.channels)
        return RodState(
            alpha_rad=np.array([0.0] + [p[f"alpha[{k}]"] for k in range(1, self.n_pose)]),
            center_xy_mm=np.array([[p[f"cx[{j}]"], p[f"cy[{j}]"]] for j in range(m)]),
            radius_mm=self.radius + np.array([p.get(f"dr[{j}]", 0.0) for j in range(m)]),
            deflection_xy_rad=np.array([p.get("wx", 0.0), p.get("wy", 0.0)]),
        )

    def predict(self, p, terms):
        """Return the readings (n, m) [mm] the rod model predicts with the terms' fitted values.

        The terms' fitted values become the spec's effects (:func:`~borescan.discrepancy.tri.term_effects`) on
        :meth:`borescan.physics.rod.RodDevice.predict` (the digital twin's model).
        """
        d = self.data
        effects = [e for t in terms for e in term_effects(t, p, d.channels)]
        with np.errstate(
            invalid="ignore", divide="ignore"
        ):  # NaN where a start puts the beam outside the hole
            return self.device.predict(self.state(p), d.pose_index, d.t_s, effects)

    def predict_stack(self, ps: list, terms) -> np.ndarray:
        """:meth:`predict` at each of ``ps`` (same term values) as a stack (S, n, m), one kernel call."""
        d = self.data
        effects = [e for t in terms for e in term_effects(t, ps[0], d.channels)]
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.device.predict_stack([self.state(p) for p in ps], d.pose_index, d.t_s, effects)

    def candidate_terms(self, *, k_max=None, vibration_f_hz=None):
        """Return the registry's rod candidates; what a layer's free hole radius absorbs is left out."""
        free = {c for c, f in zip(self.data.channels, self.radius_free) if f}
        return registry_terms(
            self.scan_kind,
            self.data.channels,
            have={"cte": bool(self.data.cte_per_k)},
            k_max=k_max,
            freed={"R": free},
        )

    def extra_starts(self, screen, keys, t1):
        """Return the starts of a chosen layer's offset-like look-alikes the screen's cut left out.

        A layer's offset, gain, bow and beam tilt screen level with each other (issue 17, point 2), so
        the exact refits' cut can keep two of them and drop the rest (on a rod calibration the screen
        ranked layer 1's four above layer 2's, and the exact fits put layer 2 four times higher): each one
        of a layer with a chosen member is refitted from its screen start. ``beam_offset`` is second
        order at d = 0: started from the layer's offset screen, d = sqrt(2 r |b|).

        ``thermal_expansion`` scales every certified radius by 1 + cte dT: with the radii fixed the base
        fit absorbs part of a large dT by bending the pose angles and the deflection, and the fit from
        there stalls (rod 22 of the contract battery, seed 1: 5794 sigma^2 left from the base fit, 0 at the
        truth), so it is also started from the pose-mean solve with the radii free (:meth:`base_start`),
        dT = mean(r_solved / r_certified - 1) / cte over the layers whose radius is certified.
        """
        layers = {
            z[1].channel
            for z in screen
            if z[1].effect in LOOKALIKE_TERMS and z[1].channel not in (None, 0) and z[1].key in keys
        }
        out = []
        for z in screen:
            t = z[1]
            if t.channel in (None, 0) or (t1 is not None and t1.channel == t.channel):
                continue
            if t.effect in LOOKALIKE_TERMS and t.channel in layers and t.key not in keys and "*" not in keys:
                out.append(z)
            if t.effect != "sensor_offset" or not ("*" in keys or t.channel in layers):
                continue
            j = self.data.channels.index(t.channel)
            b = z[2][f"{t.key}.b_mm"]
            st = {k: v for k, v in z[2].items() if not k.startswith(t.key)}
            st[f"beam_offset@{t.channel}.d_mm"] = math.sqrt(2.0 * self.radius[j] * max(abs(b), 1e-6))
            out.append((0.0, Term("beam_offset", t.channel, device=self.device_type), st))
            out += self._tilt_starts(j, b, st)
        if t1 is None and any(z[1].effect == "thermal_expansion" for z in screen):
            out += self._thermal_start()
        return out

    def settle_screen(self, screen: list) -> list:
        """Return the linear screen with each layer's ``beam_tilt`` started where it lengthens as its offset.

        At gamma = 0 a tilt's column is about l tan(gamma0), near zero, so its linearised start is
        meaningless (6006 rad on rod 284 of the battery, seed 2, as the second term of a pair). It is
        replaced by the root of :meth:`_tilt_starts` for the same layer's screened offset whose sign is the
        linear start's, with that offset's base parameters; gamma = 0 where the screen has no such offset or
        no tilt lengthens that much.
        """
        offsets = {z.term.channel: z for z in screen if z.term.effect == "sensor_offset"}
        out = []
        for z in screen:
            if z.term.effect == "beam_tilt" and z.term.channel not in (None, 0):
                name = f"{z.term.key}.gamma_rad"
                start = {**z.start, name: 0.0}
                off = offsets.get(z.term.channel)
                if off is not None:
                    key = f"{off.term.key}.b_mm"
                    base = {k: v for k, v in off.start.items() if k != key}
                    j = self.data.channels.index(z.term.channel)
                    roots = [st for _, _, st in self._tilt_starts(j, off.start[key], base)]
                    same = [st for st in roots if (st[name] > 0) == (z.start[name] > 0)]
                    start = (same or roots or [start])[0]
                z = replace(z, start=start)
            out.append(z)
        return out

    def _tilt_starts(self, j: int, b_mm: float, start: dict) -> list[tuple]:
        """Return ``beam_tilt`` starts of layer ``j`` that lengthen its readings by the offset's ``b_mm``.

        The tilt gamma adds to the layer's own gamma0 and lengthens the beam l by l (sec(gamma0 + gamma) -
        sec gamma0): even in gamma0 + gamma, so a fit from gamma = 0 (its column there is l tan gamma0, near
        zero) may not reach either side, and the base fit has already bent the pose angles and the
        deflection to absorb part of it (rod 10 of the battery, seed 1). Both roots of
        sec(gamma0 + gamma) = sec gamma0 + b / l, l the layer's mean beam length, are started, with the base
        parameters of the offset's screen (``start``); none where b shortens the beam below gamma = -gamma0.
        """
        ch = self.data.channels[j]
        v = self.data.values_mm[:, j]
        length = float(np.nanmean(v[self.valid[:, j]])) + self.l0[j] if self.valid[:, j].any() else math.nan
        g0 = float(self.gamma[j])
        sec = 1.0 / math.cos(g0) + b_mm / length if length > 0 else math.nan
        if not sec >= 1.0:
            return []
        g = math.acos(1.0 / sec)
        term = Term("beam_tilt", ch, device=self.device_type)
        return [(0.0, term, {**start, f"beam_tilt@{ch}.gamma_rad": s * g - g0}) for s in (1.0, -1.0)]

    def plausibility_origin(self, t: Term, parameter: str) -> float:
        """Return what a fitted size is added to before its plausible range judges it (``judge.implausible``).

        A rod's ``beam_tilt`` gamma adds to its layer's nominal out-of-plane angle gamma0, so the beam's
        angle gamma0 + gamma is judged (seed 1 rod 10 of the battery: the mirror root gamma = -0.1015 is a
        beam at -0.096 rad, inside 0.1); every other size is judged as fitted (0).
        """
        if t.effect == "beam_tilt" and parameter == "gamma_rad" and t.channel in self.data.channels:
            return float(self.gamma[self.data.channels.index(t.channel)])
        return 0.0

    def _thermal_start(self) -> list[tuple]:
        """Return the thermal start of :meth:`extra_starts` (empty without a CTE or a certified radius)."""
        cte, fixed = self.data.cte_per_k, ~self.radius_free
        if not cte or not fixed.any():
            return []
        st = self.base_start()
        ratio = self.solved_radius_mm[fixed] / self.radius[fixed] - 1.0
        if not np.all(np.isfinite(ratio)):
            return []
        st["thermal_expansion.dT"] = float(np.mean(ratio) / cte)
        return [(0.0, Term("thermal_expansion", None, device=self.device_type), st)]


# ---------------------------------------------------------------------------- static tri set


class StaticModel(_PoseModel):
    """Static three-sensor set: device at unknown S_p per pose inside the artifact (module doc)."""

    device_type = "tri_lds"
    base_description = "device.nominal beams, artifact R20; device position per pose free"
    scan_kind = "tri_static"

    def __init__(self, data: PoseData):
        super().__init__(data)
        meta = data.meta
        allb = design_beams(meta, EXAMINATION_NEEDS_GEOMETRY)
        idx = [allb.channels.index(c) for c in data.channels]
        self.beams = Beams(data.channels, allb.beta_rad[idx], allb.rho_mm[idx], allb.d_b_mm[idx])
        art = meta.get("artifact", {}) or {}
        dia = art.get("certified_diameter_mm") or art.get("nominal_diameter_mm")
        if dia is None:
            raise MissingScanKey("artifact has neither certified_diameter_mm nor nominal_diameter_mm")
        self.R = float(dia) / 2.0
        #: no certified diameter (a part): the radius is the measurand and a free base parameter
        self.radius_free = art.get("certified_diameter_mm") is None
        self.n_pose = len(data.poses)
        #: the static case of the three-sensor device's model (:mod:`borescan.physics.tri`), the twin's
        self.device = TriDevice(self.beams, data.cte_per_k or 0.0, tuple(data.range_mm))

    def base_names(self):
        """Return the base model's parameter names (device position per pose, radius change)."""
        names = [f"sx[{k}]" for k in range(self.n_pose)] + [f"sy[{k}]" for k in range(self.n_pose)]
        return names + (["dR"] if self.radius_free else [])

    def _scale(self, n):
        return 1e-3 if n == "dR" else 1e-2

    def base_start(self):
        """Per pose, to first order v_c = m_c - S . u_c (m_c the centred reading): least squares."""
        d = self.data
        m0 = centred_beam_length_mm(self.beams.rho_mm, self.R) - self.beams.d_b_mm
        U = np.stack([np.cos(self.beams.beta_rad), np.sin(self.beams.beta_rad)], axis=1)
        out = {}
        for k in range(self.n_pose):
            v = np.nanmean(np.where(self.valid, d.values_mm, np.nan)[d.pose_index == k], axis=0)
            ok = np.isfinite(v)
            s, *_ = np.linalg.lstsq(-U[ok], (v - m0)[ok], rcond=None)
            out[f"sx[{k}]"], out[f"sy[{k}]"] = float(s[0]), float(s[1])
        return out

    def base_summary(self, p):
        """Return the base fit's device positions at ``p``."""
        self._last = np.zeros(self.data.t_s.size)
        return {
            "device_xy_mm": [[float(p[f"sx[{k}]"]), float(p[f"sy[{k}]"])] for k in range(self.n_pose)],
            "radius_mm": float(self.R + p.get("dR", 0.0)),
            "radius_free": bool(self.radius_free),
        }

    def predict(self, p, terms):
        """Return the readings (n, c) [mm] the three-sensor model predicts with the terms' fitted values.

        The terms' fitted values become the spec's effects (:func:`~borescan.discrepancy.tri.term_effects`) on
        :meth:`borescan.physics.tri.TriDevice.predict` (the digital twin's model), the device at S_p and angle
        0 in a bore centred at the origin.
        """
        d = self.data
        xy = np.array([[p[f"sx[{k}]"], p[f"sy[{k}]"]] for k in range(self.n_pose)])
        state = TriStaticState(xy, np.zeros(self.n_pose), Bore((0.0, 0.0), self.R + p.get("dR", 0.0)))
        effects = [e for t in terms for e in term_effects(t, p, d.channels)]
        return self.device.predict(state, d.pose_index, d.t_s, effects)

    def candidate_terms(self, *, k_max=None, vibration_f_hz=None):
        """Return the registry's static candidates; a free bore radius absorbs what every channel shares."""
        return registry_terms(
            self.scan_kind,
            self.data.channels,
            have={"cte": bool(self.data.cte_per_k)},
            k_max=k_max,
            freed={"R": "shared" if self.radius_free else set()},
        )

    def extra_starts(self, screen, keys, t1):
        """Return the screen starts of the set's zero members the exact refits' cut left out.

        The zeroes of a static set (an offset of any channel or of every channel, a gauge's thermal
        expansion) move the readings along the beams alike, and the data fix one combination of them
        (:mod:`~borescan.discrepancy.classes`): they screen level with each other, so the cut can keep
        some and drop the rest, and a pair's second term among them is then the one the noise favoured
        (battery static 143 of seed 2: a bow with an offset on channel 2, fitted only with channel 1's
        offset, the common one and the expansion). Where one zero member is chosen, each other is refitted
        from its screen start (beside ``t1``, a pair's first term, when given).
        """
        chosen = {k for k in keys if k != "*"}
        zero = [z for z in screen if z[1].effect in ZERO_MEMBERS and (t1 is None or z[1].key != t1.key)]
        if not any(z[1].key in chosen for z in zero):
            return []
        return [z for z in zero if z[1].key not in chosen]
