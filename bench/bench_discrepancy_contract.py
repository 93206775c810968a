"""Discrepancy workflow on the widened battery: scans drawn over everything the contract allows.

Three-sensor scans come from :func:`borescan.synthetic.tri_scenarios.draw_tri_calibration` (bore 75-200 mm,
any beam directions and offsets, speed ramps, encoder or rpm profile, nulls, a channel leaving
its range; ~20 % effect-free, the rest with one named effect from
:func:`borescan.discrepancy.battery.random_effect`). Rod scans come from
:func:`borescan.synthetic.rod_scenarios.draw_rod_scan` (2-3 holes of 100-200 mm, 8-40 poses, 5-30 readings per
pose, noise 2-20 um, eccentricity up to 2.5 mm, deflection up to 1 deg; half in ring-gauge sets
with certified diameters, half in parts with nominal ones, whose radii are then free), ~20 % effect-free, the
rest with one rod-applicable
effect that ``random_effect`` draws (``beam_offset`` has no random magnitude there and is left out).

Reference (what the scan is examined against). The pipeline examines a calibrated device
against its latest calibration (``discrepancy.reference``). The bench's stand-in for a perfect
calibration is the scan's true beam geometry (three-sensor: ``truth["contract"]["beams"]``
passed as ``beams=``; rod: the true layers as ``device.nominal`` and certified hole diameters,
as a setting master would give, or nominal ones of a part). ``--reference nominal`` instead examines
three-sensor scans
the way the pipeline treats an uncalibrated device: ``device.nominal`` (the design geometry,
off by up to 30 mrad / 1 mm) with beam lengths and angles freed; the effects a calibration
absorbs (offsets, delays, thermal expansion) cannot then be named, and are scored as such.

Scoring (the issue's rule): "missing_effect" is correct when it names exactly the hidden effect
(name, channel, harmonic); "ambiguous" when it lists the hidden effect and every other candidate
is a spec look-alike of it (``axis_tilt`` ~ ``bore_lobing[k=2]``, ``thermal_expansion`` ~
``sensor_offset`` on every channel). An effect-free scan is correct with "no_missing_effect";
anything else on it is a false alarm. Median gap shrink: gap_before / gap_after over the effect scans.

Run: ``.venv/bin/python -m bench.bench_discrepancy_contract --n 60 --seed 1 --workers 2``
"""

from __future__ import annotations

import argparse
import time
import traceback
from collections import Counter, defaultdict
from concurrent.futures import ProcessPoolExecutor

import numpy as np

#: Effects of the spec that apply to a rod scan and that ``random_effect`` can draw.
ROD_EFFECTS = (
    "sensor_offset",
    "sensor_gain",
    "sensor_nonlinearity",
    "sensor_drift",
    "quantization",
    "outliers",
    "thermal_expansion",
    "beam_tilt",
)
#: Spec look-alikes (geometry-and-effects.md, "Some effects look alike in one scan").
SPEC_LOOKALIKES = [({"axis_tilt"}, {"bore_lobing[k=2]"}), ({"thermal_expansion"}, {"sensor_offset@all"})]


def lookalike(a: str, b: str, kind: str = "tri", strict: bool = False) -> bool:
    """Return the spec's look-alike effects.

    Spec look-alikes; unless ``strict``, also the three-sensor ``beam_tilt`` and ``sensor_gain``
    on one channel, which the registry defines identically (v' = v / cos(gamma) = v (1 + h), h >= 0).
    """
    if any((a in g1 and b in g2) or (a in g2 and b in g1) for g1, g2 in SPEC_LOOKALIKES):
        return True
    ea, _, ca = a.partition("@")
    eb, _, cb = b.partition("@")
    return not strict and kind == "tri" and {ea, eb} == {"beam_tilt", "sensor_gain"} and ca == cb


