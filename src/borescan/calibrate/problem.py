"""The full-data calibration as a problem: its data, its parameters and how they sit in one vector.

:class:`FullProblem` holds what :func:`borescan.calibrate.full_fit.fit_full_calibration` fits (each
scan's readings, which of them count, the angle each belongs to, the position priors, the noise
floors) and the layout of its internal parameter vector:

- per channel psi = beta + asin(rho / R), rho, g = d_b + rho^2 / (2R)
  (:mod:`borescan.physics.tri_params`); psi of the first channel only when the beams are absolute
  (else beta of the first channel is the gauge, held at the design value);
- per scan the offset o = S - C (x, y), the phase where it is free, the speed scale where the
  angle is commanded (:class:`NuisanceColumns`).

The public parameters are the same with beta for psi and d_b for g (:meth:`FullProblem.public`);
the calibration's own (3c,) vector is (beta, rho, d_b) per channel (:meth:`FullProblem.params_of`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from borescan.calibrate.result import AcceptanceRule
from borescan.geometry import Beams
from borescan.kinematics import AngleModel
from borescan.physics.tri_params import dbeta_drho_at_psi, dd_b_drho_at_g, straighten, unstraighten

__all__ = [
    "NuisanceColumns",
    "nuisance_columns",
    "ScanNuisance",
    "FullProblem",
    "public_index",
    "channel_offsets",
    "per_scan_xy",
    "public_param_names",
]


@dataclass(frozen=True)
class NuisanceColumns:
    """Where one scan's nuisance parameters sit in the parameter vector (None: not free)."""

    ox: int
    oy: int
    phase: int | None = None
    scale: int | None = None

    def items(self) -> list[tuple[str, int]]:
        """Return (name, column) of the free ones, in vector order."""
        pairs = [("ox", self.ox), ("oy", self.oy), ("phase", self.phase), ("scale", self.scale)]
        return [(n, i) for n, i in pairs if i is not None]


def nuisance_columns(
    first: int, free_phase: Sequence[bool], commanded: Sequence[bool]
) -> tuple[tuple[NuisanceColumns, ...], int]:
    """Return each scan's columns from column ``first`` on, and the vector's length."""
    out, col = [], first
    for fp, cm in zip(free_phase, commanded):
        phase = col + 2 if fp else None
        scale = col + 2 + int(fp) if cm else None
        out.append(NuisanceColumns(col, col + 1, phase, scale))
        col += 2 + int(fp) + int(cm)
    return tuple(out), col


@dataclass(frozen=True)
class ScanNuisance:
    """One scan's nuisance values: offset o = S - C [mm], phase [rad], speed scale [-]."""

    offset_mm: np.ndarray
    phase_rad: float
    speed_scale: float


def public_index(c: int, ch0_free: int) -> np.ndarray:
    """Return where the calibration's parameters sit in the full fit's public vector.

    Where the calibration's (3c,) parameters (beta, rho, d_b per channel) sit in the full fit's free
    public vector (betas of the free channels, rhos, d_bs, nuisance); -1 for a gauge-fixed beta.
    """
    idx = np.full(3 * c, -1)
    for j in range(c):
        idx[3 * j] = j - 1 + ch0_free if (j > 0 or ch0_free) else -1
        idx[3 * j + 1] = c - 1 + ch0_free + j
        idx[3 * j + 2] = 2 * c - 1 + ch0_free + j
    return idx


def channel_offsets(tau_s, c: int) -> np.ndarray | None:
    """Per channel time offsets (c,) [s], None when absent or all zero."""
    if tau_s is None:
        return None
    tau = np.broadcast_to(np.asarray(tau_s, dtype=float), (c,)).copy()
    return None if not np.any(tau) else tau


def per_scan_xy(xy, K: int) -> list:
    """``None``, one (x, y) for every scan, or one (x, y) / None per scan -> list of (2,) or None."""
    if xy is None:
        return [None] * K
    if isinstance(xy, (list, tuple)) and len(xy) == K and (K != 2 or not np.isscalar(xy[0])):
        return [None if p is None else np.asarray(p, dtype=float).reshape(2) for p in xy]
    a = np.asarray(xy, dtype=float)
    if a.shape == (2,):
        return [a] * K
    return [np.asarray(p, dtype=float).reshape(2) for p in a]


