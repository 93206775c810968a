"""Three-sensor spindle scans: base model and the named effects as parametric terms.

The base model is the ideal device of the spec (``geometry-and-effects.md``) with the beam
geometry of ``device.nominal`` held fixed, the artifact radius R20 from its certified (else
nominal) diameter, the spindle at ``spindle.position`` (or the spindle stream) turning at
``rpm_nominal``; free are the nuisance parameters only: the bore centre (cx, cy), plus the
start phase when the spindle moves during the scan (for a fixed spindle and a round bore the
phase is the same thing as the direction of the centre offset).

Why the beams are not freed: ``sensor_offset`` on a channel is exactly a change of that
channel's d_b, ``channel_delay`` exactly a change of its beta (at constant speed), and
``thermal_expansion`` exactly a common change of every d_b. Freeing those base parameters
would make these effects invisible; holding them at the stated geometry keeps them
identifiable, and a finding of such an effect says which calibration parameter would absorb
it (a calibration matter rather than a missing physical effect).

Each candidate is a :class:`Term`: one named effect of the spec, its channel (if any) and its
fitted parameters. Internally phase-type effects are fitted in Cartesian form (A, B), which is
linear near zero amplitude, and converted to the spec's (amplitude, phase) at the end.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from borescan.discrepancy.fitting import block_indices, dead_zone, leading_block, noise_floor_mm, spike_mask
from borescan.geometry import Beams, Bore, bore_wall_radius
from borescan.kinematics import AngleModel, angle_model_from_arrays

__all__ = ["TriData", "Term", "TriModel", "tri_data_from_arrays", "candidate_terms", "term_parameters"]

# Internal parameters of each effect and their typical scale (for step sizes and starting values).
INTERNAL: dict[str, tuple[tuple[str, float], ...]] = {
    "sensor_offset": (("b_mm", 1e-3),),
    "sensor_gain": (("g", 1e-4),),
    "sensor_nonlinearity": (("a_mm", 1e-3),),
    "sensor_drift": (("k_mm_per_s", 1e-5),),
    "channel_delay": (("tau_s", 1e-4),),
    "beam_tilt": (("h", 1e-4),),  # h = 1 / cos(gamma) - 1
    "vibration": (("f_hz", 1e-2), ("A", 1e-3), ("B", 1e-3)),
    "speed_error": (("eps", 1e-4),),
    "speed_ripple": (("A", 1e-3), ("B", 1e-3)),
    "spindle_error_motion": (("A", 1e-3), ("B", 1e-3)),
    "axis_tilt": (("p", 1e-4), ("q", 1e-4)),  # beta^2 (cos 2 az, sin 2 az)
    "bore_lobing": (("A", 1e-3), ("B", 1e-3)),
    "thermal_expansion": (("dT", 1.0),),  # T - 20 degC
}
BASE_SCALE = {"cx": 1e-2, "cy": 1e-2, "phase": 1e-3, "dbeta": 1e-4, "dd_b": 1e-3, "dR": 1e-3}
# Calibration parameter that would absorb an effect (reported with the finding).
ABSORBED_BY = {
    "sensor_offset": "d_b_mm of the channel (every d_b when common)",
    "channel_delay": "beta_rad of the channel (at constant speed)",
    "thermal_expansion": "every d_b_mm (a common offset)",
}


@dataclass(frozen=True)
class Term:
    """One candidate: a named effect of the spec on one channel (or none) with a harmonic ``k``.

    ``channel=0`` means the same parameter on every channel (the look-alike of
    ``thermal_expansion`` for ``sensor_offset``).
    """

    effect: str
    channel: int | None = None
    k: int | None = None

    @property
    def key(self) -> str:
        s = self.effect
        if self.channel is not None:
            s += "@" + ("all" if self.channel == 0 else str(self.channel))
        if self.k is not None:
            s += f"[k={self.k}]"
        return s

    def names(self) -> list[str]:
        return [f"{self.key}.{n}" for n, _ in INTERNAL[self.effect]]

    def scales(self) -> list[float]:
        return [s for _, s in INTERNAL[self.effect]]


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
        return self.omega_rad_s / (2.0 * np.pi)

    @property
    def encoder(self) -> bool:
        """The angle is measured (spec: then there is no speed error to find)."""
        return self.angle_model is not None and self.angle_model.source == "encoder"

    def turned_rad(self, t_s: np.ndarray) -> np.ndarray:
        """Unsigned turned angle x(t) since t = 0 that the model assumes (phi = phase + direction x):
        the commanded profile's angle (:mod:`borescan.kinematics`), omega t without one; with an
        encoder the measured angle less its value at t = 0."""
        if self.angle_model is None:
            return self.omega_rad_s * np.asarray(t_s, dtype=float)
        x = self.angle_model.commanded_rad(t_s)
        if self.encoder:
            x = x - self.phase_rad
        return self.direction * x


def tri_data_from_arrays(
    scan_id: str, meta: dict, t_s: np.ndarray, values_mm: np.ndarray, channels, spindle: dict | None = None,
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
    nominal = meta["device"]["nominal"]["beams"]
    beams_all = Beams.from_nominal(nominal)
    idx = [beams_all.channels.index(c) for c in channels]
    beams = Beams(channels, beams_all.beta_rad[idx], beams_all.rho_mm[idx], beams_all.d_b_mm[idx])
    art = meta.get("artifact", {}) or {}
    dia = art.get("certified_diameter_mm") or art.get("nominal_diameter_mm")
    if dia is None:
        raise ValueError(f"{scan_id}: scan.json: artifact has no certified or nominal diameter")
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
            rpm_nominal=rpm, direction=sp.get("direction", "ccw"), spindle_t_s=np.asarray(spindle["t_s"], dtype=float),
            spindle_angle_rad=spindle.get("angle_rad"), spindle_rpm=spindle.get("rpm"))
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
        omega_rad_s=abs(angle_model.mean_omega_rad_s()) if angle_model is not None else 2.0 * np.pi * rpm / 60.0,
        direction=direction,
        angle_model=angle_model,
        spindle_xy_mm=S,
        center_xy_mm=C,
        range_mm=range_mm,
        phase_rad=phase,
        free_phase=free_phase,
        temperature_c=None if env.get("temperature_c") is None else float(env["temperature_c"]),
    )


#: effects applied to the readings after the ray geometry (:func:`apply_reading_terms`)
READING_EFFECTS = frozenset({"beam_tilt", "sensor_offset", "sensor_gain", "sensor_nonlinearity", "sensor_drift",
                             "vibration"})


def apply_reading_terms(
    v: np.ndarray,
    t: np.ndarray,
    by: dict[str, list[Term]],
    p: dict[str, float],
    channels,
    range_mm,
    beam_tilt: bool = True,
) -> np.ndarray:
    """Beam (``beam_tilt``: v / cos(gamma) = v (1 + h)) and reading-stage terms, in the order of
    :mod:`borescan.effects`: offset, gain, nonlinearity, drift, vibration. ``t`` (n, c) [s]."""
    v = np.array(v, dtype=float, copy=True)
    c = len(channels)

    def par(term: Term, name: str) -> float:
        return p[f"{term.key}.{name}"]

    def cols(term: Term) -> list[int]:
        return list(range(c)) if term.channel in (None, 0) else [list(channels).index(term.channel)]

    if beam_tilt:
        for term in by.get("beam_tilt", []):
            for j in cols(term):
                v[:, j] = v[:, j] * (1.0 + par(term, "h"))
    for term in by.get("sensor_offset", []):
        for j in cols(term):
            v[:, j] = v[:, j] + par(term, "b_mm")
    for term in by.get("sensor_gain", []):
        for j in cols(term):
            v[:, j] = v[:, j] * (1.0 + par(term, "g"))
    for term in by.get("sensor_nonlinearity", []):
        for j in cols(term):
            u = v[:, j] / range_mm[j]
            v[:, j] = v[:, j] + par(term, "a_mm") * 4.0 * u * (1.0 - u)
    for term in by.get("sensor_drift", []):
        for j in cols(term):
            v[:, j] = v[:, j] + par(term, "k_mm_per_s") * t[:, j]
    for term in by.get("vibration", []):
        w = 2.0 * np.pi * par(term, "f_hz") * t
        v = v + par(term, "A") * np.sin(w) + par(term, "B") * np.cos(w)
    return v


def fast_readings(
    phi_rad: np.ndarray, spindle_xy_mm: np.ndarray, beams: Beams, bore: Bore, n_iter: int = 3
) -> np.ndarray:
    """Readings of :func:`borescan.geometry.tri_spindle_readings`, written out for speed.

    Circle: the cancellation-free root of |o + s u - C| = R. Ellipse / lobes: fixed point
    s <- root for the wall radius r(theta(s)) at the current hit point; near-normal incidence
    makes each step shrink the error by about (dr/dtheta / R) tan(incidence), so three steps
    reach machine precision for the bores of the spec.

    Parameters
    ----------
    phi_rad : (n,) or (n, c); spindle_xy_mm : (2,), (n, 2) or (n, c, 2)

    Returns
    -------
    ndarray (n, c) [mm]
    """
    phi = np.asarray(phi_rad, dtype=float)
    if phi.ndim == 1:
        phi = phi[:, None]
    S = np.asarray(spindle_xy_mm, dtype=float)
    if S.ndim == 2:
        S = S[:, None, :]
    cb, sb = np.cos(beams.beta_rad), np.sin(beams.beta_rad)
    fx, fy = -beams.rho_mm * sb, beams.rho_mm * cb
    cp, sp = np.cos(phi), np.sin(phi)
    ox = S[..., 0] - bore.center_xy_mm[0] + cp * fx - sp * fy
    oy = S[..., 1] - bore.center_xy_mm[1] + sp * fx + cp * fy
    dx = cp * cb - sp * sb
    dy = sp * cb + cp * sb
    b = ox * dx + oy * dy
    oo = ox * ox + oy * oy

    def root(R):
        c = oo - R * R
        with np.errstate(invalid="ignore", divide="ignore"):
            sq = np.sqrt(b * b - c)  # NaN where the ray misses
            return np.where(b <= 0.0, -b + sq, -c / (b + sq))

    s = root(bore.radius_mm)
    if not bore.is_circle:
        for _ in range(n_iter):
            theta = np.arctan2(oy + s * dy, ox + s * dx)
            r, _ = bore_wall_radius(theta, bore)
            s = root(r)
    return s - beams.d_b_mm


class TriModel:
    """Forward model of a spindle scan: base geometry plus any set of :class:`Term`.

    Composition follows :mod:`borescan.effects`: time base (delay), kinematics (speed error,
    then ripple), spindle position (error motion), bore (thermal, tilt, lobing), beam
    (beam_tilt), reading (offset, gain, nonlinearity, drift, vibration).
    """

    def __init__(self, data: TriData, weights: np.ndarray | None = None, free_beams: tuple[str, ...] = ()):
        bad = set(free_beams) - {"beta", "d_b"}
        if bad:
            raise ValueError(f"free_beams takes 'beta' and/or 'd_b', got {sorted(bad)}")
        #: beam parameters freed in the base model (their effects are then absorbed, not named)
        self.free_beams = tuple(free_beams)
        self.data = data
        self.valid = np.isfinite(data.values_mm)
        self.weights = np.ones(len(data.channels)) if weights is None else np.asarray(weights, dtype=float)
        self.mask = self.valid.copy()
        #: half cell of coarsely quantised channels (c,) or None (see ``examine_model``)
        self.dead_zone_mm: np.ndarray | None = None
        self._geo_cache: tuple | None = None

    # ------------------------------------------------------------------ forward
    def predict(self, p: dict[str, float], terms: list[Term]) -> np.ndarray:
        """Readings (n, c) [mm] for full parameters ``p`` (base + every term's internal names)."""
        d = self.data
        c = len(d.channels)
        t = np.broadcast_to(d.t_s[:, None], (d.t_s.size, c)).astype(float)
        by = {}
        for term in terms:
            by.setdefault(term.effect, []).append(term)

        def par(term: Term, name: str) -> float:
            return p[f"{term.key}.{name}"]

        def cols(term: Term) -> list[int]:
            return list(range(c)) if term.channel in (None, 0) else [d.channels.index(term.channel)]

        for term in by.get("channel_delay", []):
            t = t.copy()
            for j in cols(term):
                t[:, j] = t[:, j] - par(term, "tau_s")
        x = d.turned_rad(t)
        for term in by.get("speed_error", []):
            x = x * (1.0 + par(term, "eps"))
        for term in by.get("speed_ripple", []):
            x = x + par(term, "A") * np.sin(x) + par(term, "B") * np.cos(x)
        phi = p.get("phase", d.phase_rad) + d.direction * x
        S = np.asarray(d.spindle_xy_mm, dtype=float)
        for term in by.get("spindle_error_motion", []):
            kp = term.k * phi
            A, B = par(term, "A"), par(term, "B")
            S0 = S[:, None, :] if S.ndim == 2 else S
            S = S0 + np.stack([A * np.cos(kp) - B * np.sin(kp), A * np.sin(kp) + B * np.cos(kp)], axis=-1)
        R = d.radius_mm + p.get("dR", 0.0)
        for term in by.get("thermal_expansion", []):
            R = R * (1.0 + (d.cte_per_k or 0.0) * par(term, "dT"))
        tilt, az = 0.0, 0.0
        for term in by.get("axis_tilt", []):
            pp, qq = par(term, "p"), par(term, "q")
            tilt = math.sqrt(math.hypot(pp, qq))
            az = 0.5 * math.atan2(qq, pp)
        lobes = []
        for term in by.get("bore_lobing", []):
            A, B = par(term, "A"), par(term, "B")
            lobes.append((term.k, math.hypot(A, B), math.atan2(B, A) / term.k))
        bore = Bore((p["cx"], p["cy"]), R, tilt, az, tuple(lobes))
        beams = d.beams
        if self.free_beams:
            c = len(d.channels)
            beams = Beams(
                d.channels,
                beams.beta_rad + np.array([p.get(f"dbeta[{j}]", 0.0) for j in range(c)]),
                beams.rho_mm,
                beams.d_b_mm + np.array([p.get(f"dd_b[{j}]", 0.0) for j in range(c)]),
            )
        v = self._geometric_readings(p, terms, phi, S, beams, bore)
        return apply_reading_terms(v, t, by, p, d.channels, d.range_mm)

    def _geometric_readings(self, p, terms, phi, S, beams, bore) -> np.ndarray:
        """:func:`fast_readings`, remembered for the last geometry: a finite-difference step in a
        reading-stage parameter (offset, gain, ...) leaves the ray geometry as it was."""
        geo_terms = tuple(t.key for t in terms if t.effect not in READING_EFFECTS)
        key = (geo_terms, tuple(sorted((k, v) for k, v in p.items()
                                       if k.split(".", 1)[0].split("@", 1)[0].split("[", 1)[0] not in READING_EFFECTS)))
        if self._geo_cache is not None and self._geo_cache[0] == key:
            return self._geo_cache[1]
        v = fast_readings(phi, S, beams, bore)
        self._geo_cache = (key, v)
        return v

    def residual(self, p: dict[str, float], terms: list[Term]) -> np.ndarray:
        """Weighted residual vector (data - model) over the unmasked samples."""
        r = dead_zone(self.data.values_mm - self.predict(p, terms), self.dead_zone_mm) * self.weights
        return r[self.mask]

    def residual_matrix(self, p: dict[str, float], terms: list[Term]) -> np.ndarray:
        """Unweighted residual (n, c) [mm], NaN where the reading is null."""
        return self.data.values_mm - self.predict(p, terms)

    # ------------------------------------------------------------------ helpers
    def base_names(self) -> list[str]:
        c = len(self.data.channels)
        names = ["cx", "cy"] + (["phase"] if self.data.free_phase else [])
        names += ["dR"] if self.data.radius_free else []
        if "beta" in self.free_beams:  # the first beam's direction stays: a common turn is the centre's
            names += [f"dbeta[{j}]" for j in range(1, c)]
        if "d_b" in self.free_beams:
            names += [f"dd_b[{j}]" for j in range(c)]
        return names

    # ------------------------------------------------------------------ engine interface
    device_type = "tri_lds"
    angle_label = "device angle [deg]"
    absorbed_by = ABSORBED_BY
    base_description = "device.nominal beams, artifact R20, spindle position, rpm_nominal"

    @property
    def rev_hz(self) -> float:
        return self.data.rev_hz

    def base_scales(self) -> list[float]:
        return [BASE_SCALE.get(n.split("[")[0], 1e-3) for n in self.base_names()]

    def base_start(self) -> dict[str, float]:
        C0 = self.initial_center()
        out = {"cx": float(C0[0]), "cy": float(C0[1])}
        if self.data.free_phase:
            out["phase"] = self.data.phase_rad
        return out

    def base_summary(self, p: dict[str, float]) -> dict:
        out = {"center_xy_mm": [float(p["cx"]), float(p["cy"])],
               "radius_mm": float(self.data.radius_mm + p.get("dR", 0.0)),
               "radius_free": bool(self.data.radius_free)}
        c = len(self.data.channels)
        if "beta" in self.free_beams:
            out["beta_minus_nominal_rad"] = [float(p.get(f"dbeta[{j}]", 0.0)) for j in range(c)]
        if "d_b" in self.free_beams:
            out["d_b_minus_nominal_mm"] = [float(p.get(f"dd_b[{j}]", 0.0)) for j in range(c)]
        return out

    def noise_floor(self, r: np.ndarray) -> np.ndarray:
        return noise_floor_mm(r)

    def spike_mask(self, r: np.ndarray, sigma: np.ndarray, k_sigma: float) -> np.ndarray:
        return spike_mask(r, sigma, k_sigma=k_sigma)

    def localise(self, r: np.ndarray, sigma: np.ndarray) -> dict:
        return _localise(self, r, sigma)

    def vibration_f(self, r: np.ndarray) -> float | None:
        return _vibration_peak(self, r)[0]

    def candidate_terms(self, *, k_max: int = 8, vibration_f_hz: float | None = None) -> list[Term]:
        """Every applicable term, less those a freed beam parameter absorbs (d_b: offsets and
        thermal expansion; beta: channel delay)."""
        terms = candidate_terms(self.data, k_max=k_max, vibration_f_hz=vibration_f_hz)
        if self.data.radius_free:  # a part's radius is the measurand: it absorbs a common offset
            terms = [t for t in terms if t.effect != "thermal_expansion" and t.channel != 0]
        if "d_b" in self.free_beams:
            terms = [t for t in terms if t.effect not in ("sensor_offset", "thermal_expansion")]
        if "beta" in self.free_beams:
            terms = [t for t in terms if t.effect != "channel_delay"]
        return terms

    def extra_starts(self, screen: list, keys: set, t1: Term | None) -> list:
        """Starts the linear screen cannot give.

        axis_tilt is not linear at zero tilt: start it from the k = 2 lobing of the screen.
        A large speed error winds the phase by many radians: start it from the rotation
        frequency seen in the readings (singles only).
        """
        out = []
        lob = next((z for z in screen if z[1].key == "bore_lobing[k=2]"), None)
        if (t1 is None or t1.effect != "axis_tilt") and lob is not None and (
            "*" in keys or "bore_lobing[k=2]" in keys
        ):
            out.append((0.0, Term("axis_tilt"), _tilt_start(lob[2], self.data)))
        if t1 is None and not self.data.encoder:
            eps0 = _rotation_eps(self)
            if eps0 is not None and abs(eps0) > 2e-3:
                C0 = self.initial_center(eps0)
                st = {**screen[0][2], "cx": float(C0[0]), "cy": float(C0[1]), "speed_error.eps": eps0}
                out.append((0.0, Term("speed_error"), st))
        return out

    def term_parameters(self, term: Term, x: dict, u: dict) -> tuple[dict, dict]:
        return term_parameters(term, x, u, self.data)

    def plot_angle(self) -> np.ndarray:
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
        rows, rhs = [], []
        c = len(d.channels)
        for j in range(c):
            ok = self.valid[:, j]
            a = phi[ok] + d.beams.beta_rad[j]
            X = np.zeros((ok.sum(), 2 + c))
            X[:, 0], X[:, 1] = -np.cos(a), -np.sin(a)
            X[:, 2 + j] = 1.0
            rows.append(X)
            rhs.append(d.values_mm[ok, j])
        X, y = np.vstack(rows), np.concatenate(rhs)
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        return S0 - coef[:2]


def candidate_terms(data: TriData, *, k_max: int = 8, vibration_f_hz: float | None = None) -> list[Term]:
    """Every named effect that applies to a spindle scan, as terms (one per channel or harmonic)."""
    terms: list[Term] = []
    per_channel = (
        "sensor_offset", "sensor_gain", "sensor_nonlinearity", "sensor_drift", "channel_delay", "beam_tilt"
    )
    for eff in per_channel:
        terms += [Term(eff, c) for c in data.channels]
    terms.append(Term("sensor_offset", 0))
    if not data.encoder:  # a measured angle has no speed error or ripple to find (spec, speed_error)
        terms += [Term("speed_error"), Term("speed_ripple")]
    if vibration_f_hz is not None:
        terms.append(Term("vibration"))
    if data.cte_per_k:
        terms.append(Term("thermal_expansion"))
    terms += [Term("bore_lobing", None, k) for k in range(2, k_max + 1)]
    terms += [Term("spindle_error_motion", None, k) for k in range(2, k_max + 1)]
    return terms


def _wrap(a: float, period: float = 2.0 * np.pi) -> float:
    return float(np.mod(a, period))


def term_parameters(term: Term, x: dict[str, float], u: dict[str, float], data: TriData | None = None) -> tuple[dict, dict]:
    """The spec's parameters of a fitted term and their standard uncertainties."""
    g = lambda n: x[f"{term.key}.{n}"]  # noqa: E731
    ug = lambda n: u.get(f"{term.key}.{n}", float("nan"))  # noqa: E731
    e = term.effect
    if e in ("sensor_offset", "sensor_gain", "sensor_nonlinearity", "sensor_drift", "channel_delay",
             "speed_error"):
        n = INTERNAL[e][0][0]
        return {n: g(n)}, {n: ug(n)}
    if e == "beam_tilt":
        h, uh = g("h"), ug("h")
        gam = math.acos(1.0 / (1.0 + h)) if h > 0 else 0.0
        ugam = uh / ((1.0 + h) ** 2 * math.sin(gam)) if gam > 0 else float("nan")
        return {"gamma_rad": gam}, {"gamma_rad": ugam}
    if e == "thermal_expansion":
        return {"temperature_c": 20.0 + g("dT")}, {"temperature_c": ug("dT")}
    if e == "axis_tilt":
        P, Q = g("p"), g("q")
        m = math.hypot(P, Q)
        um = math.sqrt(((P * ug("p")) ** 2 + (Q * ug("q")) ** 2)) / max(m, 1e-300)
        beta = math.sqrt(m)
        return (
            {"beta_rad": beta, "azimuth": _wrap(0.5 * math.atan2(Q, P), np.pi)},
            {"beta_rad": um / (2.0 * max(beta, 1e-300)), "azimuth": 0.5 * um / max(m, 1e-300)},
        )
    A, B = g("A"), g("B")
    amp = math.hypot(A, B)
    uamp = math.sqrt((A * ug("A")) ** 2 + (B * ug("B")) ** 2) / max(amp, 1e-300)
    uph = math.sqrt((B * ug("A")) ** 2 + (A * ug("B")) ** 2) / max(amp, 1e-300) ** 2
    ph = math.atan2(B, A)
    if e == "bore_lobing":
        return (
            {"k": term.k, "a_mm": amp, "phase": _wrap(ph / term.k, 2 * np.pi / term.k)},
            {"a_mm": uamp, "phase": uph / term.k},
        )
    if e == "spindle_error_motion":
        return {"k": term.k, "rho_mm": amp, "phase": _wrap(ph)}, {"rho_mm": uamp, "phase": uph}
    if e == "speed_ripple":
        return {"a_rad": amp, "phase": _wrap(ph)}, {"a_rad": uamp, "phase": uph}
    if e == "vibration":
        return (
            {"f_hz": g("f_hz"), "a_mm": amp, "phase": _wrap(ph)},
            {"f_hz": ug("f_hz"), "a_mm": uamp, "phase": uph},
        )
    raise ValueError(f"no parameter conversion for {e!r}")


def _vibration_peak(model: TriModel, r: np.ndarray) -> tuple[float | None, float]:
    """Frequency [Hz] of the strongest residual line that is not a whole multiple of the rotation."""
    d = model.data
    n = leading_block(d.t_s)
    r = r[:n]
    if n < 16:
        return None, 0.0
    dt = float(np.median(np.diff(d.t_s[:n])))
    rr = np.where(np.isfinite(r), r, 0.0)
    rr = rr - rr.mean(axis=0)
    nfft = 1 << int(math.ceil(math.log2(n * 8)))
    spec = np.abs(np.fft.rfft(rr, nfft, axis=0)) ** 2
    power = spec.sum(axis=1)
    f = np.fft.rfftfreq(nfft, dt)
    upr = f / d.rev_hz
    far = np.abs(upr - np.round(upr)) > 0.25
    far &= upr > 0.5
    if not far.any():
        return None, 0.0
    i = int(np.argmax(np.where(far, power, -1.0)))
    if 0 < i < power.size - 1:
        a, b, c = power[i - 1], power[i], power[i + 1]
        den = a - 2 * b + c
        off = 0.5 * (a - c) / den if den != 0 else 0.0
        return float(f[i] + off * (f[1] - f[0])), float(power[i])
    return float(f[i]), float(power[i])


def _localise(model: TriModel, r: np.ndarray, sigma: np.ndarray) -> dict:
    """Where the base residual sits: channels, part of the revolution, UPR spectrum, trends."""
    d = model.data
    out: dict[str, Any] = {"channels": {}, "revolution": {}, "spectrum_upr": []}
    phi = np.mod(d.direction * d.omega_rad_s * d.t_s, 2 * np.pi)
    for j, ch in enumerate(d.channels):
        ok = np.isfinite(r[:, j]) & model.mask[:, j]
        x = r[ok, j]
        rms = float(np.sqrt(np.mean(x**2))) if x.size else float("nan")
        tt = d.t_s[ok]
        vv = d.values_mm[ok, j]
        slope_t = float(np.polyfit(tt, x, 1)[0]) if x.size > 2 and np.ptp(tt) > 0 else 0.0
        slope_v = float(np.polyfit(vv, x, 1)[0]) if x.size > 2 and np.ptp(vv) > 0 else 0.0
        out["channels"][str(ch)] = {
            "rms_mm": rms,
            "mean_mm": float(np.mean(x)) if x.size else float("nan"),
            "noise_mm": float(sigma[j]),
            "excess": rms / max(float(sigma[j]), 1e-12),
            "trend_mm_per_s": slope_t,
            "trend_per_mm_reading": slope_v,
        }
    bins = np.linspace(0, 2 * np.pi, 13)
    ib = np.clip(np.digitize(phi, bins) - 1, 0, 11)
    rr = np.where(model.mask, r, np.nan)
    for b in range(12):
        seg = rr[ib == b]
        seg = seg[np.isfinite(seg)]
        out["revolution"][f"{int(round(np.degrees(bins[b])))}-{int(round(np.degrees(bins[b + 1])))}deg"] = (
            float(np.sqrt(np.mean(seg**2))) if seg.size else float("nan")
        )
    n = leading_block(d.t_s)
    if n >= 16:
        dt = float(np.median(np.diff(d.t_s[:n])))
        z = np.where(np.isfinite(rr[:n]), rr[:n], 0.0)
        z = z - z.mean(axis=0)
        nfft = 1 << int(math.ceil(math.log2(n * 4)))
        amp = 2.0 * np.abs(np.fft.rfft(z, nfft, axis=0)) / n
        upr = np.fft.rfftfreq(nfft, dt) / d.rev_hz
        tot = np.sqrt((amp**2).sum(axis=1))
        peaks = [i for i in range(1, tot.size - 1) if tot[i] >= tot[i - 1] and tot[i] > tot[i + 1]]
        peaks.sort(key=lambda i: -tot[i])
        for i in peaks[:5]:
            out["spectrum_upr"].append(
                {
                    "upr": float(upr[i]),
                    "amplitude_mm": {str(ch): float(amp[i, j]) for j, ch in enumerate(d.channels)},
                }
            )
    return out




def _tilt_start(lobing_start: dict, data: "TriData") -> dict:
    """Start of an axis_tilt fit from a k = 2 lobing start.

    The ellipse is r ~ R + (R beta^2 / 4)(1 + cos 2(theta - azimuth)): beta^2 = 4 a / R.
    """
    A, B = lobing_start["bore_lobing[k=2].A"], lobing_start["bore_lobing[k=2].B"]
    st = {n: v for n, v in lobing_start.items() if not n.startswith("bore_lobing[k=2]")}
    m = 4.0 / data.radius_mm
    st.update({"axis_tilt.p": m * A, "axis_tilt.q": m * B})
    return st




def _rotation_eps(model: TriModel) -> float | None:
    """Relative speed error from the strongest line of the readings within +-30 % of the nominal
    rotation frequency (the eccentricity undulates once per revolution); None without one."""
    d = model.data
    n = leading_block(d.t_s)
    if n < 32:
        return None
    dt = float(np.median(np.diff(d.t_s[:n])))
    v = np.where(model.valid[:n], d.values_mm[:n], np.nan)
    v = v - np.nanmean(v, axis=0)
    v = np.where(np.isfinite(v), v, 0.0)
    nfft = 1 << int(math.ceil(math.log2(n * 16)))
    power = (np.abs(np.fft.rfft(v, nfft, axis=0)) ** 2).sum(axis=1)
    f = np.fft.rfftfreq(nfft, dt)
    band = (f > 0.7 * d.rev_hz) & (f < 1.3 * d.rev_hz)
    if not band.any():
        return None
    i = int(np.argmax(np.where(band, power, -1.0)))
    if 0 < i < power.size - 1:
        a, b, c = power[i - 1], power[i], power[i + 1]
        den = a - 2 * b + c
        fi = f[i] + (0.5 * (a - c) / den if den != 0 else 0.0) * (f[1] - f[0])
    else:
        fi = f[i]
    return float(fi / d.rev_hz - 1.0)
