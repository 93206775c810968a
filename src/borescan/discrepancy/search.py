"""The candidate search of one examination: linear screen, exact refits of singles, then pairs.

Every candidate is compared on one footing, the Bayesian information criterion of its weighted fit
(``BIC = n ln(RSS / n) + p ln(n)``): the linearised screen at the base fit estimates it, an exact refit
replaces the estimate. Exact refits are made only where the screen cannot decide (a candidate whose
linearised gain falls more than twice the threshold short of the best exact single can neither be named
nor seed a pair that counts); the nonlinear starts (axis tilt from the k = 2 lobing, a large speed error
from the readings' rotation line) are always refitted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from borescan.discrepancy.fitting import FitResult, fit_least_squares, residual_sparsity
from borescan.discrepancy.terms import Term

__all__ = [
    "BIC_TIE",
    "BaseProjection",
    "Candidate",
    "by_bic",
    "Fitter",
    "Search",
    "jacobian_columns",
    "lstsq",
    "rms",
    "search_candidates",
    "tie_sorted",
]


@dataclass(frozen=True)
class Candidate:
    """An exact fit of the base model with one or two candidate terms."""

    fit: FitResult
    terms: tuple[Term, ...]

    @property
    def keys(self) -> tuple[str, ...]:
        """The terms' keys (``sensor_gain@2``, ``bore_lobing[k=3]``)."""
        return tuple(t.key for t in self.terms)


@dataclass(frozen=True)
class Screened:
    """A candidate of the linear screen: its linearised RSS, the term and the start it gives."""

    rss: float
    term: Term
    start: dict


def jacobian_columns(
    model,
    p: dict,
    terms: list[Term],
    names: list[str],
    scales: list[float],
    f0: np.ndarray | None = None,
    about: tuple[dict, list[Term]] | None = None,
) -> np.ndarray:
    """Forward-difference columns of the weighted model over the unmasked samples, per unit scale.

    ``f0``: the residual at ``p`` when the caller has it (a candidate term at zero adds nothing:
    its residual is the one without it, bit for bit), else it is evaluated here. ``about``: the point
    (parameters, terms) ``p`` adds zero-valued terms to; a model with ``residual_first_order`` then takes
    the steps it can to first order about it (the tri model's bore and spindle-position steps,
    :mod:`borescan.discrepancy.tri_screen`), the others exactly.
    """
    if f0 is None:
        f0 = model.residual(p, terms)
    first_order = getattr(model, "residual_first_order", None) if about is not None else None
    cols = []
    for n, s in zip(names, scales):
        q = dict(p)
        q[n] = q[n] + s
        r = None if first_order is None else first_order(about, q, terms)
        cols.append(f0 - (model.residual(q, terms) if r is None else r))  # d(model)/d(param) * scale
    return np.stack(cols, axis=1) if cols else np.zeros((f0.size, 0))


def lstsq(J: np.ndarray, r: np.ndarray) -> np.ndarray | None:
    """Return the linearised least-squares step of the screen, or None.

    None when the Jacobian or the residual is not finite (a finite-difference step left the model
    undefined) or the solver fails.
    """
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        return None
    try:
        return np.linalg.lstsq(J, r, rcond=None)[0]
    except np.linalg.LinAlgError:
        return None


