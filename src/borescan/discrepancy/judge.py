"""What a candidate must satisfy to be named, and what the verdict then says.

Three rules, each stated once and applied to every candidate (singles and pairs) before the information
criterion chooses among them:

- **plausible**: every fitted size within its plausible range (schema ``discrepancy.plausible_ranges``,
  each with its reason), to :data:`BOUND_SIGMAS` standard uncertainties but no more than
  :data:`PLAUSIBLE_MARGIN` of the range's half-width (:meth:`PlausibleRange.admits`); a candidate that
  needs a value farther out is dropped and the finding says so ("explained only by a 1.70 mm sensor
  offset on channel 3: no sensor of this range has ..."). A fit within its uncertainty of a bound does
  not need the value beyond it (battery static 110 of seed 2: a true bow of 0.090 mm, fitted 0.1003 +-
  0.014 mm with its gain, was dropped against the 0.1 mm bound and the scan named as another channel's
  gain);
- **physical**: within the registry's bounds (a beam tilt only lengthens a reading), to
  :data:`BOUND_SIGMAS` standard uncertainties;
- **scope-consistent**: a bore's form, the spindle's motion or speed and the time base reach every channel
  that sees the bore, each through its own beam geometry; a candidate whose effects of that scope reach,
  together, one channel only (their signatures cancel on the others: what the base cannot absorb of them
  sits on one channel and what is left on the others is not seen, chi-square at most 9) is explaining a
  one-channel pattern and is dropped: a one-channel pattern belongs to that channel's sensor or beam.

A verdict names its effects as *the* explanation only when their fit converged and left the gap within
``floor_ratio`` (1.10) of the noise floor; otherwise the finding is "partly explained" and says what
remains (:func:`explanation`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from borescan.config import schema_default
from borescan.discrepancy.search import Candidate, rms
from borescan.discrepancy.terms import Term, term_parameters
from borescan.effects import EFFECTS

__all__ = [
    "PlausibleRange",
    "plausible_ranges",
    "Rejection",
    "implausible",
    "unphysical",
    "scope_conflict",
    "judge",
    "explanation",
    "BOUND_SIGMAS",
    "PLAUSIBLE_MARGIN",
    "CONFINED_SHARE",
    "SEEN_CHI2",
]

#: a combination of artifact/spindle/time-scope effects whose signature puts this share of its chi-square
#: on one channel reaches that channel only (three channels that see a bore share it about equally)
CONFINED_SHARE = 0.8
#: a fitted value needs a bound's far side (plausible or physical) when it lies this many standard
#: uncertainties beyond it
BOUND_SIGMAS = 2.0
#: the most a fit's uncertainty widens a plausible range, as a share of the range's half-width: a poorly
#: determined value (a static set's single-channel offset, 0.99 +- 0.27 mm against 0.5 mm) is not made
#: plausible by its own spread
PLAUSIBLE_MARGIN = 0.1
#: chi-square (noise units) of a signature that the data see: a confined signature reaches the other
#: channels when its part there is above this
SEEN_CHI2 = 9.0


@dataclass(frozen=True)
class PlausibleRange:
    """The plausible values of one effect's size parameter (schema ``discrepancy.plausible_ranges``).

    low, high : bounds in the parameter's unit, or in multiples of the sensor's range when ``per_range``.
    """

    effect: str
    parameter: str
    low: float
    high: float
    per_range: bool
    reason: str

    def bounds(self, range_mm: float | None) -> tuple[float, float]:
        """Return the bounds in the parameter's unit (a per-range bound times ``range_mm``)."""
        f = float(range_mm) if self.per_range and range_mm else 1.0
        return self.low * f, self.high * f

    def admits(self, value: float, u: float, range_mm: float | None) -> bool:
        """Return whether a fitted ``value`` +- ``u`` is plausible.

        Plausible: within the bounds widened by :data:`BOUND_SIGMAS` u, at most :data:`PLAUSIBLE_MARGIN` of
        the range's half-width (a non-finite u widens nothing).
        """
        lo, hi = self.bounds(range_mm)
        slack = min(BOUND_SIGMAS * u, PLAUSIBLE_MARGIN * 0.5 * (hi - lo)) if math.isfinite(u) else 0.0
        return lo - slack <= value <= hi + slack


