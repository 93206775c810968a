"""``borescan simulate``: write simulated scans (``borescan-raw/1``) and their ground truth.

``borescan simulate demo --out DIR [--seed N]`` writes the embedded demo nights;
``borescan simulate tri|static|rod --raw-root RAW --truth-root TRUTH ...`` writes one scan, with
``--effect NAME:key=value,...`` (repeatable) for the named effects of the spec;
``borescan simulate contract --n N --seed S --out DIR`` writes the contract battery
(:func:`borescan.synthetic.battery.write_battery`: ring-gauge calibration scans drawn over every range
the raw format and the geometry page allow, ``--kinds`` for static sets, rods, rotating
measurements and rod calibrations, ``--effect-share`` / ``--effect-scale`` for effects on a share
of the scans at sizes from just visible to large, ``--per-night``; DIR/raw, DIR/truth, DIR/battery.json).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from borescan.commands._common import (
    Progress,
    UsageError,
    finite_float,
    night_date,
    nonnegative_int,
    positive_float,
    positive_int,
)

NAME = "simulate"
HELP = (
    "write simulated scans in borescan-raw/1 plus ground truth (demo nights, one scan, or the "
    "contract battery)"
)

_SCAN_ID_RE = re.compile(r"[A-Za-z0-9_-]{1,64}")  # raw-scan-format.md


def _scan_id(text: str) -> str:
    """argparse type: a scan id of the raw format."""
    if not _SCAN_ID_RE.fullmatch(text):
        raise argparse.ArgumentTypeError(f"{text!r} is not a scan id (1-64 of A-Z a-z 0-9 _ -)")
    return text


def _effect_text(text: str) -> str:
    """argparse type: ``NAME:key=value,...`` whose values are numbers; the message names the parameter.

    The effect itself (name, parameter names, channel) is checked by
    :func:`borescan.effects.parse_effect` when the scan is simulated.
    """
    name, _, rest = text.strip().partition(":")
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq:
            raise argparse.ArgumentTypeError(f"effect {name!r}: expected key=value, got {item!r}")
        try:
            float(val)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"effect {name!r}: parameter {key.strip()!r}: {val.strip()!r} is not a number"
            ) from None
    return text


def _outside(raw_root: Path, truth_root: Path) -> None:
    """Refuse a truth folder inside the raw root (the pipeline and ``validate`` would find it there)."""
    raw, truth = raw_root.resolve(), truth_root.resolve()
    if truth == raw or truth.is_relative_to(raw):
        raise UsageError(
            f"--truth-root {truth_root} is inside --raw-root {raw_root}; ground truth must live "
            "outside the raw tree (raw-scan-format.md), e.g. a sibling folder 'truth'"
        )


def _common(p: argparse.ArgumentParser, kind: str, scan_id: str, noise: float) -> None:
    p.add_argument(
        "--raw-root", type=Path, required=True, help="raw root (night=*/scan=* folders are written here)"
    )
    p.add_argument(
        "--truth-root",
        type=Path,
        required=True,
        help="folder for <scan_id>.truth.json (keep it outside the raw root)",
    )
    p.add_argument("--scan-id", type=_scan_id, default=scan_id, help=f"scan id (default {scan_id})")
    p.add_argument(
        "--night", type=night_date, default="2026-11-20", help="night YYYY-MM-DD (default 2026-11-20)"
    )
    p.add_argument(
        "--kind",
        default=kind,
        help=f"scan kind (default {kind})",
        choices=("calibration", "centering", "verification", "measurement"),
    )
    p.add_argument("--seed", type=nonnegative_int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--noise-mm", type=finite_float, default=noise, help=f"reading noise sigma [mm] (default {noise})"
    )
    from borescan.effects import EFFECTS

    p.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="NAME:k=v,...",
        type=_effect_text,
        help="named effect, e.g. channel_delay:channel=2,tau_s=0.0012 (repeatable); "
        f"names: {', '.join(EFFECTS)}",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Sub-subcommands ``demo``, ``tri``, ``static``, ``rod``, ``contract``."""
    from borescan.synthetic.scenes import ROD_NOISE_MM, TRI_NOISE_MM, YANG_RING_GAUGE_DIAMETER_MM

    sub = parser.add_subparsers(dest="sim_kind", metavar="WHAT", required=True)
    p = sub.add_parser("demo", help="the embedded demo nights (4 nights, TRI-01 and ROD-01)")
    p.add_argument(
        "--out", type=Path, required=True, help="output folder (DIR/raw, DIR/truth, DIR/.complete)"
    )
    p.add_argument("--seed", type=nonnegative_int, default=None, help="seed (default: the fixed demo seed)")

    p = sub.add_parser("tri", help="one three-sensor spindle scan (Yang 2017 set-up at P1 in RG-275)")
    _common(p, "calibration", "SIM-TRI-SPINDLE", TRI_NOISE_MM)
    p.add_argument("--n-rev", type=positive_float, default=60.0, help="revolutions (default 60)")
    p.add_argument("--rpm", type=positive_float, default=60.0, help="nominal speed [1/min] (default 60)")
    p.add_argument(
        "--sample-rate-hz", type=positive_float, default=660.0, help="LDS sample rate [Hz] (default 660)"
    )
    p.add_argument(
        "--diameter-mm",
        type=positive_float,
        default=YANG_RING_GAUGE_DIAMETER_MM,
        help="bore diameter at 20 degC [mm]",
    )
    p.add_argument(
        "--spindle-xy-mm",
        type=finite_float,
        nargs=2,
        default=None,
        metavar=("X", "Y"),
        help="spindle position (default P1 = 262.955 -275.502)",
    )
    p.add_argument("--phase-rad", type=finite_float, default=0.0, help="device angle at t = 0 [rad]")
    p.add_argument("--cw", action="store_true", help="turn clockwise")
    p.add_argument("--no-encoder", action="store_true", help="spindle stream without angle_rad (null)")

    p = sub.add_parser("static", help="static three-sensor measurements: one block of samples per pose")
    _common(p, "verification", "SIM-TRI-STATIC", TRI_NOISE_MM)
    p.add_argument(
        "--diameter-mm",
        type=positive_float,
        default=YANG_RING_GAUGE_DIAMETER_MM,
        help="bore diameter at 20 degC [mm]",
    )
    p.add_argument("--poses", type=positive_int, default=10, help="number of device poses (default 10)")
    p.add_argument("--samples-per-pose", type=positive_int, default=20, help="samples per pose (default 20)")

    p = sub.add_parser("rod", help="measuring rod in a two-hole part (Wang 2017 set-up)")
    _common(p, "measurement", "SIM-ROD", ROD_NOISE_MM)
    p.add_argument("--poses", type=positive_int, default=24, help="rod rotations (default 24)")
    p.add_argument(
        "--samples-per-pose", type=positive_int, default=5, help="samples per rotation (default 5)"
    )

    p = sub.add_parser(
        "contract",
        help="battery of scans drawn over the whole contract (calibration, static, rod) "
        "(borescan.synthetic; fixed seeds, scan i from its own child seed)",
    )
    p.add_argument("--n", type=positive_int, default=200, help="number of scans, >= 1 (default 200)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="battery seed, >= 0 (default 0)")
    p.add_argument(
        "--out", type=Path, required=True, help="output folder (DIR/raw, DIR/truth, DIR/battery.json)"
    )
    p.add_argument(
        "--with-effects", action="store_true", help="one named effect per scan (default: effect-free scans)"
    )
    p.add_argument(
        "--kinds",
        default="calibration",
        help="comma-separated kinds, N scans of each: calibration (spindle scans in ring gauges), "
        "static (static three-sensor sets: ring gauges and parts), rod (rod scans in ring-gauge "
        "sets and parts), measurement (rotating measurements of parts on the device of calibration "
        "scan i), rod_calibration (rod calibration scans in ring-gauge sets); default calibration",
    )
    p.add_argument(
        "--effect-share",
        type=finite_float,
        default=None,
        metavar="P",
        help="each scan has one named effect with probability P in 0..1 (instead of --with-effects)",
    )
    p.add_argument(
        "--effect-scale",
        type=positive_float,
        nargs=2,
        default=(1.0, 1.0),
        metavar=("LOW", "HIGH"),
        help="effect sizes times a factor log-uniform in LOW..HIGH (default 1 1: the battery's sizes)",
    )
    p.add_argument(
        "--per-night", type=positive_int, default=25, help="scans a night from 2027-01-01 (default 25)"
    )


def run(args: argparse.Namespace) -> int:
    """Write the requested scans; print the scan folders. Bad input raises :class:`UsageError` (exit 2)."""
    import numpy as np

    from borescan.effects import parse_effect
    from borescan.synthetic import demo, scenes, simulate

    if args.sim_kind == "demo":
        try:
            paths = demo.make_demo(args.out, seed=demo.DEMO_SEED if args.seed is None else args.seed)
        except FileExistsError as e:
            raise UsageError(
                f"{e}; --out {args.out} holds other demo scans, choose an empty folder"
            ) from None
        print(f"{len(paths)} scans written under {args.out / 'raw'}; truth in {args.out / 'truth'}")
        return 0
    if args.sim_kind == "contract":
        return _run_contract(args)
    _outside(args.raw_root, args.truth_root)
    try:
        effects = [parse_effect(s) for s in args.effect]
    except ValueError as e:
        raise UsageError(str(e)) from None
    common = {
        "scan_id": args.scan_id,
        "night": args.night,
        "kind": args.kind,
        "seed": args.seed,
        "noise_mm": args.noise_mm,
        "effects": effects,
    }
    try:
        if args.sim_kind == "tri":
            scene = scenes.default_tri_scene(
                rpm_nominal=args.rpm,
                sample_rate_hz=args.sample_rate_hz,
                bore_radius_20_mm=args.diameter_mm / 2,
                phase_rad=args.phase_rad,
                direction="cw" if args.cw else "ccw",
                **({"spindle_xy_mm": tuple(args.spindle_xy_mm)} if args.spindle_xy_mm else {}),
            )
            sim = simulate.simulate_tri_spindle(
                scene,
                n_rev=args.n_rev,
                encoder=not args.no_encoder,
                center_xy_mm=scene.bore_center_xy_mm,
                **common,
            )
        elif args.sim_kind == "static":
            scene = scenes.default_tri_scene(
                bore_center_xy_mm=(0.0, 0.0), bore_radius_20_mm=args.diameter_mm / 2
            )
            rng = np.random.default_rng(args.seed + 1)
            r = 1.5 * np.sqrt(rng.uniform(0, 1, args.poses))
            a = rng.uniform(0, 2 * np.pi, args.poses)
            xy = np.stack([r * np.cos(a), r * np.sin(a)], -1)
            sim = simulate.simulate_tri_static(
                scene,
                xy,
                rng.uniform(0, 2 * np.pi, args.poses),
                samples_per_pose=args.samples_per_pose,
                **common,
            )
        else:
            sim = simulate.simulate_rod(
                None, n_poses=args.poses, samples_per_pose=args.samples_per_pose, **common
            )
    except ValueError as e:
        raise UsageError(str(e)) from None
    try:
        path = simulate.write_simulated(sim, args.raw_root, args.truth_root)
    except FileExistsError as e:
        raise UsageError(f"{e}; choose another --scan-id (or another --raw-root)") from None
    print(path)
    return 0


def _run_contract(args: argparse.Namespace) -> int:
    """``simulate contract``: write the battery, one progress line every ~10 % of the scans."""
    from borescan import rawio
    from borescan.synthetic import battery

    if args.n < 1:  # also checked by argparse; kept for programmatic callers
        raise UsageError(f"--n must be >= 1, got {args.n}")
    kinds = tuple(k.strip() for k in str(args.kinds).split(",") if k.strip())
    unknown = [k for k in kinds if k not in battery.BATTERY_KINDS]
    if unknown or not kinds:
        raise UsageError(
            f"--kinds {args.kinds!r}: each kind must be one of {', '.join(battery.BATTERY_KINDS)}"
        )
    bar = Progress(args.n * len(kinds), "  written", stream=sys.stdout, min_interval_s=0.0)

    def progress(i: int, n: int, path: Path) -> None:
        bar.update(i + 1, path.name)

    print(
        f"contract battery: {args.n} scans of each of {', '.join(kinds)}, seed {args.seed} -> {args.out}",
        flush=True,
    )
    try:
        paths = battery.write_battery(
            args.out,
            args.n,
            args.seed,
            effect_free=not args.with_effects,
            progress=progress,
            kinds=kinds,
            effect_share=args.effect_share,
            effect_scale_range=tuple(args.effect_scale),
            per_night=args.per_night,
        )
    except (FileExistsError, ValueError, rawio.ScanError) as e:
        raise UsageError(str(e)) from None
    print(
        f"{len(paths)} scans written under {args.out / 'raw'}; truth in {args.out / 'truth'}; "
        f"index {args.out / 'battery.json'}"
    )
    return 0
