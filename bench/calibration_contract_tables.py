"""The tables of the three-sensor calibration contract bench (:mod:`bench.bench_calibration_contract`).

From the per-scan rows the bench writes: acceptance figures, coverage of the stated uncertainties, the
mirror check, printed as the module doc of the bench describes them.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

#: the parameter families of a three-sensor calibration, in a channel's block order
FAMILIES = ("beta", "rho", "d_b")


def fixed_channel(beta_reference: str, channels) -> int | None:
    """Index of the beta held fixed (``"channel <c> fixed"``), None for ``"absolute"``."""
    if beta_reference == "absolute":
        return None
    parts = str(beta_reference).split()
    if len(parts) >= 2 and parts[0] == "channel":
        return list(channels).index(int(parts[1]))
    raise ValueError(f"unknown beta_reference {beta_reference!r}")


def summarize(rows: list[dict]) -> dict:
    """Return the acceptance figures of the rows (see the module doc); also printed by :func:`print_table`."""
    acc = [r for r in rows if r["accepted"]]
    out = {
        "scans": len(rows),
        "accepted": len(acc),
        "refused": len(rows) - len(acc),
        "reasons": Counter(r["reason"].split(";")[0][:160] for r in rows if not r["accepted"]),
    }
    z_all = []
    for fam in FAMILIES:
        z, ratio = [], []
        for r in acc:
            for k, fm in enumerate(r["families"]):
                if fm != fam:
                    continue
                if r["u"][k] > 0:
                    z.append(r["err"][k] / r["u"][k])
                if r.get("u_crb") and r["u_crb"][k] > 0:
                    ratio.append(r["u"][k] / r["u_crb"][k])
        z = np.array(z)
        z_all.append(z)
        out[fam] = {
            "n": z.size,
            "sd": float(np.std(z)) if z.size else float("nan"),
            "mean": float(np.mean(z)) if z.size else float("nan"),
            "max_abs": float(np.max(np.abs(z))) if z.size else float("nan"),
            "cover95": float(np.mean(np.abs(z) <= 1.959964)) if z.size else float("nan"),
            "n_over4": int(np.sum(np.abs(z) > 4.0)),
            "u_crb_max": float(np.max(ratio)) if ratio else float("nan"),
            "u_crb_median": float(np.median(ratio)) if ratio else float("nan"),
            "u_crb_min": float(np.min(ratio)) if ratio else float("nan"),
        }
    z = np.concatenate(z_all) if z_all else np.zeros(0)
    out["pooled"] = {
        "n": z.size,
        "sd": float(np.std(z)) if z.size else float("nan"),
        "cover95": float(np.mean(np.abs(z) <= 1.959964)) if z.size else float("nan"),
        "max_abs": float(np.max(np.abs(z))) if z.size else float("nan"),
    }
    excess = np.array(
        [(r["ssr_fit"] - r["ssr_true"]) / r["ssr_spread"] for r in acc if np.isfinite(r["ssr_fit"])]
    )
    sharp = [
        (r["ssr_excess_sigma2"], r["prior_penalty_true"] + 3.0, r["scan_id"])
        for r in acc
        if np.isfinite(r["ssr_fit"])
    ]
    out["wrong_minimum"] = {
        "checked": int(excess.size),
        "failed": int(np.sum(excess > 1.0)),
        "max_excess_in_spreads": float(excess.max()) if excess.size else float("nan"),
        "sharp_failed": sorted(sid for ex, lim, sid in sharp if ex > lim),
        "max_excess_sigma2": float(max(ex for ex, _, _ in sharp)) if sharp else float("nan"),
    }
    out["seconds"] = {
        "total": float(sum(r["seconds"] for r in rows)),
        "max": float(max(r["seconds"] for r in rows)) if rows else float("nan"),
    }
    return out


def _channel_of_row(k: int, families: list[str], c: int, f: int | None) -> int:
    """Channel index of row k of :func:`_compared` (betas of the non-fixed channels, rhos, d_bs)."""
    nb = sum(1 for x in families if x == "beta")
    if k < nb:
        return k + (1 if f is not None and k >= f else 0)
    return (k - nb) % c


#: a scan whose weakest beam has |rho| / u(rho) below this at the fit: every beam's bound follows that rho
#: (the shared rho^2 mode, ``bench.bench_calibration_band``), so u / CRB(truth) in [0.9, 1.2] is out of reach
ANCHOR_RHO_OVER_U = 5.0


def weakest_rho_over_u(row: dict) -> float:
    """Return min over a bench row's beams of |rho fitted| / u(rho) (rho fitted = true + error)."""
    fam = row["families"]
    k = [i for i, x in enumerate(fam) if x == "rho"]
    return float(
        min(
            abs(rt + row["err"][i]) / row["u"][i] if row["u"][i] > 0 else np.inf
            for i, rt in zip(k, row["rho_true_mm"])
        )
    )


