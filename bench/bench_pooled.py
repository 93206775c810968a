"""Pooled examination of several scans of one device against examining each scan alone.

Each scenario draws one three-sensor device over the contract's ranges
(:data:`borescan.synthetic.contract.TRI_CONTRACT`: beam directions at least 20 deg apart, |rho| <= 15 mm,
gauge radius 75-200 mm, sensor ranges 6-10 mm, noise 1-4 um, encoder or commanded angle) and
several ring-gauge spindle scans of it with one hidden effect, in one of three designs:

- ``speeds``: three scans at different signed speeds (two speeds and one scan turning the other way);
- ``one_speed``: three scans at one speed and direction, different eccentricities;
- ``eccentricities``: three scans at one speed with eccentricities of about 0.2, 1.2 and 2.6 mm;
- ``nights``: two nights of two scans.

The hidden effect acts in every scan with the same parameters (device effects: sensor_*,
channel_delay, beam_tilt; artifact effects bore_lobing and axis_tilt in every scan of the gauge;
thermal_expansion in every scan of the night), except the run effects (speed_ripple,
spindle_error_motion), which act in one scan; magnitudes from
:func:`borescan.discrepancy.battery.random_effect`. A quarter of the scenarios are effect-free.

Reference, as a night does it: the night's scans are calibrated together
(:func:`borescan.calibrate.full_fit.fit_full_calibration`, with the scans' centre and spindle position as
priors; a calibration refused by the acceptance rule is still used, as fitted, and counted).
Each scan is examined alone against its night's calibration (``beams=``), and all scans are
examined together (:func:`borescan.discrepancy.pooled.examine_pooled`) starting from the latest
calibration.

Scoring. "identifiable": channel_delay at several speeds, every other effect except
sensor_offset (always a d_b), channel_delay at one speed (a beta) and thermal_expansion in one
gauge on one night (a common d_b): the pooled verdict is correct when it names the hidden effect
on its channel (spec look-alikes allowed in an "ambiguous" verdict: beam_tilt ~ sensor_gain,
axis_tilt ~ bore_lobing k = 2) and nothing else. For the absorbed ones it is correct when it names
no effect and lists the hidden effect under ``absorbed`` with its absorbing parameter. A single
scan is correct by the same rule (its calibration absorbed what it could, so an absorbed effect
is correct as "no_missing_effect"); a scenario's single scans "failed" when any one of them is
not correct. Effect-free: correct when nothing is named (a false alarm otherwise).

Run: ``python -m bench.bench_pooled --n 40 --seed 1`` (``--workers 2`` by default). A long battery
can be run in parts that keep their rows: ``--first 0 --n 10 --jsonl rows.jsonl``, then
``--first 10 --n 10 --jsonl rows.jsonl`` and so on (scenario i is the same whatever the part),
and ``--from-jsonl rows.jsonl`` prints the table of every row kept.
"""

from __future__ import annotations

import argparse
import json
import math
import time
import traceback
from collections import Counter, defaultdict

import numpy as np

from bench.pooled_scenarios import MAX_SAMPLES, calibrate, draw_scenario

LOOKALIKES = ({"beam_tilt", "sensor_gain"}, {"axis_tilt", "bore_lobing[k=2]"})


def label(n: dict) -> str:
    """Label of a named entry: effect@channel[k=..] (group left out)."""
    from borescan.discrepancy.battery import named_label

    return named_label(n)


def truth_label(effect) -> str:
    """Return the label of a hidden effect as the findings write it."""
    from borescan.discrepancy.battery import effect_label

    return effect_label(effect)


def _like(a: str, b: str) -> bool:
    ea, _, ca = a.partition("@")
    eb, _, cb = b.partition("@")
    if {ea, eb} == {"beam_tilt", "sensor_gain"} and ca == cb:
        return True
    return {a, b} == {"axis_tilt", "bore_lobing[k=2]"}


def value_ok(entry: dict | None, effect) -> bool:
    """Return whether the named value of the hidden effect is near the truth.

    Return the named value of the hidden effect's magnitude within max(3 u, 20 %) of the truth (sign
    included).
    """
    from borescan.discrepancy.battery import MAGNITUDE

    if entry is None or effect is None or effect.name not in MAGNITUDE:
        return True
    key = MAGNITUDE[effect.name]
    true, found = float(effect.params[key]), entry["parameters"].get(key)
    u = entry["uncertainties"].get(f"u_{key}")
    if found is None:
        return False
    tol = max(3.0 * (u if u is not None and math.isfinite(u) else 0.0), 0.2 * abs(true))
    return abs(float(found) - true) <= tol


def correct(
    verdict: str, named: list[dict], absorbed: list[str] | None, effect, expect_absorbed_: bool
) -> bool:
    """Return whether a verdict is right by the bench's rule (module doc).

    Return the bench's rule (module doc): right names and, for the hidden effect, its value.
    ``absorbed``: the effects the verdict lists as absorbed (None: a single scan).
    """
    labels = [label(n) for n in named]
    if effect is None:
        return verdict == "no_missing_effect" and not labels
    truth = truth_label(effect)
    if expect_absorbed_:
        return not labels and (absorbed is None or effect.name in absorbed)
    if truth not in labels and not (verdict == "ambiguous" and any(_like(truth, n) for n in labels)):
        return False
    if not all(n == truth or _like(n, truth) for n in labels):
        return False
    return value_ok(next((n for n in named if label(n) == truth), None), effect)


