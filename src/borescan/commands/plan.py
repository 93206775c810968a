"""``borescan plan``: what a proposed ring-gauge calibration scan will fix.

And the smallest scan that fixes enough.

The device's design comes from a preset (``--device yang``: Yang 2017's beams, Table 1, on his 275.029 mm
ring at sigma 2 um; ``--device demo``: TRI-01's design of the embedded demo, sigma 4 um) or from a scan
folder (``--scan DIR``: its scan.json ``device.nominal`` beams, sensors' ranges and gauge, and the noise
floor of its own readings). :func:`borescan.plan.predict` gives each parameter's Cramer-Rao standard
uncertainty and each beam's mirror depth for the proposed scan; :func:`borescan.plan.recommend` the
fewest revolutions, then the smallest offset, that reach ``--target-u-beta-urad`` with every rho's sign
resolved and every reading inside its sensor's range.
"""

from __future__ import annotations

import dataclasses
import argparse
import math
from pathlib import Path

from borescan.commands._common import UsageError

NAME = "plan"
HELP = (
    "predict a calibration scan's uncertainties (Cramer-Rao) and each beam's mirror depth, and "
    "recommend the smallest scan reaching a target"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``borescan plan`` options to ``parser``."""
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--device", choices=("yang", "demo"), help="a built-in device design and its ring gauge")
    src.add_argument(
        "--scan", type=Path, metavar="DIR", help="a tri_lds scan folder: its design, sensors, gauge, noise"
    )
    src.add_argument(
        "--rod-scan",
        type=Path,
        metavar="DIR",
        help="a rod scan folder (one hold): the poses and spread that bring its u(D) to --target-u-d-um",
    )
    parser.add_argument(
        "--target-u-d-um", type=float, default=2.5, help="rod: target standard uncertainty of a diameter [um]"
    )
    parser.add_argument(
        "--poses-grid",
        type=int,
        nargs="+",
        default=[8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256],
        help="rod: numbers of poses the recommendation tries",
    )
    parser.add_argument(
        "--spreads-deg",
        type=float,
        nargs="+",
        default=[90.0, 180.0, 270.0, 360.0],
        help="rod: arcs the poses may cover [deg]",
    )
    parser.add_argument(
        "--noise-um", type=float, default=None, help="sensor noise sigma [um] (overrides the design's)"
    )
    parser.add_argument(
        "--range-mm", type=float, default=None, help="sensor range [mm] (overrides the design's)"
    )
    parser.add_argument(
        "--offset-mm", type=float, default=2.3, help="spindle offset from the gauge centre [mm]"
    )
    parser.add_argument(
        "--offset-direction-deg", type=float, default=0.0, help="direction of that offset [deg]"
    )
    parser.add_argument("--revolutions", type=float, default=60.0, help="revolutions of the scan")
    parser.add_argument(
        "--samples-per-rev", type=int, default=660, help="samples per revolution at the first speed"
    )
    parser.add_argument("--rpm", type=float, nargs="+", default=[60.0], help="speeds, equal revolutions each")
    parser.add_argument("--direction", choices=("ccw", "cw"), default="ccw")
    parser.add_argument("--no-encoder", action="store_true", help="angle commanded, not measured")
    parser.add_argument(
        "--positions-unknown", action="store_true", help="scan.json gives no spindle/centre position"
    )
    parser.add_argument(
        "--target-u-beta-urad",
        type=float,
        default=50.0,
        help="target u(beta_c - beta_1) [urad] (a common rotation of the beams moves no diameter)",
    )
    parser.add_argument(
        "--offsets-mm",
        type=float,
        nargs="+",
        default=[0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0],
        help="offsets the recommendation tries [mm]",
    )
    parser.add_argument(
        "--revolutions-grid",
        type=float,
        nargs="+",
        default=[1, 2, 5, 10, 20, 30, 60, 120, 240],
        help="revolutions the recommendation tries",
    )


def _design(args):
    """(DeviceDesign, gauge radius [mm]) from the preset or the scan folder, with the overrides."""
    import numpy as np

    from borescan.geometry import Beams
    from borescan.plan import DeviceDesign
    from borescan.synthetic import scenes

    if args.device == "yang":
        beams, R, sig, rng = scenes.YANG_BEAMS, scenes.YANG_RING_GAUGE_DIAMETER_MM / 2, 0.002, 10.0
        c = 3
        sig, rng = (sig,) * c, (rng,) * c
    elif args.device == "demo":
        from borescan.synthetic import demo

        beams, R = demo.NOMINAL_BEAMS, demo.RG275["certified_diameter_mm"] / 2
        sig, rng = (scenes.TRI_NOISE_MM,) * 3, (10.0,) * 3
    else:
        from borescan import rawio
        from borescan.noise import noise_floor_mm

        try:
            scan = rawio.read_scan(args.scan)
        except rawio.ScanError as err:
            raise UsageError(str(err)) from None
        meta = scan.meta
        if (meta.get("device") or {}).get("type") != "tri_lds":
            raise UsageError(f"{scan.scan_id}: scan.json: not a tri_lds scan")
        beams = Beams.from_nominal(meta["device"]["nominal"]["beams"])
        art = meta.get("artifact") or {}
        d = art.get("certified_diameter_mm", art.get("nominal_diameter_mm"))
        if d is None:
            raise UsageError(f"{scan.scan_id}: scan.json: artifact has no diameter (no gauge to plan on)")
        R = float(d) / 2
        m = rawio.lds_matrix(scan)
        idx = [m.channels.index(ch) for ch in beams.channels]
        sig = tuple(float(x) for x in noise_floor_mm(np.asarray(m.values_mm)[:, idx], order=4))
        sensors = {int(s["channel"]): s for s in meta.get("sensors", [])}
        rng = tuple(float(sensors.get(ch, {}).get("range_mm", 10.0)) for ch in beams.channels)
    c = len(beams.channels)
    if args.noise_um is not None:
        sig = (args.noise_um * 1e-3,) * c
    if args.range_mm is not None:
        rng = (args.range_mm,) * c
    return DeviceDesign(beams, tuple(sig), tuple(rng)), float(R)


def _print(p, title: str) -> None:
    from borescan.plan import samples_to_resolve

    s = p.scan
    print(
        f"{title}: offset {s.offset_mm:g} mm at {math.degrees(s.offset_direction_rad):g} deg, "
        f"{s.revolutions:g} rev x {s.samples_per_rev} samples/rev ({s.n_samples} samples per channel), "
        f"rpm {', '.join(f'{r:g}' for r in s.rpm)}, "
        f"{'encoder' if s.encoder else 'commanded angle'}, positions "
        f"{'known' if s.positions_known else 'unknown'}; beams {p.beta_reference}; readings "
        f"{'inside' if p.in_range else 'OUTSIDE'} the sensors' range"
    )
    print(
        f"  {'ch':>3s} {'u(beta) urad':>13s} {'u(beta-beta1)':>14s} "
        f"{'u(rho) um':>10s} {'u(d_b) um':>10s} {'mirror dchi2':>13s} "
        f"{'sign':>9s} {'offset to resolve mm':>21s}"
    )
    for j, ch in enumerate(p.channels):
        depth = f"{p.mirror_depth[j]:.1f}" if p.mirror_possible[j] else "no mirror"
        print(
            f"  {ch:3d} {p.u_beta_rad[j] * 1e6:13.1f} {p.u_dbeta_rad[j] * 1e6:14.1f} "
            f"{p.u_rho_mm[j] * 1e3:10.2f} {p.u_d_b_mm[j] * 1e3:10.2f} "
            f"{depth:>13s} {'resolved' if p.resolved[j] else 'FLAGGED':>9s} {p.offset_to_resolve_mm[j]:21.2f}"
        )
    for j, ch in enumerate(p.channels):
        if not p.offset_can_resolve[j]:
            n_fix = samples_to_resolve(p.radius_mm, p.noise_mm[j], p.offset_limit_mm, p.rho_mm[j])
            print(
                f"  channel {ch}: no offset resolves the sign of rho ({p.rho_mm[j]:g} mm): it needs "
                f"{p.offset_to_resolve_mm[j]:.2f} mm and the sensors' range allows "
                f"{p.offset_limit_mm:.2f} mm; "
                f"take {math.ceil(n_fix)} samples per channel at that offset (more revolutions or samples "
                "per revolution) or a longer-range sensor"
            )


def run(args: argparse.Namespace) -> int:
    """Print the proposed scan's predicted uncertainties (or a recommended scan); return the exit status."""
    from borescan.config import schema_defaults
    from borescan.plan import ScanDesign, largest_offset_mm, predict, recommend

    if args.rod_scan is not None:
        return _run_rod(args)
    device, R = _design(args)
    scan = ScanDesign(
        offset_mm=args.offset_mm,
        offset_direction_rad=math.radians(args.offset_direction_deg),
        revolutions=args.revolutions,
        samples_per_rev=args.samples_per_rev,
        rpm=tuple(args.rpm),
        direction=args.direction,
        encoder=not args.no_encoder,
        positions_known=not args.positions_unknown,
        position_accuracy_mm=float(schema_defaults()["calibration"]["position_accuracy_mm"]),
    )
    print(
        f"gauge radius {R:.4f} mm; noise {', '.join(f'{s * 1e3:.2f}' for s in device.noise_mm)} um; "
        f"range {', '.join(f'{r:g}' for r in device.range_mm)} mm"
    )
    _print(predict(device, R, scan), "proposed")
    target = args.target_u_beta_urad * 1e-6
    rec = recommend(device, R, scan, target, args.offsets_mm, args.revolutions_grid)
    if rec is None:
        print(
            f"no scan of {max(args.revolutions_grid):g} revolutions or fewer at offsets up to "
            f"{max(args.offsets_mm):g} mm reaches u(beta_c - beta_1) "
            f"<= {args.target_u_beta_urad:g} urad with every rho "
            "resolved inside the sensors' range: more samples per revolution, lower noise or a longer-range "
            "sensor (a larger offset) would"
        )
        from dataclasses import replace

        limit_mm = largest_offset_mm(device, R)
        cands = [
            predict(device, R, replace(scan, revolutions=float(r), offset_mm=float(o)), limit_mm)
            for r in args.revolutions_grid
            for o in args.offsets_mm
        ]
        ok = [p for p in cands if p.in_range and all(p.resolved)]
        if ok:
            best = min(
                ok, key=lambda p: (round(max(p.u_dbeta_rad) * 1e6, 1), p.scan.n_samples, p.scan.offset_mm)
            )
            _print(
                best,
                f"best reachable of those (u(beta_c - beta_1) <= {max(best.u_dbeta_rad) * 1e6:.0f} urad)",
            )
        return 1
    _print(rec, f"recommended (u(beta_c - beta_1) <= {args.target_u_beta_urad:g} urad, every rho resolved)")
    return 0


def _run_rod(args: argparse.Namespace) -> int:
    """Print a hold's u(D), solved and planned, and per spread the fewest poses reaching the target."""
    from borescan import rawio, rod_calibration
    from borescan.calibrations import rod_layers, rod_nominal_calibration_rows
    from borescan.config import load_config
    from borescan.plan_rod import hold_of_solution, predict_rod, recommend_rod
    from borescan.preconditions import design_layers
    from borescan.rod import RodSolveError, solve_rod

    try:
        scan = rawio.read_scan(args.rod_scan)
        design_layers(scan.meta, "the plan solves the hold with the design layers")
    except (rawio.ScanError, ValueError) as err:
        raise UsageError(str(err)) from None
    if (scan.meta.get("device") or {}).get("type") != "rod":
        raise UsageError(f"{scan.scan_id}: scan.json: not a rod scan")
    coax = rod_calibration.rod_coaxiality_mm(load_config()["uncertainty"])
    channels, means, u_mean, _s = rod_calibration.pose_means_of_scan(scan)
    layers = rod_layers(rod_nominal_calibration_rows(scan.meta, scan.night, scan.scan_id), channels)
    try:
        sol = solve_rod(means, layers=layers, u_reading_mm=u_mean, coaxiality_mm=coax)
    except RodSolveError as err:
        print(f"{scan.scan_id}: lds.parquet: the hold gives no radii: {err}")
        return 1
    hold = hold_of_solution(sol, coax)
    here = predict_rod(hold)
    um = ", ".join
    print(
        f"{scan.scan_id}: {hold.n_poses} poses over {math.degrees(hold.spread_rad):.0f} deg, pose-mean "
        f"u {hold.sigma_mm * 1e3:.2f} um, deflection {hold.axis.omega_rad * 1e3:.2f} mrad, holes' coaxiality "
        f"{'not used' if coax is None else f'{coax:g} mm'}"
    )
    print(f"  u(D) of the solve [um]: {um(f'{x * 1e3:.2f}' for x in sol.u_diameter_mm)}")
    print(f"  u(D) planned for this hold's poses [um]: {um(f'{x * 1e3:.2f}' for x in here.u_diameter_mm)}")
    even = predict_rod(dataclasses.replace(hold, alpha_rad=None))
    print(
        "  u(D) planned for these poses equally spaced [um]: "
        + um(f"{x * 1e3:.2f}" for x in even.u_diameter_mm)
    )
    spreads = [math.radians(d) for d in args.spreads_deg]
    target = args.target_u_d_um * 1e-3
    ok = False
    for spread, best in recommend_rod(hold, target, args.poses_grid, spreads):
        if best is None:
            print(
                f"  over {math.degrees(spread):3.0f} deg: no hold of up to {max(args.poses_grid)} poses "
                "reaches "
                f"u(D) <= {args.target_u_d_um:g} um"
            )
        else:
            ok = True
            print(
                f"  over {math.degrees(spread):3.0f} deg: {best.hold.n_poses} poses give u(D) "
                f"{um(f'{x * 1e3:.2f}' for x in best.u_diameter_mm)} um"
            )
    if not ok:
        print(
            "  the rod held as in this scan cannot reach the target with more poses alone: hold it more "
            "skew to the holes (a larger deflection across its eccentricity), or lower the noise of a pose "
            "mean (more readings per pose)"
        )
    return 0 if ok else 1
