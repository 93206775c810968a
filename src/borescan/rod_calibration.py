"""Rod calibration: each layer's base length l0 from certified ring gauges (traceable rod diameters).

The rod solve (:func:`borescan.rod.solve_rod`) gives each hole radius from readings l = l0 + v,
so an error in a layer's base length l0 moves that hole's radius by the same amount (exactly for
a centred rod; for an eccentric one dr/dl0 = 1 + O(e^2 / r^2)). Wang 2017 takes l0 from the
design; nothing in the readings of a part can separate it from the radius. A calibration scan
turns the rod in ring gauges of certified diameter, one per layer (a gauge set: the artifact's
``features`` each with ``certified_diameter_mm``; or one ring gauge for every layer: the
artifact's own ``certified_diameter_mm``), and finds the l0 at which the solve returns the
gauges' radii at their temperature:

    l0_m  <-  l0_m + (R_m(T) - r_m(l0)),    R_m(T) = D_m,20 / 2 (1 + alpha (T - 20 degC)),

iterated until the step is below 1e-7 mm or u(r) / 1000 (a fixed point with contraction O(e^2 / r^2); two or
three solves). The other
layer constants (phi, d, gamma, h) stay at their nominal values: l0 absorbs what a beam angle, offset
or tilt does at the calibration hold's eccentricity and deflection; what it does at a later hold's
is that diameter's ``layer_geometry`` input (:mod:`borescan.rod_layer_geometry`).

GUM budget of l0 (outputs l0 of every layer; :class:`borescan.uncertainty.Budget`): the solve's
radius uncertainty (readings; sensitivity -1), the choice between the solve's minima where another
lies within 25 chi2 (:mod:`borescan.rod_minima`, :func:`minima_term`), each gauge's certified
diameter (f / 2; a gauge used by several layers is one input), the gauges' temperature (R20 alpha)
and expansion coefficient (R20 (T - 20)), and each sensor's linearity and resolution in the
calibration (sensitivity -1: l0 takes up a constant reading error, which then reappears,
independently, in a measurement at another point of the range). A rod diameter measured with the
calibration takes the whole budget with sensitivity 2 on its layer's l0
(:func:`borescan.measure.diameter_uncertainty`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .artifacts import (
    ArtifactCte,
    ScanTemperature,
    artifact_cte,
    artifact_key,
    radius_at_temperature_mm,
    scan_temperature,
)
from .effects import REFERENCE_TEMPERATURE_C, thermal_expansion_factor
from .atomic import json_ready
from .calibrate.result import make_calibration_id
from .calibrations import rod_layers, rod_nominal_calibration_rows
from .config import schema_default
from .geometry import RodLayer
from .preconditions import ROD_CALIBRATION_NEEDS_LAYERS, design_layers
from .rod import RodSolution, solve_rod
from .rod_minima import DELTA_CHI2_MAX, minima_radius_cov
from .rod_layer_geometry import (
    LayerGeometryDraws,
    calibration_draws,
    layer_geometry_prior,
)
from .uncertainty import Budget, Input, Term

__all__ = [
    "ROD_CALIBRATION_METHOD",
    "RodCalibration",
    "RodCalibrationHold",
    "RodCalibrationInputError",
    "calibrate_hold",
    "layer_gauges",
    "rod_coaxiality_mm",
    "calibrate_l0",
    "rod_calibration_budget",
    "minima_term",
    "rod_calibration_id",
    "rod_calibration_rows",
    "rod_calibration_from_rows",
    "rod_layer_draws_from_rows",
    "layer_geometry_record",
    "pose_means_of_scan",
]

#: ``calibrations.method`` of a rod calibrated on certified ring gauges
ROD_CALIBRATION_METHOD = "rod_gauge"


@dataclass(frozen=True)
class RodCalibration:
    """A rod's layer geometry with base lengths calibrated on certified gauges.

    layers : calibrated RodLayer per channel (l0 calibrated; phi, d, gamma, h nominal)
    l0_nominal_mm : (m,) the design base lengths the calibration started from
    u_l0_mm : (m,) combined standard uncertainty of l0 (the budget's)
    budget : outputs ``l0_mm[<channel>]``
    gauges : per layer the gauge it was calibrated in (artifact-shaped dict, with ``radius_at_t_mm``)
    solution : the rod solve at the calibrated l0 (radii equal to the gauges' within 1e-9 mm)
    iterations : solves of the fixed point; residual_rms_mm : of that solve
    """

    calibration_id: str
    device_id: str
    scan_ids: tuple[str, ...]
    layers: tuple[RodLayer, ...]
    l0_nominal_mm: np.ndarray
    u_l0_mm: np.ndarray
    budget: Budget
    gauges: tuple[dict, ...]
    solution: RodSolution | None
    iterations: int
    residual_rms_mm: float
    method: str = ROD_CALIBRATION_METHOD
    diagnostics: dict = field(default_factory=dict)

    @property
    def channels(self) -> tuple[int, ...]:
        """The layers' channels."""
        return tuple(int(lay.channel) for lay in self.layers)

    @property
    def l0_mm(self) -> np.ndarray:
        """Base lengths l0 [mm] of the layers."""
        return np.array([lay.l0_mm for lay in self.layers], dtype=float)


def rod_coaxiality_mm(unc_cfg: dict) -> float | None:
    """Return the holes' coaxiality tolerance (``uncertainty.rod_hole_coaxiality_mm``) [mm]."""
    if "rod_hole_coaxiality_mm" in unc_cfg:
        v = unc_cfg["rod_hole_coaxiality_mm"]
    else:
        v = schema_default("uncertainty", "rod_hole_coaxiality_mm")
    return None if v is None else float(v)


def layer_gauges(meta: dict, channels) -> list[dict]:
    """Return the certified gauge each rod layer of a calibration or verification scan turns in.

    A layer names its feature in ``rod.layers``; the artifact's feature of that id with
    ``certified_diameter_mm`` is the layer's gauge (a gauge set; its ``id``, ``certificate``,
    ``u_diameter_mm`` (expanded, with ``k``) and ``cte_per_k`` fall back to the artifact's), else
    the artifact itself when it is a ``ring_gauge`` with ``certified_diameter_mm`` (one gauge for
    every layer). Returns one artifact-shaped dict per channel with ``channel`` and ``feature``.

    Raises
    ------
    ValueError naming the layer when it has no certified diameter.
    """
    art = dict(meta.get("artifact") or {})
    feats = {str(f.get("id")): f for f in art.get("features") or [] if f.get("id") is not None}
    layer_feature = {int(l["channel"]): l.get("feature") for l in (meta.get("rod") or {}).get("layers") or []}
    out = []
    for ch in channels:
        feat = layer_feature.get(int(ch))
        f = feats.get(str(feat)) if feat is not None else None
        if f is not None and f.get("certified_diameter_mm") is not None:
            g = {
                "id": f.get("gauge_id") or (f"{art.get('id')}/{feat}" if art.get("id") else str(feat)),
                "type": "ring_gauge",
                "certified_diameter_mm": float(f["certified_diameter_mm"]),
                "u_diameter_mm": f.get("u_diameter_mm", art.get("u_diameter_mm")),
                "k": f.get("k", art.get("k", 2)),
                "certificate": f.get("certificate", art.get("certificate")),
                "cte_per_k": f.get("cte_per_k", art.get("cte_per_k")),
            }
        elif art.get("type") == "ring_gauge" and art.get("certified_diameter_mm") is not None:
            g = {
                k: art.get(k)
                for k in (
                    "id",
                    "type",
                    "certified_diameter_mm",
                    "u_diameter_mm",
                    "k",
                    "certificate",
                    "cte_per_k",
                )
            }
            g["k"] = g["k"] if g["k"] is not None else 2
        else:
            raise ValueError(
                f"rod layer {int(ch)} (feature {feat!r}) has no certified diameter: a rod calibration "
                "or verification "
                "needs artifact.features[].certified_diameter_mm for the layer's feature, or a "
                "ring_gauge artifact "
                "with certified_diameter_mm"
            )
        if g["u_diameter_mm"] is None:
            raise ValueError(
                f"rod layer {int(ch)}: gauge {g['id']} states no u_diameter_mm (its certificate's U)"
            )
        # the expansion coefficient is the artifact's (artifacts.artifact_cte): one input under its key
        g.update(channel=int(ch), feature=feat, cte_key=artifact_key(art))
        out.append(g)
    return out


def calibrate_l0(
    means_mm,
    layers,
    u_reading_mm,
    radius_at_t_mm,
    *,
    coaxiality_mm: float | None = None,
    tol_mm: float = 1e-7,
    max_iter: int = 10,
) -> tuple[tuple[RodLayer, ...], RodSolution, int]:
    """Return base lengths at which the rod solve returns the gauges' radii (fixed point of the module doc).

    Parameters
    ----------
    means_mm : (n, m) mean reading per pose and layer [mm]
    layers : RodLayer per column (start: the nominal geometry)
    u_reading_mm : standard uncertainty of one mean [mm] (None: from the residuals)
    radius_at_t_mm : (m,) each gauge's radius at the scan's temperature [mm]
    coaxiality_mm : the gauges' coaxiality (``uncertainty.rod_hole_coaxiality_mm``; :func:`rod_coaxiality_mm`)

    Returns
    -------
    (calibrated layers, the solve at them, number of solves)

    Raises
    ------
    borescan.rod.RodSolveError from the solve; ValueError when the iteration does not settle.
    """
    target = np.asarray(radius_at_t_mm, dtype=float)
    lays = tuple(layers)
    for it in range(1, max_iter + 1):
        sol = solve_rod(means_mm, layers=lays, u_reading_mm=u_reading_mm, coaxiality_mm=coaxiality_mm)
        step = target - sol.radius_mm
        # settled when the step is below tol_mm or a thousandth of the radius' own uncertainty (the
        # solve's optimiser tolerance and its deflection average make r(l0) rough at the nm level)
        if np.all(np.abs(step) <= np.maximum(tol_mm, 1e-3 * sol.u_radius_mm)):
            return lays, sol, it
        lays = tuple(replace(lay, l0_mm=float(lay.l0_mm + s)) for lay, s in zip(lays, step))
    raise ValueError(
        f"rod calibration did not settle in {max_iter} solves: radius - gauge "
        f"{np.array2string(step * 1e3, precision=4)} um"
    )


def rod_calibration_budget(
    calibrated_l0_mm,
    solution: RodSolution,
    gauges: list[dict],
    temperature,
    cte,
    sensors: dict,
    scan_id: str,
    default_resolution_mm: float,
) -> Budget:
    """GUM budget of the calibrated base lengths (outputs ``l0_mm[<channel>]``; module doc).

    ``temperature`` (:class:`borescan.artifacts.ScanTemperature`) and ``cte``
    (:class:`borescan.artifacts.ArtifactCte`) of the gauges; ``sensors`` channel -> scan.json entry.
    """
    from .measure import sensor_terms

    chans = [int(g["channel"]) for g in gauges]
    m = len(chans)
    b = Budget(tuple(f"l0_mm[{ch}]" for ch in chans), ("mm",) * m, np.asarray(calibrated_l0_mm, float))
    u_r = np.asarray(solution.u_radius_mm, dtype=float)
    b.add(
        Term(
            Input(
                f"fit:{scan_id}:readings",
                f"rod solve of the readings of {scan_id} (radius of each layer's gauge)",
                "r",
                "mm",
                None,
                float(solution.sigma_mm),
                "normal",
                source="rod.solve_rod covariance; u(x_i): standard uncertainty of one mean reading",
            ),
            cov=np.diag(u_r**2),
            note="l0 = l0 + R(T) - r: sensitivity -1 on each layer's radius",
        )
    )
    if solution.other_minima:  # the solve's choice between minima the readings do not rule out
        b.add(minima_term(solution, f"rod_minima:{scan_id}", f"the rod solve's minimum of {scan_id}"))
    dT = temperature.temperature_c - REFERENCE_TEMPERATURE_C
    f = thermal_expansion_factor(cte.cte_per_k, temperature.temperature_c)
    by_gauge: dict[str, list[int]] = {}
    for j, g in enumerate(gauges):
        by_gauge.setdefault(f"gauge:{artifact_key(g)}:D20", []).append(j)
    for key, js in by_gauge.items():
        g = gauges[js[0]]
        k_cert = float(g.get("k") or 2.0)
        s = np.zeros(m)
        s[js] = 0.5 * f
        b.add(
            Term(
                Input(
                    key,
                    f"certified diameter of ring gauge {g['id']} at 20 degC",
                    "D_g",
                    "mm",
                    float(g["certified_diameter_mm"]),
                    float(g["u_diameter_mm"]) / k_cert,
                    "normal",
                    source=f"certificate {g.get('certificate')}: U = {g['u_diameter_mm']} mm (k = "
                    f"{k_cert:g})",
                ),
                s,
            )
        )
    r20 = np.array([0.5 * float(g["certified_diameter_mm"]) for g in gauges])
    b.add(
        Term(
            temperature.budget_input(f"temperature:{scan_id}", f"temperature of the gauges during {scan_id}"),
            r20 * cte.cte_per_k,
        )
    )
    b.add(
        Term(
            cte.budget_input(
                f"cte:{gauges[0].get('cte_key') or artifact_key(gauges[0])}",
                "expansion coefficient of the gauges",
            ),
            r20 * dT,
        )
    )
    for t in sensor_terms(
        sensors, chans, -np.eye(m), f"rodcal:{scan_id}", None, default_resolution_mm, "calibration"
    ):
        b.add(t)
    return b.merged()


def minima_term(solution: RodSolution, key: str, what: str) -> Term:
    """Return the choice between the solve's minima as one input on the radii (sensitivity +-1).

    Its covariance is :func:`borescan.rod_minima.minima_radius_cov` (the chosen radii reported;
    the others' offsets with their weights), its source lists each minimum's chi^2 and weight.
    """
    cov = minima_radius_cov(solution.radius_mm, solution.other_minima)
    alts = "; ".join(
        f"dchi2 {mk.delta_chi2:.2f}, weight {mk.weight:.3f}, r - r0 "
        + ", ".join(f"{1e3 * d:+.2f}" for d in mk.radius_mm - solution.radius_mm)
        + " um"
        for mk in solution.other_minima
    )
    return Term(
        Input(
            key,
            f"{what}: other minima within {DELTA_CHI2_MAX:g} chi2 (the chosen one reported)",
            "r_k - r_0",
            "mm",
            0.0,
            float(np.sqrt(np.max(np.diag(cov)))),
            "normal",
            source=f"rod solve's starts (borescan.rod_minima): {alts}",
        ),
        cov=cov,
        note="the choice's root mean square error over the minima's weights (mean folded in)",
    )


def rod_calibration_id(device_id: str, scan_ids, night: str) -> str:
    """Return the deterministic id of a rod calibration.

    Deterministic id ``<device>-<YYYYMMDD>-rod_gauge-<8 hex>``
    (:func:`borescan.calibrate.result.make_calibration_id`).
    """
    return make_calibration_id(device_id, scan_ids, ROD_CALIBRATION_METHOD, night)


class RodCalibrationInputError(ValueError):
    """A rod calibration scan lacks what its scan.json must give (design layers, a gauge per layer, T)."""


@dataclass(frozen=True)
class RodCalibrationHold:
    """One ring-gauge hold of a rod calibrated (:func:`calibrate_hold`).

    calibration : the calibration (layers, budget, the solve at them; ``diagnostics`` with the hold's
        readings and its layer-geometry draws, as recorded in ``calibration_json``)
    means_mm : (n, m) mean reading per pose and layer [mm]; u_mean_mm : u of one mean [mm]
    temperature, cte : the gauges' temperature and expansion coefficient
    sensors : channel -> scan.json entry; raw_files : ``<scan>/<file>`` -> SHA-256 of the raw files
    """

    calibration: RodCalibration
    means_mm: np.ndarray
    u_mean_mm: float | None
    temperature: ScanTemperature
    cte: ArtifactCte
    sensors: dict
    raw_files: dict

    def rows(self, night: str, certificate_path: str | None, p: float) -> list[dict]:
        """Return the calibration's ``calibrations`` rows (:func:`rod_calibration_rows`)."""
        from .rawio import combined_sha256

        return rod_calibration_rows(
            self.calibration, night, certificate_path, combined_sha256(self.raw_files), p
        )


def calibrate_hold(
    scan, unc_cfg: dict, start=None, *, night: str | None = None, cleaning=None
) -> RodCalibrationHold:
    """Calibrate a rod's base lengths from one ring-gauge scan (the module doc's step, whole).

    The pose means (:func:`pose_means_of_scan`, spike policy ``cleaning``), each layer's gauge
    (:func:`layer_gauges`) at the scan's temperature (R20 (1 + alpha (T - 20)): the gauges as the
    rod reads them, spec ``thermal_expansion``), the fixed point (:func:`calibrate_l0`) from
    ``start`` (RodLayer per channel; None: the design, ``device.nominal.layers``), its budget
    (:func:`rod_calibration_budget`) and the layer-geometry draws (:func:`layer_geometry_record`, at
    the fixed point's own solve). ``night``: of the calibration id (None: the scan's).

    Raises
    ------
    RodCalibrationInputError: scan.json lacks the design layers, a layer's certified gauge or the
    temperature (MissingTemperature's message); borescan.rod.RodSolveError: the readings give no
    radii (the message says what hold would); ValueError: the fixed point does not settle.
    """
    meta, sid = scan.meta, scan.scan_id
    night = scan.night if night is None else night
    try:
        if start is None:
            design_layers(meta, ROD_CALIBRATION_NEEDS_LAYERS)  # MissingDesignGeometry names what is missing
            nominal = rod_nominal_calibration_rows(meta, night, sid)
        channels, means, u_mean, sensors = pose_means_of_scan(scan, cleaning)
        layers = tuple(rod_layers(nominal, channels) if start is None else start)
        gauges = layer_gauges(meta, channels)
        temp, cte = scan_temperature(meta, unc_cfg), artifact_cte(meta, unc_cfg)
    except ValueError as err:  # MissingTemperature is one
        raise RodCalibrationInputError(str(err)) from err
    radius_t = [
        radius_at_temperature_mm(0.5 * g["certified_diameter_mm"], cte.cte_per_k, temp.temperature_c)
        for g in gauges
    ]
    coax = rod_coaxiality_mm(unc_cfg)
    cal_layers, sol, n_iter = calibrate_l0(means, layers, u_mean, radius_t, coaxiality_mm=coax)
    l0 = [lay.l0_mm for lay in cal_layers]
    res = float(unc_cfg["sensor_resolution_mm"])
    budget = rod_calibration_budget(l0, sol, gauges, temp, cte, sensors, sid, res)
    from .measure import hold_readings

    cal = RodCalibration(
        calibration_id=rod_calibration_id(meta["device"]["id"], [sid], night),
        device_id=meta["device"]["id"],
        scan_ids=(sid,),
        layers=tuple(cal_layers),
        l0_nominal_mm=np.array([lay.l0_mm for lay in layers]),
        u_l0_mm=budget.u(),
        budget=budget,
        gauges=tuple(dict(g, radius_at_t_mm=r) for g, r in zip(gauges, radius_t)),
        solution=sol,
        iterations=n_iter,
        residual_rms_mm=float(sol.residual_rms_mm),
        diagnostics={
            "hold_readings": hold_readings(means),
            "layer_geometry": layer_geometry_record(means, cal_layers, u_mean, unc_cfg, sol),
        },
    )
    raw_files = {f"{sid}/{k}": v for k, v in sorted(scan.sha256.items())}
    return RodCalibrationHold(cal, means, u_mean, temp, cte, sensors, raw_files)


def rod_calibration_rows(
    cal: RodCalibration, night: str, certificate_path: str | None, raw_sha256: str, p: float
) -> list[dict]:
    """Return the ``calibrations`` rows of a rod calibration.

    Return the ``calibrations`` rows of a rod calibration (one per layer; l0 with its standard uncertainty
    u).
    """
    blob = json.dumps(_to_dict(cal), sort_keys=True, allow_nan=False)
    rows = []
    for j, lay in enumerate(cal.layers):
        rows.append(
            {
                "calibration_id": cal.calibration_id,
                "device_id": cal.device_id,
                "device_type": "rod",
                "scan_id": cal.scan_ids[0],
                "channel": int(lay.channel),
                "l0_mm": float(lay.l0_mm),
                "h_mm": float(lay.h_mm),
                "phi_rad": float(lay.phi_rad),
                "d_mm": float(lay.d_mm),
                "gamma_rad": float(lay.gamma_rad),
                "u_l0_mm": float(cal.u_l0_mm[j]),
                "method": cal.method,
                "certificate_path": certificate_path,
                "night": night,
                "valid_from": night,
                "status": "valid",
                "raw_sha256": raw_sha256,
                "residual_rms_mm": float(cal.residual_rms_mm),
                "coverage_probability": float(p),
                "calibration_json": blob,
            }
        )
    return rows


def _to_dict(cal: RodCalibration) -> dict[str, Any]:
    return {
        "calibration_id": cal.calibration_id,
        "device_id": cal.device_id,
        "scan_ids": list(cal.scan_ids),
        "method": cal.method,
        "l0_nominal_mm": [float(x) for x in cal.l0_nominal_mm],
        "u_l0_mm": [float(x) for x in cal.u_l0_mm],
        "budget": json_ready(cal.budget.to_dict()),
        "gauges": [json_ready(g) for g in cal.gauges],
        "iterations": cal.iterations,
        "residual_rms_mm": float(cal.residual_rms_mm),
        "hold_readings": cal.diagnostics.get("hold_readings"),
        "layer_geometry": cal.diagnostics.get("layer_geometry"),
    }


def rod_calibration_from_rows(rows: list[dict]) -> tuple[list[RodLayer], Budget | None, dict | None]:
    """Return the layers, budget and calibration hold's readings of a recorded rod calibration.

    Layers, budget and :func:`hold_readings` of a recorded rod calibration (``calibrations`` rows
    of one id); budget and hold are None for the ``nominal`` record (design geometry, nothing
    calibrated), the hold None for a record made before it was kept.
    """
    rows = sorted(rows, key=lambda r: int(r["channel"]))
    layers = rod_layers(rows, [int(r["channel"]) for r in rows])
    blob = rows[0].get("calibration_json") if rows else None
    if not blob:
        return layers, None, None
    d = json.loads(blob)
    return layers, Budget.from_dict(d["budget"]), d.get("hold_readings")


def layer_geometry_record(
    means_mm, layers, u_reading_mm, unc_cfg: dict, nominal: RodSolution | None = None
) -> dict | None:
    """Return the calibration hold's layer-geometry draws as recorded (None: ``rod_layer_geometry_draws`` 0).

    ``layers``: the calibrated ones, ``nominal`` the solve at them (:func:`calibrate_l0`'s; solved
    here when None; :func:`borescan.rod_layer_geometry.calibration_draws`).
    """
    prior = layer_geometry_prior(unc_cfg)
    if prior.draws < 1:
        return None
    coax = rod_coaxiality_mm(unc_cfg)
    return calibration_draws(means_mm, layers, u_reading_mm, coax, prior, nominal).to_dict()


def rod_layer_draws_from_rows(rows: list[dict]) -> LayerGeometryDraws | None:
    """Return the layer-geometry draws a rod calibration recorded (None: none recorded, or the design)."""
    blob = rows[0].get("calibration_json") if rows else None
    return LayerGeometryDraws.from_dict(json.loads(blob).get("layer_geometry")) if blob else None


def pose_means_of_scan(scan, cleaning=None) -> tuple[list[int], np.ndarray, float | None, dict]:
    """Return the pose means of a rod scan with their uncertainty.

    (channels, mean reading per pose and layer (n, m), u of one mean from the data sheet, sensors)
    of a rod scan (:func:`borescan.measure.pose_means`, :func:`borescan.measure.mean_reading_u_mm`)
    over its readings cleaned by the spike policy ``cleaning`` (:func:`borescan.readings.prepared_matrix`).
    The mean's u is the sensors' repeatability: their linearity is one systematic curve, not a
    scatter, and enters the budgets as such (:func:`borescan.measure.linearity_terms`).
    """
    from . import measure, readings

    mat = readings.prepared_matrix(scan, cleaning)
    _poses, means, counts = measure.pose_means(mat.values_mm, mat.pose)
    sensors = {int(s["channel"]): s for s in scan.meta.get("sensors", [])}
    u_mean = measure.mean_reading_u_mm(measure.reading_u_mm(sensors, mat.channels, linearity=False), counts)
    return [int(c) for c in mat.channels], means, u_mean, sensors
