"""The one forward model of a three-sensor spindle scan: base geometry plus registered effects.

The digital twin (:func:`borescan.synthetic.scenes.tri_readings`), the discrepancy workflow
(:meth:`borescan.discrepancy.tri.TriModel.predict`) and the full-data calibration
(:mod:`borescan.calibrate.residuals`: :func:`tri_readings_at`, :func:`commanded_device_angle`,
:func:`tri_spindle_jacobian`) evaluate readings here and nowhere else. The physics of each named
effect is its forward function in :mod:`borescan.effects`; the ray-to-bore reading is
:func:`borescan.geometry.tri_spindle_readings`.

Composition order (``shared/spec/geometry-and-effects.md``; stages of :mod:`borescan.effects`):

1. time base: ``channel_delay`` gives channel c the time t_c = t - tau_c; everything below
   is evaluated at t_c (the channel shows the whole reading of time t - tau);
2. kinematics: x = Phi(t_c), the unsigned turned angle the base model assumes (the commanded
   profile, omega t at constant speed), then ``speed_error`` (x (1 + eps)), then
   ``speed_ripple`` (x + a sin(x + phase)); device angle phi = phase_rad + direction x;
3. spindle position: S = S0 (+ ``spindle_error_motion`` at phi);
4. bore: circle C, R20, then ``axis_tilt``, ``bore_lobing``, ``thermal_expansion`` (each
   changes its own part of :class:`~borescan.geometry.Bore`, so their order is immaterial);
5. exact intersection, v = s - d_b (:func:`~borescan.geometry.tri_spindle_readings`);
6. beam: ``beam_tilt`` (v / cos gamma);
7. reading: offset, gain, nonlinearity, drift (k t_c), vibration (at t_c).

Output-stage effects (noise, ``quantization``, ``outliers``) are the generators' business
(:func:`borescan.synthetic.simulate.simulate_tri_spindle`). Steps 1-7 are noise-free and deterministic.

A static set (no spindle stream) is the same model with one device position and angle per pose
(:class:`TriDevice`): steps 2-3 are then given, not computed, so kinematic and spindle-position
effects do not apply; :func:`borescan.synthetic.simulate.simulate_tri_static` and the static discrepancy
model (:class:`borescan.discrepancy.poses.StaticModel`) both call :meth:`TriDevice.predict`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from borescan.effects import EFFECTS, Effect, apply_effects, sort_effects
from borescan.geometry import (
    Beams,
    Bore,
    beam_frame,
    bore_wall_radius,
    tri_spindle_readings,
    tri_spindle_readings_channel_major,
)

__all__ = [
    "TriBase",
    "GEOMETRY_STAGES",
    "channel_times",
    "device_angle",
    "spindle_positions",
    "bore_with_effects",
    "tri_geometry",
    "tri_scene",
    "tri_readings_at",
    "tri_reading_stage",
    "tri_forward",
    "CORRECTABLE_STAGES",
    "tri_correct_readings",
    "first_harmonic_start",
    "commanded_device_angle",
    "tri_spindle_jacobian",
    "TriStaticState",
    "TriStaticJacobian",
    "TriDevice",
    "reading_stage_slope",
]

TRI = "tri_lds"
_SPEED_ERROR = EFFECTS["speed_error"].forward[TRI]
#: Stages that change the ray geometry (steps 1-5); the rest act on the readings.
GEOMETRY_STAGES: tuple[str, ...] = ("time_base", "kinematics", "spindle_position", "bore")


@dataclass(frozen=True)
class TriBase:
    """Base geometry of a spindle scan: everything the readings depend on except the effects.

    Attributes
    ----------
    beams : beam geometry (beta [rad], rho [mm], d_b [mm] per channel).
    bore : the effect-free bore: circle of centre C (machine frame) and radius R20 [mm].
    spindle_xy_mm : spindle axis S0, (2,) or one per sample (n, 2) [mm].
    turned_rad : t [s] -> unsigned turned angle x(t) the base model assumes [rad] (omega t,
        the integral of the commanded rpm profile, or the encoder angle less its start).
    phase_rad : device angle at x = 0 [rad]; direction : +1 ccw, -1 cw.
    cte_per_k : artifact expansion coefficient for ``thermal_expansion`` [1/K].
    range_mm : sensor range per channel, for ``sensor_nonlinearity`` [mm].
    """

    beams: Beams
    bore: Bore
    spindle_xy_mm: np.ndarray
    turned_rad: Callable[[np.ndarray], np.ndarray]
    phase_rad: float = 0.0
    direction: float = 1.0
    cte_per_k: float = 0.0
    range_mm: Sequence[float] | float = 10.0

    @property
    def channels(self) -> tuple[int, ...]:
        """The beams' channels."""
        return self.beams.channels


