"""Mirrored starts of a three-sensor base fit whose beam offsets rho are free.

A beam's reading depends on its offset rho through sqrt(R^2 - rho^2) (even in rho) and, to first order in
the eccentricity, through a turn of its harmonic by asin(rho / R), which a free beam direction absorbs. So
rho and -rho (with the direction turned by 2 asin(rho / R)) fit a scan alike to first order, and a fit
from the design can stop in the mirror: on an effect-free calibration of the battery, rho of channel 2 at
+5.7 mm instead of -6.1 mm left a 0.5 um pattern (chi2 572 over 17 876 residuals on the noise-free scan)
that a gain or a beam tilt then "explained" (a false alarm). The examination therefore refits the base
from each channel's mirror and keeps the lowest RSS.
"""

from __future__ import annotations

import math
from itertools import product

import numpy as np

from borescan.discrepancy.tri import TriModel

__all__ = ["mirrored_rho_starts"]


def mirrored_rho_starts(model, p: dict[str, float]) -> list[dict[str, float]]:
    """Return one start per channel: its rho mirrored at the same wall direction psi and level g.

    Empty unless the model is one scan's :class:`TriModel` and frees rho (``model.free_beams``; its
    beams move in (psi, rho, g), :meth:`TriModel.beams_at`). Besides the plain mirror, the beam's psi
    turned by -4 asin(rho / R) (for the first beam, whose psi is held, the other beams turned the other
    way) and the phase turned by +-2 asin(rho / R) are tried; the start of lowest RSS is kept: a cheap
    evaluation per choice, the fit comes after.
    """
    if not isinstance(model, TriModel) or "rho" not in model.free_beams:
        return []  # one scan's three-sensor model only (a pooled model's shared beams are its own)
    d = model.data
    radius = float(d.radius_mm + p.get("dR", 0.0))
    c = len(d.channels)
    out = []
    for j in range(c):
        rho = float(d.beams.rho_mm[j] + p.get(f"drho[{j}]", 0.0))
        if 0.0 < abs(rho) < radius:
            best = _mirror(model, p, j, rho, 2.0 * math.asin(rho / radius))
            if best is not None:
                out.append(best)
    return out


def _mirror(model, p: dict[str, float], j: int, rho: float, delta: float) -> dict[str, float] | None:
    """Return channel j's mirrored start of lowest RSS over the turn's signs, or None (none finite)."""
    rho_design = float(model.data.beams.rho_mm[j])
    best, best_rss = None, math.inf
    for turn, s_frame in product((0.0, -2.0 * delta), (1.0, -1.0, 0.0)):
        if s_frame and "phase" not in p:
            continue
        st = dict(p)
        st[f"drho[{j}]"] = -rho - rho_design
        if j > 0:
            st[f"dpsi[{j}]"] = st.get(f"dpsi[{j}]", 0.0) + turn
        else:  # the held first beam: the others turn the other way
            for k in range(1, len(model.data.channels)):
                st[f"dpsi[{k}]"] = st.get(f"dpsi[{k}]", 0.0) - turn
        if s_frame:
            st["phase"] += s_frame * delta
        r = model.residual(st, [])
        rss = float(r @ r) if np.all(np.isfinite(r)) else math.inf
        if rss < best_rss:
            best, best_rss = st, rss
    return best