class BaseProjection:
    """The linearised fit of the base (or base + seed) columns, shared by every screened term.

    The joint least-squares fit of ``[J0, Jt]`` to ``r`` is the fit of the term's columns projected off
    ``J0``'s span to the projected residual, then ``J0``'s coefficients for what the term leaves: one SVD
    of ``J0`` for the whole screen instead of one least-squares solve of the full matrix per term.
    Singular values below ``lstsq``'s default cut (machine epsilon times the larger dimension, relative to
    the largest of the joint matrix, bounded here by the larger of ``J0``'s and the term columns' norm)
    are dropped, as the joint solve drops them.
    """

    def __init__(self, J0: np.ndarray, r: np.ndarray):
        self.ok = bool(np.all(np.isfinite(J0)) and np.all(np.isfinite(r)))
        self.r = r
        m = max(J0.shape[0], J0.shape[1] + 1)
        self.eps = np.finfo(float).eps * m
        if not self.ok or J0.shape[1] == 0:
            self.U, self.Vs, self.s0 = np.zeros((r.size, 0)), np.zeros((J0.shape[1], 0)), 0.0
            self.r_perp = r
            return
        U, s, Vt = np.linalg.svd(J0, full_matrices=False)
        self.s0 = float(s[0])
        keep = s > self.eps * self.s0
        self.U, self.Vs = U[:, keep], Vt[keep].T / s[keep]
        self.r_perp = r - self.U @ (self.U.T @ r)

    def fit(self, Jt: np.ndarray) -> tuple[float, np.ndarray] | None:
        """Return the linearised RSS of base + term and the coefficients (base columns first), or None.

        None when the term's columns are not finite (a finite-difference step left the model undefined).
        """
        if not (self.ok and np.all(np.isfinite(Jt))):
            return None
        Tp = Jt - self.U @ (self.U.T @ Jt)
        try:
            Ut, st, Vtt = np.linalg.svd(Tp, full_matrices=False)
        except np.linalg.LinAlgError:
            return None
        cut = self.eps * max(self.s0, float(np.linalg.norm(Jt)))  # Frobenius: >= the 2-norm, no SVD
        keep = st > cut
        c_t = Vtt[keep].T @ ((Ut[:, keep].T @ self.r_perp) / st[keep])
        resid = self.r_perp - Tp @ c_t
        c_0 = self.Vs @ (self.U.T @ (self.r - Jt @ c_t))
        return float(resid @ resid), np.concatenate([c_0, c_t])


#: BICs closer than this are a tie [BIC units]: look-alikes' fits agree to their convergence (a rotating
#: measurement's beam_tilt@1 and sensor_gain@1, each with a vibration, at 59078.4345305 to 1.6e-9; the fits
#: stop at ftol 1e-8 of the cost, n x 1e-8 in BIC: 6e-4 for 60 000 samples), far below any difference the
#: decision reads (its threshold, ~10); their order, which the last digits would decide, goes by name
BIC_TIE = 0.01


def tie_sorted(items: list, score, name, tie: float = BIC_TIE) -> list:
    """Return ``items`` by ``score`` ascending; scores within ``tie`` of a run's first by ``name`` instead."""
    out: list = []
    group: list = []
    for z in sorted(items, key=score):
        if group and score(z) - score(group[0]) > tie:
            out += sorted(group, key=name)
            group = []
        group.append(z)
    return out + sorted(group, key=name)


def by_bic(cands: list[Candidate]) -> list[Candidate]:
    """Return the candidates best BIC first; ties (:data:`BIC_TIE`) in the order of their keys."""
    return tie_sorted(cands, lambda z: z.fit.bic, lambda z: (z.keys, z.fit.bic))


def rms(r: np.ndarray, mask: np.ndarray) -> float:
    """Root mean square of the finite residuals under ``mask`` (NaN for none) [mm]."""
    x = r[mask & np.isfinite(r)]
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def _fitted(t: Term) -> tuple[list[str], list[float]]:
    """Return a term's linearly screened names and scales (a vibration's frequency is held at its start)."""
    keep = [(n, s) for n, s in zip(t.names(), t.scales()) if not n.endswith("f_hz")]
    return [n for n, _ in keep], [s for _, s in keep]


#: evaluation cap of a base fit (no terms): every candidate is compared with it and starts from it, so it
#: must converge; from the design, a calibration's free beams can take ~170 evaluations to absorb a large
#: eccentricity (battery calibration 201 of seed 1: stopped at 60 its RSS was 35 % above the converged
#: one, and every candidate "gained" ~4800 in BIC by finishing the base's own fit)
BASE_MAX_NFEV = 300


