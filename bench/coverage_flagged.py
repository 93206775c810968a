"""The chains of ``python -m bench.bench_coverage --flagged`` (issue 36) and what is printed of them.

:func:`draw_calibration` draws the contract's calibration scenes with bores to R 500 mm and keeps those in
which Eq. (1) of :mod:`borescan.mirror` at the truth puts a beam's mirror less than 25 in chi^2 above the
minimum; :func:`flagged_summary` / :func:`print_flagged`: the coverage of the diameters measured with the
flagged calibrations (their own 95 % intervals: the two-solution mixture, JCGM 101), refusals apart, the
calibration's own values split into resolved beams and flagged beams' kept solution, and the wrong-sign main
solutions against the stated probabilities, in total (Poisson-binomial) and per bin of the probability.
"""

from __future__ import annotations

import numpy as np

#: ``--flagged``: the contract's ranges with bores to R 500 mm (the spec sets no upper limit; issue 36's
#: acceptance battery reaches R 500 mm)
FLAGGED_BORE_RADIUS_MM = (75.0, 500.0)
#: ``--flagged``: candidate scenes drawn per chain before the chain is given up
FLAGGED_ATTEMPTS = 200


def shallowest_mirror(truth: dict) -> float:
    """Return the smallest Eq. (1) mirror depth delta chi2_m over the beams at the truth; inf if none exists.

    :func:`borescan.mirror.predicted_depth` with the scan's samples, the true spindle offset, each beam's
    true rho, the noise and the gauge radius; beams with |rho| <= sqrt(2) e have no mirror.
    """
    from borescan.mirror import mirror_exists, predicted_depth

    ct = truth["contract"]
    e = float(np.hypot(*np.subtract(ct["spindle_xy_mm"], ct["center_xy_mm"])))
    rho = [float(b["rho"]) for b in ct["beams"]]
    depths = [
        predicted_depth([ct["n_samples"]], [e], r, [ct["noise_mm"]], float(ct["bore_radius_mm"]))
        for r in rho
        if mirror_exists(r, e)
    ]
    return min(depths, default=float("inf"))


def draw_calibration(i: int, seed: int, flagged: bool):
    """Return chain i's calibration scene; with ``flagged`` the first with a mirror shallower than 25.

    Candidates (``SeedSequence(seed, spawn_key=(i, 2, a))``, a = 0, 1, ...) are drawn over the contract with
    bores to :data:`FLAGGED_BORE_RADIUS_MM` and kept when :func:`shallowest_mirror` < 25
    (:data:`borescan.mirror.RESOLVED_DCHI2`): conditioning on the truth, every draw is still the contract's.
    """
    from borescan.mirror import RESOLVED_DCHI2
    from borescan.synthetic import battery, contract, tri_scenarios

    sid, night = battery.battery_scan_id(seed, i), "2027-02-01"
    if not flagged:
        return tri_scenarios.draw_tri_calibration(battery.battery_rng(seed, i), scan_id=sid, night=night)
    wide = dict(contract.TRI_CONTRACT, bore_radius_mm=FLAGGED_BORE_RADIUS_MM)
    for a in range(FLAGGED_ATTEMPTS):
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(i), 2, a)))
        sim = tri_scenarios.draw_tri_calibration(rng, scan_id=sid, night=night, contract=wide)
        if shallowest_mirror(sim.truth) < RESOLVED_DCHI2:
            return sim
    raise RuntimeError(f"chain {i}: no scene with a mirror shallower than 25 in {FLAGGED_ATTEMPTS} draws")


#: bins of the stated probability of the wrong sign in which the observed wrong signs are counted
WEIGHT_BINS = ((0.0, 0.01), (0.01, 0.1), (0.1, 0.3), (0.3, 0.51))


