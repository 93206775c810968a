"""What a ring-gauge calibration scan will fix, before it is made (``borescan plan``).

From a device's design (its nominal beams, each sensor's noise and range), a gauge and a proposed
spindle scan (offset from the gauge centre and its direction, revolutions, samples per revolution,
speeds, encoder or commanded angle, positions known or not), :func:`predict` gives each calibrated
parameter's standard uncertainty as the Cramer-Rao bound of the calibration's own model, and each
beam's mirror depth (:func:`borescan.mirror.predicted_depth`); :func:`recommend` finds the smallest
scan reaching a target (u(beta) at most a stated value, every rho's sign resolved).

The bound is sigma^2 (J^T J + prior)^-1 with J the readings' analytic Jacobian of
:func:`borescan.physics.tri.tri_spindle_jacobian` (the calibration's, not a second geometry) at the
design, over the free parameters of :func:`borescan.calibrate.full_fit.fit_full_calibration` for that scan:
per channel beta (the first one held unless an encoder angle and known positions make the beams
absolute), rho, d_b; the offset o = S - C (2; prior u = a sqrt(2/3) per coordinate when positions are
known); with a commanded angle the speed scale, and the phase where positions are known. d_b adds
the fit's second-order term 3 u(rho)^4 / (4 R^2) (d_b = g - rho^2 / (2R)).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from borescan.physics.tri import tri_spindle_jacobian
from borescan.geometry import Beams
from borescan.mirror import RESOLVED_DCHI2, mirror_exists, offset_to_resolve_mm, predicted_depth

__all__ = [
    "DeviceDesign",
    "PlanPrediction",
    "ScanDesign",
    "largest_offset_mm",
    "predict",
    "recommend",
    "samples_to_resolve",
    "scan_angles_rad",
]


@dataclass(frozen=True)
class DeviceDesign:
    """A three-sensor device as designed: nominal beams, each sensor's noise sigma and range [mm]."""

    beams: Beams
    noise_mm: tuple[float, ...]
    range_mm: tuple[float, ...]


@dataclass(frozen=True)
class ScanDesign:
    """A proposed ring-gauge spindle scan.

    offset_mm, offset_direction_rad : the spindle's offset from the gauge centre (o = S - C) [mm, rad]
    revolutions : turns of the whole scan, split equally over ``rpm`` (one segment per speed)
    samples_per_rev : samples per revolution at the first speed (the sample rate is fixed) [-]
    rpm : the speeds [1/min]; direction ``"ccw"`` or ``"cw"``
    encoder : the angle measured (else commanded: speed scale free, phase free where positions known)
    positions_known, position_accuracy_mm : scan.json gives S and C, each within +- a per coordinate
    """

    offset_mm: float
    offset_direction_rad: float = 0.0
    revolutions: float = 10.0
    samples_per_rev: int = 660
    rpm: tuple[float, ...] = (60.0,)
    direction: str = "ccw"
    encoder: bool = True
    positions_known: bool = True
    position_accuracy_mm: float = 0.002

    @property
    def n_samples(self) -> int:
        """Samples of each channel over the whole scan."""
        rate_hz = self.samples_per_rev * self.rpm[0] / 60.0
        seg_s = [self.revolutions / len(self.rpm) * 60.0 / r for r in self.rpm]
        return round(rate_hz * sum(seg_s))


@dataclass(frozen=True)
class PlanPrediction:
    """What :func:`predict` says of one scan.

    Standard uncertainties per channel (Cramer-Rao bound; ``u_dbeta_rad`` of beta_c - beta_first, what a
    diameter depends on: a common rotation moves none), each beam's mirror (possible, depth, the offset that
    would resolve it), whether every beam's readings stay inside its sensor's range, and the beta reference
    the calibration will use.
    """

    scan: ScanDesign
    channels: tuple[int, ...]
    u_beta_rad: tuple[float, ...]
    u_rho_mm: tuple[float, ...]
    u_d_b_mm: tuple[float, ...]
    u_dbeta_rad: tuple[float, ...]
    beta_reference: str
    mirror_possible: tuple[bool, ...]
    mirror_depth: tuple[float, ...]
    offset_to_resolve_mm: tuple[float, ...]
    in_range: bool
    rho_mm: tuple[float, ...]
    noise_mm: tuple[float, ...]
    radius_mm: float
    offset_limit_mm: float
    cov: np.ndarray = field(repr=False, compare=False)

    @property
    def resolved(self) -> tuple[bool, ...]:
        """Per beam: no mirror, or its depth at least :data:`borescan.mirror.RESOLVED_DCHI2`."""
        return tuple((not p) or d >= RESOLVED_DCHI2 for p, d in zip(self.mirror_possible, self.mirror_depth))

    @property
    def offset_can_resolve(self) -> tuple[bool, ...]:
        """Per beam: some offset inside the sensors' range resolves its sign at this scan's samples.

        False where the offset that resolves it exceeds :attr:`offset_limit_mm` while a mirror still exists
        there: only more samples (lower noise) or a longer-range sensor would (:func:`samples_to_resolve`).
        """
        e = self.offset_limit_mm
        return tuple(
            x <= e or not mirror_exists(float(r), e) for x, r in zip(self.offset_to_resolve_mm, self.rho_mm)
        )


