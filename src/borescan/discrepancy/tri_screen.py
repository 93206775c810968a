"""Steps in a three-sensor spindle scan's bore and spindle axis, to first order about the point stepped from.

Two places take small steps of the tri examination model's parameters from a point: the linear screen
(:func:`borescan.discrepancy.search.linear_screen`: every candidate's columns at the base fit) and the
exact fits' forward differences (:func:`borescan.discrepancy.search._residual_stack`). A step of the
bore's centre or radius (the model's ``bore_parameters``), of ``bore_lobing``, ``axis_tilt``,
``thermal_expansion`` or of ``spindle_error_motion`` changes only the bore or the spindle axis, and its
exact readings solve the ray-to-wall intersection again (Newton iterations for a lobed bore: on the kept
contract night the screen's lobing and error-motion columns took 2.3 of its 2.9 CPU s for the 23
calibration scans). Here the step's readings come to first order from the wall points of the point
stepped from (:mod:`borescan.physics.tri_first_order`); the reading stage (gain, offset, ...) and the
residual's weights and dead zone are applied exactly, as :meth:`~borescan.discrepancy.tri.TriModel.residual`
does. A step's readings differ from the exact ones by about |step|^2 / R (1e-8 mm for a micrometre's
lobing on a 20 mm bore): a forward difference's own error is of that order and sign.
"""

from __future__ import annotations

import numpy as np

from borescan.physics.tri import bore_with_effects, spindle_positions, tri_reading_stage, tri_scene
from borescan.physics.tri_first_order import tri_readings_first_order, tri_wall_points

__all__ = ["FIRST_ORDER_STAGES", "FirstOrderResidual"]

#: The stages whose changes are taken to first order; a step that changes any other stage is exact.
FIRST_ORDER_STAGES: tuple[str, ...] = ("spindle_position", "bore")


class FirstOrderResidual:
    """A tri model's residual with the ray geometry to first order about a point (its wall points kept).

    The wall points are computed once per point stepped from (once per screen, once per Jacobian).
    """

    def __init__(self, model):
        self.model = model
        self._key: tuple | None = None
        self._state: tuple | None = None

    def __call__(self, about: tuple[dict, list], q: dict[str, float], terms: list) -> np.ndarray | None:
        """Return ``model.residual(q, terms)`` to first order about ``about = (p0, terms0)``, or None.

        None where ``q`` and ``terms`` differ from ``about`` in more than the bore (its centre and radius,
        the model's ``bore_parameters``, and its effects) and the spindle-position effects: that step is the
        exact residual's.
        """
        p0, terms0 = about
        m = self.model
        moved = {k for k, v in q.items() if "." not in k and p0.get(k) != v}
        if not moved <= set(m.bore_parameters) or any(k not in q for k in p0 if "." not in k):
            return None
        st0, st1 = m.stages(p0, terms0), m.stages(q, terms)
        if any(st1[s] != st0[s] for s in st1 if s not in FIRST_ORDER_STAGES):
            return None
        key = m.geometry_key(p0, st0)
        if key != self._key:  # the wall points of the point stepped from, once per screen or Jacobian
            base = m.base(p0)
            tc, phi, S, bore = tri_scene(base, m.data.t_s, st0)
            v, _ = m.geometry(p0, st0)  # the exact readings there, as the residual at p0 computed them
            self._key, self._state = key, (base, tc, phi, tri_wall_points(phi, S, base.beams, bore, v))
        base, tc, phi, wall = self._state
        S1 = bore1 = None
        if st1["spindle_position"] != st0["spindle_position"]:
            S1 = spindle_positions(base, phi, st1["spindle_position"])
        if moved or st1["bore"] != st0["bore"]:
            bore1 = bore_with_effects(m.base(q).bore if moved else base.bore, st1["bore"], base.cte_per_k)
        v = tri_readings_first_order(wall, S1, bore1)
        d = m.data
        return m.weighted(tri_reading_stage(v, tc, st1, d.channels, d.range_mm))
