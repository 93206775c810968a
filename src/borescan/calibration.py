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
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from borescan.atomic import json_ready
from borescan.config import schema_default
from borescan.fit import FitResult, fit_result, jacobian_summary
from borescan.geometry import (
    Beams,
    Bore,
    beam_frame,
    tri_spindle_readings,
    tri_spindle_readings_channel_major,
)
from borescan.kinematics import AngleModel, angle_model_from_arrays, estimate_speed_scale
from borescan.levmar import levenberg_marquardt
from borescan.mirror import (
    RESOLVED_DCHI2,
    BeamMirror,
    MirrorSolution,
    mirror_exists,
    offset_to_resolve_mm,
    predicted_depth,
    valid_bore_radius_range_mm,
)
from borescan.noise import noise_floor_mm
from borescan.physics.tri import first_harmonic_start

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
    "AcceptanceRule",
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
    fit : the least-squares :class:`borescan.fit.FitResult` in the fit's internal parameters
        (full_lsq; not serialised by :meth:`to_dict`, None after :meth:`from_dict`)
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
    fit: FitResult | None = field(default=None, compare=False, repr=False)

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
        return json_ready(
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
    """Return base length d_b and tangential radius r (Yang 2017, Eqs. 8, 10, 11).

    Return base length d_b and tangential radius r = |rho| from the extreme readings (Yang 2017, Eqs. 8,
    10, 11).

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
    _check_status(status2)  # beam 2's sign follows from s1 and whether the two agree (the four cases)
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
            channels,
            r,
            d_b,
            statuses,
            fs,
            samples_per_rev,
            R - oe,
            beta_ref_rad=beta_ref_rad,
            beta_nominal_rad=beta_nominal_rad,
            direction=direction,
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
        channels,
        np.abs(p0[1::3]),
        p0[2::3],
        statuses,
        nf,
        samples_per_rev,
        R_mm - oe_mm,
        beta_ref_rad=beta_ref_rad,
        beta_nominal_rad=beta_nominal_rad,
        direction=direction,
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


def _public_index(c: int, ch0_free: int) -> np.ndarray:
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


def _channel_offsets(tau_s, c: int) -> np.ndarray | None:
    """Per channel time offsets (c,) [s], None when absent or all zero."""
    if tau_s is None:
        return None
    tau = np.broadcast_to(np.asarray(tau_s, dtype=float), (c,)).copy()
    return None if not np.any(tau) else tau


def _readings_and_jacobian(
    phi: np.ndarray, beams: Beams, offset: np.ndarray, R: float
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Return the exact readings at device angles ``phi`` and their derivatives.

    Exact readings (n, c) at device angles ``phi`` (n,) (or per channel, (n, c) / (n, 1)) and
    their analytic derivatives, channel-major: each ``jac[...]`` is (c, n) (``.T`` is the (n, c) view).

    The wall point is P = o + Rot(phi)(F + s u) with the gauge centre at the origin; implicit
    differentiation of |P|^2 = R^2 gives ds/dp = -(P . dP/dp) / (P . Rot(phi) u).
    ``jac["phi"]`` is dv/dphi (the chain rule gives phase and speed-scale columns). Computed
    channel-major for numpy's long inner loops, as :func:`borescan.geometry.tri_spindle_readings`.
    """
    phi = np.asarray(phi, dtype=float)
    phi = phi[:, None] if phi.ndim == 1 else phi
    v_cn = tri_spindle_readings_channel_major(phi, offset, beams, Bore((0.0, 0.0), R))  # (c, n)
    s = v_cn + np.asarray(beams.d_b_mm, dtype=float)[:, None]
    F, u = beam_frame(beams.beta_rad, beams.rho_mm)  # (c, 2)
    n_vec = np.stack([-u[:, 1], u[:, 0]], axis=-1)
    cph, sph = np.ascontiguousarray(np.cos(phi).T), np.ascontiguousarray(np.sin(phi).T)  # (1 or c, n)

    def rot(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return cph * a[:, 0:1] - sph * a[:, 1:2], sph * a[:, 0:1] + cph * a[:, 1:2]

    dev_x, dev_y = F[:, 0:1] + s * u[:, 0:1], F[:, 1:2] + s * u[:, 1:2]  # device-frame wall points
    wx = cph * dev_x - sph * dev_y
    wy = sph * dev_x + cph * dev_y
    Px, Py = offset[0] + wx, offset[1] + wy
    ux, uy = rot(u)
    den = Px * ux + Py * uy
    nx, ny = rot(n_vec)
    rho = np.asarray(beams.rho_mm, dtype=float)[:, None]
    # dP/dbeta = Rot(phi)(-rho u + s n)
    dbx, dby = -rho * ux + s * nx, -rho * uy + s * ny
    jac = {
        "beta": -(Px * dbx + Py * dby) / den,
        "rho": -(Px * nx + Py * ny) / den,
        "ox": -Px / den,
        "oy": -Py / den,
        # dP/dphi = perp(Rot(phi)(F + s u)) = (-wy, wx)
        "phi": -(Px * (-wy) + Py * wx) / den,
    }
    return v_cn.T, jac


@dataclass(frozen=True)
class AcceptanceRule:
    """When a full-data calibration is trusted (``calibration`` section of the config).

    max_residual_to_noise : largest accepted ratio of a channel's residual rms to its readings'
        own white-noise floor (4th differences, model-free); under the model the ratio is
        1 within ~1 % for the scans of the contract, so 1.25 refuses no correct fit while an
        unmodelled effect of about 0.75 noise sigma rms is refused.
    head_radius_mm : |rho| of a beam cannot exceed the sensor head's radius [mm].
    position_accuracy_mm : the machine's stated accuracy of each coordinate of the scan's
        ``center`` and ``spindle.position``, a half-width (rectangular: standard uncertainty
        a / sqrt(3), GUM 4.3.7) [mm]; they enter the fit as priors.
    speed_scale_range : speeds the search considers, as multiples of the commanded profile.

    The defaults are the schema's (``calibration`` section): :meth:`from_config`, :meth:`defaults`.
    """

    max_residual_to_noise: float
    head_radius_mm: float
    position_accuracy_mm: float
    speed_scale_range: tuple[float, float]

    @classmethod
    def from_config(cls, cal_cfg: Mapping[str, Any]) -> "AcceptanceRule":
        """Return the rule of a config's ``calibration`` section."""
        return cls(
            max_residual_to_noise=float(cal_cfg["max_residual_to_noise"]),
            head_radius_mm=float(cal_cfg["head_radius_mm"]),
            position_accuracy_mm=float(cal_cfg["position_accuracy_mm"]),
            speed_scale_range=(float(cal_cfg["speed_scale_min"]), float(cal_cfg["speed_scale_max"])),
        )

    @classmethod
    def defaults(cls, **overrides: Any) -> "AcceptanceRule":
        """Return the rule of the schema's defaults, with ``overrides``."""
        return replace(cls.from_config(schema_default("calibration")), **overrides)


def fit_full_calibration(  # noqa: C901 (the 698-line full_lsq fit, to become a problem object of small functions)
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
    angle_models: Sequence[AngleModel] | None = None,
    range_mm=None,
    rule: AcceptanceRule | None = None,
    scan_ids: Sequence[str] | None = None,
    device_id: str = "",
    raw_sha256: dict[str, str] | None = None,
    night: str | None = None,
    max_nfev: int = 1000,
    cond_max: float = 1e10,
    channel_time_offsets_s=None,
) -> TriCalibration:
    """Least-squares calibration on every sample of one or more ring-gauge spindle scans.

    Model (spec "Spindle scan", exact via :func:`borescan.geometry.tri_spindle_readings`):
    v_c(t) = s - d_b_c with |o + Rot(phi(t))(F_c + s u_c)| = R, o = S - C (machine frame).
    The angle phi(t) comes from each scan's :class:`~borescan.kinematics.AngleModel`: the encoder
    angle itself, or phase + (1 + eps) Phi(t) with Phi the integral of the rpm profile (or
    rpm_nominal t). The Yang 2017 Eq. 8 relations hold at the extremes of this model.

    Unknowns: per channel beta, rho, d_b; per scan o (2), and with a commanded (not measured)
    angle the speed scale 1 + eps and the phase. A ring gauge is a circle, so the data fix
    beta_c + phi - angle(o) and |o| only. Hence:

    - a scan with ``center_xy_mm`` and ``spindle_xy_mm`` gives o a prior (each coordinate within
      +-``rule.position_accuracy_mm``, standard uncertainty that / sqrt(3)), which fixes angle(o);
    - with an encoder and such a prior the beams are absolute (beta of every channel free);
      otherwise beta of the first channel is held at ``nominal`` (the gauge freedom, said in
      ``diagnostics["gauge"]`` and ``diagnostics["beta_reference"]``);
    - a commanded angle's phase is free only where the prior fixes angle(o) (else it is held at
      ``phase0_rad``, the same gauge freedom).

    Starting values that cannot miss: the speed scale from the readings' spectrum over
    ``rule.speed_scale_range`` refined on the first-harmonic misfit; offset and levels from the
    linear first harmonic; the beams from the design. Internally beta + asin(rho / R) and
    d_b + rho^2 / (2 R) (the quantities the data fix best) are the fitted parameters, which
    straightens the valleys; then every beam's mirror solution (rho of opposite sign at the same
    first harmonic, a second minimum of nearly equal cost) is refitted on every sample and the
    lower cost kept (``diagnostics["mirror_solutions"]``; on long scans a screen on every step-th
    sample first sets aside the mirrors far above the kept cost or returning to it,
    :data:`MIRROR_SCREEN_READINGS`). rho enters the readings mostly through
    rho^2 (the first harmonic's amplitude |o| sqrt(1 + rho^2 / R^2)), so its cost valley can be
    skewed and curved, beta moving non-linearly with it: each rho's profile (every other parameter
    refitted) is checked at rho +- 2 u; where it is not the linear one it is walked out to
    Delta chi^2 = 12.5 and the likelihood-weighted spread of every parameter along it enters the
    covariance (``diagnostics["rho_profiles"]``); a lower cost found on the way is refitted and kept.
    Distinct minima (mirror starts, dips along a profile) are listed with 2 (cost - cost_kept) / s^2
    (``diagnostics["minima"]``, ``"n_minima"``, ``"ambiguous_minima"`` when one is within 4 s^2).
    Each beam's mirror check (``diagnostics["mirror_check"]``, :mod:`borescan.mirror`, issue 36): the
    depth N e^4 rho^2 / (2 sigma^2 R^4) next to the lowest minimum found with that beam's rho of the
    other sign; resolved (none, or >= 25 in chi^2): one value with u from its own curvature; flagged:
    two weighted solutions (refitted from the final solution's mirror, covariance from their own
    Jacobians), never folded into one u, and a non-linear profile of another beam along which the
    flagged rho changes sign adds nothing to that beam. u(d_b) of a linear
    profile includes the second-order term of d_b = g - rho^2 / (2R) (3 u(rho)^4 / (4 R^2)). Solved with
    :func:`borescan.levmar.levenberg_marquardt` (MINPACK's Levenberg-Marquardt on a LAPACK QR,
    analytic Jacobian). Covariance
    s^2 (J^T J)^-1, s^2 = SSR / dof.

    Censoring at the sensor range: the sensor nulls a reading whose noisy value leaves [0, range], so
    near a limit the valid readings are a truncated, biased sample. After the first solution, the
    valid readings whose fitted value lies within ``CENSOR_GUARD_SIGMA`` noise sigmas of a limit (or
    beyond it) are set aside and the fit is redone without them (:func:`_censoring_keep`,
    ``diagnostics["censoring_guard"]``); a limit beyond which the channel has valid readings is not
    treated as one.

    Acceptance (:class:`AcceptanceRule`): each channel's residual rms within
    ``max_residual_to_noise`` of its readings' own noise floor, |rho| within the head radius,
    d_b within what the gauge and the sensor range allow; otherwise ``CalibrationError`` with
    the reason.

    Parameters
    ----------
    t_s : (n,) or list of (n_k,) sample times per scan [s]
    readings_mm : (n, c) or list of (n_k, c), NaN = missing [mm]
    channels : channel numbers (c,), ascending; nominal : Beams, the design geometry (a start)
    R_mm : ring gauge radius at the scan's temperature [mm]
    spindle_xy_mm, center_xy_mm : per scan spindle axis and gauge centre (machine frame) or None
    rpm, direction, phase0_rad : without ``angle_models``: constant speed ``rpm`` per scan
    angle_models : per scan :class:`~borescan.kinematics.AngleModel` (overrides rpm/direction)
    range_mm : sensor range per channel (d_b plausibility), default 10 mm
    max_nfev, cond_max : iteration limit; largest acceptable condition number
    channel_time_offsets_s : (c,) per channel tau: its reading at stamp t is the geometry of time
        t - tau (a device model's carried ``channel_delay``); the angle of channel c is evaluated
        there. None: every channel at its stamp.

    Returns
    -------
    TriCalibration with method "full_lsq"

    Raises
    ------
    CalibrationError naming the scans when the fit does not converge, the Jacobian is rank
    deficient or worse conditioned than ``cond_max``, there are fewer samples than parameters,
    or the result fails the acceptance rule.
    """
    rule = rule or AcceptanceRule.defaults()
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
    if angle_models is None:
        rpms = np.broadcast_to(np.asarray(rpm, float), (K,))
        angle_models = [angle_model_from_arrays(rpm_nominal=float(r), direction=direction) for r in rpms]
    angle_models = list(angle_models)
    if len(angle_models) != K:
        raise ValueError("angle_models needs one entry per scan")
    phases0 = [float(x) for x in np.broadcast_to(np.asarray(phase0_rad, float), (K,))]
    Ss = _per_scan_xy(spindle_xy_mm, K)
    Cs = _per_scan_xy(center_xy_mm, K)
    priors = [None if (Ss[k] is None or Cs[k] is None) else Ss[k] - Cs[k] for k in range(K)]
    range_arr = np.broadcast_to(np.asarray(10.0 if range_mm is None else range_mm, float), (c,))
    masks = [np.isfinite(y) for y in ys]
    n_obs = int(sum(m.sum() for m in masks))
    Phis = [am.commanded_rad(t) for am, t in zip(angle_models, ts)]
    tau_c = _channel_offsets(channel_time_offsets_s, c)
    # the angle each reading belongs to: (n, 1) for every channel, (n, c) with carried channel delays
    Phis_c = [
        P[:, None] if tau_c is None else am.commanded_rad(t[:, None] - tau_c[None, :])
        for P, am, t in zip(Phis, angle_models, ts)
    ]
    commanded = [am.fits_speed_and_phase for am in angle_models]
    free_phase = [commanded[k] and priors[k] is not None for k in range(K)]
    absolute = any(am.source == "encoder" and priors[k] is not None for k, am in enumerate(angle_models))

    n_needed = 3 * c - 1 + int(absolute) + sum(2 + int(free_phase[k]) + int(commanded[k]) for k in range(K))
    n_prior_rows = 2 * sum(p is not None for p in priors)
    if n_obs + n_prior_rows <= n_needed:
        raise CalibrationError(scan_ids, f"{n_obs} valid samples for {n_needed} parameters")

    # ---- noise floor of the readings themselves (model-free), per scan and channel
    floors = np.array([noise_floor_mm(y, order=4) for y in ys])  # (K, c)
    sigma = float(np.sqrt(np.mean(floors**2))) if np.all(np.isfinite(floors)) else 0.0
    # the machine's stated accuracy is a half-width (rectangular, GUM 4.3.7: u = a / sqrt(3)) on each of
    # the centre and the spindle position, so o = S - C has u = a sqrt(2/3) per coordinate
    prior_w = (sigma if sigma > 0 else 1e-3) / (rule.position_accuracy_mm * np.sqrt(2.0 / 3.0))

    # ---- per scan: speed scale, offset, phase (starts)
    scales0, offsets0, phase_start = [], [], []
    kconst = np.zeros(c)
    for k in range(K):
        if commanded[k]:
            try:
                g = estimate_speed_scale(Phis[k], ys[k], scale_range=rule.speed_scale_range)
            except ValueError as exc:
                raise CalibrationError([scan_ids[k]], f"no rotation found in the readings: {exc}") from exc
            phi_k = g * Phis[k]
        else:
            g = 1.0
            phi_k = Phis[k]
        off, kc, _ = first_harmonic_start(phi_k, ys[k], masks[k], nominal.beta_rad)
        ph = phases0[k] if commanded[k] else 0.0
        if priors[k] is not None:
            if free_phase[k]:
                ph = float(np.arctan2(priors[k][1], priors[k][0]) - np.arctan2(off[1], off[0]))
            off = priors[k]
        elif commanded[k]:
            # phase held at phase0: the linear fit was made at phase 0, rotate its offset
            cph, sph = np.cos(ph), np.sin(ph)
            off = np.array([cph * off[0] - sph * off[1], sph * off[0] + cph * off[1]])
        scales0.append(g)
        offsets0.append(np.asarray(off, float))
        phase_start.append(ph)
        kconst += kc / K

    def phi_of(k: int, phase: float, scale: float) -> np.ndarray:
        return phase + scale * Phis_c[k] if commanded[k] else Phis_c[k]

    # ---- internal parameters: per channel psi = beta + asin(rho/R), rho, g = d_b + rho^2/(2R);
    # psi of the first channel only when the beams are absolute; per scan ox, oy, [phase], [scale]
    ch0_free = 1 if absolute else 0
    n_beam = 3 * c - 1 + ch0_free
    nuis_cols: list[dict[str, int]] = []
    col = n_beam
    for k in range(K):
        d = {"ox": col, "oy": col + 1}
        col += 2
        if free_phase[k]:
            d["phase"] = col
            col += 1
        if commanded[k]:
            d["scale"] = col
            col += 1
        nuis_cols.append(d)
    p_free = col
    internal_names = (
        [f"psi_{ch}_rad" for j, ch in enumerate(channels) if j > 0 or ch0_free]
        + [f"rho_{ch}_mm" for ch in channels]
        + [f"g_{ch}_mm" for ch in channels]
    )
    for k in range(K):
        internal_names += [f"{scan_ids[k]}.{name}" for name in nuis_cols[k]]
    n_prior = 2 * sum(p is not None for p in priors)
    if n_obs + n_prior <= p_free:
        raise CalibrationError(scan_ids, f"{n_obs} valid samples for {p_free} parameters")
    beta1_fixed = float(nominal.beta_rad[0])

    def split(x: np.ndarray):
        psi = x[: c - 1 + ch0_free]
        if not ch0_free:
            psi = np.concatenate([[np.nan], psi])
        rho = x[c - 1 + ch0_free : 2 * c - 1 + ch0_free]
        g = x[2 * c - 1 + ch0_free : n_beam]
        return psi, rho, g

    def unpack(x: np.ndarray):
        psi, rho, g = split(x)
        arc = np.arcsin(np.clip(rho / R_mm, -1.0, 1.0))
        beta = psi - arc
        if not ch0_free:
            beta[0] = beta1_fixed
        d_b = g - rho**2 / (2.0 * R_mm)
        beams = Beams(channels, beta, rho, d_b)
        nuis = []
        for k in range(K):
            cols = nuis_cols[k]
            nuis.append(
                (
                    np.array([x[cols["ox"]], x[cols["oy"]]]),
                    x[cols["phase"]] if "phase" in cols else phase_start[k],
                    x[cols["scale"]] if "scale" in cols else 1.0,
                )
            )
        return beams, nuis

    def pack(beams: Beams, nuis) -> np.ndarray:
        arc = np.arcsin(np.clip(beams.rho_mm / R_mm, -1.0, 1.0))
        psi = beams.beta_rad + arc
        x = np.zeros(p_free)
        x[: c - 1 + ch0_free] = psi if ch0_free else psi[1:]
        x[c - 1 + ch0_free : 2 * c - 1 + ch0_free] = beams.rho_mm
        x[2 * c - 1 + ch0_free : n_beam] = beams.d_b_mm + beams.rho_mm**2 / (2.0 * R_mm)
        for k in range(K):
            cols = nuis_cols[k]
            x[cols["ox"]], x[cols["oy"]] = nuis[k][0]
            if "phase" in cols:
                x[cols["phase"]] = nuis[k][1]
            if "scale" in cols:
                x[cols["scale"]] = nuis[k][2]
        return x

    def public(x: np.ndarray) -> np.ndarray:
        """Return internal free parameters -> public ones (beta for psi, d_b for g; the rest as they are)."""
        out = np.array(x, dtype=float, copy=True)
        psi, rho, g = split(x)
        for j in range(c):
            if j > 0 or ch0_free:
                out[j - 1 + ch0_free] = psi[j] - np.arcsin(np.clip(rho[j] / R_mm, -1.0, 1.0))
            out[2 * c - 1 + ch0_free + j] = g[j] - rho[j] ** 2 / (2.0 * R_mm)
        return out

    def model(  # noqa: C901 (part of the full_lsq fit, to be split into small functions)
        x: np.ndarray, with_jac: bool, full: bool = False, rows: list | None = None
    ):
        beams, nuis = unpack(x)
        rho = beams.rho_mm
        dbeta_drho = -1.0 / np.sqrt(np.maximum(R_mm**2 - rho**2, 1e-300))
        ncols = p_free + (1 + K if full else 0)
        res_parts, blocks = [], []
        for k in range(K):
            off, ph, sc = nuis[k]
            sel = slice(None) if rows is None else rows[k]
            t_phi = phi_of(k, ph, sc)[sel]
            if with_jac:
                v, jac = _readings_and_jacobian(t_phi, beams, off, R_mm)
                blocks.append((k, sel, jac))
            else:  # the readings alone (the same call _readings_and_jacobian makes)
                v = tri_spindle_readings(t_phi, off, beams, Bore((0.0, 0.0), R_mm))
            res_parts.append((v - ys[k][sel])[masks[k][sel]])
        for k in range(K):
            if priors[k] is not None:
                res_parts.append(prior_w * (nuis[k][0] - priors[k]))
        r = np.concatenate(res_parts)
        if not with_jac:
            return r
        # the Jacobian is filled column by column into its transpose (ncols, rows): returned as
        # J = JT.T, Fortran-ordered, the layout MINPACK works in (no reordering copy); rows in the
        # order of r (per scan the valid readings sample by sample, channel by channel; then priors)
        JT = np.zeros((ncols, r.size))
        b0 = 0
        for k, sel, jac in blocks:
            m = masks[k][sel]
            n_k = int(m.sum())
            at = (np.cumsum(m.ravel()) - 1).reshape(m.shape)  # row of each valid reading in the block
            rows_of = [b0 + at[m[:, j], j] for j in range(c)]
            for j in range(c):
                mj, rj = m[:, j], rows_of[j]
                if j > 0 or ch0_free:
                    JT[j - 1 + ch0_free, rj] = jac["beta"][j, mj]
                # d/drho at fixed psi and g: beta moves by -drho/sqrt(R^2-rho^2), d_b by -rho/R drho
                drho = jac["rho"][j, mj] + rho[j] / R_mm
                if j > 0 or ch0_free:
                    drho = drho + jac["beta"][j, mj] * dbeta_drho[j]
                JT[c - 1 + ch0_free + j, rj] = drho
                JT[2 * c - 1 + ch0_free + j, rj] = -1.0
            blk = slice(b0, b0 + n_k)
            cols = nuis_cols[k]
            JT[cols["ox"], blk] = jac["ox"].T[m]
            JT[cols["oy"], blk] = jac["oy"].T[m]
            dphi = jac["phi"].T[m]
            if "phase" in cols:
                JT[cols["phase"], blk] = dphi
            if "scale" in cols:
                JT[cols["scale"], blk] = (jac["phi"].T * Phis_c[k][sel])[m]
            if full:
                if not ch0_free:
                    JT[p_free, rows_of[0]] = jac["beta"][0, m[:, 0]]
                JT[p_free + 1 + k, blk] = dphi
            b0 += n_k
        for k in range(K):
            if priors[k] is not None:
                JT[nuis_cols[k]["ox"], b0] = prior_w
                JT[nuis_cols[k]["oy"], b0 + 1] = prior_w
                b0 += 2
        return r, JT.T

    # ---- start from the design geometry, then the mirror solutions: rho_c -> -rho_c at fixed psi and g
    # keeps the first harmonic and the mean level, so each beam has two minima of nearly equal cost
    # that only the second harmonic's phase tells apart (mirror_search below).
    d_b0 = np.sqrt(np.maximum(R_mm**2 - nominal.rho_mm**2, 0.0)) - kconst
    start_beams = Beams(channels, nominal.beta_rad.copy(), nominal.rho_mm.copy(), d_b0)
    x0 = pack(start_beams, [(offsets0[k], phase_start[k], scales0[k]) for k in range(K)])

    def solve(x_start: np.ndarray, rows=None, nfev: int = max_nfev):
        return levenberg_marquardt(
            lambda x: model(x, False, rows=rows),
            x_start,
            lambda x: model(x, True, rows=rows)[1],
            max_nfev=nfev,
            xtol=1e-10,
            ftol=1e-10,
            gtol=1e-10,
        )

    def solve_fixed(x_start: np.ndarray, i_fix: int, nfev: int = 30):
        """Minimum of the cost over every internal parameter but ``i_fix`` (held at ``x_start[i_fix]``)."""
        keep = np.arange(p_free) != i_fix
        base = np.array(x_start, dtype=float)

        def full(z: np.ndarray) -> np.ndarray:
            x = base.copy()
            x[keep] = z
            return x

        with np.errstate(all="ignore"):
            res = levenberg_marquardt(
                lambda z: model(full(z), False),
                base[keep],
                lambda z: model(full(z), True)[1].T[keep].T,
                max_nfev=nfev,
                xtol=1e-10,
                ftol=1e-10,
                gtol=1e-10,
                jac_at_solution=False,
            )
        return full(res.x), float(res.cost), bool(res.success) and bool(np.isfinite(res.cost))

    # long scans: each mirror start is first fitted on every step-th sample of each scan (the cost's
    # shape is the same, about 1/step of it); only a mirror the screen cannot set aside is refitted
    # on every sample (:data:`MIRROR_SCREEN_READINGS`, :data:`MIRROR_SCREEN_DCHI2`)
    step = max(1, n_obs // MIRROR_SCREEN_READINGS)
    screen = [slice(None, None, step)] * K if step > 1 else None

    def mirror_start(x: np.ndarray, j: int) -> np.ndarray:
        """Return the mirror of beam ``j`` (rho -> -rho at fixed psi and g).

        The gauge-fixed first beam's psi is not free: flipping its rho moves psi_1 by delta = -2 asin(rho_1 /
        R), and the readings depend on psi_c + phase - angle(o), so every other psi moves by delta too and
        each scan's frame turns by delta (its offset without a prior, else its free phase back by delta).
        """
        xf = np.array(x, dtype=float, copy=True)
        xf[i_rho0 + j] = -xf[i_rho0 + j]
        if j == 0 and not ch0_free:
            delta = -2.0 * float(np.arcsin(np.clip(x[i_rho0] / R_mm, -1.0, 1.0)))
            xf[: c - 1] += delta
            cd, sd = np.cos(delta), np.sin(delta)
            for k in range(K):
                cols = nuis_cols[k]
                if priors[k] is None:
                    ox, oy = x[cols["ox"]], x[cols["oy"]]
                    xf[cols["ox"]], xf[cols["oy"]] = cd * ox - sd * oy, sd * ox + cd * oy
                elif "phase" in cols:
                    xf[cols["phase"]] -= delta
        return xf

    def mirror_search(sol):
        """Refit from every beam's mirror (:func:`mirror_start`); keep the lowest cost."""
        tried, alts = [], []
        kept = None  # the kept solution refitted on the screen's samples, its s^2 and u of its rhos
        for j in range(c):
            xf = mirror_start(sol.x, j)
            if screen is not None:
                if kept is None:
                    with np.errstate(all="ignore"):
                        k_sub = solve(sol.x, rows=screen)
                    s2_full = 2.0 * float(sol.cost) / max(n_obs + n_prior - p_free, 1)
                    u_int = np.sqrt(np.diag(jacobian_summary(sol.jac).cov_unit) * s2_full)
                    kept = (k_sub, s2_full, u_int)
                k_sub, s2_full, u_int = kept
                with np.errstate(all="ignore"):
                    t_sub = solve(xf, rows=screen)
                if bool(t_sub.success) and np.isfinite(t_sub.cost) and np.isfinite(k_sub.cost):
                    # the mirror's cost above the kept one, scaled to every sample, in chi^2 units
                    d_est = 2.0 * step * float(t_sub.cost - k_sub.cost) / s2_full
                    u_sub = np.sqrt(
                        np.diag(jacobian_summary(t_sub.jac).cov_unit)
                        * 2.0
                        * float(t_sub.cost)
                        / max(n_obs // step + n_prior - p_free, 1)
                    )
                    same = bool(np.all(np.abs(t_sub.x - k_sub.x) <= 0.01 * u_sub))
                    rho_clear = abs(sol.x[i_rho0 + j]) > MIRROR_SCREEN_RHO_U * u_int[i_rho0 + j]
                    if d_est > MIRROR_SCREEN_DCHI2 or (same and rho_clear):
                        entry = {
                            "channel": int(channels[j]),
                            "cost_kept": float(sol.cost),
                            "mirror_taken": False,
                            "screened_every": int(step),
                        }
                        if same:
                            entry.update(cost_mirror=float(sol.cost), screen="returned to the kept minimum")
                            alts.append(None)
                        else:  # its cost on every sample estimated from the screen's (d_est chi^2 above)
                            cost_est = float(sol.cost) + 0.5 * d_est * s2_full
                            entry.update(
                                cost_mirror=cost_est, screen=f"{d_est:.0f} s^2 above the kept minimum"
                            )
                            alts.append(_Screened(x=t_sub.x, cost=cost_est))
                        tried.append(entry)
                        continue
            with np.errstate(all="ignore"):
                trial = solve(xf)  # from the flipped start, as without a screen (the screen's solution can
                # sit in a flat valley of a weak rho where LM on every sample crawls: 1000 evaluations seen)
            fine = bool(trial.success) and bool(np.isfinite(trial.cost))
            better = fine and trial.cost < sol.cost
            tried.append(
                {
                    "channel": int(channels[j]),
                    "cost_kept": float(sol.cost),
                    "cost_mirror": float(trial.cost),
                    "mirror_taken": better,
                }
            )
            alts.append((sol if better else trial) if fine else None)
            if better:
                sol = trial
                kept = None
        return sol, tried, alts

    i_rho0 = c - 1 + ch0_free
    censored: dict[str, list[int]] = {}
    try:
        sol = solve(x0)
        mirrors_tried, alternatives = [], []
        if bool(sol.success) and np.isfinite(sol.cost):
            # A sensor nulls a reading whose *noisy* value leaves its range, so a valid reading whose
            # true value lies within a few sigma of a range limit is a censored draw: its noise is biased
            # away from the limit (E[e | kept] = sigma phi(a) / Phi(a), a = distance / sigma), which biases
            # every beam parameter the flank near the limit informs. Readings whose fitted value lies within
            # CENSOR_GUARD_SIGMA of a limit (or beyond it) are set aside: a selection on the model, not on
            # the noise, so the rest is an unbiased sample; then the fit is redone on the rest.
            beams_1, nuis_1 = unpack(sol.x)
            for k in range(K):
                off, ph, sc = nuis_1[k]
                v_k = tri_spindle_readings(phi_of(k, ph, sc), off, beams_1, Bore((0.0, 0.0), R_mm))
                keep, _ = _censoring_keep(v_k, ys[k], range_arr, _guard_sigma(floors[k], sigma))
                drop = masks[k] & ~keep
                censored[scan_ids[k]] = [int(x) for x in drop.sum(axis=0)]
                masks[k] = masks[k] & keep
            if any(sum(v) for v in censored.values()):
                n_obs = int(sum(m.sum() for m in masks))
                if n_obs + n_prior <= p_free:
                    raise CalibrationError(
                        scan_ids,
                        f"{n_obs} valid samples (away from the sensor range limits) for {p_free} parameters",
                    )
                with np.errstate(all="ignore"):
                    sol = solve(sol.x)
            sol, mirrors_tried, alternatives = mirror_search(sol)
        profiles: list[dict] = []
        for _round in range(3):
            r, J = np.asarray(sol.fun), np.asarray(sol.jac)  # at sol.x (levenberg_marquardt returns both)
            converged = bool(sol.success) and bool(np.all(np.isfinite(r)))
            if not converged:
                raise CalibrationError(
                    scan_ids, f"full_lsq did not converge after {sol.nfev} evaluations ({sol.message})"
                )
            fit = fit_result(
                internal_names, sol.x, r, J, success=converged, message=str(sol.message), nfev=int(sol.nfev)
            )
            rank, cond = fit.rank, fit.condition
            if rank < p_free or cond > cond_max:
                raise CalibrationError(
                    scan_ids,
                    f"full_lsq Jacobian rank {rank} of {p_free}, condition {cond:.3g} (limit "
                    f"{cond_max:.3g}); "
                    "the data do not determine the parameters (is the spindle offset from the gauge centre?)",
                )
            s2 = fit.sigma**2
            cov_int = fit.cov
            rho_hat = unpack(sol.x)[0].rho_mm
            # Jacobian of the public free parameters (beta free, rho, d_b, nuisance) w.r.t. internal ones
            cov_free = _public_cov(sol.x, cov_int, c, ch0_free, R_mm)
            # the linearisation, checked along each rho: rho enters the readings mostly through rho^2
            # (the first harmonic's amplitude |o| sqrt(1 + rho^2/R^2)), so its cost valley can be
            # skewed and curved (beta and the other rhos move non-linearly with it)
            profiles, lower = [], None
            for j in range(c):
                prof, lower = _rho_profile(
                    j,
                    c,
                    sol.x,
                    float(sol.cost),
                    s2,
                    cov_int,
                    cov_free,
                    solve_fixed,
                    public,
                    i_rho0 + j,
                    rule.head_radius_mm,
                )
                prof["channel"] = int(channels[j])
                profiles.append(prof)
                if lower is not None:
                    break
            if lower is None:
                break
            # a lower cost along a profile: the optimizer had stopped short of the minimum
            with np.errstate(all="ignore"):
                trial = solve(lower)
            if not (bool(trial.success) and np.isfinite(trial.cost) and trial.cost < sol.cost):
                break
            sol, more, alts = mirror_search(trial)
            mirrors_tried, alternatives = mirrors_tried + more, alternatives + alts
    except (ValueError, FloatingPointError) as exc:  # NaN readings from a diverging step
        raise CalibrationError(scan_ids, f"full_lsq fit failed: {exc}") from exc
    n_rows = n_obs + n_prior
    dof = n_rows - p_free
    ssr_readings = float(r[:n_obs] @ r[:n_obs])
    _, Jf = model(sol.x, True, full=True)
    cf = np.linalg.norm(Jf, axis=0)
    cf[cf == 0] = 1.0
    svf = np.linalg.svd(Jf / cf, compute_uv=False)
    rank_all = int(np.sum(svf > svf[0] * max(Jf.shape) * np.finfo(float).eps * 1e3))
    beams, nuis = unpack(sol.x)
    rho_hat = beams.rho_mm
    p_hat = public(sol.x)
    # Where the profile of a rho is not the linear prediction, the spread of every parameter along
    # it (likelihood-weighted second moment about the estimate) replaces the linear part along that
    # rho wherever it is larger (PSD part of the difference: never smaller than the linear covariance)
    u2_rho = np.diag(cov_free)[i_rho0 : i_rho0 + c].copy()
    idx = _public_index(c, ch0_free)
    ok = idx >= 0

    def params_of(v: np.ndarray) -> np.ndarray:
        out = np.zeros(v.shape[:-1] + (3 * c,))
        out[..., ok] = v[..., idx[ok]]
        return out

    # ---- the mirror check of every beam (issue 36): Eq. (1) of borescan.mirror next to the explicit refit
    # from -rho; a flagged beam (a mirror within RESOLVED_DCHI2) is carried as two weighted solutions
    checks = _mirror_checks(
        sol,
        s2,
        mirrors_tried,
        alternatives,
        cov_free,
        p_hat,
        rho_hat,
        nuis,
        masks,
        floors,
        channels,
        R_mm,
        i_rho0=i_rho0,
        refit=lambda j: solve(mirror_start(sol.x, j)),
        public=public,
        params_of=params_of,
        public_cov=lambda x, C: _public_cov(x, C, c, ch0_free, R_mm),
    )
    flagged = {j for j, m in enumerate(checks) if not m.resolved}
    extra = np.zeros_like(cov_free)
    for j, prof in enumerate(profiles):
        M = prof.pop("_second_moment", None)
        P, wts = prof.pop("_points", (None, None))
        if M is None:
            continue
        if (
            j in flagged
        ):  # a flagged beam's profile walks into its mirror's valley: the two solutions carry it
            prof["not_used"] = "the sign of this rho is not resolved: two solutions instead of one spread"
            continue
        crossed = [
            int(channels[f])
            for f in sorted(flagged)
            if np.any(np.sign(p_hat[i_rho0 + f] + P[:, i_rho0 + f]) != np.sign(p_hat[i_rho0 + f]))
        ]
        if crossed:  # refitted along this rho, a flagged beam went over to its mirror: that is its two
            # solutions' spread, not this beam's own curvature
            prof["not_used"] = f"along this profile the flagged rho of channel(s) {crossed} changed sign"
            continue
        i = i_rho0 + j
        E = M - np.outer(cov_free[:, i], cov_free[:, i]) / cov_free[i, i]
        w, V = np.linalg.eigh(0.5 * (E + E.T))
        E_psd = (V * np.clip(w, 0.0, None)) @ V.T
        extra += E_psd
        prof["u_rho_profile_mm"] = float(np.sqrt(M[i, i]))
        # what a quantity computed from the beams needs to map this spread by itself (a secant per
        # point, not the linear sensitivities): the points, their weights, the linear covariance's column
        # of this rho and the extra covariance this profile adds, all in the calibration's parameter order
        prof["points"] = {
            "delta_params": params_of(P).tolist(),
            "weight": [float(x) for x in wts / wts.sum()],
        }
        prof["linear_cov_column"] = params_of(cov_free[:, i]).tolist()
        prof["extra_cov_params"] = params_of(params_of(E_psd).T).tolist()
    cov_free = cov_free + extra
    # d_b = g - rho^2 / (2R) is quadratic in rho: with rho ~ N(rho_hat, u^2) the linear term above
    # misses var(rho^2) = 2 u^4 and the bias E[rho_hat^2] - rho^2 = u^2; both are added to u(d_b)^2
    # as 3 u^4 / (4 R^2) where the rho profile was linear (else the profile's spread holds them)
    for j, prof in enumerate(profiles):
        if prof["linear"]:
            i_g = 2 * c - 1 + ch0_free + j
            cov_free[i_g, i_g] += 3.0 * u2_rho[j] ** 2 / (4.0 * R_mm**2)
    # Distinct minima from the mirror starts (and dips along the profiles), each with its
    # Delta = 2 (cost - cost_kept) / s^2 and whether the profile of every rho it moves already spans it;
    # they are reported, not added to the covariance (see below).
    minima, seen = [], [p_hat]
    u_pub = np.sqrt(np.clip(np.diag(cov_free), 0.0, None))
    u_pub[u_pub == 0] = 1.0
    for entry, alt in zip(mirrors_tried, alternatives):
        if alt is None:
            continue
        d_chi2 = 2.0 * (alt.cost - sol.cost) / s2
        entry["delta_ssr_over_s2"] = float(d_chi2)
        entry["within_noise"] = bool(d_chi2 < 4.0)
        p_alt = public(alt.x)
        if any(np.max(np.abs(p_alt - q) / u_pub) < 0.1 for q in seen):
            continue
        seen.append(p_alt)
        minima.append(
            {
                "source": f"mirror start of channel {entry['channel']}",
                "rho_mm": [float(x) for x in p_alt[i_rho0 : i_rho0 + c]],
                "delta_ssr_over_s2": float(d_chi2),
                "_p": p_alt,
            }
        )
    for prof in profiles:
        for dip in prof.get("profile_minima", []):
            minima.append(
                {
                    "source": f"profile of rho of channel {prof['channel']}",
                    "rho_mm": dip["rho_mm"],
                    "delta_ssr_over_s2": dip["delta_ssr_over_s2"],
                    "_p": None,
                }
            )
    for m in minima:
        p_alt = m.pop("_p")
        if p_alt is None:
            continue
        # spanned: every rho in which the minimum differs from the estimate (by more than 2 u) lies on its
        # own channel's walked profile, whose spread the covariance holds already (a profile of another
        # channel that merely contains this minimum's value of its own rho says nothing about it)
        moved = [j for j in range(c) if abs(p_alt[i_rho0 + j] - p_hat[i_rho0 + j]) > 2.0 * u_pub[i_rho0 + j]]
        spanned = bool(moved) and all(
            (not profiles[j]["linear"])
            and profiles[j]["rho_range_mm"][0] <= p_alt[i_rho0 + j] <= profiles[j]["rho_range_mm"][1]
            for j in moved
        )
        m["spanned_by_profile"] = bool(spanned)
        # not added to the covariance: a mirror within RESOLVED_DCHI2 is the flagged beam's second solution
        # (diagnostics["mirror_check"]), one further away weighs less than exp(-12.5)
    ambiguous = [m for m in minima if m["delta_ssr_over_s2"] < 4.0]
    cov = np.zeros((3 * c, 3 * c))
    cov[np.ix_(ok, ok)] = cov_free[np.ix_(idx[ok], idx[ok])]
    u_rho = np.sqrt(np.diag(cov_free)[c - 1 + ch0_free : 2 * c - 1 + ch0_free])
    g_hat = sol.x[2 * c - 1 + ch0_free : n_beam]
    u_g = np.sqrt(np.diag(cov_int)[2 * c - 1 + ch0_free : n_beam])
    weak = [int(ch) for ch, r_, u_ in zip(channels, rho_hat, u_rho) if abs(r_) < 2.0 * u_]

    # ---- per scan figures and the acceptance rule
    nuisance = {}
    bounds = np.concatenate([[0], np.cumsum([int(m.sum()) for m in masks])])
    ratios = np.zeros((K, c))
    for k in range(K):
        off, ph, sc = nuis[k]
        cols = nuis_cols[k]
        res_k = np.full(ys[k].shape, np.nan)
        res_k[masks[k]] = r[bounds[k] : bounds[k + 1]]
        rms_ch = np.sqrt(np.nanmean(res_k**2, axis=0))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios[k] = np.where(floors[k] > 0, rms_ch / floors[k], np.inf)
        am = angle_models[k]
        entry = {
            "offset_x_mm": float(off[0]),
            "offset_y_mm": float(off[1]),
            "oe_mm": float(np.hypot(*off)),
            "u_offset_x_mm": float(np.sqrt(cov_free[cols["ox"], cols["ox"]])),
            "u_offset_y_mm": float(np.sqrt(cov_free[cols["oy"], cols["oy"]])),
            "angle_source": am.source,
            "phase0_rad": float(ph),
            "phase_free": bool(free_phase[k]),
            "speed_scale": float(sc),
            "u_speed_scale": float(np.sqrt(cov_free[cols["scale"], cols["scale"]]))
            if "scale" in cols
            else 0.0,
            "omega_rad_s": float(sc * am.mean_omega_rad_s()),
            "residual_rms_mm": float(np.sqrt(np.mean(r[bounds[k] : bounds[k + 1]] ** 2))),
            "noise_floor_mm": [float(f) for f in floors[k]],
            "residual_to_noise": [float(x) for x in ratios[k]],
        }
        entry["u_omega_rad_s"] = float(abs(entry["u_speed_scale"] * am.mean_omega_rad_s()))
        entry["rpm"] = float(abs(entry["omega_rad_s"]) * 60.0 / (2.0 * np.pi))
        if "phase" in cols:
            entry["u_phase0_rad"] = float(np.sqrt(cov_free[cols["phase"], cols["phase"]]))
        nuisance[scan_ids[k]] = entry
    problems = _acceptance_problems(beams, nuis, ratios, scan_ids, channels, R_mm, range_arr, rule)
    if problems:
        raise CalibrationError(scan_ids, "calibration refused: " + "; ".join(problems))
    ref = "absolute" if absolute else f"channel {channels[0]} fixed"
    gauge = (
        "beams absolute in the encoder frame: the scan's centre and spindle position fix the offset direction"
        if absolute
        else f"beta of channel {channels[0]} held at the design value {beta1_fixed!r} rad: a ring gauge "
        "fixes only "
        "beta_c - beta_1, |offset| and beta_1 + phase - angle(offset) per scan, and no scan has both "
        "an encoder "
        "angle and a known centre and spindle position"
    )
    return TriCalibration(
        calibration_id=make_calibration_id(device_id, scan_ids, "full_lsq", night),
        device_id=device_id,
        beams=beams,
        cov=cov,
        method="full_lsq",
        scan_ids=tuple(scan_ids),
        raw_sha256=dict(raw_sha256 or {}),
        residual_rms_mm=float(np.sqrt(ssr_readings / n_obs)),
        dof=dof,
        rank=rank,
        condition=cond,
        converged=converged,
        nuisance=nuisance,
        fit=fit,
        diagnostics={
            **({} if tau_c is None else {"channel_time_offsets_s": [float(x) for x in tau_c]}),
            "gauge": gauge,
            "beta_reference": ref,
            "n_obs": n_obs,
            "n_prior_rows": n_prior,
            "n_params": p_free,
            "n_params_all_free": p_free + (0 if ch0_free else 1) + K,
            "rank_all_free": rank_all,
            "nfev": int(sol.nfev),
            "cost": float(sol.cost),
            "singular_values_scaled": fit.extra["singular_values"],
            "g_mm": g_hat,
            "u_g_mm": u_g,
            "g_note": "g = d_b + rho^2 / (2 R): the mean level the data fix best (R the gauge radius)",
            "weak_rho_channels": weak,
            "mirror_solutions": mirrors_tried,
            "mirror_check": [m.to_dict() for m in checks],
            "mirror_note": (
                "per beam: the mirror's depth predicted by N e^4 "
                "rho^2 / (2 sigma^2 R^4) and refitted from -rho; "
                "resolved (no mirror, or delta chi^2 >= "
                f"{RESOLVED_DCHI2:g}): one value, u from its own curvature; "
                "flagged: two solutions with covariance, delta chi^2 "
                "and weight, the probability of the wrong sign, "
                "the bore range where the calibration may be used "
                "and the spindle offset that would resolve it"
            ),
            "n_minima": 1 + len(minima),
            "minima": minima,
            "ambiguous_minima": bool(ambiguous),
            "minima_note": (
                "distinct minima of SSR + prior besides the one kept "
                "(mirror starts, dips along the rho profiles), "
                "delta_ssr_over_s2 = 2 (cost - cost_kept) / s^2; "
                "below 4 the data cannot reject it (ambiguous); "
                "not in the covariance: a beam whose rho sign such "
                "a minimum flips is flagged in mirror_check and "
                "carried as two weighted solutions"
            ),
            "rho_profiles": profiles,
            "rho_profile_note": (
                "per channel the cost profiled along rho (every other parameter refitted): linear when "
                "at rho +- 2 u "
                "it rises by 4 +- 1 s^2 and bends no parameter by more than u / 2; otherwise the "
                "likelihood-weighted "
                "spread of every parameter along the profile enters the covariance"
            ),
            "weak_rho_note": (
                "|rho| < 2 u(rho): rho is not distinguished from 0; d_b = g - rho^2/(2R) is then far from "
                "linear in the data, and u(d_b) carries the second-order term 3 u(rho)^4 / (4 R^2)"
            ),
            "acceptance": {
                "max_residual_to_noise": rule.max_residual_to_noise,
                "residual_to_noise_max": float(np.max(ratios)),
                "head_radius_mm": rule.head_radius_mm,
                "position_accuracy_mm": rule.position_accuracy_mm,
            },
            "param_names": _param_names(channels, scan_ids, ch0_free, nuis_cols),
            "cov_free": cov_free,
            "censoring_guard": {
                "k_sigma": CENSOR_GUARD_SIGMA,
                "range_mm": [float(x) for x in range_arr],
                "set_aside": censored,
                "note": (
                    "valid readings whose fitted value lies within k_sigma noise sigmas of a sensor "
                    "range limit "
                    "(0 or range_mm) or beyond it, per scan and channel: the sensor nulls a reading on "
                    "its noisy "
                    "value, so near a limit the valid ones are a truncated (biased) sample; not fitted"
                ),
            },
        },
    )


def _public_cov(x: np.ndarray, cov_int: np.ndarray, c: int, ch0_free: int, R_mm: float) -> np.ndarray:
    """Return the covariance of the public free parameters from the internal one.

    The public parameters are (beta, rho, d_b, nuisance), the internal ones (psi, rho, g, nuisance) at the
    internal vector ``x``: beta = psi - asin(rho / R), d_b = g - rho^2 / (2R).
    """
    i_rho0 = c - 1 + ch0_free
    rho = np.asarray(x[i_rho0 : i_rho0 + c], dtype=float)
    A = np.eye(cov_int.shape[0])
    for j in range(c):
        A[2 * c - 1 + ch0_free + j, i_rho0 + j] = -rho[j] / R_mm
        if j > 0 or ch0_free:
            A[j - 1 + ch0_free, i_rho0 + j] = -1.0 / np.sqrt(R_mm**2 - rho[j] ** 2)
    return A @ cov_int @ A.T


def _mirror_checks(
    sol,
    s2,
    tried,
    alternatives,
    cov_free,
    p_hat,
    rho_hat,
    nuis,
    masks,
    floors,
    channels,
    R_mm,
    *,
    i_rho0,
    refit,
    public,
    params_of,
    public_cov,
) -> list[BeamMirror]:
    """One :class:`borescan.mirror.BeamMirror` per channel (:func:`fit_full_calibration`).

    Every minimum of the mirror search (from any beam's start; delta chi^2 = 2 (cost - cost_kept) / s^2)
    is a candidate mirror of each beam whose rho it has of the other sign; the lowest is the beam's. No
    mirror: no such minimum (the refits returned to the kept solution, within 0.1 u of every parameter,
    or kept the sign). A beam whose mirror lies within :data:`borescan.mirror.RESOLVED_DCHI2` is refitted
    once more from the final solution's mirror (``refit(j)``); that refit, or the candidate where it is
    lower, is its second solution, with covariance from its own Jacobian. Weights exp(-delta chi^2 / 2)
    over the kept solution and this beam's mirror. (``tried`` is the search's log, aligned with
    ``alternatives``.)
    """
    u_pub = np.sqrt(np.clip(np.diag(cov_free), 0.0, None))
    u_pub[u_pub == 0] = 1.0
    # every minimum the search found (from any beam's mirror start) counts for each beam whose rho sign it
    # flips: the lowest of them is that beam's mirror candidate
    best: dict[int, tuple[float, Any]] = {}
    for alt in alternatives:
        if alt is None or not np.isfinite(alt.cost):
            continue
        p_alt = public(alt.x)
        if bool(np.max(np.abs(p_alt - p_hat) / u_pub) < 0.1):
            continue
        d_alt = max(2.0 * (float(alt.cost) - float(sol.cost)) / s2, 0.0)
        for j in range(len(channels)):
            if np.sign(p_alt[i_rho0 + j]) != np.sign(rho_hat[j]) and d_alt < best.get(j, (np.inf, None))[0]:
                best[j] = (d_alt, alt)
    e_k = np.array([float(np.hypot(*n[0])) for n in nuis])
    out = []
    for j, ch in enumerate(channels):
        n_k = np.array([int(m[:, j].sum()) for m in masks])
        sig_k = np.asarray(floors, float)[:, j]
        rho = float(rho_hat[j])
        pred = predicted_depth(n_k, e_k, rho, sig_k, R_mm)
        sigma = float(np.sqrt(np.sum(n_k * sig_k**2) / max(n_k.sum(), 1)))
        x_fix = offset_to_resolve_mm(R_mm, sigma, float(n_k.sum()), rho)
        d_chi2, cand = best.get(j, (None, None))
        common = dict(
            channel=int(ch),
            rho_mm=rho,
            offset_mm=float(np.max(e_k)),
            mirror_possible=mirror_exists(rho, e_k),
            predicted_delta_chi2=pred,
            offset_to_resolve_mm=x_fix,
        )
        if d_chi2 is not None and d_chi2 < RESOLVED_DCHI2:
            with np.errstate(all="ignore"):
                trial = refit(j)
            ok = (
                bool(trial.success)
                and np.isfinite(trial.cost)
                and np.sign(public(trial.x)[i_rho0 + j]) != np.sign(rho)
            )
            if not ok or (hasattr(cand, "jac") and cand.cost < trial.cost):
                trial = cand  # another start found this beam's other sign lower than its own refit
            p_alt = public(trial.x) if hasattr(trial, "jac") else None
            if p_alt is not None and np.sign(p_alt[i_rho0 + j]) != np.sign(rho):
                d_chi2 = max(2.0 * (float(trial.cost) - float(sol.cost)) / s2, 0.0)
                fr = fit_result(
                    [f"p{i}" for i in range(trial.x.size)],
                    trial.x,
                    np.asarray(trial.fun),
                    np.asarray(trial.jac),
                    success=True,
                )
                cov_alt = params_of(params_of(public_cov(trial.x, fr.cov)).T)
                w_alt = float(np.exp(-0.5 * d_chi2))
                w_main = 1.0 / (1.0 + w_alt)
                pa, pm = params_of(p_alt), params_of(p_hat)
                # the beam's direction uncertainty (a gauge-fixed beta: the smallest of the other beams')
                u_b = np.sqrt(np.clip(np.diag(params_of(params_of(cov_free).T))[0::3], 0.0, None))
                u_beta = float(u_b[j]) if u_b[j] > 0 else float(np.min(u_b[u_b > 0], initial=np.inf))
                lo, hi = valid_bore_radius_range_mm(R_mm, pm, pa, u_beta)
                out.append(
                    BeamMirror(
                        **common,
                        refit_delta_chi2=d_chi2,
                        resolved=False,
                        weight_main=w_main,
                        p_wrong_sign=1.0 - w_main,
                        alternative=MirrorSolution(
                            tuple(float(v) for v in pa),
                            tuple(tuple(float(v) for v in row) for row in cov_alt),
                            d_chi2,
                            1.0 - w_main,
                        ),
                        rho_alt_mm=float(pa[3 * j + 1]),
                        valid_bore_diameter_mm=(2.0 * lo, 2.0 * hi),
                    )
                )
                continue
            d_chi2 = None if p_alt is None or np.sign(p_alt[i_rho0 + j]) == np.sign(rho) else d_chi2
        out.append(
            BeamMirror(**common, refit_delta_chi2=d_chi2, resolved=True, weight_main=1.0, p_wrong_sign=0.0)
        )
    return out


#: the mirror search on long scans (:func:`fit_full_calibration`): with more than twice this many valid
#: readings each mirror start is first fitted on every step-th sample (step = n_obs // this); a mirror
#: whose screened cost, scaled to every sample, lies more than MIRROR_SCREEN_DCHI2 s^2 above the kept
#: minimum's (its weight exp(-Delta/2) is nil; the scaled estimate's standard deviation is
#: sqrt(4 step Delta), 20 s^2 at Delta = 12.5, step 8), or that returns to the kept minimum while that
#: beam's rho lies more than MIRROR_SCREEN_RHO_U of its u from 0, is not refitted on every sample
MIRROR_SCREEN_READINGS = 50_000
MIRROR_SCREEN_DCHI2 = 200.0
MIRROR_SCREEN_RHO_U = 10.0


@dataclass(frozen=True)
class _Screened:
    """A mirror minimum set aside by the screen: its parameters there and its estimated full cost."""

    x: np.ndarray
    cost: float


#: the linearisation check of a rho: at rho_hat +- 2 u the profile's Delta chi^2 must lie within
#: 4 +- 1 (its width within ~12 % of the linear one) and every parameter within half its u of the
#: linear prediction; otherwise the profile is walked out to Delta chi^2 = 12.5 (weights below 0.2 %)
_PROFILE_CHECK_DCHI2 = 1.0
_PROFILE_CHECK_BEND = 0.5
_PROFILE_END_DCHI2 = 12.5
_PROFILE_MAX_STEPS = 14


def _rho_profile(  # noqa: C901 (part of the full_lsq fit, to be split into small functions)
    j, c, x_hat, cost0, s2, cov_int, cov_free, solve_fixed, public, i, head_radius_mm
):
    """Profile of the full-data cost along rho of channel index ``j`` (internal and public index ``i``).

    Each point holds rho at a value and minimises the cost over every other parameter
    (``solve_fixed``, warm-started from the neighbour plus the linear regression on rho);
    Delta = 2 (cost - cost0) / s^2 is the profile likelihood ratio in chi^2 units.

    Returns (dict, lower): the dict has ``linear`` (the check at +-2 u passed), the check's Delta
    values, and when not linear the walked ``rho_range_mm``, ``n_points``, ``profile_minima``
    (local minima along the walk other than the estimate) and ``_second_moment``, the
    likelihood-weighted second moment of the public parameters about the estimate (trapezoid
    rule in rho, weights exp(-Delta/2)). ``lower`` is an internal vector of lower cost than
    ``x_hat`` when the profile found one (the fit had not reached the minimum), else None.
    """
    u = float(np.sqrt(cov_free[i, i]))
    p0 = public(x_hat)
    u_pub = np.sqrt(np.clip(np.diag(cov_free), 0.0, None))
    b_int = cov_int[:, i] / cov_int[i, i]
    b_pub = cov_free[:, i] / cov_free[i, i]
    rho0 = float(x_hat[i])
    tol = -0.01  # a profile point lower than the estimate by more than 0.01 s^2 is a lower minimum

    def at(delta: float, x_from: np.ndarray):
        xs = x_from + b_int * (delta - (x_from[i] - rho0))
        xs[i] = rho0 + delta
        x, cost, ok = solve_fixed(xs, i)
        return x, 2.0 * (cost - cost0) / s2, ok

    out: dict = {"u_rho_linear_mm": u, "linear": True}
    pts = {0.0: (x_hat, 0.0)}
    checks = []
    for k in (-2.0, 2.0):
        if abs(rho0 + k * u) >= head_radius_mm:
            out["linear"] = False
            continue
        x, d, ok = at(k * u, x_hat)
        if not ok:
            out["linear"] = False
            continue
        if d < tol:
            return out, x
        pts[k * u] = (x, d)
        checks.append(d)
        dev = public(x) - p0 - b_pub * k * u
        bend = np.abs(dev) / np.where(u_pub > 0, u_pub, np.inf)
        if abs(d - 4.0) > _PROFILE_CHECK_DCHI2 or float(np.max(bend)) > _PROFILE_CHECK_BEND:
            out["linear"] = False
    out["check_delta_ssr_over_s2"] = [float(d) for d in checks]
    if out["linear"]:
        return out, None
    for sgn in (-1.0, 1.0):
        side = sorted((dl for dl in pts if dl * sgn > 0), key=abs)
        delta = side[-1] if side else 0.0
        x_prev, d_prev = pts[delta]
        step = u
        for _ in range(_PROFILE_MAX_STEPS):
            if d_prev > _PROFILE_END_DCHI2:
                break
            new = delta + sgn * step
            if abs(rho0 + new) >= head_radius_mm:
                break
            x, d, ok = at(new, x_prev)
            if not ok:
                break
            if d < tol:
                return out, x
            pts[new] = (x, d)
            if d - d_prev < 1.0:  # a flat stretch: widen the step
                step *= 2.0
            delta, x_prev, d_prev = new, x, d
    deltas = np.array(sorted(pts))
    dchi = np.array([pts[dl][1] for dl in deltas])
    out["rho_range_mm"] = [float(rho0 + deltas[0]), float(rho0 + deltas[-1])]
    out["n_points"] = int(deltas.size)
    if deltas.size < 3 or deltas[0] >= 0.0 or deltas[-1] <= 0.0:
        # no refit converged on one side: the linear covariance stays, and the diagnostics say so
        out["profile_failed"] = True
        return out, None
    P = np.array([public(pts[dl][0]) - p0 for dl in deltas])
    wts = np.exp(-0.5 * np.clip(dchi, 0.0, None))
    # trapezoid weights in rho
    h = np.diff(deltas)
    tw = np.zeros(deltas.size)
    tw[:-1] += h / 2.0
    tw[1:] += h / 2.0
    wts = wts * tw
    out["_second_moment"] = (P * wts[:, None]).T @ P / wts.sum()
    out["_points"] = (P, wts)
    out["delta_ssr_over_s2_at_ends"] = [float(dchi[0]), float(dchi[-1])]
    out["profile_minima"] = [
        {
            "rho_mm": [float(v) for v in public(pts[deltas[k]][0])[i - j : i - j + c]],
            "delta_ssr_over_s2": float(dchi[k]),
        }
        for k in range(1, deltas.size - 1)
        if deltas[k] != 0.0 and dchi[k] < dchi[k - 1] and dchi[k] < dchi[k + 1]
    ]
    return out, None


#: readings whose fitted value lies within this many noise sigmas of a sensor range limit are set aside
#: (censoring at the range limits, :func:`_censoring_keep`); beyond 4 sigma the bias sigma phi(4) / Phi(4)
#: is 1.3e-4 sigma
CENSOR_GUARD_SIGMA = 4.0


def _guard_sigma(floors_k: np.ndarray, sigma: float) -> np.ndarray:
    """Noise sigma per channel for the censoring guard: the channel's own floor, else the pooled one."""
    f = np.asarray(floors_k, dtype=float)
    return np.where(np.isfinite(f) & (f > 0), f, sigma)


def _censoring_keep(v_model: np.ndarray, y: np.ndarray, range_mm: np.ndarray, sigma_c: np.ndarray):
    """Return the mask of readings not censored by a sensor range limit.

    Return readings (n, c) not censored by a sensor range limit: True where the model value ``v_model``
    lies more than ``CENSOR_GUARD_SIGMA`` sigma inside [0, range].

    The raw format nulls a reading when the sensor reports no valid value (out of range), which
    the sensor decides on the noisy value; so near a limit the valid readings are a truncated
    sample (biased by up to ~0.8 sigma) and beyond it a few noisy ones stay valid. The selection
    here is on the model, which the noise does not move (to within the fit's own small
    uncertainty), so the kept readings are unbiased. A limit is taken as a censoring limit only
    where no valid reading of the channel lies beyond it (a sensor reporting negative values or
    values above its stated range is not censored there).

    Returns (keep (n, c) bool, limits {"lower": [bool] * c, "upper": [bool] * c}).
    """
    v = np.asarray(v_model, dtype=float)
    yy = np.asarray(y, dtype=float)
    c = v.shape[1]
    rng = np.broadcast_to(np.asarray(range_mm, dtype=float), (c,))
    g = CENSOR_GUARD_SIGMA * np.broadcast_to(np.asarray(sigma_c, dtype=float), (c,))
    keep = np.ones(v.shape, dtype=bool)
    lower, upper = [], []
    with np.errstate(invalid="ignore"):
        for j in range(c):
            ok = np.isfinite(yy[:, j])
            lo = not bool(np.any(yy[ok, j] < 0.0))
            hi = not bool(np.any(yy[ok, j] > rng[j]))
            if lo:
                keep[:, j] &= v[:, j] > g[j]
            if hi:
                keep[:, j] &= v[:, j] < rng[j] - g[j]
            lower.append(lo)
            upper.append(hi)
    return keep, {"lower": lower, "upper": upper}


def _per_scan_xy(xy, K: int) -> list:
    """``None``, one (x, y) for every scan, or one (x, y) / None per scan -> list of (2,) or None."""
    if xy is None:
        return [None] * K
    if isinstance(xy, (list, tuple)) and len(xy) == K and (K != 2 or not np.isscalar(xy[0])):
        return [None if p is None else np.asarray(p, dtype=float).reshape(2) for p in xy]
    a = np.asarray(xy, dtype=float)
    if a.shape == (2,):
        return [a] * K
    return [np.asarray(p, dtype=float).reshape(2) for p in a]


def _acceptance_problems(beams, nuis, ratios, scan_ids, channels, R_mm, range_arr, rule) -> list[str]:
    """Why a converged fit is not a calibration (empty when it is)."""
    out = []
    for k, sid in enumerate(scan_ids):
        for j, ch in enumerate(channels):
            if not ratios[k, j] <= rule.max_residual_to_noise:
                out.append(
                    f"{sid} channel {ch}: residual rms is {ratios[k, j]:.2f} times the readings' own "
                    "noise floor "
                    f"(limit {rule.max_residual_to_noise:g}): the model misses an effect"
                )
    for j, ch in enumerate(channels):
        rho, d_b = float(beams.rho_mm[j]), float(beams.d_b_mm[j])
        if abs(rho) > rule.head_radius_mm:
            out.append(
                f"channel {ch}: |rho| = {abs(rho):.3f} mm exceeds the head radius {rule.head_radius_mm:g} mm"
            )
            continue
        oe = max(float(np.hypot(*n[0])) for n in nuis)
        s0 = np.sqrt(max(R_mm**2 - rho**2, 0.0))
        lo, hi = s0 - oe - range_arr[j], s0 + oe
        if not (lo - 0.01 <= d_b <= hi + 0.01):
            out.append(
                f"channel {ch}: d_b = {d_b:.4f} mm outside [{lo:.4f}, {hi:.4f}] mm, what a gauge of radius "
                f"{R_mm:.4f} mm with offset {oe:.4f} mm and a {range_arr[j]:g} mm sensor allow"
            )
    return out


def _param_names(
    channels: Sequence[int],
    scan_ids: Sequence[str],
    ch0_free: int = 0,
    nuis_cols: list[dict[str, int]] | None = None,
) -> list[str]:
    names = [f"beta_rad[{ch}]" for ch in (channels if ch0_free else channels[1:])]
    names += [f"rho_mm[{ch}]" for ch in channels] + [f"d_b_mm[{ch}]" for ch in channels]
    for k, s in enumerate(scan_ids):
        cols = nuis_cols[k] if nuis_cols else {"ox": 0, "oy": 1}
        names += [f"offset_x_mm[{s}]", f"offset_y_mm[{s}]"]
        if "phase" in cols:
            names.append(f"phase0_rad[{s}]")
        if "scale" in cols:
            names.append(f"speed_scale[{s}]")
    return names


def full_residuals(
    cal: TriCalibration,
    t_s,
    readings_mm,
    R_mm: float,
    scan_id: str | None = None,
    angle_model: AngleModel | None = None,
) -> np.ndarray:
    """Residuals (model - reading) (n, c) [mm] of a ``full_lsq`` calibration on one of its scans.

    Uses the scan's fitted offset, phase and speed scale from ``cal.nuisance`` with the scan's
    ``angle_model`` (default: constant speed ``omega_rad_s``); NaN readings give NaN residuals.
    """
    if cal.method != "full_lsq":
        raise ValueError(f"full_residuals needs a full_lsq calibration, got {cal.method!r}")
    scan_id = scan_id if scan_id is not None else cal.scan_ids[0]
    nu = cal.nuisance[scan_id]
    t = np.asarray(t_s, dtype=float)
    tau_c = _channel_offsets(cal.diagnostics.get("channel_time_offsets_s"), len(cal.beams.channels))
    t = t if tau_c is None else t[:, None] - tau_c[None, :]
    if angle_model is None:
        phi = nu["phase0_rad"] + nu["omega_rad_s"] * t
    else:
        phi = angle_model.phi_rad(t, nu["phase0_rad"], nu.get("speed_scale", 1.0))
    off = np.array([nu["offset_x_mm"], nu["offset_y_mm"]])
    model = tri_spindle_readings(phi, off, cal.beams, Bore((0.0, 0.0), R_mm))
    return model - np.asarray(readings_mm, dtype=float)


# --------------------------------------------------------------------------- sensitivities (GUM budget)


def full_lsq_sensitivities(  # noqa: C901 (part of the full_lsq fit, to be split into small functions)
    cal: TriCalibration,
    t_s,
    readings_mm,
    R_mm: float,
    angle_models: Sequence[AngleModel],
    *,
    spindle_xy_mm=None,
    center_xy_mm=None,
    reading_perturbations: Mapping[str, Sequence[np.ndarray]] | None = None,
) -> dict[str, Any]:
    """Return a ``full_lsq`` calibration's sensitivities and covariance split.

    Linear sensitivities of a ``full_lsq`` calibration to what it takes as known, and the split
    of its covariance into the readings' part and the position priors' part.

    At the solution, J is the Jacobian of the readings' residuals with respect to the free public
    parameters p (beta where free, rho, d_b, per scan the offset o = S - C, the phase where free
    and the speed scale without an encoder), Jp that of the prior rows w (o - o_reported) with
    w = sigma / (a sqrt(2/3)) (sigma the readings' noise floor, a the stated position accuracy,
    as in :func:`fit_full_calibration`), H = J^T J + Jp^T Jp and s^2 = SSR / dof. The estimate
    stays the minimum when an input moves, so to first order (implicit differentiation of the
    normal equations):

    - gauge radius: dp/dR = -H^-1 J^T dv/dR, with dv/dR = R / (P . Rot(phi) u) from |P| = R,
      P the wall point relative to the gauge centre (``_readings_and_jacobian``: dv/dR equals
      |(dv/do_x, dv/do_y)|);
    - a constant error e_c of every reading of channel c: dp/de_c = H^-1 J^T 1_c;
    - the reported offset of scan k (prior mean): dp/do_k = H^-1 Jp_k^T w;
    - covariance of the fit: s^2 H^-1 = s^2 H^-1 J^T J H^-1 (readings) + s^2 H^-1 Jp^T Jp H^-1
      (priors). The calibration's ``cov`` adds to s^2 H^-1 the second-order term of d_b in rho,
      the spread along a non-linear rho profile and any unresolved minimum; ``cov_extra`` is that
      difference.

    Parameters
    ----------
    cal : the ``full_lsq`` TriCalibration (its nuisance, diagnostics cost and acceptance)
    t_s, readings_mm : per scan (lists), exactly what the fit saw (despiked readings, NaN missing)
    R_mm : the gauge radius the fit used [mm]
    angle_models : per scan AngleModel, as given to the fit
    spindle_xy_mm, center_xy_mm : per scan reported positions (None where unknown), as given to the fit
    reading_perturbations : name -> per scan dy (n, c): readings that move by dy per unit of a
        quantity (e.g. a carried device-model parameter); dp = H^-1 J^T dy for each

    Returns
    -------
    dict with, in the calibration's (3c,) parameter order (gauge-fixed beta: 0):
    ``dR`` (3c,) [per mm], ``reading_offset`` (3c, c) [-], ``offset_prior`` {scan_id: (3c, 2)} [-],
    ``cov_readings``, ``cov_priors``, ``cov_linear`` (= their sum), ``cov_extra`` (3c, 3c),
    ``s2`` [mm^2], ``prior_sigma_mm`` (u of each reported offset coordinate) and
    ``second_order_d_b_mm2`` (c,) (the d_b variance term 3 u(rho)^4 / (4 R^2)),
    ``reading_perturbation`` {name: (3c,)} (per ``reading_perturbations``) and
    ``channel_time_offset`` (3c, c) [per s] (dp / d tau_c: the time at which channel c's readings are
    taken, as a carried ``channel_delay``).
    """
    if cal.method != "full_lsq":
        raise ValueError(f"full_lsq_sensitivities needs a full_lsq calibration, got {cal.method!r}")
    ts = [np.asarray(x, dtype=float) for x in t_s]
    ys = [np.asarray(x, dtype=float) for x in readings_mm]
    K = len(ts)
    if len(ys) != K or len(angle_models) != K or len(cal.scan_ids) != K:
        raise ValueError("t_s, readings_mm, angle_models and the calibration's scans must correspond")
    beams = cal.beams
    c = len(beams.channels)
    Ss, Cs = _per_scan_xy(spindle_xy_mm, K), _per_scan_xy(center_xy_mm, K)
    priors = [None if (Ss[k] is None or Cs[k] is None) else Ss[k] - Cs[k] for k in range(K)]
    ch0_free = 1 if cal.diagnostics.get("beta_reference") == "absolute" else 0
    nb = 3 * c - 1 + ch0_free
    cols, col = [], nb
    for k, sid in enumerate(cal.scan_ids):
        nu = cal.nuisance[sid]
        d = {"ox": col, "oy": col + 1}
        col += 2
        if nu.get("phase_free"):
            d["phase"] = col
            col += 1
        if angle_models[k].fits_speed_and_phase:
            d["scale"] = col
            col += 1
        cols.append(d)
    p = col
    floors = np.array([noise_floor_mm(y, order=4) for y in ys])
    sigma = float(np.sqrt(np.mean(floors**2))) if np.all(np.isfinite(floors)) else 0.0
    a = float(
        cal.diagnostics.get("acceptance", {}).get(
            "position_accuracy_mm", AcceptanceRule.defaults().position_accuracy_mm
        )
    )
    prior_sigma = a * np.sqrt(2.0 / 3.0)
    w = (sigma if sigma > 0 else 1e-3) / prior_sigma
    guard = cal.diagnostics.get("censoring_guard")
    guard_range = np.asarray(guard["range_mm"], dtype=float) if guard else None

    tau_c = _channel_offsets(cal.diagnostics.get("channel_time_offsets_s"), c)
    J_parts, dR_parts, chan_parts, mask_parts, dtau_parts = [], [], [], [], []
    for k, sid in enumerate(cal.scan_ids):
        nu, am = cal.nuisance[sid], angle_models[k]

        def phi_at(tt, nu=nu, am=am):
            P = am.commanded_rad(tt)
            return (
                float(nu["phase0_rad"]) + float(nu.get("speed_scale", 1.0)) * P
                if am.fits_speed_and_phase
                else P
            )

        tc = np.repeat(ts[k][:, None], c, axis=1) - (0.0 if tau_c is None else tau_c[None, :])
        Phi = am.commanded_rad(tc)
        phi = phi_at(tc)
        off = np.array([nu["offset_x_mm"], nu["offset_y_mm"]], dtype=float)
        v_k, jac = _readings_and_jacobian(phi, beams, off, R_mm)
        jac = {name: a.T for name, a in jac.items()}  # (n, c) views
        # the model's readings per unit of a channel's time offset: phi of channel c at t - tau_c
        h = 1e-6
        dtau_parts.append(jac["phi"] * (phi_at(tc - h) - phi_at(tc + h)) / (2.0 * h))
        n = ts[k].size
        Jk = np.zeros((n, c, p))
        for j in range(c):
            if j > 0 or ch0_free:
                Jk[:, j, j - 1 + ch0_free] = jac["beta"][:, j]
            Jk[:, j, c - 1 + ch0_free + j] = jac["rho"][:, j]
            Jk[:, j, 2 * c - 1 + ch0_free + j] = -1.0
        Jk[:, :, cols[k]["ox"]] = jac["ox"]
        Jk[:, :, cols[k]["oy"]] = jac["oy"]
        if "phase" in cols[k]:
            Jk[:, :, cols[k]["phase"]] = jac["phi"]
        if "scale" in cols[k]:
            Jk[:, :, cols[k]["scale"]] = jac["phi"] * Phi
        m = np.isfinite(ys[k])
        if guard is not None:  # the readings the fit set aside near the sensor range limits
            m &= _censoring_keep(v_k, ys[k], guard_range, _guard_sigma(floors[k], sigma))[0]
        J_parts.append(Jk[m])
        mask_parts.append(m)
        dR_parts.append(np.hypot(jac["ox"], jac["oy"])[m])
        chan_parts.append(np.broadcast_to(np.arange(c), (n, c))[m])
    J = np.vstack(J_parts)
    dv_dR = np.concatenate(dR_parts)
    chan = np.concatenate(chan_parts)
    Jp_rows, prior_cols = [], {}
    for k, sid in enumerate(cal.scan_ids):
        if priors[k] is None:
            continue
        row = np.zeros((2, p))
        row[0, cols[k]["ox"]] = w
        row[1, cols[k]["oy"]] = w
        prior_cols[sid] = len(Jp_rows)
        Jp_rows.append(row)
    Jp = np.vstack(Jp_rows) if Jp_rows else np.zeros((0, p))
    colnorm = np.sqrt(np.sum(J**2, axis=0) + np.sum(Jp**2, axis=0))
    colnorm[colnorm == 0] = 1.0
    Hs = (J / colnorm).T @ (J / colnorm) + (Jp / colnorm).T @ (Jp / colnorm)
    Hinv = np.linalg.pinv(Hs, rcond=1e-15, hermitian=True) / np.outer(colnorm, colnorm)
    s2 = 2.0 * float(cal.diagnostics["cost"]) / float(cal.dof)

    # public free parameters -> the calibration's (3c,) order
    idx = _public_index(c, ch0_free)
    ok = idx >= 0

    def vec(x: np.ndarray) -> np.ndarray:
        out = np.zeros((3 * c,) + x.shape[1:])
        out[ok] = x[idx[ok]]
        return out

    def mat(C: np.ndarray) -> np.ndarray:
        out = np.zeros((3 * c, 3 * c))
        out[np.ix_(ok, ok)] = C[np.ix_(idx[ok], idx[ok])]
        return out

    dR = vec(-Hinv @ (J.T @ dv_dR))
    reading_offset = np.column_stack([vec(Hinv @ J[chan == j].sum(axis=0)) for j in range(c)])

    def response(dys) -> np.ndarray:  # dp = H^-1 J^T dy: readings that move by dy (per scan (n, c))
        return vec(Hinv @ (J.T @ np.concatenate([np.asarray(d, float)[m] for d, m in zip(dys, mask_parts)])))

    perturbation = {name: response(dys) for name, dys in (reading_perturbations or {}).items()}
    # a channel's time offset moves the model's readings by df; the fit answers as to readings moved by -df
    time_offset = np.column_stack(
        [response([-np.where(np.arange(c)[None, :] == j, d, 0.0) for d in dtau_parts]) for j in range(c)]
    )
    offset_prior = {}
    for sid, r0 in prior_cols.items():
        rows = Jp[2 * r0 : 2 * r0 + 2]
        offset_prior[sid] = vec(Hinv @ rows.T * w)
    A = Hinv @ J.T
    cov_readings = mat(s2 * (A @ A.T))
    B = Hinv @ Jp.T
    cov_priors = mat(s2 * (B @ B.T))
    cov_linear = mat(s2 * Hinv)
    u2_rho = np.diag(cov_linear)[1::3]
    second = 3.0 * u2_rho**2 / (4.0 * R_mm**2)
    return {
        "dR": dR,
        "reading_offset": reading_offset,
        "offset_prior": offset_prior,
        "cov_readings": cov_readings,
        "cov_priors": cov_priors,
        "cov_linear": cov_linear,
        "cov_extra": cal.cov - cov_linear,
        "s2": s2,
        "prior_sigma_mm": float(prior_sigma),
        "second_order_d_b_mm2": second,
        "reading_perturbation": perturbation,
        "channel_time_offset": time_offset,
    }