def score(verdict: str, named: list[str], truth: list[str], kind: str = "tri", strict: bool = False) -> bool:
    """Return whether a verdict and its named effects are right for the scan's true effects."""
    if not truth:
        return verdict == "no_missing_effect"
    if verdict == "no_missing_effect":
        return False
    if any(t not in named for t in truth):
        return False
    others = [n for n in named if n not in truth]
    if verdict == "missing_effect":
        return not others
    return all(any(lookalike(n, t, kind, strict) for t in truth) for n in others)


# ------------------------------------------------------------------------------------------ draws


def _tri_case(seed: int, i: int, effect_free: bool, reference: str):
    from borescan.geometry import Beams
    from borescan.synthetic.battery import battery_rng, battery_scan_id
    from borescan.synthetic.tri_scenarios import draw_tri_calibration

    rng = battery_rng(seed, i)
    sim = draw_tri_calibration(
        rng, scan_id=battery_scan_id(seed, i), night="2027-01-01", effect_free=effect_free
    )
    if reference == "truth":
        cfg = {"beams": Beams.from_nominal(sim.truth["contract"]["beams"])}
    else:
        cfg = {"free_beams": ("d_b", "beta", "rho")}
    c = sim.truth["contract"]
    info = {
        "angle": c["angle_source"],
        "speed_change": bool(c["speed_change"]),
        "out_of_range": c["out_of_range"] is not None,
        "R": round(c["bore_radius_mm"], 1),
    }
    return sim, cfg, info


def _rod_case(seed: int, i: int, effect_free: bool, noise_free: bool = False):
    from borescan.synthetic.battery import battery_rng
    from borescan.synthetic.contract import ROD_CONTRACT
    from borescan.synthetic.rod_scenarios import draw_rod_scan

    contract = dict(ROD_CONTRACT, noise_mm=(0.0, 0.0)) if noise_free else ROD_CONTRACT
    rng = battery_rng(seed + 100_000, i)
    sim = draw_rod_scan(
        rng, scan_id=f"ROD{seed}-{i:05d}", night="2027-01-01", effect_free=effect_free, contract=contract
    )
    c = sim.truth["contract"]
    info = {
        "poses": c["n_poses"],
        "per_pose": c["samples_per_pose"],
        "noise_um": round(c["noise_mm"] * 1e3, 1),
        "holes": len(c["diameters_mm"]),
        "artifact": c["artifact"],
    }
    return sim, {}, info


def _term(label: str):
    from borescan.discrepancy.tri import Term

    name, _, rest = label.partition("@")
    k = None
    if "[k=" in (rest or name):
        (rest, _, kk) = rest.partition("[k=") if rest else ("", "", name.partition("[k=")[2])
        name = name.partition("[k=")[0]
        k = int(kk.rstrip("]"))
    channel = None if not rest else (0 if rest == "all" else int(rest))
    return Term(name, channel, k)


def data_lookalikes(
    clean, truth: str, others: list[str], sigma_mm: float, threshold: float = 10.0
) -> dict[str, float]:
    """How well each of ``others`` imitates the hidden effect ``truth`` in this very scan.

    ``clean`` is the same rod scan simulated without noise (the same geometry, poses and hidden
    effect): the base model plus ``truth`` fits it exactly, so fitting base plus another candidate
    B leaves an RSS that a noisy scan would show as B's expected BIC deficit, RSS / sigma^2.
    Below ``threshold`` the data of this scan cannot tell B from the truth however the workflow
    decides: a look-alike of this scan (an independent check, from the simulated truth).

    Returns {label: RSS / sigma^2}, with ``"(base)"`` for the base model alone (below
    ``threshold`` the base parameters, e.g. a part's free hole radii, absorb the effect: this scan
    cannot show it).
    """
    from borescan.discrepancy.examine import scan_arrays
    from borescan.discrepancy.fitting import fit_least_squares
    from borescan.discrepancy.poses import RodModel, pose_data_from_arrays

    t_s, ch, vals, pose, _ = scan_arrays(clean)
    model = RodModel(pose_data_from_arrays(clean.meta["scan_id"], clean.meta, t_s, vals, ch, pose))
    names, scales = model.base_names(), model.base_scales()
    st = model.base_start()
    base = fit_least_squares(lambda p: model.residual(p, []), names, [st.get(n, 0.0) for n in names], scales)
    out = {"(base)": float(base.rss / sigma_mm**2)}  # the base model alone: is the effect visible at all?
    for lab in others:
        t = _term(lab)
        best = base.rss
        for d0 in (0.0,) if t.effect != "beam_offset" else (0.3, -0.3, 1.0, -1.0):
            x0 = [base.values()[n] for n in names] + [
                d0 if t.effect == "beam_offset" else 0.0 for _ in t.names()
            ]
            try:
                fr = fit_least_squares(
                    lambda p, t=t: model.residual(p, [t]),
                    names + t.names(),
                    x0,
                    scales + t.scales(),
                    max_nfev=200,
                )
            except ValueError:
                continue
            if np.isfinite(fr.rss):
                best = min(best, fr.rss)
        out[lab] = float(best / sigma_mm**2)
    return out


