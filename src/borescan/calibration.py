"""Calibration of the three-sensor device: Yang 2017 (Eqs. 8-15) and a full-data least-squares fit.

Two methods return the same result type, :class:`TriCalibration`, whose parameter vector is, per
channel in ascending channel order, ``(beta_rad, rho_mm, d_b_mm)`` (``docs/DESIGN.md``).

Yang 2017 method
    Per channel the mean extreme readings d_max, d_min on a ring gauge of radius R with spindle
    offset oe give d_b and r = |rho| from Eq. 8 (closed form below, Eqs. 10-11); the sign of rho
    follows from the "advanced"/"backward" status (Yang §2.3) and the beam angles from the times at
    which the beams pass their feature point (Eqs. 12-15).

    Sign conventions, checked against :func:`borescan.geometry.tri_spindle_readings` in the tests:
    with the spindle turning counter-clockwise (the raw format's positive direction), a beam is
    "advanced" (more samples from its minimum to its maximum than back, Yang §2.3) exactly when
    rho > 0. At its minimum the wall point of beam c lies on the ray from the axis O' through the
    nearest wall point, at distance X = R - oe (Eq. 13), and its device-frame polar angle is
    beta_c + asin(rho_c / X). Hence, with theta_t the rotation from the feature point of beam 2
    to that of beam 1 (beam 1 arrives later),

        beta_2 - beta_1 = theta_t + asin(rho_1 / X) - asin(rho_2 / X).

    With angles measured in the sense of rotation and the statuses of the §2.3 sampling rule, the
    printed Eq. 14 has the opposite sign of the asin terms for every status combination: the exact
    angle is theta = theta_t - theta_c, not Eq. 12's theta_c + theta_t (equivalently, Eq. 12/14
    hold with "advanced" and "backward" swapped). :func:`yang_theta_c` implements Eq. 14 as
    printed; :func:`yang_to_beams` uses the relation above for either direction.

Full-data method
    :func:`fit_full_calibration` fits every sample of one or more spindle scans to the exact
    forward model with an analytic Jacobian (implicit differentiation of the ray-circle root).
    Free: beta_c - beta_1 (c >= 2), rho_c, d_b_c, and per scan the spindle-to-gauge offset
    (2 components, machine frame) and the rotation rate. A ring gauge is a circle, so the data
    depend on beta_1, the phase phi_0 and the offset direction only through
    beta_1 + phi_0 - angle(offset) per scan: beta_1 (the device x axis) and phi_0 (the spindle
    encoder zero) are the gauge and are held fixed; the diagnostics report the rank of the
    Jacobian with all of them free (deficient by 1 + number of scans).
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy.optimize import least_squares

from borescan.geometry import Beams, Bore, beam_frame, tri_spindle_readings

__all__ = [
    "CalibrationError",
    "TriCalibration",
    "make_calibration_id",
    "yang_oe",
    "yang_d_b_r",
    "yang_sensitivities",
    "yang_theta_c",
    "yang_theta_t",
    "yang_status",
    "yang_to_beams",
    "yang_calibration",
    "fit_full_calibration",
    "full_residuals",
]

STATUSES = ("advanced", "backward")


class CalibrationError(Exception):
    """A calibration that cannot be trusted (no convergence, rank deficiency, bad input).

    ``str(e)`` is ``"<scan ids>: <problem>"``.
    """

    def __init__(self, scan_ids: Sequence[str], problem: str) -> None:
        self.scan_ids = tuple(str(s) for s in scan_ids)
        self.problem = problem
        super().__init__(f"{','.join(self.scan_ids) or '<no scan id>'}: {problem}")


# --------------------------------------------------------------------------- result type


def make_calibration_id(
    device_id: str, scan_ids: Sequence[str], method: str, night: str | None = None
) -> str:
    """Deterministic id ``<device_id>-<YYYYMMDD>-<method>-<8 hex>``.

    The hash is sha256 of device id, sorted scan ids and method. The date is ``night``
    (``YYYY-MM-DD``) or, if absent, the first ``N<YYYYMMDD>`` found in the scan ids; it is
    left out when neither exists.
    """
    scan_ids = sorted(str(s) for s in scan_ids)
    key = json.dumps({"device_id": device_id, "scan_ids": scan_ids, "method": method}, sort_keys=True)
    digest = hashlib.sha256(key.encode()).hexdigest()[:8]
    date = night.replace("-", "") if night else None
    if date is None:
        for s in scan_ids:
            m = re.search(r"N(\d{8})", s)
            if m:
                date = m.group(1)
                break
    parts = [device_id] + ([date] if date else []) + [method, digest]
    return "-".join(parts)


def _json_safe(x: Any) -> Any:
    """Recursively convert numpy scalars/arrays to JSON-safe Python (NaN/inf -> None)."""
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, np.ndarray):
        return _json_safe(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if np.isfinite(x) else None
    return x


@dataclass
class TriCalibration:
    """Calibrated beams of a three-sensor device with covariance and fit diagnostics.

    Attributes
    ----------
    calibration_id, device_id : str
    beams : Beams
        Calibrated (beta_rad, rho_mm, d_b_mm) per channel.
    cov : ndarray (3c, 3c)
        Covariance, order per channel (beta_rad, rho_mm, d_b_mm). Gauge-fixed parameters
        (beta of the first channel) have zero rows/columns.
    method : str
        ``"yang2017"`` or ``"full_lsq"``.
    scan_ids : tuple of str; raw_sha256 : dict file name -> hex digest
    residual_rms_mm, dof, rank, condition, converged : fit diagnostics (NaN/-1 where undefined)
    nuisance : dict scan_id -> dict of per-scan estimates (offset, rotation rate, ...)
    diagnostics : dict of further JSON-safe information (gauge, rank with all parameters free, ...)
    """

    calibration_id: str
    device_id: str
    beams: Beams
    cov: np.ndarray
    method: str
    scan_ids: tuple[str, ...]
    raw_sha256: dict[str, str] = field(default_factory=dict)
    residual_rms_mm: float = float("nan")
    dof: int = -1
    rank: int = -1
    condition: float = float("nan")
    converged: bool = True
    nuisance: dict[str, dict[str, float]] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        c = len(self.beams.channels)
        self.cov = np.asarray(self.cov, dtype=float)
        if self.cov.shape != (3 * c, 3 * c):
            raise ValueError(f"cov must be ({3 * c}, {3 * c}), got {self.cov.shape}")
        self.scan_ids = tuple(self.scan_ids)

    @property
    def params(self) -> np.ndarray:
        """Parameter vector (3c,), per channel (beta_rad, rho_mm, d_b_mm)."""
        b = self.beams
        return np.stack([b.beta_rad, b.rho_mm, b.d_b_mm], axis=1).ravel()

    def _u(self, k: int) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov)[k::3], 0.0, None))

    @property
    def u_beta_rad(self) -> np.ndarray:
        """Standard uncertainties of beta per channel [rad]."""
        return self._u(0)

    @property
    def u_rho_mm(self) -> np.ndarray:
        """Standard uncertainties of rho per channel [mm]."""
        return self._u(1)

    @property
    def u_d_b_mm(self) -> np.ndarray:
        """Standard uncertainties of d_b per channel [mm]."""
        return self._u(2)

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix (3c, 3c); zero rows/columns for gauge-fixed parameters."""
        u = np.sqrt(np.clip(np.diag(self.cov), 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            r = self.cov / np.outer(u, u)
        r = np.where(np.outer(u, u) > 0, r, 0.0)
        np.fill_diagonal(r, np.where(u > 0, 1.0, 0.0))
        return r

    def to_dict(self) -> dict:
        """JSON-safe dict (inverse: :meth:`from_dict`)."""
        return _json_safe(
            {
                "calibration_id": self.calibration_id,
                "device_id": self.device_id,
                "method": self.method,
                "scan_ids": list(self.scan_ids),
                "raw_sha256": dict(sorted(self.raw_sha256.items())),
                "beams": self.beams.to_nominal(),
                "cov": self.cov,
                "residual_rms_mm": self.residual_rms_mm,
                "dof": self.dof,
                "rank": self.rank,
                "condition": self.condition,
                "converged": self.converged,
                "nuisance": self.nuisance,
                "diagnostics": self.diagnostics,
            }
        )

    @classmethod
    def from_dict(cls, d: dict) -> "TriCalibration":
        """Rebuild from :meth:`to_dict` output."""

        def f(x: Any) -> float:
            return float("nan") if x is None else float(x)

        return cls(
            calibration_id=d["calibration_id"],
            device_id=d["device_id"],
            beams=Beams.from_nominal(d["beams"]),
            cov=np.array([[f(v) for v in row] for row in d["cov"]]),
            method=d["method"],
            scan_ids=tuple(d["scan_ids"]),
            raw_sha256=dict(d.get("raw_sha256", {})),
            residual_rms_mm=f(d.get("residual_rms_mm")),
            dof=int(d.get("dof", -1)),
            rank=int(d.get("rank", -1)),
            condition=f(d.get("condition")),
            converged=bool(d.get("converged", True)),
            nuisance=d.get("nuisance", {}),
            diagnostics=d.get("diagnostics", {}),
        )


# --------------------------------------------------------------------------- Yang 2017


def yang_oe(p1_xy: Sequence[float], p0_xy: Sequence[float]) -> float:
    """Spindle-to-gauge-centre distance oe = |P1 - P0| [mm] (Yang 2017, Eq. 9)."""
    p1 = np.asarray(p1_xy, dtype=float)
    p0 = np.asarray(p0_xy, dtype=float)
    return float(np.hypot(*(p1 - p0)))


def yang_d_b_r(d_max_mm, d_min_mm, R_mm, oe_mm) -> tuple[np.ndarray, np.ndarray]:
    """Base length d_b and tangential radius r = |rho| from the extreme readings (Yang 2017, Eqs. 8, 10, 11).

    Eq. 8: (d_b + d_min)^2 + r^2 = (R - oe)^2 and (d_b + d_max)^2 + r^2 = (R + oe)^2.
    Subtracting: (d_max - d_min)(2 d_b + d_max + d_min) = 4 R oe, so

        d_b = 2 R oe / D - (d_max + d_min) / 2,  D = d_max - d_min          (Eq. 10)
        r   = sqrt((R - oe)^2 - (d_b + d_min)^2)                          (Eq. 11)

    Parameters
    ----------
    d_max_mm, d_min_mm : array_like, mean maximum / minimum reading per channel [mm]
    R_mm : ring gauge radius [mm]; oe_mm : spindle offset from the gauge centre [mm]

    Returns
    -------
    d_b_mm, r_mm : ndarray [mm]; r is NaN where Eq. 8 has no real solution (r^2 < 0).
    """
    d_max = np.asarray(d_max_mm, dtype=float)
    d_min = np.asarray(d_min_mm, dtype=float)
    D = d_max - d_min
    d_b = 2.0 * R_mm * oe_mm / D - 0.5 * (d_max + d_min)
    a = d_b + d_min
    r2 = (R_mm - oe_mm) ** 2 - a * a
    r = np.sqrt(np.where(r2 >= 0.0, r2, np.nan))
    return d_b, r


def yang_sensitivities(d_max_mm, d_min_mm, R_mm, oe_mm) -> dict[str, np.ndarray]:
    """Analytic partial derivatives of d_b and r (Eqs. 10-11) with respect to d_max, d_min, R, oe.

    With D = d_max - d_min, a = d_b + d_min = 2 R oe / D - D / 2 and X = R - oe:
    dr/dd_max = -dr/dd_min = a (2 R oe / D^2 + 1/2) / r, dr/doe = -(X + 2 R a / D) / r,
    dr/dR = (X - 2 oe a / D) / r; dd_b/dd_max = -2 R oe / D^2 - 1/2,
    dd_b/dd_min = 2 R oe / D^2 - 1/2, dd_b/dR = 2 oe / D, dd_b/doe = 2 R / D.

    Returns
    -------
    dict with keys ``dr_dd_max``, ``dr_dd_min``, ``dr_dR``, ``dr_doe``, ``dd_b_dd_max``,
    ``dd_b_dd_min``, ``dd_b_dR``, ``dd_b_doe`` (dimensionless, mm/mm).
    """
    d_max = np.asarray(d_max_mm, dtype=float)
    d_min = np.asarray(d_min_mm, dtype=float)
    D = d_max - d_min
    d_b, r = yang_d_b_r(d_max, d_min, R_mm, oe_mm)
    a = d_b + d_min
    X = R_mm - oe_mm
    g = 2.0 * R_mm * oe_mm / D**2 + 0.5
    return {
        "dr_dd_max": a * g / r,
        "dr_dd_min": -a * g / r,
        "dr_dR": (X - 2.0 * oe_mm * a / D) / r,
        "dr_doe": -(X + 2.0 * R_mm * a / D) / r,
        "dd_b_dd_max": -2.0 * R_mm * oe_mm / D**2 - 0.5,
        "dd_b_dd_min": 2.0 * R_mm * oe_mm / D**2 - 0.5,
        "dd_b_dR": 2.0 * oe_mm / D,
        "dd_b_doe": 2.0 * R_mm / D,
    }


def _check_status(status: str) -> str:
    if status not in STATUSES:
        raise ValueError(f"status must be one of {STATUSES}, got {status!r}")
    return status


def yang_theta_c(r1_mm: float, r2_mm: float, X_mm: float, status1: str, status2: str) -> float:
    """Correction angle theta_c between two beams, as printed in Yang 2017, Eq. 14.

    Both backward: +asin(r1/X) - asin(r2/X); both advanced: -asin(r1/X) + asin(r2/X);
    1 advanced, 2 backward: -asin(r1/X) - asin(r2/X); 1 backward, 2 advanced: +asin(r1/X) + asin(r2/X).
    X = R - oe (Eq. 13). Beam ("Line") 1 reaches the feature point after beam 2. Measured in
    the sense of rotation, the exact angle from beam 1 to beam 2 is theta_t - theta_c, not
    Eq. 12's theta_t + theta_c (module docstring; checked against the forward model).

    Returns
    -------
    float [rad]
    """
    s1 = 1.0 if _check_status(status1) == "backward" else -1.0
    s2 = 1.0 if _check_status(status2) == "backward" else -1.0
    a1 = float(np.arcsin(r1_mm / X_mm))
    a2 = float(np.arcsin(r2_mm / X_mm))
    if status1 == status2:
        return s1 * (a1 - a2)
    return s1 * (a1 + a2)


def yang_theta_t(spacing_samples: float, samples_per_rev: float) -> float:
    """Rotation between two feature-point passages, theta_t = omega * Delta t (Yang 2017, Eq. 15).

    With Delta t = spacing / f_s and omega = 2 pi f_s / samples_per_rev:
    theta_t = 2 pi spacing / samples_per_rev [rad].
    """
    return 2.0 * np.pi * float(spacing_samples) / float(samples_per_rev)


def yang_status(n_min_to_max: float, n_max_to_min: float) -> str:
    """Yang 2017 §2.3: "backward" if fewer samples from minimum to maximum than back, else "advanced"."""
    return "backward" if n_min_to_max < n_max_to_min else "advanced"


def _wrap_near(angle: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Add multiples of 2 pi to ``angle`` to bring it within pi of ``ref``."""
    return ref + (angle - ref + np.pi) % (2.0 * np.pi) - np.pi


def yang_to_beams(
    channels: Sequence[int],
    r_mm,
    d_b_mm,
    statuses: Sequence[str],
    feature_sample,
    samples_per_rev: float,
    X_mm: float,
    *,
    beta_ref_rad: float = 0.0,
    beta_nominal_rad=None,
    direction: str = "ccw",
) -> Beams:
    """Convert Yang's (r, d_b, statuses, feature-point times) into the spec's (beta, rho, d_b).

    rho_c = +r_c for "advanced" and -r_c for "backward" beams (counter-clockwise rotation; the
    other way round for clockwise). The beam angles come from Eqs. 12-15 in the spec's frame:
    beta_c = beta_1 - s theta_t(1 -> c) + asin(rho_1 / X) - asin(rho_c / X), where
    theta_t(1 -> c) = 2 pi (n_c - n_1) / N (Eq. 15), s = +1 (ccw) or -1 (cw).

    Parameters
    ----------
    channels : channel numbers (c,)
    r_mm, d_b_mm : Yang's tangential radius and base length per channel [mm]
    statuses : "advanced" / "backward" per channel
    feature_sample : sample position of each channel's feature point (its minimum), any common
        origin [samples]
    samples_per_rev : N [samples]; X_mm : R - oe (Eq. 13) [mm]
    beta_ref_rad : beta of the first channel (the gauge: Yang's method gives angles between beams)
    beta_nominal_rad : optional (c,), picks the 2 pi branch of each beta; else within pi of the
        Eq. 12 value measured from beta_ref
    direction : "ccw" or "cw" spindle rotation (seen from +z)
    """
    sgn = {"ccw": 1.0, "cw": -1.0}[direction]
    r = np.asarray(r_mm, dtype=float)
    rho = np.array([sgn * (1.0 if _check_status(s) == "advanced" else -1.0) for s in statuses]) * r
    n = np.asarray(feature_sample, dtype=float)
    theta_t = 2.0 * np.pi * (n - n[0]) / float(samples_per_rev)
    corr = np.arcsin(rho / X_mm)
    beta = beta_ref_rad - sgn * theta_t + corr[0] - corr
    ref = np.asarray(beta_nominal_rad, dtype=float) if beta_nominal_rad is not None else beta
    beta = _wrap_near(beta, ref)
    beta[0] = beta_ref_rad
    channels = tuple(int(c) for c in channels)
    return Beams(channels=channels, beta_rad=beta, rho_mm=rho, d_b_mm=np.asarray(d_b_mm, float))


def yang_calibration(
    d_max_mm,
    d_min_mm,
    statuses: Sequence[str],
    feature_sample,
    samples_per_rev: float,
    R_mm: float,
    oe_mm: float,
    *,
    channels: Sequence[int] = (1, 2, 3),
    device_id: str = "",
    scan_ids: Sequence[str] = (),
    raw_sha256: dict[str, str] | None = None,
    beta_ref_rad: float = 0.0,
    beta_nominal_rad=None,
    direction: str = "ccw",
    u_d_max_mm=0.0,
    u_d_min_mm=0.0,
    u_feature_sample=0.0,
    u_oe_mm: float = 0.0,
    u_R_mm: float = 0.0,
    night: str | None = None,
) -> TriCalibration:
    """Yang 2017 calibration (Eqs. 8-15) with linear uncertainty propagation.

    Inputs are the per-channel means of the extreme readings and feature-point positions over
    the revolutions; their standard uncertainties (e.g. standard errors of the means) and those
    of oe and R are propagated by a central-difference Jacobian of the closed forms.

    Raises
    ------
    CalibrationError if Eq. 8 has no real solution (r^2 < 0) for some channel.
    """
    d_max = np.asarray(d_max_mm, dtype=float)
    d_min = np.asarray(d_min_mm, dtype=float)
    nf = np.asarray(feature_sample, dtype=float)
    c = d_max.size

    def forward(x: np.ndarray) -> np.ndarray:
        dmx, dmn, fs = x[:c], x[c : 2 * c], x[2 * c : 3 * c]
        oe, R = x[3 * c], x[3 * c + 1]
        d_b, r = yang_d_b_r(dmx, dmn, R, oe)
        b = yang_to_beams(
            channels, r, d_b, statuses, fs, samples_per_rev, R - oe,
            beta_ref_rad=beta_ref_rad, beta_nominal_rad=beta_nominal_rad, direction=direction,
        )
        return np.stack([b.beta_rad, b.rho_mm, b.d_b_mm], axis=1).ravel()

    x0 = np.concatenate([d_max, d_min, nf, [oe_mm, R_mm]])
    p0 = forward(x0)
    if not np.all(np.isfinite(p0)):
        bad = [int(ch) for ch, v in zip(channels, p0[1::3]) if not np.isfinite(v)]
        raise CalibrationError(scan_ids, f"Yang Eq. 8 has no real solution r for channel(s) {bad} (r^2 < 0)")
    u_x = np.concatenate(
        [
            np.broadcast_to(np.asarray(u_d_max_mm, float), (c,)),
            np.broadcast_to(np.asarray(u_d_min_mm, float), (c,)),
            np.broadcast_to(np.asarray(u_feature_sample, float), (c,)),
            [u_oe_mm, u_R_mm],
        ]
    )
    J = np.zeros((3 * c, x0.size))
    for k in range(x0.size):
        h = 1e-6 * max(1.0, abs(x0[k])) if k < 3 * c or k == 3 * c else 1e-6 * abs(x0[k])
        xp, xm = x0.copy(), x0.copy()
        xp[k] += h
        xm[k] -= h
        J[:, k] = (forward(xp) - forward(xm)) / (2.0 * h)
    J[np.abs(J) < 1e-300] = 0.0
    cov = (J * u_x**2) @ J.T
    beams = yang_to_beams(
        channels, np.abs(p0[1::3]), p0[2::3], statuses, nf, samples_per_rev, R_mm - oe_mm,
        beta_ref_rad=beta_ref_rad, beta_nominal_rad=beta_nominal_rad, direction=direction,
    )
    return TriCalibration(
        calibration_id=make_calibration_id(device_id, scan_ids, "yang2017", night),
        device_id=device_id,
        beams=beams,
        cov=cov,
        method="yang2017",
        scan_ids=tuple(scan_ids),
        raw_sha256=dict(raw_sha256 or {}),
        diagnostics={
            "gauge": (
                "beta of the first channel fixed at beta_ref_rad; Yang's method gives angles between beams"
            ),
            "X_mm": R_mm - oe_mm,
            "d_max_mm": d_max,
            "d_min_mm": d_min,
            "statuses": list(statuses),
            "oe_mm": oe_mm,
            "R_mm": R_mm,
        },
    )


# --------------------------------------------------------------------------- full-data fit


def _readings_and_jacobian(
    t: np.ndarray, beams: Beams, offset: np.ndarray, omega: float, phase0: float, R: float
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Exact readings (n, c) and their analytic derivatives for one scan.

    The wall point is P = o + Rot(phi)(F + s u) with the gauge centre at the origin; implicit
    differentiation of |P|^2 = R^2 gives ds/dp = -(P . dP/dp) / (P . Rot(phi) u).
    """
    phi = phase0 + omega * t
    v = tri_spindle_readings(phi, offset, beams, Bore((0.0, 0.0), R))
    s = v + beams.d_b_mm
    F, u = beam_frame(beams.beta_rad, beams.rho_mm)  # (c, 2)
    n_vec = np.stack([-u[:, 1], u[:, 0]], axis=-1)
    cph, sph = np.cos(phi)[:, None], np.sin(phi)[:, None]

    def rot(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return cph * a[:, 0] - sph * a[:, 1], sph * a[:, 0] + cph * a[:, 1]

    dev = F + s[..., None] * u  # (n, c, 2) device-frame wall points
    wx = cph * dev[..., 0] - sph * dev[..., 1]
    wy = sph * dev[..., 0] + cph * dev[..., 1]
    Px, Py = offset[0] + wx, offset[1] + wy
    ux, uy = rot(u)
    den = Px * ux + Py * uy
    nx, ny = rot(n_vec)
    rho = beams.rho_mm
    # dP/dbeta = Rot(phi)(-rho u + s n)
    dbx, dby = -rho * ux + s * nx, -rho * uy + s * ny
    jac = {
        "beta": -(Px * dbx + Py * dby) / den,
        "rho": -(Px * nx + Py * ny) / den,
        "ox": -Px / den,
        "oy": -Py / den,
    }
    # dP/dphi = perp(Rot(phi)(F + s u)) = (-wy, wx)
    dphi = -(Px * (-wy) + Py * wx) / den
    jac["phase"] = dphi
    jac["omega"] = dphi * t[:, None]
    return v, jac


def _linear_start(
    t: np.ndarray, y: np.ndarray, mask: np.ndarray, beta: np.ndarray, omega: float, phase0: float
):
    """Offset (S - C) and constant per channel from v ~ k_c - ox cos(phi + beta_c) - oy sin(phi + beta_c)."""
    n, c = y.shape
    rows, rhs = [], []
    for j in range(c):
        m = mask[:, j]
        ang = phase0 + omega * t[m] + beta[j]
        A = np.zeros((m.sum(), 2 + c))
        A[:, 0] = -np.cos(ang)
        A[:, 1] = -np.sin(ang)
        A[:, 2 + j] = 1.0
        rows.append(A)
        rhs.append(y[m, j])
    A = np.vstack(rows)
    b = np.concatenate(rhs)
    sol, res, *_ = np.linalg.lstsq(A, b, rcond=None)
    sse = float(np.sum((A @ sol - b) ** 2))
    return sol[:2], sol[2:], sse


def fit_full_calibration(
    t_s,
    readings_mm,
    channels: Sequence[int],
    nominal: Beams,
    R_mm: float,
    spindle_xy_mm=None,
    rpm=60.0,
    *,
    center_xy_mm=None,
    direction: str = "ccw",
    phase0_rad=0.0,
    scan_ids: Sequence[str] | None = None,
    device_id: str = "",
    raw_sha256: dict[str, str] | None = None,
    night: str | None = None,
    speed_search: float = 0.01,
    max_nfev: int = 1000,
    cond_max: float = 1e10,
) -> TriCalibration:
    """Least-squares calibration on every sample of one or more ring-gauge spindle scans.

    Model (spec "Spindle scan", exact via :func:`borescan.geometry.tri_spindle_readings`):
    v_c(t) = s - d_b_c with |o + Rot(phi(t))(F_c + s u_c)| = R, phi(t) = phi_0 + omega t,
    o = spindle axis minus gauge centre (machine frame). The Yang 2017 Eq. 8 relations hold at
    the extremes of this model.

    Free parameters: beta_c (c >= 2), rho_c, d_b_c; per scan o (2) and omega. Fixed (gauge):
    beta of the first channel (``nominal``) and phi_0 per scan (``phase0_rad``, the encoder
    zero). Solved with ``scipy.optimize.least_squares`` (Levenberg-Marquardt, analytic Jacobian,
    Jacobian-scaled steps). Covariance: s^2 (J^T J)^-1 with s^2 = SSR / dof.

    Parameters
    ----------
    t_s : (n,) or list of (n_k,) sample times per scan [s]
    readings_mm : (n, c) or list of (n_k, c), NaN = missing [mm]
    channels : channel numbers (c,), ascending; nominal : Beams, the starting point and gauge
    R_mm : ring gauge radius [mm]
    spindle_xy_mm, center_xy_mm : optional spindle position and gauge centre per scan (machine
        frame) for the starting offset; without them the offset starts from a linear first-
        harmonic fit
    rpm : nominal speed per scan (scalar or list); direction : "ccw" or "cw"
    speed_search : relative range of a coarse search of the rotation rate around rpm
    max_nfev, cond_max : iteration limit; largest acceptable condition number

    Returns
    -------
    TriCalibration with method "full_lsq"

    Raises
    ------
    CalibrationError naming the scans when the fit does not converge, the Jacobian is rank
    deficient or worse conditioned than ``cond_max``, or there are fewer samples than parameters.
    """
    multi = isinstance(t_s, (list, tuple))
    ts = [np.asarray(x, dtype=float) for x in (t_s if multi else [t_s])]
    ys = [np.asarray(x, dtype=float) for x in (readings_mm if multi else [readings_mm])]
    K = len(ts)
    scan_ids = list(scan_ids) if scan_ids is not None else [f"scan{k + 1}" for k in range(K)]
    if len(scan_ids) != K or len(ys) != K:
        raise ValueError("t_s, readings_mm and scan_ids must have one entry per scan")
    channels = tuple(int(c) for c in channels)
    if tuple(nominal.channels) != channels:
        raise ValueError(f"nominal beams are for channels {nominal.channels}, readings for {channels}")
    c = len(channels)
    for k in range(K):
        if ys[k].shape != (ts[k].size, c):
            raise ValueError(f"{scan_ids[k]}: readings shape {ys[k].shape}, expected ({ts[k].size}, {c})")
    sgn = {"ccw": 1.0, "cw": -1.0}[direction]
    rpms = [float(x) for x in np.broadcast_to(np.asarray(rpm, float), (K,))]
    phases = [float(x) for x in np.broadcast_to(np.asarray(phase0_rad, float), (K,))]
    masks = [np.isfinite(y) for y in ys]
    n_obs = int(sum(m.sum() for m in masks))

    # ---- starting values: rotation rate (coarse search), offset and d_b (linear first harmonic)
    offsets0, omegas0 = [], []
    kconst = np.zeros(c)
    for k in range(K):
        w_nom = sgn * 2.0 * np.pi * rpms[k] / 60.0
        # grid step keeps the phase error at the end of the scan below ~0.05 rad
        span = float(np.ptp(ts[k])) if ts[k].size else 0.0
        n_grid = int(np.clip(np.ceil(2.0 * speed_search * abs(w_nom) * span / 0.05), 1, 4000)) | 1
        grid = w_nom * (1.0 + np.linspace(-speed_search, speed_search, n_grid)) if speed_search > 0 else [w_nom]

        # the search only ranks rates on the grid: every stride-th sample (<= 4000 per scan) is plenty
        sub = slice(None, None, max(1, ts[k].size // 4000))
        t_sub, y_sub, m_sub = ts[k][sub], ys[k][sub], masks[k][sub]

        def sse(w: float, k: int = k, t_sub=t_sub, y_sub=y_sub, m_sub=m_sub) -> float:
            return _linear_start(t_sub, y_sub, m_sub, nominal.beta_rad, w, phases[k])[2]

        best = min(grid, key=sse)
        off, kc, _ = _linear_start(ts[k], ys[k], masks[k], nominal.beta_rad, best, phases[k])
        if spindle_xy_mm is not None and center_xy_mm is not None:
            S = np.broadcast_to(np.asarray(spindle_xy_mm, float), (K, 2))[k]
            C = np.broadcast_to(np.asarray(center_xy_mm, float), (K, 2))[k]
            off = S - C
        offsets0.append(np.asarray(off, float))
        omegas0.append(float(best))
        kconst += kc / K
    d_b0 = np.sqrt(R_mm**2 - nominal.rho_mm**2) - kconst

    # ---- internal parameter vector: [beta_2..c, rho_1..c, g_1..c, (ox, oy, omega) per scan] with
    # g = d_b + rho^2 / (2 R), the well-determined mean level: it straightens the curved
    # rho-d_b valley (readings depend on rho mostly through rho^2 / (2 R) - d_b).
    n_beam = 3 * c - 1
    p_free = n_beam + 3 * K
    if n_obs <= p_free:
        raise CalibrationError(scan_ids, f"{n_obs} valid samples for {p_free} parameters")
    beta1 = float(nominal.beta_rad[0])

    def unpack(x: np.ndarray) -> tuple[Beams, list[np.ndarray], list[float]]:
        beta = np.concatenate([[beta1], x[: c - 1]])
        rho = x[c - 1 : 2 * c - 1]
        d_b = x[2 * c - 1 : 3 * c - 1] - rho**2 / (2.0 * R_mm)
        nuis = x[n_beam:].reshape(K, 3)
        return Beams(channels, beta, rho, d_b), [nu[:2] for nu in nuis], [float(nu[2]) for nu in nuis]

    x0 = np.concatenate(
        [nominal.beta_rad[1:], nominal.rho_mm, d_b0 + nominal.rho_mm**2 / (2.0 * R_mm)]
        + [np.r_[offsets0[k], omegas0[k]] for k in range(K)]
    )

    def model(x: np.ndarray, with_jac: bool, full: bool = False):
        beams, offs, oms = unpack(x)
        res_parts, jac_parts = [], []
        ncols = p_free + (1 + K if full else 0)
        for k in range(K):
            v, jac = _readings_and_jacobian(ts[k], beams, offs[k], oms[k], phases[k], R_mm)
            m = masks[k]
            res_parts.append((v - ys[k])[m])
            if with_jac:
                nk = ts[k].size
                Jk = np.zeros((nk, c, ncols))
                for j in range(c):
                    if j > 0:
                        Jk[:, j, j - 1] = jac["beta"][:, j]
                    Jk[:, j, c - 1 + j] = jac["rho"][:, j] + beams.rho_mm[j] / R_mm
                    Jk[:, j, 2 * c - 1 + j] = -1.0
                col = n_beam + 3 * k
                Jk[:, :, col] = jac["ox"]
                Jk[:, :, col + 1] = jac["oy"]
                Jk[:, :, col + 2] = jac["omega"]
                if full:
                    Jk[:, 0, p_free] = jac["beta"][:, 0]
                    Jk[:, :, p_free + 1 + k] = jac["phase"]
                jac_parts.append(Jk[m])
        r = np.concatenate(res_parts)
        return (r, np.vstack(jac_parts)) if with_jac else r

    try:
        sol = least_squares(
            lambda x: model(x, False),
            x0,
            jac=lambda x: model(x, True)[1],
            method="lm",
            x_scale="jac",
            max_nfev=max_nfev,
            xtol=1e-10,
            ftol=1e-10,
            gtol=1e-10,
        )
    except (ValueError, FloatingPointError) as exc:  # NaN readings from a diverging step
        raise CalibrationError(scan_ids, f"full_lsq fit failed: {exc}") from exc
    r, J = model(sol.x, True)
    converged = bool(sol.success) and bool(np.all(np.isfinite(r)))
    if not converged:
        raise CalibrationError(
            scan_ids, f"full_lsq did not converge after {sol.nfev} evaluations ({sol.message})"
        )
    dof = n_obs - p_free
    ssr = float(r @ r)
    s2 = ssr / dof
    colnorm = np.linalg.norm(J, axis=0)
    colnorm[colnorm == 0] = 1.0
    Js = J / colnorm
    _, sv, Vt = np.linalg.svd(Js, full_matrices=False)
    tol = sv[0] * max(Js.shape) * np.finfo(float).eps
    rank = int(np.sum(sv > tol))
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    # rank with the gauge parameters (beta_1, phase per scan) free too
    _, Jf = model(sol.x, True, full=True)
    cf = np.linalg.norm(Jf, axis=0)
    cf[cf == 0] = 1.0
    svf = np.linalg.svd(Jf / cf, compute_uv=False)
    rank_all = int(np.sum(svf > svf[0] * max(Jf.shape) * np.finfo(float).eps * 1e3))
    if rank < p_free or cond > cond_max:
        raise CalibrationError(
            scan_ids,
            f"full_lsq Jacobian rank {rank} of {p_free}, condition {cond:.3g} (limit {cond_max:.3g}); "
            "the data do not determine the parameters (is the spindle offset from the gauge centre?)",
        )
    cov_s = (Vt.T / sv**2) @ Vt
    cov_int = s2 * cov_s / np.outer(colnorm, colnorm)
    # back to (beta, rho, d_b): d_b = g - rho^2 / (2 R)
    A = np.eye(p_free)
    rho_hat = sol.x[c - 1 : 2 * c - 1]
    for j in range(c):
        A[2 * c - 1 + j, c - 1 + j] = -rho_hat[j] / R_mm
    cov_free = A @ cov_int @ A.T
    # map to (beta, rho, d_b) per channel; beta_1 row/column zero (gauge)
    idx = np.full(3 * c, -1)
    for j in range(c):
        idx[3 * j] = j - 1 if j > 0 else -1
        idx[3 * j + 1] = c - 1 + j
        idx[3 * j + 2] = 2 * c - 1 + j
    cov = np.zeros((3 * c, 3 * c))
    ok = idx >= 0
    cov[np.ix_(ok, ok)] = cov_free[np.ix_(idx[ok], idx[ok])]
    beams, offs, oms = unpack(sol.x)
    u_rho = np.sqrt(np.diag(cov_free)[c - 1 : 2 * c - 1])
    g_hat = sol.x[2 * c - 1 : 3 * c - 1]
    u_g = np.sqrt(np.diag(cov_int)[2 * c - 1 : 3 * c - 1])
    weak = [int(ch) for ch, r_, u_ in zip(channels, beams.rho_mm, u_rho) if abs(r_) < 2.0 * u_]
    nuisance = {}
    bounds = np.concatenate([[0], np.cumsum([int(m.sum()) for m in masks])])
    for k in range(K):
        col = n_beam + 3 * k
        u_nu = np.sqrt(np.diag(cov_free)[col : col + 3])
        nuisance[scan_ids[k]] = {
            "offset_x_mm": float(offs[k][0]),
            "offset_y_mm": float(offs[k][1]),
            "oe_mm": float(np.hypot(*offs[k])),
            "omega_rad_s": oms[k],
            "rpm": float(abs(oms[k]) * 60.0 / (2.0 * np.pi)),
            "u_offset_x_mm": float(u_nu[0]),
            "u_offset_y_mm": float(u_nu[1]),
            "u_omega_rad_s": float(u_nu[2]),
            "phase0_rad": phases[k],
            "residual_rms_mm": float(np.sqrt(np.mean(r[bounds[k] : bounds[k + 1]] ** 2))),
        }
    return TriCalibration(
        calibration_id=make_calibration_id(device_id, scan_ids, "full_lsq", night),
        device_id=device_id,
        beams=beams,
        cov=cov,
        method="full_lsq",
        scan_ids=tuple(scan_ids),
        raw_sha256=dict(raw_sha256 or {}),
        residual_rms_mm=float(np.sqrt(ssr / n_obs)),
        dof=dof,
        rank=rank,
        condition=cond,
        converged=converged,
        nuisance=nuisance,
        diagnostics={
            "gauge": (
                f"beta of channel {channels[0]} fixed at {beta1!r} rad and phase0 per scan fixed: "
                "a ring gauge "
                "determines only beta_c - beta_1, |offset| and beta_1 + phase0 - angle(offset) per scan"
            ),
            "n_obs": n_obs,
            "n_params": p_free,
            "n_params_all_free": p_free + 1 + K,
            "rank_all_free": rank_all,
            "nfev": int(sol.nfev),
            "cost": float(sol.cost),
            "singular_values_scaled": sv,
            "g_mm": g_hat,
            "u_g_mm": u_g,
            "g_note": "g = d_b + rho^2 / (2 R): the mean level the data fix best (R the gauge radius)",
            "weak_rho_channels": weak,
            "weak_rho_note": (
                "|rho| < 2 u(rho): rho is not distinguished from 0, d_b = g - rho^2/(2R) is then far from "
                "linear in the data and its linearised u understates the error"
            ),
            "param_names": _param_names(channels, scan_ids),
            "cov_free": cov_free,
        },
    )


def _param_names(channels: Sequence[int], scan_ids: Sequence[str]) -> list[str]:
    names = [f"beta_rad[{ch}]" for ch in channels[1:]]
    names += [f"rho_mm[{ch}]" for ch in channels] + [f"d_b_mm[{ch}]" for ch in channels]
    for s in scan_ids:
        names += [f"offset_x_mm[{s}]", f"offset_y_mm[{s}]", f"omega_rad_s[{s}]"]
    return names


def full_residuals(
    cal: TriCalibration, t_s, readings_mm, R_mm: float, scan_id: str | None = None
) -> np.ndarray:
    """Residuals (model - reading) (n, c) [mm] of a ``full_lsq`` calibration on one of its scans.

    Uses the scan's fitted offset, rotation rate and fixed phase from ``cal.nuisance``; NaN
    readings give NaN residuals.
    """
    if cal.method != "full_lsq":
        raise ValueError(f"full_residuals needs a full_lsq calibration, got {cal.method!r}")
    scan_id = scan_id if scan_id is not None else cal.scan_ids[0]
    nu = cal.nuisance[scan_id]
    t = np.asarray(t_s, dtype=float)
    phi = nu["phase0_rad"] + nu["omega_rad_s"] * t
    off = np.array([nu["offset_x_mm"], nu["offset_y_mm"]])
    model = tri_spindle_readings(phi, off, cal.beams, Bore((0.0, 0.0), R_mm))
    return model - np.asarray(readings_mm, dtype=float)
