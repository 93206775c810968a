"""Discrepancy workflow benchmark: a seeded battery of 40 spindle scans with hidden effects.

Prints the share named correctly, the false-alarm rate, the share of claims whose gap after is at the
noise floor (within 1.10x) and CPU seconds per scan.
"""

from __future__ import annotations

import time


def main() -> None:
    """Run a 40-scan battery; print its table, accuracy, false alarms and CPU time per scan."""
    from borescan.discrepancy.battery import run_battery

    t0 = time.process_time()
    res = run_battery(40, seed=3)
    cpu = (time.process_time() - t0) / len(res.rows)
    print(res.table())
    print(
        f"correct naming {res.accuracy:.1%}; false alarms {res.false_alarm_rate:.1%}; "
        f"gap after at the floor on {res.share_at_floor:.1%} of the claims; {cpu:.2f} s CPU per scan"
    )


if __name__ == "__main__":
    main()
