"""Candidate terms: the registry's named effects as fitted parameters, for every examination model.

A :class:`Term` is one named effect of the spec (``shared/spec/geometry-and-effects.md``) on one channel
(or every channel) with a harmonic ``k`` where it has one; the registry (:data:`borescan.effects.EFFECTS`)
gives its fitted parameters (phase-type effects in Cartesian form (A, B), linear near zero amplitude) and
their conversion to the spec's parameters (:func:`term_effects`, :func:`term_values`,
:func:`term_parameters`), and the candidates of each scan kind (:func:`registry_terms`: three-sensor
spindle scans, :mod:`borescan.discrepancy.tri`; static sets and rod scans, :mod:`borescan.discrepancy.poses`;
a device's pooled scans, :mod:`borescan.discrepancy.pooled`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from borescan.config import schema_default
from borescan.effects import EFFECTS, SCAN_KIND_DEVICE, Effect

__all__ = ["Term", "registry_terms", "term_effects", "term_parameters", "term_values"]


@dataclass(frozen=True)
class Term:
    """One candidate: a named effect of the spec on one channel (or none) with a harmonic ``k``.

    ``channel=0`` means the same parameter on every channel (the look-alike of ``thermal_expansion`` for
    ``sensor_offset``); ``device``: whose fit parameterisation (registry ``fit_params``; None the default).
    """

    effect: str
    channel: int | None = None
    k: int | None = None
    device: str | None = field(default=None, compare=False, kw_only=True)

    @property
    def key(self) -> str:
        """The term's key: the effect, ``@channel`` and ``k`` where they apply."""
        s = self.effect
        if self.channel is not None:
            s += "@" + ("all" if self.channel == 0 else str(self.channel))
        if self.k is not None:
            s += f"[k={self.k}]"
        return s

    def names(self) -> list[str]:
        """Prefixed fitted parameter names, e.g. ``bore_lobing[k=3].A`` (registry ``fit``)."""
        return [f"{self.key}.{q.name}" for q in EFFECTS[self.effect].fit_params(self.device)]

    def scales(self) -> list[float]:
        """Typical magnitudes of :meth:`names` (registry ``fit``)."""
        return [q.scale for q in EFFECTS[self.effect].fit_params(self.device)]


def term_effects(term: Term, p: dict[str, float], channels) -> list[Effect]:
    """Return the spec's effects of a fitted term.

    Its fitted values ``p[f"{term.key}.{name}"]`` converted by the registry for the term's device
    (:meth:`~borescan.effects.EffectSpec.spec_params`); channel 0 (or None): one effect per channel.
    """
    spec = EFFECTS[term.effect]
    x = {q.name: p[f"{term.key}.{q.name}"] for q in spec.fit_params(term.device)}
    par, _ = spec.spec_params(x, None, term.k, term.device)
    if spec.per_channel:
        chans = channels if term.channel in (None, 0) else (term.channel,)
        return [Effect(term.effect, {"channel": c, **par}) for c in chans]
    return [Effect(term.effect, par)]


def term_values(term: Term, effect: Effect) -> dict[str, float]:
    """Return the term's fitted values of a spec effect.

    Inverse of :func:`term_effects`: the term's fitted values ``{f"{term.key}.{name}": value}``
    of a spec effect (:meth:`~borescan.effects.EffectSpec.internal`).
    """
    return {f"{term.key}.{n}": v for n, v in effect.spec.internal(effect.params, term.device).items()}


def registry_terms(
    scan_kind: str,
    channels,
    *,
    have: dict[str, bool],
    k_max: int | None = None,
    freed: dict[str, set | str] | None = None,
    conditions: frozenset[str] = frozenset(),
) -> list[Term]:
    """Return the registry's candidate terms for a scan of ``scan_kind``.

    Return the registry's candidate terms for a scan of ``scan_kind`` (``"tri_spindle"``,
    ``"tri_static"``, ``"rod"``): the only list of candidates the workflow has.

    Every effect whose ``candidate[scan_kind]`` is ``"screen"`` and whose ``needs`` the scan meets
    (``have``: need -> met): per-channel effects one term per channel, then the ``common`` ones
    as one term on every channel (channel 0), then the others, one term per harmonic
    k = 2..k_max where the effect has one. Terms a freed base parameter absorbs (the registry's
    ``absorbed_by[scan_kind]``) are left out: ``freed`` maps a base parameter to the set of
    channels whose own copy of it is free (a per-channel term is absorbed when its channel is in
    the set, a common term when the set is not empty), or to ``"shared"`` for one parameter of
    every channel (absorbs only the common terms: a bore radius absorbs a common offset, not one
    channel's), unless the scan meets the registry's ``absorbed_unless[scan_kind]`` condition for that
    parameter (``conditions``, e.g. ``"speeds_differ"``: a delay is a change of beta only at one speed).
    ``k_max`` None: the schema's ``discrepancy.max_harmonic``.
    """
    freed = {k: v for k, v in (freed or {}).items() if v}
    if k_max is None:
        k_max = int(schema_default("discrepancy", "max_harmonic"))
    specs = [
        s
        for s in EFFECTS.values()
        if s.candidate.get(scan_kind) == "screen" and all(have.get(n, False) for n in s.needs)
    ]
    dev = SCAN_KIND_DEVICE[scan_kind]
    terms = [Term(s.name, c, device=dev) for s in specs if s.per_channel for c in channels]
    terms += [Term(s.name, 0, device=dev) for s in specs if s.per_channel and s.common]
    for s in (s for s in specs if not s.per_channel):
        terms += [Term(s.name, None, k, device=dev) for k in (range(2, k_max + 1) if s.harmonic else [None])]

    def absorbed(t: Term) -> bool:
        common = t.channel in (0, None)
        unless = EFFECTS[t.effect].absorbed_unless.get(scan_kind, {})
        for b in EFFECTS[t.effect].absorbers(scan_kind):
            f = freed.get(b)
            if f is None or unless.get(b) in conditions:
                continue
            if common or (f != "shared" and t.channel in f):
                return True
        return False

    return [t for t in terms if not absorbed(t)]


def term_parameters(term: Term, x: dict[str, float], u: dict[str, float]) -> tuple[dict, dict]:
    """Return the spec's parameters of a fitted term and their uncertainties.

    Return the spec's parameters of a fitted term and their standard uncertainties (the registry's
    :meth:`~borescan.effects.EffectSpec.spec_params`).
    """
    spec, fit = EFFECTS[term.effect], EFFECTS[term.effect].fit_params(term.device)
    if not fit:
        raise ValueError(f"no parameter conversion for {term.effect!r}")
    xi = {q.name: x[f"{term.key}.{q.name}"] for q in fit}
    ui = {q.name: u.get(f"{term.key}.{q.name}", float("nan")) for q in fit}
    return spec.spec_params(xi, ui, term.k, term.device)
