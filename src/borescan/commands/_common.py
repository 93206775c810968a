"""What the subcommands share.

What the subcommands share: the user-error exception, argument types, progress lines, times with their
zone.

Exit codes of every ``borescan`` command: 0 done; 1 the command ran and its answer is "no"
(``validate`` found problems, ``import-csv`` refused the data, ``trace`` knows no such id, a
query failed); 2 the command could not run as asked (bad arguments, a missing file or folder, a
scan that exists already). A user error never prints a traceback: raise :class:`UsageError`
(exit 2) or :class:`CommandFailed` (exit 1) with a message naming the problem.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import math
import sys
import time
from pathlib import Path
from typing import TextIO

__all__ = [
    "UsageError",
    "CommandFailed",
    "int_at_least",
    "positive_int",
    "nonnegative_int",
    "probability",
    "positive_float",
    "finite_float",
    "night_date",
    "Progress",
    "utc_text",
    "command_config",
]


class UsageError(Exception):
    """The command cannot run as asked (exit 2).

    The command cannot run as asked (exit 2); ``str()`` is the message shown after
    ``borescan <command>:``.
    """

    exit_code = 2


class CommandFailed(Exception):
    """The command ran and the answer is a failure (exit 1), e.g. an unknown id."""

    exit_code = 1


def int_at_least(minimum: int):
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


positive_int = int_at_least(1)
nonnegative_int = int_at_least(0)


def finite_float(text: str) -> float:
    """argparse type: a finite number."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    v = finite_float(text)
    if v <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return v


def probability(text: str) -> float:
    """argparse type: a share in [0, 1]."""
    v = finite_float(text)
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a share between 0 and 1, got {text}")
    return v


def night_date(text: str) -> str:
    """argparse type: a calendar date YYYY-MM-DD (a night)."""
    try:
        d = _dt.date.fromisoformat(text)
    except ValueError:
        d = None
    if d is None or len(text) != 10:
        raise argparse.ArgumentTypeError(f"expected a date YYYY-MM-DD, got {text!r}")
    return text


def utc_text(value: _dt.datetime) -> str:
    """Return a time with its zone, ISO 8601 in UTC: ``2026-11-21T22:14:03Z`` (fraction kept when present).

    The catalog stores TIMESTAMP values as naive UTC (:mod:`borescan.catalog`); a naive value is
    read as UTC, an aware one converted to it.
    """
    if value.tzinfo is not None:
        value = value.astimezone(_dt.timezone.utc).replace(tzinfo=None)
    return value.isoformat(timespec="microseconds" if value.microsecond else "seconds") + "Z"


class Progress:
    """Progress lines of a long command on ``stream`` (stderr): ``label i/n (p %), elapsed, left``.

    At most about ``lines`` lines plus the last, and never more than one per ``min_interval_s``
    seconds (the last always). Disabled when ``enabled`` is false.
    """

    def __init__(
        self,
        total: int,
        label: str,
        *,
        enabled: bool = True,
        lines: int = 10,
        min_interval_s: float = 1.0,
        stream: TextIO | None = None,
    ):
        self.total = max(int(total), 0)
        self.label = label
        self.enabled = enabled and self.total > 0
        self.step = max(1, self.total // max(lines, 1))
        self.min_interval_s = min_interval_s
        self.stream = stream
        self.t0 = time.monotonic()
        self._last = -math.inf

    def update(self, done: int, note: str = "") -> None:
        """Report that ``done`` of ``total`` are finished."""
        if not self.enabled:
            return
        now = time.monotonic()
        last = done >= self.total
        if not last and (done % self.step or now - self._last < self.min_interval_s):
            return
        self._last = now
        elapsed = now - self.t0
        left = elapsed / done * (self.total - done) if done else math.nan
        tail = f", about {_duration(left)} left" if not last and math.isfinite(left) else ""
        text = (
            f"{self.label} {done}/{self.total} ({100 * done / self.total:.0f} %), {_duration(elapsed)}{tail}"
        )
        print(text + (f"  {note}" if note else ""), file=self.stream or sys.stderr, flush=True)


def _duration(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 60} min {s % 60:02d} s" if s >= 60 else f"{seconds:.0f} s"


def existing_path(path: Path, what: str) -> Path:
    """``path`` when it exists, else :class:`UsageError` naming it and ``what`` it should be."""
    if not Path(path).exists():
        raise UsageError(f"{what} {path} does not exist")
    return Path(path)


def command_config(path: Path | None) -> tuple[dict, str]:
    """Return the pipeline config a command judges by, with where it came from.

    ``path``, else ``config/config.yaml`` when present, else the schema's defaults
    (:func:`borescan.config.load_config`, checked against the schema). A missing or
    invalid file is a :class:`UsageError` naming it.
    """
    from borescan.config import ConfigError, load_config

    if path is None and Path("config/config.yaml").is_file():
        path = Path("config/config.yaml")
    if path is not None and not Path(path).is_file():
        raise UsageError(f"config file {path} does not exist")
    try:
        return load_config(path), str(path) if path is not None else "schema default"
    except ConfigError as err:
        raise UsageError(str(err)) from None
