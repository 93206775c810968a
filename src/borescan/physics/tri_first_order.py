"""Three-sensor spindle readings to first order in a small change of the spindle position and the bore.

The discrepancy workflow asks, at a fit, how a small step of a bore or spindle-position parameter would
move the readings: the linear screen's candidate columns (:func:`borescan.discrepancy.search.linear_screen`)
and the exact fits' forward differences in the bore's centre and radius, ``bore_lobing``, ``axis_tilt``,
``thermal_expansion`` and ``spindle_error_motion`` (:mod:`borescan.discrepancy.tri_screen`). The exact
answer solves the ray-to-wall intersection again (Newton iterations for a lobed bore,
:func:`borescan.geometry.tri_spindle_readings`). To first order it is the implicit derivative of the
wall condition at the wall points the exact solve has found (step 5 of :mod:`borescan.physics.tri`):

    g(P) = |P - C| - r(theta(P)) = 0,   P = S + Rot(phi)(F + s u),   v = s - d_b
    dv = ds = -(g'(P) - g(P) + grad g . (dS - dC)) / (grad g . d),   d = Rot(phi) u

with g' the wall function of the changed bore's shape about the old centre at the same points
(:func:`borescan.geometry.bore_wall_function`), dS the change of the spindle axis and dC that of the
bore's centre (a move of the whole bore is a move of the spindle the other way). The device angle and
the beams are those of the point: a kinematic, time-base or beam change is not taken here. The error
is of second order in the change, about |change|^2 / R (a micrometre's lobing on a 20 mm bore: 1e-8 mm;
``tests/test_tri_first_order.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from borescan.geometry import (
    Beams,
    Bore,
    beam_frame,
    bore_wall_function,
    bore_wall_radius,
    spindle_axis_channel_major,
)

__all__ = ["TriWallPoints", "tri_wall_points", "tri_readings_first_order"]


@dataclass(frozen=True)
class TriWallPoints:
    """Where the beams of a spindle scan meet the wall, and how their readings move with it.

    Attributes
    ----------
    readings_mm : (n, c) the exact readings v the points come from [mm].
    x_mm, y_mm : (c, n) wall points P in machine coordinates [mm].
    g_mm : (c, n) the base bore's wall function at P (zero to the solver's tolerance) [mm].
    kx, ky : (c, n) grad g / (grad g . d): a change dS of the spindle axis moves a reading by
        -(kx dSx + ky dSy) [-].
    inv_den : (c, n) 1 / (grad g . d) [-].
    spindle_x_mm, spindle_y_mm : the spindle axis S the points were computed with, channel-major
        (scalars, (1, n) or (c, n)) [mm].
    bore : the bore the points are on; center_xy_mm : its centre C; r_mm, theta_rad : (c, n) |P - C| and
        the polar angle of P about C.
    """

    readings_mm: np.ndarray
    x_mm: np.ndarray
    y_mm: np.ndarray
    g_mm: np.ndarray
    kx: np.ndarray
    ky: np.ndarray
    inv_den: np.ndarray
    spindle_x_mm: np.ndarray | float
    spindle_y_mm: np.ndarray | float
    bore: Bore
    center_xy_mm: tuple[float, float]
    r_mm: np.ndarray
    theta_rad: np.ndarray


def tri_wall_points(
    phi_rad: np.ndarray, spindle_xy_mm: np.ndarray, beams: Beams, bore: Bore, readings_mm: np.ndarray
) -> TriWallPoints:
    """Return the wall points of exact readings ``readings_mm`` (n, c) and their first-order sensitivities.

    ``phi_rad`` (n,), (n, 1) or (n, c), ``spindle_xy_mm`` (2,), (n, 2) or (n, c, 2) and ``bore`` are
    those the readings were computed with (:func:`borescan.physics.tri.tri_readings_at`).
    """
    phi = np.asarray(phi_rad, dtype=float)
    phi = phi[:, None] if phi.ndim == 1 else phi
    cph, sph = np.ascontiguousarray(np.cos(phi).T), np.ascontiguousarray(np.sin(phi).T)  # (1 or c, n)
    F, u = beam_frame(beams.beta_rad, beams.rho_mm)  # (c, 2)
    s = np.asarray(readings_mm, dtype=float).T + np.asarray(beams.d_b_mm, dtype=float)[:, None]
    dev_x, dev_y = F[:, 0:1] + s * u[:, 0:1], F[:, 1:2] + s * u[:, 1:2]
    sx, sy = spindle_axis_channel_major(spindle_xy_mm)
    x = sx + cph * dev_x - sph * dev_y
    y = sy + sph * dev_x + cph * dev_y
    dx, dy = cph * u[:, 0:1] - sph * u[:, 1:2], sph * u[:, 0:1] + cph * u[:, 1:2]
    g, gx, gy, r, theta = bore_wall_function(x, y, bore)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_den = 1.0 / (gx * dx + gy * dy)
    return TriWallPoints(
        np.asarray(readings_mm, dtype=float),
        x,
        y,
        g,
        gx * inv_den,
        gy * inv_den,
        inv_den,
        sx,
        sy,
        bore,
        tuple(bore.center_xy_mm),
        r,
        theta,
    )


def tri_readings_first_order(
    wall: TriWallPoints, spindle_xy_mm: np.ndarray | None = None, bore: Bore | None = None
) -> np.ndarray:
    """Return the readings (n, c) [mm] with the spindle axis at ``spindle_xy_mm`` and the wall of ``bore``.

    To first order about ``wall`` (module doc); None for either leaves it as the wall points had it.
    """
    ds = np.zeros_like(wall.x_mm)
    # a move of the bore's centre by dC is, to first order, a move of the spindle axis by -dC
    dx, dy = 0.0, 0.0
    if spindle_xy_mm is not None:
        sx, sy = spindle_axis_channel_major(spindle_xy_mm)
        dx, dy = sx - wall.spindle_x_mm, sy - wall.spindle_y_mm
    if bore is not None:
        dx, dy = (
            dx - (bore.center_xy_mm[0] - wall.center_xy_mm[0]),
            dy - (bore.center_xy_mm[1] - wall.center_xy_mm[1]),
        )
        shape = replace(bore, center_xy_mm=wall.center_xy_mm)  # the new shape about the points' centre
        if shape != wall.bore:
            ds -= (wall.r_mm - bore_wall_radius(wall.theta_rad, shape)[0] - wall.g_mm) * wall.inv_den
    if not (np.isscalar(dx) and dx == 0.0 and np.isscalar(dy) and dy == 0.0):
        ds -= wall.kx * dx + wall.ky * dy
    return wall.readings_mm + ds.T