def public_param_names(
    channels: Sequence[int], scan_ids: Sequence[str], ch0_free: int, cols: Sequence[NuisanceColumns]
) -> list[str]:
    """Return the names of the public free parameters, in vector order."""
    names = [f"beta_rad[{ch}]" for ch in (channels if ch0_free else channels[1:])]
    names += [f"rho_mm[{ch}]" for ch in channels] + [f"d_b_mm[{ch}]" for ch in channels]
    for k, s in enumerate(scan_ids):
        names += [f"offset_x_mm[{s}]", f"offset_y_mm[{s}]"]
        if cols[k].phase is not None:
            names.append(f"phase0_rad[{s}]")
        if cols[k].scale is not None:
            names.append(f"speed_scale[{s}]")
    return names


@dataclass(frozen=True)
class FullProblem:
    """One full-data calibration problem (module doc): the data of K scans and the parameter layout.

    Attributes
    ----------
    scan_ids, channels : the scans and the channels (ascending).
    R_mm : ring gauge radius at the scans' temperature [mm].
    ys, masks : per scan readings (n_k, c) [mm] and the readings the fit uses (valid, not censored).
    angle_models : per scan :class:`~borescan.kinematics.AngleModel`.
    commanded_rad : per scan the commanded angle of each reading, (n_k, 1) or (n_k, c) with channel
        time offsets [rad].
    commanded, free_phase : per scan: the angle is commanded (speed scale free); the phase is free.
    priors : per scan the reported offset S - C, or None.
    prior_w : weight of a prior row (the noise floor over the prior's u) [-].
    floors, sigma : readings' noise floor per scan and channel (K, c), and pooled [mm].
    range_mm : sensor range per channel [mm]; tau_s : channel time offsets (c,) or None [s].
    absolute : the beams are absolute (beta of the first channel free).
    beta1_fixed_rad : the design beta of the first channel (the gauge when not absolute).
    phase_held_rad : per scan the phase where it is not free [rad].
    cols : per scan :class:`NuisanceColumns`; n_params : length of the internal vector.
    rule : the acceptance rule; max_nfev, cond_max : iteration limit, largest condition number.
    """

    scan_ids: tuple[str, ...]
    channels: tuple[int, ...]
    R_mm: float
    ys: tuple[np.ndarray, ...]
    masks: tuple[np.ndarray, ...]
    angle_models: tuple[AngleModel, ...]
    commanded_rad: tuple[np.ndarray, ...]
    commanded: tuple[bool, ...]
    free_phase: tuple[bool, ...]
    priors: tuple[np.ndarray | None, ...]
    prior_w: float
    floors: np.ndarray
    sigma: float
    range_mm: np.ndarray
    tau_s: np.ndarray | None
    absolute: bool
    beta1_fixed_rad: float
    phase_held_rad: tuple[float, ...]
    cols: tuple[NuisanceColumns, ...]
    n_params: int
    rule: AcceptanceRule
    max_nfev: int = 1000
    cond_max: float = 1e10
    #: per (scan, rows, first row) the Jacobian rows of each channel's valid readings
    #: (:func:`borescan.calibrate.residuals.block_rows`); a problem with other masks starts empty
    row_cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    # ---- sizes and offsets
    @property
    def c(self) -> int:
        """Number of channels."""
        return len(self.channels)

    @property
    def K(self) -> int:
        """Number of scans."""
        return len(self.scan_ids)

    @property
    def ch0_free(self) -> int:
        """1 when psi of the first channel is free (absolute beams), else 0."""
        return 1 if self.absolute else 0

    @property
    def n_beam(self) -> int:
        """Number of beam parameters (psi, rho, g)."""
        return 3 * self.c - 1 + self.ch0_free

    @property
    def i_rho0(self) -> int:
        """Index of the first rho."""
        return self.c - 1 + self.ch0_free

    @property
    def i_g0(self) -> int:
        """Index of the first g (d_b in the public vector)."""
        return 2 * self.c - 1 + self.ch0_free

    @property
    def n_obs(self) -> int:
        """Number of readings the fit uses."""
        return int(sum(m.sum() for m in self.masks))

    @property
    def n_prior(self) -> int:
        """Number of prior rows (2 per scan with a reported offset)."""
        return 2 * sum(p is not None for p in self.priors)

    def beta_free(self, j: int) -> bool:
        """Return whether beta (psi) of channel index ``j`` is a parameter."""
        return j > 0 or self.absolute

    # ---- the internal vector
    def split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return (psi (c,), NaN for a gauge-fixed one; rho (c,); g (c,)) of an internal vector."""
        psi = x[: self.i_rho0]
        if not self.ch0_free:
            psi = np.concatenate([[np.nan], psi])
        return psi, x[self.i_rho0 : self.i_g0], x[self.i_g0 : self.n_beam]

    def unpack(self, x: np.ndarray) -> tuple[Beams, list[ScanNuisance]]:
        """Return the beams and each scan's nuisance values of an internal vector."""
        psi, rho, g = self.split(x)
        beta, d_b = unstraighten(psi, rho, g, self.R_mm)
        if not self.ch0_free:
            beta[0] = self.beta1_fixed_rad
        nuis = [
            ScanNuisance(
                np.array([x[cl.ox], x[cl.oy]]),
                x[cl.phase] if cl.phase is not None else self.phase_held_rad[k],
                x[cl.scale] if cl.scale is not None else 1.0,
            )
            for k, cl in enumerate(self.cols)
        ]
        return Beams(self.channels, beta, rho, d_b), nuis

    def pack(self, beams: Beams, nuis: Sequence[ScanNuisance]) -> np.ndarray:
        """Return the internal vector of beams and nuisance values (inverse of :meth:`unpack`)."""
        psi, g = straighten(beams.beta_rad, beams.rho_mm, beams.d_b_mm, self.R_mm)
        x = np.zeros(self.n_params)
        x[: self.i_rho0] = psi if self.ch0_free else psi[1:]
        x[self.i_rho0 : self.i_g0] = beams.rho_mm
        x[self.i_g0 : self.n_beam] = g
        for cl, nu in zip(self.cols, nuis):
            x[cl.ox], x[cl.oy] = nu.offset_mm
            if cl.phase is not None:
                x[cl.phase] = nu.phase_rad
            if cl.scale is not None:
                x[cl.scale] = nu.speed_scale
        return x

    def public(self, x: np.ndarray) -> np.ndarray:
        """Return internal free parameters -> public ones (beta for psi, d_b for g; the rest as they are)."""
        out = np.array(x, dtype=float, copy=True)
        psi, rho, g = self.split(x)
        beta, d_b = unstraighten(psi, rho, g, self.R_mm)
        out[: self.i_rho0] = beta if self.ch0_free else beta[1:]
        out[self.i_g0 : self.n_beam] = d_b
        return out

    def public_cov(self, x: np.ndarray, cov_int: np.ndarray) -> np.ndarray:
        """Return the covariance of the public free parameters from the internal one at ``x``.

        beta = psi - asin(rho / R), d_b = g - rho^2 / (2R): A = d public / d internal, A C A^T.
        """
        rho = np.asarray(x[self.i_rho0 : self.i_g0], dtype=float)
        A = np.eye(cov_int.shape[0])
        dg = dd_b_drho_at_g(rho, self.R_mm)
        dpsi = dbeta_drho_at_psi(rho, self.R_mm)
        for j in range(self.c):
            A[self.i_g0 + j, self.i_rho0 + j] = dg[j]
            if self.beta_free(j):
                A[j - 1 + self.ch0_free, self.i_rho0 + j] = dpsi[j]
        return A @ cov_int @ A.T

    def params_of(self, v: np.ndarray) -> np.ndarray:
        """Return the calibration's (..., 3c) order of public vectors (..., n) (gauge-fixed beta: 0)."""
        idx = public_index(self.c, self.ch0_free)
        ok = idx >= 0
        out = np.zeros(v.shape[:-1] + (3 * self.c,))
        out[..., ok] = v[..., idx[ok]]
        return out

    def internal_names(self) -> list[str]:
        """Return the names of the internal parameters, in vector order."""
        names = (
            [f"psi_{ch}_rad" for j, ch in enumerate(self.channels) if self.beta_free(j)]
            + [f"rho_{ch}_mm" for ch in self.channels]
            + [f"g_{ch}_mm" for ch in self.channels]
        )
        for sid, cl in zip(self.scan_ids, self.cols):
            names += [f"{sid}.{name}" for name, _ in cl.items()]
        return names

    def public_names(self) -> list[str]:
        """Return the names of the public free parameters, in vector order."""
        return public_param_names(self.channels, self.scan_ids, self.ch0_free, self.cols)
