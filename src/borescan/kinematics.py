"""Rotation angle of a spindle scan: the one place it is obtained (spec "Spindle scan").

``shared/spec/geometry-and-effects.md`` fixes the order of preference for the device angle
phi(t) at a reading's time t:

1. ``encoder``: ``angle_rad`` of ``spindle.parquet`` interpolated at t; the device frame is the
   machine frame at encoder angle 0, so phi is absolute and nothing about it is fitted;
2. ``profile``: no encoder angle; the commanded profile Phi(t) = integral of the ``rpm`` column
   over the spindle clock with Phi(0) = 0 (any profile: ramps, several speeds, stops), and
   phi(t) = phase + (1 + eps) Phi(t) with the phase and the speed scale eps free;
3. ``nominal``: no spindle stream; Phi(t) = omega_nominal t from ``rpm_nominal``, phi as in 2.

The digital twin (:mod:`borescan.synthetic.simulate`) draws its scans through the same functions, so the
model that writes a scan and the model that reads it agree to rounding.

Sign: ``rpm`` is a speed magnitude with ``spindle.direction`` (``ccw`` positive, seen from +z,
raw format "Units and frames"); a profile that already carries negative values is taken as
signed. The encoder angle is signed by itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from borescan.physics.tri import commanded_device_angle

__all__ = [
    "SOURCES",
    "AngleModel",
    "profile_angle_rad",
    "angle_model_from_arrays",
    "angle_model_of_scan",
    "direction_sign",
    "speed_scale_from_readings",
    "refine_speed_scale",
    "estimate_speed_scale",
    "first_harmonic_sse_grid",
]

SOURCES = ("encoder", "profile", "nominal")
RPM_TO_RAD_S = 2.0 * math.pi / 60.0


def direction_sign(direction: str | None) -> float:
    """+1 for ``ccw`` (and missing), -1 for ``cw``; anything else is a ``ValueError``."""
    d = "ccw" if direction is None else str(direction).strip().lower()
    if d not in ("ccw", "cw"):
        raise ValueError(f"spindle.direction must be 'ccw' or 'cw', got {direction!r}")
    return 1.0 if d == "ccw" else -1.0


def profile_angle_rad(t_s: np.ndarray, knot_t_s: np.ndarray, knot_omega_rad_s: np.ndarray) -> np.ndarray:
    """Integral Phi(t) of a piecewise-linear angular speed, Phi(0) = 0.

    The speed is linear between knots (the trapezoid rule of the spindle clock, exact for a
    piecewise-linear profile) and constant outside them; within the segment k
    Phi(t) = Phi_k + w_k tau + (w_{k+1} - w_k) tau^2 / (2 dt_k), tau = t - t_k.

    Parameters
    ----------
    t_s : ndarray (...) times since scan start [s]
    knot_t_s : ndarray (m,) strictly increasing knot times [s], m >= 1
    knot_omega_rad_s : ndarray (m,) signed angular speed at the knots [rad/s]

    Returns
    -------
    ndarray (...) turned angle since t = 0 [rad]
    """
    tk = np.asarray(knot_t_s, dtype=float)
    wk = np.asarray(knot_omega_rad_s, dtype=float)
    t = np.asarray(t_s, dtype=float)
    if tk.ndim != 1 or tk.shape != wk.shape or tk.size == 0:
        raise ValueError("profile knots must be two 1-d arrays of one length >= 1")
    if tk.size == 1:
        return wk[0] * t
    if np.any(np.diff(tk) <= 0):
        raise ValueError("profile knot times must be strictly increasing")
    dt = np.diff(tk)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (wk[:-1] + wk[1:]) * dt)])  # Phi at knots, from tk[0]
    # Phi measured from t = 0: before the first knot the speed is wk[0]
    phi_at_0 = _segment_integral(np.array(0.0), tk, wk, cum, dt)
    return _segment_integral(t, tk, wk, cum, dt) - phi_at_0


def _segment_integral(t, tk, wk, cum, dt):
    k = np.clip(np.searchsorted(tk, t, side="right") - 1, 0, tk.size - 2)
    tau = t - tk[k]
    before = t < tk[0]
    after = t > tk[-1]
    slope = (wk[k + 1] - wk[k]) / dt[k]
    inside = cum[k] + wk[k] * tau + 0.5 * slope * tau * tau
    out = np.where(before, wk[0] * (t - tk[0]), inside)
    return np.where(after, cum[-1] + wk[-1] * (t - tk[-1]), out)


@dataclass(frozen=True)
class AngleModel:
    """How phi(t) is obtained for one scan, and the commanded angle Phi(t) it rests on.

    Attributes
    ----------
    source : ``"encoder"``, ``"profile"`` or ``"nominal"`` (module doc).
    knot_t_s : (m,) spindle clock [s] (one knot at t = 0 for ``nominal``).
    knot_value : (m,) encoder angle [rad] (``encoder``) or signed angular speed [rad/s]
        (``profile``, ``nominal``).
    """

    source: str
    knot_t_s: np.ndarray
    knot_value: np.ndarray

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"angle source must be one of {SOURCES}, got {self.source!r}")
        t = np.asarray(self.knot_t_s, dtype=float)
        v = np.asarray(self.knot_value, dtype=float)
        if t.shape != v.shape or t.ndim != 1 or t.size == 0:
            raise ValueError("AngleModel needs two 1-d knot arrays of one length >= 1")
        if self.source == "encoder" and t.size < 2:
            raise ValueError("an encoder angle needs at least 2 valid samples")
        object.__setattr__(self, "knot_t_s", t)
        object.__setattr__(self, "knot_value", v)
        object.__setattr__(
            self, "_last", (None, None, None)
        )  # (t array, Phi(t)): fits evaluate one t again and again

    @property
    def fits_speed_and_phase(self) -> bool:
        """True when phi = phase + (1 + eps) Phi(t) has a free phase and speed scale."""
        return self.source != "encoder"

    def commanded_rad(self, t_s: np.ndarray) -> np.ndarray:
        """Phi(t): the encoder angle, or the integral of the commanded speed from t = 0 [rad]."""
        key = _readonly_key(t_s)
        last_key, _, last_phi = self._last
        if key is not None and key == last_key:  # the same read-only times (or a view of them) as last time
            return last_phi
        t = np.asarray(t_s, dtype=float)
        if self.source == "encoder":
            phi = _encoder_interp(t, self.knot_t_s, self.knot_value)
        else:
            phi = profile_angle_rad(t, self.knot_t_s, self.knot_value)
        if key is not None:
            phi.flags.writeable = False
            # the base array is held so that its memory cannot be reused by another array
            object.__setattr__(self, "_last", (key, t_s.base if t_s.base is not None else t_s, phi))
        return phi

    def phi_rad(self, t_s: np.ndarray, phase_rad: float = 0.0, speed_scale: float = 1.0) -> np.ndarray:
        """Device angle phi(t) = phase + scale Phi(t) (``encoder``: the interpolated angle itself)."""
        if self.source == "encoder":
            return self.commanded_rad(t_s)
        return commanded_device_angle(self.commanded_rad(t_s), phase_rad, speed_scale)

    def mean_omega_rad_s(self) -> float:
        """Signed mean angular speed over the spindle clock [rad/s] (nominal: the constant speed)."""
        if self.knot_t_s.size < 2:
            return float(self.knot_value[0])
        span = self.knot_t_s[-1] - self.knot_t_s[0]
        return float((self.commanded_rad(self.knot_t_s[-1]) - self.commanded_rad(self.knot_t_s[0])) / span)

    def describe(self) -> str:
        """Return a sentence saying where the angle comes from."""
        return {
            "encoder": "encoder angle interpolated at each reading (absolute frame)",
            "profile": "integral of the rpm profile, phase and speed scale fitted",
            "nominal": "rpm_nominal * t, phase and speed scale fitted",
        }[self.source]


def _readonly_key(t) -> tuple | None:
    """Return the identity of a read-only float array's values, or None.

    Identity of a read-only float array's values (memory, shape, strides), None otherwise:
    evaluations on such an array (fits evaluate one set of times again and again) are cached.
    """
    if not isinstance(t, np.ndarray) or t.dtype != np.float64 or t.flags.writeable:
        return None
    base = t
    while base.base is not None and isinstance(base.base, np.ndarray):
        base = base.base
    if base.flags.writeable:  # a read-only view of a writable array may change under it
        return None
    return (t.__array_interface__["data"][0], t.shape, t.strides)


def _encoder_interp(t: np.ndarray, tk: np.ndarray, ak: np.ndarray) -> np.ndarray:
    """Cubic (not-a-knot) spline of the unwrapped encoder angle; linear with too few samples.

    Outside the encoder's time span the angle continues at the end speeds (linear).
    """
    if tk.size < 4:
        return _lin_extrap(t, tk, ak)
    from scipy.interpolate import CubicSpline

    cs = CubicSpline(tk, ak, bc_type="not-a-knot", extrapolate=False)
    out = cs(t)
    lo, hi = t < tk[0], t > tk[-1]
    if np.any(lo) or np.any(hi):
        d = cs.derivative()
        out = np.where(lo, ak[0] + d(tk[0]) * (t - tk[0]), out)
        out = np.where(hi, ak[-1] + d(tk[-1]) * (t - tk[-1]), out)
    return out


def _lin_extrap(t, tk, ak):
    s0 = (ak[1] - ak[0]) / (tk[1] - tk[0])
    s1 = (ak[-1] - ak[-2]) / (tk[-1] - tk[-2])
    out = np.interp(t, tk, ak)
    out = np.where(t < tk[0], ak[0] + s0 * (t - tk[0]), out)
    return np.where(t > tk[-1], ak[-1] + s1 * (t - tk[-1]), out)


def angle_model_from_arrays(
    *,
    rpm_nominal: float | None,
    direction: str | None = "ccw",
    spindle_t_s: np.ndarray | None = None,
    spindle_angle_rad: np.ndarray | None = None,
    spindle_rpm: np.ndarray | None = None,
) -> AngleModel:
    """Return the :class:`AngleModel` of a scan, in the spec's order of preference.

    Parameters
    ----------
    rpm_nominal : ``spindle.rpm_nominal`` of scan.json [1/min] (used only without a stream)
    direction : ``spindle.direction`` (``ccw``/``cw``)
    spindle_t_s, spindle_angle_rad, spindle_rpm : the spindle stream's columns (NaN = null)

    Raises
    ------
    ValueError when neither a usable stream nor ``rpm_nominal`` gives an angle.
    """
    sgn = direction_sign(direction)
    if spindle_t_s is not None and len(spindle_t_s) > 0:
        ts = np.asarray(spindle_t_s, dtype=float)
        if spindle_angle_rad is not None:
            a = np.asarray(spindle_angle_rad, dtype=float)
            ok = np.isfinite(a)
            if ok.sum() >= 2:
                return AngleModel("encoder", ts[ok], a[ok])
        if spindle_rpm is not None:
            r = np.asarray(spindle_rpm, dtype=float)
            ok = np.isfinite(r)
            if ok.any():
                r = r[ok]
                signed = r if np.any(r < 0) else sgn * r
                return AngleModel("profile", ts[ok], signed * RPM_TO_RAD_S)
    if rpm_nominal is None or not np.isfinite(float(rpm_nominal)) or float(rpm_nominal) == 0.0:
        raise ValueError(
            "no encoder angle, no rpm profile and no spindle.rpm_nominal: the rotation angle is unknown"
        )
    return AngleModel("nominal", np.zeros(1), np.array([sgn * abs(float(rpm_nominal)) * RPM_TO_RAD_S]))


def angle_model_of_scan(meta: dict, spindle) -> AngleModel:
    """Return the angle model of one raw scan.

    :func:`angle_model_from_arrays` of one raw scan: ``scan.json`` (``meta``) and its spindle
    stream (a polars frame with the raw format's columns, or None); nulls become NaN.
    """
    sp_meta = meta.get("spindle") or {}
    kw = {}
    if spindle is not None and spindle.height:
        kw = {
            "spindle_t_s": spindle["t_ns"].to_numpy().astype(float) * 1e-9,
            "spindle_angle_rad": spindle["angle_rad"].cast(float).fill_null(np.nan).to_numpy(),
            "spindle_rpm": spindle["rpm"].cast(float).fill_null(np.nan).to_numpy(),
        }
    return angle_model_from_arrays(
        rpm_nominal=sp_meta.get("rpm_nominal"), direction=sp_meta.get("direction", "ccw"), **kw
    )


def speed_scale_from_readings(
    commanded_rad: np.ndarray,
    readings_mm: np.ndarray,
    *,
    scale_range: tuple[float, float] = (0.25, 4.0),
) -> float:
    """Coarse speed scale 1 + eps: the readings are periodic in phi = phase + (1 + eps) Phi.

    Every channel is resampled on a uniform grid of the commanded angle Phi (nulls bridged
    linearly for this estimate only), the power spectra are summed and the strongest line in
    ``scale_range`` cycles per revolution of Phi is refined by a parabola through its bin and
    its neighbours. A ring-gauge reading is dominated by its first harmonic (amplitude = the
    spindle offset), so that line is the rotation itself.

    Parameters
    ----------
    commanded_rad : (n,) Phi at each reading [rad] (monotonic: stops and reversals are sorted out)
    readings_mm : (n, c) [mm], NaN = null

    Returns
    -------
    float, the estimated (1 + eps) > 0 (sign of Phi's direction included in Phi itself).
    """
    Phi = np.asarray(commanded_rad, dtype=float)
    y = np.asarray(readings_mm, dtype=float).reshape(Phi.size, -1)
    sgn = 1.0 if Phi[-1] >= Phi[0] else -1.0
    x = sgn * Phi
    order = np.argsort(x, kind="stable")
    x = x[order]
    y = y[order]
    keep = np.concatenate([[True], np.diff(x) > 1e-12])
    x, y = x[keep], y[keep]
    span = x[-1] - x[0]
    if span <= 0:
        raise ValueError("the commanded angle does not advance: no speed to estimate")
    n_grid = int(min(max(8 * x.size, 1024), 1 << 20))
    n_grid = 1 << int(math.ceil(math.log2(n_grid)))
    grid = x[0] + np.arange(n_grid) * (span / n_grid)
    power = np.zeros(n_grid // 2 + 1)
    window = np.hanning(n_grid)  # up to 2^20 points: once, not per channel
    for j in range(y.shape[1]):
        ok = np.isfinite(y[:, j])
        if ok.sum() < 8:
            continue
        yj = np.interp(grid, x[ok], y[ok, j])
        yj = yj - yj.mean()
        power += np.abs(np.fft.rfft(yj * window)) ** 2
    # bin k is k / span cycles per rad of Phi, i.e. 2 pi k / span cycles per revolution of Phi
    cyc = 2.0 * math.pi * np.arange(power.size) / span
    band = (cyc >= scale_range[0]) & (cyc <= scale_range[1])
    if not band.any() or not np.any(power[band] > 0):
        raise ValueError("no rotation line in the readings' spectrum")
    k = int(np.flatnonzero(band)[np.argmax(power[band])])
    if 0 < k < power.size - 1:
        a, b, c = np.log(power[k - 1 : k + 2] + 1e-300)
        den = a - 2 * b + c
        dk = 0.5 * (a - c) / den if den < 0 else 0.0
    else:
        dk = 0.0
    return float(2.0 * math.pi * (k + dk) / span)


def first_harmonic_sse_grid(
    scales: np.ndarray, commanded_rad: np.ndarray, readings_mm: np.ndarray, mask: np.ndarray
) -> np.ndarray:
    """Misfit of v_c ~ k_c + a_c cos(phi) + b_c sin(phi), each channel on its own, at phi = g Phi per scale g.

    The sum over channels of each channel's least-squares residual sum of squares [mm^2], one value per
    scale of ``scales`` (G,), for the readings ``readings_mm`` (n, c) at commanded angles ``commanded_rad``
    (n,) [rad] that ``mask`` (n, c) keeps (a channel with fewer than four is left out). Every scale is
    solved at once: the 3 x 3 normal equations of (1, cos, sin) per scale in one batch, then the residuals
    themselves (so the sum of squares is off by |A d|^2 for a solution error d: second order, no
    cancellation against |v|^2). Each channel's columns are well conditioned over the revolution or more
    of a scan; cos and sin are computed once for all channels.
    """
    g = np.asarray(scales, dtype=float)
    y = np.asarray(readings_mm, dtype=float)
    phi = np.multiply.outer(g, np.asarray(commanded_rad, dtype=float))
    cos_all, sin_all = np.cos(phi), np.sin(phi)
    sse = np.zeros(g.size)
    for j in range(y.shape[1]):
        m = mask[:, j]
        n = int(m.sum())
        if n < 4:
            continue
        c, s, v = cos_all[:, m], sin_all[:, m], y[m, j]
        normal = np.empty((g.size, 3, 3))
        normal[:, 0, 0] = n
        normal[:, 0, 1] = normal[:, 1, 0] = c.sum(axis=1)
        normal[:, 0, 2] = normal[:, 2, 0] = s.sum(axis=1)
        normal[:, 1, 1] = np.einsum("gn,gn->g", c, c)
        normal[:, 2, 2] = np.einsum("gn,gn->g", s, s)
        normal[:, 1, 2] = normal[:, 2, 1] = np.einsum("gn,gn->g", c, s)
        rhs = np.stack([np.full(g.size, v.sum()), c @ v, s @ v], axis=1)
        try:
            k_a_b = np.linalg.solve(normal, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:  # readings at fewer than three distinct angles: the least-norm
            # least-squares solution, as lstsq gives it (pinv(A^T A) A^T = pinv(A): the same residuals)
            k_a_b = np.einsum("gij,gj->gi", np.linalg.pinv(normal), rhs)
        r = k_a_b[:, :1] + k_a_b[:, 1:2] * c + k_a_b[:, 2:] * s - v
        sse += np.einsum("gn,gn->g", r, r)
    return sse


def refine_speed_scale(
    commanded_rad: np.ndarray, readings_mm: np.ndarray, coarse: float, max_samples: int = 4000
) -> float:
    """Speed scale 1 + eps minimising the first-harmonic misfit near a coarse spectral estimate.

    A grid over +-1.5 spectral bins (bin = 2 pi / span of Phi) with 121 points, then a parabola
    through the best point and its neighbours; at most ``max_samples`` samples are used. The
    phase error this leaves at the end of the scan is below ~0.05 rad, well inside the
    convergence region of the least-squares fits that follow.
    """
    Phi = np.asarray(commanded_rad, dtype=float)
    y = np.asarray(readings_mm, dtype=float).reshape(Phi.size, -1)
    sub = slice(None, None, max(1, Phi.size // max_samples))
    P, ys = Phi[sub], y[sub]
    ms = np.isfinite(ys)
    span = float(np.ptp(Phi)) or 1.0
    half = 1.5 * 2.0 * math.pi / span
    grid = coarse + np.linspace(-half, half, 121)
    sse = first_harmonic_sse_grid(grid, P, ys, ms)
    i = int(np.argmin(sse))
    if 0 < i < grid.size - 1:
        a, b, c = sse[i - 1 : i + 2]
        den = a - 2 * b + c
        if den > 0:
            return float(grid[i] + 0.5 * (a - c) / den * (grid[1] - grid[0]))
    return float(grid[i])


def estimate_speed_scale(
    commanded_rad: np.ndarray, readings_mm: np.ndarray, scale_range: tuple[float, float] = (0.25, 4.0)
) -> float:
    """:func:`speed_scale_from_readings` refined by :func:`refine_speed_scale`."""
    coarse = speed_scale_from_readings(commanded_rad, readings_mm, scale_range=scale_range)
    return refine_speed_scale(commanded_rad, readings_mm, coarse)
