"""Logging for workflow scripts: messages go to the rule's log file and to stderr (progress)."""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path
from typing import Callable, Iterator


@contextlib.contextmanager
def log_to(path: str | Path) -> Iterator[Callable[[str], None]]:
    """Yield a ``log(msg)`` function writing timestamped-by-elapsed-time lines to ``path`` and stderr."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with path.open("w") as fh:

        def log(msg: str) -> None:
            line = f"[{time.perf_counter() - t0:7.2f} s] {msg}"
            fh.write(line + "\n")
            fh.flush()
            print(line, file=sys.stderr, flush=True)

        yield log
