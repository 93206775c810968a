"""Page layout of the certificate PDF (:class:`_Doc`) and the number and label style of its tables."""

from __future__ import annotations

import contextlib
import logging
import math
import textwrap
from collections.abc import Iterator
from typing import Any

import matplotlib
import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from borescan.uncertainty import round_uncertainty

_PDF_METADATA = {"Creator": None, "Producer": None, "CreationDate": None, "ModDate": None}

_RC = {"font.family": "DejaVu Sans", "font.size": 8, "svg.hashsalt": "borescan", "pdf.compression": 6}

#: The PDF's text set in Helvetica, one of the PDF standard's 14 fonts every reader has (nothing embedded):
#: matplotlib then writes each string whole, measured from the font's AFM metrics, instead of shaping,
#: tracking and subsetting DejaVu Sans glyph by glyph (about half a three-sensor certificate's CPU). Those
#: fonts encode WinAnsi (cp1252) only, so the residual axes' minus is the ASCII hyphen-minus; see
#: :func:`_pdf_rc` for a certificate whose text needs more than WinAnsi.
_PDF_CORE_RC = {
    "font.family": "Helvetica",
    "pdf.use14corefonts": True,
    "axes.unicode_minus": False,
}


def _pdf_rc(cert: dict) -> dict:
    """Return the matplotlib settings of the certificate's PDF pages.

    Helvetica (:data:`_PDF_CORE_RC`) when every string of ``cert`` is in WinAnsi (cp1252); otherwise the
    embedded DejaVu Sans of :data:`_RC`, which has the glyphs (a laboratory name in Polish, a Greek
    letter in a remark), so no character is ever replaced.
    """
    import json

    try:
        json.dumps(cert, ensure_ascii=False, sort_keys=True).encode("cp1252")
    except UnicodeEncodeError:
        return dict(_RC)
    return {**_RC, **_PDF_CORE_RC}


@contextlib.contextmanager
def _pdf_context(cert: dict) -> Iterator[None]:
    """Draw and write the certificate's PDF pages inside this.

    Its settings (:func:`_pdf_rc`), and matplotlib's warning that the core fonts' regular weight is named
    Medium silenced.
    """
    from matplotlib.backends import backend_pdf

    log, quiet = logging.getLogger("matplotlib.font_manager"), _HelveticaWeightFilter()
    log.addFilter(quiet)
    parse_afm = backend_pdf.AFM
    backend_pdf.AFM = _core_font_metrics
    try:
        with matplotlib.rc_context(_pdf_rc(cert)):
            yield
    finally:
        backend_pdf.AFM = parse_afm
        log.removeFilter(quiet)


#: the core fonts' metrics by AFM file, parsed once per process (:func:`_core_font_metrics`)
_AFM_BY_FILE: dict[str, Any] = {}


def _core_font_metrics(fh):
    """Return the parsed AFM file ``fh``, parsed on its first use in this process.

    matplotlib's PDF writer parses the whole AFM file of every core font a document uses (its kerning
    pairs included) only to read the font's name, once per document: 4 fonts and 40 certificates a
    night, about 25 ms of a certificate's CPU. Inside :func:`_pdf_context` it gets this instead; the
    files are matplotlib's own, the metrics are only read, and the documents are byte for byte the same.
    """
    from matplotlib._afm import AFM

    key = str(getattr(fh, "name", ""))
    if not key:
        return AFM(fh)
    if key not in _AFM_BY_FILE:
        _AFM_BY_FILE[key] = AFM(fh)
    return _AFM_BY_FILE[key]


