"""The one forward model of a measuring-rod scan: base geometry plus registered effects.

The digital twin (:func:`borescan.synthetic.scenes.rod_readings_with_effects`) and the rod's discrepancy
model (:class:`borescan.discrepancy.poses.RodModel`) evaluate readings here and nowhere else. The
physics of each named effect is its forward function in :mod:`borescan.effects`; the ray-cylinder
reading is :func:`borescan.geometry.rod_readings` (Wang 2017 Eq. 16 when d = gamma = omega = 0).

Composition order (``shared/spec/geometry-and-effects.md``; stages of :mod:`borescan.effects`):

1. bore: each hole's circle (centre, radius), then the bore-stage effects (``thermal_expansion``:
   R = R20 (1 + cte (T - 20))); a rod's hole stays a circle (a bore effect that makes it anything
   else raises ``ValueError``);
2. beam: the layer's geometry, ``beam_offset`` (d += d_mm, Wang 2017 Eq. 5), ``beam_tilt``
   (gamma += gamma_rad, Eq. 6);
3. exact ray-cylinder intersection at the rod rotations alpha, v = l - l0;
4. reading: offset, gain, nonlinearity, drift at the readings' times.

Output-stage effects (noise, ``quantization``, ``outliers``) are the generators' business
(:func:`borescan.synthetic.simulate.simulate_rod`). Time-base and kinematic effects do not apply to a rod
(turned by hand, pose by pose).

A fit's base unknowns (:class:`RodState`: pose angles, hole centres relative to the axis at the
spot's height, radii, the axis deflection; :func:`rod_section_geometry`) become a :class:`RodBase`
through :meth:`RodDevice.base`; :meth:`RodDevice.jacobian` gives the readings' derivatives.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from borescan.effects import Effect, apply_effects, sort_effects
from borescan.geometry import (
    Bore,
    Hole,
    RodAxis,
    RodLayer,
    rod_axis_rotation,
    rod_axis_rotation_xy,
    rod_layer_arrays,
    rod_ray_readings,
    rod_readings,
)

__all__ = [
    "RodBase",
    "RodState",
    "RodJacobian",
    "RodDevice",
    "rod_forward",
    "rod_layers_with_effects",
    "rod_holes_with_effects",
    "rod_reading_stage",
    "rod_section_geometry",
    "rod_section_arrays",
    "rod_section_readings",
]

ROD = "rod"


@dataclass(frozen=True)
class RodBase:
    """Base geometry of a rod scan: everything the readings depend on except the effects.

    Attributes
    ----------
    layers : the layers' geometry (h, l0, phi, d, gamma), one per channel.
    holes : one effect-free hole per layer (centre, R20) [mm].
    axis : the rod axis's pose in the part frame.
    cte_per_k : artifact expansion coefficient for ``thermal_expansion`` [1/K].
    range_mm : sensor range per channel, for ``sensor_nonlinearity`` [mm].
    """

    layers: tuple[RodLayer, ...]
    holes: tuple[Hole, ...]
    axis: RodAxis = RodAxis()
    cte_per_k: float = 0.0
    range_mm: Sequence[float] | float = 10.0

    @property
    def channels(self) -> tuple[int, ...]:
        """Return the layers' channels, in layer order."""
        return tuple(int(lay.channel) for lay in self.layers)


def _stages(effects: Iterable[Effect], channels: Sequence[int]) -> dict[str, list[Effect]]:
    effects = [e if isinstance(e, Effect) else Effect.from_dict(e) for e in effects]
    return sort_effects(effects, ROD, channels)


def rod_layers_with_effects(layers: Sequence[RodLayer], beam_effects: Iterable[Effect]) -> list[RodLayer]:
    """Return the layers after the beam-stage effects (step 2), in composition order."""
    out = list(layers)
    chans = [lay.channel for lay in out]
    for e in beam_effects:
        j = chans.index(e.channel)
        out[j] = e.spec.forward[ROD](out[j], e.params)
    return out


def rod_holes_with_effects(
    holes: Sequence[Hole], bore_effects: Sequence[Effect], cte_per_k: float
) -> list[Hole]:
    """Return the holes after the bore-stage effects (step 1), in composition order.

    Raises
    ------
    ValueError when an effect makes a hole other than a circle (the rod's geometry has circles only).
    """
    from borescan.physics.tri import bore_with_effects

    out = []
    for h in holes:
        b = bore_with_effects(Bore(h.center_xy_mm, h.radius_mm), bore_effects, cte_per_k, device=ROD)
        if not b.is_circle:
            raise ValueError(
                f"effects {[e.name for e in bore_effects]} make a rod's hole other than a circle"
            )
        out.append(Hole(tuple(b.center_xy_mm), b.radius_mm))
    return out