def expect_absorbed(name: str | None, design: str) -> bool:
    """Return whether the base model absorbs the hidden effect ``name`` under ``design``."""
    if name == "sensor_offset":
        return True
    if name == "channel_delay":
        return design != "speeds"
    return name == "thermal_expansion"  # one temperature in every scan: a common d_b


# ------------------------------------------------------------------------------------ one scenario


def run_one(job: tuple) -> dict:
    """Examine one scenario scan by scan and pooled; return its row."""
    from borescan.discrepancy.examine import analyse_scan, discrepancy_settings
    from borescan.discrepancy.pooled import examine_pooled, pooled_scan

    seed, i = job
    t0 = time.process_time()
    try:
        sc = draw_scenario(seed, i)
        settings = {**discrepancy_settings(), "max_samples": MAX_SAMPLES}
        by_night: dict[str, list] = defaultdict(list)
        for s, n in zip(sc["sims"], sc["nights"]):
            by_night[n].append(s)
        cals, accepted = {}, []
        for n, ss in by_night.items():
            cals[n], ok = calibrate(ss)
            accepted.append(ok)
        truth = truth_label(sc["effect"]) if sc["effect"] is not None else None
        absorbed_expected = expect_absorbed(sc["name"], sc["design"])
        singles = []
        t1 = time.process_time()
        for s, n in zip(sc["sims"], sc["nights"]):
            ref = {"beams": cals[n].beams} if cals[n] is not None else {"free_beams": ("d_b", "beta")}
            f = analyse_scan(s, **ref, **settings).findings
            named = [label(x) for x in f["named"]]
            hit = sc["run_scan"] is None or s.scan_id.endswith(f"-{sc['run_scan']}")
            singles.append(
                {
                    "scan_id": s.scan_id,
                    "verdict": f["verdict"],
                    "named": named,
                    "correct": correct(
                        f["verdict"], f["named"], None, sc["effect"] if hit else None, absorbed_expected
                    ),
                }
            )
        t2 = time.process_time()
        latest = next((cals[n] for n in sorted(cals, reverse=True) if cals[n] is not None), None)
        pe = examine_pooled(
            [pooled_scan(s, MAX_SAMPLES) for s in sc["sims"]],
            latest.beams if latest is not None else None,
            **settings,
        )
        t3 = time.process_time()
        pf = pe.findings
        named = [label(x) for x in pf["named"]]
        absorbed = [a["effect"] for a in pf["absorbed"]]
        ok = correct(pf["verdict"], pf["named"], absorbed, sc["effect"], absorbed_expected)
        value = None
        if sc["effect"] is not None and not absorbed_expected:
            hit = next((x for x in pf["named"] if label(x) == truth), None)
            if hit is not None:
                value = {
                    "true": dict(sc["effect"].params),
                    "found": hit["parameters"],
                    "u": hit["uncertainties"],
                    "scans": hit.get("scans"),
                }
        return {
            "i": i,
            "name": sc["name"] or "(none)",
            "design": sc["design"],
            "truth": truth,
            "expect_absorbed": absorbed_expected,
            "singles": singles,
            "singles_failed": not all(s["correct"] for s in singles),
            "verdict": pf["verdict"],
            "named": named,
            "absorbed": absorbed,
            "correct": ok,
            "value": value,
            "calibration_accepted": all(accepted),
            "calibrated": all(c is not None for c in cals.values()),
            "encoder": sc["encoder"],
            "advice": [a["advice"] for a in pf["absorbed"]],
            "cpu_single_s": t2 - t1,
            "cpu_pooled_s": t3 - t2,
            "cpu_s": time.process_time() - t0,
        }
    except Exception as err:  # noqa: BLE001 - a crash is a result of the bench
        return {
            "i": i,
            "name": "error",
            "design": "",
            "truth": None,
            "expect_absorbed": False,
            "singles": [],
            "singles_failed": True,
            "verdict": "error",
            "named": [],
            "absorbed": [],
            "correct": False,
            "value": None,
            "calibration_accepted": False,
            "encoder": None,
            "advice": [],
            "error": f"{type(err).__name__}: {err}",
            "tb": traceback.format_exc(limit=6),
            "cpu_single_s": 0.0,
            "cpu_pooled_s": 0.0,
            "cpu_s": time.process_time() - t0,
        }


# ------------------------------------------------------------------------------------ report