def channel_times(t_s: np.ndarray, channels: Sequence[int], time_effects: Sequence[Effect]) -> np.ndarray:
    """Return times each channel's reading belongs to (step 1): t_c = t - tau_c.

    Returns
    -------
    ndarray (n, 1) without time-base effects (broadcasts over channels), else (n, c) [s].
    """
    t = np.asarray(t_s, dtype=float)
    if not time_effects:
        return t[:, None]
    tc = np.repeat(t[:, None], len(channels), axis=1)
    for e in time_effects:
        j = list(channels).index(e.channel)
        tc[:, j] = e.spec.forward[TRI](tc[:, j], e.params)
    return tc


def device_angle(base: TriBase, t_s: np.ndarray, kinematic_effects: Sequence[Effect]) -> np.ndarray:
    """Device angle phi = phase + direction x, x = turned angle after the kinematic effects (step 2).

    Parameters
    ----------
    t_s : ndarray (...) [s]

    Returns
    -------
    ndarray (...) [rad]
    """
    x = base.turned_rad(t_s)
    for e in kinematic_effects:
        x = e.spec.forward[TRI](x, e.params)
    return base.phase_rad + base.direction * x


def spindle_positions(base: TriBase, phi_rad: np.ndarray, position_effects: Sequence[Effect]) -> np.ndarray:
    """Spindle axis S(phi) (step 3): S0, plus ``spindle_error_motion`` at the device angle.

    Returns
    -------
    ndarray (2,) or (n, 2) without effects, else (n, 1, 2) where every channel has the sample's angle
    (``phi_rad`` (n,) or (n, 1): the position is computed once per sample) or (n, c, 2) [mm].
    """
    S = np.asarray(base.spindle_xy_mm, dtype=float)
    if not position_effects:
        return S
    phi = np.asarray(phi_rad, dtype=float)
    phi = phi[:, None] if phi.ndim == 1 else phi
    S = S[:, None, :] if S.ndim == 2 else S
    for e in position_effects:
        S = e.spec.forward[TRI](S, phi, e.params)
    return S


def bore_with_effects(
    bore: Bore, bore_effects: Iterable[Effect], cte_per_k: float, device: str = TRI
) -> Bore:
    """Return the bore after the bore-stage effects (step 4), in composition order."""
    for e in bore_effects:
        bore = e.spec.forward[device](bore, e.params, cte_per_k)
    return bore


def tri_geometry(
    base: TriBase, t_s: np.ndarray, st: dict[str, list[Effect]]
) -> tuple[np.ndarray, np.ndarray]:
    """Compute steps 1-5: exact readings of the ray geometry with the geometric effects.

    ``t_s`` (n,) sample times since scan start [s]; ``st`` effects grouped by stage (:func:`sort_effects`).
    Returns v (n, c) [mm] and the channel times tc (n, 1) or (n, c) [s].
    """
    tc, phi, S, bore = tri_scene(base, t_s, st)
    return tri_readings_at(phi, S, base.beams, bore), tc


