"""The calibrate stage's typed records: its jobs, what a job reads, what it makes.

:class:`CalibrationJob` (with its :class:`CalibrationSettings`) crosses to a worker process and
:class:`CalibrationJobResult` back (:func:`borescan.stages.calibrate.calibrate_device`); a
three-sensor device's job is a :class:`TriDeviceJob`
(:func:`borescan.stages.calibrate_tri.calibrate_tri_device`) whose scans' fit inputs are
:class:`SpindleInputs` (:func:`borescan.stages.calibration_fit.spindle_inputs`); every job returns
a :class:`CalibrationOutcome`. No context dicts, no out-parameter lists.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from borescan import device_model, rawio, readings
from borescan.artifacts import ArtifactCte, ScanTemperature
from borescan.device_model import DeviceEffect
from borescan.effects import device_model_effects
from borescan.geometry import Beams
from borescan.kinematics import AngleModel
from borescan.readings import CleaningPolicy
from borescan.stages.quarantine import Quarantined, write_quarantine_record

__all__ = [
    "SpindleInputs",
    "TriCalibrationContext",
    "TriDeviceJob",
    "CalibrationOutcome",
    "UsableScans",
    "FitBlame",
    "CalibrationSettings",
    "CalibrationJob",
    "CalibrationJobResult",
]


@dataclass(frozen=True)
class SpindleInputs:
    """The fit inputs of one spindle scan (:func:`spindle_inputs`).

    Attributes
    ----------
    t_s : (n,) sample times [s]; readings_mm : (n, c) despiked readings (corrected for the device
        model's beam and reading effects when one is carried, :func:`borescan.device_model.correct_inputs`).
    readings_recorded_mm : the readings before that correction, None when not corrected.
    channels : the channels of the columns; range_mm : (c,) sensor ranges; sensors : scan.json's per channel.
    spindle_xy_mm : the reported spindle position S; center_xy_mm : the reported gauge centre C, or None.
    rpm : mean speed [rev/min]; direction : ``ccw`` or ``cw``; angle_model : where the angle comes from.
    radius_mm : the gauge's radius at the scan's temperature; temperature, cte : how they were taken.
    artifact : scan.json's ``artifact``.
    """

    t_s: np.ndarray
    readings_mm: np.ndarray
    channels: tuple[int, ...]
    spindle_xy_mm: tuple[float, float]
    center_xy_mm: tuple[float, float] | None
    rpm: float
    direction: str
    angle_model: AngleModel
    range_mm: np.ndarray
    radius_mm: float
    temperature: ScanTemperature
    cte: ArtifactCte
    artifact: dict
    sensors: dict
    readings_recorded_mm: np.ndarray | None = None


@dataclass(frozen=True)
class TriCalibrationContext:
    """What a calibration job reads besides its scans.

    Attributes
    ----------
    uncertainty, laboratory, verification : the config's sections of those names.
    raw_root : the raw data's root; scans_table : the night's ``scans`` table (path or frame).
    cleaning : the readings' spike policy (:func:`borescan.readings.cleaning_policy`).
    device_model : (device id, channels) -> the device model a calibration carries
        (:func:`borescan.device_model.lookup`).
    """

    uncertainty: dict
    laboratory: dict
    verification: dict
    raw_root: Path
    scans_table: Path | pl.DataFrame
    cleaning: CleaningPolicy
    device_model: Callable[[str, Sequence[int]], list[DeviceEffect]]


@dataclass(frozen=True)
class RodCalibrationContext:
    """What a rod calibration job reads besides its scan.

    Attributes
    ----------
    uncertainty, laboratory, verification : the config's sections of those names.
    scans_table : the night's ``scans`` table (the night's verification scans are found in it).
    cleaning : the readings' spike policy (:func:`borescan.readings.cleaning_policy`); None: none.
    """

    uncertainty: dict
    laboratory: dict
    verification: dict
    scans_table: Path | pl.DataFrame
    cleaning: CleaningPolicy | None = None


@dataclass(frozen=True)
class TriDeviceJob:
    """One three-sensor device's calibration job of a night.

    Attributes
    ----------
    items : the device's calibration scans, (scans row, raw folder) each.
    night : the night; results_root : where certificates and quarantine records go.
    summary : the signal stage's per-channel summary of the night.
    cfg : the config's ``calibration`` section; ctx : :class:`TriCalibrationContext`.
    log : where the job's log lines go.
    """

    items: tuple[tuple[dict, Path], ...]
    night: str
    results_root: Path
    summary: pl.DataFrame
    cfg: dict
    ctx: TriCalibrationContext
    log: Callable[[str], None]

    def config_sections(self) -> dict:
        """Return the config sections a certificate's config hash covers."""
        c = self.ctx
        return {
            "calibration": self.cfg,
            "uncertainty": c.uncertainty,
            "laboratory": c.laboratory,
            "verification": c.verification,
        }

    def set_aside(self, scan_id: str, file: str, reason: str) -> Quarantined:
        """Quarantine a scan of the job (write its record) and return the record."""
        q = Quarantined(scan_id, self.night, "calibrate", file, reason)
        write_quarantine_record(self.results_root, q)
        return q


