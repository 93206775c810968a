"""Yang 2017 versus full-data least squares on simulated ring-gauge scans with known truth.

Scans are synthesised directly with :func:`borescan.geometry.tri_spindle_readings` plus
Gaussian noise. Printed: parameter errors and the diameter error on a verification ring against
revolutions (the shape of Yang 2017 Fig. 9), noise and centre offset; and the coverage of
+-2u intervals of the full fit over a seeded batch. Run: ``python -m bench.bench_calibration``.
"""

from __future__ import annotations

import sys

import numpy as np

from borescan.calibrate.full_fit import fit_full_calibration
from borescan.calibrate.result import CalibrationError
from borescan.calibrate.yang import yang_calibration, yang_status
from borescan.geometry import (
    Beams,
    Bore,
    circumcircle,
    tri_spindle_readings,
    tri_static_readings,
    wall_points_device,
)

# Truth near Yang 2017 Table 1 (r, d_b), beams about 120 deg apart; gauge and offset as in §3.1.
TRUE = Beams(
    channels=(1, 2, 3),
    beta_rad=np.array([0.3, 0.3 + 2.1, 0.3 + 4.2]),
    rho_mm=np.array([5.5484, -2.5295, 1.5262]),
    d_b_mm=np.array([132.6718, 132.8883, 134.1108]),
)
R_MM = 275.029 / 2
OFFSET_MM = np.array([0.122, -2.320])  # P1 - P0 of Yang 2017 (oe = 2.3232 mm)


def simulate_scan(
    beams: Beams,
    offset_mm,
    n_rev: int,
    samples_per_rev: int,
    noise_mm: float,
    rng,
    R_mm: float = R_MM,
    phase0_rad: float = 0.0,
    rpm: float = 60.0,
):
    """Sample times [s] and noisy readings (n, c) [mm] of a ccw spindle scan of a ring gauge."""
    omega = 2.0 * np.pi * rpm / 60.0
    t = np.arange(n_rev * samples_per_rev) / (samples_per_rev * rpm / 60.0)
    v = tri_spindle_readings(
        phase0_rad + omega * t, np.asarray(offset_mm, float), beams, Bore((0.0, 0.0), R_mm)
    )
    return t, v + rng.normal(0.0, noise_mm, v.shape)


def perturbed_nominal(rng, beams: Beams = TRUE) -> Beams:
    """Return a design geometry a little off the truth (starting point of the fit)."""
    c = len(beams.channels)
    return Beams(
        beams.channels,
        beams.beta_rad + rng.uniform(-0.01, 0.01, c),
        beams.rho_mm + rng.uniform(-0.5, 0.5, c),
        beams.d_b_mm + rng.uniform(-0.1, 0.1, c),
    )


def yang_extremes(readings_mm: np.ndarray, samples_per_rev: int, half_window: int | None = None) -> dict:
    """Per-revolution sub-sample extremes (quartic fit over +-30 deg) and their means.

    Returns d_max, d_min (means), their standard errors, feature positions (mean minimum
    position modulo samples_per_rev) and the Yang §2.3 statuses.
    """
    n, c = readings_mm.shape
    N = samples_per_rev
    w = half_window or N // 12
    n_rev = n // N
    out = {k: np.zeros((n_rev, c)) for k in ("d_min", "d_max", "n_min", "n_max")}
    k_loc = np.arange(-w, w + 1, dtype=float)
    for j in range(c):
        y = readings_mm[:, j]
        for rev in range(n_rev):
            seg = slice(rev * N, (rev + 1) * N)
            for key, pick, sign in (("d_min", np.argmin, 1.0), ("d_max", np.argmax, -1.0)):
                i_rel = int(pick(y[seg]))
                # window taken periodically within the revolution (exact revolutions in simulation)
                yy = y[rev * N + (i_rel + k_loc.astype(int)) % N]
                i0 = rev * N + i_rel
                p = np.polyfit(k_loc, yy, 4)
                roots = np.roots(np.polyder(p))
                roots = roots[np.isreal(roots)].real
                roots = roots[np.abs(roots) <= w / 2] if np.any(np.abs(roots) <= w / 2) else np.array([0.0])
                vals = np.polyval(p, roots)
                kbest = roots[np.argmin(sign * vals)]
                out[key][rev, j] = np.polyval(p, kbest)
                out["n_" + key[2:]][rev, j] = i0 + kbest
    n_mm = np.mean((out["n_max"] - out["n_min"]) % N, axis=0)
    res = {
        "d_max": out["d_max"].mean(0),
        "d_min": out["d_min"].mean(0),
        "u_d_max": out["d_max"].std(0, ddof=1) / np.sqrt(n_rev) if n_rev > 1 else np.zeros(c),
        "u_d_min": out["d_min"].std(0, ddof=1) / np.sqrt(n_rev) if n_rev > 1 else np.zeros(c),
        "statuses": [yang_status(a, N - a) for a in n_mm],
    }
    # feature position: circular mean of the minimum positions modulo N
    ang = 2.0 * np.pi * (out["n_min"] % N) / N
    res["feature"] = (np.angle(np.exp(1j * ang).mean(0)) % (2.0 * np.pi)) * N / (2.0 * np.pi)
    return res


