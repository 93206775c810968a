"""Paired CPU of rod examinations: the base fit and capped refits as before against the rod's stall rule.

``python -m bench.bench_rod_examination SEED KIND:I ...`` (``OPENBLAS_NUM_THREADS=1``): each draw of the
contract battery (:mod:`bench.bench_discrepancy_contract`, its first 300 rod draws of ``SEED``, sized the
same) is examined twice in turn by each behaviour in one process, CPU by ``time.process_time``: "old" holds
``search.Fitter.refit_gain_bic`` at 0 (one base fit of up to ``BASE_MAX_NFEV`` evaluations, every capped
candidate refitted from the base start), "new" is the examination as shipped. Prints the CPU seconds and
the verdict and names of each.
"""

from __future__ import annotations

import sys
import time

from bench.bench_discrepancy_contract import _draw, _jobs, _sized
from borescan.discrepancy import examine as ex
from borescan.discrepancy.examine import discrepancy_settings, examine_scan
from borescan.discrepancy.search import Fitter


class _HeldFitter(Fitter):
    """The fitter with ``refit_gain_bic`` held at 0 (the behaviour before the rod's stall rule)."""

    def __setattr__(self, k, v):
        super().__setattr__(k, 0.0 if k == "refit_gain_bic" else v)


def main(argv: list[str]) -> None:
    """Examine each ``KIND:I`` draw of seed ``argv[0]`` by both behaviours, alternated twice."""
    seed = int(argv[0])
    jobs = {(j[0], j[2]): j for j in _jobs(300, seed, 0.2, 300.0, ("rod", "rod_calibration"), 0.15)}
    cfg = discrepancy_settings()
    for spec in argv[1:]:
        kind, i = spec.split(":")
        job = jobs[(kind, int(i))]
        sim, kw = _draw(kind, seed, int(i), job[3], 1.0, False)
        scale, extra, _ = _sized(job, kw, cfg, sim, float(sim.truth["contract"]["noise_mm"]))
        sim, _ = _draw(kind, seed, int(i), job[3], scale, False, extra)
        res: dict[str, list] = {"old": [], "new": []}
        try:
            for _ in range(2):
                for name, cls in (("old", _HeldFitter), ("new", Fitter)):
                    ex.Fitter = cls
                    t0 = time.process_time()
                    f = examine_scan(sim, **kw, **cfg)
                    named = [f"{n['effect']}@{n.get('channel')}" for n in f["named"]]
                    res[name].append((time.process_time() - t0, f["verdict"], named))
        finally:
            ex.Fitter = Fitter
        cols = [
            f"{k}: {', '.join(f'{c:.2f}' for c, _, _ in v)} s {v[0][1]} {v[0][2]}" for k, v in res.items()
        ]
        print(spec, " | ".join(cols), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