def rod_reading_stage(
    v_mm: np.ndarray,
    t_s: np.ndarray | None,
    st: dict[str, list[Effect]],
    channels: Sequence[int],
    range_mm: Sequence[float] | float,
) -> np.ndarray:
    """Step 4: reading effects on readings ``v_mm`` (n, m) at times ``t_s`` (n,) [s] (zeros when None)."""
    if not st["reading"]:
        return v_mm
    t = np.zeros(v_mm.shape[0]) if t_s is None else np.asarray(t_s, dtype=float)
    return apply_effects(
        v_mm, t, channels, st["reading"], device_type=ROD, range_mm=range_mm, stages=("reading",)
    )


def rod_forward(
    base: RodBase, alpha_rad: np.ndarray, t_s: np.ndarray | None = None, effects: Iterable[Effect] = ()
) -> np.ndarray:
    """Noise-free readings of a rod scan with effects (steps 1-4 of the module doc).

    Parameters
    ----------
    base : RodBase
    alpha_rad : ndarray (n,) rod rotation per reading [rad]
    t_s : ndarray (n,) times since scan start [s], for ``sensor_drift`` (zeros when omitted)
    effects : :class:`~borescan.effects.Effect` (output-stage effects are ignored)

    Returns
    -------
    ndarray (n, m) readings [mm], channels in ``base.layers`` order; NaN where a beam misses.
    """
    st = _stages(effects, base.channels)
    layers = rod_layers_with_effects(base.layers, st["beam"])
    holes = rod_holes_with_effects(base.holes, st["bore"], base.cte_per_k)
    v = rod_readings(np.atleast_1d(np.asarray(alpha_rad, dtype=float)), layers, holes, base.axis)
    return rod_reading_stage(v, t_s, st, base.channels, base.range_mm)


def rod_section_geometry(
    layers: Sequence[RodLayer], center_xy_mm, radius_mm, deflection_xy_rad
) -> tuple[list[Hole], RodAxis]:
    """Holes and rod axis of :func:`borescan.geometry.rod_readings` from a fit's unknowns.

    Gauge: the rod axis passes through the part origin at z = 0 (dx = dy = 0); the deflection
    vector w = omega (cos omega_az, sin omega_az) [rad]. ``center_xy_mm`` (m, 2) is hole m's
    centre relative to the point where the tilted axis crosses the height of layer m's spot,
    z_m = h_m + r_m tan(gamma_m): the shift z_m sin(omega) (cos omega_az, sin omega_az) (first
    order in omega, not identifiable beside a free centre) is moved out of the unknowns, so that
    the readings depend on w only through the section's ellipse (second order).

    Returns
    -------
    holes : list of Hole (m); axis : RodAxis
    """
    c = np.asarray(center_xy_mm, dtype=float).reshape(-1, 2)
    r = np.asarray(radius_mm, dtype=float).reshape(-1)
    h = np.array([lay.h_mm for lay in layers])
    g = np.array([lay.gamma_rad for lay in layers])
    ctr, om, az = rod_section_arrays(h, g, c, r, deflection_xy_rad)
    return [Hole((float(x), float(y)), float(rr)) for (x, y), rr in zip(ctr, r, strict=True)], RodAxis(
        0.0, 0.0, float(om), float(az)
    )


def rod_section_arrays(h_mm, gamma_rad, center_xy_mm, radius_mm, deflection_xy_rad):
    """:func:`rod_section_geometry` on arrays, for one fit's unknowns or a stack of them.

    h_mm, gamma_rad (m,): the layers'; center_xy_mm (..., m, 2), radius_mm (..., m), deflection_xy_rad
    (..., 2). Returns the holes' centres (..., m, 2) and the axis's omega and azimuth (...) [rad].
    """
    c = np.asarray(center_xy_mm, dtype=float)
    r = np.asarray(radius_mm, dtype=float)
    w = np.asarray(deflection_xy_rad, dtype=float)
    om = np.hypot(w[..., 0], w[..., 1])
    az = np.where(om > 0, np.arctan2(w[..., 1], w[..., 0]), 0.0)
    z = h_mm + r * np.tan(gamma_rad)
    ctr = c + (z * np.sinc(om / np.pi)[..., None])[..., None] * w[..., None, :]
    return ctr, om, az


