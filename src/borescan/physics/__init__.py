"""The device models, one forward model per device that the digital twin and every fit call.

Each is the base geometry (:mod:`borescan.geometry`) composed with the registered effects
(:data:`borescan.effects.EFFECTS`).

- :mod:`borescan.physics.tri`: the three-sensor device (``tri_lds``), a spindle scan
  (:func:`~borescan.physics.tri.tri_forward`) and a static set, one position and angle per pose
  (:class:`~borescan.physics.tri.TriDevice`);
- :mod:`borescan.physics.rod`: the measuring rod (:class:`~borescan.physics.rod.RodDevice`).
"""