def p_at_least(p: list[float], k: int) -> float:
    """Return P(X >= k), X the wrong signs under the stated probabilities ``p`` (Poisson-binomial)."""
    dist = np.array([1.0])
    for q in p:
        dist = np.convolve(dist, [1.0 - q, q])
    return float(dist[k:].sum())


def mirror_summary(rows: list[dict]) -> dict:
    """Return issue 36's figures for the resolved and the flagged beams.

    Resolved beams' z (SD, 95 % coverage, u / CRB in [0.9, 1.2]), the flagged count against Eq. (1)'s at the
    truth, and among flagged beams the observed wrong-sign rate against the stated probabilities (their mean).
    The count of beams whose sign the scan does not determine follows the certificate's rule
    (:attr:`borescan.mirror.BeamMirror.sign_determined`: a mirror possible at the fit and its depth below 25,
    the refit's where it found a separate minimum, else Eq. (1) at the fit): the flagged (two solutions)
    plus those in one valley through both signs; printed beside Eq. (1) alone at the fit and at the truth.
    """
    anchored: list[bool] = []  # the scan's weakest |rho| / u(rho) >= ANCHOR_RHO_OVER_U
    z, ratio, e_crb, n_beams, n_flag, n_formula, p_stated, wrong, sign_err_resolved = (
        [],
        [],
        [],
        0,
        0,
        0,
        [],
        [],
        0,
    )
    n_undetermined = n_at_fit = 0  # the certificate's rule, and Eq. (1) alone at the fit
    for r in rows:
        if not r.get("accepted") or "mirror" not in r:
            continue
        fam, c = r["families"], len(r["mirror"])
        f = fixed_channel(r["beta_reference"], [m["channel"] for m in r["mirror"]])
        flagged = {j for j, m in enumerate(r["mirror"]) if not m["resolved"]}
        strong = weakest_rho_over_u(r) >= ANCHOR_RHO_OVER_U
        for j, m in enumerate(r["mirror"]):
            n_beams += 1
            n_formula += int(m["formula_flagged"])
            n_undetermined += int(not m.get("sign_determined", m["resolved"]))
            n_at_fit += int(m.get("formula_at_fit", False))
            k_rho = sum(1 for x in fam if x == "beta") + j
            u_crb_rho = (r.get("u_crb") or [0.0] * len(fam))[k_rho]
            if m["resolved"]:  # a gross error only where the sign means something: |rho| > 2 CRB
                sign_err_resolved += int(not m["sign_right"] and abs(r["rho_true_mm"][j]) > 2.0 * u_crb_rho)
            else:
                n_flag += 1
                p_stated.append(m["p_wrong_sign"])
                wrong.append(0.0 if m["sign_right"] else 1.0)
        for k in range(len(fam)):
            j = _channel_of_row(k, fam, c, f)
            if j in flagged or (fam[k] == "beta" and f is not None and f in flagged) or r["u"][k] <= 0:
                continue
            z.append(r["err"][k] / r["u"][k])
            if r.get("u_crb") and r["u_crb"][k] > 0:
                ratio.append(r["u"][k] / r["u_crb"][k])
                e_crb.append(r["err"][k] / r["u_crb"][k])
                anchored.append(strong)
    z, ratio, e_crb, anchored = np.array(z), np.array(ratio), np.array(e_crb), np.array(anchored, bool)
    in_band = (ratio >= 0.9) & (ratio <= 1.2)
    return {
        "beams": n_beams,
        "flagged": n_flag,
        "formula_flagged": n_formula,
        "sign_undetermined": n_undetermined,
        "formula_at_fit": n_at_fit,
        "resolved_z_sd": float(np.std(z)) if z.size else float("nan"),
        "resolved_cover95": float(np.mean(np.abs(z) <= 1.959964)) if z.size else float("nan"),
        "resolved_u_crb_in_0.9_1.2": float(np.mean(in_band)) if ratio.size else float("nan"),
        "resolved_anchored_n": int(anchored.sum()),
        "resolved_anchored_u_crb_in_0.9_1.2": float(np.mean(in_band[anchored]))
        if anchored.any()
        else float("nan"),
        "resolved_sign_errors": sign_err_resolved,
        "resolved_err_over_crb_rms": float(np.sqrt(np.mean(e_crb**2))) if e_crb.size else float("nan"),
        "flagged_wrong_sign_observed": float(np.mean(wrong)) if wrong else float("nan"),
        "flagged_wrong_sign_stated": float(np.mean(p_stated)) if p_stated else float("nan"),
        "flagged_wrong_sign_count": int(sum(wrong)),
        "flagged_wrong_sign_p_at_least": p_at_least(p_stated, int(sum(wrong))),
    }


