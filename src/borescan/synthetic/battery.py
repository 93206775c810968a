"""Batteries of contract scans written deterministically: scan i from its own child seed."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from borescan.synthetic.rod_scenarios import draw_rod_scan
from borescan.synthetic.simulate import write_simulated
from borescan.synthetic.tri_scenarios import draw_tri_calibration, draw_tri_measurement, draw_tri_static

__all__ = ["battery_rng", "BATTERY_KINDS", "battery_scan_id", "write_battery"]


def battery_rng(seed: int, index: int) -> np.random.Generator:
    """Return the generator of scan ``index`` of the battery ``seed``.

    Return the generator of scan ``index`` of the battery ``seed``:
    ``SeedSequence(seed, spawn_key=(index,))``.

    The same as ``SeedSequence(seed).spawn(n)[index]`` for any n > index, so a longer battery
    starts with the scans of a shorter one.
    """
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(index),)))


#: battery scan kinds -> (id prefix, child-seed stream): calibration scans keep the stream they always had
BATTERY_KINDS = {
    "calibration": ("CT", 0),
    "static": ("CS", 1),
    "rod": ("CR", 2),
    "measurement": ("CM", 3),
    "rod_calibration": ("CK", 4),
}


def battery_scan_id(seed: int, index: int, kind: str = "calibration") -> str:
    """Return the scan id of scan ``index`` of battery ``seed``.

    ``CT<seed>-<index:05d>`` (calibration), ``CS...`` (static sets), ``CR...`` (rods), ``CM...`` (rotating
    measurements), ``CK...`` (rod calibrations).
    """
    return f"{BATTERY_KINDS[kind][0]}{int(seed)}-{int(index):05d}"


def _kind_rng(seed: int, index: int, kind: str) -> np.random.Generator:
    stream = BATTERY_KINDS[kind][1]
    if stream == 0:
        return battery_rng(seed, index)
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(index), stream)))


def _battery_night(index: int, per_night: int = 25) -> str:
    """Night of scan ``index``: ``per_night`` scans a night from 2027-01-01."""
    from datetime import date, timedelta

    return (date(2027, 1, 1) + timedelta(days=index // per_night)).isoformat()


def write_battery(
    out_dir: Path | str,
    n: int,
    seed: int,
    *,
    effect_free: bool = True,
    only: Sequence[int] | None = None,
    progress: Callable[[int, int, Path], None] | None = None,
    kinds: Sequence[str] = ("calibration",),
    effect_share: float | None = None,
    effect_scale_range: tuple[float, float] = (1.0, 1.0),
    per_night: int = 25,
) -> list[Path]:
    """Write ``n`` contract calibration scans: raw tree under ``out_dir/raw``, truth under ``out_dir/truth``.

    Scan i (0-based) is :func:`draw_tri_calibration` with :func:`battery_rng` (seed, i), id
    :func:`battery_scan_id` and its own device (``TRI-<scan id>``); 25 scans a night from
    2027-01-01. ``out_dir/battery.json`` lists the seed, n and the scan ids. Writing the same
    battery again is a no-op (raw folders are write-once; same content is accepted).

    Parameters
    ----------
    out_dir : output folder
    n : number of scans (>= 1)
    seed : battery seed (>= 0)
    effect_free : False draws one named effect per scan
    only : write only these scan indices (each in 0..n-1): the same scans as in the whole
        battery, e.g. to re-examine a few
    progress : called as progress(k, total, scan_folder) after each scan (k counts from 0)
    kinds : which scans, ``n`` of each: ``"calibration"`` (:func:`draw_tri_calibration`),
        ``"static"`` (:func:`draw_tri_static`: ring gauges with certified diameters and parts
        with nominal ones), ``"rod"`` (:func:`draw_rod_scan`), ``"measurement"``
        (:func:`draw_tri_measurement` on the device of calibration scan i, the same night),
        ``"rod_calibration"`` (:func:`draw_rod_scan` as a calibration scan); each kind from its own seed
        stream
    effect_share : None: ``effect_free`` for every scan; else each scan has an effect with this
        probability, drawn with its size factor (log-uniform in ``effect_scale_range``) from the
        scan's own stream ``SeedSequence(seed, spawn_key=(i, 10 + kind stream))``, so the scans'
        other draws are those of the effect-free battery
    per_night : scans a night (index // per_night nights after 2027-01-01)

    Returns
    -------
    list of the scan folders, in the order written.
    """
    if int(n) < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if int(seed) < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    indices = list(range(int(n))) if only is None else [int(i) for i in only]
    if any(i < 0 or i >= int(n) for i in indices):
        raise ValueError(f"scan indices must lie in 0..{int(n) - 1}, got {indices}")
    out_dir = Path(out_dir)
    raw, truth = out_dir / "raw", out_dir / "truth"
    unknown = [k for k in kinds if k not in BATTERY_KINDS]
    if unknown or not kinds:
        raise ValueError(f"kinds must be among {sorted(BATTERY_KINDS)}, got {list(kinds)}")
    jobs = [(kind, i) for kind in kinds for i in indices]
    paths = []
    for k, (kind, i) in enumerate(jobs):
        free, factor = _effect_draw(seed, i, kind, effect_free, effect_share, effect_scale_range)
        night, sid = _battery_night(i, per_night), battery_scan_id(seed, i, kind)
        rng = _kind_rng(seed, i, kind)
        if kind == "measurement":
            cal = draw_tri_calibration(
                _kind_rng(seed, i, "calibration"), scan_id=battery_scan_id(seed, i), night=night
            )
            sim = draw_tri_measurement(
                rng, scan_id=sid, night=night, calibration=cal, effect_free=free, effect_scale=factor
            )
        elif kind == "rod_calibration":
            sim = draw_rod_scan(
                rng, scan_id=sid, night=night, effect_free=free, effect_scale=factor, calibration=True
            )
        else:
            draw = {"calibration": draw_tri_calibration, "static": draw_tri_static, "rod": draw_rod_scan}[
                kind
            ]
            sim = draw(rng, scan_id=sid, night=night, effect_free=free, effect_scale=factor)
        paths.append(write_simulated(sim, raw, truth))
        if progress is not None:
            progress(k, len(jobs), paths[-1])
    index = {
        "generator": "borescan.synthetic.battery.write_battery",
        "seed": int(seed),
        "n": int(n),
        "effect_free": bool(effect_free),
        "kinds": list(kinds),
        "effect_share": effect_share,
        "effect_scale_range": list(effect_scale_range),
        "per_night": int(per_night),
        "scan_ids": [battery_scan_id(seed, i, kind) for kind, i in jobs],
    }
    tmp = out_dir / ".battery.json.tmp"
    tmp.write_text(json.dumps(index, indent=2) + "\n")
    os.replace(tmp, out_dir / "battery.json")
    return paths


def _effect_draw(
    seed: int, index: int, kind: str, effect_free: bool, share: float | None, scale_range: tuple[float, float]
) -> tuple[bool, float]:
    """(effect_free, size factor) of scan ``index`` of ``kind`` (see :func:`write_battery`)."""
    if share is None:
        return effect_free, 1.0
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"effect share must lie in 0..1, got {share}")
    lo, hi = (float(x) for x in scale_range)
    if not 0.0 < lo <= hi:
        raise ValueError(f"effect size factors must satisfy 0 < low <= high, got {scale_range}")
    rng = np.random.default_rng(
        np.random.SeedSequence(int(seed), spawn_key=(int(index), 10 + BATTERY_KINDS[kind][1]))
    )
    free = bool(rng.random() >= share)
    return free, float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