def rod_section_readings(alpha_rad, layer_arrays, center_xy_mm, radius_mm, deflection_xy_rad, section=None):
    """Return the readings (..., n, m) at a rod fit's unknowns, one set or a stack of them [mm].

    The holes and axis of :func:`rod_section_arrays`, then the ray kernel
    (:func:`borescan.geometry.rod_ray_readings`): :func:`rod_section_geometry` and
    :func:`borescan.geometry.rod_readings` on arrays. ``layer_arrays``: the beams' (phi, d, h, gamma, l0)
    (:func:`borescan.geometry.rod_layer_arrays`, after any beam effect); ``section``: the (h, gamma) the
    centres are referred to (the layers before beam effects; default: ``layer_arrays``'). alpha_rad
    (..., n), center_xy_mm (..., m, 2), radius_mm (..., m), deflection_xy_rad (..., 2).
    """
    _phi, _d, h, gamma, _l0 = layer_arrays
    h, gamma = (h, gamma) if section is None else section
    ctr, om, az = rod_section_arrays(h, gamma, center_xy_mm, radius_mm, deflection_xy_rad)
    shift = np.zeros(np.shape(om) + (2,))  # the gauge: the axis through the part origin
    return rod_ray_readings(alpha_rad, layer_arrays, ctr, radius_mm, rod_axis_rotation_xy(om, az), shift)


@dataclass(frozen=True)
class RodState:
    """A rod fit's base unknowns (:func:`rod_section_geometry`).

    Attributes
    ----------
    alpha_rad : ndarray (P,), the rod's rotation per pose [rad].
    center_xy_mm : ndarray (m, 2), hole centres relative to the axis at the spot's height [mm].
    radius_mm : ndarray (m,), the holes' R20 [mm].
    deflection_xy_rad : ndarray (2,), the axis deflection w = omega (cos az, sin az) [rad].
    """

    alpha_rad: np.ndarray
    center_xy_mm: np.ndarray
    radius_mm: np.ndarray
    deflection_xy_rad: np.ndarray


@dataclass(frozen=True)
class RodJacobian:
    """Derivatives of the rod's readings with respect to the base unknowns.

    Each reading (n, m) of :meth:`RodDevice.predict` with respect to the base unknowns of its pose and layer;
    the effects held at their values.

    Attributes
    ----------
    d_alpha : ndarray (n, m), d v / d alpha of the reading's pose [mm/rad].
    d_center : ndarray (n, m, 2), d v / d centre of the reading's layer [-].
    d_radius : ndarray (n, m), d v / d R20 of the reading's layer [-].
    d_deflection : ndarray (n, m, 2), d v / d w [mm/rad].
    """

    d_alpha: np.ndarray
    d_center: np.ndarray
    d_radius: np.ndarray
    d_deflection: np.ndarray