class Fitter:
    """Exact fits of the base model plus terms, with the base fit as the fallback start."""

    def __init__(self, model):
        self.model = model
        self.base_names = model.base_names()
        self.base_scales = model.base_scales()
        self.fallback: dict[str, float] = {}
        #: the base frees beam geometry (a calibration): fitted in (psi, rho, g) (``TriModel.beams_at``) the
        #: rho/d_b valley of (beta, rho, d_b) is an axis, but a base fit that absorbs a large missing effect
        #: still moves rho by mm to tens of mm, where a candidate's fit may need more evaluations or a start
        #: nearer the design; a rod model has such a valley too (its ``flat_valley``: pose angles, centres and
        #: deflection); the static model's fits are left as they were (their caps are their budgets)
        self.flat_valley = bool(getattr(model, "free_beams", ()) or getattr(model, "flat_valley", False))

    def __call__(self, terms: list[Term], start: dict[str, float]) -> FitResult | None:
        """Fit base + terms from ``start``; None when the model cannot be fitted.

        If the model is undefined there (a ray missing the bore), from the base fit with zero effects;
        None when that fails too. Where the base frees beam geometry (``flat_valley``), a base fit (no
        terms) may take up to :data:`BASE_MAX_NFEV` evaluations, and a fit with terms that stops at its
        evaluation cap is fitted again with the base parameters at the base model's own start (the terms'
        values kept), the lower RSS kept: a base fit that absorbed a large missing effect moves the beams
        far out (offsets 12 mm out to mimic an axis tilt's ellipse), from where the term's fit may stop at
        its cap, while from the base's start it lands in a few (:func:`_restart`).
        """
        if not terms:
            return self._fit(terms, start, BASE_MAX_NFEV if self.flat_valley else 60)
        fr = self._fit(terms, start)
        if fr is None or fr.success or not self.flat_valley:
            return fr
        again = self._fit(terms, _restart(start, self.model.base_start(), self.base_names))
        return again if again is not None and again.rss < fr.rss else fr

    def _fit(self, terms: list[Term], start: dict[str, float], max_nfev: int = 60) -> FitResult | None:
        """Fit base + terms from ``start``, else from the fallback (the base fit, zero effects)."""
        model = self.model
        names = self.base_names + [n for t in terms for n in t.names()]
        scales = self.base_scales + [s for t in terms for s in t.scales()]
        sparsity = residual_sparsity(
            names, model.mask, model.data.channels, getattr(model.data, "pose_index", None)
        )
        stack = _residual_stack(model, terms)  # the forward differences in one call, where it can
        for st in (start, {**self.fallback, **{k: v for k, v in start.items() if k.endswith("f_hz")}}):
            xs = [st.get(n, 0.0) for n in names]
            try:
                fr = fit_least_squares(
                    lambda p: model.residual(p, terms),
                    names,
                    xs,
                    scales,
                    sparsity=sparsity,
                    max_nfev=max_nfev,
                    residual_stack_fn=stack,
                )
            except ValueError:
                continue
            if np.isfinite(fr.rss):
                return fr
        return None


def _residual_stack(model, terms: list[Term]):
    """Return ``model.residual`` at the forward differences' steps from a point, or None.

    ``run(p, ps)``: the residuals at the steps ``ps`` from ``p``. With ``model.predict_stack`` (the rod) the
    sets that share their term values (forward differences in base parameters) are predicted in one
    stacked call each (the effects are the same for the whole stack), a set alone one by one. With
    ``model.residual_first_order`` (the tri model) a step in the bore or the spindle axis is taken to first
    order about ``p`` (:mod:`borescan.discrepancy.tri_screen`), any other exactly. None for neither.
    """
    first_order = getattr(model, "residual_first_order", None)
    if first_order is not None:

        def run_first_order(p: dict[str, float], ps: list[dict[str, float]]) -> list[np.ndarray]:
            out = [first_order((p, terms), q, terms) for q in ps]
            return [model.residual(q, terms) if r is None else r for q, r in zip(ps, out, strict=True)]

        return run_first_order
    predict_stack = getattr(model, "predict_stack", None)
    if predict_stack is None:
        return None
    names = [n for t in terms for n in t.names()]

    def run(p: dict[str, float], ps: list[dict[str, float]]) -> list[np.ndarray]:
        keys = [tuple(q.get(n) for n in names) for q in ps]
        out: list = [None] * len(ps)
        for key in dict.fromkeys(keys):  # the sets with the same term values, in order of appearance
            idx = [i for i, k in enumerate(keys) if k == key]
            if len(idx) == 1:
                out[idx[0]] = model.residual(ps[idx[0]], terms)
                continue
            for i, v in zip(idx, predict_stack([ps[i] for i in idx], terms), strict=True):
                out[i] = model.weighted(v)
        return out

    return run


