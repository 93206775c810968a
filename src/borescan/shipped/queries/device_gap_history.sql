-- Gap between the model and the spindle scans of each device, night by night (pooled examination).
-- Answers: "How far has device X's model been from its gauge scans over time; which effect did the
-- pooled examination name, which effects were already in the device model, and which calibration
-- drifts were flagged that night and explained by a named effect?"
-- One row per device and night, oldest first:
--   verdict                          missing_effect, ambiguous, no_missing_effect (failed: see reason)
--   gap_before_mm, gap_after_mm      rms residual of the base model, and with the named effects [mm]
--   noise_floor_mm, gap_over_noise   pooled noise floor [mm]; gap_before_mm / noise_floor_mm [-]
--   named                            named terms (effect@channel), comma separated
--   device_model                     device-model terms fitted with the base (config devices:)
--   scan_ids                         the pooled scans (comma separated)
--   drifts_flagged, drifts_explained calibration drifts flagged that night, and those a named effect explains
-- Run: borescan sql --query device_gap_history   (or: SELECT * FROM device_gap_history)
SELECT
    p.device_id,
    p.night,
    any_value(p.verdict) AS verdict,
    any_value(p.gap_before_mm) AS gap_before_mm,
    any_value(p.gap_after_mm) AS gap_after_mm,
    any_value(p.noise_floor_mm) AS noise_floor_mm,
    any_value(p.gap_before_mm) / nullif(any_value(p.noise_floor_mm), 0) AS gap_over_noise,
    string_agg(p.term, ',' ORDER BY p.term) FILTER (WHERE p.effect IS NOT NULL AND NOT coalesce(p.in_device_model, false)) AS named,
    string_agg(p.term, ',' ORDER BY p.term) FILTER (WHERE coalesce(p.in_device_model, false)) AS device_model,
    any_value(p.scan_ids) AS scan_ids,
    coalesce(any_value(d.flagged), 0) AS drifts_flagged,
    coalesce(any_value(d.explained), 0) AS drifts_explained,
    any_value(p.reason) AS reason
FROM pooled_findings p
LEFT JOIN (
    SELECT device_id, night,
           count(*) FILTER (WHERE flagged) AS flagged,
           count(*) FILTER (WHERE flagged AND coalesce(explained_by, '') <> '') AS explained
    FROM calibration_drift GROUP BY device_id, night
) d ON d.device_id = p.device_id AND d.night = p.night
GROUP BY p.device_id, p.night
ORDER BY p.device_id, p.night
