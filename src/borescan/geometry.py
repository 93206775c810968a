"""Exact forward geometry of both devices (``shared/spec/geometry-and-effects.md``).

Everything here is a pure, vectorised function of numpy arrays. Lengths are in mm,
angles in rad. No small-angle shortcut is taken anywhere: readings come from exact
ray-circle, ray-ellipse, ray-lobed-bore (Newton to machine precision) and ray-cylinder
intersections.

Three-sensor device (``tri_lds``, Yang et al. 2017)
    Device frame: origin at the rotation axis O'. Beam i has direction
    u = (cos beta, sin beta), normal n = (-sin beta, cos beta), foot point F = rho * n and
    base length d_b; a reading v puts the wall point at W = F + (d_b + v) u, so
    |O'W|^2 = (d_b + v)^2 + rho^2 (Yang 2017, Eq. 8).

Measuring rod (``rod``, Wang et al. 2017)
    Rod frame: z along the rotation axis, origin at the rear end B. Layer m at rotation
    alpha and reading v (l = l0 + v) has its spot at
    d n(alpha+phi) + l cos(gamma) u(alpha+phi) + (h + l sin(gamma)) z.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "Beams",
    "Bore",
    "RodLayer",
    "layer_dict",
    "Hole",
    "RodAxis",
    "beam_frame",
    "centred_beam_length_mm",
    "wall_points_device",
    "ray_bore_distance",
    "bore_wall_radius",
    "bore_wall_function",
    "tri_spindle_readings",
    "tri_spindle_readings_channel_major",
    "spindle_axis_channel_major",
    "tri_static_readings",
    "circumcircle",
    "rod_axis_rotation",
    "rod_readings",
    "rod_axis_rotation_xy",
    "rod_ray_readings",
    "rod_layer_arrays",
]


# --------------------------------------------------------------------------- tri_lds


@dataclass(frozen=True)
class Beams:
    """Beam geometry of a three-sensor (or n-sensor) device, one entry per channel.

    Attributes
    ----------
    channels : tuple of int
        1-based channel numbers, in the order of the arrays below.
    beta_rad : ndarray (c,)
        Direction in which each laser travels, counter-clockwise from the device x axis [rad].
    rho_mm : ndarray (c,)
        Signed offset of each beam line from the rotation axis O' [mm]; r = |rho|.
    d_b_mm : ndarray (c,)
        Base-circle length, from the foot point F to the measuring start point [mm].
    """

    channels: tuple[int, ...]
    beta_rad: np.ndarray
    rho_mm: np.ndarray
    d_b_mm: np.ndarray

    def __post_init__(self) -> None:
        for name in ("beta_rad", "rho_mm", "d_b_mm"):
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != (len(self.channels),):
                raise ValueError(f"Beams.{name} must have shape ({len(self.channels)},), got {arr.shape}")
            object.__setattr__(self, name, arr)

    @classmethod
    def from_nominal(cls, beams: list[dict]) -> "Beams":
        """Build from ``scan.json`` ``device.nominal.beams`` (keys channel, beta, rho, d_b)."""
        beams = sorted(beams, key=lambda b: int(b["channel"]))
        return cls(
            channels=tuple(int(b["channel"]) for b in beams),
            beta_rad=np.array([float(b["beta"]) for b in beams]),
            rho_mm=np.array([float(b["rho"]) for b in beams]),
            d_b_mm=np.array([float(b["d_b"]) for b in beams]),
        )

    def to_nominal(self) -> list[dict]:
        """Inverse of :meth:`from_nominal`."""
        return [
            {"channel": int(c), "beta": float(b), "rho": float(r), "d_b": float(d)}
            for c, b, r, d in zip(self.channels, self.beta_rad, self.rho_mm, self.d_b_mm)
        ]


@dataclass(frozen=True)
class Bore:
    """A bore cross-section in machine coordinates.

    The wall radius about the centre at polar angle theta is
    ``r_e(theta) + sum_k a_k cos(k (theta - phase_k))`` where ``r_e`` is the ellipse of
    ``axis_tilt`` (semi-axes R / cos(tilt) along ``tilt_azimuth_rad`` and R across; a circle
    when tilt is 0) and the sum is ``bore_lobing``.

    Attributes
    ----------
    center_xy_mm : (2,) bore centre C in machine coordinates [mm].
    radius_mm : nominal radius R (already thermally expanded if applicable) [mm].
    tilt_rad, tilt_azimuth_rad : axis_tilt angle and the azimuth of the long axis [rad].
    lobes : tuple of (k, a_mm, phase_rad) lobing terms, k >= 2.
    """

    center_xy_mm: tuple[float, float]
    radius_mm: float
    tilt_rad: float = 0.0
    tilt_azimuth_rad: float = 0.0
    lobes: tuple[tuple[int, float, float], ...] = field(default_factory=tuple)

    @property
    def is_circle(self) -> bool:
        """Whether the bore is a circle (no tilt, no lobes)."""
        return self.tilt_rad == 0.0 and not any(a != 0.0 for _, a, _ in self.lobes)


def beam_frame(beta_rad: np.ndarray, rho_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Foot points F = rho n and unit directions u of beams in the device frame.

    Returns
    -------
    F, u : ndarray (..., 2) [mm], [-]
    """
    beta = np.asarray(beta_rad, dtype=float)
    rho = np.asarray(rho_mm, dtype=float)
    u = np.stack([np.cos(beta), np.sin(beta)], axis=-1)
    n = np.stack([-np.sin(beta), np.cos(beta)], axis=-1)
    return rho[..., None] * n, u


