"""Scans with each optional key of ``raw-scan-format.md`` removed (issue 37, item 1).

One small night of both devices (a three-sensor calibration, verification and part measurement,
a rod gauge calibration, verification and part measurement), then, for every optional key the
spec's ``scan.json`` lists, a copy of each of those scans that has the key, without it. The
spec's required keys (marked * there) are never removed: a scan without one is bad raw data,
set aside at ingest (``tests/bad_inputs.py``).
"""

from __future__ import annotations

import copy
from dataclasses import replace
from pathlib import Path

import numpy as np

from borescan.synthetic import demo, scenes, simulate

NIGHT = "2026-11-20"

#: The optional keys of the spec's scan.json, as paths; a list index ``[]`` means "in every entry".
OPTIONAL_KEYS: tuple[tuple[str, ...], ...] = (
    ("device", "nominal"),
    ("sensors", "[]", "model"),
    ("sensors", "[]", "serial"),
    ("sensors", "[]", "range_mm"),
    ("sensors", "[]", "linearity_fs"),
    ("sensors", "[]", "repeatability_mm"),
    ("spindle",),
    ("spindle", "rpm_nominal"),
    ("spindle", "direction"),
    ("spindle", "position"),
    ("artifact", "nominal_diameter_mm"),
    ("artifact", "certified_diameter_mm"),
    ("artifact", "u_diameter_mm"),
    ("artifact", "k"),
    ("artifact", "certificate"),
    ("artifact", "cte_per_k"),
    ("artifact", "features"),
    ("center",),
    ("rod",),
    ("environment",),
    ("operator",),
    ("acquisition",),
)


def key_name(path: tuple[str, ...]) -> str:
    """``device.nominal``, ``sensors[].model``: a key path as people write it."""
    return ".".join(path).replace(".[]", "[]")


def has_key(meta, path) -> bool:
    node = meta
    for i, k in enumerate(path):
        if k == "[]":
            return isinstance(node, list) and bool(node) and all(has_key(e, path[i + 1 :]) for e in node)
        if not isinstance(node, dict) or k not in node:
            return False
        node = node[k]
    return True


def without(meta: dict, path: tuple[str, ...]) -> dict:
    """Return a deep copy of ``meta`` without the key at ``path`` (in every list entry for ``[]``)."""
    out = copy.deepcopy(meta)

    def drop(node, p):
        if p[0] == "[]":
            for e in node:
                drop(e, p[1:])
        elif len(p) == 1:
            node.pop(p[0], None)
        else:
            drop(node[p[0]], p[1:])

    drop(out, path)
    return out


