"""Diameters: static three-sensor readings, rotating scans, and verification against gauges.

Static (Yang 2017, Eqs. 1-7 in coordinate form): each reading v_i puts a wall point at
W_i = rho_i n_i + (d_b,i + v_i) u_i in the device frame (``geometry.wall_points_device``); the
bore is the circumcircle of the three points (least-squares circle with more channels) and
D = 2R. The uncertainty is first-order propagation with the exact Jacobian

    dR = sum_i g_i  nhat_i . dW_i,   g = last row of (A^T A)^-1 A^T,  A_i = [nhat_i^T, 1],

nhat_i the unit vector from the centre to W_i (A is square for three channels: the
circumcircle), with dW/dbeta = -rho u + s n, dW/drho = n, dW/dd_b = dW/dv = u, s = d_b + v.

Rotating (device on a spindle): wall points in machine coordinates p = S + Rot(phi) W; the
least-squares circle gives the diameter, the ISO 12181 reference circles the roundness, and
``circlefit.harmonic_spectrum`` the undulations per revolution.

GUM budget of a diameter (:func:`diameter_uncertainty`): the calibration's own budget (its
fit, gauge, temperature, expansion coefficient, positions, sensor linearity; carried in the
calibration's ``diagnostics["budget"]``) mapped through dD/d(beta, rho, d_b); the readings'
scatter (Type A); each sensor's linearity and resolution at this measurement (independent of
those at the calibration: the data sheet bounds the deviation anywhere in the range, not its
shape); and the temperature correction to 20 degC (ISO 1), D20 = D_T / (1 + alpha (T - 20)),
with the part's temperature and expansion coefficient. Every diameter is given at the measured
temperature and at 20 degC. A verification compares D20 with the gauge's certified D20; where
the gauge is the calibration's own, its certified diameter enters both and its sensitivity is
the difference (:meth:`borescan.uncertainty.Budget.merged`). The verdict follows the configured
decision rule (:func:`decide`, ILAC-G8:09/2019).
"""

from __future__ import annotations

from .sensors import (
    hold_readings,
    linearity_change_mm,
    linearity_terms,
    mean_reading_u_mm,
    pose_means,
    reading_u_mm,
    sensor_ranges_mm,
    sensor_terms,
)
from .static import StaticDiameter, static_diameter, static_diameter_jacobian
from .rotating import RotatingResult, wall_points_machine, measure_rotating, measure_scan, DiameterModel
from .budget import DiameterUncertainty, diameter_uncertainty
from .tri import calibration_budget_of, tri_diameter_with_budget
from .rod import layer_jacobian, minima_input, rod_diameters_with_budget, rod_verifications
from .verify import (
    only_feature_id,
    part_feature,
    part_conformity,
    Verification,
    verify,
    diameter_row,
    verification_row,
    DECISION_RULES,
    decide,
    verify_budget,
    verification_for_certificate,
)

__all__ = [
    "only_feature_id",
    "part_feature",
    "part_conformity",
    "StaticDiameter",
    "RotatingResult",
    "Verification",
    "static_diameter",
    "static_diameter_jacobian",
    "wall_points_machine",
    "measure_rotating",
    "measure_scan",
    "verify",
    "pose_means",
    "reading_u_mm",
    "hold_readings",
    "linearity_change_mm",
    "linearity_terms",
    "mean_reading_u_mm",
    "diameter_row",
    "verification_row",
    "sensor_terms",
    "sensor_ranges_mm",
    "DiameterUncertainty",
    "diameter_uncertainty",
    "DECISION_RULES",
    "decide",
    "verify_budget",
    "DiameterModel",
    "calibration_budget_of",
    "tri_diameter_with_budget",
    "layer_jacobian",
    "minima_input",
    "rod_diameters_with_budget",
    "rod_verifications",
    "verification_for_certificate",
]