def run_yang(t, v, samples_per_rev, oe_mm, nominal: Beams, R_mm: float = R_MM):
    """Yang 2017 calibration from a simulated scan (oe as given, gauge beta_1 = nominal)."""
    ex = yang_extremes(v, samples_per_rev)
    return yang_calibration(
        ex["d_max"],
        ex["d_min"],
        ex["statuses"],
        ex["feature"],
        samples_per_rev,
        R_mm,
        oe_mm,
        channels=nominal.channels,
        beta_ref_rad=float(nominal.beta_rad[0]),
        beta_nominal_rad=nominal.beta_rad,
        u_d_max_mm=ex["u_d_max"],
        u_d_min_mm=ex["u_d_min"],
        scan_ids=("sim",),
    )


VERIFY_POSITIONS = np.array([[0.3, -0.2], [-0.8, 0.5], [1.2, 0.9], [-0.4, -1.1], [0.0, 0.0]])
VERIFY_ANGLES = np.array([0.1, 1.3, 2.9, 4.0, 5.5])


def verification_error_mm(beams_est: Beams, beams_true: Beams = TRUE, R_ring_mm: float = 137.5) -> np.ndarray:
    """Diameter error [mm] of static three-point measurements in a ring of known radius.

    True readings from ``beams_true`` at five device poses; diameter = 2 x circumradius of the wall
    points computed with ``beams_est`` (Yang 2017 Eqs. 1-3). Invariant to a common rotation of the
    betas, so the gauge choice does not matter.
    """
    v = tri_static_readings(VERIFY_POSITIONS, VERIFY_ANGLES, beams_true, Bore((0.0, 0.0), R_ring_mm))
    _, r = circumcircle(wall_points_device(v, beams_est))
    return 2.0 * r - 2.0 * R_ring_mm


def param_errors(beams_est: Beams, beams_true: Beams = TRUE) -> dict:
    """Errors of beta_c - beta_1 [rad], rho [mm], d_b [mm]."""
    db = (beams_est.beta_rad - beams_est.beta_rad[0]) - (beams_true.beta_rad - beams_true.beta_rad[0])
    return {
        "beta": db[1:],
        "rho": beams_est.rho_mm - beams_true.rho_mm,
        "d_b": beams_est.d_b_mm - beams_true.d_b_mm,
    }


def one_trial(rng, n_rev=5, N=200, noise_mm=0.002, offset_mm=OFFSET_MM, oe_error_mm=0.0):
    """One simulated scan calibrated both ways; returns dict of results (None where a method failed)."""
    nominal = perturbed_nominal(rng)
    t, v = simulate_scan(TRUE, offset_mm, n_rev, N, noise_mm, rng)
    out = {}
    try:
        out["full"] = fit_full_calibration(t, v, TRUE.channels, nominal, R_MM, rpm=60.0)
    except CalibrationError:
        out["full"] = None
    try:
        out["yang"] = run_yang(t, v, N, float(np.hypot(*offset_mm)) + oe_error_mm, nominal)
    except CalibrationError:
        out["yang"] = None
    return out


def coverage(n_cal: int = 200, seed: int = 7, n_rev: int = 5, N: int = 200, noise_mm: float = 0.002) -> dict:
    """Fraction of true values inside +-2u of the full fit, per parameter, and the mean z^2."""
    rng = np.random.default_rng(seed)
    names = ["beta2-beta1", "beta3-beta1", "rho1", "rho2", "rho3", "d_b1", "d_b2", "d_b3"]
    z = []
    for _ in range(n_cal):
        nominal = perturbed_nominal(rng)
        t, v = simulate_scan(TRUE, OFFSET_MM, n_rev, N, noise_mm, rng)
        cal = fit_full_calibration(t, v, TRUE.channels, nominal, R_MM, rpm=60.0)
        e = param_errors(cal.beams)
        # beta_1 is the gauge (fixed, u = 0): the uncertainty of beta_c - beta_1 is u(beta_c)
        err = np.concatenate([e["beta"], e["rho"], e["d_b"]])
        u = np.concatenate([cal.u_beta_rad[1:], cal.u_rho_mm, cal.u_d_b_mm])
        z.append(err / u)
    z = np.array(z)
    return {
        "names": names,
        "within_2u": np.mean(np.abs(z) <= 2.0, axis=0),
        "mean_z2": np.mean(z**2, axis=0),
        "n": n_cal,
    }


