"""The three-sensor calibration: Yang 2017 and the full-data fit on the device model, and its budget.

- :mod:`~borescan.calibrate.result`: :class:`~borescan.calibrate.result.TriCalibration` (what both
  methods give), ``CalibrationError``, the calibration id, the acceptance rule;
- :mod:`~borescan.calibrate.yang`: Yang 2017 (Eqs. 8-15) from the extreme readings;
- :mod:`~borescan.calibrate.full_fit`: the full-data fit, a problem
  (:mod:`~borescan.calibrate.problem`: data and parameter layout) solved by small functions:
  :mod:`~borescan.calibrate.starts`, :mod:`~borescan.calibrate.residuals` (the device model's
  readings and analytic Jacobian, :mod:`borescan.physics.tri`), :mod:`~borescan.calibrate.censoring`,
  :mod:`~borescan.calibrate.mirror_search`, :mod:`~borescan.calibrate.profiles`,
  :mod:`~borescan.calibrate.summary`;
- :mod:`~borescan.calibrate.sensitivities` and :mod:`~borescan.calibrate.budget`: the GUM budget.
"""
