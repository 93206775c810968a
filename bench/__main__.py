"""Run all benchmarks (or those named on the command line): python -m bench [name ...].

The headline runs first: ``contract_night`` (a night drawn over the whole contract, raw to
report); the reference night (``pipeline``) stays as a regression guard. A benchmark module with
``RUN_BY_DEFAULT = False`` (one that takes many minutes) runs only when named.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
from pathlib import Path

HEADLINE = "bench_contract_night"


def main(argv: list[str]) -> int:
    """Run the benchmarks whose names contain one of ``argv`` (all run by default when empty); return 0."""
    here = Path(__file__).parent
    names = sorted(
        (m.name for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_")),
        key=lambda n: (n != HEADLINE, n),
    )
    if argv:
        names = [n for n in names if any(a in n for a in argv)]
    for name in names:
        module = importlib.import_module(f"bench.{name}")
        if not argv and not getattr(module, "RUN_BY_DEFAULT", True):
            print(
                f"=== {name}: run on request only (python -m bench {name.removeprefix('bench_')})", flush=True
            )
            continue
        print(f"=== {name}", flush=True)
        module.main()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
