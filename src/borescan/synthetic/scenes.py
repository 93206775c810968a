"""The twin's scenes: the true geometry of a simulated scan and its noise-free readings.

Forward models: :func:`tri_readings` is :func:`borescan.physics.tri.tri_forward` (the one forward
model of a spindle scan, shared with the discrepancy workflow; composition order in its
module doc) on the scene's true geometry. Static sets and rod scans are
:class:`borescan.physics.tri.TriDevice` and :func:`borescan.physics.rod.rod_forward`. Every fit
calls the same device models inside least squares. The generators that add noise and write
``borescan-raw/1`` scans are in :mod:`borescan.synthetic.simulate`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from borescan.effects import Effect, as_effects, sort_effects
from borescan.geometry import Beams, Bore, Hole, RodAxis, RodLayer, layer_dict
from borescan.kinematics import RPM_TO_RAD_S, profile_angle_rad
from borescan.physics.rod import RodBase, rod_forward
from borescan.physics.tri import TriBase, TriDevice, TriStaticState, device_angle, tri_forward

__all__ = [
    "YANG_RING_GAUGE_DIAMETER_MM",
    "YANG_P0_XY_MM",
    "YANG_P1_XY_MM",
    "YANG_BEAMS",
    "TRI_NOISE_MM",
    "ROD_NOISE_MM",
    "TriScene",
    "RodScene",
    "tri_base",
    "tri_phi",
    "tri_readings",
    "tri_static_readings_with_effects",
    "rod_base",
    "rod_readings_with_effects",
    "default_tri_scene",
    "default_rod_scene",
]


# --------------------------------------------------------------------------- defaults (papers)

#: Yang 2017 §3.1: ring gauge inner diameter [mm].
YANG_RING_GAUGE_DIAMETER_MM = 275.029
#: Yang 2017 §3.1: ring gauge centre P0 in machine coordinates [mm].
YANG_P0_XY_MM = (262.833, -273.182)
#: Yang 2017 §3.1: spindle position P1 during calibration [mm] (oe = 2.3232 mm; the paper prints 2.3222).
YANG_P1_XY_MM = (262.955, -275.502)
#: Beams with r and d_b of Yang 2017 Table 1, about 120 deg apart; in a 60 rpm ccw scan at P1
#: the feature points come in the order 2-1-3 and sensors 1, 2 are "backward", 3 "advanced" (Table 2).
YANG_BEAMS = Beams(
    channels=(1, 2, 3),
    beta_rad=np.array([0.35, 0.35 + math.radians(121.0), 0.35 + math.radians(241.0)]),
    rho_mm=np.array([-5.5484, -2.5295, 1.5262]),
    d_b_mm=np.array([132.6718, 132.8883, 134.1108]),
)
#: Noise sigma of the HG-C1030 readings after the paper's filtering (Yang 2017 §4: the 15 um
#: raw beat falls to 3 um after filtering; repeatability 10 um) [mm].
TRI_NOISE_MM = 0.004
#: Noise sigma of the rod's OD2-P30W04 readings (Wang 2017 §2.2: 0.02 mm over the span,
#: taken as 2 sigma) [mm].
ROD_NOISE_MM = 0.010


# --------------------------------------------------------------------------- scenes


@dataclass(frozen=True)
class TriScene:
    """A three-sensor device turning on a spindle inside a bore (the truth of one scan).

    Attributes
    ----------
    beams : true beam geometry.
    bore_center_xy_mm : bore centre C in machine coordinates [mm].
    bore_radius_20_mm : bore radius R20 at 20 degC [mm].
    spindle_xy_mm : commanded spindle position S0 [mm].
    rpm_nominal : commanded speed [1/min]; phase_rad : device angle at t = 0 [rad];
    rpm_profile : commanded speed profile as knots ((t_s, rpm), ...), linear between knots and
    constant outside them (empty: ``rpm_nominal`` throughout) [s, 1/min];
    direction : ``"ccw"`` or ``"cw"``; sample_rate_hz : LDS sample rate [Hz];
    range_mm : sensor range per channel [mm]; cte_per_k : artifact CTE [1/K];
    temperature_c : artifact temperature written to scan.json [degC] (the radius changes only
    through a ``thermal_expansion`` effect).
    """

    beams: Beams = YANG_BEAMS
    bore_center_xy_mm: tuple[float, float] = YANG_P0_XY_MM
    bore_radius_20_mm: float = YANG_RING_GAUGE_DIAMETER_MM / 2
    spindle_xy_mm: tuple[float, float] = YANG_P1_XY_MM
    rpm_nominal: float = 60.0
    phase_rad: float = 0.0
    direction: str = "ccw"
    sample_rate_hz: float = 660.0
    range_mm: tuple[float, ...] = (10.0, 10.0, 10.0)
    cte_per_k: float = 11.5e-6
    temperature_c: float = 20.0
    rpm_profile: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        if self.rpm_profile:
            t = [float(k[0]) for k in self.rpm_profile]
            if any(b <= a for a, b in zip(t, t[1:])) or any(float(k[1]) < 0 for k in self.rpm_profile):
                raise ValueError("rpm_profile needs strictly increasing times and speeds >= 0")
        if self.direction not in ("ccw", "cw"):
            raise ValueError(f"direction must be 'ccw' or 'cw', got {self.direction!r}")
        if len(self.range_mm) != len(self.beams.channels):
            raise ValueError("range_mm needs one entry per channel")

    @property
    def omega_rad_per_s(self) -> float:
        """Nominal angular speed 2 pi rpm / 60 [rad/s]."""
        return 2.0 * math.pi * self.rpm_nominal / 60.0

    def commanded_angle_rad(self, t_s: np.ndarray) -> np.ndarray:
        """Return the unsigned commanded angle Phi(t) since t = 0 [rad].

        Unsigned commanded angle Phi(t) since t = 0: the integral of the profile
        (:func:`borescan.kinematics.profile_angle_rad`, the function the pipeline reads scans with),
        omega_nominal t without a profile [rad].
        """
        if not self.rpm_profile:
            return self.omega_rad_per_s * np.asarray(t_s, dtype=float)
        kt = np.array([float(k[0]) for k in self.rpm_profile])
        kw = np.array([float(k[1]) for k in self.rpm_profile]) * RPM_TO_RAD_S
        return profile_angle_rad(t_s, kt, kw)

    def commanded_rpm(self, t_s: np.ndarray) -> np.ndarray:
        """Commanded speed at times t (what ``spindle.parquet`` reports in ``rpm``) [1/min]."""
        t = np.asarray(t_s, dtype=float)
        if not self.rpm_profile:
            return np.full(t.shape, float(self.rpm_nominal))
        return np.interp(t, [float(k[0]) for k in self.rpm_profile], [float(k[1]) for k in self.rpm_profile])

    def bore(self) -> Bore:
        """Return the effect-free bore: circle C, R20."""
        return Bore(tuple(map(float, self.bore_center_xy_mm)), float(self.bore_radius_20_mm))

    def to_dict(self) -> dict:
        """Return the scene as JSON-ready data (:meth:`from_dict` reads it back)."""
        return {
            "beams": self.beams.to_nominal(),
            "bore_center_xy_mm": list(map(float, self.bore_center_xy_mm)),
            "bore_radius_20_mm": float(self.bore_radius_20_mm),
            "spindle_xy_mm": list(map(float, self.spindle_xy_mm)),
            "rpm_nominal": self.rpm_nominal,
            "phase_rad": self.phase_rad,
            "direction": self.direction,
            "sample_rate_hz": self.sample_rate_hz,
            "range_mm": list(self.range_mm),
            "cte_per_k": self.cte_per_k,
            "temperature_c": self.temperature_c,
            "rpm_profile": [list(map(float, k)) for k in self.rpm_profile],
        }

    @classmethod
    def from_dict(cls, d: dict) -> "TriScene":
        """Inverse of :meth:`to_dict` (e.g. ``truth["scene"]`` of a tri_lds scan)."""
        return cls(
            beams=Beams.from_nominal(d["beams"]),
            bore_center_xy_mm=tuple(d["bore_center_xy_mm"]),
            bore_radius_20_mm=d["bore_radius_20_mm"],
            spindle_xy_mm=tuple(d["spindle_xy_mm"]),
            rpm_nominal=d["rpm_nominal"],
            phase_rad=d["phase_rad"],
            direction=d["direction"],
            sample_rate_hz=d["sample_rate_hz"],
            range_mm=tuple(d["range_mm"]),
            cte_per_k=d["cte_per_k"],
            temperature_c=d["temperature_c"],
            rpm_profile=tuple(tuple(map(float, k)) for k in d.get("rpm_profile", ())),
        )


@dataclass(frozen=True)
class RodScene:
    """A measuring rod in a part with coaxial holes (the truth of one scan).

    layers : true layer geometry (one per channel); holes : one hole per layer (part frame);
    axis : rod axis pose; range_mm : sensor range per layer [mm]; sample_rate_hz [Hz];
    cte_per_k [1/K]; temperature_c [degC] (as in :class:`TriScene`).
    """

    layers: tuple[RodLayer, ...]
    holes: tuple[Hole, ...]
    axis: RodAxis = RodAxis()
    range_mm: tuple[float, ...] = (8.0, 8.0)
    sample_rate_hz: float = 100.0
    cte_per_k: float = 11.5e-6
    temperature_c: float = 20.0

    def __post_init__(self) -> None:
        if not (len(self.layers) == len(self.holes) == len(self.range_mm)):
            raise ValueError("RodScene needs one hole and one range per layer")

    @property
    def channels(self) -> tuple[int, ...]:
        """The layers' channels."""
        return tuple(int(lay.channel) for lay in self.layers)

    def to_dict(self) -> dict:
        """Return the scene as JSON-ready data."""
        return {
            "layers": [layer_dict(lay) for lay in self.layers],
            "holes": [{"center_xy_mm": list(h.center_xy_mm), "radius_mm": h.radius_mm} for h in self.holes],
            "axis": {
                "dx_mm": self.axis.dx_mm,
                "dy_mm": self.axis.dy_mm,
                "omega_rad": self.axis.omega_rad,
                "omega_az_rad": self.axis.omega_az_rad,
            },
            "range_mm": list(self.range_mm),
            "sample_rate_hz": self.sample_rate_hz,
            "cte_per_k": self.cte_per_k,
            "temperature_c": self.temperature_c,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "RodScene":
        """Inverse of :meth:`to_dict` (e.g. ``truth["scene"]`` of a rod scan)."""
        layers = tuple(
            RodLayer(
                channel=int(x["channel"]),
                h_mm=x["h"],
                l0_mm=x["l0"],
                phi_rad=x["phi"],
                d_mm=x["d"],
                gamma_rad=x["gamma"],
            )
            for x in d["layers"]
        )
        holes = tuple(Hole(tuple(h["center_xy_mm"]), h["radius_mm"]) for h in d["holes"])
        a = d["axis"]
        return cls(
            layers=layers,
            holes=holes,
            axis=RodAxis(a["dx_mm"], a["dy_mm"], a["omega_rad"], a["omega_az_rad"]),
            range_mm=tuple(d["range_mm"]),
            sample_rate_hz=d["sample_rate_hz"],
            cte_per_k=d["cte_per_k"],
            temperature_c=d["temperature_c"],
        )


# --------------------------------------------------------------------------- forward models


def tri_base(scene: TriScene) -> TriBase:
    """Return the scene's true base geometry for :mod:`borescan.physics.tri`.

    Effect-free bore C, R20; turned angle the commanded profile; phase and direction of the scene.
    """
    return TriBase(
        beams=scene.beams,
        bore=scene.bore(),
        spindle_xy_mm=np.asarray(scene.spindle_xy_mm, dtype=float),
        turned_rad=scene.commanded_angle_rad,
        phase_rad=float(scene.phase_rad),
        direction=1.0 if scene.direction == "ccw" else -1.0,
        cte_per_k=float(scene.cte_per_k),
        range_mm=tuple(scene.range_mm),
    )


def tri_phi(scene: TriScene, t_s: np.ndarray, effects: Iterable[Effect] = ()) -> np.ndarray:
    """Device angle phi(t) with the kinematic effects (:func:`borescan.physics.tri.device_angle`).

    phi = phase + sgn x, x = Phi(t) the commanded angle (``scene.commanded_angle_rad``: omega t,
    or the integral of the rpm profile), then x <- x (1 + eps) (``speed_error``) and
    x <- x + a sin(x + phase) (``speed_ripple``); sgn = +1 for ccw, -1 for cw.

    Parameters
    ----------
    t_s : ndarray (...) times [s]

    Returns
    -------
    ndarray (...) [rad]
    """
    st = sort_effects(as_effects(effects), "tri_lds", scene.beams.channels)
    return device_angle(tri_base(scene), np.asarray(t_s, dtype=float), st["kinematics"])


def tri_readings(scene: TriScene, t_s: np.ndarray, effects: Iterable[Effect] = ()) -> np.ndarray:
    """Return noise-free readings of a spindle scan with effects.

    :func:`borescan.physics.tri.tri_forward` on the scene's true geometry (:func:`tri_base`).

    v = s - d_b, s > 0 the root of |S(phi) + Rot(phi)(F + s u) - C| = r_wall, phi = phi(t_c),
    then beam and reading effects.

    Parameters
    ----------
    scene : TriScene
    t_s : ndarray (n,) sample times since scan start [s]
    effects : iterable of :class:`~borescan.effects.Effect`

    Returns
    -------
    ndarray (n, c) readings [mm], channels in ``scene.beams.channels`` order; not clipped to
    the sensor range. Output-stage effects (``quantization``, ``outliers``) act after the noise
    and are left to the generators (:func:`simulate_tri_spindle`).
    """
    return tri_forward(tri_base(scene), t_s, as_effects(effects))


def tri_static_readings_with_effects(
    scene: TriScene,
    device_xy_mm: np.ndarray,
    device_angle_rad: np.ndarray,
    t_s: np.ndarray,
    effects: Iterable[Effect] = (),
) -> np.ndarray:
    """Return noise-free readings of a static device at poses with effects.

    Poses are xy (n, 2) and angle (n,): :meth:`borescan.physics.tri.TriDevice.predict` on the scene's beams
    and bore, one pose a reading.

    Kinematic and spindle effects do not apply (``ValueError``); ``channel_delay`` shifts the time
    that drift and vibration see.

    Returns
    -------
    ndarray (n, c) [mm]
    """
    xy = np.atleast_2d(np.asarray(device_xy_mm, dtype=float))
    state = TriStaticState(xy, np.asarray(device_angle_rad, dtype=float), scene.bore())
    device = TriDevice(scene.beams, float(scene.cte_per_k), tuple(scene.range_mm))
    return device.predict(state, np.arange(xy.shape[0]), t_s, as_effects(effects))


def rod_base(scene: RodScene) -> RodBase:
    """Return the scene's true base geometry for :mod:`borescan.physics.rod`.

    That is the layers, the effect-free holes and the axis.
    """
    return RodBase(
        tuple(scene.layers), tuple(scene.holes), scene.axis, float(scene.cte_per_k), tuple(scene.range_mm)
    )


def rod_readings_with_effects(
    scene: RodScene, alpha_rad: np.ndarray, effects: Iterable[Effect] = (), t_s: np.ndarray | None = None
) -> np.ndarray:
    """Return noise-free rod readings with effects.

    :func:`borescan.physics.rod.rod_forward` on the scene's true geometry (:func:`rod_base`).

    Beam effects change the layer (``beam_offset``: d += d_mm, Wang 2017 Eq. 5; ``beam_tilt``:
    gamma += gamma_rad, Eq. 6), bore effects the holes (``thermal_expansion``), then the exact
    ray-cylinder readings (:func:`borescan.geometry.rod_readings`; Wang Eq. 16 when
    gamma = d = omega = 0) and the reading effects at times ``t_s``.

    Parameters
    ----------
    alpha_rad : ndarray (n,) rod rotation per reading [rad]
    t_s : ndarray (n,) times [s] for ``sensor_drift`` (zeros when omitted)

    Returns
    -------
    ndarray (n, m) [mm]
    """
    return rod_forward(rod_base(scene), alpha_rad, t_s, as_effects(effects))


# --------------------------------------------------------------------------- default scenes


def default_tri_scene(**overrides: Any) -> TriScene:
    """Yang 2017 calibration set-up: RG-275 at P0, spindle at P1, 60 rpm, 660 samples/rev, HG-C1030."""
    return replace(TriScene(), **overrides)


#: Wang 2017 §3.5: 500 mm rod, two 150 mm holes; layers at h = 100 and 400 mm.
def default_rod_scene(**overrides: Any) -> RodScene:
    """Wang 2017 set-up: 500 mm rod, two 150 mm holes at h = 100, 400 mm, OD2-P30W04 (span 8 mm).

    l0 = 71 mm puts the readings mid-span (l = r = 75 mm gives v = 4 mm); d = 0.3 mm and
    gamma = 0.3 deg are within Wang's d_m < 0.5 mm, gamma_m < 0.5 deg; eccentricity 1.2 mm < 2 mm.
    """
    scene = RodScene(
        layers=(
            RodLayer(channel=1, h_mm=100.0, l0_mm=71.0, phi_rad=0.0, d_mm=0.3, gamma_rad=math.radians(0.3)),
            RodLayer(
                channel=2, h_mm=400.0, l0_mm=71.0, phi_rad=0.05, d_mm=-0.2, gamma_rad=math.radians(-0.2)
            ),
        ),
        holes=(Hole((0.0, 0.0), 75.004), Hole((0.02, -0.015), 74.997)),
        axis=RodAxis(dx_mm=1.2, dy_mm=-0.8, omega_rad=math.radians(0.1), omega_az_rad=0.7),
        range_mm=(8.0, 8.0),
        sample_rate_hz=100.0,
    )
    return replace(scene, **overrides)
