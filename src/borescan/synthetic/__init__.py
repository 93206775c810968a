"""Synthetic data: the digital twin and the test-data generators, outside the core library.

- :mod:`~borescan.synthetic.scenes`: the true geometry of a simulated scan and its noise-free readings
  (the device models of :mod:`borescan.physics` on it);
- :mod:`~borescan.synthetic.simulate`: scans in ``borescan-raw/1`` with noise and ground truth;
- :mod:`~borescan.synthetic.contract`, :mod:`~borescan.synthetic.tri_scenarios`,
  :mod:`~borescan.synthetic.rod_scenarios`, :mod:`~borescan.synthetic.battery`: scans drawn over the
  whole contract, batteries of them (``borescan simulate contract``);
- :mod:`~borescan.synthetic.demo`: the embedded demo nights (``borescan simulate demo``);
- :mod:`~borescan.synthetic.history`: a year of nights copied cheaply from a small one (history bench).

The core library (calibration, measurement, stages, discrepancy examination, raw I/O) never imports
this package (``tests/test_layout.py``); ``borescan simulate``, ``borescan plan``'s device presets, the
papers' reproductions, the discrepancy battery, the benches and the tests do.
"""
