-- Nightly verification error per device, and how it drifts.
-- Answers: "Is device X still within tolerance on the ring gauge, and is its error creeping?"
-- One row per verification scan (ring gauge measured with the device's current calibration):
--   error_mm            measured - certified diameter [mm]
--   change_mm           error_mm minus the device's previous verification error [mm]
--   moving_range_mm     |change_mm| (the MR of the individuals control chart) [mm]
--   mean_error_mm       mean error of the device's verifications up to this one [mm]
--   drift_mm_per_day    least-squares slope of error_mm over the night, all verifications of the
--                       device up to this one (null until there are two nights) [mm/day]
--   margin_mm           tolerance_mm - |error_mm|; negative means the verification failed [mm]
-- Run: borescan sql --query verification_drift   (or: SELECT * FROM verification_drift)
SELECT
    v.device_id,
    v.night,
    v.scan_id,
    v.artifact_id,
    v.calibration_id,
    v.measured_mm,
    v.certified_mm,
    v.error_mm,
    v.tolerance_mm,
    v.passed,
    v.tolerance_mm - abs(v.error_mm) AS margin_mm,
    v.error_mm - lag(v.error_mm) OVER w AS change_mm,
    abs(v.error_mm - lag(v.error_mm) OVER w) AS moving_range_mm,
    avg(v.error_mm) OVER (w ROWS BETWEEN UNBOUNDED PRECEDING AND CURRENT ROW) AS mean_error_mm,
    CASE WHEN isfinite(regr_slope(v.error_mm, date_diff('day', DATE '1970-01-01', v.night))
                       OVER (w ROWS BETWEEN UNBOUNDED PRECEDING AND CURRENT ROW))
         THEN regr_slope(v.error_mm, date_diff('day', DATE '1970-01-01', v.night))
                       OVER (w ROWS BETWEEN UNBOUNDED PRECEDING AND CURRENT ROW)
    END AS drift_mm_per_day,
    row_number() OVER w AS n_verifications
FROM verifications v
LEFT JOIN scans s ON s.scan_id = v.scan_id
WINDOW w AS (PARTITION BY v.device_id ORDER BY v.night, s.started_at, v.scan_id)
ORDER BY v.device_id, v.night, s.started_at, v.scan_id;