def flagged_summary(rows: list[dict]) -> dict:
    """Return issue 36's figures of the chains whose calibration has a flagged beam.

    Diameters measured with them (the two-solution mixture, JCGM 101): 95 % coverage of their own intervals
    and z SD; measurements refused (outside the valid bore range, or otherwise) counted apart; among flagged
    beams the wrong-sign main solutions observed against the stated probabilities (their sum, and the
    Poisson-binomial P of that many or more).
    """
    from bench.bench_coverage import _stats
    from bench.calibration_contract_tables import p_at_least

    acc = [r for r in rows if r.get("accepted") and r.get("flagged")]
    beams = [b for r in acc for b in r.get("flagged_beams", [])]
    wrong = sum(int(b["wrong_sign"]) for b in beams)
    p_stated = [b["p_wrong_sign"] for b in beams]
    out = {
        "flagged_chains": len(acc),
        "parts_measured": sum(1 for r in acc if r.get("diameters")),
        "mixtures": sum(1 for r in acc if r.get("mixture")),
        "refused_valid_range": sum(1 for r in acc if "the range where" in r.get("measure_error", "")),
        "refused_other": sorted(
            r["measure_error"][:160]
            for r in acc
            if r.get("measure_error") and "the range where" not in r["measure_error"]
        ),
        "no_part": sum(1 for r in acc if not r.get("diameters") and not r.get("measure_error")),
        "flagged_beams": len(beams),
        "wrong_sign": wrong,
        "wrong_sign_stated": float(sum(p_stated)),
        "wrong_sign_p_at_least": p_at_least(p_stated, wrong) if beams else float("nan"),
        "families": {},
        # calibration of the weights: per bin of the stated probability, beams, wrong signs, stated sum
        "by_weight": [
            (
                lo,
                hi,
                sum(1 for b in beams if lo <= b["p_wrong_sign"] < hi),
                sum(int(b["wrong_sign"]) for b in beams if lo <= b["p_wrong_sign"] < hi),
                float(sum(b["p_wrong_sign"] for b in beams if lo <= b["p_wrong_sign"] < hi)),
            )
            for lo, hi in WEIGHT_BINS
        ],
    }
    for fam in ("beta", "rho", "d_b"):  # the calibration's own values: the flagged beams' kept solution apart
        for what, keep in (("resolved beams", False), ("flagged beams, kept solution", True)):
            out["families"][f"{fam}, {what}"] = _stats(
                [
                    x
                    for r in acc
                    for x in r["params"]
                    if x["family"] == fam
                    and (x.get("channel") in {b["channel"] for b in r.get("flagged_beams", [])}) == keep
                ]
            )
    for fam in ("D at 20 degC", "D at T"):
        out["families"][fam] = _stats([x for r in acc for x in r.get("diameters", []) if x["family"] == fam])
        out["families"][fam + ", wrong sign kept"] = _stats(
            [
                x
                for r in acc
                if any(b["wrong_sign"] for b in r.get("flagged_beams", []))
                for x in r.get("diameters", [])
                if x["family"] == fam
            ]
        )
    return out


def print_flagged(rows: list[dict]) -> dict:
    """Print :func:`flagged_summary` of the rows; return it."""
    f = flagged_summary(rows)
    print(
        f"flagged calibrations (a beam's sign of rho not determined): {f['flagged_chains']}, parts measured "
        f"{f['parts_measured']} ({f['mixtures']} as a two-solution mixture), refused outside the valid bore "
        f"range {f['refused_valid_range']}, refused otherwise {len(f['refused_other'])}, no part drawn "
        f"{f['no_part']}"
    )
    for why in f["refused_other"]:
        print(f"  refused: {why}")
    for fam, d in f["families"].items():
        if d["n"]:
            ok = "yes" if 0.93 <= d["cover"] <= 0.97 else "NO"
            print(
                f"  {fam:34s} n {d['n']:4d}  cover95 {d['cover']:6.1%} +- {d['se']:.1%}  "
                f"z SD {d['z_sd']:.3f}  max|z| {d['z_max']:.2f}  accept 93-97 % {ok}"
            )
    print(
        f"  flagged beams {f['flagged_beams']}: wrong-sign main solution {f['wrong_sign']}, stated "
        f"{f['wrong_sign_stated']:.2f} (sum of the weights); P(that many or more | stated weights) "
        f"{f['wrong_sign_p_at_least']:.2f}"
    )
    for lo, hi, n, w, st in f["by_weight"]:
        print(f"    stated p in [{lo:.2f}, {hi:.2f}): beams {n:3d}, wrong sign {w:3d}, stated {st:6.2f}")
    return f
