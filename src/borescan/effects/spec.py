"""The types of the effect registry: stages, scan kinds, scopes, fit parameters, an effect's specification."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "STAGES",
    "TRI",
    "ROD",
    "SCAN_KINDS",
    "SCAN_KIND_DEVICE",
    "SCOPES",
    "FitParam",
    "DeviceFit",
    "EffectSpec",
]

STAGES: tuple[str, ...] = ("time_base", "kinematics", "spindle_position", "bore", "beam", "reading", "output")
TRI = "tri_lds"
ROD = "rod"
#: Scan kinds the registry describes absorption and candidacy for.
SCAN_KINDS: tuple[str, ...] = ("tri_spindle", "tri_static", "rod")
#: The device type of each scan kind (whose fit parameterisation, ``EffectSpec.fit_params``, its terms take).
SCAN_KIND_DEVICE: Mapping[str, str] = {"tri_spindle": TRI, "tri_static": TRI, "rod": ROD}
#: What an effect belongs to when scans are examined together (``EffectSpec.scope``).
SCOPES: tuple[str, ...] = ("device", "night", "artifact", "scan")


@dataclass(frozen=True)
class FitParam:
    """One parameter a fit varies for an effect (its internal parameterisation).

    Attributes
    ----------
    name : internal name, e.g. ``"A"``; a fit prefixes it with the term, ``bore_lobing[k=3].A``.
    unit : unit of the value (``"-"`` dimensionless).
    scale : typical magnitude, for step sizes and starting values [unit].
    lower, upper : bounds of the physical domain [unit]; the forward model clips to them.
    """

    name: str
    unit: str
    scale: float
    lower: float = -math.inf
    upper: float = math.inf


@dataclass(frozen=True)
class DeviceFit:
    """A device's own fit parameterisation of an effect, where it differs from the effect's ``fit``.

    Attributes
    ----------
    fit : the parameters a fit of this device varies.
    to_internal, from_internal : as :class:`EffectSpec`'s (None: the same names and values).
    """

    fit: tuple[FitParam, ...]
    to_internal: Callable[[Mapping[str, float]], dict] | None = None
    from_internal: Callable[..., tuple[dict, dict]] | None = None


@dataclass(frozen=True)
class EffectSpec:
    """One named effect of the spec.

    Attributes
    ----------
    name : spec name, e.g. ``"channel_delay"``.
    device_types : device types it applies to (``"tri_lds"``, ``"rod"``).
    params : parameter name -> unit (``"-"`` for dimensionless, ``"channel"`` for the 1-based channel).
    stage : one of :data:`STAGES`.
    forward : device type -> pure forward function (signature per stage, see module doc).
    definition : the spec's definition, for messages and reports.
    fit : the parameters a fit varies (empty: not fitted).
    to_internal : spec parameters -> ``{fit name: value}``; None: the same names and values.
    from_internal : ``(x, u, k) -> (parameters, uncertainties)``, the inverse with linear
        propagation of standard uncertainties ``u`` (may be None); ``k`` the harmonic of a
        term; None: the same names and values.
    absorbed_by : scan kind -> {base parameter: what a finding reports}.
    candidate : scan kind -> ``"screen"``, ``"start"`` or ``"evidence"`` (module doc).
    needs : conditions a scan must meet for the term to be tried (module doc).
    common : a per-channel effect is also tried as one value on every channel.
    scope : ``"device"``, ``"night"``, ``"artifact"`` or ``"scan"`` (module doc).
    absorbed_unless : scan kind -> {base parameter: condition that breaks the absorption} (module doc).
    orientation : the spec parameter that turns with the artifact (module doc), or None.
    separated_by : what another scan must differ in to tell the effect from its look-alikes, as the
        report advises it (README "When something needs attention"); "" when no such advice.
    example : sensible parameter values (spec names; channel 2 for channel effects), for tests,
        demos and docs.
    device_fit : device type -> :class:`DeviceFit`, that device's fit parameterisation where it is not
        ``fit`` / ``to_internal`` / ``from_internal`` (a rod's ``beam_tilt`` adds a signed gamma to its
        layer's own, where the three-sensor reading divides by cos gamma, even in gamma).
    """

    name: str
    device_types: tuple[str, ...]
    params: Mapping[str, str]
    stage: str
    forward: Mapping[str, Callable[..., Any]]
    definition: str
    fit: tuple[FitParam, ...] = ()
    to_internal: Callable[[Mapping[str, float]], dict] | None = None
    from_internal: Callable[..., tuple[dict, dict]] | None = None
    absorbed_by: Mapping[str, Mapping[str, str]] = field(default_factory=dict)
    candidate: Mapping[str, str] = field(default_factory=dict)
    needs: tuple[str, ...] = ()
    common: bool = False
    example: Mapping[str, Any] = field(default_factory=dict)
    scope: str = "device"
    absorbed_unless: Mapping[str, Mapping[str, str]] = field(default_factory=dict)
    orientation: str | None = None
    separated_by: str = ""
    device_fit: Mapping[str, DeviceFit] = field(default_factory=dict)

    def _fit_of(self, device: str | None) -> DeviceFit:
        """Return the fit parameterisation of ``device`` (None: the effect's default)."""
        own = self.device_fit.get(device) if device is not None else None
        return own if own is not None else DeviceFit(self.fit, self.to_internal, self.from_internal)

    def fit_params(self, device: str | None = None) -> tuple[FitParam, ...]:
        """Return the parameters a fit of ``device`` varies (None: the effect's default ``fit``)."""
        return self._fit_of(device).fit

    @property
    def per_channel(self) -> bool:
        """True when the effect acts on one channel (has a ``channel`` parameter)."""
        return "channel" in self.params

    @property
    def harmonic(self) -> bool:
        """True when the effect has a whole-number harmonic ``k`` (one term per k)."""
        return "k" in self.params

    def internal(self, params: Mapping[str, float], device: str | None = None) -> dict[str, float]:
        """Return the fit's values ``{fit name: value}`` of the spec's ``params`` (``to_internal``).

        ``device``: whose parameterisation (:meth:`fit_params`); None the effect's default.
        """
        f = self._fit_of(device)
        if f.to_internal is not None:
            return f.to_internal(params)
        return {q.name: float(params[q.name]) for q in f.fit}

    def spec_params(
        self,
        x: Mapping[str, float],
        u: Mapping[str, float] | None = None,
        k: int | None = None,
        device: str | None = None,
    ) -> tuple[dict[str, Any], dict[str, float]]:
        """Return the spec's parameters of fitted values ``x``.

        Return the spec's parameters (and their standard uncertainties when ``u`` is given) of
        fitted values ``x`` (``{fit name: value}``) of ``device``'s parameterisation (:meth:`fit_params`),
        clipped to the fit's bounds first; ``channel`` is not included, ``k`` is for harmonic effects.
        """
        f = self._fit_of(device)
        x = {q.name: min(max(float(x[q.name]), q.lower), q.upper) for q in f.fit}
        if f.from_internal is not None:
            par, unc = f.from_internal(x, u, k)
        else:
            par = dict(x)
            unc = {} if u is None else {q.name: u.get(q.name, math.nan) for q in f.fit}
        if self.harmonic:
            par = {"k": k, **par}
        return par, unc

    def absorbers(self, scan_kind: str) -> Mapping[str, str]:
        """Return base parameters that absorb the effect in scans of ``scan_kind`` (may be empty)."""
        return self.absorbed_by.get(scan_kind, {})
