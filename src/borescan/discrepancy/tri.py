"""Three-sensor spindle scans: base model and the named effects as parametric terms.

The base model is the ideal device of the spec (``geometry-and-effects.md``) with the beam
geometry of ``device.nominal`` held fixed, the artifact radius R20 from its certified (else
nominal) diameter, the spindle at ``spindle.position`` (or the spindle stream) turning at
``rpm_nominal``; free are the nuisance parameters only: the bore centre (cx, cy), plus the
start phase when the spindle moves during the scan (for a fixed spindle and a round bore the
phase is the same thing as the direction of the centre offset).

Why the beams are held (unless compared with the design, :mod:`.reference`): ``sensor_offset`` is
exactly a change of a channel's d_b, ``channel_delay`` of its beta (at one speed), ``thermal_expansion``
a common change of every d_b. Freeing them makes these effects invisible; held, they stay identifiable
and a finding says which calibration parameter would absorb it (a calibration matter).

Each candidate is a :class:`~borescan.discrepancy.terms.Term`: one named effect of the spec, its
channel (if any) and its fitted parameters. The registry (:data:`borescan.effects.EFFECTS`) is the
vocabulary: it gives each term its fitted parameters (phase-type effects in Cartesian form (A, B),
linear near zero amplitude), their conversion to the spec's parameters, which base parameters absorb
it and whether it is a candidate of a spindle scan. :meth:`TriModel.predict` converts the fitted
values to the spec's parameters and evaluates :func:`borescan.physics.tri.tri_forward`'s composition,
the forward model the digital twin uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from borescan.discrepancy.fitting import block_indices, dead_zone, noise_floor_mm, spike_mask
from borescan.discrepancy.terms import Term, registry_terms, term_effects, term_parameters, term_values
from borescan.discrepancy.tri_screen import FirstOrderResidual
from borescan.discrepancy.tri_signals import localise, rotation_eps, speeds_differ, tilt_start, vibration_peak
from borescan.effects import Effect, calibration_absorbers, sort_effects
from borescan.geometry import Beams, Bore
from borescan.kinematics import AngleModel, angle_model_from_arrays
from borescan.physics.tri_params import moved_beams
from borescan.physics.tri import (
    GEOMETRY_STAGES,
    TriBase,
    first_harmonic_start,
    tri_geometry,
    tri_reading_stage,
)
from borescan.preconditions import EXAMINATION_NEEDS_GEOMETRY, MissingScanKey, design_beams

__all__ = ["TriData", "TriModel", "tri_data_from_arrays", "candidate_terms"]

#: Scan kind of this model in the registry's ``absorbed_by`` / ``candidate``.
SCAN_KIND = "tri_spindle"
BASE_SCALE = {"cx": 1e-2, "cy": 1e-2, "phase": 1e-3, "dpsi": 1e-4, "dg": 1e-3, "drho": 1e-2, "dR": 1e-3}


@dataclass
class TriData:
    """A three-sensor spindle scan reduced to arrays (everything the model needs).

    t_s (n,) times; values_mm (n, c) readings (NaN = null); channels; beams (nominal);
    radius_mm R20; cte_per_k; omega_rad_s (nominal, > 0); direction +1 ccw / -1 cw;
    spindle_xy_mm (2,) or (n, 2); center_xy_mm (2,) or None; range_mm (c,); phase_rad start
    angle; free_phase whether the start phase is a free parameter.
    """

    scan_id: str
    t_s: np.ndarray
    values_mm: np.ndarray
    channels: tuple[int, ...]
    beams: Beams
    radius_mm: float
    cte_per_k: float | None
    omega_rad_s: float
    direction: float
    spindle_xy_mm: np.ndarray
    center_xy_mm: np.ndarray | None
    range_mm: np.ndarray
    phase_rad: float = 0.0
    free_phase: bool = False
    temperature_c: float | None = None
    n_total: int | None = None
    radius_free: bool = False
    angle_model: AngleModel | None = None

    @property
    def rev_hz(self) -> float:
        """Revolution frequency [Hz]."""
        return self.omega_rad_s / (2.0 * np.pi)

    @property
    def encoder(self) -> bool:
        """The angle is measured (spec: then there is no speed error to find)."""
        return self.angle_model is not None and self.angle_model.source == "encoder"

    def turned_rad(self, t_s: np.ndarray) -> np.ndarray:
        """Return the unsigned turned angle x(t) the model assumes.

        Unsigned turned angle x(t) since t = 0 that the model assumes (phi = phase + direction x):
        the commanded profile's angle (:mod:`borescan.kinematics`), omega t without one; with an
        encoder the measured angle less its value at t = 0.
        """
        if self.angle_model is None:
            return self.omega_rad_s * np.asarray(t_s, dtype=float)
        x = self.angle_model.commanded_rad(t_s)
        if self.encoder:
            x = x - self.phase_rad
        return self.direction * x


def tri_data_from_arrays(
    scan_id: str,
    meta: dict,
    t_s: np.ndarray,
    values_mm: np.ndarray,
    channels,
    spindle: dict | None = None,
    max_samples: int | None = None,
) -> TriData:
    """Build :class:`TriData` from ``scan.json`` metadata and the reading matrix.

    ``spindle`` (optional) holds arrays ``t_s``, ``x_mm``, ``y_mm``, ``angle_rad`` of the spindle stream.
    Scans longer than ``max_samples`` are cut to four contiguous blocks spread over the scan
    (:func:`~borescan.discrepancy.fitting.block_indices`); ``n_total`` keeps the full length.
    """
    n_total = len(t_s)
    if max_samples is not None and n_total > max_samples:
        keep = block_indices(n_total, int(max_samples))
        t_s, values_mm = np.asarray(t_s)[keep], np.asarray(values_mm)[keep]
    channels = tuple(int(c) for c in channels)
    beams_all = design_beams(meta, EXAMINATION_NEEDS_GEOMETRY)
    idx = [beams_all.channels.index(c) for c in channels]
    beams = Beams(channels, beams_all.beta_rad[idx], beams_all.rho_mm[idx], beams_all.d_b_mm[idx])
    art = meta.get("artifact", {}) or {}
    dia = art.get("certified_diameter_mm") or art.get("nominal_diameter_mm")
    if dia is None:
        raise MissingScanKey("artifact has neither certified_diameter_mm nor nominal_diameter_mm")
    sp = meta.get("spindle", {}) or {}
    rpm = float(sp.get("rpm_nominal", 60.0))
    direction = -1.0 if str(sp.get("direction", "ccw")).lower() == "cw" else 1.0
    sensors = {int(s["channel"]): s for s in meta.get("sensors", [])}
    range_mm = np.array([float(sensors.get(c, {}).get("range_mm", 10.0) or 10.0) for c in channels])
    pos = sp.get("position") or {}
    S = np.array([float(pos.get("x_mm", 0.0)), float(pos.get("y_mm", 0.0))])
    phase, free_phase = 0.0, False
    t_s = np.asarray(t_s, dtype=float)
    angle_model = None
    if spindle is not None and len(spindle.get("t_s", [])):
        angle_model = angle_model_from_arrays(
            rpm_nominal=rpm,
            direction=sp.get("direction", "ccw"),
            spindle_t_s=np.asarray(spindle["t_s"], dtype=float),
            spindle_angle_rad=spindle.get("angle_rad"),
            spindle_rpm=spindle.get("rpm"),
        )
        ts = np.asarray(spindle["t_s"], dtype=float)
        xs = np.interp(t_s, ts, np.asarray(spindle["x_mm"], dtype=float))
        ys = np.interp(t_s, ts, np.asarray(spindle["y_mm"], dtype=float))
        if np.ptp(xs) > 1e-6 or np.ptp(ys) > 1e-6:
            S = np.stack([xs, ys], axis=-1)
            free_phase = True
        else:
            S = np.array([xs[0], ys[0]])
        ang = spindle.get("angle_rad")
        if ang is not None:
            ang = np.asarray(ang, dtype=float)
            ok = np.isfinite(ang)
            if ok.any():
                phase = float(np.interp(0.0, ts[ok], ang[ok]))
    center = meta.get("center")
    C = np.array([float(center["x_mm"]), float(center["y_mm"])]) if center else None
    env = meta.get("environment", {}) or {}
    cte = art.get("cte_per_k")
    t_s = np.array(t_s, dtype=float)
    t_s.flags.writeable = False  # fixed for the examination: its angle is computed once (kinematics)
    return TriData(
        radius_free=art.get("certified_diameter_mm") is None,
        n_total=n_total,
        scan_id=scan_id,
        t_s=t_s,
        values_mm=np.asarray(values_mm, dtype=float),
        channels=channels,
        beams=beams,
        radius_mm=float(dia) / 2.0,
        cte_per_k=None if cte is None else float(cte),
        omega_rad_s=abs(angle_model.mean_omega_rad_s())
        if angle_model is not None
        else 2.0 * np.pi * rpm / 60.0,
        direction=direction,
        angle_model=angle_model,
        spindle_xy_mm=S,
        center_xy_mm=C,
        range_mm=range_mm,
        phase_rad=phase,
        free_phase=free_phase,
        temperature_c=None if env.get("temperature_c") is None else float(env["temperature_c"]),
    )


class TriModel:
    """Forward model of a spindle scan: base geometry plus any set of :class:`Term`.

    Composition follows :mod:`borescan.effects`: time base (delay), kinematics (speed error,
    then ripple), spindle position (error motion), bore (thermal, tilt, lobing), beam
    (beam_tilt), reading (offset, gain, nonlinearity, drift, vibration).
    """

    def __init__(
        self,
        data: TriData,
        weights: np.ndarray | None = None,
        free_beams: tuple[str, ...] = (),
        device_effects=(),
    ):
        bad = set(free_beams) - {"beta", "d_b", "rho"}
        if bad:
            raise ValueError(f"free_beams takes 'beta', 'd_b' and/or 'rho', got {sorted(bad)}")
        #: the device model's effects (:mod:`borescan.device_model`) in the base: fitted with it from their
        #: carried values, never candidates
        self.device_terms = tuple(Term(e.name, e.channel) for e in device_effects)
        self._device_start: dict[str, float] = {}
        for t, e in zip(self.device_terms, device_effects):
            self._device_start.update(term_values(t, e))
        #: beam parameters freed in the base model (their effects are then absorbed, not named)
        self.free_beams = tuple(free_beams)
        self.data = data
        self.valid = np.isfinite(data.values_mm)
        self.weights = np.ones(len(data.channels)) if weights is None else np.asarray(weights, dtype=float)
        self.mask = self.valid.copy()
        #: half cell of coarsely quantised channels (c,) or None (see ``examine_model``)
        self.dead_zone_mm: np.ndarray | None = None
        self._geo_cache: tuple | None = None
        self.residual_first_order = FirstOrderResidual(self)  # the linear screen's bore and spindle columns

    # ------------------------------------------------------------------ forward
    def base(self, p: dict[str, float]) -> TriBase:
        """Return the base geometry at base parameters ``p`` (centre, phase, radius, freed beams)."""
        d = self.data
        return TriBase(
            beams=self.beams_at(p),
            bore=Bore((p["cx"], p["cy"]), d.radius_mm + p.get("dR", 0.0)),
            spindle_xy_mm=np.asarray(d.spindle_xy_mm, dtype=float),
            turned_rad=d.turned_rad,
            phase_rad=p.get("phase", d.phase_rad),
            direction=d.direction,
            cte_per_k=d.cte_per_k or 0.0,
            range_mm=d.range_mm,
        )

    def beams_at(self, p: dict[str, float]) -> Beams:
        """Return the beams at ``p``: the design moved by the freed dpsi, drho, dg [j] (``moved_beams``)."""
        # in (psi, rho, g) the flat rho/d_b valley of (beta, rho, d_b), d_b ~ g - rho^2 / (2 R), is an axis
        c = len(self.data.channels)
        if not self.free_beams:
            return self.data.beams
        dpsi, drho, dg = ([p.get(f"{n}[{j}]", 0.0) for j in range(c)] for n in ("dpsi", "drho", "dg"))
        R = float(self.data.radius_mm)
        return moved_beams(self.data.beams, R, np.array(dpsi), np.array(drho), np.array(dg), self.free_beams)

    def predict(self, p: dict[str, float], terms: list[Term]) -> np.ndarray:
        """Return readings (n, c) [mm] for full parameters ``p`` (base + every term's fitted names).

        The terms' fitted values become the spec's effects (:func:`term_effects`) and the
        readings come from the composition of :mod:`borescan.physics.tri` (the digital twin's). The
        ray geometry is remembered for the last geometric state: a finite-difference step in a
        beam- or reading-stage parameter (offset, gain, ...) leaves it as it was.
        """
        d = self.data
        st = self.stages(p, terms)
        v, tc = self.geometry(p, st)
        return tri_reading_stage(v, tc, st, d.channels, d.range_mm)

    def geometry(self, p: dict[str, float], st: dict[str, list[Effect]]) -> tuple[np.ndarray, np.ndarray]:
        """Return the exact readings (n, c) of the ray geometry and the channel times at ``p`` and ``st``."""
        key = self.geometry_key(p, st)
        if self._geo_cache is None or self._geo_cache[0] != key:
            self._geo_cache = (key, tri_geometry(self.base(p), self.data.t_s, st))
        return self._geo_cache[1]

    @staticmethod
    def geometry_key(p: dict[str, float], st: dict[str, list[Effect]]) -> tuple:
        """Return what the ray geometry at ``p`` and ``st`` depends on: geometric effects, base parameters."""
        return (
            tuple(e for stage in GEOMETRY_STAGES for e in st[stage]),
            tuple(sorted((k, v) for k, v in p.items() if "." not in k)),
        )

    def stages(self, p: dict[str, float], terms: list[Term]) -> dict[str, list[Effect]]:
        """Return the effects of the device model and ``terms`` at ``p``, grouped by stage."""
        d = self.data
        if self.device_terms:
            keys = {t.key for t in self.device_terms}
            terms = list(self.device_terms) + [t for t in terms if t.key not in keys]
        return sort_effects([e for t in terms for e in term_effects(t, p, d.channels)], "tri_lds", d.channels)

    def residual(self, p: dict[str, float], terms: list[Term]) -> np.ndarray:
        """Weighted residual vector (data - model) over the unmasked samples."""
        return self.weighted(self.predict(p, terms))

    def weighted(self, predicted_mm: np.ndarray) -> np.ndarray:
        """Weighted residual vector of predicted readings (n, c) over the unmasked samples."""
        r = dead_zone(self.data.values_mm - predicted_mm, self.dead_zone_mm) * self.weights
        return r[self.mask]

    def residual_matrix(self, p: dict[str, float], terms: list[Term]) -> np.ndarray:
        """Unweighted residual (n, c) [mm], NaN where the reading is null."""
        return self.data.values_mm - self.predict(p, terms)

    #: base parameters that move only the bore (:meth:`base`): the centre and the radius
    bore_parameters = ("cx", "cy", "dR")

    # ------------------------------------------------------------------ helpers
    def base_names(self) -> list[str]:
        """Return the base model's parameter names (centre, phase, beams, device terms)."""
        c = len(self.data.channels)
        names = ["cx", "cy"] + (["phase"] if self.data.free_phase else [])
        names += ["dR"] if self.data.radius_free else []
        if "beta" in self.free_beams:  # the first beam's direction stays: a common turn is the centre's
            names += [f"dpsi[{j}]" for j in range(1, c)]
        if "d_b" in self.free_beams:
            names += [f"dg[{j}]" for j in range(c)]
        if "rho" in self.free_beams:  # a device never calibrated: its design offsets are off by up to mm
            names += [f"drho[{j}]" for j in range(c)]
        return names + [n for t in self.device_terms for n in t.names()]

    # ------------------------------------------------------------------ engine interface
    device_type = "tri_lds"
    angle_label = "device angle [deg]"
    scan_kind = SCAN_KIND

    @property
    def absorbed_by(self) -> dict[str, str]:
        """Return effect -> the calibration parameters that absorb it (:func:`calibration_absorbers`)."""
        return calibration_absorbers(self.scan_kind)

    base_description = "device.nominal beams, artifact R20, spindle position, rpm_nominal"

    @property
    def rev_hz(self) -> float:
        """Revolution frequency [Hz] of the scan."""
        return self.data.rev_hz

    def base_scales(self) -> list[float]:
        """Return the typical sizes of :meth:`base_names`' parameters."""
        own = dict(
            zip(
                (n for t in self.device_terms for n in t.names()),
                (s for t in self.device_terms for s in t.scales()),
            )
        )
        return [own.get(n, BASE_SCALE.get(n.split("[")[0], 1e-3)) for n in self.base_names()]

    def base_start(self) -> dict[str, float]:
        """Return the base fit's start (centre from the readings, device terms' own starts)."""
        C0 = self.initial_center()
        out = {"cx": float(C0[0]), "cy": float(C0[1]), **self._device_start}
        if self.data.free_phase:
            out["phase"] = self.data.phase_rad
        return out

    def base_summary(self, p: dict[str, float]) -> dict:
        """Return the base fit's geometry at ``p`` (centre, radius, beams)."""
        out = {
            "center_xy_mm": [float(p["cx"]), float(p["cy"])],
            "radius_mm": float(self.data.radius_mm + p.get("dR", 0.0)),
            "radius_free": bool(self.data.radius_free),
        }
        b, b0 = self.beams_at(p), self.data.beams
        if "beta" in self.free_beams:
            out["beta_minus_nominal_rad"] = [float(x) for x in b.beta_rad - b0.beta_rad]
        if "d_b" in self.free_beams:
            out["d_b_minus_nominal_mm"] = [float(x) for x in b.d_b_mm - b0.d_b_mm]
        if "rho" in self.free_beams:
            out["rho_minus_nominal_mm"] = [float(x) for x in b.rho_mm - b0.rho_mm]
        if self.device_terms:
            out["device_model"] = {n: float(p[n]) for t in self.device_terms for n in t.names()}
        return out

    def noise_floor(self, r: np.ndarray) -> np.ndarray:
        """Return the noise floor [mm] of the residuals ``r`` per channel."""
        return noise_floor_mm(r)

    def spike_mask(self, r: np.ndarray, sigma: np.ndarray, k_sigma: float) -> np.ndarray:
        """Return the mask of residuals further than ``k_sigma`` noise levels out."""
        return spike_mask(r, sigma, k_sigma=k_sigma)

    def localise(self, r: np.ndarray, sigma: np.ndarray) -> dict:
        """Return where in the scan the residuals ``r`` concentrate."""
        return localise(self, r, sigma)

    def vibration_f(self, r: np.ndarray) -> float | None:
        """Return the frequency [Hz] of the residuals' vibration peak, or None."""
        return vibration_peak(self, r)[0]

    def candidate_terms(self, *, k_max: int | None = None, vibration_f_hz: float | None = None) -> list[Term]:
        """Return every applicable term, less those a freed base parameter absorbs.

        The terms are :func:`candidate_terms`'; absorbed per the registry's ``absorbed_by``: d_b offsets and
        thermal expansion, beta channel delay, a free radius R the common offset and thermal expansion.
        """
        chans = set(self.data.channels)
        freed: dict[str, set | str] = {b: chans for b in self.free_beams}
        if self.data.radius_free:  # a part's radius is the measurand: it absorbs what every channel shares
            freed["R"] = "shared"
        keys = {t.key for t in self.device_terms}
        conditions = frozenset({"speeds_differ"} if speeds_differ(self.data) else ())
        return [
            t
            for t in candidate_terms(
                self.data, k_max=k_max, vibration_f_hz=vibration_f_hz, freed=freed, conditions=conditions
            )
            if t.key not in keys
        ]

    def extra_starts(self, screen: list, keys: set, t1: Term | None) -> list:
        """Return the starts the linear screen cannot give.

        axis_tilt is not linear at zero tilt: start it from the k = 2 lobing of the screen.
        A large speed error winds the phase by many radians: start it from the rotation
        frequency seen in the readings (singles only).
        """
        out = []
        lob = next((z for z in screen if z[1].key == "bore_lobing[k=2]"), None)
        if (
            (t1 is None or t1.effect != "axis_tilt")
            and lob is not None
            and ("*" in keys or "bore_lobing[k=2]" in keys)
        ):
            out.append((0.0, Term("axis_tilt"), tilt_start(lob[2], self.data)))
        if t1 is None and not self.data.encoder:
            eps0 = rotation_eps(self)
            if eps0 is not None and abs(eps0) > 2e-3:
                C0 = self.initial_center(eps0)
                st = {
                    **(screen[0][2] if screen else self.base_start()),
                    "cx": float(C0[0]),
                    "cy": float(C0[1]),
                    "speed_error.eps": eps0,
                }
                out.append((0.0, Term("speed_error"), st))
        return out

    def term_parameters(self, term: Term, x: dict, u: dict) -> tuple[dict, dict]:
        """Return a term's parameters and their uncertainties from the fit's ``x`` and ``u``."""
        return term_parameters(term, x, u)

    def plot_angle(self) -> np.ndarray:
        """Return the spindle angle [rad] of every sample, for the plots."""
        d = self.data
        return np.mod(d.phase_rad + d.direction * d.turned_rad(d.t_s), 2 * np.pi)

    def initial_center(self, eps: float = 0.0) -> np.ndarray:
        """Bore centre from the one-undulation-per-revolution content of the readings.

        To first order v_c = m_c - (S - C) . u(phi + beta_c), a linear regression (speed
        ``rpm_nominal (1 + eps)``).
        """
        d = self.data
        phi = d.phase_rad + d.direction * (1.0 + eps) * d.turned_rad(d.t_s)
        S = np.asarray(d.spindle_xy_mm, dtype=float)
        S0 = S.mean(axis=0) if S.ndim == 2 else S
        offset, _, _ = first_harmonic_start(phi, d.values_mm, self.valid, d.beams.beta_rad)
        return S0 - offset


def candidate_terms(
    data: TriData,
    *,
    k_max: int | None = None,
    vibration_f_hz: float | None = None,
    freed: dict[str, set | str] | None = None,
    conditions: frozenset[str] = frozenset(),
) -> list[Term]:
    """Return the registry's candidates of a spindle scan.

    Return the registry's candidates of a spindle scan (:func:`registry_terms`): ``commanded_angle``
    when the scan has no encoder, ``vibration_line`` when ``vibration_f_hz`` was found, ``cte``
    when the artifact's CTE is known.
    """
    have = {
        "commanded_angle": not data.encoder,
        "vibration_line": vibration_f_hz is not None,
        "cte": bool(data.cte_per_k),
    }
    return registry_terms(
        SCAN_KIND, data.channels, have=have, k_max=k_max, freed=freed, conditions=conditions
    )
