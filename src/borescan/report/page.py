"""One page's context (links, plots drawn only when their input changed) and empty-section texts."""

from __future__ import annotations

import base64
import contextlib
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import polars as pl

from borescan.atomic import atomic_write_bytes, atomic_write_text
from borescan.parallel import map_in_order
from borescan.report.data import _code_fingerprint, frame_fingerprint
from borescan.report.plots import _png_bytes
from borescan.report.text import _img, _rel, _safe


@dataclass(frozen=True)
class PlotJob:
    """A plot to draw: ``plot(data, key, *args)`` as the month's PNG ``fname`` (sent to a worker)."""

    fname: str
    plot: Callable[..., Any]
    data: pl.DataFrame
    key: str
    args: tuple


def draw_plot(job: PlotJob) -> bytes:
    """Return the PNG of ``job`` (run on the report job's processes by :meth:`_PlotCache.draw`)."""
    return _png_bytes(job.plot(job.data, job.key, *job.args))


#: What a page holds where a plot still to be drawn goes (the PNG's base64, by :meth:`_PlotCache.draw`).
_PENDING = "@@PNG {}@@"


class _PlotCache:
    """Plots of one month folder: file name -> fingerprint of its input (``plots.json``).

    A plot whose input and code are unchanged is not drawn again. The others are drawn together
    once the page's sections are rendered (:meth:`draw`), on the report job's processes.
    """

    def __init__(self, folder: Path, use: bool = True):
        self.folder = folder
        self.file = folder / "plots.json"
        self.old: dict[str, str] = {}
        if use and self.file.is_file():
            with contextlib.suppress(ValueError):
                self.old = json.loads(self.file.read_text())
        self.new: dict[str, str] = {}
        self.pending: dict[str, PlotJob] = {}
        self.drawn = 0

    def embedded(self, key: str, job: PlotJob) -> str:
        """Return the PNG ``job.fname`` as base64, read back when its key is unchanged.

        Where the key changed or the file is gone, a placeholder that :meth:`draw` replaces.
        """
        self.new[job.fname] = key
        if self.old.get(job.fname) == key and (self.folder / job.fname).is_file():
            return base64.b64encode((self.folder / job.fname).read_bytes()).decode("ascii")
        self.pending[job.fname] = job
        return _PENDING.format(job.fname)

    def draw(self, workers: int = 1) -> dict[str, str]:
        """Draw the pending plots on up to ``workers`` processes and write them.

        Returns placeholder -> base64 of the PNG, for :func:`fill_plots`.
        """
        jobs = list(self.pending.values())
        out = {}
        for job, png in zip(jobs, map_in_order(draw_plot, jobs, workers), strict=True):
            atomic_write_bytes(self.folder / job.fname, png)
            out[_PENDING.format(job.fname)] = base64.b64encode(png).decode("ascii")
            self.drawn += 1
        self.pending.clear()
        return out

    def save(self) -> None:
        """Record the plots of the page just written and remove the ones it no longer shows."""
        for f in self.folder.glob("*.png"):
            if f.name not in self.new:
                f.unlink()
        atomic_write_text(self.file, json.dumps(self.new, indent=1, sort_keys=True) + "\n")


def fill_plots(fragment: str, drawn: dict[str, str]) -> str:
    """Return ``fragment`` with the placeholders of :meth:`_PlotCache.embedded` replaced by the PNGs."""
    for token, data in drawn.items():
        fragment = fragment.replace(token, data)
    return fragment


class _PieceCache:
    """HTML pieces of one month folder (``pieces.json``): key -> the piece and the files it looked at.

    A piece (a night's summary box and row, a scan's findings row) is keyed by the digest of the
    rows it shows; it is reused while those rows, the report's code and every results file the
    piece linked to or read (present or not, size and time) are unchanged, so a month's earlier
    nights are not rendered again when a night is added.
    """

    def __init__(self, folder: Path, use: bool = True):
        self.file = folder / "pieces.json"
        self.old: dict[str, dict[str, Any]] = {}
        if use and self.file.is_file():
            with contextlib.suppress(ValueError):
                self.old = json.loads(self.file.read_text())
        self.new: dict[str, dict[str, Any]] = {}
        self.rendered = 0

    def save(self) -> None:
        """Record the pieces of the page just written (the others are dropped)."""
        atomic_write_text(self.file, json.dumps(self.new, sort_keys=True) + "\n")