def _restart(start: dict[str, float], base_start: dict[str, float], base_names: list[str]) -> dict:
    """Return ``start`` with its base parameters at the base model's own start (a term's values kept)."""
    return {**start, **{n: base_start.get(n, 0.0) for n in base_names}}


def linear_screen(
    fitter: Fitter, p0: dict, seed: list[Term], terms: list[Term], vib_start: dict
) -> list[Screened]:
    """Linearised refits of every term beside ``seed`` at the fit ``p0`` (of base + seed), best first."""
    model = fitter.model
    r = model.residual(p0, seed)
    names0 = fitter.base_names + [n for t in seed for n in t.names()]
    scales0 = fitter.base_scales + [s for t in seed for s in t.scales()]
    proj = BaseProjection(jacobian_columns(model, p0, seed, names0, scales0, f0=r), r)
    out = []
    for t in terms:
        if not seed and t.channel == 0 and len(model.data.channels) == 1:
            continue  # a common term is the channel's own
        if seed and (t.key == seed[0].key or (t.effect == seed[0].effect and t.channel == seed[0].channel)):
            continue
        vib = vib_start if (not seed or t.effect == "vibration") else {}
        pt = {**p0, **{n: 0.0 for n in t.names()}, **vib}
        tn, ts = _fitted(t)
        fitted = proj.fit(jacobian_columns(model, pt, [*seed, t], tn, ts, f0=r, about=(p0, seed)))
        if fitted is None:  # the term's start leaves the model undefined (a ray missing the bore)
            continue
        rss, coef = fitted
        start = dict(pt)
        for n, s, a in zip(names0 + tn, scales0 + ts, coef):
            start[n] = start[n] + a * s
        out.append(Screened(rss, t, start))
    out = getattr(model, "settle_screen", list)(out)  # starts a model knows better than the linearisation
    out.sort(key=lambda z: z.rss)
    return out


@dataclass
class Search:
    """Everything the candidate search found (exact singles and pairs, best first) and its bookkeeping."""

    singles: list[Candidate] = field(default_factory=list)
    pairs: list[Candidate] = field(default_factory=list)
    screen: list[Screened] = field(default_factory=list)
    screen_dbic: list[float] = field(default_factory=list)
    gated: bool = False
    singles_skipped: int = 0
    skipped_bic: list[float] = field(default_factory=list)
    pairs_refitted: int = 0


def _lin_dbic(rss_before: float, rss: float, t: Term, n: int) -> float:
    """Linearised Delta BIC of adding ``t`` (its screened parameters) to a fit of RSS ``rss_before``."""
    return float(n * math.log(rss_before / max(rss, 1e-300)) - len(_fitted(t)[0]) * math.log(n))


