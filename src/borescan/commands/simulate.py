"""``borescan simulate``: write simulated scans (``borescan-raw/1``) and their ground truth.

``borescan simulate demo --out DIR [--seed N]`` writes the embedded demo nights;
``borescan simulate tri|static|rod --raw-root RAW --truth-root TRUTH ...`` writes one scan, with
``--effect NAME:key=value,...`` (repeatable) for the named effects of the spec;
``borescan simulate contract --n N --seed S --out DIR`` writes the contract battery
(:func:`borescan.scenarios.write_battery`: ring-gauge calibration scans drawn over every range
the raw format and the geometry page allow; DIR/raw, DIR/truth, DIR/battery.json).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from borescan.effects import EFFECTS, parse_effect

NAME = "simulate"
HELP = "write simulated scans in borescan-raw/1 plus ground truth (demo nights, one scan, or the contract battery)"


def _int_at_least(minimum: int):
    """argparse type: an integer >= ``minimum``, with a message naming the bound."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {v}")
        return v

    return parse


_positive_int = _int_at_least(1)
_nonnegative_int = _int_at_least(0)


def _common(p: argparse.ArgumentParser, kind: str, scan_id: str, noise: float) -> None:
    p.add_argument("--raw-root", type=Path, required=True,
                   help="raw root (night=*/scan=* folders are written here)")
    p.add_argument("--truth-root", type=Path, required=True,
                   help="folder for <scan_id>.truth.json (keep it outside the raw root)")
    p.add_argument("--scan-id", default=scan_id, help=f"scan id (default {scan_id})")
    p.add_argument("--night", default="2026-11-20", help="night YYYY-MM-DD (default 2026-11-20)")
    p.add_argument("--kind", default=kind, help=f"scan kind (default {kind})",
                   choices=("calibration", "centering", "verification", "measurement"))
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--noise-mm", type=float, default=noise,
                   help=f"reading noise sigma [mm] (default {noise})")
    p.add_argument("--effect", action="append", default=[], metavar="NAME:k=v,...",
                   help="named effect, e.g. channel_delay:channel=2,tau_s=0.0012 (repeatable); "
                        f"names: {', '.join(EFFECTS)}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Sub-subcommands ``demo``, ``tri``, ``static``, ``rod``, ``contract``."""
    from borescan.simulate import ROD_NOISE_MM, TRI_NOISE_MM, YANG_RING_GAUGE_DIAMETER_MM

    sub = parser.add_subparsers(dest="sim_kind", metavar="WHAT", required=True)
    p = sub.add_parser("demo", help="the embedded demo nights (2 nights, TRI-01 and ROD-01)")
    p.add_argument("--out", type=Path, required=True,
                   help="output folder (DIR/raw, DIR/truth, DIR/.complete)")
    p.add_argument("--seed", type=int, default=None, help="seed (default: the fixed demo seed)")

    p = sub.add_parser("tri", help="one three-sensor spindle scan (Yang 2017 set-up at P1 in RG-275)")
    _common(p, "calibration", "SIM-TRI-SPINDLE", TRI_NOISE_MM)
    p.add_argument("--n-rev", type=float, default=60.0, help="revolutions (default 60)")
    p.add_argument("--rpm", type=float, default=60.0, help="nominal speed [1/min] (default 60)")
    p.add_argument("--sample-rate-hz", type=float, default=660.0, help="LDS sample rate [Hz] (default 660)")
    p.add_argument("--diameter-mm", type=float, default=YANG_RING_GAUGE_DIAMETER_MM,
                   help="bore diameter at 20 degC [mm]")
    p.add_argument("--spindle-xy-mm", type=float, nargs=2, default=None, metavar=("X", "Y"),
                   help="spindle position (default P1 = 262.955 -275.502)")
    p.add_argument("--phase-rad", type=float, default=0.0, help="device angle at t = 0 [rad]")
    p.add_argument("--cw", action="store_true", help="turn clockwise")
    p.add_argument("--no-encoder", action="store_true", help="spindle stream without angle_rad (null)")

    p = sub.add_parser("static", help="static three-sensor measurements: one block of samples per pose")
    _common(p, "verification", "SIM-TRI-STATIC", TRI_NOISE_MM)
    p.add_argument("--diameter-mm", type=float, default=YANG_RING_GAUGE_DIAMETER_MM,
                   help="bore diameter at 20 degC [mm]")
    p.add_argument("--poses", type=int, default=10, help="number of device poses (default 10)")
    p.add_argument("--samples-per-pose", type=int, default=20, help="samples per pose (default 20)")

    p = sub.add_parser("rod", help="measuring rod in a two-hole part (Wang 2017 set-up)")
    _common(p, "measurement", "SIM-ROD", ROD_NOISE_MM)
    p.add_argument("--poses", type=int, default=24, help="rod rotations (default 24)")
    p.add_argument("--samples-per-pose", type=int, default=5, help="samples per rotation (default 5)")

    p = sub.add_parser("contract", help="battery of ring-gauge calibration scans drawn over the whole contract "
                                        "(borescan.scenarios; fixed seeds, scan i from its own child seed)")
    p.add_argument("--n", type=_positive_int, default=200, help="number of scans, >= 1 (default 200)")
    p.add_argument("--seed", type=_nonnegative_int, default=0, help="battery seed, >= 0 (default 0)")
    p.add_argument("--out", type=Path, required=True,
                   help="output folder (DIR/raw, DIR/truth, DIR/battery.json)")
    p.add_argument("--with-effects", action="store_true",
                   help="one named effect per scan (default: effect-free scans)")


def run(args: argparse.Namespace) -> int:
    """Write the requested scans; print the scan folders; exit 2 on bad effect specs."""
    from borescan import demo, simulate

    if args.sim_kind == "demo":
        paths = demo.make_demo(args.out, seed=demo.DEMO_SEED if args.seed is None else args.seed)
        print(f"{len(paths)} scans written under {args.out / 'raw'}; truth in {args.out / 'truth'}")
        return 0
    if args.sim_kind == "contract":
        return _run_contract(args)
    try:
        effects = [parse_effect(s) for s in args.effect]
    except ValueError as e:
        print(f"borescan simulate: {e}", file=sys.stderr)
        return 2
    common = {"scan_id": args.scan_id, "night": args.night, "kind": args.kind, "seed": args.seed,
              "noise_mm": args.noise_mm, "effects": effects}
    try:
        if args.sim_kind == "tri":
            scene = simulate.default_tri_scene(
                rpm_nominal=args.rpm, sample_rate_hz=args.sample_rate_hz,
                bore_radius_20_mm=args.diameter_mm / 2,
                phase_rad=args.phase_rad, direction="cw" if args.cw else "ccw",
                **({"spindle_xy_mm": tuple(args.spindle_xy_mm)} if args.spindle_xy_mm else {}),
            )
            sim = simulate.simulate_tri_spindle(scene, n_rev=args.n_rev, encoder=not args.no_encoder,
                                                center_xy_mm=scene.bore_center_xy_mm, **common)
        elif args.sim_kind == "static":
            scene = simulate.default_tri_scene(bore_center_xy_mm=(0.0, 0.0),
                                               bore_radius_20_mm=args.diameter_mm / 2)
            rng = np.random.default_rng(args.seed + 1)
            r = 1.5 * np.sqrt(rng.uniform(0, 1, args.poses))
            a = rng.uniform(0, 2 * np.pi, args.poses)
            xy = np.stack([r * np.cos(a), r * np.sin(a)], -1)
            sim = simulate.simulate_tri_static(scene, xy, rng.uniform(0, 2 * np.pi, args.poses),
                                               samples_per_pose=args.samples_per_pose, **common)
        else:
            sim = simulate.simulate_rod(None, n_poses=args.poses, samples_per_pose=args.samples_per_pose,
                                        **common)
    except ValueError as e:
        print(f"borescan simulate: {e}", file=sys.stderr)
        return 2
    path = simulate.write_simulated(sim, args.raw_root, args.truth_root)
    print(path)
    return 0


def _run_contract(args: argparse.Namespace) -> int:
    """``simulate contract``: write the battery, one progress line every ~10 % of the scans."""
    from borescan import rawio, scenarios

    if args.n < 1:  # also checked by argparse; kept for programmatic callers
        print(f"borescan simulate contract: --n must be >= 1, got {args.n}", file=sys.stderr)
        return 2
    step = max(1, args.n // 10)

    def progress(i: int, n: int, path: Path) -> None:
        if (i + 1) % step == 0 or i + 1 == n:
            print(f"  {i + 1}/{n} {path.name}", flush=True)

    print(f"contract battery: {args.n} scans, seed {args.seed} -> {args.out}", flush=True)
    try:
        paths = scenarios.write_battery(args.out, args.n, args.seed, effect_free=not args.with_effects,
                                        progress=progress)
    except (FileExistsError, ValueError, rawio.ScanError) as e:
        print(f"borescan simulate contract: {e}", file=sys.stderr)
        return 2
    print(f"{len(paths)} scans written under {args.out / 'raw'}; truth in {args.out / 'truth'}; "
          f"index {args.out / 'battery.json'}")
    return 0