def _row(label, res_list, key):
    fits = [r[key] for r in res_list if r[key] is not None]
    nfail = len(res_list) - len(fits)
    if not fits:
        return f"{label:>22s} {key:>5s}  all {nfail} failed"
    e = [param_errors(c.beams) for c in fits]
    rms = lambda a: np.sqrt(np.mean(np.square(a), axis=0))  # noqa: E731
    beta = rms([x["beta"] for x in e]) * 1e6
    rho = rms([x["rho"] for x in e]) * 1e3
    d_b = rms([x["d_b"] for x in e]) * 1e3
    dia = np.array([verification_error_mm(c.beams) for c in fits]) * 1e3
    dia_other = (
        np.array(
            [
                np.r_[
                    verification_error_mm(c.beams, R_ring_mm=136.0),
                    verification_error_mm(c.beams, R_ring_mm=139.0),
                ]
                for c in fits
            ]
        )
        * 1e3
    )
    return (
        f"{label:>22s} {key:>5s}  beta(urad) {beta[0]:8.1f} {beta[1]:8.1f}  rho(um) {rho[0]:8.1f} "
        f"{rho[1]:8.1f} {rho[2]:8.1f}"
        f"  d_b(um) {d_b[0]:7.2f} {d_b[1]:7.2f} {d_b[2]:7.2f}  |dD| rms/max(um) "
        f"{np.sqrt(np.mean(dia**2)):7.2f} "
        f"{np.max(np.abs(dia)):7.2f}  272/278mm {np.sqrt(np.mean(dia_other**2)):7.2f} "
        f"{np.max(np.abs(dia_other)):7.2f}"
        f"  fail {nfail}"
    )


def main(trials: int = 20) -> None:
    """Print the comparison tables and the coverage (RMS over ``trials`` seeded scans per cell)."""
    print(
        "RMS errors over",
        trials,
        "scans; 200 samples/rev, ccw 60 rpm; beta as beta_c - beta_1; "
        "|dD| = diameter error on a 275.000 mm verification ring, 5 static poses, "
        "then on 272 and 278 mm rings (rms, max)",
    )
    print("-- revolutions (noise 2 um, oe 2.3232 mm; Yang with exact oe)")
    for n_rev in (1, 2, 5, 10, 20, 50, 100):
        rng = np.random.default_rng(100 + n_rev)
        res = [one_trial(rng, n_rev=n_rev) for _ in range(trials if n_rev <= 20 else max(4, trials // 4))]
        for key in ("full", "yang"):
            print(_row(f"n_rev={n_rev}", res, key))
    print("-- noise (5 revolutions)")
    for noise in (0.0005, 0.002, 0.005):
        rng = np.random.default_rng(200)
        res = [one_trial(rng, noise_mm=noise) for _ in range(trials)]
        for key in ("full", "yang"):
            print(_row(f"noise={noise * 1e3:.1f}um", res, key))
    print("-- centre offset (5 revolutions, noise 2 um)")
    for oe in (0.5, 1.0, 2.3232, 4.0):
        rng = np.random.default_rng(300)
        off = OFFSET_MM / np.hypot(*OFFSET_MM) * oe
        res = [one_trial(rng, offset_mm=off) for _ in range(trials)]
        for key in ("full", "yang"):
            print(_row(f"oe={oe:.2f}mm", res, key))
    print("-- Yang with oe off by +2 um (the machine's stated position accuracy), 5 revolutions")
    rng = np.random.default_rng(400)
    res = [one_trial(rng, oe_error_mm=0.002) for _ in range(trials)]
    print(_row("oe+2um", res, "yang"))
    cov = coverage()
    print(f"-- coverage of +-2u, full fit, {cov['n']} calibrations (5 rev x 200 samples, 2 um noise)")
    for name, f, z2 in zip(cov["names"], cov["within_2u"], cov["mean_z2"]):
        print(f"{name:>12s}  within 2u {f:5.3f}   mean z^2 {z2:5.2f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20)
