-- Each calibration's status as of the catalog's newest night, with its validity window.
-- Answers: "Which calibration may each device use today, and why is the others' not valid?"
-- One row per calibration:
--   valid_from, recalibration_due   from the calibration (recalibration_due null: does not expire, a rod's nominal)
--   valid_until   the night it stopped being usable: the first of failed verification, superseded, expired (null: still valid)
--   status        its latest event of calibration_status_history (valid, superseded, failed_verification, expired)
--   status_night, reason   when and why
-- Run: borescan sql --query calibration_lifecycle
WITH h AS (
    SELECT *, row_number() OVER (PARTITION BY calibration_id ORDER BY night DESC,
        CASE status WHEN 'failed_verification' THEN 0 WHEN 'expired' THEN 1 WHEN 'superseded' THEN 2 ELSE 3 END) AS k
    FROM calibration_status_history WHERE calibration_id IS NOT NULL
),
ends AS (
    SELECT calibration_id, min(night) AS valid_until
    FROM calibration_status_history WHERE status <> 'valid' AND calibration_id IS NOT NULL
    GROUP BY calibration_id
),
cal AS (
    SELECT calibration_id, any_value(device_id) AS device_id, any_value(method) AS method,
           min(valid_from) AS valid_from, min(recalibration_due) AS recalibration_due
    FROM calibrations GROUP BY calibration_id
)
SELECT c.calibration_id, c.device_id, c.method, c.valid_from, c.recalibration_due, e.valid_until,
       h.status, h.night AS status_night, h.reason
FROM cal c
JOIN h ON h.calibration_id = c.calibration_id AND h.k = 1
LEFT JOIN ends e ON e.calibration_id = c.calibration_id
ORDER BY c.device_id, c.valid_from, c.calibration_id;