@dataclass(frozen=True)
class CalibrationOutcome:
    """What a calibration job made: table rows, scans set aside, certificates issued.

    Attributes
    ----------
    calibration_rows : rows of the ``calibrations`` table.
    calibration_scan_rows : rows of ``calibration_scans`` (calibration id, scan id).
    quarantined : the scans set aside, each with its reason.
    certificate_rows : ``stage/certificate_issues`` rows (:func:`borescan.certificate_issue.issue_row`).
    """

    calibration_rows: tuple[dict, ...] = ()
    calibration_scan_rows: tuple[dict, ...] = ()
    quarantined: tuple[Quarantined, ...] = ()
    certificate_rows: tuple[dict, ...] = ()

    def __add__(self, other: "CalibrationOutcome") -> "CalibrationOutcome":
        """Return both outcomes, this one's rows first."""
        return CalibrationOutcome(
            self.calibration_rows + other.calibration_rows,
            self.calibration_scan_rows + other.calibration_scan_rows,
            self.quarantined + other.quarantined,
            self.certificate_rows + other.certificate_rows,
        )


@dataclass(frozen=True)
class UsableScans:
    """A device's calibration scans of the night that a fit can use, and what was set aside.

    scans, inputs : the usable scans and their fit inputs (:func:`spindle_inputs`); nominal : the design
    geometry of the first (the start of the fit); lost : each scan set aside before the fit with its
    reason (a failed fit's record names them); quarantined : the records this stage wrote.
    """

    scans: tuple[rawio.RawScan, ...]
    inputs: tuple[SpindleInputs, ...]
    nominal: Beams | None
    lost: tuple[str, ...]
    quarantined: tuple[Quarantined, ...]


@dataclass(frozen=True)
class FitBlame:
    """What a failed fit did to its scans: the records written, the scans still usable, the ones lost."""

    quarantined: tuple[Quarantined, ...]
    kept: tuple[int, ...]
    lost: tuple[str, ...]


@dataclass(frozen=True)
class CalibrationSettings:
    """What every calibration job of a night reads besides its scans (picklable: jobs run in processes).

    Attributes
    ----------
    uncertainty, laboratory, verification, signal : the config's sections of those names.
    raw_root : the raw data's root; scans_table : the night's ``scans`` table (path or frame).
    devices : the config's ``devices`` section (the device models users decided), or None.
    night : the night; pooled_rows : earlier nights' pooled findings (a device model's values).
    auto_nights : ``discrepancy.device_model_auto_nights``.
    """

    uncertainty: dict
    laboratory: dict
    verification: dict
    signal: dict
    raw_root: Path
    scans_table: Path | pl.DataFrame
    devices: dict | None
    night: str
    pooled_rows: tuple[dict, ...]
    auto_nights: int

    def context(self) -> TriCalibrationContext:
        """Return a job's context: these sections, the readings' cleaning policy, the device model lookup."""
        devices, night = self.devices, self.night
        return TriCalibrationContext(
            uncertainty=self.uncertainty,
            laboratory=self.laboratory,
            verification=self.verification,
            raw_root=Path(self.raw_root),
            scans_table=self.scans_table,
            cleaning=readings.cleaning_policy(self.signal),
            device_model=device_model.lookup(
                lambda dev: device_model_effects(devices, dev, night),
                self.pooled_rows,
                night,
                self.auto_nights,
            ),
        )


@dataclass(frozen=True)
class CalibrationJob:
    """One job of :func:`stage_calibrate`: a three-sensor device's calibration scans or one rod's scan.

    Attributes
    ----------
    kind : ``"tri"`` or ``"rod"``; items : (scans row, raw folder) of each scan (one for a rod).
    results_root : where certificates and quarantine records go; summary : the signal stage's summary.
    cfg : the config's ``calibration`` section; settings : :class:`CalibrationSettings`.
    """

    kind: str
    items: tuple[tuple[dict, Path], ...]
    results_root: Path
    summary: pl.DataFrame
    cfg: dict
    settings: CalibrationSettings

    @property
    def name(self) -> str:
        """Return the job's name in the log: the device id (three-sensor) or the scan id (rod)."""
        return self.items[0][0]["device_id"] if self.kind == "tri" else self.items[0][0]["scan_id"]


@dataclass(frozen=True)
class CalibrationJobResult:
    """What a job made (:class:`~borescan.stages.calibrate_tri.CalibrationOutcome`) and its log lines."""

    kind: str
    outcome: CalibrationOutcome
    log_lines: tuple[str, ...]