def run_one(job: tuple) -> dict:
    """Draw and examine one scan; the row of the result table."""
    from borescan.discrepancy.battery import effect_label, named_label
    from borescan.discrepancy.examine import examine_scan
    from borescan.effects import Effect

    kind, seed, i, effect_free, reference = job
    t0 = time.process_time()
    try:
        sim, cfg, info = (
            _tri_case(seed, i, effect_free, reference) if kind == "tri" else _rod_case(seed, i, effect_free)
        )
        effects = [Effect(e["name"], e["params"]) if isinstance(e, dict) else e for e in sim.truth["effects"]]
        # the spec: with an encoder the angle is measured, a speed error or ripple is not there to find
        encoder = kind == "tri" and sim.truth["contract"]["encoder"]
        truth = [
            effect_label(e) for e in effects if not (encoder and e.name in ("speed_error", "speed_ripple"))
        ]
        hidden = [effect_label(e) for e in effects]
        f = examine_scan(sim, **cfg)
    except Exception as err:  # noqa: BLE001 - a crash is a result of the bench
        return {
            "kind": kind,
            "i": i,
            "truth": [],
            "hidden": [],
            "verdict": "error",
            "named": [],
            "correct": False,
            "correct_strict": False,
            "error": f"{type(err).__name__}: {err}",
            "tb": traceback.format_exc(limit=4),
            "info": {},
            "effect_free": effect_free,
            "params": [],
            "cpu_s": time.process_time() - t0,
        }
    named = [named_label(x) for x in f["named"]]
    look = {}
    correct = score(f["verdict"], named, truth, kind)
    correct_data = correct
    if (
        kind == "rod"
        and not correct
        and truth
        and (f["verdict"] == "no_missing_effect" or all(t in named for t in truth))
    ):
        clean, _, _ = _rod_case(seed, i, effect_free, noise_free=True)
        look = data_lookalikes(clean, truth[0], [n for n in named if n not in truth], info["noise_um"] * 1e-3)
        others = [v for k, v in look.items() if k != "(base)"]
        correct_data = (
            look["(base)"] < 10.0
            if f["verdict"] == "no_missing_effect"
            else bool(others) and max(others) < 10.0
        )
    return {
        "kind": kind,
        "i": i,
        "scan_id": f["scan_id"],
        "truth": truth,
        "params": [dict(e.params) for e in effects],
        "hidden": hidden,
        "effect_free": effect_free or not truth,
        "verdict": f["verdict"],
        "named": named,
        "correct": correct,
        "correct_strict": score(f["verdict"], named, truth, kind, True),
        "correct_data": correct_data,
        "lookalike_rss_over_s2": look,
        "gap_before_mm": f["gap_before"]["rms_mm"],
        "gap_after_mm": f["gap_after"]["rms_mm"],
        "noise_floor_mm": f["noise_floor_mm"],
        "info": info,
        "cpu_s": time.process_time() - t0,
    }


# ------------------------------------------------------------------------------------------ report


