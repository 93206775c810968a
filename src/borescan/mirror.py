"""The sign of a beam's rho that a ring-gauge scan may not fix: mirror solutions, their depth, the fix.

A three-sensor calibration on a ring gauge of radius L (the wall distance from the spindle axis)
with the spindle offset e from the gauge centre sees each beam's reading

    v(a) = sqrt(L^2 - (rho + e sin a)^2) - e cos a - d_b
         = L - d_b - rho^2 / (2L) - e cos a - (rho e / L) sin a - (e^2 / (4L)) (1 - cos 2a) + ...,

a = phi + beta - angle(o). The mean level and the first harmonic (amplitude e sqrt(1 + rho^2/L^2),
phase a - asin(rho / L)) are kept by rho -> -rho with beta -> beta + 2 asin(rho / L) (the mirror
solution); only the second harmonic's phase, which moves by 2 (2 rho / L), tells them apart. The
difference of the two second harmonics has amplitude (e^2 / (4L)) 4 |rho| / L = e^2 |rho| / L^2, so
over N samples of noise sigma the mirror lies

    delta_chi2_m = N e^4 rho^2 / (2 sigma^2 L^4)                                            (1)

above the true minimum (:func:`predicted_depth`; the fit's other parameters absorb a little of it:
an explicit refit from -rho gives the exact value, ``diagnostics["mirror_check"]``). A mirror exists
only when |rho| > sqrt(2) e (below that the refit from -rho returns to the kept minimum).

The decision (issue 36): the sign of a beam's rho is *determined* by the scan
(:attr:`BeamMirror.sign_determined`) unless a mirror is possible at the fitted rho (|rho| > sqrt(2) e)
and its depth is below 25 (:data:`RESOLVED_DCHI2`), the depth being the explicit refit's where the
refit from -rho found a separate minimum of the other sign, else Eq. (1) at the fit: one rule for the
certificate and the contract bench's count. A determined sign gives one Gaussian value with u from its
own curvature. An undetermined one takes one of two forms. A separate minimum within 25: the beam is
*flagged* (``resolved`` False), two solutions, each with its covariance, delta chi2 and weight
exp(-delta chi2 / 2) (normalised), the probability of the wrong sign (the mirror's weight), the bore
range in which the calibration may be used (:func:`valid_bore_radius_range_mm`: the two solutions agree
at the gauge, their wall points rotate apart by 2 rho (1/L_cal - 1/L) elsewhere), and the spindle offset
that would resolve it, (1) solved for e at delta_chi2_m = K (:func:`offset_to_resolve_mm`). No separate
minimum (:attr:`BeamMirror.one_valley`: the refit slides back through rho = 0, u(rho) ~ |rho|): one
value whose u spans both signs, the rho profile's spread (:mod:`borescan.calibrate.profiles`), and the
same offset to resolve it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = [
    "RESOLVED_DCHI2",
    "BeamMirror",
    "MirrorSolution",
    "MixtureDiameter",
    "format_probability",
    "mirror_checks_of",
    "mirror_exists",
    "mixture_components",
    "mixture_diameter",
    "mixture_seed",
    "offset_to_resolve_mm",
    "predicted_depth",
    "refusal",
    "valid_bore_radius_range_mm",
]

#: a mirror at least this far (in chi^2 units) above the kept minimum is resolved: its weight
#: exp(-25/2) = 3.7e-6 (issue 36: from 25 the local Cramer-Rao bound holds; from 9 to 25 the two
#: modes are sharp and separate; below 9 even the main one is not Gaussian)
RESOLVED_DCHI2 = 25.0


def format_probability(p: float) -> str:
    """Return a probability or weight as text that never reads 0 or 1 when it is not.

    From 0.001 to 0.999: three decimals ("0.184"); below 0.001 one significant digit ("3e-4", for
    exp(-8.2)); above 0.999 as 1 minus that ("1 - 3e-4"); exactly 0 or 1 as "0" / "1"; nan as "n/a".
    """
    if not math.isfinite(p):
        return "n/a"
    if p <= 0.0 or p >= 1.0:
        return "0" if p <= 0.0 else "1"
    if p < 0.001:
        mant, exp = f"{p:.0e}".split("e")
        return f"{mant}e{int(exp)}"
    if p > 0.999:
        return f"1 - {format_probability(1.0 - p)}"
    return f"{p:.3f}"


def predicted_depth(n_samples, offset_mm, rho_mm: float, sigma_mm, radius_mm: float) -> float:
    """Depth of the mirror minimum, Eq. (1) of the module, summed over scans.

    Parameters
    ----------
    n_samples : (K,) valid readings of the channel per scan [-]
    offset_mm : (K,) spindle-to-gauge-centre distance e per scan [mm]
    rho_mm : the beam's rho [mm]
    sigma_mm : (K,) the channel's noise per scan [mm]
    radius_mm : the gauge radius L (wall distance from the spindle axis) [mm]

    Returns
    -------
    float
        sum_k N_k e_k^4 rho^2 / (2 sigma_k^2 L^4) [chi^2 units]; inf where sigma is 0.
    """
    n = np.atleast_1d(np.asarray(n_samples, dtype=float))
    e = np.broadcast_to(np.asarray(offset_mm, dtype=float), n.shape)
    s = np.broadcast_to(np.asarray(sigma_mm, dtype=float), n.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(s > 0, n * e**4 * rho_mm**2 / (2.0 * s**2 * radius_mm**4), np.inf)
    return float(np.sum(terms))


def mirror_exists(rho_mm: float, offset_mm) -> bool:
    """Whether a mirror solution exists: |rho| > sqrt(2) e (the largest offset of the scans)."""
    return bool(abs(rho_mm) > math.sqrt(2.0) * float(np.max(np.atleast_1d(offset_mm))))


def offset_to_resolve_mm(
    radius_mm: float, sigma_mm: float, n_samples: float, rho_mm: float, k: float = RESOLVED_DCHI2
) -> float:
    """Return the spindle offset at which the mirror lies ``k`` above the minimum.

    Eq. (1) solved for e: X = L (2 k sigma^2 / (N rho^2))^(1/4) [mm]; inf for rho = 0 (no mirror to resolve:
    any offset).
    """
    if rho_mm == 0.0 or n_samples <= 0:
        return float("inf")
    return float(radius_mm * (2.0 * k * sigma_mm**2 / (n_samples * rho_mm**2)) ** 0.25)


def valid_bore_radius_range_mm(
    radius_cal_mm: float, params_main, params_alt, u_beta_rad: float, n_grid: int = 4001
) -> tuple[float, float]:
    """Return the bore radii L where the two solutions place the wall points alike.

    Every pair of beams' relative direction differs between them by at most 2 u(beta).

    The direction of beam c's wall point in a bore of radius L is beta_c + asin(rho_c / L). Between the
    solutions it moves by Delta_c(L) = (beta_alt - beta)_c + asin(rho_alt_c / L) - asin(rho_c / L); a
    common rotation of every beam moves no diameter, so the criterion is max_{c,c'} |Delta_c - Delta_c'|
    <= 2 u (u the flagged beam's u(beta)). The two solutions agree at the gauge (L_cal); the interval
    of 1/L containing 1/L_cal where this holds is found on a grid of 1/L over [0, 4 / L_cal].

    Parameters
    ----------
    params_main, params_alt : (3c,) per channel (beta_rad, rho_mm, d_b_mm)

    Returns
    -------
    (L_min, L_max) [mm]; L_max = inf when every bore larger than the gauge qualifies.
    """
    pm = np.asarray(params_main, dtype=float)
    pa = np.asarray(params_alt, dtype=float)
    dbeta = (pa[0::3] - pm[0::3] + np.pi) % (2 * np.pi) - np.pi
    x = np.linspace(0.0, 4.0 / radius_cal_mm, n_grid)  # 1/L
    delta = (
        dbeta[None, :]
        + np.arcsin(np.clip(pa[1::3][None, :] * x[:, None], -1, 1))
        - np.arcsin(np.clip(pm[1::3][None, :] * x[:, None], -1, 1))
    )
    spread = delta.max(axis=1) - delta.min(axis=1)
    good = spread <= 2.0 * u_beta_rad
    i0 = int(np.argmin(np.abs(x - 1.0 / radius_cal_mm)))
    if not good[i0]:  # the solutions differ at the gauge itself (by more than 2 u): only the gauge's size
        return (float(radius_cal_mm), float(radius_cal_mm))
    lo_i = i0
    while lo_i > 0 and good[lo_i - 1]:
        lo_i -= 1
    hi_i = i0
    while hi_i < n_grid - 1 and good[hi_i + 1]:
        hi_i += 1
    L_max = float("inf") if lo_i == 0 else float(1.0 / x[lo_i])
    L_min = float(1.0 / x[hi_i])
    return (L_min, L_max)


@dataclass(frozen=True)
class MirrorSolution:
    """The second solution of a flagged beam.

    The calibration's (3c,) parameters there (per channel beta_rad, rho_mm, d_b_mm), their covariance from its
    own curvature, delta chi2 above the kept minimum and its normalised weight.
    """

    params: tuple[float, ...]
    cov: tuple[tuple[float, ...], ...]
    delta_chi2: float
    weight: float

    @property
    def params_array(self) -> np.ndarray:
        """Return the parameters as a float array."""
        return np.asarray(self.params, dtype=float)

    @property
    def cov_array(self) -> np.ndarray:
        """Return the covariance as a float array."""
        return np.asarray(self.cov, dtype=float)


@dataclass(frozen=True)
class BeamMirror:
    """The mirror check of one beam (``TriCalibration.diagnostics["mirror_check"]``, one per channel).

    ``predicted_delta_chi2``: Eq. (1) of the module at the fitted rho and offsets; ``refit_delta_chi2``:
    the explicit refit from -rho (None when it returned to the kept minimum: no mirror);
    ``resolved``: no mirror or refit_delta_chi2 >= :data:`RESOLVED_DCHI2`; for a flagged beam
    ``weight_main`` and ``p_wrong_sign`` (the two solutions' normalised weights), ``alternative`` and
    ``valid_bore_diameter_mm`` (where the calibration may be used); ``offset_to_resolve_mm`` the
    spindle offset X that would put the mirror at delta chi2 = 25 on a scan of the same samples;
    ``refitted``: whether the refit from -rho was made (issue 38: not where no mirror is possible or where
    the predicted depth and ``start_delta_chi2``, the cost at the unrefitted mirror start, which the refit
    could only lower, are both far above the threshold,
    :data:`borescan.calibrate.mirror_search.MIRROR_CLEAR_DCHI2`). Where the sign is not determined,
    ``offset_limit_mm`` is the largest offset the sensors' range allows at this gauge
    (:func:`borescan.plan.largest_offset_mm`) and ``samples_to_resolve`` the samples per channel that
    would resolve it at that offset (:func:`borescan.plan.samples_to_resolve`); :meth:`fix` says which.
    """

    channel: int
    rho_mm: float
    offset_mm: float
    mirror_possible: bool
    predicted_delta_chi2: float
    refit_delta_chi2: float | None
    resolved: bool
    weight_main: float
    p_wrong_sign: float
    offset_to_resolve_mm: float
    alternative: MirrorSolution | None = None
    rho_alt_mm: float | None = None
    valid_bore_diameter_mm: tuple[float, float] | None = None
    refitted: bool = True
    start_delta_chi2: float | None = None
    offset_limit_mm: float | None = None
    samples_to_resolve: float | None = None

    @property
    def one_valley(self) -> bool:
        """Return whether the mirror is predicted within 25 but the refit found no separate minimum.

        One valley through both signs: the sign is not determined, and the rho profile carries the spread.
        """
        return bool(
            self.resolved
            and self.mirror_possible
            and self.refit_delta_chi2 is None
            and self.predicted_delta_chi2 < RESOLVED_DCHI2
        )

    @property
    def sign_determined(self) -> bool:
        """Return whether the scan determines the sign of rho (module doc: one rule, two forms when not)."""
        return bool(self.resolved and not self.one_valley)

    def to_dict(self) -> dict[str, Any]:
        """Return the fields as a JSON-ready dict (NaN as None, infinities as ``"inf"`` or ``"-inf"``).

        With ``sign_determined`` and ``one_valley`` (derived, not read back by :meth:`from_dict`).
        """
        d = asdict(self)
        d["sign_determined"] = self.sign_determined
        d["one_valley"] = self.one_valley
        for k, v in d.items():
            if isinstance(v, float) and not math.isfinite(v):
                d[k] = None if math.isnan(v) else ("inf" if v > 0 else "-inf")
        if self.valid_bore_diameter_mm is not None:
            d["valid_bore_diameter_mm"] = [
                x if math.isfinite(x) else "inf" for x in self.valid_bore_diameter_mm
            ]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> BeamMirror:
        """Rebuild a BeamMirror from :meth:`to_dict`'s dict."""

        def f(x):
            return float("inf") if x == "inf" else float("nan") if x is None else float(x)

        alt = d.get("alternative")
        vb = d.get("valid_bore_diameter_mm")
        return cls(
            channel=int(d["channel"]),
            rho_mm=f(d["rho_mm"]),
            offset_mm=f(d["offset_mm"]),
            mirror_possible=bool(d["mirror_possible"]),
            predicted_delta_chi2=f(d["predicted_delta_chi2"]),
            refit_delta_chi2=None if d.get("refit_delta_chi2") is None else f(d["refit_delta_chi2"]),
            resolved=bool(d["resolved"]),
            weight_main=f(d["weight_main"]),
            p_wrong_sign=f(d["p_wrong_sign"]),
            offset_to_resolve_mm=f(d["offset_to_resolve_mm"]),
            alternative=None
            if alt is None
            else MirrorSolution(
                tuple(float(x) for x in alt["params"]),
                tuple(tuple(float(x) for x in row) for row in alt["cov"]),
                float(alt["delta_chi2"]),
                float(alt["weight"]),
            ),
            rho_alt_mm=None if d.get("rho_alt_mm") is None else f(d["rho_alt_mm"]),
            valid_bore_diameter_mm=None if vb is None else (f(vb[0]), f(vb[1])),
            refitted=bool(d.get("refitted", True)),
            start_delta_chi2=None if d.get("start_delta_chi2") is None else f(d["start_delta_chi2"]),
            offset_limit_mm=None if d.get("offset_limit_mm") is None else f(d["offset_limit_mm"]),
            samples_to_resolve=None if d.get("samples_to_resolve") is None else f(d["samples_to_resolve"]),
        )

    def fix(self) -> str:
        """Return what would resolve the sign, within the sensors' range (``borescan plan``'s rule).

        The offset X that puts the mirror at delta chi^2 = 25 where the range allows it (or the offsets
        at which no mirror exists, |rho| <= sqrt(2) e); where no allowed offset resolves it, the samples
        per channel that would at the largest allowed offset, or a longer-range sensor.
        """
        x, lim = self.offset_to_resolve_mm, self.offset_limit_mm
        if lim is None or not math.isfinite(lim):
            return f"a spindle offset of at least {x:.2f} mm from the gauge centre would resolve it"
        if x <= lim:
            return (
                f"a spindle offset of at least {x:.2f} mm from the gauge centre would resolve it "
                f"(the sensors' range allows up to {lim:.2f} mm)"
            )
        if not mirror_exists(self.rho_mm, lim):
            return (
                f"a spindle offset between {abs(self.rho_mm) / math.sqrt(2.0):.2f} and {lim:.2f} mm from the "
                "gauge centre (the most the sensors' range allows) would resolve it: there no mirror exists"
            )
        n = self.samples_to_resolve
        take = (
            f"{math.ceil(n)} samples per channel at that offset (more revolutions or samples per revolution)"
            if n is not None and math.isfinite(n)
            else "more samples"
        )
        return (
            f"no spindle offset the sensors' range allows resolves it: it needs {x:.2f} mm and the range "
            f"allows {lim:.2f} mm; take {take} or a longer-range sensor"
        )

    def statement(self) -> str:
        """One sentence for a certificate or report."""
        if self.one_valley:
            return (
                f"the sign of rho of channel {self.channel} is not determined by this scan: one valley "
                f"through both signs (mirror predicted {self.predicted_delta_chi2:.1f} chi^2 above, the "
                f"refit from -rho found no separate minimum); rho = {self.rho_mm:+.4f} mm with u spanning "
                f"both signs; {self.fix()}"
            )
        if self.resolved:
            if self.refit_delta_chi2 is not None:
                how = f"mirror {self.refit_delta_chi2:.1f} chi^2 above the solution"
            elif not self.mirror_possible:
                how = "no mirror solution (|rho| <= sqrt(2) e)"
            elif not self.refitted:
                how = f"mirror predicted {self.predicted_delta_chi2:.1f} chi^2 above the solution"
            else:
                how = "the refit from -rho returned to this solution"
            return f"channel {self.channel}: sign of rho resolved ({how})"
        lo, hi = self.valid_bore_diameter_mm or (float("nan"), float("nan"))
        hi_s = "no upper limit" if not math.isfinite(hi) else f"{hi:.1f} mm"
        return (
            f"the sign of rho of channel {self.channel} is not determined by this scan: two solutions, "
            f"rho = {self.rho_mm:+.4f} mm (weight {format_probability(self.weight_main)}) and "
            f"{self.rho_alt_mm if self.rho_alt_mm is not None else float('nan'):+.4f} mm "
            f"(delta chi^2 {self.refit_delta_chi2:.2f}, weight {format_probability(self.p_wrong_sign)} = "
            "probability of the "
            f"wrong sign); use for bores of diameter {lo:.1f} mm to {hi_s}; {self.fix()}"
        )


def mirror_checks_of(diagnostics: dict | None) -> list[BeamMirror]:
    """Return the calibration's mirror checks (``diagnostics["mirror_check"]``), typed; [] when absent."""
    return [BeamMirror.from_dict(d) for d in (diagnostics or {}).get("mirror_check", [])]


def mixture_components(
    params: np.ndarray, cov: np.ndarray, checks: Sequence[BeamMirror]
) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """Return the calibration as a mixture: (weight, params (3c,), cov (3c, 3c)) per component.

    The kept solution and one component per flagged beam's mirror, weights exp(-delta chi2 / 2) normalised
    over all of them.

    Joint flips of two flagged beams (weight of order exp(-(d_1 + d_2) / 2)) are not components.
    """
    alts = [m.alternative for m in checks if not m.resolved and m.alternative is not None]
    raw = np.array([1.0] + [math.exp(-0.5 * max(a.delta_chi2, 0.0)) for a in alts])
    w = raw / raw.sum()
    out = [(float(w[0]), np.asarray(params, float), np.asarray(cov, float))]
    out += [(float(wk), a.params_array, a.cov_array) for wk, a in zip(w[1:], alts)]
    return out


@dataclass(frozen=True)
class MixtureDiameter:
    """A diameter measured with a flagged calibration, with the components of its mixture.

    The two-solution mixture propagated by Monte Carlo (JCGM 101:2008). Per component (the kept solution, each
    flagged beam's mirror): weight, D_T with that solution's beams and its standard uncertainty; of the
    mixture: the estimate (the mean), u (the standard deviation), the probabilistically symmetric coverage
    interval for ``p`` (JCGM 101 7.7), at the scan's temperature and at 20 degC; ``draws`` and ``seed``
    (deterministic: from the scan and calibration ids).
    """

    weights: tuple[float, ...]
    diameters_mm: tuple[float, ...]
    u_components_mm: tuple[float, ...]
    diameter_mm: float
    u_mm: float
    interval_mm: tuple[float, float]
    diameter_20_mm: float
    u_20_mm: float
    interval_20_mm: tuple[float, float]
    p: float
    draws: int
    seed: int

    def to_dict(self) -> dict:
        """Return the fields as a JSON-ready dict."""
        return asdict(self)


#: Monte Carlo trials of a mixture diameter (JCGM 101 7.2: 10^6 for a 95 % interval to about 2 digits)
MIXTURE_DRAWS = 1_000_000


def mixture_diameter(
    components: Sequence[tuple[float, float, float]],
    factor_20: float,
    u_20_main_mm: float,
    u_t_main_mm: float,
    p: float,
    seed: int,
    draws: int = MIXTURE_DRAWS,
) -> MixtureDiameter:
    """Monte Carlo of a diameter whose calibration has several weighted solutions (JCGM 101:2008).

    Parameters
    ----------
    components : (weight, D_T [mm], extra variance [mm^2]) per solution, the kept one first; the extra
        variance is what that solution's own fit covariance adds over the kept one's (0 for the kept one)
    factor_20 : D20 / D_T (ISO 1 thermal correction)
    u_20_main_mm, u_t_main_mm : the GUM budget's u of D20 and D_T with the kept solution
    p : coverage probability; seed : the generator's seed; draws : trials

    Each trial picks a solution by its weight and draws D_T ~ N(D_k, u_T^2 + extra_k) and, with the same
    normal deviate, D20 = f D_k + z sqrt(u_20^2 + f^2 extra_k) (the budget's inputs are common to every
    solution). The estimate is the mean, u the standard deviation, the interval the p-quantiles' symmetric
    pair (JCGM 101 7.7).
    """
    w = np.array([c[0] for c in components], dtype=float)
    w = w / w.sum()
    d = np.array([c[1] for c in components], dtype=float)
    extra = np.array([max(c[2], 0.0) for c in components], dtype=float)
    rng = np.random.default_rng(seed)
    k = rng.choice(w.size, size=draws, p=w)
    z = rng.standard_normal(draws)
    u_t = np.sqrt(u_t_main_mm**2 + extra)
    u_20 = np.sqrt(u_20_main_mm**2 + factor_20**2 * extra)
    x_t = d[k] + z * u_t[k]
    x_20 = factor_20 * d[k] + z * u_20[k]
    q = [(1.0 - p) / 2.0, (1.0 + p) / 2.0]
    lo_t, hi_t = np.quantile(x_t, q)
    lo_20, hi_20 = np.quantile(x_20, q)
    return MixtureDiameter(
        weights=tuple(float(x) for x in w),
        diameters_mm=tuple(float(x) for x in d),
        u_components_mm=tuple(float(x) for x in u_t),
        diameter_mm=float(x_t.mean()),
        u_mm=float(x_t.std(ddof=1)),
        interval_mm=(float(lo_t), float(hi_t)),
        diameter_20_mm=float(x_20.mean()),
        u_20_mm=float(x_20.std(ddof=1)),
        interval_20_mm=(float(lo_20), float(hi_20)),
        p=float(p),
        draws=int(draws),
        seed=int(seed),
    )


def mixture_seed(*ids: str) -> int:
    """Return a deterministic seed from ids (sha256, first 8 bytes)."""
    import hashlib

    return int.from_bytes(hashlib.sha256("\x1f".join(ids).encode()).digest()[:8], "little")


def refusal(
    scan_id: str, calibration_id: str, diameter_mm: float, checks: Sequence[BeamMirror]
) -> str | None:
    """Return the reason a diameter of ``diameter_mm`` may not be measured with this calibration, else None.

    That is a flagged beam whose valid bore range excludes it.
    """
    for m in checks:
        if m.resolved or m.valid_bore_diameter_mm is None:
            continue
        lo, hi = m.valid_bore_diameter_mm
        if not lo <= diameter_mm <= hi:
            hi_s = "no upper limit" if not math.isfinite(hi) else f"{hi:.1f} mm"
            return (
                f"{scan_id}: bore diameter {diameter_mm:.3f} mm "
                f"outside {lo:.1f} mm to {hi_s}, the range where "
                f"calibration {calibration_id} may be used: the sign of rho of channel {m.channel} is not "
                "determined by its scan (probability of the wrong "
                f"sign {format_probability(m.p_wrong_sign)}), and away from the "
                f"gauge its two solutions place the wall points apart; to recalibrate: {m.fix()}"
            )
    return None
