"""What a three-sensor calibration gives: its result type, its error, its id and its acceptance rule.

:class:`TriCalibration` is the result of both methods (Yang 2017, :mod:`borescan.calibrate.yang`;
the full-data fit, :mod:`borescan.calibrate.full_fit`); its parameter vector is, per channel in
ascending channel order, ``(beta_rad, rho_mm, d_b_mm)`` (``docs/DESIGN.md``).
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from borescan.atomic import json_ready
from borescan.config import schema_default
from borescan.fit import FitResult
from borescan.geometry import Beams

__all__ = ["STATUSES", "CalibrationError", "make_calibration_id", "TriCalibration", "AcceptanceRule"]

STATUSES = ("advanced", "backward")


class CalibrationError(Exception):
    """A calibration that cannot be trusted (no convergence, rank deficiency, bad input).

    ``str(e)`` is ``"<scan ids>: <problem>"``.
    """

    def __init__(self, scan_ids: Sequence[str], problem: str) -> None:
        self.scan_ids = tuple(str(s) for s in scan_ids)
        self.problem = problem
        super().__init__(f"{','.join(self.scan_ids) or '<no scan id>'}: {problem}")


def make_calibration_id(
    device_id: str, scan_ids: Sequence[str], method: str, night: str | None = None
) -> str:
    """Deterministic id ``<device_id>-<YYYYMMDD>-<method>-<8 hex>``.

    The hash is sha256 of device id, sorted scan ids and method. The date is ``night``
    (``YYYY-MM-DD``) or, if absent, the first ``N<YYYYMMDD>`` found in the scan ids; it is
    left out when neither exists.
    """
    scan_ids = sorted(str(s) for s in scan_ids)
    key = json.dumps({"device_id": device_id, "scan_ids": scan_ids, "method": method}, sort_keys=True)
    digest = hashlib.sha256(key.encode()).hexdigest()[:8]
    date = night.replace("-", "") if night else None
    if date is None:
        for s in scan_ids:
            m = re.search(r"N(\d{8})", s)
            if m:
                date = m.group(1)
                break
    parts = [device_id] + ([date] if date else []) + [method, digest]
    return "-".join(parts)


@dataclass
class TriCalibration:
    """Calibrated beams of a three-sensor device with covariance and fit diagnostics.

    Attributes
    ----------
    calibration_id, device_id : str
    beams : Beams
        Calibrated (beta_rad, rho_mm, d_b_mm) per channel.
    cov : ndarray (3c, 3c)
        Covariance, order per channel (beta_rad, rho_mm, d_b_mm). Gauge-fixed parameters
        (beta of the first channel) have zero rows/columns.
    method : str
        ``"yang2017"`` or ``"full_lsq"``.
    scan_ids : tuple of str; raw_sha256 : dict file name -> hex digest
    residual_rms_mm, dof, rank, condition, converged : fit diagnostics (NaN/-1 where undefined)
    nuisance : dict scan_id -> dict of per-scan estimates (offset, rotation rate, ...)
    diagnostics : dict of further JSON-safe information (gauge, rank with all parameters free, ...)
    fit : the least-squares :class:`borescan.fit.FitResult` in the fit's internal parameters
        (full_lsq; not serialised by :meth:`to_dict`, None after :meth:`from_dict`)
    """

    calibration_id: str
    device_id: str
    beams: Beams
    cov: np.ndarray
    method: str
    scan_ids: tuple[str, ...]
    raw_sha256: dict[str, str] = field(default_factory=dict)
    residual_rms_mm: float = float("nan")
    dof: int = -1
    rank: int = -1
    condition: float = float("nan")
    converged: bool = True
    nuisance: dict[str, dict[str, float]] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)
    fit: FitResult | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        c = len(self.beams.channels)
        self.cov = np.asarray(self.cov, dtype=float)
        if self.cov.shape != (3 * c, 3 * c):
            raise ValueError(f"cov must be ({3 * c}, {3 * c}), got {self.cov.shape}")
        self.scan_ids = tuple(self.scan_ids)

    @property
    def params(self) -> np.ndarray:
        """Parameter vector (3c,), per channel (beta_rad, rho_mm, d_b_mm)."""
        b = self.beams
        return np.stack([b.beta_rad, b.rho_mm, b.d_b_mm], axis=1).ravel()

    def _u(self, k: int) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov)[k::3], 0.0, None))

    @property
    def u_beta_rad(self) -> np.ndarray:
        """Standard uncertainties of beta per channel [rad]."""
        return self._u(0)

    @property
    def u_rho_mm(self) -> np.ndarray:
        """Standard uncertainties of rho per channel [mm]."""
        return self._u(1)

    @property
    def u_d_b_mm(self) -> np.ndarray:
        """Standard uncertainties of d_b per channel [mm]."""
        return self._u(2)

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix (3c, 3c); zero rows/columns for gauge-fixed parameters."""
        u = np.sqrt(np.clip(np.diag(self.cov), 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            r = self.cov / np.outer(u, u)
        r = np.where(np.outer(u, u) > 0, r, 0.0)
        np.fill_diagonal(r, np.where(u > 0, 1.0, 0.0))
        return r

    def to_dict(self) -> dict:
        """JSON-safe dict (inverse: :meth:`from_dict`)."""
        return json_ready(
            {
                "calibration_id": self.calibration_id,
                "device_id": self.device_id,
                "method": self.method,
                "scan_ids": list(self.scan_ids),
                "raw_sha256": dict(sorted(self.raw_sha256.items())),
                "beams": self.beams.to_nominal(),
                "cov": self.cov,
                "residual_rms_mm": self.residual_rms_mm,
                "dof": self.dof,
                "rank": self.rank,
                "condition": self.condition,
                "converged": self.converged,
                "nuisance": self.nuisance,
                "diagnostics": self.diagnostics,
            }
        )

    @classmethod
    def from_dict(cls, d: dict) -> "TriCalibration":
        """Rebuild from :meth:`to_dict` output."""

        def f(x: Any) -> float:
            return float("nan") if x is None else float(x)

        return cls(
            calibration_id=d["calibration_id"],
            device_id=d["device_id"],
            beams=Beams.from_nominal(d["beams"]),
            cov=np.array([[f(v) for v in row] for row in d["cov"]]),
            method=d["method"],
            scan_ids=tuple(d["scan_ids"]),
            raw_sha256=dict(d.get("raw_sha256", {})),
            residual_rms_mm=f(d.get("residual_rms_mm")),
            dof=int(d.get("dof", -1)),
            rank=int(d.get("rank", -1)),
            condition=f(d.get("condition")),
            converged=bool(d.get("converged", True)),
            nuisance=d.get("nuisance", {}),
            diagnostics=d.get("diagnostics", {}),
        )


@dataclass(frozen=True)
class AcceptanceRule:
    """When a full-data calibration is trusted (``calibration`` section of the config).

    max_residual_to_noise : largest accepted ratio of a channel's residual rms to its readings'
        own white-noise floor (4th differences, model-free); under the model the ratio is
        1 within ~1 % for the scans of the contract, so 1.25 refuses no correct fit while an
        unmodelled effect of about 0.75 noise sigma rms is refused.
    head_radius_mm : |rho| of a beam cannot exceed the sensor head's radius [mm].
    position_accuracy_mm : the machine's stated accuracy of each coordinate of the scan's
        ``center`` and ``spindle.position``, a half-width (rectangular: standard uncertainty
        a / sqrt(3), GUM 4.3.7) [mm]; they enter the fit as priors.
    speed_scale_range : speeds the search considers, as multiples of the commanded profile.

    The defaults are the schema's (``calibration`` section): :meth:`from_config`, :meth:`defaults`.
    """

    max_residual_to_noise: float
    head_radius_mm: float
    position_accuracy_mm: float
    speed_scale_range: tuple[float, float]

    @classmethod
    def from_config(cls, cal_cfg: Mapping[str, Any]) -> "AcceptanceRule":
        """Return the rule of a config's ``calibration`` section."""
        return cls(
            max_residual_to_noise=float(cal_cfg["max_residual_to_noise"]),
            head_radius_mm=float(cal_cfg["head_radius_mm"]),
            position_accuracy_mm=float(cal_cfg["position_accuracy_mm"]),
            speed_scale_range=(float(cal_cfg["speed_scale_min"]), float(cal_cfg["speed_scale_max"])),
        )

    @classmethod
    def defaults(cls, **overrides: Any) -> "AcceptanceRule":
        """Return the rule of the schema's defaults, with ``overrides``."""
        return replace(cls.from_config(schema_default("calibration")), **overrides)
