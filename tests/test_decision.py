"""Issue 37 item 3: the decision rules (ILAC-G8:09/2019 4.2, ISO 14253-1) against their closed forms."""

from __future__ import annotations

import pytest

from borescan.decision import CANNOT_DECIDE, CONFORMS, DOES_NOT_CONFORM, decision

T, U = 15.0e-3, 4.0e-3  # tolerance and expanded uncertainty [mm]; w = U


@pytest.mark.parametrize(
    "e_um, rule, verdict, passed",
    [
        # guarded acceptance: conforms |E| <= T - w = 11 um; does not conform |E| > T = 15 um
        (10.9, "guarded_acceptance", CONFORMS, True),
        (11.1, "guarded_acceptance", CANNOT_DECIDE, False),
        (-14.9, "guarded_acceptance", CANNOT_DECIDE, False),
        (15.1, "guarded_acceptance", DOES_NOT_CONFORM, False),
        # guarded rejection: does not conform |E| > T + w = 19 um; conforms |E| <= T
        (14.9, "guarded_rejection", CONFORMS, True),
        (-15.1, "guarded_rejection", CANNOT_DECIDE, True),
        (18.9, "guarded_rejection", CANNOT_DECIDE, True),
        (19.1, "guarded_rejection", DOES_NOT_CONFORM, False),
        # simple acceptance: the limit is T itself
        (14.9, "simple_acceptance", CONFORMS, True),
        (-15.1, "simple_acceptance", DOES_NOT_CONFORM, False),
    ],
)
def test_verdicts_and_limits_are_the_closed_forms(e_um, rule, verdict, passed):
    d = decision(e_um * 1e-3, U, T, rule, 1.0)
    assert (d.verdict, d.passed) == (verdict, passed)
    w = 0.0 if rule == "simple_acceptance" else U
    assert d.guard_band_mm == w
    assert (
        d.acceptance_limit_mm
        == {"simple_acceptance": T, "guarded_acceptance": T - w, "guarded_rejection": T + w}[rule]
    )
    assert d.short.startswith(verdict + " (") and ("w = 4.0 um" in d.short) == (w > 0)


def test_u_not_smaller_than_t_cannot_decide_under_every_rule():
    for rule in ("simple_acceptance", "guarded_acceptance", "guarded_rejection"):
        d = decision(0.0, 0.020, T, rule, 1.0)  # a perfect reading with U = 20 um against T = 15 um
        assert d.verdict == CANNOT_DECIDE and "not smaller than the tolerance" in d.statement, rule
    # the factor scales the band; the old name is guarded acceptance
    assert decision(0.012, U, T, "guarded_acceptance", 0.5).verdict == CONFORMS  # 12 <= 15 - 2
    old, new = decision(0.012, U, T, "guard_band", 1.0), decision(0.012, U, T, "guarded_acceptance", 1.0)
    assert (old.verdict, old.passed, old.acceptance_limit_mm) == (
        new.verdict,
        new.passed,
        new.acceptance_limit_mm,
    )


def test_unknown_rule_or_negative_band_is_refused():
    with pytest.raises(ValueError, match="unknown decision rule 'strict'; valid: \\['guarded_acceptance'"):
        decision(0.0, U, T, "strict")
    with pytest.raises(ValueError, match="guard_band_factor must be >= 0"):
        decision(0.0, U, T, "guarded_acceptance", -1.0)


def test_trace_and_report_show_the_verdict_with_its_rule(tmp_path, capsys):
    """The stage's statement (verdict, U, T, rule, guard band) is what `borescan trace` and the
    report's verification table show, not a bare passed/FAILED.
    """
    import polars as pl
    from test_catalog import make_history

    from borescan import catalog
    from borescan.report.pages import write_report
    from borescan.cli import main

    res = tmp_path / "results"
    t = make_history(res)
    d = decision(
        0.020, 0.018, 0.015, "guarded_rejection", 1.0
    )  # 15 < 20 <= 33 um: cannot decide, not rejected
    t["verifications"] = t["verifications"].with_columns(
        pl.when(pl.col("scan_id") == "VER-21").then(pl.lit(d.statement)).otherwise(None).alias("conformity")
    )
    catalog.build_catalog(res, t)
    assert main(["trace", "VER-21", "--results", str(res)]) == 0
    out = capsys.readouterr().out
    assert (
        "CANNOT DECIDE: |E| = 20.00 um, U(E) = 18.00 um, tolerance T = 15.00 um; rule: guarded rejection"
        in out
    )
    assert "w = 18.0 um" in out
    assert main(["status", "--results", str(res), "--as-of", "2026-11-21", "--validity-days", "30"]) == 0
    assert (
        "VER-21 on 2026-11-21: error +0.0200 mm (tolerance 0.015 mm) CANNOT DECIDE" in capsys.readouterr().out
    )
    html = write_report(res).read_text() + "".join(
        p.read_text() for p in sorted((res / "report").glob("*/index.html"))
    )
    assert '<span class="warn">CANNOT DECIDE</span><br><small>|E| = 20.00 um, U(E) = 18.00 um' in html
    # the night's summary counts it and says what to do
    assert "<li><b>cannot decide</b> verification VER-21 (TRI-01, gauge RG-275): |E| = 20.00 um" in html


def test_a_result_that_cannot_decide_never_reads_as_accepted():
    """The statement of a 'cannot decide' said "the result is accepted by the rule" (the demo's
    verifications, U(E) 18.8 um against T 15 um): it now says where |E| lies and that conformity cannot be
    stated.
    """
    inside = decision(0.0005, 0.0188, 0.015)
    outside = decision(0.016, 0.0188, 0.015)
    assert inside.verdict == outside.verdict == CANNOT_DECIDE
    assert "accepted" not in inside.statement and "accepted" not in outside.statement
    assert inside.statement.endswith("|E| is within the acceptance limit, but conformity cannot be stated")
    assert outside.statement.endswith("|E| is beyond the acceptance limit, but conformity cannot be stated")