@dataclass(frozen=True)
class RodDevice:
    """The measuring rod's model.

    Its layers' geometry (design or calibrated), the artifact's CTE, the sensors' ranges. :meth:`predict` is
    :func:`rod_forward` at the base of :meth:`base`.
    """

    layers: tuple[RodLayer, ...]
    cte_per_k: float = 0.0
    range_mm: Sequence[float] | float = 10.0

    @property
    def channels(self) -> tuple[int, ...]:
        """Return the layers' channels, in layer order."""
        return tuple(int(lay.channel) for lay in self.layers)

    def base(self, state: RodState) -> RodBase:
        """Return the base geometry of the fit's unknowns (:func:`rod_section_geometry` on these layers)."""
        holes, axis = rod_section_geometry(
            self.layers, state.center_xy_mm, state.radius_mm, state.deflection_xy_rad
        )
        return RodBase(tuple(self.layers), tuple(holes), axis, self.cte_per_k, self.range_mm)

    def predict(
        self,
        state: RodState,
        pose_index: np.ndarray,
        t_s: np.ndarray | None = None,
        effects: Iterable[Effect] = (),
    ) -> np.ndarray:
        """Noise-free readings (n, m) [mm] of the poses ``pose_index`` (n,) at times ``t_s`` (n,)."""
        alpha = np.asarray(state.alpha_rad, dtype=float)[np.asarray(pose_index)]
        return rod_forward(self.base(state), alpha, t_s, effects)

    def predict_stack(
        self,
        states: Sequence[RodState],
        pose_index: np.ndarray,
        t_s: np.ndarray | None = None,
        effects: Iterable[Effect] = (),
    ) -> np.ndarray:
        """:meth:`predict` at each of ``states`` with the same ``effects``, as a stack (S, n, m) [mm].

        One call of the ray kernel (:func:`borescan.geometry.rod_ray_readings`) for every state: a fit's
        forward differences in the base unknowns. The same numbers as :meth:`predict` state by state, to
        the rounding of numpy's vectorised loops; with bore-stage effects (which act on each state's holes)
        it is :meth:`predict` state by state.
        """
        st = _stages(effects, self.channels)
        if st["bore"]:
            return np.stack([self.predict(s, pose_index, t_s, effects) for s in states])
        v = rod_section_readings(
            np.stack([np.asarray(s.alpha_rad, dtype=float) for s in states])[:, np.asarray(pose_index)],
            rod_layer_arrays(rod_layers_with_effects(self.layers, st["beam"])),
            np.stack([np.asarray(s.center_xy_mm, dtype=float).reshape(-1, 2) for s in states]),
            np.stack([np.asarray(s.radius_mm, dtype=float) for s in states]),
            np.stack([np.asarray(s.deflection_xy_rad, dtype=float) for s in states]),
            section=(np.array([x.h_mm for x in self.layers]), np.array([x.gamma_rad for x in self.layers])),
        )
        return np.stack([rod_reading_stage(vk, t_s, st, self.channels, self.range_mm) for vk in v])

    def jacobian(
        self,
        state: RodState,
        pose_index: np.ndarray,
        t_s: np.ndarray | None = None,
        effects: Iterable[Effect] = (),
        step_rad: float = 1e-6,
        radius_step_mm: float = 1e-3,
    ) -> RodJacobian:
        """Return the derivatives of :meth:`predict` with respect to the base unknowns.

        The spot P = O + s E (O = Rm (d n(a) + h z), E = Rm (cos(gamma) u(a) + sin(gamma) z), the layers
        after the beam effects) solves |P_xy - c| = r; implicitly, with q = P_xy - c,
        ds = (r dr + q . dc - q . (dO + s dE)_xy) / (q . E_xy), dO/da = -d Rm u, dE/da = cos(gamma) Rm n;
        the centre moves with R20 by tan(gamma) sinc(omega) w (:func:`rod_section_geometry`), the
        effective radius by the bore effects' central difference (linear in R20 for the registry's);
        the reading effects by their pointwise slope. The deflection turns the whole axis: its two
        columns are central differences of :meth:`predict` (step ``step_rad``).
        """
        pose_index = np.asarray(pose_index)
        base = self.base(state)
        st = _stages(effects, self.channels)
        layers = rod_layers_with_effects(base.layers, st["beam"])
        holes = rod_holes_with_effects(base.holes, st["bore"], self.cte_per_k)
        alpha = np.asarray(state.alpha_rad, dtype=float)[pose_index]
        v = rod_readings(alpha, layers, holes, base.axis)
        Rm = rod_axis_rotation(base.axis)[:2]
        w = np.asarray(state.deflection_xy_rad, dtype=float)
        sinc = np.sinc(float(np.hypot(*w)) / np.pi)
        r20 = np.asarray(state.radius_mm, dtype=float)
        n, m = v.shape
        d_alpha, d_radius, d_center = np.empty((n, m)), np.empty((n, m)), np.empty((n, m, 2))
        for j, (lay, hole) in enumerate(zip(layers, holes, strict=True)):
            a = alpha + lay.phi_rad
            u = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)
            nn = np.stack([-np.sin(a), np.cos(a), np.zeros_like(a)], axis=-1)
            O = (lay.d_mm * nn + lay.h_mm * np.array([0.0, 0.0, 1.0])) @ Rm.T
            E = (np.cos(lay.gamma_rad) * u + np.sin(lay.gamma_rad) * np.array([0.0, 0.0, 1.0])) @ Rm.T
            s = v[:, j] + lay.l0_mm
            q = O + s[:, None] * E - np.asarray(hole.center_xy_mm, dtype=float)
            den = np.einsum("ij,ij->i", q, E)
            dO, dE = -lay.d_mm * (u @ Rm.T), np.cos(lay.gamma_rad) * (nn @ Rm.T)
            d_alpha[:, j] = -np.einsum("ij,ij->i", q, dO + s[:, None] * dE) / den
            d_center[:, j] = q / den[:, None]
            hi, lo = (
                rod_holes_with_effects([Hole(hole.center_xy_mm, r20[j] + h)], st["bore"], self.cte_per_k)[0]
                for h in (radius_step_mm, -radius_step_mm)
            )
            dr_eff = (hi.radius_mm - lo.radius_mm) / (2.0 * radius_step_mm)
            dc_dr = np.tan(base.layers[j].gamma_rad) * sinc * w
            d_radius[:, j] = (hole.radius_mm * dr_eff + q @ dc_dr) / den
        k = np.ones_like(v)
        if st["reading"]:
            k = (
                rod_reading_stage(v + 1e-4, t_s, st, self.channels, self.range_mm)
                - rod_reading_stage(v - 1e-4, t_s, st, self.channels, self.range_mm)
            ) / 2e-4
        d_deflection = np.empty((n, m, 2))
        for i in range(2):
            e = np.zeros(2)
            e[i] = step_rad
            up = self.predict(replace(state, deflection_xy_rad=w + e), pose_index, t_s, effects)
            down = self.predict(replace(state, deflection_xy_rad=w - e), pose_index, t_s, effects)
            d_deflection[..., i] = (up - down) / (2.0 * step_rad)
        return RodJacobian(d_alpha * k, d_center * k[..., None], d_radius * k, d_deflection)