def _file_state(path: Path) -> list[int] | None:
    """Return [mtime_ns, size] of a file, None when it does not exist."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return [st.st_mtime_ns, st.st_size]


class Page:
    """The sections of one page over ``tables`` (a month's rows).

    ``up``: the page's path back to the results folder ("" for ``report.html``, ``"../../"`` for
    a month page); ``plots``: the month's plot folder as seen from the page; ``pieces``: the
    month's cached pieces (:meth:`piece`; None renders every piece).
    """

    def __init__(
        self,
        root: Path,
        tables: dict[str, pl.DataFrame],
        cache: _PlotCache,
        up: str = "",
        plots: str = "",
        pieces: _PieceCache | None = None,
    ):
        self.root = root
        self.t = tables
        self.cache = cache
        self.up = up
        self.plots = plots
        self.code = _code_fingerprint()
        self.pieces = pieces
        self._seen: dict[str, dict[str, Any]] | None = None  # what the piece being rendered looked at

    def link(self, path: str | None) -> str | None:
        """Return the page's relative link to a results file, None when it does not exist."""
        rel = _rel(self.root, path)
        if self._seen is not None and path:
            self._seen["links"][path] = rel
        return None if rel is None else self.up + rel

    def read_text(self, path: Path) -> str:
        """Return a results file's text (OSError when unreadable), remembered by the piece being rendered."""
        if self._seen is not None:
            self._seen["files"][str(path)] = _file_state(path)
        return path.read_text()

    def piece(self, kind: str, rows_key: str, render: Callable[[], Any]) -> Any:
        """Return ``render()`` (JSON: lists, dicts, text), reused from ``pieces.json`` when unchanged.

        ``rows_key`` is the digest of the rows the piece shows (:func:`group_fingerprints`); the
        piece is rendered again when it, the report's code, or a file it linked to or read changed.
        """
        key = hashlib.sha256(f"{self.code} {kind} {rows_key}".encode()).hexdigest()[:16]
        old = self.pieces.old.get(key) if self.pieces is not None else None
        if (
            old is not None
            and all(_rel(self.root, p) == rel for p, rel in old["links"].items())
            and all(_file_state(Path(p)) == st for p, st in old["files"].items())
        ):
            self.pieces.new[key] = old
            return old["value"]
        self._seen = {"links": {}, "files": {}}
        try:
            value = json.loads(json.dumps(render()))  # what a reuse returns: lists, not tuples
            seen = self._seen
        finally:
            self._seen = None
        if self.pieces is not None:
            self.pieces.new[key] = {"value": value, **seen}
            self.pieces.rendered += 1
        return value

    def figure(self, plot, data: pl.DataFrame, key: str, name: str, alt: str, *args) -> str:
        """Draw ``plot(data, key, *args)`` as ``<month>/<name>.png`` when its input changed.

        ``plot(data, key, *args)`` as ``<month>/<name>.png``, drawn only when its input changed (by
        :meth:`_PlotCache.draw`, which fills in the placeholder returned meanwhile); embedded in the
        page as a ``data:`` image that links to the PNG file.
        """
        fname = _safe(name) + ".png"
        fp = hashlib.sha256(
            f"{self.code} {plot.__name__} {key} {args} {frame_fingerprint(data)}".encode()
        ).hexdigest()[:16]
        return _img(self.plots + fname, self.cache.embedded(fp, PlotJob(fname, plot, data, key, args)), alt)

    # ---------------------------------------------------------------- sections


#: What a section says when the catalog holds no rows for it.
_EMPTY = {
    "calibration": '<p class="empty">No calibrations in the catalog.</p>',
    "verification": '<p class="empty">No verifications in the catalog.</p>',
    "diameters": '<p class="empty">No diameters in the catalog.</p>',
    "discrepancy": '<p class="empty">No findings in the catalog.</p>',
    "pooled": '<p class="empty">No pooled examination in the catalog.</p>',
    "quarantine": '<p class="empty">No quarantined scans.</p>',
    "summary": '<p class="empty">No nights in the catalog.</p>',
}