def tri_scene(base: TriBase, t_s: np.ndarray, st: dict[str, list[Effect]]) -> tuple:
    """Compute steps 1-4 of :func:`tri_geometry`: channel times tc, device angle phi, spindle axis S, bore."""
    tc = channel_times(t_s, base.channels, st["time_base"])
    phi = device_angle(base, tc, st["kinematics"])
    S = spindle_positions(base, phi, st["spindle_position"])
    return tc, phi, S, bore_with_effects(base.bore, st["bore"], base.cte_per_k)


def tri_readings_at(phi_rad: np.ndarray, spindle_xy_mm: np.ndarray, beams: Beams, bore: Bore) -> np.ndarray:
    """Step 5: exact readings at given device angles and spindle positions in a bore (its effects applied).

    The step of :func:`tri_forward` (through :func:`tri_geometry`), of the static sets
    (:meth:`TriDevice.predict`) and of the full-data calibration on its ring gauge
    (:mod:`borescan.calibrate.residuals`): v = s - d_b, s > 0 the root of
    |S + Rot(phi)(F + s u) - C| = r_wall (:func:`borescan.geometry.tri_spindle_readings`).

    Parameters
    ----------
    phi_rad : ndarray (n,) or (n, c) device angle [rad]
    spindle_xy_mm : ndarray (2,), (n, 2) or (n, c, 2) spindle axis S [mm]
    beams : Beams; bore : Bore (after step 4)

    Returns
    -------
    ndarray (n, c) [mm]; NaN where a beam misses.
    """
    return tri_spindle_readings(phi_rad, spindle_xy_mm, beams, bore)


def tri_reading_stage(
    v_mm: np.ndarray,
    tc_s: np.ndarray,
    st: dict[str, list[Effect]],
    channels: Sequence[int],
    range_mm: Sequence[float] | float,
) -> np.ndarray:
    """Apply steps 6-7: beam and reading effects on readings ``v_mm`` (n, c) at channel times ``tc_s``."""
    if not (st["beam"] or st["reading"]):
        return v_mm
    return apply_effects(
        v_mm, tc_s, channels, st["beam"] + st["reading"], range_mm=range_mm, stages=("beam", "reading")
    )


def tri_forward(base: TriBase, t_s: np.ndarray, effects: Iterable[Effect] = ()) -> np.ndarray:
    """Noise-free readings of a spindle scan with effects (steps 1-7 of the module doc).

    v = s - d_b, s > 0 the root of |S(phi) + Rot(phi)(F + s u) - C| = r_wall(theta),
    phi = phi(t_c), then beam and reading effects.

    Parameters
    ----------
    base : TriBase
    t_s : ndarray (n,) sample times since scan start [s]
    effects : :class:`~borescan.effects.Effect` (output-stage effects are ignored)

    Returns
    -------
    ndarray (n, c) readings [mm], channels in ``base.beams`` order; NaN where a beam misses.
    """
    st = sort_effects(effects, TRI, base.channels)
    v, tc = tri_geometry(base, t_s, st)
    return tri_reading_stage(v, tc, st, base.channels, base.range_mm)


