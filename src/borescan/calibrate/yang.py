"""Yang 2017 (Eqs. 8-15): a three-sensor calibration from the extreme readings on a ring gauge.

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
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from borescan.calibrate.result import STATUSES, CalibrationError, TriCalibration, make_calibration_id
from borescan.geometry import Beams

__all__ = [
    "yang_oe",
    "yang_d_b_r",
    "yang_sensitivities",
    "yang_theta_c",
    "yang_theta_t",
    "yang_status",
    "yang_to_beams",
    "yang_calibration",
]


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