def plausible_ranges(section: dict | None = None) -> dict[str, PlausibleRange]:
    """Return effect -> :class:`PlausibleRange` from the schema's defaults, updated by ``section``."""
    merged = {**schema_default("discrepancy", "plausible_ranges"), **(section or {})}
    out = {}
    for effect, d in merged.items():
        if effect not in EFFECTS:
            raise ValueError(
                f"discrepancy.plausible_ranges: unknown effect {effect!r}; valid: {', '.join(EFFECTS)}"
            )
        high = float(d["high"])
        out[effect] = PlausibleRange(
            effect,
            str(d["parameter"]),
            float(d.get("low", -high)),
            high,
            bool(d.get("per_range")),
            str(d["reason"]),
        )
    return out


@dataclass(frozen=True)
class Rejection:
    """A candidate dropped before the information criterion chose: its terms, why, and the sentence."""

    terms: tuple[str, ...]
    rule: str  # "implausible", "unphysical" or "scope"
    delta_bic: float
    sentence: str

    def to_dict(self) -> dict:
        """JSON-ready form (findings.json ``rejected``)."""
        return {
            "terms": list(self.terms),
            "rule": self.rule,
            "delta_bic": self.delta_bic,
            "why": self.sentence,
        }


def _where(t: Term) -> str:
    return "" if t.channel is None else " on every channel" if t.channel == 0 else f" on channel {t.channel}"


def _range_of(model, t: Term) -> float | None:
    """Return the sensor range [mm] of the term's channel (the smallest for an every-channel term), or None.

    Read from the model's data, else from its scans' (a pooled model); None when no range is known.
    """
    datas = [model.data] + [getattr(k, "data", None) for k in getattr(model, "scans", ())]
    for d in datas:
        rng = np.atleast_1d(getattr(d, "range_mm", np.array([])))
        chans = list(getattr(d, "channels", ()))
        if rng.size and rng.size == len(chans):
            return float(rng[chans.index(t.channel)]) if t.channel in chans else float(np.min(rng))
    return None


def implausible(model, cand: Candidate, ranges: dict[str, PlausibleRange]) -> str | None:
    """Return the sentence of the first fitted size its plausible range does not admit, or None.

    The size judged is the fitted value plus the model's ``plausibility_origin`` where it has one (a rod's
    beam tilt adds to its layer's nominal angle: the beam's own angle is judged).
    """
    x, u = cand.fit.values(), cand.fit.uncertainties()
    for t in cand.terms:
        pr = ranges.get(t.effect)
        if pr is None:
            continue
        par, unc = term_parameters(t, x, u)
        if pr.parameter not in par:
            continue
        v, uv = float(par[pr.parameter]), float(unc.get(pr.parameter, math.nan))
        origin = model.plausibility_origin(t, pr.parameter) if hasattr(model, "plausibility_origin") else 0.0
        v += origin
        name = pr.parameter if origin == 0.0 else f"the nominal {origin:.4g} + {pr.parameter}"
        range_mm = _range_of(model, t)
        if pr.per_range and range_mm is None:
            continue  # a limit in sensor ranges with no range known: not judged
        if not pr.admits(v, uv, range_mm):
            lo, hi = pr.bounds(range_mm)
            unit = EFFECTS[t.effect].params.get(pr.parameter, "")
            return (
                f"explained only by {t.effect}{_where(t)} with {name} = {v:.4g} +- {uv:.2g} {unit}, "
                f"outside the plausible {lo:.4g} to {hi:.4g} {unit}: {pr.reason}"
            )
    return None


def unphysical(cand: Candidate) -> str | None:
    """Return why a fit needs a value more than two standard uncertainties outside its registry bounds."""
    v, u = cand.fit.values(), cand.fit.uncertainties()
    for t in cand.terms:
        for q in EFFECTS[t.effect].fit_params(t.device):
            n = f"{t.key}.{q.name}"
            if v[n] < q.lower - BOUND_SIGMAS * u[n] or v[n] > q.upper + BOUND_SIGMAS * u[n]:
                return (
                    f"{t.key} needs {q.name} = {v[n]:.3g}, outside its physical bounds [{q.lower}, {q.upper}]"
                )
    return None


def _reaches_all(t: Term) -> bool:
    """Return True for an effect of the bore, the spindle or the time base, or one value on every channel."""
    return t.channel == 0 or not EFFECTS[t.effect].per_channel


