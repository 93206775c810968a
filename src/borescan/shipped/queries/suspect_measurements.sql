-- Measurements that used a calibration whose later verification failed.
-- Answers: "Which certified diameters must be re-checked because the calibration they relied on
-- failed a ring-gauge verification?"
-- One row per diameter whose calibration_id has at least one failed verification; the first
-- failed verification of that calibration is named:
--   failed_verification_scan_id, failed_night, failed_error_mm, failed_tolerance_mm
--   measured_before_failure   true when the measurement came before that failed verification
--                             (it was accepted at the time), false when after it
-- Run: borescan sql --query suspect_measurements   (or: SELECT * FROM suspect_measurements)
WITH failed AS (
    SELECT
        v.calibration_id,
        v.scan_id AS failed_verification_scan_id,
        v.night AS failed_night,
        s.started_at AS failed_started_at,
        v.error_mm AS failed_error_mm,
        v.tolerance_mm AS failed_tolerance_mm,
        row_number() OVER (PARTITION BY v.calibration_id ORDER BY v.night, s.started_at, v.scan_id) AS k
    FROM verifications v
    LEFT JOIN scans s ON s.scan_id = v.scan_id
    WHERE NOT v.passed AND v.calibration_id IS NOT NULL
)
SELECT
    d.scan_id,
    d.night,
    d.device_id,
    d.artifact_id,
    d.feature,
    d.diameter_mm,
    d.u_diameter_mm,
    d.method,
    d.calibration_id,
    f.failed_verification_scan_id,
    f.failed_night,
    f.failed_error_mm,
    f.failed_tolerance_mm,
    (d.night, coalesce(s.started_at, TIMESTAMP '1970-01-01'))
        < (f.failed_night, coalesce(f.failed_started_at, TIMESTAMP '1970-01-01')) AS measured_before_failure
FROM diameters d
JOIN failed f ON f.calibration_id = d.calibration_id AND f.k = 1
LEFT JOIN scans s ON s.scan_id = d.scan_id
WHERE coalesce(s.kind, 'measurement') = 'measurement'
ORDER BY d.device_id, d.night, s.started_at, d.scan_id, d.feature;
