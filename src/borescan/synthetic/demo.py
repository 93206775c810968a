"""The embedded demo nights (``borescan simulate demo --out DIR``).

Four nights (2026-11-20, -21, -23, -24), deterministic for a seed, written to ``DIR/raw`` (scans in
``borescan-raw/1``) and ``DIR/truth`` (``<scan_id>.truth.json`` plus ``manifest.json``);
``DIR/.complete`` is written last.

Per night, device TRI-01 (Yang 2017 set-up):

- ``N<date>-TRI01-CEN``: centring scan (kind ``centering``), spindle near the gauge centre, 10 rev;
- ``N<date>-TRI01-CAL-P1-A``/``-B``: calibration at P1 in RG-275 (275.029 mm), 60 rev each;
- ``N<date>-TRI01-VER-RG275``/``-VER-RG280``: static verification of two certified ring gauges;
- ``N<date>-TRI01-MEAS-<part>``: static measurements of three housings (kind ``measurement``);

and the measuring rod ROD-01 (Wang 2017 set-up) on a two-hole part, 24 poses:
``N<date>-ROD01-MEAS-CYL2H``.

The 10 mm range of the HG-C1030 and base lengths near 132.7-134.1 mm limit a static bore to
about 272-282 mm diameter, so the second gauge is 280.0118 mm and the housings are 276-281 mm.
The device's ``nominal`` geometry in scan.json is the design (round numbers); the truth differs
by manufacturing deviations (beta 1 deg on channels 2, 3; rho <= 0.05 mm; d_b <= 0.03 mm).

Night 2 is at 20.6 degC (``thermal_expansion``), its second calibration scan has
``channel_delay`` on channel 2 (1.2 ms), and one housing has 3-lobing (4 um).

**The loop** (nights 3 and 4, :data:`LOOP_NIGHTS`): the delay stays (channel 2's cable was
changed between the two calibration scans of night 2). At one speed a delay is a shift of beta
(omega tau), so no scan of nights 1-2 can estimate it. Night 3 (2026-11-23) calibrates TRI-01
at two speeds (``N20261123-TRI01-CAL-P1-A`` at 60 rpm, ``-B`` at 30 rpm, 1320 samples/rev) and
verifies on RG-275: its pooled examination estimates the delay from the two speeds. The shipped
``config/devices.yaml`` lists ``{effect: channel_delay@2, from: 2026-11-24}`` (a user's decision
after reading that night's report), so night 4 (2026-11-24, the same two speeds, verifications on
RG-275 and RG-280) calibrates with the delay carried at night 3's estimate; the report shows the
calibration's residual fall to the noise floor. The loop nights have no rod and no parts.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from borescan.effects import Effect
from borescan.geometry import Beams, Hole, RodAxis, RodLayer
from borescan.synthetic.scenes import YANG_P0_XY_MM, YANG_P1_XY_MM, RodScene, default_tri_scene
from borescan.synthetic.simulate import (
    SimulatedScan,
    simulate_rod,
    simulate_tri_spindle,
    simulate_tri_static,
    started_at_plus,
    write_simulated,
)

__all__ = ["DEMO_NIGHTS", "LOOP_NIGHTS", "DEMO_SEED", "NOMINAL_BEAMS", "make_demo", "demo_scans"]

#: nights of the loop (see the module docstring): TRI-01 calibrated at two speeds, the delay in every scan
LOOP_NIGHTS = ("2026-11-23", "2026-11-24")
DEMO_NIGHTS = ("2026-11-20", "2026-11-21") + LOOP_NIGHTS
#: the hidden channel delay of TRI-01 from night 2 on [s]
DEMO_DELAY = Effect("channel_delay", {"channel": 2, "tau_s": 0.0012})
DEMO_SEED = 20261120
CTE_STEEL_PER_K = 11.5e-6

#: Design geometry of TRI-01 written to scan.json ``device.nominal`` (truth: ``YANG_BEAMS``).
NOMINAL_BEAMS = Beams(
    channels=(1, 2, 3),
    beta_rad=np.array([0.35, 0.35 + 2 * math.pi / 3, 0.35 + 4 * math.pi / 3]),
    rho_mm=np.array([-5.5, -2.5, 1.5]),
    d_b_mm=np.array([132.7, 132.9, 134.1]),
)

RG275 = {
    "id": "RG-275",
    "type": "ring_gauge",
    "nominal_diameter_mm": 275.029,
    "certified_diameter_mm": 275.029,
    "u_diameter_mm": 0.0015,
    "k": 2,
    "certificate": "RG-275/2026-03",
    "cte_per_k": CTE_STEEL_PER_K,
}
RG280 = {
    "id": "RG-280",
    "type": "ring_gauge",
    "nominal_diameter_mm": 280.0,
    "certified_diameter_mm": 280.0118,
    "u_diameter_mm": 0.0015,
    "k": 2,
    "certificate": "RG-280/2026-05",
    "cte_per_k": CTE_STEEL_PER_K,
}
#: Housings measured per night: (part id, true diameter at 20 degC [mm], nominal [mm], lobing a [mm]).
PARTS = {
    "2026-11-20": [
        ("HSG-1101", 276.4123, 276.4, 0.0),
        ("HSG-1102", 278.9507, 278.95, 0.0),
        ("HSG-1103", 280.6052, 280.6, 0.0),
    ],
    "2026-11-21": [
        ("HSG-1104", 276.3968, 276.4, 0.0),
        ("HSG-1105", 278.9584, 278.95, 0.004),
        ("HSG-1106", 280.5931, 280.6, 0.0),
    ],
}
#: Two-hole part for the rod (Wang 2017: 500 mm rod, two 150 mm holes), true diameters [mm].
ROD_PART = {
    "id": "CYL-2H-0042",
    "d_mm": {"H1": 150.0082, "H2": 149.9941},
    "z_mm": {"H1": 100.0, "H2": 400.0},
    "tolerance_mm": 0.020,
}
#: Drawing tolerance of the housings' bores, +- [mm] (scan.json features[].tolerance_mm): HSG-1101 is
#: made 12.3 um over its nominal, out of tolerance, so the report has a part to flag.
PART_TOLERANCE_MM = 0.010
#: The rod's true layers. Its scan.json gives the design base length 71.0 mm for both: layer 1's is
#: really 12.3 um longer, layer 2's 8.7 um shorter, so only a calibration on ring gauges makes its
#: diameters right (and traceable).
ROD_LAYERS = (
    RodLayer(channel=1, h_mm=100.0, l0_mm=71.0123, phi_rad=0.0, d_mm=0.31, gamma_rad=math.radians(0.27)),
    RodLayer(channel=2, h_mm=400.0, l0_mm=70.9913, phi_rad=0.04, d_mm=-0.22, gamma_rad=math.radians(-0.18)),
)
#: The design layers of ROD-01's scan.json (device.nominal): l0 = 71.0 mm, beams on the axis.
ROD_NOMINAL_LAYERS = tuple(
    replace(lay, l0_mm=71.0, d_mm=0.0, gamma_rad=0.0, phi_rad=0.0) for lay in ROD_LAYERS
)
#: Ring-gauge set for the rod: two certified rings stacked at the layers' heights (features H1, H2).
RGS150 = {
    "id": "RGS-150",
    "type": "ring_gauge",
    "nominal_diameter_mm": 150.0,
    "u_diameter_mm": 0.0012,
    "k": 2,
    "certificate": "RGS-150/2026-02",
    "cte_per_k": CTE_STEEL_PER_K,
    "features": [
        {
            "id": "H1",
            "z_mm": 100.0,
            "nominal_diameter_mm": 150.0,
            "certified_diameter_mm": 150.0021,
            "gauge_id": "RG-150A",
        },
        {
            "id": "H2",
            "z_mm": 400.0,
            "nominal_diameter_mm": 150.0,
            "certified_diameter_mm": 149.9987,
            "gauge_id": "RG-150B",
        },
    ],
}


def _static_poses(rng: np.random.Generator, n: int, r_max_mm: float) -> tuple[np.ndarray, np.ndarray]:
    r = r_max_mm * np.sqrt(rng.uniform(0.0, 1.0, n))
    a = rng.uniform(0.0, 2 * np.pi, n)
    return np.stack([r * np.cos(a), r * np.sin(a)], -1), rng.uniform(0.0, 2 * np.pi, n)


def _part_artifact(part_id: str, d_nom_mm: float) -> dict:
    return {
        "id": part_id,
        "type": "part",
        "nominal_diameter_mm": d_nom_mm,
        "cte_per_k": CTE_STEEL_PER_K,
        "features": [
            {"id": "B1", "z_mm": 0.0, "nominal_diameter_mm": d_nom_mm, "tolerance_mm": PART_TOLERANCE_MM}
        ],
    }


def _rod_scene(
    rng: np.random.Generator, temp_c: float, d: dict | None = None, min_omega_deg: float = 0.0
) -> RodScene:
    """Return the rod in the two holes ``d``.

    Return the rod in the two holes ``d`` (feature -> true diameter at 20 degC; default the part's). A
    gauge calibration holds the rod visibly skew to the holes (``min_omega_deg``): with the rod
    parallel to them the offsets of the layers are collinear and the radii undetermined (rod.py).
    """
    d = d or ROD_PART["d_mm"]
    axis = RodAxis(
        dx_mm=float(rng.uniform(-1.5, 1.5)),
        dy_mm=float(rng.uniform(-1.5, 1.5)),
        omega_rad=math.radians(float(rng.uniform(min_omega_deg, 0.2))),
        omega_az_rad=float(rng.uniform(0.0, 2 * np.pi)),
    )
    holes = (Hole((0.0, 0.0), d["H1"] / 2), Hole((0.012, -0.021), d["H2"] / 2))
    return RodScene(
        layers=ROD_LAYERS,
        holes=holes,
        axis=axis,
        range_mm=(8.0, 8.0),
        sample_rate_hz=100.0,
        cte_per_k=CTE_STEEL_PER_K,
        temperature_c=temp_c,
    )


def demo_scans(seed: int = DEMO_SEED) -> list[SimulatedScan]:
    """All demo scans, in writing order (deterministic for ``seed``)."""
    rng = np.random.default_rng(seed)
    scans: list[SimulatedScan] = []
    gauge_center = tuple(YANG_P0_XY_MM)
    for i_night, night in enumerate(DEMO_NIGHTS):
        if night in LOOP_NIGHTS:
            scans += _loop_night(seed, i_night, night)
            continue
        tag = "N" + night.replace("-", "")
        temp_c = 20.0 if i_night == 0 else 20.6
        thermal = [] if temp_c == 20.0 else [Effect("thermal_expansion", {"temperature_c": temp_c})]
        slot = iter(range(100))

        def kw(name: str, kind: str, tag: str = tag, night: str = night, slot=slot) -> dict:
            """One scan's id, night, kind, seed and start (the night's values bound here)."""
            return {
                "scan_id": f"{tag}-{name}",
                "night": night,
                "kind": kind,
                "seed": int(rng.integers(2**31)),
                "started_at": started_at_plus(night, 22, 6 * next(slot)),
            }

        base = default_tri_scene(temperature_c=temp_c, cte_per_k=CTE_STEEL_PER_K)
        # centring: the commanded spindle position "P0" is a few um off the true gauge centre
        p0_cmd = tuple(float(x) for x in np.round(np.asarray(gauge_center) + rng.normal(0.0, 0.003, 2), 3))
        scene = replace(base, spindle_xy_mm=p0_cmd, phase_rad=float(rng.uniform(0, 2 * np.pi)))
        scans.append(
            simulate_tri_spindle(
                scene,
                n_rev=10,
                effects=thermal,
                artifact=RG275,
                spindle_label="P0",
                nominal_beams=NOMINAL_BEAMS,
                **kw("TRI01-CEN", "centering"),
            )
        )
        for label in ("A", "B"):
            effects = list(thermal)
            if i_night == 1 and label == "B":
                effects.append(DEMO_DELAY)
            scene = replace(base, spindle_xy_mm=YANG_P1_XY_MM, phase_rad=float(rng.uniform(0, 2 * np.pi)))
            scans.append(
                simulate_tri_spindle(
                    scene,
                    n_rev=60,
                    effects=effects,
                    artifact=RG275,
                    spindle_label="P1",
                    center_xy_mm=gauge_center,
                    nominal_beams=NOMINAL_BEAMS,
                    **kw(f"TRI01-CAL-P1-{label}", "calibration"),
                )
            )
        for gauge in (RG275, RG280):
            scene = replace(
                base, bore_center_xy_mm=(0.0, 0.0), bore_radius_20_mm=gauge["certified_diameter_mm"] / 2
            )
            xy, ang = _static_poses(rng, 10, 1.5)
            name = f"TRI01-VER-{gauge['id'].replace('-', '')}"
            scans.append(
                simulate_tri_static(
                    scene,
                    xy,
                    ang,
                    effects=thermal,
                    artifact=gauge,
                    nominal_beams=NOMINAL_BEAMS,
                    **kw(name, "verification"),
                )
            )
        for part_id, d_true, d_nom, lobe in PARTS[night]:
            scene = replace(base, bore_center_xy_mm=(0.0, 0.0), bore_radius_20_mm=d_true / 2)
            effects = list(thermal)
            if lobe:
                effects.append(Effect("bore_lobing", {"k": 3, "a_mm": lobe, "phase": 0.4}))
            xy, ang = _static_poses(rng, 5, 1.0)
            name = f"TRI01-MEAS-{part_id.replace('-', '')}"
            scans.append(
                simulate_tri_static(
                    scene,
                    xy,
                    ang,
                    effects=effects,
                    artifact=_part_artifact(part_id, d_nom),
                    nominal_beams=NOMINAL_BEAMS,
                    **kw(name, "measurement"),
                )
            )
        # measuring rod on the two-hole part
        artifact = {
            "id": ROD_PART["id"],
            "type": "part",
            "nominal_diameter_mm": 150.0,
            "cte_per_k": CTE_STEEL_PER_K,
            "features": [
                {
                    "id": f,
                    "z_mm": ROD_PART["z_mm"][f],
                    "nominal_diameter_mm": 150.0,
                    "tolerance_mm": ROD_PART["tolerance_mm"],
                }
                for f in ("H1", "H2")
            ],
        }
        scans.append(
            simulate_rod(
                _rod_scene(rng, temp_c),
                n_poses=24,
                samples_per_pose=5,
                effects=thermal,
                artifact=artifact,
                features=("H1", "H2"),
                device_id="ROD-01",
                nominal_layers=ROD_NOMINAL_LAYERS,
                **kw("ROD01-MEAS-CYL2H", "measurement"),
            )
        )
        # the rod in its ring-gauge set: calibrated on the first night, verified on each (drawn from
        # their own generator so that the scans above stay as they were)
        rod_rng = np.random.default_rng([seed, i_night, 150])
        gauge_d = {f["id"]: f["certified_diameter_mm"] for f in RGS150["features"]}
        rod_kinds = (
            (("CAL", "calibration"), ("VER", "verification")) if i_night == 0 else (("VER", "verification"),)
        )
        for tag_kind, kind in rod_kinds:
            scans.append(
                simulate_rod(
                    _rod_scene(rod_rng, temp_c, gauge_d, min_omega_deg=0.12),
                    n_poses=24,
                    samples_per_pose=5,
                    effects=thermal,
                    artifact=RGS150,
                    features=("H1", "H2"),
                    device_id="ROD-01",
                    nominal_layers=ROD_NOMINAL_LAYERS,
                    scan_id=f"{tag}-ROD01-{tag_kind}-RGS150",
                    night=night,
                    kind=kind,
                    seed=int(rod_rng.integers(2**31)),
                    started_at=started_at_plus(night, 22, 6 * next(slot)),
                )
            )
    return scans


def _loop_night(seed: int, i_night: int, night: str) -> list[SimulatedScan]:
    """Return a loop night of TRI-01 (module docstring).

    Return a loop night of TRI-01 (module docstring): calibration in RG-275 at 60 and 30 rpm with the
    delay, then static verifications (RG-275; RG-280 too on the last night). Its own generator,
    so the nights before stay as they were.
    """
    rng = np.random.default_rng([seed, i_night, 300])
    tag = "N" + night.replace("-", "")
    slot = iter(range(100))

    def kw(name: str, kind: str) -> dict:
        return {
            "scan_id": f"{tag}-{name}",
            "night": night,
            "kind": kind,
            "seed": int(rng.integers(2**31)),
            "started_at": started_at_plus(night, 22, 6 * next(slot)),
            "nominal_beams": NOMINAL_BEAMS,
        }

    base = default_tri_scene(temperature_c=20.0, cte_per_k=CTE_STEEL_PER_K)
    scans = []
    for label, rpm, n_rev in (("A", 60.0, 30.0), ("B", 30.0, 15.0)):
        scene = replace(
            base, spindle_xy_mm=YANG_P1_XY_MM, rpm_nominal=rpm, phase_rad=float(rng.uniform(0, 2 * np.pi))
        )
        scans.append(
            simulate_tri_spindle(
                scene,
                n_rev=n_rev,
                effects=[DEMO_DELAY],
                artifact=RG275,
                spindle_label="P1",
                center_xy_mm=tuple(YANG_P0_XY_MM),
                **kw(f"TRI01-CAL-P1-{label}", "calibration"),
            )
        )
    for gauge in (RG275, RG280) if night == LOOP_NIGHTS[-1] else (RG275,):
        scene = replace(
            base, bore_center_xy_mm=(0.0, 0.0), bore_radius_20_mm=gauge["certified_diameter_mm"] / 2
        )
        xy, ang = _static_poses(rng, 10, 1.5)
        scans.append(
            simulate_tri_static(
                scene,
                xy,
                ang,
                effects=[DEMO_DELAY],
                artifact=gauge,
                **kw(f"TRI01-VER-{gauge['id'].replace('-', '')}", "verification"),
            )
        )
    return scans


def make_demo(out_dir: Path | str, seed: int = DEMO_SEED) -> list[Path]:
    """Write the demo nights under ``out_dir`` (``raw/``, ``truth/``, then ``.complete``).

    Returns
    -------
    list of Path: the scan folders written.
    """
    out = Path(out_dir)
    raw, truth = out / "raw", out / "truth"
    paths = []
    manifest = []
    for sim in demo_scans(seed):
        paths.append(write_simulated(sim, raw, truth))
        manifest.append(
            {
                "scan_id": sim.scan_id,
                "night": sim.meta["night"],
                "kind": sim.meta["kind"],
                "device_id": sim.meta["device"]["id"],
                "artifact_id": sim.meta["artifact"]["id"],
                "effects": sim.truth["effects"],
            }
        )
    (truth / "manifest.json").write_text(json.dumps({"seed": seed, "scans": manifest}, indent=2) + "\n")
    tmp = out / ".complete.tmp"
    tmp.write_text(json.dumps({"seed": seed, "n_scans": len(paths)}) + "\n")
    os.replace(tmp, out / ".complete")
    return paths
