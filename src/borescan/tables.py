"""The history tables, defined once: columns, types, keys.

Each :class:`Table` names its columns with a logical type; from it come both the polars schema
of the per-night stage tables (``<results_root>/stage/<table>/night=<night>.parquet``) and the
DuckDB DDL of ``catalog.duckdb`` (:mod:`borescan.catalog`). Dates and times are text in the
stage tables (as the raw ``scan.json`` has them) and ``DATE`` / ``TIMESTAMP`` in the catalog.

A column marked ``stage=False`` is the catalog's alone: it is filled there from other tables
(a finding's night from its scan, ...), so the stage table does not carry it. Columns not listed
here may still be written by a stage (e.g. ``calibration_json``); the catalog keeps them after
these, with the type DuckDB infers.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import polars as pl

__all__ = ["TYPES", "Column", "Table", "TABLES", "polars_schema", "frame", "conform"]

#: logical type -> (polars dtype of the stage table, DuckDB type of the catalog)
TYPES: dict[str, tuple[pl.DataType, str]] = {
    "text": (pl.Utf8, "VARCHAR"),
    "float": (pl.Float64, "DOUBLE"),
    "bool": (pl.Boolean, "BOOLEAN"),
    "int": (pl.Int64, "BIGINT"),
    "channel": (pl.Int64, "SMALLINT"),
    "date": (pl.Utf8, "DATE"),
    "timestamp": (pl.Utf8, "TIMESTAMP"),
}


@dataclass(frozen=True)
class Column:
    """One column of a history table: name, type (a key of :data:`TYPES`), in the stage files or not."""

    name: str
    type: str
    stage: bool = True

    def __post_init__(self) -> None:
        if self.type not in TYPES:
            raise ValueError(f"column {self.name}: unknown type {self.type!r}; valid: {sorted(TYPES)}")


@dataclass(frozen=True)
class Table:
    """One history table.

    One history table: columns in order, key columns (rows are inserted in key order;
    unique when ``primary``).
    """

    name: str
    columns: tuple[Column, ...]
    key: tuple[str, ...]
    primary: bool = False

    def polars_schema(self) -> dict[str, pl.DataType]:
        """Column -> polars dtype of the stage table (catalog-only columns left out)."""
        return {c.name: TYPES[c.type][0] for c in self.columns if c.stage}

    def duckdb_types(self) -> dict[str, str]:
        """Column -> DuckDB type of the catalog table, in column order."""
        return {c.name: TYPES[c.type][1] for c in self.columns}

    def ddl(self, extra: Mapping[str, str] | None = None) -> str:
        """``CREATE TABLE`` of the catalog table; ``extra`` columns (name -> DuckDB type) go after ours."""
        cols = [f"{_q(n)} {t}" for n, t in self.duckdb_types().items()]
        cols += [f"{_q(n)} {t}" for n, t in (extra or {}).items()]
        if self.primary:
            cols.append(f"PRIMARY KEY ({', '.join(_q(k) for k in self.key)})")
        return f"CREATE TABLE {_q(self.name)} ({', '.join(cols)})"


def _q(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


def _cols(spec: str) -> tuple[Column, ...]:
    """``"a:text b:float c:date!"`` -> columns; a trailing ``!`` marks a catalog-only column."""
    out = []
    for item in spec.split():
        name, _, typ = item.partition(":")
        out.append(Column(name, typ.rstrip("!"), stage=not typ.endswith("!")))
    return tuple(out)


_T = [
    # (scan_id, night): a scan id reused in a later night is quarantined but still recorded.
    Table(
        "scans",
        _cols(
            "scan_id:text night:date device_id:text device_type:text kind:text artifact_id:text "
            "started_at:timestamp status:text reason:text raw_sha256:text raw_path:text simulated:bool "
            # the artifact's certificate as this scan's scan.json gives it (kept per scan: history
            # that a later scan naming the artifact cannot rewrite)
            "artifact_certificate:text artifact_certified_diameter_mm:float artifact_u_diameter_mm:float "
            "artifact_features_certified:text"
        ),
        ("scan_id", "night"),
        primary=True,
    ),
    Table(
        "scan_files",
        _cols("scan_id:text file:text sha256:text bytes:int night:date"),
        ("scan_id", "night", "file"),
        primary=True,
    ),
    Table(
        "artifacts",
        _cols(
            "artifact_id:text type:text certificate:text nominal_diameter_mm:float "
            "certified_diameter_mm:float u_diameter_mm:float k:float cte_per_k:float"
        ),
        ("artifact_id",),
        primary=True,
    ),
    Table(
        "calibrations",
        _cols(
            "calibration_id:text device_id:text device_type:text scan_id:text channel:channel "
            "rho_mm:float d_b_mm:float beta_rad:float u_rho_mm:float u_d_b_mm:float u_beta_rad:float "
            "l0_mm:float h_mm:float phi_rad:float d_mm:float gamma_rad:float "
            "u_l0_mm:float u_h_mm:float u_phi_rad:float u_d_mm:float u_gamma_rad:float "
            "method:text certificate_path:text certificate_sha256:text "
            "night:date valid_from:date status:text raw_sha256:text "
            # GUM budget (issue 19): expanded uncertainties (not U_*: DuckDB names ignore case), k, gauge
            # temperature
            "expanded_u_beta_rad:float expanded_u_rho_mm:float "
            "expanded_u_d_b_mm:float k_beta:float k_rho:float k_d_b:float "
            "coverage_probability:float temperature_c:float temperature_assumed:bool recalibration_due:date "
            # the mirror check of each beam (issue 36): resolved, or two solutions with the wrong sign's
            # probability
            "rho_sign_resolved:bool mirror_delta_chi2:float mirror_depth_predicted:float p_wrong_sign:float "
            "valid_bore_min_mm:float valid_bore_max_mm:float offset_to_resolve_mm:float rho_sign_fix:text "
            # SHA-256 of the row's calibration_json (the stage's full record, kept after these columns): a
            # changed calibration is told by its digest, without reading every calibration's record
            "calibration_json_sha256:text!"
        ),
        ("calibration_id", "channel"),
        primary=True,
    ),
    Table(
        "calibration_scans",
        _cols("calibration_id:text scan_id:text"),
        ("calibration_id", "scan_id"),
        primary=True,
    ),
    Table(
        "diameters",
        _cols(
            "diameter_id:text scan_id:text night:date device_id:text artifact_id:text feature:text "
            "diameter_mm:float u_diameter_mm:float calibration_id:text method:text raw_sha256:text "
            # the part's nominal and tolerance (scan.json / config) and the verdict at 20 degC
            "nominal_diameter_mm:float tolerance_mm:float deviation_mm:float conformity:text "
            # diameter_mm is at temperature_c; diameter_20_mm at 20 degC (ISO 1), with the budget
            "temperature_c:float u_temperature_c:float temperature_assumed:bool cte_per_k:float "
            "cte_assumed:bool diameter_20_mm:float u_diameter_20_mm:float expanded_u_diameter_20_mm:float "
            "expanded_u_diameter_mm:float k:float k_at_t:float coverage_probability:float nu_eff:float "
            "coverage_method:text thermal_correction_mm:float u_thermal_correction_mm:float "
            "budget_json:text"
        ),
        ("diameter_id", "method"),
    ),
    Table(
        "verifications",
        _cols(
            "scan_id:text night:date device_id:text artifact_id:text measured_mm:float "
            "certified_mm:float error_mm:float tolerance_mm:float passed:bool calibration_id:text "
            # measured_mm is at 20 degC (= certified_mm + error_mm); as measured at temperature_c
            "measured_at_t_mm:float temperature_c:float temperature_assumed:bool "
            "expected_at_t_mm:float u_measured_mm:float u_error_mm:float expanded_u_error_mm:float "
            "k:float acceptance_limit_mm:float decision_rule:text conformity:text budget_json:text "
            # a rod verifies each layer in its own gauge: one row per layer (null for tri_lds)
            "feature:text "
            # the budget's largest input (its key) and, when U(E) is not below the tolerance, what would
            # reduce it (rod: measure.rod_verifications; null when nothing is said)
            "dominant_input:text dominant_fix:text"
        ),
        ("scan_id", "calibration_id", "feature"),
    ),
    Table(
        "findings",
        _cols(
            "scan_id:text night:date! verdict:text effect:text channel:channel parameters:text "
            "gap_before_mm:float gap_after_mm:float noise_floor_mm:float uncertainties:text statement:text"
        ),
        ("scan_id", "effect", "channel"),
    ),
    Table(
        "quarantine",
        _cols("scan_id:text night:date stage:text file:text reason:text"),
        ("scan_id", "night", "stage", "file"),
    ),
    # issue 22: pooled examination of a device's spindle scans of a window of nights (one row per named
    # effect, per device-model term, or one row with a null effect); nights and scan_ids comma-separated
    Table(
        "pooled_findings",
        _cols(
            "night:date device_id:text nights:text scan_ids:text verdict:text effect:text "
            "channel:channel term:text "
            "group:text parameters:text uncertainties:text evidence_scans:text in_device_model:bool "
            "device_model:text "
            "absorbed:text gap_before_mm:float gap_after_mm:float noise_floor_mm:float "
            "findings_path:text reason:text"
        ),
        ("night", "device_id", "term"),
    ),
    # issue 22: change of a beam parameter between consecutive calibrations (the later one valid from
    # the night)
    Table(
        "calibration_drift",
        _cols(
            "night:date device_id:text channel:channel parameter:text calibration_id_before:text "
            "calibration_id_after:text valid_from_before:date valid_from_after:date value_before:float "
            "value_after:float change:float u_before:float u_after:float u_combined:float "
            "change_over_u:float "
            "multiple:float flagged:bool explained_by:text explanation:text"
        ),
        ("device_id", "channel", "parameter", "calibration_id_after"),
    ),
    # issue 40: the settings each night was processed with (borescan.night_config), and each
    # recomputation of past nights with other settings (night: the first night recomputed)
    Table(
        "night_config",
        _cols("night:date config_hash:text config_json:text recorded_by:text first_processed:date"),
        ("night",),
        primary=True,
    ),
    Table(
        "config_changes",
        _cols(
            "night:date change_id:text nights:text old_hashes:text new_hash:text "
            "changed_keys:text archive:text"
        ),
        ("change_id",),
        primary=True,
    ),
]

#: every history table by name, in catalog order
TABLES: dict[str, Table] = {t.name: t for t in _T}


def _table(name: str) -> Table:
    try:
        return TABLES[name]
    except KeyError:
        raise ValueError(f"unknown history table {name!r}; valid: {sorted(TABLES)}") from None


def polars_schema(name: str) -> dict[str, pl.DataType]:
    """Return the stage table's polars schema of history table ``name``."""
    return _table(name).polars_schema()