def first_harmonic_start(
    phi_rad: np.ndarray, readings_mm: np.ndarray, mask: np.ndarray, beta_rad: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """Return the spindle's offset from the bore centre from the readings' first harmonic: a linear start.

    To first order in the offset o = S - C (the geometry expanded about a centred spindle), channel c
    reads v_c = k_c - o . u(phi + beta_c); o and the levels k_c by linear least squares over the
    readings ``mask`` keeps. The start of the calibration and of the discrepancy fit's bore centre.

    Parameters
    ----------
    phi_rad : ndarray (n,) device angle [rad]
    readings_mm : ndarray (n, c) [mm]; mask : ndarray (n, c) bool, the readings to use
    beta_rad : ndarray (c,) beam directions [rad]

    Returns
    -------
    offset (2,) [mm], levels k (c,) [mm], the sum of squared residuals [mm^2]
    """
    c = readings_mm.shape[1]
    rows, rhs = [], []
    for j in range(c):
        m = mask[:, j]
        ang = phi_rad[m] + beta_rad[j]
        A = np.zeros((m.sum(), 2 + c))
        A[:, 0] = -np.cos(ang)
        A[:, 1] = -np.sin(ang)
        A[:, 2 + j] = 1.0
        rows.append(A)
        rhs.append(readings_mm[m, j])
    A = np.vstack(rows)
    b = np.concatenate(rhs)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    sse = float(np.sum((A @ sol - b) ** 2))
    return sol[:2], sol[2:], sse


def commanded_device_angle(commanded_rad: np.ndarray, phase_rad: float, speed_scale: float) -> np.ndarray:
    """Device angle phi = phase + scale Phi of a turned angle Phi the fit takes as commanded [rad].

    Step 2 of the module doc with ``speed_error`` of eps = scale - 1: ``commanded_rad`` is the signed
    commanded angle (direction x, :meth:`borescan.kinematics.AngleModel.commanded_rad`), so
    phase + direction (1 + eps) x = phase + scale Phi. The one place of this kinematics for the fits
    (:mod:`borescan.calibrate`, :meth:`borescan.kinematics.AngleModel.phi_rad`), through the registry's
    ``speed_error`` forward function (:func:`device_angle` applies the same one in :func:`tri_forward`).
    """
    return phase_rad + _SPEED_ERROR(commanded_rad, {"eps": speed_scale - 1.0})


def tri_spindle_jacobian(
    phi: np.ndarray, beams: Beams, offset: np.ndarray, R: float, readings_cn: np.ndarray | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Return the exact readings of a spindle scan on a ring gauge at device angles ``phi``, with derivatives.

    Exact readings (n, c) at device angles ``phi`` (n,) (or per channel, (n, c) / (n, 1)) and
    their analytic derivatives, channel-major: each ``jac[...]`` is (c, n) (``.T`` is the (n, c) view).

    The wall point is P = o + Rot(phi)(F + s u) with the gauge centre at the origin; implicit
    differentiation of |P|^2 = R^2 gives ds/dp = -(P . dP/dp) / (P . Rot(phi) u).
    ``jac["phi"]`` is dv/dphi (the chain rule gives phase and speed-scale columns). Computed
    channel-major for numpy's long inner loops, as :func:`borescan.geometry.tri_spindle_readings`.
    The gauge of the calibration (a circle, no effects): the readings are those of :func:`tri_forward`
    (checked in the tests), the derivatives against its central differences. ``readings_cn``: the
    readings (c, n) at these angles when the caller has them already (the calibration's residuals).
    """
    phi = np.asarray(phi, dtype=float)
    phi = phi[:, None] if phi.ndim == 1 else phi
    v_cn = (
        tri_spindle_readings_channel_major(phi, offset, beams, Bore((0.0, 0.0), R))  # (c, n)
        if readings_cn is None
        else readings_cn
    )
    s = v_cn + np.asarray(beams.d_b_mm, dtype=float)[:, None]
    F, u = beam_frame(beams.beta_rad, beams.rho_mm)  # (c, 2)
    n_vec = np.stack([-u[:, 1], u[:, 0]], axis=-1)
    cph, sph = np.ascontiguousarray(np.cos(phi).T), np.ascontiguousarray(np.sin(phi).T)  # (1 or c, n)

    def rot(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return cph * a[:, 0:1] - sph * a[:, 1:2], sph * a[:, 0:1] + cph * a[:, 1:2]

    dev_x, dev_y = F[:, 0:1] + s * u[:, 0:1], F[:, 1:2] + s * u[:, 1:2]  # device-frame wall points
    wx = cph * dev_x - sph * dev_y
    wy = sph * dev_x + cph * dev_y
    Px, Py = offset[0] + wx, offset[1] + wy
    ux, uy = rot(u)
    den = Px * ux + Py * uy
    nx, ny = rot(n_vec)
    rho = np.asarray(beams.rho_mm, dtype=float)[:, None]
    # dP/dbeta = Rot(phi)(-rho u + s n)
    dbx, dby = -rho * ux + s * nx, -rho * uy + s * ny
    jac = {
        "beta": -(Px * dbx + Py * dby) / den,
        "rho": -(Px * nx + Py * ny) / den,
        "ox": -Px / den,
        "oy": -Py / den,
        # dP/dphi = perp(Rot(phi)(F + s u)) = (-wy, wx)
        "phi": -(Px * (-wy) + Py * wx) / den,
    }
    return v_cn.T, jac


#: Stages whose effects recorded readings can be corrected for pointwise, without the scene: what a
#: channel's sensor makes of its distance (beam, reading). A time-base effect (``channel_delay``) is
#: carried by the time each channel's angle is taken at, never by resampling the readings (that would
#: average neighbouring noise: a smaller, correlated scatter the fit would take for the noise).
CORRECTABLE_STAGES: tuple[str, ...] = ("beam", "reading")


def tri_correct_readings(
    t_s: np.ndarray,
    readings_mm: np.ndarray,
    channels: Sequence[int],
    effects: Iterable[Effect],
    range_mm: Sequence[float] | float = 10.0,
    *,
    tol_mm: float = 1e-12,
    max_iter: int = 50,
) -> np.ndarray:
    """Return readings corrected for beam and reading effects.

    Return readings corrected for beam and reading effects: the inverse of steps 6-7 of :func:`tri_forward`
    (a device model's effects, carried).

    v_obs = f(v), f the composed forward functions of the registry at each reading's channel time,
    is inverted by the fixed point v <- v_obs - (f(v) - v) (f is the identity plus an effect far
    smaller than v; stops at ``tol_mm``). Each reading is corrected on its own: the noise stays white.

    Parameters
    ----------
    t_s : ndarray (n,) sample times [s] (``sensor_drift``)
    readings_mm : ndarray (n, c) recorded readings [mm], NaN for nulls (they stay null)
    channels : the channels of the columns
    effects : :class:`~borescan.effects.Effect` of the beam and reading stages (others raise)
    range_mm : sensor range per channel, for ``sensor_nonlinearity`` [mm]

    Returns
    -------
    ndarray (n, c) [mm]: readings as the base model (without these effects) would give them.

    Raises
    ------
    ValueError for an effect of another stage (it changes the scene or the time a channel sees, not
    what its sensor makes of a distance) or a fixed point that does not converge.
    """
    effects = list(effects)
    st = sort_effects(effects, TRI, channels)
    other = [e.name for stage, es in st.items() if stage not in CORRECTABLE_STAGES for e in es]
    if other:
        raise ValueError(
            f"effects {other} are not corrected in the readings: they change the scene or the time a "
            "channel sees (a channel delay is carried by the channel's angle)"
        )
    v_obs = np.asarray(readings_mm, dtype=float)
    tc = np.asarray(t_s, dtype=float)[:, None]
    v = v_obs.copy()
    for _ in range(max_iter):
        v_new = v_obs - (tri_reading_stage(v, tc, st, channels, range_mm) - v)
        done = np.nanmax(np.abs(v_new - v), initial=0.0) <= tol_mm
        v = v_new
        if done:
            return v
    raise ValueError(
        f"correcting the readings for {[e.name for e in effects]} did not converge in {max_iter} "
        "iterations (is an effect as large as the readings?)"
    )


# --------------------------------------------------------------------------- static sets


def reading_stage_slope(
    v_mm: np.ndarray,
    tc_s: np.ndarray,
    st: dict[str, list[Effect]],
    channels: Sequence[int],
    range_mm: Sequence[float] | float,
    step_mm: float = 1e-4,
) -> np.ndarray:
    """d(steps 6-7)/dv at each reading: how a change of the geometric reading shows in the recorded one.

    The beam and reading effects act reading by reading, so the slope is the central difference of
    that pointwise map (exact for the registry's effects, which are at most quadratic in v).

    Returns
    -------
    ndarray like ``v_mm`` [-]; ones without beam and reading effects.
    """
    if not (st["beam"] or st["reading"]):
        return np.ones_like(v_mm)
    up = tri_reading_stage(v_mm + step_mm, tc_s, st, channels, range_mm)
    down = tri_reading_stage(v_mm - step_mm, tc_s, st, channels, range_mm)
    return (up - down) / (2.0 * step_mm)


@dataclass(frozen=True)
class TriStaticState:
    """Base geometry of a static set: the device's rotation axis and angle per pose, the bore.

    Attributes
    ----------
    device_xy_mm : ndarray (P, 2), the device's rotation axis per pose, machine frame [mm].
    device_angle_rad : ndarray (P,), the device's angle per pose [rad].
    bore : the effect-free bore (centre C, radius R20) [mm].
    """

    device_xy_mm: np.ndarray
    device_angle_rad: np.ndarray
    bore: Bore


@dataclass(frozen=True)
class TriStaticJacobian:
    """Derivatives of the three-sensor device's readings with respect to the base geometry.

    Each reading (n, c) of :meth:`TriDevice.predict` with respect to its pose's base geometry and the bore's;
    the effects held at their values.

    Attributes
    ----------
    d_device_xy : ndarray (n, c, 2), d v / d (x, y) of the reading's pose [-].
    d_device_angle : ndarray (n, c), d v / d angle of the reading's pose [mm/rad].
    d_center : ndarray (n, c, 2), d v / d C [-].
    d_radius : ndarray (n, c), d v / d R20 [-].
    """

    d_device_xy: np.ndarray
    d_device_angle: np.ndarray
    d_center: np.ndarray
    d_radius: np.ndarray


def _perp(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the vector turned by +90 degrees, J (x, y) = (-y, x)."""
    return -y, x


@dataclass(frozen=True)
class TriDevice:
    """The three-sensor device's model of a static set: one position and angle per pose.

    The same composition as a spindle scan (:func:`tri_forward`, module doc) with steps 2-3 given
    per pose: time base, bore effects, the exact ray-to-bore readings, beam and reading effects.

    Attributes
    ----------
    beams : beam geometry (beta [rad], rho [mm], d_b [mm] per channel).
    cte_per_k : artifact expansion coefficient for ``thermal_expansion`` [1/K].
    range_mm : sensor range per channel, for ``sensor_nonlinearity`` [mm].
    """

    beams: Beams
    cte_per_k: float = 0.0
    range_mm: Sequence[float] | float = 10.0

    @property
    def channels(self) -> tuple[int, ...]:
        """Return the beams' channels."""
        return self.beams.channels

    def _stages(self, effects: Iterable[Effect]) -> dict[str, list[Effect]]:
        st = sort_effects(effects, TRI, self.channels)
        bad = [e.name for e in st["kinematics"] + st["spindle_position"]]
        if bad:
            raise ValueError(f"effects {bad} do not apply to a static tri_lds measurement (no spindle turns)")
        return st

    def _geometry(self, state: TriStaticState, pose_index: np.ndarray, st: dict[str, list[Effect]]):
        """Return steps 4-5 per pose, then indexed per reading: (v (n, c), the bore with its effects)."""
        bore = bore_with_effects(state.bore, st["bore"], self.cte_per_k)
        ang = np.atleast_1d(np.asarray(state.device_angle_rad, dtype=float))
        xy = np.atleast_2d(np.asarray(state.device_xy_mm, dtype=float))
        return tri_readings_at(ang, xy, self.beams, bore)[np.asarray(pose_index)], bore

    def predict(
        self, state: TriStaticState, pose_index: np.ndarray, t_s: np.ndarray, effects: Iterable[Effect] = ()
    ) -> np.ndarray:
        """Noise-free readings of a static set with effects.

        Parameters
        ----------
        state : TriStaticState (P poses)
        pose_index : ndarray (n,) int, each reading's pose (0..P-1)
        t_s : ndarray (n,) times since scan start [s] (drift, vibration, channel delay)
        effects : :class:`~borescan.effects.Effect`; kinematic and spindle-position effects raise
            ``ValueError``, output-stage effects are ignored (the generators' business)

        Returns
        -------
        ndarray (n, c) [mm]; NaN where a beam misses.
        """
        st = self._stages(effects)
        v, _ = self._geometry(state, pose_index, st)
        tc = channel_times(t_s, self.channels, st["time_base"])
        return tri_reading_stage(v, tc, st, self.channels, self.range_mm)

    def jacobian(
        self,
        state: TriStaticState,
        pose_index: np.ndarray,
        t_s: np.ndarray,
        effects: Iterable[Effect] = (),
        radius_step_mm: float = 1e-3,
    ) -> TriStaticJacobian:
        """Analytic derivatives of :meth:`predict` with respect to the base geometry.

        The wall point q = o + s d (o = S - C + Rot(a) F, d = Rot(a) u, relative to the bore's
        centre) solves |q| = r_wall(theta(q)); implicitly, with g = q / |q| - r'(theta) J q / |q|^2
        (J the +90 degree turn): ds = (dr_wall - g . (dS - dC + J (Rot(a) F + s d) da)) / (g . d).
        r' is the wall's slope (:func:`borescan.geometry.bore_wall_radius`: ellipse, lobes), dr_wall /
        dR20 the central difference over the bore effects (linear in R20 for the registry's), and the
        beam and reading effects enter through their pointwise slope (:func:`reading_stage_slope`).
        """
        st = self._stages(effects)
        pose_index = np.asarray(pose_index)
        v, bore = self._geometry(state, pose_index, st)
        ang = np.atleast_1d(np.asarray(state.device_angle_rad, dtype=float))[pose_index][:, None]
        xy = np.atleast_2d(np.asarray(state.device_xy_mm, dtype=float))[pose_index]
        b = np.asarray(self.beams.beta_rad, dtype=float)[None, :]
        rho = np.asarray(self.beams.rho_mm, dtype=float)[None, :]
        s = v + np.asarray(self.beams.d_b_mm, dtype=float)[None, :]
        a = ang + b
        dx, dy = np.cos(a), np.sin(a)
        fx, fy = -rho * dy, rho * dx  # Rot(angle) F, F = rho n(beta)
        qx = xy[:, 0:1] - bore.center_xy_mm[0] + fx + s * dx
        qy = xy[:, 1:2] - bore.center_xy_mm[1] + fy + s * dy
        nq = np.hypot(qx, qy)
        theta = np.arctan2(qy, qx)
        _, slope = bore_wall_radius(theta, bore)
        jx, jy = _perp(qx, qy)
        gx, gy = qx / nq - slope * jx / nq**2, qy / nq - slope * jy / nq**2
        den = gx * dx + gy * dy
        R = state.bore.radius_mm
        hi, lo = (
            bore_with_effects(replace(state.bore, radius_mm=R + h), st["bore"], self.cte_per_k)
            for h in (radius_step_mm, -radius_step_mm)
        )
        dwall = (bore_wall_radius(theta, hi)[0] - bore_wall_radius(theta, lo)[0]) / (2.0 * radius_step_mm)
        px, py = _perp(fx + s * dx, fy + s * dy)
        tc = channel_times(t_s, self.channels, st["time_base"])
        k = reading_stage_slope(v, tc, st, self.channels, self.range_mm)
        d_xy = np.stack([-gx / den, -gy / den], axis=-1) * k[..., None]
        return TriStaticJacobian(
            d_device_xy=d_xy,
            d_device_angle=-(gx * px + gy * py) / den * k,
            d_center=-d_xy,
            d_radius=dwall / den * k,
        )
