-- Every change of status of every calibration: the lifecycle kept as history.
-- Answers: "When did this calibration become valid, and when and why did it stop being so?"
-- One row per calibration and event, in time order:
--   status    valid                (from valid_from; the calibration's certificate was issued)
--             failed_verification  (a ring-gauge verification made with it failed: refused from then on)
--             superseded           (a later calibration of the same device became valid)
--             expired              (from the night after its recalibration_due, the last night a
--                                   measurement may use it; listed once the catalog holds that night)
--             refused              (a calibration of the device was refused: no certificate; calibration_id null)
--   night     the night the status began
--   reason    what caused it (the verification scan and its error, the superseding calibration, ...)
--   other_id  the superseding calibration (superseded), else null
--   method    the calibration's method (``nominal``: a rod's design geometry, used until its first
--             ring-gauge calibration, which supersedes it; it never expires)
-- A calibration superseded before its recalibration_due does not also expire. The report's night
-- summary reads this view (one definition of the lifecycle).
-- A calibration's current status is its latest event (see calibration_lifecycle).
-- Run: borescan sql --query calibration_status_history
WITH cal AS (
    SELECT calibration_id, any_value(device_id) AS device_id, any_value(method) AS method,
           min(valid_from) AS valid_from, min(recalibration_due) AS recalibration_due
    FROM calibrations
    GROUP BY calibration_id
),
latest AS (SELECT max(night) AS night FROM scans),
failed AS (
    SELECT v.calibration_id, v.night, v.scan_id, v.error_mm, v.tolerance_mm,
           row_number() OVER (PARTITION BY v.calibration_id ORDER BY v.night, s.started_at, v.scan_id) AS k
    FROM verifications v LEFT JOIN scans s ON s.scan_id = v.scan_id
    WHERE NOT v.passed AND v.calibration_id IS NOT NULL
),
measured AS (SELECT * FROM cal WHERE coalesce(method, '') <> 'nominal'),
nxt AS (
    SELECT calibration_id, device_id,
           lead(valid_from) OVER (PARTITION BY device_id ORDER BY valid_from, calibration_id) AS next_from,
           lead(calibration_id) OVER (PARTITION BY device_id ORDER BY valid_from, calibration_id) AS next_id
    FROM measured
    UNION ALL
    -- a design geometry is superseded by the device's first calibration on certified gauges
    SELECT n.calibration_id, n.device_id, greatest(n.valid_from, f.valid_from), f.calibration_id
    FROM cal n JOIN (SELECT device_id, arg_min(calibration_id, (valid_from, calibration_id)) AS calibration_id,
                            min(valid_from) AS valid_from FROM measured GROUP BY device_id) f USING (device_id)
    WHERE n.method = 'nominal'
),
events AS (
    SELECT calibration_id, device_id, 'valid' AS status, valid_from AS night,
           'calibration ' || method || ' issued' AS reason, NULL::VARCHAR AS other_id
    FROM cal
    UNION ALL
    SELECT f.calibration_id, c.device_id, 'failed_verification', f.night,
           'verification ' || f.scan_id || ' error ' || CAST(round(f.error_mm * 1000, 2) AS VARCHAR)
           || ' um outside +-' || CAST(round(f.tolerance_mm * 1000, 2) AS VARCHAR) || ' um', NULL
    FROM failed f JOIN cal c USING (calibration_id) WHERE f.k = 1
    UNION ALL
    SELECT calibration_id, device_id, 'superseded', next_from, 'superseded by ' || next_id, next_id
    FROM nxt WHERE next_from IS NOT NULL
    UNION ALL
    SELECT c.calibration_id, c.device_id, 'expired', CAST(c.recalibration_due + 1 AS DATE),
           'recalibration was due ' || CAST(c.recalibration_due AS VARCHAR), NULL
    FROM cal c JOIN nxt USING (calibration_id), latest l
    WHERE c.recalibration_due IS NOT NULL AND c.recalibration_due < l.night
      AND (nxt.next_from IS NULL OR nxt.next_from > c.recalibration_due)
    UNION ALL
    SELECT DISTINCT NULL, s.device_id, 'refused', q.night, q.reason, NULL
    FROM quarantine q JOIN scans s ON s.scan_id = q.scan_id AND s.night = q.night
    WHERE q.stage = 'calibrate'
)
SELECT e.calibration_id, e.device_id, e.status, e.night, e.reason, e.other_id, c.method
FROM events e LEFT JOIN cal c USING (calibration_id)
ORDER BY e.device_id, e.night, e.calibration_id NULLS FIRST,
         CASE e.status WHEN 'refused' THEN 0 WHEN 'valid' THEN 1 WHEN 'superseded' THEN 2
                       WHEN 'failed_verification' THEN 3 ELSE 4 END;