def frame(name: str, rows: Iterable[Mapping]) -> pl.DataFrame:
    """Return rows as a frame with table ``name``'s stage schema.

    Rows (dicts keyed by column name) as a frame with table ``name``'s stage schema; empty frame
    with the schema when there are none.
    """
    schema = polars_schema(name)
    rows = list(rows)
    return pl.DataFrame(rows, schema=schema, orient="row") if rows else pl.DataFrame(schema=schema)


def conform(name: str, df: pl.DataFrame) -> pl.DataFrame:
    """Return ``df`` with every stage column of table ``name``.

    A missing one added as nulls of its type, the table's columns first and cast to their types, other columns
    kept after them.

    A stage whose rows happen to lack a kind of column (a rod-only night's calibrations have no
    ``beta_rad``; an empty night has no rows at all) still writes and reads the table's columns.
    """
    schema = polars_schema(name)
    missing = [pl.lit(None, dtype=t).alias(c) for c, t in schema.items() if c not in df.columns]
    if missing:
        df = df.with_columns(missing) if df.width else pl.DataFrame(schema=schema)
    casts = [pl.col(c).cast(t) for c, t in schema.items() if df.schema[c] != t]
    if casts:
        df = df.with_columns(casts)
    return df.select([*schema, *(c for c in df.columns if c not in schema)])
