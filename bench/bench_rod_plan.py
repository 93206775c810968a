"""CPU of the rod hold plan (``plan_rod.recommend_rod``) on the demo rod's verification holds.

The measure stage asks it, for each verification layer whose U(E) is not below the tolerance,
what would reduce it (``plan_rod.dominant_fix``: the fewest poses over 360, 270 and 180 deg
that bring u(D) to half the allowed u(E)). This bench runs the demo rod's verifications
(:func:`bench.bench_rod_demo.run`), keeps each verification hold and the target that
``dominant_fix`` is given, and times ``recommend_rod`` on each with those spreads on the CPU clock
of this process (``time.process_time``: pin BLAS to one thread, ``OPENBLAS_NUM_THREADS=1``, or its
spinning threads are counted too), best of ``--repeat``. Printed per hold: CPU s and the
recommendation per spread. Compare two checkouts by running it with each one's ``src`` on
``PYTHONPATH``, alternated.

Run: ``OPENBLAS_NUM_THREADS=1 python -m bench.bench_rod_plan --raw RAW_ROOT`` (``borescan simulate
demo`` writes one).
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

RUN_BY_DEFAULT = False

#: the spreads ``plan_rod.dominant_fix`` asks for [rad]
SPREADS_RAD = (2 * math.pi, 1.5 * math.pi, math.pi)


def holds(raw_root: Path) -> list[tuple]:
    """Return (hold, target u(D) [mm]) of every verification layer whose fix the measure stage asks for."""
    from borescan import plan_rod
    from borescan.plan_rod import hold_of_solution

    from . import bench_rod_demo

    seen = []
    ask = plan_rod.dominant_fix

    def record(key, diameter, coaxiality_mm, u_allowed_mm):
        seen.append((hold_of_solution(diameter["solution"], coaxiality_mm), 0.5 * u_allowed_mm))
        return ask(key, diameter, coaxiality_mm, u_allowed_mm)

    plan_rod.dominant_fix = record
    try:
        bench_rod_demo.run(raw_root)
    finally:
        plan_rod.dominant_fix = ask
    return seen


def main(argv=None) -> None:
    """Print the plan's CPU per verification hold (module doc)."""
    from borescan.plan_rod import recommend_rod

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--raw", type=Path, default=os.environ.get("BORESCAN_DEMO_RAW"))
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args([] if argv is None and __name__ != "__main__" else argv)
    if args.raw is None:
        print("no demo raw root: pass --raw or set BORESCAN_DEMO_RAW (borescan simulate demo writes one)")
        return
    total = 0.0
    for i, (hold, target) in enumerate(holds(args.raw)):
        cpu = []
        for _ in range(args.repeat):
            t0 = time.process_time()
            res = recommend_rod(hold, target, spreads_rad=SPREADS_RAD)
            cpu.append(time.process_time() - t0)
        total += min(cpu)
        rec = ", ".join(
            f"{math.degrees(s):.0f} deg: " + ("none" if b is None else f"{b.hold.n_poses} poses")
            for s, b in res
        )
        print(f"hold {i}: target u(D) {target * 1e3:.2f} um, CPU {min(cpu):.4f} s; {rec}")
    print(f"recommend_rod CPU, sum over holds (best of {args.repeat}): {total:.3f} s")


if __name__ == "__main__":
    main()
