"""Rod scans drawn over the contract (:data:`borescan.synthetic.contract.ROD_CONTRACT`, module doc there)."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace

import numpy as np

from borescan.geometry import Hole, RodAxis, RodLayer
from borescan.synthetic import simulate
from borescan.synthetic.contract import ROD_CONTRACT, artifact_of
from borescan.synthetic.scenes import RodScene

__all__ = ["RodDraw", "draw_rod_geometry", "draw_rod_scan"]


@dataclass(frozen=True)
class RodDraw:
    """A rod geometry drawn over the contract, with its poses and readings per pose."""

    layers: tuple[RodLayer, ...]
    holes: tuple[Hole, ...]
    axis: RodAxis
    alpha_rad: np.ndarray  # (n_poses,) pose angles [rad]
    samples_per_pose: int
    noise_mm: float

    @property
    def n_poses(self) -> int:
        """Number of poses."""
        return int(self.alpha_rad.size)

    @property
    def n_holes(self) -> int:
        """Number of holes (= layers)."""
        return len(self.holes)


def draw_rod_geometry(rng: np.random.Generator, contract: dict = ROD_CONTRACT) -> RodDraw:
    """Return a rod geometry drawn over the contract.

    Rod geometry over the contract: 2-3 coaxial holes of radius 50-100 mm 100-300 mm apart,
    layer geometry (l0, phi, d, gamma) of a real rod, eccentricity up to 2.5 mm and deflection up
    to 1 deg, 8-40 poses at random angles, 5-30 readings per pose, noise 2-20 um.

    Returns
    -------
    RodDraw
    """
    m = int(rng.integers(contract["n_holes"][0], contract["n_holes"][1] + 1))
    r = rng.uniform(*contract["hole_radius_mm"], m)
    h = rng.uniform(50.0, 150.0) + np.concatenate([[0.0], np.cumsum(rng.uniform(100.0, 300.0, m - 1))])
    layers = [
        RodLayer(
            j + 1,
            float(h[j]),
            float(r[j] - 4.0),
            phi_rad=float(rng.uniform(-0.1, 0.1)),
            d_mm=float(rng.uniform(-0.5, 0.5)),
            gamma_rad=float(np.deg2rad(rng.uniform(-0.5, 0.5))),
        )
        for j in range(m)
    ]
    off = rng.uniform(-0.05, 0.05, (m, 2))
    holes = [Hole((float(off[j, 0]), float(off[j, 1])), float(r[j])) for j in range(m)]
    e, te = contract["eccentricity_mm"] * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
    axis = RodAxis(
        float(e * np.cos(te)),
        float(e * np.sin(te)),
        float(np.deg2rad(rng.uniform(0.0, contract["deflection_deg"]))),
        float(rng.uniform(0, 2 * np.pi)),
    )
    n = int(rng.integers(contract["n_poses"][0], contract["n_poses"][1] + 1))
    k = int(rng.integers(contract["samples_per_pose"][0], contract["samples_per_pose"][1] + 1))
    sig = float(rng.uniform(*contract["noise_mm"]))
    alpha = rng.uniform(0, 2 * np.pi, n)
    return RodDraw(tuple(layers), tuple(holes), axis, alpha, k, sig)


def draw_rod_scan(
    rng: np.random.Generator,
    *,
    scan_id: str,
    night: str,
    effect_free: bool = True,
    contract: dict = ROD_CONTRACT,
    effect_scale: float = 1.0,
    extra_effects: tuple = (),
    calibration: bool = False,
):
    """Return a rod scan drawn over the contract.

    The geometry is :func:`draw_rod_geometry`'s, in a ring-gauge set with certified diameters (half of the
    scans: what a rod is verified on) or in a part with nominal ones. Each layer's sensor (range 30 mm) sits
    mid-range so that eccentricity and deflection stay inside it.

    ``calibration``: a rod calibration scan instead (kind ``calibration``, always in a ring-gauge
    set; the same draws otherwise).

    Returns
    -------
    borescan.synthetic.simulate.SimulatedScan
        ``truth["contract"]`` holds the draw.
    """
    g = draw_rod_geometry(rng, contract)
    layers = [
        replace(lay, l0_mm=float(hh.radius_mm - contract["range_mm"] / 2))
        for lay, hh in zip(g.layers, g.holes)
    ]
    kind = "ring_gauge" if rng.random() < contract["p_ring_gauge"] or calibration else "part"
    art = artifact_of(
        kind,
        f"{'RGS' if kind == 'ring_gauge' else 'CYL'}-{scan_id}"[:40],
        [2 * hh.radius_mm for hh in g.holes],
        [lay.h_mm for lay in layers],
        11.5e-6,
    )
    scene = RodScene(
        layers=tuple(layers),
        holes=g.holes,
        axis=g.axis,
        range_mm=(contract["range_mm"],) * g.n_holes,
    )
    effects = []
    if not effect_free:
        from borescan.discrepancy.battery import random_effect, scale_effect

        name = str(
            rng.choice(
                (
                    "sensor_offset",
                    "sensor_gain",
                    "sensor_nonlinearity",
                    "sensor_drift",
                    "quantization",
                    "outliers",
                    "thermal_expansion",
                    "beam_tilt",
                )
            )
        )
        effects = [
            scale_effect(random_effect(name, rng, scene.channels, 0.1, scene.sample_rate_hz), effect_scale)
        ]
    effects = [*effects, *extra_effects]  # a second effect, drawn and sized by the caller
    sim = simulate.simulate_rod(
        scene,
        g.alpha_rad,
        samples_per_pose=g.samples_per_pose,
        noise_mm=g.noise_mm,
        seed=int(rng.integers(0, 2**31 - 1)),
        artifact=art,
        nominal_layers=layers,
        effects=effects,
        scan_id=scan_id,
        night=night,
        device_id=f"ROD-{scan_id}"[:64],
        kind="calibration" if calibration else "verification" if kind == "ring_gauge" else "measurement",
    )
    meta = json.loads(json.dumps(sim.meta))
    for sensor in meta.get("sensors", []):  # the data sheet states the repeatability the scan has
        sensor["repeatability_mm"] = g.noise_mm
    truth = dict(sim.truth)
    truth["contract"] = {
        "generator": "borescan.synthetic.rod_scenarios.draw_rod_scan",
        "effect_free": not effects,
        "artifact": kind,
        "diameters_mm": [2 * hh.radius_mm for hh in g.holes],
        "n_poses": g.n_poses,
        "samples_per_pose": g.samples_per_pose,
        "noise_mm": g.noise_mm,
        "eccentricity_mm": float(np.hypot(g.axis.dx_mm, g.axis.dy_mm)),
        "deflection_rad": g.axis.omega_rad,
    }
    return replace(sim, meta=meta, truth=truth)
