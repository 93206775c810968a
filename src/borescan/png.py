"""PNG files of rendered plots: rows unfiltered, one zlib stream (PNG specification, ISO/IEC 15948).

A plot is mostly flat colour (white paper, a few lines and markers). Pillow, which matplotlib writes
PNG with, tries each of the five row filters on every row and keeps the one that looks best: on the
night's gap plots that took 26 ms of a 1200 x 950 plot at zlib level 1 and gave 189 kB, where the
rows unfiltered (filter type 0) take 8.5 ms and give 158 kB; the pixels are the same (lossless).
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

__all__ = ["PNG_SIGNATURE", "rgb_png"]

#: the eight bytes every PNG file starts with (ISO/IEC 15948, 5.2)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

_METRES_PER_INCH = 0.0254


def _chunk(kind: bytes, data: bytes) -> bytes:
    """Return one chunk: length, type, data, CRC-32 of type and data (ISO/IEC 15948, 5.3)."""
    crc = zlib.crc32(kind + data) & 0xFFFFFFFF
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)


def rgb_png(pixels: np.ndarray, dpi: float | None = None, level: int = 1) -> bytes:
    """Return the PNG file of ``pixels``: 8-bit truecolour, rows unfiltered, zlib at ``level``.

    ``pixels``: (height, width, 3 or 4) uint8, top row first (an Agg canvas's ``buffer_rgba()``); only
    the first three channels are written (an opaque figure's alpha carries nothing). ``dpi``: written
    as the physical pixel size (pHYs, pixels per metre) as Pillow writes it; None writes none.
    """
    a = np.asarray(pixels)
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] not in (3, 4):
        raise ValueError(f"rgb_png needs (height, width, 3 or 4) uint8 pixels, got {a.dtype} {a.shape}")
    h, w = a.shape[:2]
    rows = np.empty((h, 1 + 3 * w), dtype=np.uint8)  # each row: filter type 0, then its RGB bytes
    rows[:, 0] = 0
    rows[:, 1:].reshape(h, w, 3)[...] = a[..., :3]
    out = [PNG_SIGNATURE, _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))]
    if dpi is not None:
        ppm = int(round(float(dpi) / _METRES_PER_INCH))
        out.append(_chunk(b"pHYs", struct.pack(">IIB", ppm, ppm, 1)))
    out += [_chunk(b"IDAT", zlib.compress(rows.data, level)), _chunk(b"IEND", b"")]
    return b"".join(out)