def search_candidates(
    fitter: Fitter, base: FitResult, terms: list[Term], c: dict, sig_ref: float, vib_start: dict
) -> Search:
    """Screen every term, refit the singles the screen cannot rule out, extend the best by pairs."""
    model = fitter.model
    T = float(c["threshold"])
    p0 = base.values()
    out = Search(screen=linear_screen(fitter, p0, [], terms, vib_start))
    rvec = model.residual(p0, [])
    rss_base = float(np.sum(rvec**2))
    n_scr = max(int(rvec.size), 2)
    out.screen_dbic = [_lin_dbic(rss_base, z.rss, z.term, n_scr) for z in out.screen]
    # gate: a scan whose base residual is at the noise floor and whose best linearised candidate is far
    # below the threshold skips the exact refits (for the small effects such a screen allows, the
    # linearisation is accurate, and a pair gains about the sum of its singles)
    gap0 = rms(model.residual_matrix(p0, []), model.mask)
    out.gated = bool(
        out.screen and max(out.screen_dbic) < float(c["screen_gate"]) * T and gap0 <= 1.5 * sig_ref
    )
    if out.gated:
        return out
    chosen = out.screen[: int(c["n_exact"])]
    keys = {z.term.key for z in chosen}
    chosen = chosen + model.extra_starts(_as_tuples(out.screen), keys, None)
    best_gain = best_lin = -math.inf
    for z in chosen:
        z = z if isinstance(z, Screened) else Screened(*z)
        dlin = _lin_dbic(rss_base, z.rss, z.term, n_scr) if z.rss > 0.0 else math.inf
        # skipped only when far below the best on both footings: a large effect's exact gain can exceed
        # its linearised one many times (a rod's 0.24 mm bow: 3445 against 1258), and its look-alikes,
        # screened level with it, must still be refitted
        if dlin < min(best_gain - 2.0 * T, 0.5 * best_gain) and dlin < min(
            best_lin - 2.0 * T, 0.5 * best_lin
        ):
            out.singles_skipped += 1
            out.skipped_bic.append(base.bic - dlin)
            continue
        fr = fitter([z.term], z.start)
        if fr is not None:
            out.singles.append(Candidate(fr, (z.term,)))
            best_gain = max(best_gain, base.bic - fr.bic)
            best_lin = max(best_lin, dlin if math.isfinite(dlin) else -math.inf)
    out.singles = by_bic(out.singles)
    seen_keys: set[str] = set()
    uniq = []
    for z in out.singles:
        if z.keys[0] not in seen_keys:
            seen_keys.add(z.keys[0])
            uniq.append(z)
    out.singles = uniq
    _search_pairs(fitter, base, terms, c, sig_ref, vib_start, out)
    _singles_from_pairs(fitter, out, T)
    return out


def _singles_from_pairs(fitter: Fitter, out: Search, T: float) -> None:
    """Refit each term of the best pair alone from the pair's fit, where that pair would be named.

    A pair is named over the singles when it beats the best by the threshold; that gain must be its second
    term's, not a better minimum of the base the pair's fit reached. Each term of the best pair is refitted
    alone from the pair's fit (the other term's parameters left out) and replaces its single where it fits
    better (battery calibration 255 of seed 2: an axis tilt's single stopped 212 in BIC above the pair it
    made with a gain of -3e-6 on channel 2, which was then named; calibration 84: a spindle motion's single
    stopped 232 above its pairs with a beam tilt, a gain, a lobing or an axis tilt, all four named). Only
    the best pair's two terms (each refit of a calibration with its beams free costs about 0.7 s CPU).
    """
    if not out.pairs or not out.singles or out.pairs[0].fit.bic >= out.singles[0].fit.bic - T:
        return
    best = out.pairs[0]
    vals = best.fit.values()
    for t, other in ((best.terms[0], best.terms[1]), (best.terms[1], best.terms[0])):
        fr = fitter([t], {n: v for n, v in vals.items() if n not in other.names()})
        if fr is None:
            continue
        old = next((i for i, z in enumerate(out.singles) if z.keys == (t.key,)), None)
        if old is None:
            out.singles.append(Candidate(fr, (t,)))
        elif fr.bic < out.singles[old].fit.bic:
            out.singles[old] = Candidate(fr, (t,))
    out.singles = by_bic(out.singles)


def _as_tuples(screen: list[Screened]) -> list[tuple]:
    """Return the screen as the models' ``extra_starts`` read it: (rss, term, start) tuples."""
    return [(z.rss, z.term, z.start) for z in screen]


