"""The linear screen's columns of a three-sensor spindle scan's bore and spindle-position candidates.

The screen (:func:`borescan.discrepancy.search.linear_screen`) takes every candidate's columns at the base
fit by a step of each of its parameters. For ``bore_lobing``, ``axis_tilt``, ``thermal_expansion`` and
``spindle_error_motion`` a step changes only the bore or the spindle axis, and the exact readings of the
step solve the ray-to-wall intersection again (Newton iterations for a lobed bore): on the contract night
the k = 2..12 lobing and the error motion were 2 of the screen's 3 s per scan kind. Here the step's
readings come to first order from the wall points of the point screened about
(:mod:`borescan.physics.tri_first_order`); the reading stage (gain, offset, ...) and the residual's
weights and dead zone are applied exactly, as :meth:`~borescan.discrepancy.tri.TriModel.residual` does.
A step's readings then differ from the exact ones by about |change|^2 / R: 5e-8 mm for a micrometre's
lobing on a 20 mm bore, against the micrometre of the column itself.
"""

from __future__ import annotations

import numpy as np

from borescan.physics.tri import GEOMETRY_STAGES, bore_with_effects, spindle_positions, tri_reading_stage
from borescan.physics.tri import tri_readings_at, tri_scene
from borescan.physics.tri_first_order import tri_readings_first_order, tri_wall_points

__all__ = ["FIRST_ORDER_STAGES", "FirstOrderResidual"]

#: The stages whose changes are taken to first order; a step that changes any other stage is exact.
FIRST_ORDER_STAGES: tuple[str, ...] = ("spindle_position", "bore")


class FirstOrderResidual:
    """A tri model's residual with the ray geometry to first order about a point (its wall points kept)."""

    def __init__(self, model):
        self.model = model
        self._key: tuple | None = None
        self._state: tuple | None = None

    def __call__(self, about: tuple[dict, list], q: dict[str, float], terms: list) -> np.ndarray | None:
        """Return ``model.residual(q, terms)`` to first order about ``about = (p0, terms0)``, or None.

        None where ``q`` and ``terms`` differ from ``about`` in more than the bore and spindle-position
        effects (a base parameter, or an effect of another stage): that step is the exact residual's.
        """
        p0, terms0 = about
        if any(k not in p0 or p0[k] != v for k, v in q.items() if "." not in k):
            return None
        m = self.model
        st0, st1 = m.stages(p0, terms0), m.stages(q, terms)
        if any(st1[s] != st0[s] for s in st1 if s not in FIRST_ORDER_STAGES):
            return None
        key = (
            tuple(e for s in GEOMETRY_STAGES for e in st0[s]),
            tuple(sorted((k, v) for k, v in p0.items() if "." not in k)),
        )
        if key != self._key:  # the wall points of the point screened about, once per screen
            base = m.base(p0)
            tc, phi, S, bore = tri_scene(base, m.data.t_s, st0)
            wall = tri_wall_points(phi, S, base.beams, bore, tri_readings_at(phi, S, base.beams, bore))
            self._key, self._state = key, (base, tc, phi, wall)
        base, tc, phi, wall = self._state
        S1 = bore1 = None
        if st1["spindle_position"] != st0["spindle_position"]:
            S1 = spindle_positions(base, phi, st1["spindle_position"])
        if st1["bore"] != st0["bore"]:
            bore1 = bore_with_effects(base.bore, st1["bore"], base.cte_per_k)
        v = tri_readings_first_order(wall, S1, bore1)
        d = m.data
        return m.weighted(tri_reading_stage(v, tc, st1, d.channels, d.range_mm))
