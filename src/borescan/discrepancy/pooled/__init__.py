"""Pooled examination of the spindle scans of one device (one night, or a window of nights).

One scan cannot tell some effects from the calibration parameters that absorb them (a
``channel_delay`` is a change of beta at one constant speed; a ``sensor_nonlinearity`` is an
offset on a centred bore); several scans of the same device, made at other speeds, other
eccentricities or in other gauges, can. This module examines K scans together with the
single-scan workflow's own search (:func:`borescan.discrepancy.examine.examine_model`: base fit,
outliers, quantisation, linear screen, exact refits, pairs, BIC with the same threshold), on a
model composed of K single-scan models (:class:`~borescan.discrepancy.tri.TriModel`, so the one
forward model :func:`borescan.physics.tri.tri_forward` of the twin), lmfit style:

- device parameters, shared by every scan and unprefixed: the beam geometry as offsets from a
  start (a calibration) in the calibration's straightened form (the quantities the data fix best,
  :func:`borescan.calibrate.full_fit.fit_full_calibration`): ``dpsi[j]`` of psi = beta + asin(rho / R)
  (every channel but the first: a common turn is each scan's centre), ``drho[j]``, ``dg[j]`` of
  g = d_b + rho^2 / (2 R) (j the channel's index, R the mean gauge radius); a weakly determined
  rho then moves along the valley instead of across it;
- per-scan nuisance parameters, prefixed by the scan id: the bore centre ``<scan>:cx``,
  ``<scan>:cy``; the start phase ``<scan>:phase`` when the spindle moves; the radius
  ``<scan>:dR`` when the artifact is not certified; the speed scale ``<scan>:eps`` when the angle
  is commanded, not measured (as the calibration fits it; the registry's ``speed_error`` is then
  that parameter);
- effect terms (:class:`PooledTerm`), one parameter set per group of scans that the registry's
  ``scope`` of the effect says shares it: ``device`` every scan, ``night`` the scans of one
  night, ``artifact`` the scans of one artifact on one night, ``scan`` one scan. A term shared by
  every scan has the registry key (``channel_delay@2``); one for a group carries the group after a
  ``#`` (``bore_lobing[k=3]#RG-275``). An effect fixed in the artifact (the registry's
  ``orientation``: a gauge's lobing, its tilt) is seen turned on another night (the gauge mounted
  again) and in a scan whose angle has its own origin (a commanded angle on a fixed spindle, where
  the phase is the direction of the centre offset): its term fits one turn per such frame
  (``<key>.turn@<night or scan>``) and shares the rest.

Absorption is decided on the pooled design from the registry: a base parameter of
``absorbed_by["tri_spindle"]`` absorbs a term when it is free for every scan the term covers (a
device parameter absorbs only terms that cover every scan), unless the condition the registry
names in ``absorbed_unless`` holds for those scans (:data:`CONDITIONS`: ``speeds_differ``,
``radii_differ``). Absorbed effects are not candidates; the verdict lists them with the
measurement that would separate them, taken from the condition (none for an offset, which is a
d_b whatever the scans).

Residuals are weighted per scan and channel by the scan's own noise floor, so that the BIC of the
pooled fit is the likelihood of K scans of different noise. Which scans carry the evidence: the
decrease of each scan's chi-square (residual over its noise floor, squared, summed) from the base
fit to the verdict's fit; the carriers are the fewest scans, largest decrease first, that hold 90 %
of the total decrease.

Calibration drift (:func:`borescan.calibrations.calibration_drift`): :func:`drift_explanations`
says which named effect a flagged change of a beam parameter is explained by (the registry's
absorbing parameter on that channel), with the change a calibration ignoring the effect would
make (:func:`calibration_equivalent`).

Entry points: :func:`examine_pooled` (findings of the device, ``findings.json``-like),
:func:`pooled_scan` (one ``RawScan``-like object to :class:`PooledScan`), :func:`drift_explanations`.
"""

from borescan.discrepancy.pooled.drift import calibration_equivalent, drift_explanations
from borescan.discrepancy.pooled.model import PooledData, PooledModel
from borescan.discrepancy.pooled.terms import (
    CONDITIONS,
    PooledScan,
    PooledTerm,
    parse_device_effect,
    pooled_scan,
)
from borescan.discrepancy.pooled.verdict import CARRIER_SHARE, PooledExamination, examine_pooled, separation

__all__ = [
    "PooledScan",
    "PooledTerm",
    "PooledData",
    "PooledModel",
    "PooledExamination",
    "CONDITIONS",
    "pooled_scan",
    "examine_pooled",
    "calibration_equivalent",
    "drift_explanations",
    "separation",
    "CARRIER_SHARE",
    "parse_device_effect",
]