def summarise(rows: list[dict]) -> str:
    """Return the contract's summary lines for the rows."""
    lines = []
    eff = [r for r in rows if r["truth"]]
    free = [r for r in rows if r["effect_free"]]
    shrink = [r["gap_before_mm"] / r["gap_after_mm"] for r in eff if r.get("gap_after_mm")]
    fa = [r for r in free if r["verdict"] != "no_missing_effect"]
    n_ok = sum(r["correct"] for r in rows)
    lines.append(
        f"scans {len(rows)} ({sum(r['kind'] == 'tri' for r in rows)} tri, "
        f"{sum(r['kind'] == 'rod' for r in rows)} rod); errors {sum(r['verdict'] == 'error' for r in rows)}"
    )
    lines.append(
        f"correct naming (all scans) {n_ok}/{len(rows)} = {n_ok / max(len(rows), 1):.1%}; "
        f"on effect scans {sum(r['correct'] for r in eff)}/{len(eff)}"
    )
    lines.append(
        f"  strict spec look-alikes only (tri beam_tilt/sensor_gain ambiguity counted wrong): "
        f"{sum(r['correct_strict'] for r in rows)}/{len(rows)} = "
        f"{sum(r['correct_strict'] for r in rows) / max(len(rows), 1):.1%}"
    )
    n_kin = sum(1 for r in rows if r["hidden"] and not r["truth"])
    lines.append(
        f"  ({n_kin} encoder scans with a hidden speed_error/speed_ripple count as effect-free: spec)"
    )
    n_data = sum(r.get("correct_data", r["correct"]) for r in rows)
    lines.append(
        f"  what each rod scan can show (noise-free refit of the same scan, RSS/sigma^2 < 10): an ambiguous "
        f"verdict whose other candidates imitate the truth, or 'no missing effect' where the base model "
        f"(e.g. a part's free radii) absorbs it, counted correct: {n_data}/{len(rows)} = "
        f"{n_data / max(len(rows), 1):.1%}"
    )
    lines.append(
        f"false alarms on effect-free scans {len(fa)}/{len(free)} = {len(fa) / max(len(free), 1):.1%}"
    )
    lines.append(f"median gap shrink (effect scans) {np.median(shrink) if shrink else float('nan'):.2f}x")
    for kind in ("tri", "rod"):
        sub = [r for r in rows if r["kind"] == kind]
        if sub:
            sf = [r for r in sub if r["effect_free"]]
            lines.append(
                f"  {kind}: correct {sum(r['correct'] for r in sub)}/{len(sub)}; false alarms "
                f"{sum(r['verdict'] != 'no_missing_effect' for r in sf)}/{len(sf)}"
            )
    table: dict[str, Counter] = defaultdict(Counter)
    for r in rows:
        k = (
            r["kind"]
            + ":"
            + (
                r["truth"][0].split("@")[0].split("[")[0]
                if r["truth"]
                else "(none)"
                if not r["hidden"]
                else r["hidden"][0] + "+encoder"
            )
        )
        table[k][
            "correct" if r["correct"] else r["verdict"] + (":" + ",".join(r["named"]) if r["named"] else "")
        ] += 1
    lines.append(f"{'hidden effect':<30}{'scans':>6}{'correct':>8}{'share':>7}  other verdicts")
    for k in sorted(table):
        cnt = table[k]
        tot = sum(cnt.values())
        ok = cnt.get("correct", 0)
        other = "; ".join(f"{v}x {kk}" for kk, v in cnt.items() if kk != "correct")
        lines.append(f"{k:<30}{tot:>6}{ok:>8}{ok / tot:>7.0%}  {other}")
    return "\n".join(lines)


