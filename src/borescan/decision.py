"""Decision rules: a measured error against a tolerance, with its expanded uncertainty.

The rules of ILAC-G8:09/2019 and ISO 14253-1:2017, the one place every verdict of the project comes from
(verifications, parts).

With ``E`` the error (measured - reference, or a part's deviation from its nominal), ``U`` its
expanded uncertainty, ``T`` the tolerance (+- T) and the guard band ``w = guard_band_factor * U``:

- ``simple_acceptance`` (ILAC-G8 4.2.1, w = 0): conforms when |E| <= T, else does not conform.
  The rule presumes U small against T; where U >= T the statement is "cannot decide" (the risk of
  a wrong decision reaches 50 % anywhere in the zone), the binary decision stays |E| <= T.
- ``guarded_acceptance`` (ILAC-G8 4.2.2; ISO 14253-1 proof of conformity): conforms when
  |E| <= T - w; does not conform when |E| > T; between, cannot decide, and the result is not
  accepted (a false accept is at most about 2.5 % at w = U, k = 2, normal error).
- ``guarded_rejection`` (ILAC-G8 4.2.3; ISO 14253-1 proof of nonconformity): does not conform when
  |E| > T + w; conforms when |E| <= T; between, cannot decide, and the result is not rejected
  (a false reject is at most about 2.5 % at w = U).

Under every rule a result whose U is not below T never "conforms" (cannot decide).

``guard_band`` is the earlier name of ``guarded_acceptance`` (configs written before it).
"""

from __future__ import annotations

import math

from dataclasses import dataclass

__all__ = [
    "DECISION_RULES",
    "CONFORMS",
    "DOES_NOT_CONFORM",
    "CANNOT_DECIDE",
    "Decision",
    "decision",
    "split_verdict",
]

CONFORMS, DOES_NOT_CONFORM, CANNOT_DECIDE = "conforms", "does not conform", "cannot decide"

#: rule name -> (ILAC-G8:09/2019 clause, what it guards)
DECISION_RULES = {
    "simple_acceptance": ("4.2.1", "simple acceptance, guard band w = 0"),
    "guarded_acceptance": ("4.2.2", "guarded acceptance, acceptance limit T - w"),
    "guarded_rejection": ("4.2.3", "guarded rejection, rejection limit T + w"),
    "guard_band": ("4.2.2", "guarded acceptance, acceptance limit T - w"),
}


@dataclass(frozen=True)
class Decision:
    """The verdict on |E| against T under a rule (lengths in mm).

    verdict : "conforms", "does not conform" or "cannot decide"
    passed : the rule's binary decision (accepted or not; a "cannot decide" is refused under
        guarded acceptance, accepted under guarded rejection and simple acceptance)
    acceptance_limit_mm : the largest |E| accepted (T - w, T, or T + w... see the module docstring)
    guard_band_mm : w
    """

    rule: str
    verdict: str
    passed: bool
    error_mm: float
    U_mm: float
    tolerance_mm: float
    guard_band_mm: float
    acceptance_limit_mm: float

    @property
    def rule_text(self) -> str:
        """Return the decision rule in words, with its ILAC-G8 clause and guard band."""
        clause, what = DECISION_RULES[self.rule]
        w = f", w = {self.guard_band_mm * 1e3:.1f} um" if self.guard_band_mm > 0 else ""
        return f"{what} (ILAC-G8:09/2019 {clause}{w})"

    @property
    def short(self) -> str:
        """``conforms (|E| 3.2 um, U 1.1 um, T 15 um, rule: guarded acceptance, w = 1.1 um)``."""
        return (
            f"{self.verdict} (|E| {abs(self.error_mm) * 1e3:.1f} um, U {self.U_mm * 1e3:.1f} um, "
            f"T {self.tolerance_mm * 1e3:.1f} um; {self.rule_text})"
        )

    @property
    def statement(self) -> str:
        """The verdict as a sentence with the rule, the guard band and the numbers it rests on."""
        text = (
            f"{self.verdict.upper()}: |E| = {abs(self.error_mm) * 1e3:.2f} "
            f"um, U(E) = {self.U_mm * 1e3:.2f} um, "
            f"tolerance T = {self.tolerance_mm * 1e3:.2f} um; rule: {self.rule_text}"
        )
        if self.verdict == CANNOT_DECIDE:
            text += (
                "; U(E) is not smaller than the tolerance"
                if self.U_mm >= self.tolerance_mm
                else "; |E| lies within the guard band"
            )
            text += (
                f"; |E| is {'within' if self.passed else 'beyond'} the acceptance limit, "
                "but conformity cannot be stated"
            )
        return text


def decision(
    error_mm: float,
    U_mm: float,
    tolerance_mm: float,
    rule: str = "simple_acceptance",
    guard_band_factor: float = 1.0,
) -> Decision:
    """Return the verdict on ``error_mm`` (E) with expanded uncertainty ``U_mm`` against +- ``tolerance_mm``.

    ``rule`` is one of the module docstring's rules; the guard band is ``guard_band_factor * U_mm`` for the
    guarded rules, 0 for simple acceptance.
    """
    if rule not in DECISION_RULES:
        raise ValueError(
            f"unknown decision rule {rule!r}; valid: {sorted(set(DECISION_RULES) - {'guard_band'})}"
        )
    if not guard_band_factor >= 0:
        raise ValueError(f"guard_band_factor must be >= 0, got {guard_band_factor!r}")
    if not all(math.isfinite(float(x)) for x in (error_mm, U_mm, tolerance_mm)) or not tolerance_mm > 0:
        raise ValueError(
            f"no verdict: the error ({error_mm!r} mm), its expanded uncertainty ({U_mm!r} mm) and the "
            f"tolerance ({tolerance_mm!r} mm) must be finite numbers, the tolerance positive"
        )
    e, U, T = abs(float(error_mm)), float(U_mm), float(tolerance_mm)
    if rule == "simple_acceptance":
        w, limit = 0.0, T
        passed = e <= T
        verdict = CANNOT_DECIDE if U >= T else CONFORMS if passed else DOES_NOT_CONFORM
    elif rule in ("guarded_acceptance", "guard_band"):
        w = float(guard_band_factor) * U
        limit = T - w
        passed = limit > 0 and e <= limit
        verdict = CONFORMS if passed else DOES_NOT_CONFORM if e > T else CANNOT_DECIDE
    else:
        w = float(guard_band_factor) * U
        limit = T + w
        passed = e <= limit
        verdict = DOES_NOT_CONFORM if not passed else CONFORMS if e <= T else CANNOT_DECIDE
    if verdict == CONFORMS and U >= T:  # no reading can show conformity when U is not below T
        verdict = CANNOT_DECIDE
    return Decision(rule, verdict, bool(passed), float(error_mm), U, T, w, limit)


def split_verdict(text: str | None) -> tuple[str | None, str]:
    """Return (verdict, the rest) of a stored :attr:`Decision.statement` or :attr:`Decision.short`.

    Those are the catalog's ``conformity`` columns; (None, text) for text of another form (older catalogs).
    """
    if not text:
        return None, ""
    low = text.lower()
    for v in (DOES_NOT_CONFORM, CANNOT_DECIDE, CONFORMS):  # "conforms" is a suffix of none, checked last
        if low.startswith(v):
            return v, text[len(v) :].lstrip(": ").strip().removeprefix("(").removesuffix(")")
    return None, text
