"""Registry of the named effects of ``shared/spec/geometry-and-effects.md``.

One :class:`EffectSpec` per name of the spec's "Named effects" table, with exactly the
spec's parameter names (``channel`` is the spec's ``c``). Each spec carries the stage of
the forward model where it acts and one pure forward function per device type.

Stages, in the order the digital twin (:mod:`borescan.synthetic.simulate`) composes them:

``time_base``
    ``f(t_s, p) -> t_s`` on one channel's times (``channel_delay``).
``kinematics``
    ``f(x_rad, p) -> x_rad`` on the turned angle x = omega t that the nominal model assumes
    (``speed_error`` first, then ``speed_ripple``); the device angle is phi = phase + x
    (ccw) or phase - x (cw).
``spindle_position``
    ``f(S_xy_mm (..., 2), phi_rad (...), p) -> S_xy_mm`` (``spindle_error_motion``).
``bore``
    ``f(bore: Bore, p, cte_per_k) -> Bore`` (``thermal_expansion``, ``axis_tilt``,
    ``bore_lobing``).
``beam``
    tri_lds: ``f(v_mm, p) -> v_mm`` on one channel (``beam_tilt``);
    rod: ``f(layer: RodLayer, p) -> RodLayer`` (``beam_tilt``, ``beam_offset``).
``reading``
    ``f(v_mm, t_s, p, range_mm) -> v_mm`` on one channel (or every channel when the
    effect has no ``channel``): offset, gain, nonlinearity, drift, vibration.
``output``
    ``f(v_mm, p, rng) -> v_mm``, after the noise: quantization, outliers.

Within a stage, effects act in the order of the spec's table (the order of :data:`EFFECTS`)
and effects of the same name in the order given. Effects compose freely, including several
of the same name on different channels. :mod:`borescan.physics.tri` composes them into the one
forward model of a spindle scan that the digital twin and the discrepancy workflow share.

The registry is also the vocabulary of the fits (lmfit style: an effect adds prefixed
parameters, e.g. ``sensor_gain@2.g``). Each spec carries

- ``fit``: the parameters a fit varies (:class:`FitParam`: name, unit, typical scale, bounds),
  with ``to_internal`` / ``from_internal`` beside the effect where they differ from the
  spec's parameters for conditioning (an amplitude and phase as A = a cos(phase),
  B = a sin(phase); ``beam_tilt`` as h = 1 / cos(gamma) - 1; ``axis_tilt`` as
  p + i q = beta^2 exp(2 i azimuth); ``thermal_expansion`` as dT = T - 20), and ``device_fit``
  where one device fits an effect otherwise (:class:`DeviceFit`: a rod's ``beam_tilt`` is the
  signed gamma added to its layer's own, not the three-sensor reading's even h; a term takes the
  parameterisation of its scan kind's device, :data:`SCAN_KIND_DEVICE`);
- ``absorbed_by``: per scan kind (:data:`SCAN_KINDS`), the base parameters that absorb the
  effect, with the text a finding reports (``"R"``: the bore radius, which absorbs only the
  form common to every channel);
- ``candidate``: per scan kind, how the discrepancy workflow looks for it: ``"screen"`` (a
  term of the linear screen), ``"start"`` (not linear at zero: only from a start another
  term's screen gives), ``"evidence"`` (named by its own test, not fitted);
  ``needs``: what a scan must have for the term to be tried (``"commanded_angle"``: no
  encoder, ``"vibration_line"``: a residual line off the rotation harmonics, ``"cte"``: the
  artifact's expansion coefficient); ``common``: a per-channel effect also tried as one
  value on every channel;
- ``scope``: what the effect belongs to when several scans are examined together
  (:mod:`borescan.discrepancy.pooled`): ``"device"`` (the sensors, the electronics: one value in
  every scan of the device), ``"night"`` (the environment of one night), ``"artifact"`` (one
  artifact: its form, its tilt) or ``"scan"`` (one run of the spindle);
- ``absorbed_unless``: per scan kind, base parameter -> the condition of a set of scans under
  which that parameter no longer absorbs the effect (``"speeds_differ"``: a delay is a change
  of beta only at one signed speed; ``"radii_differ"``: a thermal change of the radius is a
  common offset only for one gauge radius); the conditions are evaluated by the pooled examination;
- ``orientation``: for an effect fixed in the machine frame (a gauge's form, its tilt), the spec
  parameter that turns with it (``phase``, ``azimuth``): scans whose angle origins differ see it
  turned by the difference.

Adding a reading effect is one :class:`EffectSpec` in :mod:`borescan.effects.registry` (plus its row in the
spec). The package: :mod:`~borescan.effects.spec` (the types), :mod:`~borescan.effects.functions` (the
forward functions, the thermal factor, the fit parameterisations), :mod:`~borescan.effects.registry`
(:data:`EFFECTS`, :class:`Effect`), :mod:`~borescan.effects.compose` (effects applied to readings),
:mod:`~borescan.effects.device_keys` (a device's model in the config); every public name is importable
from ``borescan.effects``.
"""

from __future__ import annotations

from borescan.effects.compose import apply_effects, sort_effects
from borescan.effects.device_keys import DEVICE_MODEL_SCAN_KIND, device_effect_key, device_model_effects
from borescan.effects.functions import REFERENCE_TEMPERATURE_C, nonlinearity_bow, thermal_expansion_factor
from borescan.effects.registry import (
    EFFECTS,
    Effect,
    as_effects,
    calibration_absorbers,
    effects_from_dicts,
    effects_to_dicts,
    get_effect,
    parse_effect,
)
from borescan.effects.spec import (
    SCAN_KIND_DEVICE,
    SCAN_KINDS,
    SCOPES,
    STAGES,
    DeviceFit,
    EffectSpec,
    FitParam,
)

__all__ = [
    "DEVICE_MODEL_SCAN_KIND",
    "STAGES",
    "SCAN_KINDS",
    "SCAN_KIND_DEVICE",
    "SCOPES",
    "FitParam",
    "DeviceFit",
    "EffectSpec",
    "Effect",
    "EFFECTS",
    "get_effect",
    "calibration_absorbers",
    "parse_effect",
    "effects_from_dicts",
    "as_effects",
    "effects_to_dicts",
    "sort_effects",
    "device_effect_key",
    "device_model_effects",
    "apply_effects",
    "nonlinearity_bow",
    "REFERENCE_TEMPERATURE_C",
    "thermal_expansion_factor",
]