def profile_one(kind: str, seed: int, i: int, reference: str, top: int = 12) -> None:
    """cProfile (CPU clock) of one scan's examination: exact fits, model evaluations, top functions."""
    import cProfile
    import pstats

    import borescan.discrepancy.examine as ex

    sim, cfg, info = _tri_case(seed, i, False, reference) if kind == "tri" else _rod_case(seed, i, False)
    prof = cProfile.Profile(time.process_time)
    prof.enable()
    f = ex.examine_scan(sim, **cfg)
    prof.disable()
    st = pstats.Stats(prof)

    def total(fn: str, col: int) -> float:
        return sum(v[col] for k, v in st.stats.items() if k[2] == fn)

    print(
        f"{kind} {i} {info}: {total('examine_scan', 3):.2f} CPU s (profiled); exact fits "
        f"{int(total('fit_least_squares', 1))}, model evaluations {int(total('residual', 1))} "
        f"({total('residual', 3):.2f} s), forward-difference Jacobians {total('jz', 3):.2f} s; "
        f"{f['verdict']} {[n['effect'] for n in f['named']]}; screen {f['screen']}"
    )
    st.sort_stats("cumulative").print_stats(top)


def main(argv: list[str] | None = None) -> None:
    """Draw the scans, examine them and print the summary (options: ``--help``)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=60, help="three-sensor scans")
    ap.add_argument("--n-rod", type=int, default=None, help="rod scans (default n / 4)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--p-free", type=float, default=0.2)
    ap.add_argument("--reference", choices=("truth", "nominal"), default="truth")
    ap.add_argument("--verbose", action="store_true", help="print every wrong scan")
    ap.add_argument(
        "--profile",
        default=None,
        metavar="KIND:I",
        help="profile the examination of one scan (e.g. tri:4, rod:2) on the CPU clock and stop",
    )
    a, _ = ap.parse_known_args(argv)  # `python -m bench discrepancy` passes its own names
    if a.profile:
        kind, _, i = a.profile.partition(":")
        profile_one(kind, a.seed, int(i), a.reference)
        return
    n_rod = a.n // 4 if a.n_rod is None else a.n_rod
    sel = np.random.default_rng([a.seed, 7])
    jobs = [("tri", a.seed, i, bool(sel.random() < a.p_free), a.reference) for i in range(a.n)]
    jobs += [("rod", a.seed, i, bool(sel.random() < a.p_free), a.reference) for i in range(n_rod)]
    t0 = time.perf_counter()
    if a.workers > 1:
        with ProcessPoolExecutor(a.workers) as ex:
            rows = list(ex.map(run_one, jobs, chunksize=1))
    else:
        rows = [run_one(j) for j in jobs]
    wall = time.perf_counter() - t0
    reference = (
        "true beams/layers (stand-in for a perfect calibration)"
        if a.reference == "truth"
        else "device.nominal, d_b and beta free"
    )
    print(f"reference: {reference}")
    print(summarise(rows))
    cpu = np.array([r["cpu_s"] for r in rows])
    print(
        f"{wall:.0f} s wall, {cpu.mean():.1f} s CPU per scan "
        f"({a.workers} workers); examination CPU s per scan "
        f"p50 {np.percentile(cpu, 50):.2f}, p95 {np.percentile(cpu, 95):.2f}, max {cpu.max():.2f} "
        f"({max(rows, key=lambda r: r['cpu_s'])['kind']} {max(rows, key=lambda r: r['cpu_s'])['i']})"
    )
    if a.verbose:
        for r in rows:
            if not r["correct"]:
                print(
                    f"  WRONG {r['kind']} {r['i']}: truth {r['truth']} {r['params']} -> {r['verdict']} "
                    f"{r['named']} "
                    f"{r.get('info')} gap "
                    f"{r.get('gap_before_mm', 0) * 1e3:.2f}->{r.get('gap_after_mm', 0) * 1e3:.2f} um "
                    f"floor {r.get('noise_floor_mm', 0) * 1e3:.2f} um {r.get('error', '')} "
                    f"{ {k: round(v, 2) for k, v in r.get('lookalike_rss_over_s2', {}).items()} or '' }"
                )
                if r.get("tb"):
                    print(r["tb"])


if __name__ == "__main__":
    main()
