"""Yang 2017 Table 2 as a model-discrepancy case: the samples per revolution.

Yang 2017 §3.2 sets 625 samples per revolution (60 rpm, so 625 Hz), but the sample numbers of
the extreme points in Table 2 advance by about 660 per revolution. In the spec's vocabulary this
is ``speed_error``: the spindle turns at rpm_nominal (1 + eps) while the model assumes
rpm_nominal, so a revolution lasts N = 625 / (1 + eps) samples, eps = 625 / N - 1. (The same
data say equally that the sensors sample at 625 N / 625 Hz = N Hz instead of 625 Hz; the
extreme-point numbers alone cannot tell the two apart.)

Model: the m-th extreme point of sequence j (channel, min/max) falls at sample
a_j + N m + e, e white (extremum jitter). Base model: N = 625 (intercepts free). With the
effect: N free. Same BIC rule as the scans.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from borescan.discrepancy.fitting import bic
from borescan.noise import mad_sigma
from borescan.resources import shipped

__all__ = ["NOMINAL_SAMPLES_PER_REV", "TABLE2_NUMBERS", "load_table2", "examine_table2"]

NOMINAL_SAMPLES_PER_REV = 625.0

#: Sample numbers of the extreme points, Yang 2017 Table 2 (transcribed from the paper text;
#: used when ``data/papers/yang2017_table2.csv`` is absent). Keys (channel, kind).
TABLE2_NUMBERS: dict[tuple[int, str], list[int]] = {
    (1, "min"): [
        312,
        971,
        1628,
        2287,
        2949,
        3610,
        4269,
        4926,
        5589,
        6246,
        6909,
        7565,
        8229,
        8887,
        9545,
        10206,
        10866,
        11528,
    ],
    (1, "max"): [
        639,
        1300,
        1957,
        2616,
        3275,
        3937,
        4595,
        5256,
        5916,
        6577,
        7237,
        7894,
        8554,
        9215,
        9875,
        10534,
        11192,
        11855,
    ],
    (2, "min"): [
        88,
        749,
        1408,
        2067,
        2729,
        3386,
        4046,
        4707,
        5367,
        6028,
        6686,
        7345,
        8003,
        8663,
        9326,
        9985,
        10645,
        11305,
    ],
    (2, "max"): [
        418,
        1079,
        1738,
        2399,
        3056,
        3717,
        4377,
        5036,
        5694,
        6356,
        7015,
        7675,
        8336,
        8995,
        9652,
        10311,
        10974,
        11635,
    ],
    (3, "min"): [
        531,
        1188,
        1847,
        2511,
        3170,
        3831,
        4489,
        5148,
        5808,
        6468,
        7128,
        7788,
        8446,
        9106,
        9766,
        10420,
        11085,
        11746,
    ],
    (3, "max"): [
        199,
        858,
        1518,
        2180,
        2838,
        3498,
        4156,
        4818,
        5475,
        6136,
        6797,
        7455,
        8115,
        8776,
        9435,
        10095,
        10755,
        11416,
    ],
}


def _default_csv() -> Path:
    return shipped("papers", "yang2017_table2.csv")


def load_table2(path: str | Path | None = None) -> dict[tuple[int, str], list[tuple[int, float]]]:
    """Extreme-point sample numbers per (channel, kind) as (row, number) pairs.

    Reads the transcription CSV (columns channel or sensor; kind ``min``/``max`` or
    ``d_min``/``d_max``; row; number; blank or non-numeric numbers are OCR gaps and skipped).
    Falls back to :data:`TABLE2_NUMBERS` when the file does not exist.
    """
    p = Path(path) if path is not None else _default_csv()
    if not p.exists():
        return {k: list(enumerate(map(float, v))) for k, v in TABLE2_NUMBERS.items()}
    import polars as pl

    df = pl.read_csv(p, infer_schema_length=0)  # all strings: tolerate gap markers
    cols = {c.lower(): c for c in df.columns}
    ch_col = cols.get("channel") or cols.get("sensor")
    kind_col = cols.get("kind") or cols.get("extreme")
    row_col = cols.get("row") or cols.get("index")
    num_col = cols.get("number") or cols.get("sample") or cols.get("sample_number")
    if not all((ch_col, kind_col, row_col, num_col)):
        raise ValueError(f"{p}: expected columns channel, kind, row, number; got {df.columns}")
    out: dict[tuple[int, str], list[tuple[int, float]]] = {}
    for ch, kind, row, num in zip(df[ch_col], df[kind_col], df[row_col], df[num_col]):
        try:
            val = float(str(num).replace(",", "").strip())
            r = int(float(row))
            c = int(float(ch))
        except (TypeError, ValueError):
            continue
        k = str(kind).lower().replace("d_", "").strip()
        if k not in ("min", "max"):
            continue
        out.setdefault((c, k), []).append((r, val))
    return {k: sorted(v) for k, v in out.items()}


def _fit(seqs, N: float | None):
    """LS fit of number = a_j + N m; N fixed when given. Returns (N, u_N, residuals)."""
    keys = sorted(seqs)
    rows, y = [], []
    for i, k in enumerate(keys):
        for m, v in seqs[k]:
            x = np.zeros(len(keys) + 1)
            x[i] = 1.0
            x[-1] = m
            rows.append(x)
            y.append(v)
    X, y = np.array(rows), np.array(y)
    if N is not None:
        y2 = y - N * X[:, -1]
        coef, *_ = np.linalg.lstsq(X[:, :-1], y2, rcond=None)
        return N, 0.0, y2 - X[:, :-1] @ coef
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ coef
    s2 = float(r @ r) / (y.size - X.shape[1])
    cov = np.linalg.inv(X.T @ X) * s2
    return float(coef[-1]), float(math.sqrt(cov[-1, -1])), r


def examine_table2(path: str | Path | None = None, *, threshold: float = 10.0) -> dict:
    """Name the Table 2 discrepancy (``speed_error``) with eps and its standard uncertainty.

    Returns
    -------
    dict in the findings format (gaps in samples: ``rms_samples``; ``rms_mm`` is None because
    the table holds sample numbers only), plus ``samples_per_rev`` measured and per sequence.
    """
    seqs = load_table2(path)
    _, _, r0 = _fit(seqs, NOMINAL_SAMPLES_PER_REV)
    N, uN, r1 = _fit(seqs, None)
    n = r0.size
    rss0, rss1 = float(r0 @ r0), float(r1 @ r1)
    p0 = len(seqs)
    dbic = bic(rss0, n, p0) - bic(rss1, n, p0 + 1)
    eps = NOMINAL_SAMPLES_PER_REV / N - 1.0
    u_eps = NOMINAL_SAMPLES_PER_REV / N**2 * uN
    # jitter floor from second differences of each sequence (robust), in samples
    d2 = np.concatenate([np.diff([v for _, v in s], 2) for s in seqs.values() if len(s) > 2])
    floor = float(mad_sigma(d2) / math.sqrt(6.0))
    per_seq = {f"{c}-{k}": _fit({(c, k): s}, None)[:2] for (c, k), s in sorted(seqs.items())}
    named = []
    verdict = "no_missing_effect"
    if dbic > threshold:
        verdict = "missing_effect"
        named.append(
            {
                "effect": "speed_error",
                "channel": None,
                "parameters": {"eps": eps},
                "uncertainties": {"u_eps": u_eps},
                "evidence": {"delta_bic": float(dbic)},
                "note": (
                    f"{N:.2f} +- {uN:.2f} samples per revolution instead of 625: the spindle turns at "
                    f"rpm_nominal (1 {eps:+.4f}), or equivalently the sensors sample at {N:.1f} Hz "
                    "instead of 625 Hz"
                ),
            }
        )
    return {
        "scan_id": "yang2017-table2",
        "verdict": verdict,
        "named": named,
        "gap_before": {"rms_mm": None, "rms_samples": math.sqrt(rss0 / n)},
        "gap_after": {"rms_mm": None, "rms_samples": math.sqrt(rss1 / n)},
        "noise_floor_mm": None,
        "noise_floor_samples": floor,
        "samples_per_rev": {
            "nominal": NOMINAL_SAMPLES_PER_REV,
            "measured": N,
            "u_measured": uN,
            "by_sequence": {k: {"value": v, "u": u} for k, (v, u) in per_seq.items()},
        },
        "n_extreme_points": n,
        "source": str(path)
        if path is not None
        else (str(_default_csv()) if _default_csv().exists() else "in-memory transcription"),
    }