def scope_conflict(model, cand: Candidate, absorbable: np.ndarray, sig_ref_mm: float) -> str | None:
    """Return why a candidate gives a one-channel pattern to effects that reach every channel, or None.

    The signature of the candidate's every-channel terms (bore, spindle, time base, a common value) is the
    change of the weighted prediction when they are set to zero at the fit; its part the base model cannot
    absorb (orthogonal to the columns of ``absorbable``, the base Jacobian) is what the data show of them.
    That part must not sit on one channel: a share above :data:`CONFINED_SHARE` of a chi-square above
    :data:`SEEN_CHI2` (noise units, ``sig_ref_mm`` the weighted noise floor) on one channel of two or more,
    with at most :data:`SEEN_CHI2` left on the others, is a conflict. A signature whose part on the other
    channels the data do see reaches them: with the beams free, what the base cannot absorb of a spindle
    motion may sit mostly on one channel (battery calibration 56 of seed 2, k = 2: 86 % of chi-square 276
    on channel 3, 40 on the others), and it is still no channel's pattern (the best one-channel candidate,
    that channel's gain, gained 345 in BIC against the motion's 569).
    """
    wide = [t for t in cand.terms if _reaches_all(t)]
    if not wide or len(model.data.channels) < 2:
        return None
    p = cand.fit.values()
    off = dict(p)
    for t in wide:
        for n in t.names():
            if not n.endswith("f_hz"):
                off[n] = 0.0
    terms = list(cand.terms)
    s = model.residual(off, terms) - model.residual(p, terms)
    if absorbable.size and np.all(np.isfinite(absorbable)) and np.all(np.isfinite(s)):
        s = s - absorbable @ np.linalg.lstsq(absorbable, s, rcond=None)[0]
    chan = np.nonzero(model.mask)[1]
    e = np.bincount(chan, weights=(s / max(sig_ref_mm, 1e-12)) ** 2, minlength=len(model.data.channels))
    total = float(np.sum(e))
    if not np.isfinite(total) or total <= SEEN_CHI2:
        return None
    j = int(np.argmax(e))
    if e[j] / total <= CONFINED_SHARE:
        return None
    if total - e[j] > SEEN_CHI2:
        return None  # the data see it on the other channels too
    names = " + ".join(t.key for t in wide)
    return (
        f"{names} would reach every channel, but what the data show of it ({e[j] / total:.0%} of its "
        f"signature) is on channel {model.data.channels[j]} alone: a pattern of one channel belongs to that "
        "channel's sensor or beam"
    )


def judge(
    model,
    cands: list[Candidate],
    absorbable: Callable[[], np.ndarray],
    sig_ref_mm: float,
    ranges: dict[str, PlausibleRange],
    base_bic: float,
) -> tuple[list[Candidate], list[Rejection]]:
    """Split candidates into those that may be named and the rejected ones (with their sentences).

    Every candidate is judged: one below the threshold may still be tied with the best (within the threshold
    of it) and so be named. ``absorbable()``: the base model's weighted Jacobian at its fit (what the base
    absorbs, for :func:`scope_conflict`); ``sig_ref_mm`` the weighted noise floor.
    """
    keep, out = [], []
    for c in cands:
        rules = (
            ("implausible", lambda c=c: implausible(model, c, ranges)),
            ("unphysical", lambda c=c: unphysical(c)),
            ("scope", lambda c=c: scope_conflict(model, c, absorbable(), sig_ref_mm)),
        )
        for rule, check in rules:
            why = check()
            if why:
                out.append(Rejection(c.keys, rule, float(base_bic - c.fit.bic), why))
                break
        else:
            keep.append(c)
    return keep, out


def explanation(
    model, named_fits: list[Candidate], r_after: np.ndarray, sigma_mm: np.ndarray, floor_ratio: float
) -> tuple[str, dict | None]:
    """Return ("fully" | "partly", what remains) of a verdict's fits and the residual they leave.

    "fully": every fit converged and the gap after is within ``floor_ratio`` of the noise floor.
    Otherwise "partly", with the gap after as a multiple of the floor, whether the fit converged, and the
    channels whose residual is above the floor (rms per channel over its own floor).
    """
    sig_ref = float(np.sqrt(np.mean(sigma_mm**2))) or 1e-6
    gap = rms(r_after, model.mask)
    ratio = gap / sig_ref
    converged = all(c.fit.success for c in named_fits)
    if converged and ratio <= floor_ratio:
        return "fully", None
    per = {}
    for j, ch in enumerate(model.data.channels):
        rj = rms(r_after[:, j : j + 1], model.mask[:, j : j + 1])
        if rj > floor_ratio * float(sigma_mm[j]):
            per[str(ch)] = rj / float(sigma_mm[j])
    return "partly", {
        "gap_after_over_floor": ratio,
        "floor_ratio": floor_ratio,
        "fit_converged": converged,
        "channels_above_floor": per,
    }