def _search_pairs(
    fitter: Fitter, base: FitResult, terms: list[Term], c: dict, sig_ref: float, vib_start: dict, out: Search
) -> None:
    """Extend the best singles by a second term (screened linearly at the single's fit); refit the pairs."""
    model = fitter.model
    T = float(c["threshold"])
    seen: set = set()
    todo: list[tuple] = []
    for seed in out.singles[: int(c["n_pair_seeds"])]:
        (t1,) = seed.terms
        p1 = seed.fit.values()
        ext = linear_screen(fitter, p1, [t1], terms, _vibration_start(model, p1, t1, vib_start))
        r1 = model.residual(p1, [t1])
        rss1 = float(np.sum(r1**2))
        n = max(int(r1.size), 2)
        gain = max((_lin_dbic(rss1, z.rss, z.term, n) for z in ext), default=-math.inf)
        # the single's gate: where the single leaves the gap at the noise floor and no second term gains
        # half the threshold at its fit (linearised), no pair can beat the single by the threshold
        if gain < float(c["screen_gate"]) * T and rms(model.residual_matrix(p1, [t1]), model.mask) <= (
            1.5 * sig_ref
        ):
            continue
        # a pair counts only if it beats the best single by the threshold (or, with no single passing,
        # the base by it): a seed whose own gain plus its best second term's falls short cannot get there
        if (base.bic - seed.fit.bic) + max(gain, 0.0) < max(base.bic - out.singles[0].fit.bic, 0.0):
            continue
        n_ext = int(c["n_pair_ext"])
        more = model.extra_starts(_as_tuples(ext), {z.term.key for z in ext[:n_ext]} | {"*"}, t1)
        for z in ext[:n_ext]:  # the pair's BIC as the screen at the single's fit estimates it
            todo.append((seed.fit.bic - _lin_dbic(rss1, z.rss, z.term, n), t1, z))
        todo += [(-math.inf, t1, Screened(*m)) for m in more]  # nonlinear starts: always refitted
    # exact refits only where the screen cannot decide: first the pairs whose estimate comes within
    # (1 - screen_gate) T of the bar a pair must pass (T below the best single and the base), then, if one
    # passed, those whose estimate may tie with the best pair (within T of it, the same margin)
    bar = min([base.bic] + [z.fit.bic for z in out.singles[:1]]) - T
    slack = (1.0 - float(c["screen_gate"])) * T
    _refit_pairs(fitter, [z for z in todo if z[0] < bar + slack], seen, out)
    if out.pairs and out.pairs[0].fit.bic < bar:
        _refit_pairs(fitter, [z for z in todo if z[0] < out.pairs[0].fit.bic + T + slack], seen, out)


def _vibration_start(model, p1: dict, t1: Term, vib_start: dict) -> dict:
    """Return the vibration's start beside a pair's first term: the line of the single's residual.

    The line is found in the base's residual first; a large effect's leakage can outshine it there
    (battery calibration 135 of seed 2: a 2-lobing at z 231 put the strongest line off the rotation's
    harmonics at 2.49 Hz, the vibration of z 17 at 12.573 Hz, which the lobing's residual shows). Unchanged
    where the base found no line (no vibration candidate) or the first term is the vibration.
    """
    if not vib_start or t1.effect == "vibration":
        return vib_start
    f_hz = model.vibration_f(np.where(model.mask, model.residual_matrix(p1, [t1]), np.nan))
    return vib_start if f_hz is None else {**vib_start, "vibration.f_hz": f_hz}


def _refit_pairs(fitter: Fitter, todo: list[tuple], seen: set, out: Search) -> None:
    """Refit each (estimate, first term, screened second term) pair not refitted yet; pairs best first."""
    for _, t1, z in todo:
        key = tuple(sorted((t1.key, z.term.key)))
        if key in seen:
            continue
        seen.add(key)
        fr = fitter([t1, z.term], z.start)
        out.pairs_refitted += 1
        if fr is not None:
            out.pairs.append(Candidate(fr, (t1, z.term)))
    out.pairs = by_bic(out.pairs)