def centred_beam_length_mm(rho_mm: np.ndarray | float, radius_mm: float) -> np.ndarray:
    """Return s0 = sqrt(R^2 - rho^2): foot point to wall along a beam, the bore centred on the rotation axis.

    Yang 2017 Eq. 8 with O' at the centre (|O'W| = R): a centred device reads v0 = s0 - d_b. Clipped at
    0 where |rho| > R (no such beam meets the wall of a centred bore) [mm].
    """
    rho = np.asarray(rho_mm, dtype=float)
    return np.sqrt(np.maximum(radius_mm**2 - rho**2, 0.0))


def wall_points_device(readings_mm: np.ndarray, beams: Beams) -> np.ndarray:
    """Wall points W = F + (d_b + v) u in the device frame.

    Parameters
    ----------
    readings_mm : ndarray (..., c) readings v [mm], channels in ``beams`` order.

    Returns
    -------
    ndarray (..., c, 2) [mm]
    """
    v = np.asarray(readings_mm, dtype=float)
    F, u = beam_frame(beams.beta_rad, beams.rho_mm)
    s = beams.d_b_mm + v
    return F + s[..., None] * u


def _positive_root(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Larger root of a s^2 + 2 b s + c = 0 (a > 0, c < 0 when the origin is inside).

    Uses the cancellation-free form, so the root is accurate to a few ulp.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.sqrt(b * b - a * c)  # NaN where the ray misses: then both branches are NaN
        return np.where(b <= 0.0, (sq - b) / a, -c / (b + sq))


def bore_wall_radius(theta_rad: np.ndarray, bore: Bore) -> tuple[np.ndarray, np.ndarray]:
    """Wall radius r(theta) of a bore about its centre and its derivative dr/dtheta.

    Ellipse of ``axis_tilt``: r_e = A B / sqrt((B cos t)^2 + (A sin t)^2), t = theta - azimuth,
    A = R / cos(tilt), B = R. Lobing adds a cos(k (theta - phase)).
    """
    theta = np.asarray(theta_rad, dtype=float)
    R = float(bore.radius_mm)
    if (
        bore.tilt_rad == 0.0
    ):  # a circle: r = R (the ellipse's formula gives R to rounding, at 6 transcendentals a point)
        r, dr = np.full(theta.shape, R), np.zeros(theta.shape)
    else:
        A = R / np.cos(bore.tilt_rad)
        B = R
        t = theta - bore.tilt_azimuth_rad
        ct, st = np.cos(t), np.sin(t)
        q = (B * ct) ** 2 + (A * st) ** 2
        r = A * B / np.sqrt(q)
        dr = -(A * B * (A * A - B * B)) * st * ct / (q * np.sqrt(q))
    for k, a, ph in bore.lobes:
        r = r + a * np.cos(k * (theta - ph))
        dr = dr - a * k * np.sin(k * (theta - ph))
    return r, dr


def bore_wall_function(x_mm: np.ndarray, y_mm: np.ndarray, bore: Bore) -> tuple[np.ndarray, ...]:
    """Return the wall function g(P) = |P - C| - r(theta(P)) of a bore at points P = (x, y), and its gradient.

    g is zero on the wall, positive outside, and its gradient is the one :func:`_wall_distance`'s Newton
    steps use: grad g = (P - C) / |P - C| - r'(theta) grad theta, grad theta = perp(P - C) / |P - C|^2.

    Returns
    -------
    g [mm], dg/dx [-], dg/dy [-], |P - C| [mm], theta [rad]: arrays like ``x_mm``.
    """
    px, py = x_mm - bore.center_xy_mm[0], y_mm - bore.center_xy_mm[1]
    rp, theta = np.hypot(px, py), np.arctan2(py, px)
    r, dr = bore_wall_radius(theta, bore)
    q = dr / (rp * rp)
    return rp - r, px / rp + q * py, py / rp - q * px, rp, theta


def _wall_distance(ox, oy, dx, dy, bore: Bore, tol_mm: float = 1e-13, max_iter: int = 60) -> np.ndarray:
    """Distance s > 0 along rays o + s d (unit d, o relative to the bore centre) to the wall.

    The one ray-to-bore solver of borescan (components as separate arrays, for speed).
    Circle: the cancellation-free root s = -b + sqrt(b^2 - c) (b <= 0) or -c / (b + sqrt(b^2 - c)),
    b = o.d, c = |o|^2 - R^2. Ellipse of ``axis_tilt``: the same root after rotating into the
    ellipse frame and shrinking the long axis by cos(tilt) (a circle of radius R; s keeps its
    scale through the quadratic's leading coefficient). Lobes: Newton on
    |P(s)| - r(theta(P(s))) = 0 from that root, until the step is below ``tol_mm``.

    Returns
    -------
    ndarray [mm]; NaN where the ray misses (origin outside and pointing away).
    """
    R = float(bore.radius_mm)
    if bore.tilt_rad != 0.0:
        ca, sa = np.cos(bore.tilt_azimuth_rad), np.sin(bore.tilt_azimuth_rad)
        ct = np.cos(bore.tilt_rad)
        ex, ey = (ox * ca + oy * sa) * ct, -ox * sa + oy * ca
        fx, fy = (dx * ca + dy * sa) * ct, -dx * sa + dy * ca
        s = _positive_root(fx * fx + fy * fy, ex * fx + ey * fy, ex * ex + ey * ey - R * R)
    else:
        s = _positive_root(1.0, ox * dx + oy * dy, ox * ox + oy * oy - R * R)
    if not any(a != 0.0 for _, a, _ in bore.lobes):
        return s
    for _ in range(max_iter):
        px, py = ox + s * dx, oy + s * dy
        rp = np.hypot(px, py)
        rw, drw = bore_wall_radius(np.arctan2(py, px), bore)
        step = (rp - rw) / ((px * dx + py * dy) / rp - drw * (px * dy - py * dx) / rp**2)
        s = s - step
        if np.nanmax(np.abs(step), initial=0.0) < tol_mm:
            break
    return s


def ray_bore_distance(
    origin: np.ndarray, direction: np.ndarray, bore: Bore, *, tol_mm: float = 1e-13, max_iter: int = 60
) -> np.ndarray:
    """Distance s > 0 along rays (unit ``direction``) from inside a bore to its wall.

    Circle and ellipse are solved in closed form; lobed bores by Newton iteration on
    |P(s) - C| - r(theta(P(s))) = 0 started from the circle/ellipse root, to ``tol_mm``
    (the solver :func:`tri_spindle_readings` uses too).

    Parameters
    ----------
    origin, direction : ndarray (..., 2) [mm], [-]
    bore : Bore

    Returns
    -------
    ndarray (...) [mm]
    """
    o = np.asarray(origin, dtype=float) - np.asarray(bore.center_xy_mm, dtype=float)
    d = np.asarray(direction, dtype=float)
    o, d = np.broadcast_arrays(o, d)
    return _wall_distance(o[..., 0], o[..., 1], d[..., 0], d[..., 1], bore, tol_mm, max_iter)


def tri_spindle_readings(
    phi_rad: np.ndarray, spindle_xy_mm: np.ndarray, beams: Beams, bore: Bore
) -> np.ndarray:
    """Return readings of a device turning on a spindle inside a bore (exact; the one implementation).

    p_machine = S + Rot(phi) p_device; the reading is v = s - d_b with s > 0 the root of
    |S + Rot(phi)(F + s u) - C| = r_wall (spec, "Spindle scan"; Yang 2017 Eq. 8 at the extrema).
    With a = phi + beta the ray starts at o = S - C + Rot(phi) F and runs along
    (cos a, sin a); the distance comes from the closed-form circle / ellipse root, Newton for
    lobes (:func:`ray_bore_distance`). Used by the digital twin, calibration, measurement and
    the discrepancy workflow alike.

    Parameters
    ----------
    phi_rad : ndarray (n,) or (n, c)
        Device rotation angle per sample (per channel when channels see different times) [rad].
    spindle_xy_mm : ndarray (2,), (n, 2) or (n, c, 2)
        Spindle axis S in machine coordinates [mm].
    beams : Beams; bore : Bore

    Returns
    -------
    ndarray (n, c) readings v [mm]; NaN where a beam misses the wall.
    """
    return np.ascontiguousarray(tri_spindle_readings_channel_major(phi_rad, spindle_xy_mm, beams, bore).T)


def spindle_axis_channel_major(spindle_xy_mm: np.ndarray) -> tuple:
    """Return the spindle axis S (2,), (n, 2) or (n, c, 2) as channel-major x and y [mm].

    Scalars, (1, n) or (c, n): the layout the channel-major ray kernels compute in
    (:func:`tri_spindle_readings_channel_major`, :mod:`borescan.physics.tri_first_order`).
    """
    S = np.asarray(spindle_xy_mm, dtype=float)
    if S.ndim == 1:
        return S[0], S[1]
    if S.ndim == 2:
        S = S[:, None, :]
    return np.ascontiguousarray(S[..., 0].T), np.ascontiguousarray(S[..., 1].T)


def tri_spindle_readings_channel_major(
    phi_rad: np.ndarray, spindle_xy_mm: np.ndarray, beams: Beams, bore: Bore
) -> np.ndarray:
    """:func:`tri_spindle_readings` as computed, channel-major: (c, n) (its transpose).

    For callers that go on computing per channel (the calibration's Jacobian), without
    transposing the readings there and back.
    """
    phi = np.asarray(phi_rad, dtype=float)
    if phi.ndim == 1:
        phi = phi[:, None]
    # computed channel-major, (c, n): numpy's loops then run along the samples; sample-major (n, c)
    # arrays with (c,) beam constants run an inner loop of c = 3 per sample, ~2x slower. The same
    # operations on the same numbers (cos and sin on phi in its own layout): the readings are bit-identical.
    beta, rho = (
        np.asarray(beams.beta_rad, dtype=float)[:, None],
        np.asarray(beams.rho_mm, dtype=float)[:, None],
    )
    cb, sb = np.cos(beta), np.sin(beta)
    fx, fy = -rho * sb, rho * cb
    cp, sp = np.ascontiguousarray(np.cos(phi).T), np.ascontiguousarray(np.sin(phi).T)
    sx, sy = spindle_axis_channel_major(spindle_xy_mm)
    sx, sy = sx - bore.center_xy_mm[0], sy - bore.center_xy_mm[1]
    ox = sx + cp * fx - sp * fy
    oy = sy + sp * fx + cp * fy
    dx = cp * cb - sp * sb
    dy = sp * cb + cp * sb
    s = _wall_distance(ox, oy, dx, dy, bore)
    return s - np.asarray(beams.d_b_mm, dtype=float)[:, None]


def tri_static_readings(
    device_xy_mm: np.ndarray, device_angle_rad: np.ndarray, beams: Beams, bore: Bore
) -> np.ndarray:
    """Return readings of a static device at position(s) ``device_xy_mm`` (…, 2) and angle(s) (…).

    Returns ndarray (…, c) [mm].
    """
    ang = np.atleast_1d(np.asarray(device_angle_rad, dtype=float))
    xy = np.atleast_2d(np.asarray(device_xy_mm, dtype=float))
    return tri_spindle_readings(ang, xy, beams, bore)


def circumcircle(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Circle through three points (closed form), vectorised.

    Parameters
    ----------
    points : ndarray (..., 3, 2) [mm]

    Returns
    -------
    center : ndarray (..., 2) [mm]; radius : ndarray (...) [mm]
    (Yang 2017 Eqs. 1-3 in coordinate form: R = AB*BC*CA / (4 S).)
    """
    p = np.asarray(points, dtype=float)
    # Shift to the first point for conditioning.
    a = p[..., 0, :]
    b = p[..., 1, :] - a
    c = p[..., 2, :] - a
    d = 2.0 * (b[..., 0] * c[..., 1] - b[..., 1] * c[..., 0])
    b2 = b[..., 0] ** 2 + b[..., 1] ** 2
    c2 = c[..., 0] ** 2 + c[..., 1] ** 2
    ux = (c[..., 1] * b2 - b[..., 1] * c2) / d
    uy = (b[..., 0] * c2 - c[..., 0] * b2) / d
    center = a + np.stack([ux, uy], axis=-1)
    return center, np.hypot(ux, uy)


# --------------------------------------------------------------------------- rod


@dataclass(frozen=True)
class RodLayer:
    """One sensor layer of the measuring rod (rod frame, spec "Measuring rod").

    channel : 1-based layer/channel index; h_mm : height along the rod axis from the rear end B;
    phi_rad : in-plane beam angle; d_mm : perpendicular offset of the beam from the axis
    (``beam_offset``, Wang 2017 Eq. 5); gamma_rad : out-of-plane tilt (Wang 2017 Eq. 6);
    l0_mm : base length from the axis foot to the measuring start point.
    """

    channel: int
    h_mm: float
    l0_mm: float
    phi_rad: float = 0.0
    d_mm: float = 0.0
    gamma_rad: float = 0.0


def layer_dict(lay: RodLayer) -> dict:
    """Return a rod layer in the spec's names.

    Return a rod layer in the spec's names, as ``device.nominal.layers`` of scan.json lists it: channel,
    h [mm], phi [rad], d [mm], gamma [rad], l0 [mm].
    """
    return {
        "channel": int(lay.channel),
        "h": float(lay.h_mm),
        "phi": float(lay.phi_rad),
        "d": float(lay.d_mm),
        "gamma": float(lay.gamma_rad),
        "l0": float(lay.l0_mm),
    }


@dataclass(frozen=True)
class Hole:
    """A hole: cylinder parallel to the part z axis, centre (a, b) [mm], radius [mm]."""

    center_xy_mm: tuple[float, float]
    radius_mm: float


@dataclass(frozen=True)
class RodAxis:
    """Pose of the rod's rotation axis in the part frame.

    dx_mm, dy_mm : eccentricity of the axis at z = 0 [mm];
    omega_rad : deflection angle of the axis from the part z axis [rad];
    omega_az_rad : azimuth towards which it deflects [rad].
    """

    dx_mm: float = 0.0
    dy_mm: float = 0.0
    omega_rad: float = 0.0
    omega_az_rad: float = 0.0


def rod_axis_rotation(axis: RodAxis) -> np.ndarray:
    """Rotation matrix rod frame -> part frame: tilts z by omega towards azimuth omega_az."""
    k = np.array([-np.sin(axis.omega_az_rad), np.cos(axis.omega_az_rad), 0.0])
    w = axis.omega_rad
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(w) * K + (1.0 - np.cos(w)) * (K @ K)


def rod_axis_rotation_xy(omega_rad, omega_az_rad) -> np.ndarray:
    """Return the x and y rows of :func:`rod_axis_rotation`, for arrays of poses (..., 2, 3).

    With k = (-sin az, cos az, 0): R = I + sin(omega) K + (1 - cos(omega)) K K (Rodrigues), written
    out; equal to :func:`rod_axis_rotation`'s rows to rounding.
    """
    om, az = np.asarray(omega_rad, dtype=float), np.asarray(omega_az_rad, dtype=float)
    kx, ky = -np.sin(az), np.cos(az)
    s, c1 = np.sin(om), 1.0 - np.cos(om)
    return np.stack(
        [
            np.stack([1.0 - c1 * ky * ky, c1 * kx * ky, s * ky], axis=-1),
            np.stack([c1 * kx * ky, 1.0 - c1 * kx * kx, -s * kx], axis=-1),
        ],
        axis=-2,
    )


def rod_ray_readings(
    alpha_rad, layer_arrays, center_xy_mm, radius_mm, rotation_xy, shift_xy_mm
) -> np.ndarray:
    """Return the readings of :func:`rod_readings` from arrays: one geometry or a stack (..., n, m).

    alpha_rad (..., n); layer_arrays: phi [rad], d [mm], h [mm], gamma [rad], l0 [mm], each (m,);
    center_xy_mm (..., m, 2), radius_mm (..., m): the holes; rotation_xy (..., 2, 3): the x and y
    rows of the rod axis's rotation (:func:`rod_axis_rotation_xy`); shift_xy_mm (..., 2): the axis's
    eccentricity (dx, dy). A fit's Jacobian evaluates all its perturbed geometries in one call.
    """
    phi, d, h, gamma, l0 = layer_arrays
    alpha = np.asarray(alpha_rad, dtype=float)
    R = np.asarray(rotation_xy, dtype=float)[..., None, None, :, :]  # (..., 1, 1, 2, 3)
    center = np.asarray(center_xy_mm, dtype=float)[..., None, :, :]  # (..., 1, m, 2)
    radius = np.asarray(radius_mm, dtype=float)[..., None, :]
    shift = np.asarray(shift_xy_mm, dtype=float)[..., None, None, :]
    # a pose's beams in the rod frame, u = (cos a, sin a, 0), n = (-sin a, cos a, 0), then their x and
    # y in the part frame (the z row of the rotation is not needed)
    a = alpha[..., :, None] + phi
    ca, sa = np.cos(a), np.sin(a)
    ox, oy = -d * sa, d * ca  # o = d n + h z
    cg, sg = np.cos(gamma), np.sin(gamma)
    ex, ey = cg * ca, cg * sa  # e = cos(gamma) u + sin(gamma) z
    wx = R[..., 0, 0] * ox + R[..., 0, 1] * oy + R[..., 0, 2] * h + shift[..., 0] - center[..., 0]
    wy = R[..., 1, 0] * ox + R[..., 1, 1] * oy + R[..., 1, 2] * h + shift[..., 1] - center[..., 1]
    Ex = R[..., 0, 0] * ex + R[..., 0, 1] * ey + R[..., 0, 2] * sg
    Ey = R[..., 1, 0] * ex + R[..., 1, 1] * ey + R[..., 1, 2] * sg
    qa = Ex * Ex + Ey * Ey
    qb = wx * Ex + wy * Ey
    qc = wx * wx + wy * wy - radius**2
    return _positive_root(qa, qb, qc) - l0


def rod_layer_arrays(layers) -> tuple[np.ndarray, ...]:
    """Return the layers' (phi [rad], d [mm], h [mm], gamma [rad], l0 [mm]) as arrays (m,) each."""
    return tuple(
        np.array([getattr(lay, k) for lay in layers], dtype=float)
        for k in ("phi_rad", "d_mm", "h_mm", "gamma_rad", "l0_mm")
    )


def rod_readings(
    alpha_rad: np.ndarray, layers: list[RodLayer], holes: list[Hole], axis: RodAxis = RodAxis()
) -> np.ndarray:
    """Return readings of the measuring rod at rotations ``alpha_rad`` (exact ray-cylinder).

    The beam of layer m starts at o = d n(a) + h z and travels along
    e = cos(gamma) u(a) + sin(gamma) z, a = alpha + phi (rod frame); it is moved into the
    part frame by the rod axis pose and intersected with the hole cylinder
    (x - a_m)^2 + (y - b_m)^2 = r_m^2. The reading is v = l - l0. With gamma = d = omega = 0
    this is Wang 2017 Eq. 16: (x_m + l cos a)^2 + (y_m + l sin a)^2 = r_m^2 with
    (x_m, y_m) = (dx - a_m, dy - b_m). Computed by :func:`rod_ray_readings`.

    Parameters
    ----------
    alpha_rad : ndarray (n,) rod rotation per pose [rad]
    layers : list of RodLayer (m); holes : list of Hole, one per layer (m)

    Returns
    -------
    ndarray (n, m) readings [mm]
    """
    alpha = np.atleast_1d(np.asarray(alpha_rad, dtype=float))
    center = np.array([hole.center_xy_mm for hole in holes], dtype=float).reshape(-1, 2)
    radius = np.array([hole.radius_mm for hole in holes], dtype=float)
    return rod_ray_readings(
        alpha,
        rod_layer_arrays(layers),
        center,
        radius,
        rod_axis_rotation_xy(axis.omega_rad, axis.omega_az_rad),
        (axis.dx_mm, axis.dy_mm),
    )
