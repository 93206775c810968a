"""The shared beams of a pooled fit and the design it summarises.

A mixin of :class:`~borescan.discrepancy.pooled.model.PooledModel`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from borescan.discrepancy.pooled.terms import BASE_SCALE
from borescan.geometry import Beams
from borescan.physics.tri_params import moved_beams


class BeamsAndDesign:
    """The shared beam geometry at pooled parameters, its covariance, the base and design summaries."""

    def plot_angle(self) -> np.ndarray:
        """Return the plotting angle [rad] of every sample, the scans one after the other."""
        return np.concatenate([m.plot_angle() for m in self.models])

    def beams_at(self, p: dict[str, float]) -> Beams:
        """Return the shared beam geometry at pooled parameters ``p`` (module doc: psi, rho, g)."""
        c = len(self.data.channels)
        dpsi, drho, dg = (
            np.array([p.get(f"{n}[{j}]", 0.0) for j in range(c)]) for n in ("dpsi", "drho", "dg")
        )
        return moved_beams(self.start_beams, self.R_mm, dpsi, drho, dg, self.free_beams)

    def _beam_deltas(self, p: dict[str, float]) -> dict[str, float]:
        """Return the single-scan models' beam offsets ``dbeta[j]``, ``drho[j]``, ``dd_b[j]`` at ``p``."""
        b, s = self.beams_at(p), self.start_beams
        out = {}
        for j in range(len(self.data.channels)):
            out[f"dbeta[{j}]"] = float(b.beta_rad[j] - s.beta_rad[j])
            out[f"drho[{j}]"] = float(b.rho_mm[j] - s.rho_mm[j])
            out[f"dd_b[{j}]"] = float(b.d_b_mm[j] - s.d_b_mm[j])
        return out

    def beam_covariance(self, p: dict[str, float], names: Sequence[str], cov: np.ndarray) -> np.ndarray:
        """Return the covariance of (beta, rho, d_b) per channel.

        Covariance (3c, 3c) of (beta, rho, d_b) per channel (the calibration's order) from the
        covariance ``cov`` of the fitted parameters ``names`` (linear propagation).
        """
        idx = [i for i, n in enumerate(names) if n in set(self._shared_names())]
        c = len(self.data.channels)

        def vec(q: dict) -> np.ndarray:
            b = self.beams_at(q)
            return np.column_stack([b.beta_rad, b.rho_mm, b.d_b_mm]).ravel()

        v0 = vec(p)
        A = np.zeros((3 * c, len(idx)))
        for col, i in enumerate(idx):
            h = BASE_SCALE[names[i].split("[")[0]] * 1e-3
            q = dict(p)
            q[names[i]] = q.get(names[i], 0.0) + h
            A[:, col] = (vec(q) - v0) / h
        C = np.asarray(cov)[np.ix_(idx, idx)]
        return A @ C @ A.T

    def base_summary(self, p: dict[str, float]) -> dict:
        """Return the base fit's beams and per-scan nuisance.

        Return the base fit's beams and per-scan nuisance (the examination asks once, at its base fit:
        the values are kept in :attr:`base_values`).
        """
        self.base_values = dict(p)
        b = self.beams_at(p)
        out = {
            "beams": b.to_nominal(),
            "beta_minus_start_rad": [float(x) for x in b.beta_rad - self.start_beams.beta_rad],
            "rho_minus_start_mm": [float(x) for x in b.rho_mm - self.start_beams.rho_mm],
            "d_b_minus_start_mm": [float(x) for x in b.d_b_mm - self.start_beams.d_b_mm],
            "scans": {},
        }
        for k, sid in enumerate(self.scan_ids):
            d = self.scans[k].data
            e = {
                "center_xy_mm": [p[f"{sid}:cx"], p[f"{sid}:cy"]],
                "radius_mm": d.radius_mm + p.get(f"{sid}:dR", 0.0),
            }
            if self.commanded[k]:
                e["speed_scale"] = 1.0 + p[f"{sid}:eps"]
            out["scans"][sid] = e
        return out

    def design(self, p: dict[str, float] | None = None) -> dict:
        """Return what distinguishes the scans.

        Return what distinguishes the scans: night, artifact, radius, signed speed, angle source and,
        with parameters ``p``, the eccentricity |S - C| of the fit.
        """
        out = {}
        for k, s in enumerate(self.scans):
            d = s.data
            w = self.signed_speeds(k)
            e = {
                "night": s.night,
                "artifact": s.artifact,
                "radius_mm": d.radius_mm,
                "speed_rad_s": [float(np.min(w)), float(np.max(w))],
                "angle": "encoder" if d.encoder else "commanded",
                "samples": int(d.t_s.size),
            }
            if p is not None:
                S = np.asarray(d.spindle_xy_mm, dtype=float)
                S0 = S.mean(axis=0) if S.ndim == 2 else S
                e["eccentricity_mm"] = float(
                    np.hypot(S0[0] - p[f"{s.scan_id}:cx"], S0[1] - p[f"{s.scan_id}:cy"])
                )
            out[s.scan_id] = e
        return out