def summarise(rows: list[dict]) -> str:
    """Return the summary lines of the scenarios' rows."""
    lines = []
    eff = [r for r in rows if r["truth"] is not None]
    free = [r for r in rows if r["truth"] is None and r["verdict"] != "error"]
    failed = [r for r in eff if r["singles_failed"]]
    n_err = sum(r["verdict"] == "error" for r in rows)
    ran = [r for r in rows if r["verdict"] != "error"]
    lines.append(
        f"scenarios {len(rows)} ({len(eff)} with a hidden effect, {len(free)} effect-free, {n_err} errors); "
        f"calibrations refused by the acceptance rule: {sum(not r['calibration_accepted'] for r in ran)} "
        f"(used as fitted; {sum(not r.get('calibrated', True) for r in ran)} diverged: design geometry "
        "instead)"
    )
    ok_f = sum(r["correct"] for r in failed)
    lines.append(
        f"pooled correct where single scans were ambiguous or wrong: {ok_f}/{len(failed)} = "
        f"{ok_f / max(len(failed), 1):.1%}"
    )
    lines.append(
        f"pooled correct on every effect scenario: {sum(r['correct'] for r in eff)}/{len(eff)}; "
        f"single scans all correct: {sum(not r['singles_failed'] for r in eff)}/{len(eff)}"
    )
    fa = [r for r in free if not r["correct"]]
    fa1 = [r for r in free if r["singles_failed"]]
    lines.append(
        f"false alarms on effect-free scenarios: pooled {len(fa)}/{len(free)} = "
        f"{len(fa) / max(len(free), 1):.1%}; "
        f"some single scan {len(fa1)}/{len(free)}"
    )
    table: dict[str, Counter] = defaultdict(Counter)
    for r in rows:
        key = f"{r['name']} / {r['design']}"
        table[key]["n"] += 1
        table[key]["single_failed"] += r["singles_failed"]
        table[key]["pooled_ok"] += r["correct"]
        table[key]["pooled_ok_where_failed"] += r["correct"] and r["singles_failed"]
    lines.append("")
    lines.append(
        f"{'hidden effect / design':<40}{'n':>4}{'singles failed':>16}"
        f"{'pooled ok':>11}{'ok where failed':>17}"
    )
    for k in sorted(table):
        c = table[k]
        lines.append(
            f"{k:<40}{c['n']:>4}{c['single_failed']:>16}{c['pooled_ok']:>11}"
            f"{str(c['pooled_ok_where_failed']) + '/' + str(c['single_failed']):>17}"
        )
    vals = [r["value"] for r in rows if r.get("value")]
    dl = [v for v in vals if "tau_s" in v["true"]]
    if dl:
        z = [
            abs(v["found"]["tau_s"] - v["true"]["tau_s"]) / v["u"]["u_tau_s"]
            for v in dl
            if v["u"].get("u_tau_s")
        ]
        lines.append("")
        lines.append(
            f"channel_delay recovered (pooled): |tau - true| / u = {', '.join(f'{x:.1f}' for x in z)}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Run the scenarios and print the summary (options: ``--help``)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40, help="scenarios")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--verbose", action="store_true", help="print every scenario the pooled verdict got wrong"
    )
    ap.add_argument("--first", type=int, default=0, help="index of the first scenario")
    ap.add_argument("--jsonl", help="append each scenario's row to this file as it finishes")
    ap.add_argument("--from-jsonl", help="summarise the rows kept in this file (runs nothing)")
    a, _ = ap.parse_known_args(argv)  # `python -m bench pooled` passes its own names
    from borescan.parallel import map_in_order

    if a.from_jsonl:
        with open(a.from_jsonl) as fh:
            kept = {(r["seed"], r["i"]): r for r in map(json.loads, fh) if r}
        rows = [kept[k] for k in sorted(kept)]
        print(f"{len(rows)} scenarios from {a.from_jsonl} (seeds {sorted({r['seed'] for r in rows})})")
        print(summarise(rows))
        _print_wrong(rows, a.verbose)
        return
    jobs = [(a.seed, i) for i in range(a.first, a.first + a.n)]
    t0 = time.perf_counter()
    rows = []
    for r in map_in_order(run_one, jobs, a.workers):  # spawned workers, one BLAS thread each
        rows.append(r)
        if a.jsonl:
            with open(a.jsonl, "a") as fh:
                fh.write(json.dumps({"seed": a.seed, **r}, default=float) + "\n")
    wall = time.perf_counter() - t0
    print(summarise(rows))
    ok = [r for r in rows if r["verdict"] != "error"]
    print(
        f"{wall:.0f} s wall ({a.workers} workers); CPU per scenario: single scans "
        f"{np.mean([r['cpu_single_s'] for r in ok]) if ok else 0:.1f} s, pooled "
        f"{np.mean([r['cpu_pooled_s'] for r in ok]) if ok else 0:.1f} s, all "
        f"{np.mean([r['cpu_s'] for r in rows]):.1f} s"
    )
    _print_wrong(rows, a.verbose)


def _print_wrong(rows: list[dict], verbose: bool) -> None:
    if verbose:
        for r in rows:
            if not r["correct"] or r["verdict"] == "error":
                print(
                    f"  WRONG {r['i']} {r['name']} / {r['design']}: truth {r['truth']} -> "
                    f"{r['verdict']} {r['named']} "
                    f"absorbed {r['absorbed']}; singles {[(s['verdict'], s['named']) for s in r['singles']]} "
                    f"{r.get('error', '')}"
                )
                if r.get("tb"):
                    print(r["tb"])


if __name__ == "__main__":
    main()