def scan_angles_rad(scan: ScanDesign) -> tuple[np.ndarray, np.ndarray]:
    """Return the device angle phi (n,) of every sample and the commanded angle Phi (n,).

    Phi is what phi is scaled from (the speed scale's column is dv/dphi Phi); phase 0, each speed segment
    continuing the previous.
    """
    rate_hz = scan.samples_per_rev * scan.rpm[0] / 60.0
    sgn = 1.0 if scan.direction == "ccw" else -1.0
    parts, start = [], 0.0
    for r in scan.rpm:
        dur = scan.revolutions / len(scan.rpm) * 60.0 / r
        t = np.arange(round(dur * rate_hz)) / rate_hz
        parts.append(start + 2.0 * math.pi * r / 60.0 * t)
        start = parts[-1][-1] + 2.0 * math.pi * r / 60.0 / rate_hz if t.size else start
    Phi = np.concatenate(parts)
    return sgn * Phi, sgn * Phi


def largest_offset_mm(device: DeviceDesign, radius_mm: float, n_angles: int = 720) -> float:
    """Return the largest spindle offset that keeps every beam's reading inside (0, range) over a turn [mm].

    Bisection on e over the readings of :func:`borescan.physics.tri.tri_spindle_jacobian` at ``n_angles``
    device angles (the offset's direction relative to the beams sweeps a full turn as the spindle turns);
    0 when even the centred spindle puts a reading outside.
    """
    phi = np.linspace(0.0, 2.0 * math.pi, n_angles, endpoint=False)
    rng = np.asarray(device.range_mm, dtype=float)

    def inside(e: float) -> bool:
        v, _ = tri_spindle_jacobian(phi, device.beams, np.array([e, 0.0]), float(radius_mm))
        return bool(np.all(v.min(axis=0) > 0.0) and np.all(v.max(axis=0) < rng))

    if not inside(0.0):
        return 0.0
    lo, hi = 0.0, float(np.max(rng))
    while inside(hi) and hi < radius_mm:
        lo, hi = hi, 2.0 * hi
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if inside(mid) else (lo, mid)
    return lo


def samples_to_resolve(
    radius_mm: float, sigma_mm: float, offset_mm: float, rho_mm: float, k: float = RESOLVED_DCHI2
) -> float:
    """Return the samples per channel that put a beam's mirror ``k`` above the minimum at ``offset_mm``.

    Eq. (1) of :mod:`borescan.mirror` solved for N: N = 2 k sigma^2 L^4 / (rho^2 e^4) [-]; inf where rho or e
    is 0.
    """
    if rho_mm == 0.0 or offset_mm <= 0.0:
        return float("inf")
    return float(2.0 * k * sigma_mm**2 * radius_mm**4 / (rho_mm**2 * offset_mm**4))