def _subset(rows, **want):
    return [r for r in rows if all(r.get(k) == v for k, v in want.items())]


def print_table(  # noqa: C901 (one line per table of the bench's printout)
    rows: list[dict],
) -> dict:
    """Print the acceptance table of the rows; return :func:`summarize` of them."""
    s = summarize(rows)
    print(f"scans {s['scans']}   accepted {s['accepted']}   refused {s['refused']}")
    for reason, k in s["reasons"].most_common():
        print(f"  refused x{k}: {reason}")
    print(
        f"{'family':8s} {'n':>5s} {'z mean':>7s} {'z SD':>6s} {'max|z|':>7s} {'|z|>4':>6s} {'cover95':>8s} "
        f"{'u/CRB med':>10s} {'u/CRB max':>10s}"
    )
    for fam in FAMILIES + ("pooled",):
        d = s[fam]
        extra = (
            (
                f"{d['mean']:7.2f} {d['sd']:6.3f} {d['max_abs']:7.2f} {d['n_over4']:6d} {d['cover95']:8.1%} "
                f"{d['u_crb_median']:10.3f} {d['u_crb_max']:10.3f}"
            )
            if fam != "pooled"
            else f"{'':7s} {d['sd']:6.3f} {d['max_abs']:7.2f} {'':6s} {d['cover95']:8.1%}"
        )
        print(f"{fam:8s} {d['n']:5d} {extra}")
    w = s["wrong_minimum"]
    print(
        f"wrong-minimum check: {w['failed']} of {w['checked']} fits with SSR_fit > SSR_truth + sigma^2 "
        "sqrt(2N); "
        f"largest (SSR_fit - SSR_truth) = {w['max_excess_in_spreads']:+.3f} spreads"
    )
    print(
        f"sharp check: {len(w['sharp_failed'])} fits with SSR_fit - SSR_truth > sigma^2 (P_truth + 3) "
        f"{w['sharp_failed'][:10]}; largest SSR_fit - SSR_truth = {w['max_excess_sigma2']:+.1f} sigma^2"
    )
    # rho is seen only through terms of order |o|^2 / R: where the bound itself exceeds |rho| / 2
    # the data cannot tell rho's sign, a calibration's linearised u does not hold there
    acc = [r for r in rows if r["accepted"]]
    ss = summarize([r for r in acc if not r.get("weak_rho")])
    print(
        f"without scans the calibration flags weak rho ({len(acc) - ss['accepted']} flagged): pooled z SD "
        f"{ss['pooled']['sd']:.3f}, max |z| {ss['pooled']['max_abs']:.2f}, cover95 "
        f"{ss['pooled']['cover95']:.1%}"
    )
    amb = []
    for r in acc:
        if not r.get("u_crb"):
            continue
        k_rho = [k for k, fm in enumerate(r["families"]) if fm == "rho"]
        if any(r["u_crb"][k] > abs(rt) / 2 for k, rt in zip(k_rho, r["rho_true_mm"])):
            amb.append(r)
    ss = summarize([r for r in acc if r not in amb])
    print(
        "scans where the truth's CRB of some rho exceeds |rho| / 2 (sign not fixed by the data): "
        f"{len(amb)}; "
        f"without them: pooled z SD {ss['pooled']['sd']:.3f}, max |z| {ss['pooled']['max_abs']:.2f}, "
        f"cover95 {ss['pooled']['cover95']:.1%}"
    )
    # where the z-scores come from: by angle source and position knowledge
    print("by case (scans accepted/total, pooled z SD, beta z SD, beta u/CRB max):")
    for src in ("encoder", "profile"):
        for known in (True, False):
            sub = _subset(rows, angle_source=src, position_known=known)
            if not sub:
                continue
            ss = summarize(sub)
            print(
                f"  {src:8s} positions {'known  ' if known else 'unknown'}: "
                f"{ss['accepted']:3d}/{ss['scans']:3d}  "
                f"pooled SD {ss['pooled']['sd']:.3f}  beta SD {ss['beta']['sd']:.3f}  "
                f"beta u/CRB max {ss['beta']['u_crb_max']:.3f}  rho u/CRB max {ss['rho']['u_crb_max']:.3f}"
            )
    for label, key in (("speed change", "speed_change"), ("out of range", "out_of_range")):
        ss = summarize(_subset(rows, **{key: True}))
        print(
            f"  {label:12s}: {ss['accepted']:3d}/{ss['scans']:3d}  pooled SD {ss['pooled']['sd']:.3f}  "
            f"cover95 {ss['pooled']['cover95']:.1%}"
        )
    worst = sorted(
        (r for r in rows if r["accepted"]),
        key=lambda r: -max(abs(e / u) if u > 0 else 0 for e, u in zip(r["err"], r["u"])),
    )[:3]
    for r in worst:
        zz = [e / u if u > 0 else float("nan") for e, u in zip(r["err"], r["u"])]
        print(
            f"  largest |z|: {r['scan_id']} ({r['angle_source']}, positions "
            f"{'known' if r['position_known'] else 'unknown'}, "
            f"{r['beta_reference']}, weak rho {r['weak_rho']}): z = {np.round(zz, 2).tolist()}"
        )
    ms = mirror_summary(rows)
    print(
        f"sign of rho not determined (the certificate's rule): {ms['sign_undetermined']} of {ms['beams']} "
        f"beams ({ms['flagged']} with two solutions, {ms['sign_undetermined'] - ms['flagged']} in one valley "
        f"through both signs); Eq. (1) < 25 at the fit: {ms['formula_at_fit']}, at the truth: "
        f"{ms['formula_flagged']}"
    )
    print(
        f"mirror check (issue 36): {ms['flagged']} of {ms['beams']} beams flagged (Eq. (1) at the truth: "
        f"{ms['formula_flagged']}); resolved beams: z SD {ms['resolved_z_sd']:.3f}, cover95 "
        f"{ms['resolved_cover95']:.1%}, u/CRB in [0.9, 1.2] "
        f"{ms['resolved_u_crb_in_0.9_1.2']:.1%} ({ms['resolved_anchored_u_crb_in_0.9_1.2']:.1%} of the "
        f"{ms['resolved_anchored_n']} in scans whose weakest |rho| / u(rho) >= {ANCHOR_RHO_OVER_U:g}), "
        "errors/CRB rms "
        f"{ms['resolved_err_over_crb_rms']:.3f}, sign errors where |rho| > 2 CRB "
        f"{ms['resolved_sign_errors']}; flagged beams: wrong "
        f"sign kept {ms['flagged_wrong_sign_observed']:.3f} "
        f"observed vs {ms['flagged_wrong_sign_stated']:.3f} stated ({ms['flagged_wrong_sign_count']} of "
        f"{ms['flagged']}; P(that many or more | stated weights) {ms['flagged_wrong_sign_p_at_least']:.2f}); "
        "diameters measured with flagged calibrations: python -m bench.bench_coverage"
    )
    print(
        f"calibration time: {s['seconds']['total']:.0f} s summed "
        f"over scans, slowest {s['seconds']['max']:.1f} s"
    )
    return s
