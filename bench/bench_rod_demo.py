"""The demo rod's gauge verifications through the library path of the calibrate and measure stages.

The rod's ring-gauge calibration scan of a raw root (``*ROD01-CAL*``: ``rod_calibration.calibrate_hold``,
as the stage does, with the holes' coaxiality of the config) and each of its verification scans
(``*ROD01-VER*``: ``rod_diameters_with_budget``, ``rod_verifications`` against the config's
tolerance). Printed per layer: the error E, U(E), the verdict, the budget's largest inputs and
``dominant_fix``. ``--coaxiality none`` repeats it with the deflection bound alone (the radii
averaged over omega uniform on 0-2 deg).

Run: ``python -m bench.bench_rod_demo --raw RAW_ROOT`` (``borescan simulate demo`` writes one);
``python -m bench rod_demo`` uses ``$BORESCAN_DEMO_RAW`` or skips with a note.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

RUN_BY_DEFAULT = False


def run(raw_root: Path, coaxiality: str | None = None, cpu_s: dict | None = None) -> list[dict]:
    """Return the verification rows of the demo rod (the calibration of the first night).

    ``cpu_s``: filled with the CPU seconds of each item (the calibration, each verification and
    each rod measurement scan ``*ROD01-MEAS*``, whose diameters are solved but not returned).
    """
    from borescan import rawio, rod_calibration
    from borescan.config import load_config
    from borescan import measure

    cfg = load_config()
    unc = dict(cfg["uncertainty"])
    if coaxiality is not None:
        unc["rod_hole_coaxiality_mm"] = None if coaxiality == "none" else float(coaxiality)
    cpu_s = {} if cpu_s is None else cpu_s
    t0 = time.process_time()
    cal = rawio.read_scan(sorted(raw_root.glob("*/scan=*ROD01-CAL*"))[0], raw_root=raw_root)
    rows = rod_calibration.calibrate_hold(cal, unc).rows(cal.night, None, float(unc["coverage_probability"]))
    cpu_s[cal.scan_id] = time.process_time() - t0
    out = []
    for d in sorted(raw_root.glob("*/scan=*ROD01-VER*")) + sorted(raw_root.glob("*/scan=*ROD01-MEAS*")):
        t0 = time.process_time()
        scan = rawio.read_scan(d, raw_root=raw_root)
        res = measure.rod_diameters_with_budget(scan, rows, unc, cal.scan_id)
        if "-VER-" in scan.scan_id:
            out += measure.rod_verifications(
                scan, res, cal.scan_id, unc, cfg["laboratory"], float(cfg["verification"]["tolerance_mm"])
            )
        cpu_s[scan.scan_id] = time.process_time() - t0
    return out


def main(argv=None) -> None:
    """Print the demo rod's verifications (module doc)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--raw", type=Path, default=os.environ.get("BORESCAN_DEMO_RAW"))
    ap.add_argument("--coaxiality", default=None, help="mm, or 'none' (default: the config's)")
    args = ap.parse_args([] if argv is None and __name__ != "__main__" else argv)
    if args.raw is None:
        print("no demo raw root: pass --raw or set BORESCAN_DEMO_RAW (borescan simulate demo writes one)")
        return
    cpu_s: dict = {}
    for r in run(args.raw, args.coaxiality, cpu_s):
        top = sorted(r["budget"], key=lambda b: -abs(b["contribution"]))[:2]
        print(
            f"{r['scan_id']} {r['feature']}: E {r['error_mm'] * 1e3:+.2f} um, U(E) "
            f"{r['expanded_u_error_mm'] * 1e3:.2f} um "
            f"(k {r['k']:.2f}); largest: "
            + ", ".join(f"{b['key']} {b['contribution'] * 1e3:.1f} um" for b in top)
        )
        if r["dominant_fix"]:
            print(f"    to reduce it: {r['dominant_fix']}")
    for sid, t in cpu_s.items():
        print(f"compute {sid} {t:.2f} s")


if __name__ == "__main__":
    main()