def predict(
    device: DeviceDesign, radius_mm: float, scan: ScanDesign, offset_limit_mm: float | None = None
) -> PlanPrediction:
    """Return the Cramer-Rao bound of every calibrated parameter and each beam's mirror for ``scan``.

    On a gauge of radius ``radius_mm`` (module doc). ``offset_limit_mm``: :func:`largest_offset_mm` of this
    device and gauge when the caller already has it (it depends on neither the offset nor the revolutions);
    computed here when None.

    Returns
    -------
    PlanPrediction; its ``cov`` (3c, 3c) in the calibration's order (per channel beta, rho, d_b; a
    held beta has zero rows and columns).
    """
    beams = device.beams
    c = len(beams.channels)
    phi, Phi = scan_angles_rad(scan)
    o = scan.offset_mm * np.array([math.cos(scan.offset_direction_rad), math.sin(scan.offset_direction_rad)])
    v, jac = tri_spindle_jacobian(phi, beams, o, float(radius_mm))  # v (n, c); jac[...] (c, n)
    sig = np.asarray(device.noise_mm, dtype=float)
    absolute = scan.encoder and scan.positions_known
    cols, names = [], []
    for j in range(c):
        if absolute or j > 0:
            cols.append(np.zeros((c, phi.size)))
            cols[-1][j] = jac["beta"][j]
            names.append(("beta", j))
    for j in range(c):
        cols.append(np.zeros((c, phi.size)))
        cols[-1][j] = jac["rho"][j]
        names.append(("rho", j))
    for j in range(c):
        cols.append(np.zeros((c, phi.size)))
        cols[-1][j] = -1.0
        names.append(("d_b", j))
    cols += [jac["ox"], jac["oy"]]
    names += [("o", 0), ("o", 1)]
    if not scan.encoder:
        if scan.positions_known:
            cols.append(jac["phi"])
            names.append(("phase", 0))
        cols.append(jac["phi"] * Phi[None, :])
        names.append(("scale", 0))
    # each channel's rows weighted by 1 / sigma_c
    J = np.stack([(col / sig[:, None]).ravel() for col in cols], axis=1)
    info = J.T @ J
    if scan.positions_known:
        u_o = scan.position_accuracy_mm * math.sqrt(2.0 / 3.0)
        for i, nm in enumerate(names):
            if nm[0] == "o":
                info[i, i] += 1.0 / u_o**2
    cov_free = np.linalg.inv(info)
    cov = np.zeros((3 * c, 3 * c))
    pos = {"beta": 0, "rho": 1, "d_b": 2}
    sel = [(i, 3 * nm[1] + pos[nm[0]]) for i, nm in enumerate(names) if nm[0] in pos]
    fi, ci = (list(t) for t in zip(*sel))
    cov[np.ix_(ci, ci)] = cov_free[np.ix_(fi, fi)]
    # d_b = g - rho^2 / (2R) is quadratic in rho: the fit's second-order term 3 u(rho)^4 / (4 R^2)
    # (variance and squared bias of u(rho)^2 / (2R), fit_full_calibration) on each d_b
    i_db = np.arange(2, 3 * c, 3)
    cov[i_db, i_db] += 3.0 * np.diag(cov)[i_db - 1] ** 2 / (4.0 * radius_mm**2)
    u = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    u_rel = [math.sqrt(max(cov[3 * j, 3 * j] + cov[0, 0] - 2 * cov[0, 3 * j], 0.0)) for j in range(c)]
    n = scan.n_samples
    depth = tuple(
        predicted_depth([n], [scan.offset_mm], float(r), [s], radius_mm) for r, s in zip(beams.rho_mm, sig)
    )
    fix = tuple(offset_to_resolve_mm(radius_mm, float(s), n, float(r)) for r, s in zip(beams.rho_mm, sig))
    rng = np.asarray(device.range_mm, dtype=float)
    in_range = bool(np.all(v.min(axis=0) > 0.0) and np.all(v.max(axis=0) < rng))
    return PlanPrediction(
        scan=scan,
        channels=tuple(beams.channels),
        u_beta_rad=tuple(u[0::3]),
        u_rho_mm=tuple(u[1::3]),
        u_d_b_mm=tuple(u[2::3]),
        u_dbeta_rad=tuple(u_rel),
        beta_reference="absolute" if absolute else f"channel {beams.channels[0]} fixed",
        mirror_possible=tuple(mirror_exists(float(r), scan.offset_mm) for r in beams.rho_mm),
        mirror_depth=depth,
        offset_to_resolve_mm=fix,
        in_range=in_range,
        rho_mm=tuple(float(r) for r in beams.rho_mm),
        noise_mm=tuple(float(x) for x in sig),
        radius_mm=float(radius_mm),
        offset_limit_mm=largest_offset_mm(device, radius_mm) if offset_limit_mm is None else offset_limit_mm,
        cov=cov,
    )


def _meets(p: PlanPrediction, target_u_beta_rad: float) -> bool:
    u_b = [u for u in p.u_dbeta_rad if u > 0]
    return p.in_range and all(p.resolved) and all(u <= target_u_beta_rad for u in u_b)


def recommend(
    device: DeviceDesign,
    radius_mm: float,
    base: ScanDesign,
    target_u_beta_rad: float,
    offsets_mm: Sequence[float],
    revolutions: Sequence[float],
) -> PlanPrediction | None:
    """Return the smallest scan like ``base`` that reaches the target.

    Every u(beta_c - beta_1) <= ``target_u_beta_rad`` (the beams' directions relative to each other; an
    absolute beta is limited by the known positions too), every rho's sign resolved, every reading inside its
    sensor's range. Smallest: fewest revolutions, then the smallest offset (candidates ``revolutions`` x
    ``offsets_mm``). None when none does.
    """
    limit_mm = largest_offset_mm(device, radius_mm)
    for rev in sorted(revolutions):
        for off in sorted(offsets_mm):
            p = predict(
                device, radius_mm, replace(base, revolutions=float(rev), offset_mm=float(off)), limit_mm
            )
            if _meets(p, target_u_beta_rad):
                return p
    return None
