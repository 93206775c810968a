-- Calibration-parameter history per device and channel.
-- Answers: "How have beam angle, offset and beam distance (or a rod layer's parameters) of
-- device X, channel c moved from one calibration to the next, and with what uncertainty?"
-- One row per calibration and channel, oldest first:
--   beta_rad, rho_mm, d_b_mm (+ u_*)   tri_lds beam parameters with standard uncertainties (k=1)
--   l0_mm, h_mm, phi_rad, d_mm, gamma_rad   rod layer parameters (null for tri_lds)
--   delta_*                         change against the previous calibration of the same channel
--   scan_ids                        the calibration scan(s), comma separated
--   certificate_path                relative to the results folder
-- Run: borescan sql --query calibration_history   (or: SELECT * FROM calibration_history)
SELECT
    c.device_id,
    c.channel,
    c.valid_from,
    c.calibration_id,
    c.method,
    c.status,
    c.beta_rad, c.u_beta_rad,
    c.rho_mm, c.u_rho_mm,
    c.d_b_mm, c.u_d_b_mm,
    c.l0_mm, c.h_mm, c.phi_rad, c.d_mm, c.gamma_rad,
    c.beta_rad - lag(c.beta_rad) OVER w AS delta_beta_rad,
    c.rho_mm - lag(c.rho_mm) OVER w AS delta_rho_mm,
    c.d_b_mm - lag(c.d_b_mm) OVER w AS delta_d_b_mm,
    c.l0_mm - lag(c.l0_mm) OVER w AS delta_l0_mm,
    (SELECT string_agg(cs.scan_id, ',' ORDER BY cs.scan_id)
       FROM calibration_scans cs WHERE cs.calibration_id = c.calibration_id) AS scan_ids,
    c.certificate_path,
    c.certificate_sha256
FROM calibrations c
WINDOW w AS (PARTITION BY c.device_id, c.channel ORDER BY c.valid_from, c.calibration_id)
ORDER BY c.device_id, c.channel, c.valid_from, c.calibration_id;
