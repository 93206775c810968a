"""Pooled examination of several scans of one device against examining each scan alone.

Each scenario draws one three-sensor device over the contract's ranges
(:data:`borescan.scenarios.TRI_CONTRACT`: beam directions at least 20 deg apart, |rho| <= 15 mm,
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

from borescan.config import schema_defaults

#: Hidden effects and the design each is drawn with ("*": any of speeds, eccentricities, nights).
CASES = (
    ("channel_delay", "speeds"),
    ("sensor_nonlinearity", "eccentricities"),
    ("sensor_offset", "eccentricities"),
    ("channel_delay", "one_speed"),
    ("sensor_gain", "*"),
    ("sensor_drift", "*"),
    ("beam_tilt", "*"),
    ("thermal_expansion", "*"),
    ("bore_lobing", "*"),
    ("axis_tilt", "*"),
    ("speed_ripple", "*"),
    ("spindle_error_motion", "*"),
    ("sensor_nonlinearity", "*"),
    ("channel_delay", "speeds"),
)
RUN_EFFECTS = ("speed_ripple", "spindle_error_motion")
LOOKALIKES = ({"beam_tilt", "sensor_gain"}, {"axis_tilt", "bore_lobing[k=2]"})
#: samples per scan, examined on four blocks (as one scan is): the night's setting (rule pooled_night)
MAX_SAMPLES = int(schema_defaults()["discrepancy"]["pooled_max_samples"])


# ------------------------------------------------------------------------------------ scenario


def _device(rng):
    """Beams, gauge radius, sensor ranges of one device (the contract's ranges)."""
    from borescan.geometry import Beams
    from borescan.scenarios import TRI_CONTRACT, draw_beam_directions, reading_span_mm

    R = float(rng.uniform(*TRI_CONTRACT["bore_radius_mm"]))
    beta = draw_beam_directions(rng, 3, TRI_CONTRACT["min_beam_separation_rad"])
    rho = rng.uniform(-TRI_CONTRACT["rho_max_mm"], TRI_CONTRACT["rho_max_mm"], 3)
    # readings must stay in range for every direction of an eccentricity up to 3 mm
    spans = np.concatenate(
        [
            reading_span_mm(beta, rho, 3.0 * np.array([math.cos(a), math.sin(a)]), R, 512)
            for a in np.linspace(0, 2 * math.pi, 8, endpoint=False)
        ]
    )
    s_min, s_max = spans.min(axis=0), spans.max(axis=0)
    range_mm = np.array([max(float(rng.uniform(6.0, 10.0)), s_max[j] - s_min[j] + 0.6) for j in range(3)])
    d_b = np.array([rng.uniform(s_max[j] - range_mm[j] + 0.2, s_min[j] - 0.2) for j in range(3)])
    return Beams((1, 2, 3), beta, rho, d_b), R, range_mm


def _designs(rng, design: str) -> list[dict]:
    """Per scan: night index, rpm, direction, eccentricity [mm]."""
    base_rpm = float(rng.uniform(30.0, 90.0))
    d0 = "ccw" if rng.random() < 0.5 else "cw"
    other = "cw" if d0 == "ccw" else "ccw"
    if design == "speeds":
        rpms = [base_rpm, base_rpm * float(rng.uniform(1.5, 2.0)), base_rpm]
        dirs = [d0, d0, other]
        ecc = rng.uniform(1.0, 2.5, 3)
        nights = [0, 0, 0]
    elif design == "eccentricities":
        rpms, dirs, nights = [base_rpm] * 3, [d0] * 3, [0, 0, 0]
        ecc = np.array([0.2, 1.2, 2.6]) * rng.uniform(0.9, 1.1, 3)
    elif design == "one_speed":
        rpms, dirs, nights = [base_rpm] * 3, [d0] * 3, [0, 0, 0]
        ecc = rng.uniform(0.8, 2.5, 3)
    elif design == "nights":
        rpms, dirs, nights = [base_rpm] * 4, [d0] * 4, [0, 0, 1, 1]
        ecc = rng.uniform(1.0, 2.5, 4)
    else:
        raise ValueError(f"unknown design {design!r}")
    return [
        {"night": n, "rpm": r, "direction": d, "ecc_mm": float(e)}
        for n, r, d, e in zip(nights, rpms, dirs, ecc)
    ]


def gauge_artifact(R: float) -> dict:
    """Return the certified ring gauge of radius ``R`` [mm] a scenario's device turns in."""
    return {
        "id": f"RG-{round(2 * R)}",
        "type": "ring_gauge",
        "nominal_diameter_mm": float(round(2 * R)),
        "certified_diameter_mm": 2 * R,
        "u_diameter_mm": 0.0015,
        "k": 2,
        "certificate": "RG/2027",
        "cte_per_k": 11.5e-6,
    }


def spindle_scans(
    rng,
    rows: list[dict],
    *,
    beams,
    R,
    range_mm,
    C,
    spr,
    noise,
    nominal,
    encoder,
    effect,
    run_scan,
    device_id,
    nights,
    tag,
) -> list:
    """Return the ring-gauge spindle scans of one design.

    Return the ring-gauge spindle scans of one design (:func:`_designs` rows, 12 revolutions each, scan
    ``<tag>-<k>``); the hidden ``effect`` in every scan, or only in scan ``run_scan`` when given.
    """
    from borescan.simulate import TriScene, simulate_tri_spindle

    art = gauge_artifact(R)
    sims = []
    for k, s in enumerate(rows):
        a = float(rng.uniform(0, 2 * math.pi))
        S = C + s["ecc_mm"] * np.array([math.cos(a), math.sin(a)])
        scene = TriScene(
            beams=beams,
            bore_center_xy_mm=(float(C[0]), float(C[1])),
            bore_radius_20_mm=R,
            spindle_xy_mm=(float(S[0]), float(S[1])),
            rpm_nominal=s["rpm"],
            phase_rad=float(rng.uniform(0, 2 * math.pi)),
            direction=s["direction"],
            sample_rate_hz=spr * s["rpm"] / 60.0,
            range_mm=tuple(float(x) for x in range_mm),
            cte_per_k=11.5e-6,
            temperature_c=20.0,
        )
        effects = [] if effect is None or (run_scan is not None and k != run_scan) else [effect]
        sims.append(
            simulate_tri_spindle(
                scene,
                scan_id=f"{tag}-{k}",
                night=nights[s["night"]],
                n_rev=12.0,
                effects=effects,
                noise_mm=noise,
                seed=int(rng.integers(0, 2**31 - 1)),
                device_id=device_id,
                nominal_beams=nominal,
                artifact=art,
                center_xy_mm=(float(C[0]), float(C[1])),
                encoder=encoder,
                spindle_rate_hz=200.0,
            )
        )
    return sims


def draw_scenario(seed: int, i: int) -> dict:
    """Scenario ``i`` of battery ``seed``: the simulated scans, the hidden effect, the design."""
    from borescan.discrepancy.battery import random_effect
    from borescan.scenarios import battery_rng
    from borescan.geometry import Beams

    rng = battery_rng(seed + 500_000, i)
    free = i % 4 == 3
    name, design = (None, "*") if free else CASES[(i - i // 4) % len(CASES)]
    if design == "*":
        design = ("speeds", "eccentricities", "nights", "one_speed")[int(rng.integers(0, 4))]
    beams, R, range_mm = _device(rng)
    nominal = Beams(
        beams.channels,
        beams.beta_rad + rng.uniform(-0.03, 0.03, 3),
        beams.rho_mm + rng.uniform(-1, 1, 3),
        beams.d_b_mm + rng.uniform(-1, 1, 3),
    )
    scans = _designs(rng, design)
    encoder = bool(rng.random() < 0.5) and name not in ("speed_ripple",)
    noise = float(rng.uniform(0.001, 0.004))
    spr = int(rng.integers(300, 501))
    C = rng.uniform(-300, 300, 2)
    effect = None
    if name is not None:
        effect = random_effect(
            name, rng, beams.channels, scans[0]["rpm"] / 60.0, spr * scans[0]["rpm"] / 60.0
        )
    run_scan = int(rng.integers(0, len(scans))) if name in RUN_EFFECTS else None
    nights = ["2027-03-01", "2027-03-02"]
    sims = spindle_scans(
        rng,
        scans,
        beams=beams,
        R=R,
        range_mm=range_mm,
        C=C,
        spr=spr,
        noise=noise,
        nominal=nominal,
        encoder=encoder,
        effect=effect,
        run_scan=run_scan,
        device_id=f"TRI-P{seed}-{i:04d}",
        nights=nights,
        tag=f"P{seed}-{i:04d}",
    )
    return {
        "sims": sims,
        "effect": effect,
        "name": name,
        "design": design,
        "run_scan": run_scan,
        "nights": [nights[s["night"]] for s in scans],
        "beams": beams,
        "noise_mm": noise,
        "encoder": encoder,
    }


def calibrate(sims) -> tuple:
    """Calibrate the scans of one night by the night's method.

    Full-data calibration of the scans of one night (the night's method): (calibration or None,
    accepted). A calibration the acceptance rule refuses only for its residual is used as fitted;
    one that fails otherwise (a diverged fit) is None: the scans are then examined as the pipeline
    examines an uncalibrated device (``device.nominal``, beam lengths and angles free).
    """
    from borescan.calibrate.full_fit import fit_full_calibration
    from borescan.calibrate.result import AcceptanceRule, CalibrationError
    from borescan.discrepancy.examine import scan_arrays
    from borescan.geometry import Beams
    from borescan.kinematics import angle_model_of_scan

    ts, ys, am, S, C = [], [], [], [], []
    for s in sims:
        t, ch, v, _, _ = scan_arrays(s)
        ts.append(t)
        ys.append(v)
        am.append(angle_model_of_scan(s.meta, s.spindle))
        S.append((s.meta["spindle"]["position"]["x_mm"], s.meta["spindle"]["position"]["y_mm"]))
        C.append((s.meta["center"]["x_mm"], s.meta["center"]["y_mm"]))
    meta = sims[0].meta
    nominal = Beams.from_nominal(meta["device"]["nominal"]["beams"])
    R = meta["artifact"]["certified_diameter_mm"] / 2
    rng_mm = [float(x["range_mm"]) for x in sorted(meta["sensors"], key=lambda x: x["channel"])]
    kw = dict(
        center_xy_mm=C,
        angle_models=am,
        range_mm=rng_mm,
        scan_ids=[s.scan_id for s in sims],
        device_id=meta["device"]["id"],
    )
    try:
        return fit_full_calibration(ts, ys, ch, nominal, R, S, **kw), True
    except CalibrationError:
        pass
    try:
        return fit_full_calibration(
            ts, ys, ch, nominal, R, S, rule=AcceptanceRule.defaults(max_residual_to_noise=1e9), **kw
        ), False
    except CalibrationError:
        return None, False


# ------------------------------------------------------------------------------------ scoring


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
