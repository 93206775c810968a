"""What a scan is compared with in the model-discrepancy examination: a calibration, else the design."""

from __future__ import annotations

import polars as pl

from borescan.calibrations import rod_layers, tri_calibration
from borescan.device_model import carried_effects, from_dicts
from borescan.geometry import layer_dict

__all__ = ["discrepancy_reference", "reference_calibration"]


def discrepancy_reference(
    calibrations: pl.DataFrame, device_id: str, device_type: str, night: str
) -> tuple[dict, str]:
    """Return the keywords that fix the reference, and its description.

    Return the keywords of :func:`borescan.discrepancy.analyse_scan` that fix the reference, and its
    description.

    A three-sensor device's design geometry (``device.nominal``) is off the real device by
    degrees and tens of um; compared with it, every scan would "miss" offsets and gains that are
    the calibration's business. So a calibrated device is examined against its latest
    calibration made on or before the night (ties broken by calibration id; the scan's own
    calibration for calibration scans; ``nominal`` records excluded) -> ``{"beams": ...}`` (and
    ``"device_effects"``: the effects of the device model that calibration carried, fitted with
    the base of a spindle scan), and a
    device without one against ``device.nominal`` with its whole beam geometry freed (the design
    is off by mm in rho as well) -> ``{"free_beams": ("d_b", "beta", "rho")}``: the examination
    then asks what a calibration of this scan could not absorb. A rod is examined against its
    latest calibration on certified ring gauges -> ``{"layers": ...}`` (its layers as
    :func:`borescan.calibrations.rod_layers` reads them for a measurement, in the ``device.nominal``
    format of :func:`borescan.geometry.layer_dict`: l0, h, d [mm], phi, gamma [rad]), else against
    ``device.nominal`` -> ``{}``.
    Unlike a measurement, the examination uses expired or failed calibrations too: it asks what
    the model misses, not whether a result may be certified.
    """
    if device_type == "tri_lds" and calibrations.height and "device_id" in calibrations.columns:
        cal = reference_calibration(calibrations, device_id, device_type, night)
        if cal is not None:
            cal_id = cal.calibration_id
            carried = carried_effects(from_dicts((cal.diagnostics or {}).get("device_model")))
            if carried:
                return (
                    {"beams": cal.beams, "device_effects": carried},
                    f"calibration {cal_id} with its device model ({', '.join(str(e) for e in carried)})",
                )
            return {"beams": cal.beams}, f"calibration {cal_id}"
    if device_type == "tri_lds":
        return {"free_beams": ("d_b", "beta", "rho")}, "device.nominal (beam geometry free)"
    if device_type == "rod" and calibrations.height and {"device_id", "l0_mm"} <= set(calibrations.columns):
        c = calibrations.filter(
            (pl.col("device_id") == device_id)
            & (pl.col("valid_from") <= night)
            & (pl.col("method") != "nominal")
            & pl.col("l0_mm").is_not_null()
        )
        if c.height:
            cal_id = c.sort("valid_from", "calibration_id")["calibration_id"][-1]
            rows = c.filter(pl.col("calibration_id") == cal_id)
            channels = sorted(int(ch) for ch in rows["channel"])
            return {
                "layers": [layer_dict(lay) for lay in rod_layers(rows, channels)]
            }, f"calibration {cal_id}"
    return {}, "device.nominal"


def reference_calibration(calibrations: pl.DataFrame, device_id: str, device_type: str, night: str):
    """Return the three-sensor calibration :func:`discrepancy_reference` examines the device's scans against.

    The latest calibration made on or before the night (ties broken by calibration id; ``nominal`` records
    excluded), a :class:`~borescan.calibrate.result.TriCalibration` (its ``scan_ids`` are the scans it was
    made from); None for a rod or a device without one.
    """
    if device_type != "tri_lds" or not calibrations.height or "device_id" not in calibrations.columns:
        return None
    c = calibrations.filter(
        (pl.col("device_id") == device_id) & (pl.col("valid_from") <= night) & (pl.col("method") != "nominal")
    )
    if not c.height:
        return None
    return tri_calibration(calibrations, c.sort("valid_from", "calibration_id")["calibration_id"][-1])
