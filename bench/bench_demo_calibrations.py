"""The demo nights' three-sensor calibrations, fitted as a night fits them, to compare across versions.

Every tri_lds device's calibration scans of each demo night are fitted together
(:func:`borescan.stages.calibration_fit.calibrate_raw_scans`), with the acceptance rule's residual
limit lifted so that the nights whose fit the rule refuses (a channel delay not yet carried) are
compared too, and from 2026-11-23 on with ``channel_delay@2`` carried at 1.2 ms (the delay the demo
simulates, as the config's device model carries it from 2026-11-24). Printed: the CPU time of the
fits (this process); written (``--out``): each calibration's parameters, standard uncertainties,
residual rms and cost. ``--compare`` prints max |dp| / u and the cost ratio against an earlier file.

Run (two checkouts, alternated, the same demo)::

    borescan simulate demo --out /tmp/demo
    PYTHONPATH=<old>/src python -m bench.bench_demo_calibrations --raw /tmp/demo/raw --out old.npz
    PYTHONPATH=<new>/src python -m bench.bench_demo_calibrations --raw /tmp/demo/raw --compare old.npz
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from borescan import rawio
from borescan.config import schema_defaults
from borescan.device_model import DeviceEffect
from borescan.effects import Effect
from borescan.stages.calibration_fit import calibrate_raw_scans

RUN_BY_DEFAULT = False  # needs a demo written by ``borescan simulate demo``
DELAY_FROM_NIGHT = "2026-11-23"
DELAY = (DeviceEffect("channel_delay@2", (Effect("channel_delay", {"channel": 2, "tau_s": 1.2e-3}),)),)


def fit_demo(raw: Path) -> tuple[dict[str, np.ndarray], float]:
    """Return each night's calibration per device (arrays by ``night/device/what``), the fits' CPU [s]."""
    cfg = dict(schema_defaults()["calibration"], max_residual_to_noise=1e9)
    out: dict[str, np.ndarray] = {}
    cpu_s = 0.0
    for night in rawio.nights(raw):
        by_device: dict[str, list] = {}
        for d in rawio.night_scan_dirs(raw, night):
            scan = rawio.read_scan(d, raw_root=raw)
            if scan.meta.get("kind") == "calibration" and scan.meta["device"].get("type") == "tri_lds":
                by_device.setdefault(scan.meta["device"]["id"], []).append(scan)
        for device, scans in sorted(by_device.items()):
            model = DELAY if night >= DELAY_FROM_NIGHT else ()
            t0 = time.process_time()
            cal = calibrate_raw_scans(scans, cfg, night=night, model=model)
            cpu_s += time.process_time() - t0
            key = f"{night}/{device}"
            out[f"{key}/params"] = np.asarray(cal.params)
            out[f"{key}/u"] = np.sqrt(np.diag(np.asarray(cal.cov)))
            out[f"{key}/rms_mm"] = np.array([cal.residual_rms_mm])
            out[f"{key}/cost"] = np.array([cal.diagnostics["cost"]])
    return out, cpu_s


def compare(old: dict[str, np.ndarray], new: dict[str, np.ndarray]) -> float:
    """Print max |dp| / u (u the old one), u new / old and the cost ratio per calibration.

    Returns the largest |dp| / u. Each u that moved by more than 1e-4 of itself is listed by parameter.
    """
    worst = 0.0
    names = ("beta", "rho", "d_b")
    for key in sorted({k.rsplit("/", 1)[0] for k in old}):
        u_old, u_new = old[f"{key}/u"], new[f"{key}/u"]
        held = u_old == 0  # the gauge-fixed beta
        dp = np.abs(new[f"{key}/params"] - old[f"{key}/params"])[~held] / u_old[~held]
        ratio = float(new[f"{key}/cost"][0] / old[f"{key}/cost"][0])
        u_ratio = np.ones_like(u_old)
        u_ratio[~held] = u_new[~held] / u_old[~held]
        worst = max(worst, float(dp.max()))
        print(
            f"{key}: max |dp|/u {dp.max():.2e}, u new/old {u_ratio.min():.6f}-{u_ratio.max():.6f}, "
            f"cost ratio new/old {ratio:.15f}"
        )
        for i in np.flatnonzero(np.abs(u_ratio - 1.0) > 1e-4):
            print(f"    u({names[i % 3]} of channel {i // 3 + 1}) {u_old[i]:.6g} -> {u_new[i]:.6g}")
    return worst


def main(argv: list[str] | None = None) -> None:
    """Fit the demo's calibrations; write and compare them (module doc)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--raw", type=Path, required=True, help="raw root of a demo (borescan simulate demo)")
    ap.add_argument("--out", type=Path, help="write the calibrations' numbers here (.npz)")
    ap.add_argument("--compare", type=Path, help="an earlier --out to compare with")
    argv = sys.argv[1:] if argv is None else argv
    if "--raw" not in argv:  # named on ``python -m bench``'s command line: say how to run it
        print(
            "needs a demo: python -m bench.bench_demo_calibrations --raw <demo>/raw [--out F] [--compare F]"
        )
        return
    args = ap.parse_args(argv)
    numbers, cpu_s = fit_demo(args.raw)
    print(f"{len({k.rsplit('/', 1)[0] for k in numbers})} calibrations fitted in {cpu_s:.2f} s CPU")
    if args.out:
        np.savez(args.out, **numbers)
    if args.compare:
        with np.load(args.compare) as old:
            print(f"largest |dp|/u {compare(dict(old), numbers):.2e}")


if __name__ == "__main__":
    main()