class _HelveticaWeightFilter(logging.Filter):
    """Drop matplotlib's "Failed to find font weight normal for Helvetica (Courier), now using medium".

    The regular weight of the core fonts' AFM files is named Medium: it is the font asked for, not a
    substitute, so the warning would only clutter every calibration job's log.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        return not (
            str(record.msg).startswith("findfont: Failed to find font weight")
            and isinstance(record.args, tuple)
            and len(record.args) == 3
            and record.args[1] in ("Helvetica", "Courier")
            and record.args[2] == "medium"
        )


_A4 = (8.27, 11.69)


def _wrap(text: str, width: int) -> list[str]:
    out = []
    for para in str(text).split("\n"):
        out.extend(textwrap.wrap(para, width) or [""])
    return out


class _Doc:
    """A4 pages with a running header/footer stamped at the end (page x of y)."""

    TOP, BOTTOM, LEFT, RIGHT = 0.885, 0.075, 0.06, 0.94

    def __init__(self, cert: dict):
        self.cert = cert
        self.pages: list[Figure] = []
        self.new_page()

    def new_page(self) -> None:
        self.fig = Figure(figsize=_A4)
        self.pages.append(self.fig)
        self.y = self.TOP

    def room(self, h: float) -> None:
        if self.y - h < self.BOTTOM:
            self.new_page()

    def heading(self, text: str, size: float = 10.5) -> None:
        self.room(0.05)
        self.y -= 0.008
        self.fig.text(self.LEFT, self.y, text, fontsize=size, weight="bold")
        self.y -= 0.02

    def para(
        self,
        text: str,
        size: float = 7.5,
        width: int = 120,
        indent: float = 0.0,
        style: str = "normal",
        color: str = "black",
    ) -> None:
        for line in _wrap(text, width):
            self.room(0.014)
            self.fig.text(self.LEFT + indent, self.y, line, fontsize=size, style=style, color=color)
            self.y -= 0.0125 * size / 7.5
        self.y -= 0.004

    def kv(
        self, rows: list[tuple[str, str]], key_w: float = 0.23, width: int = 92, size: float = 7.5
    ) -> None:
        for key, val in rows:
            lines = _wrap(val, width)
            self.room(0.0135 * len(lines))
            self.fig.text(self.LEFT, self.y, key, fontsize=size, weight="bold")
            for line in lines:
                self.fig.text(self.LEFT + key_w, self.y, line, fontsize=size)
                self.y -= 0.0135
            self.y -= 0.002

    def table(
        self,
        cols: list[str],
        cells: list[list[str]],
        widths: list[float] | None = None,
        size: float = 6.5,
        row_h: float = 0.0145,
        bold_last: bool = False,
    ) -> None:
        """Draw a grid table at the current line: a header row, ``cells`` below it, equal rows.

        Column ``widths`` are shares of the text width (normalised; equal when None); each cell's
        text is centred in it. Drawn straight on the page (one text per cell, the grid as one line
        collection, the header's shading as one rectangle), without an Axes and its ``Table``:
        the same page as ``Axes.table(..., bbox=[0, 0, 1, 1], cellLoc="center")`` drew, at about
        half the cost of that table's axes, ticks and cell-by-cell layout.
        """
        n, ncol = len(cells) + 1, len(cols)
        h = row_h * n
        self.room(h + 0.01)
        shares = np.full(ncol, 1.0 / ncol) if widths is None else np.asarray(widths, float)
        edges = self.LEFT + (self.RIGHT - self.LEFT) * np.concatenate(
            ([0.0], np.cumsum(shares) / shares.sum())
        )
        top = self.y
        rows_y = top - row_h * np.arange(n + 1)
        fig = self.fig
        fig.add_artist(
            Rectangle(
                (self.LEFT, top - row_h),
                self.RIGHT - self.LEFT,
                row_h,
                transform=fig.transFigure,
                facecolor="#e8e8e8",
                edgecolor="none",
            )
        )
        segments = [[(self.LEFT, y), (self.RIGHT, y)] for y in rows_y]
        segments += [[(x, top), (x, top - h)] for x in edges]
        fig.add_artist(LineCollection(segments, transform=fig.transFigure, colors="black", linewidths=0.4))
        centres = (edges[:-1] + edges[1:]) / 2
        for r, row in enumerate([cols, *cells]):
            weight = "bold" if r == 0 or (bold_last and r == n - 1) else "normal"
            y = top - row_h * (r + 0.5)
            for x, text in zip(centres, row):
                fig.text(x, y, str(text), fontsize=size, weight=weight, ha="center", va="center")
        self.y -= h + 0.012

    def finish(self) -> list[Figure]:
        c = self.cert
        lab = c["laboratory"]
        n = len(self.pages)
        for i, fig in enumerate(self.pages):
            fig.text(self.LEFT, 0.962, str(lab.get("name")), fontsize=10, weight="bold")
            fig.text(self.LEFT, 0.948, str(lab.get("address")), fontsize=7)
            fig.text(self.LEFT, 0.936, str(lab.get("accreditation")), fontsize=6.5, style="italic")
            fig.text(self.RIGHT, 0.962, "Calibration certificate", fontsize=10, weight="bold", ha="right")
            fig.text(
                self.RIGHT,
                0.948,
                f"No. {c['administrativeData']['coreData']['uniqueIdentifier']}",
                fontsize=7.5,
                ha="right",
            )
            fig.text(self.RIGHT, 0.936, f"Page {i + 1} of {n}", fontsize=7.5, ha="right", weight="bold")
            fig.add_artist(_hline(fig, 0.928))
            fig.add_artist(_hline(fig, 0.058))
            fig.text(
                self.LEFT,
                0.046,
                "The results relate only to the item calibrated. This certificate shall not be "
                "reproduced except in full without the written approval of the issuing laboratory.",
                fontsize=6,
            )
            fig.text(
                self.LEFT,
                0.034,
                f"Issued {c['dates'].get('issue') or 'n/a'} by borescan {c['software_version']} "
                f"(config {c['config_hash']}); machine-readable copy: certificate.json",
                fontsize=6,
            )
            fig.text(self.RIGHT, 0.034, f"Page {i + 1} of {n}", fontsize=6, ha="right")
        return self.pages


def _hline(fig: Figure, y: float):
    from matplotlib.lines import Line2D

    return Line2D([_Doc.LEFT, _Doc.RIGHT], [y, y], transform=fig.transFigure, color="0.3", lw=0.6)


def _num(x: Any, spec: str, none: str = "n/a") -> str:
    try:
        x = float(x)
    except (TypeError, ValueError):
        return none if x is None else str(x)
    return format(x, spec) if np.isfinite(x) else none


def _scaled(x: Any, scale: float) -> float | None:
    return None if x is None else float(x) * scale


def _ppm(x: Any) -> str:
    try:
        return f"{float(x) * 1e6:.3g} x 10^-6 /K"
    except (TypeError, ValueError):
        return "n/a"


def _vu(value: float, U: float, scale: float = 1.0) -> tuple[str, str]:
    """Value and U (2 significant digits, rounded up) with the same decimals, both times ``scale``."""
    Ur, dec = round_uncertainty(U * scale)
    d = max(dec, 0)
    return f"{value * scale:.{d}f}", f"{Ur:.{d}f}"


def _sig(x: Any, digits: int = 3, none: str = "n/a") -> str:
    """Return ``x`` to ``digits`` significant digits in fixed-point notation, trailing zeros dropped.

    ``1670`` for 1.67e3, ``0.0000666`` for 6.66e-5, ``-0.5`` for -0.5: never an exponent.
    """
    try:
        x = float(x)
    except (TypeError, ValueError):
        return none
    if not np.isfinite(x):
        return none
    if x == 0.0:
        return "0"
    dec = max(digits - 1 - math.floor(math.log10(abs(x))), 0)
    text = f"{round(x, dec):.{dec}f}"
    return text.rstrip("0").rstrip(".") if "." in text else text


#: the unit a budget input is shown in, by its unit and kind: (factor from the JSON unit, value unit,
#: uncertainty unit). Positions and gauge diameters in mm, small lengths (linearity, resolution, the
#: fit's scatter) in um, angles in mrad, times in ms, expansion coefficients in ppm/K (10^-6/K).
_DISPLAY_UNITS = {
    ("mm", "position"): (1.0, "mm", "mm"),
    ("mm", "gauge"): (1.0, "mm", "mm"),
    ("mm", None): (1e3, "um", "um"),
    ("rad", None): (1e3, "mrad", "mrad"),
    ("s", None): (1e3, "ms", "ms"),
    ("degC", None): (1.0, "degC", "K"),
    ("1/K", None): (1e6, "ppm/K", "ppm/K"),
}


def _display_unit(unit: str, key: str) -> tuple[float, str, str]:
    kind = str(key).partition(":")[0]
    return _DISPLAY_UNITS.get((unit, kind)) or _DISPLAY_UNITS.get((unit, None)) or (1.0, unit, unit)


def _est_u_text(x: Any, u: Any, unit: str, key: str = "") -> tuple[str, str]:
    """Return a budget input's estimate and standard uncertainty as table cells.

    Both in the unit chosen for the input (:data:`_DISPLAY_UNITS`); u to 2 significant digits (rounded
    up, as U on the results page) and the estimate with the same decimals; "-" for a missing estimate,
    "(vector)" for a vector input's missing u.
    """
    scale, vunit, uunit = _display_unit(unit, key)
    if u is None or not np.isfinite(float(u)) or float(u) == 0.0:
        est = "-" if x is None else f"{_sig(float(x) * scale, 4)} {vunit}"
        return est, "(vector)" if u is None else f"0 {uunit}"
    ur, dec = round_uncertainty(float(u) * scale)
    d = max(dec, 0)
    est = "-" if x is None else f"{float(x) * scale:.{d}f} {vunit}"
    return est, f"{ur:.{d}f} {uunit}"


_DIST = {
    "normal": "normal",
    "rectangular": "rect.",
    "triangular": "triang.",
    "arcsine": "U-shaped",
    "multivariate normal": "normal (vec.)",
}


def _dof_text(nu: Any) -> str:
    if nu is None:
        return "inf"
    nu = float(nu)
    return "inf" if not np.isfinite(nu) or nu > 1e5 else f"{nu:.0f}"


def _short_quantity(row: dict) -> str:
    q = row["quantity"]
    return q if len(q) <= 52 else q[:50] + ".."


def _line(fig: Figure, x0: float, x1: float, y: float):
    from matplotlib.lines import Line2D

    return Line2D([x0, x1], [y, y], transform=fig.transFigure, color="black", lw=0.6)


def _date_range(dates: dict) -> str:
    b, e = dates.get("begin"), dates.get("end")
    if not b:
        return "n/a"
    return b if b == e or not e else f"{b} to {e}"


def _dominant_label(key: str) -> str:
    if not key:
        return ""
    kind = key.split(":", 1)[0]
    labels = {
        "fit": "fit to the readings (Type A)",
        "linearity": "sensor linearity",
        "resolution": "sensor resolution",
        "gauge": "reference gauge",
        "temperature": "temperature",
        "cte": "expansion coefficient",
        "position": "reported positions",
        "readings": "readings",
    }
    tail = key.rsplit(":", 1)[-1]
    return labels.get(kind, kind) + (f" ({tail})" if kind in ("linearity", "resolution") else "")


def _label(row: dict) -> str:
    """Short name of a budget row for the PDF tables (the full one is in certificate.json)."""
    key = str(row.get("key", ""))
    kind, _, rest = key.partition(":")
    tail = key.rsplit(":", 1)[-1]
    if kind == "fit":
        names = {
            "readings": "fit to the readings (scatter)",
            "second_order": "2nd-order term of d_b in rho",
            "extrema": "extreme readings (scatter)",
        }
        if tail.startswith("profile"):
            return f"rho profile, ch {tail.removeprefix('profile')} (non-linear)"
        return names.get(tail, "unresolved mirror solution " + tail.removeprefix("mirror"))
    if kind == "device_model":  # device_model:<device>:<effect key>:<parameter>@<night>
        parts = rest.split(":")
        return (
            f"device model {parts[1]} {parts[2].split('@')[0]}" if len(parts) >= 3 else _short_quantity(row)
        )
    if kind == "position":
        return f"offset S-C, {tail} (reported positions)"
    if kind == "gauge":
        return f"gauge {rest.split('@')[0]}: certified D20"
    if kind == "temperature":
        return f"temperature, {rest}"
    if kind == "cte":
        return f"expansion coeff., {rest.split('@')[0]}"
    if kind in ("linearity", "resolution"):
        what = "calib." if "(calibration)" in row.get("quantity", "") else "meas."
        return f"{kind}, ch {tail.removeprefix('ch')} ({what})"
    if kind == "readings":
        return "readings (scatter)"
    return _short_quantity(row)


def _tiny(r: dict, uc: float) -> bool:
    c = r.get("contribution") or 0.0
    return uc > 0 and c < 1e-5 * uc


def _fixed_title(ax, text: str) -> None:
    """Title ``text`` at the top left of a residual panel, where matplotlib would put it, without measuring.

    Left to itself, matplotlib measures every y tick label of the panel at each drawing to see
    whether the axis's offset text ("1e3", "+1000") would cover the title (a tenth of a certificate's
    CPU); the panel's y labels are written in full instead (no offset text, no multiplier), so the
    title stays at the top of the axes, where it was placed: the same pixels.
    """
    ax.ticklabel_format(axis="y", style="plain", useOffset=False)
    ax.set_title(text, fontsize=8, loc="left", y=1.0)