def base_scans() -> list[simulate.SimulatedScan]:
    """Return the night's complete scans: every optional key present where the scan kind has it."""
    rng = np.random.default_rng(37)
    started = iter(simulate.started_at_plus(NIGHT, 22, 2 * i) for i in range(1000))
    base = scenes.default_tri_scene(temperature_c=20.0, cte_per_k=demo.CTE_STEEL_PER_K)
    out = []
    scene = replace(base, spindle_xy_mm=scenes.YANG_P1_XY_MM)
    out.append(
        simulate.simulate_tri_spindle(
            scene,
            n_rev=6,
            artifact=demo.RG275,
            spindle_label="P1",
            center_xy_mm=tuple(scenes.YANG_P0_XY_MM),
            nominal_beams=demo.NOMINAL_BEAMS,
            scan_id="OPT-TRI-CAL",
            night=NIGHT,
            kind="calibration",
            seed=1,
            started_at=next(started),
        )
    )
    xy = rng.uniform(-1.0, 1.0, (6, 2))
    ang = rng.uniform(-0.5, 0.5, 6)
    gauge = replace(
        base, bore_center_xy_mm=(0.0, 0.0), bore_radius_20_mm=demo.RG275["certified_diameter_mm"] / 2
    )
    out.append(
        simulate.simulate_tri_static(
            gauge,
            xy,
            ang,
            artifact=demo.RG275,
            nominal_beams=demo.NOMINAL_BEAMS,
            scan_id="OPT-TRI-VER",
            night=NIGHT,
            kind="verification",
            seed=2,
            started_at=next(started),
        )
    )
    part = {
        "id": "HSG-37",
        "type": "part",
        "nominal_diameter_mm": 277.0,
        "cte_per_k": demo.CTE_STEEL_PER_K,
        "features": [{"id": "B1", "z_mm": 50.0, "nominal_diameter_mm": 277.0, "tolerance_mm": 0.05}],
    }
    bore = replace(base, bore_center_xy_mm=(0.0, 0.0), bore_radius_20_mm=138.51)
    out.append(
        simulate.simulate_tri_static(
            bore,
            xy,
            ang,
            artifact=part,
            nominal_beams=demo.NOMINAL_BEAMS,
            scan_id="OPT-TRI-MEAS",
            night=NIGHT,
            kind="measurement",
            seed=3,
            started_at=next(started),
        )
    )
    gauge_d = {f["id"]: f["certified_diameter_mm"] for f in demo.RGS150["features"]}
    rod_rng = np.random.default_rng(38)
    for kind, tag, artifact in (("calibration", "CAL", demo.RGS150), ("verification", "VER", demo.RGS150)):
        out.append(
            simulate.simulate_rod(
                demo._rod_scene(rod_rng, 20.0, gauge_d, min_omega_deg=0.12),
                n_poses=24,
                samples_per_pose=5,
                artifact=artifact,
                features=("H1", "H2"),
                device_id="ROD-01",
                nominal_layers=demo.ROD_NOMINAL_LAYERS,
                scan_id=f"OPT-ROD-{tag}",
                night=NIGHT,
                kind=kind,
                seed=4 + len(out),
                started_at=next(started),
            )
        )
    rod_part = {
        "id": "CYL-37",
        "type": "part",
        "nominal_diameter_mm": 150.0,
        "cte_per_k": demo.CTE_STEEL_PER_K,
        "features": [
            {
                "id": f,
                "z_mm": demo.ROD_PART["z_mm"][f],
                "nominal_diameter_mm": 150.0,
                "tolerance_mm": demo.ROD_PART["tolerance_mm"],
            }
            for f in ("H1", "H2")
        ],
    }
    out.append(
        simulate.simulate_rod(
            demo._rod_scene(rod_rng, 20.0),
            n_poses=24,
            samples_per_pose=5,
            artifact=rod_part,
            features=("H1", "H2"),
            device_id="ROD-01",
            nominal_layers=demo.ROD_NOMINAL_LAYERS,
            scan_id="OPT-ROD-MEAS",
            night=NIGHT,
            kind="measurement",
            seed=9,
            started_at=next(started),
        )
    )
    # the example of docs/import-csv.md: too short to calibrate and without device.nominal, on a
    # device with no calibration, then a part measured with that device
    short = simulate.simulate_tri_spindle(
        scene,
        n_rev=3,
        artifact=demo.RG275,
        spindle_label="P1",
        center_xy_mm=tuple(scenes.YANG_P0_XY_MM),
        nominal_beams=demo.NOMINAL_BEAMS,
        scan_id="OPT-SHORT-NO-NOMINAL",
        night=NIGHT,
        kind="calibration",
        seed=10,
        started_at=next(started),
        device_id="TRI-SHORT",
    )
    orphan = simulate.simulate_tri_static(
        bore,
        xy,
        ang,
        artifact=part,
        nominal_beams=demo.NOMINAL_BEAMS,
        scan_id="OPT-UNCALIBRATED-NO-NOMINAL",
        night=NIGHT,
        kind="measurement",
        seed=11,
        started_at=next(started),
        device_id="TRI-SHORT",
    )
    for sim in (short, orphan):
        out.append(replace(sim, meta=without(sim.meta, ("device", "nominal"))))
    return out


def variant_id(scan_id: str, path: tuple[str, ...]) -> str:
    return f"{scan_id}-NO-" + "-".join(p.upper().replace("_", "") for p in path if p != "[]")


def write_night(raw_root: Path, truth_root: Path) -> dict[str, tuple[str, tuple[str, ...] | None]]:
    """Write the base scans and every variant; returns scan_id -> (base scan_id, removed key path or None).

    A calibration scan's variant calibrates a device of its own (``<device>-K<nn>``), so that each
    missing key meets the calibration alone (one device's calibration scans are fitted together);
    the other variants keep the base scan's device, calibrated by the complete calibration scan.
    """
    written = {}
    for sim in base_scans():
        simulate.write_simulated(sim, raw_root, truth_root)
        written[sim.scan_id] = (sim.scan_id, None)
        if not has_key(sim.meta, ("device", "nominal")):
            written[sim.scan_id] = (sim.scan_id, ("device", "nominal"))
            continue  # the import-csv example: itself a scan without a key
        for i, path in enumerate(OPTIONAL_KEYS):
            if not has_key(sim.meta, path):
                continue
            sid = variant_id(sim.scan_id, path)
            meta = dict(without(sim.meta, path), scan_id=sid)
            if meta["kind"] == "calibration":
                meta["device"] = dict(meta["device"], id=f"{meta['device']['id']}-K{i:02d}")
            simulate.write_simulated(replace(sim, meta=meta), raw_root, truth_root)
            written[sid] = (sim.scan_id, path)
    return written
