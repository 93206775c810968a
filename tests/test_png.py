"""borescan.png: the PNG writer of the gap plots, checked by an independent decoder (Pillow)."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from borescan.png import PNG_SIGNATURE, rgb_png


def _chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    """Return the (type, data) chunks of a PNG file, each CRC checked."""
    assert data[:8] == PNG_SIGNATURE
    out, at = [], 8
    while at < len(data):
        (n,) = struct.unpack(">I", data[at : at + 4])
        kind, body = data[at + 4 : at + 8], data[at + 8 : at + 8 + n]
        (crc,) = struct.unpack(">I", data[at + 8 + n : at + 12 + n])
        assert crc == zlib.crc32(kind + body) & 0xFFFFFFFF, kind
        out.append((kind, body))
        at += 12 + n
    return out


@pytest.mark.parametrize("shape", [(1, 1, 3), (7, 5, 4), (950, 1200, 4), (31, 2, 3)])
def test_pixels_come_back_from_an_independent_decoder(shape):
    """Random pixels (RGBA: the alpha dropped; odd sizes; a plot's size) decode to the same RGB."""
    rng = np.random.default_rng(sum(shape))
    px = rng.integers(0, 256, shape, dtype=np.uint8)
    png = rgb_png(px, dpi=110)
    im = Image.open(io.BytesIO(png))
    assert im.mode == "RGB" and im.size == (shape[1], shape[0])
    assert np.array_equal(np.asarray(im), px[..., :3])
    # the pixel size in whole pixels per metre (pHYs), as Pillow writes it for the same dpi
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(px[..., :3])).save(buf, format="png", dpi=(110, 110))
    assert dict(_chunks(png))[b"pHYs"] == dict(_chunks(buf.getvalue()))[b"pHYs"]
    assert im.info["dpi"] == pytest.approx((110, 110), abs=0.5 * 0.0254)


def test_a_strided_canvas_buffer_and_its_chunks():
    """A view of an RGBA buffer (not contiguous) is written as its RGB; the file holds IHDR, pHYs (or
    not), one IDAT and IEND, its rows filter type 0.
    """
    rgba = np.zeros((4, 3, 4), dtype=np.uint8)
    rgba[..., 0] = np.arange(12, dtype=np.uint8).reshape(4, 3)
    rgba[..., 3] = 255
    view = rgba[::-1]  # rows bottom up: a view with a negative stride
    for dpi, kinds in ((None, [b"IHDR", b"IDAT", b"IEND"]), (100, [b"IHDR", b"pHYs", b"IDAT", b"IEND"])):
        chunks = _chunks(rgb_png(view, dpi=dpi))
        assert [k for k, _ in chunks] == kinds
        w, h, depth, colour, *_ = struct.unpack(">IIBBBBB", chunks[0][1])
        assert (w, h, depth, colour) == (3, 4, 8, 2)
        rows = np.frombuffer(zlib.decompress(dict(chunks)[b"IDAT"]), dtype=np.uint8).reshape(4, 1 + 9)
        assert np.all(rows[:, 0] == 0)
        assert np.array_equal(rows[:, 1:].reshape(4, 3, 3), view[..., :3])


def test_anything_but_8_bit_rgb_or_rgba_is_refused():
    """Grey, 16-bit or flat arrays are refused with the shape and type named."""
    for bad in (np.zeros((4, 4), np.uint8), np.zeros((4, 4, 3), np.uint16), np.zeros((4, 4, 2), np.uint8)):
        with pytest.raises(ValueError, match="uint8 pixels"):
            rgb_png(bad)


def test_a_report_plot_is_the_picture_savefig_draws():
    """report.plots._png_bytes writes the pixels matplotlib's savefig draws at 100 dpi (opaque), pixel for
    pixel, and its pHYs says 100 dpi: a figure as the report's (constrained layout, error bars, rotated
    labels, a legend and text).
    """
    from matplotlib.figure import Figure

    from borescan.report.plots import PNG_DPI, _png_bytes

    def figure():
        fig = Figure(figsize=(6.4, 3.2), layout="constrained")
        ax = fig.subplots()
        x = np.arange(31)
        ax.errorbar(x, np.sin(x / 4.0), yerr=0.2, fmt="o", ms=3, label="conforms")
        ax.axhline(0.5, ls="--", color="C1")
        ax.set_xticks(x[::5], [f"2027-12-{d:02d}" for d in x[::5] + 1], rotation=30, ha="right")
        ax.set_ylabel("error [µm]")
        ax.legend(loc="lower left")
        fig.suptitle("TRI-01, gauge RG-275")
        return fig

    buf = io.BytesIO()
    figure().savefig(buf, format="png", dpi=PNG_DPI)
    want = np.asarray(Image.open(buf))
    got = Image.open(io.BytesIO(_png_bytes(figure())))
    assert np.all(want[..., 3] == 255)  # savefig's picture is opaque: its RGB is all there is to compare
    assert np.array_equal(np.asarray(got), want[..., :3])
    assert got.info["dpi"] == pytest.approx((PNG_DPI, PNG_DPI), abs=0.5 * 0.0254)
