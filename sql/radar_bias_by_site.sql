-- name: radar_bias_by_site
-- description: registration bias of each radar site (reported - true) estimated from the
--   AIS reports of cooperative ships by `surveil calibrate-radars`: range bias, range gain
--   (m per km), azimuth (north alignment) bias and time offset with their 95% confidence intervals, the
--   reports and ships used and the fit's residuals. One row per estimation window whose
--   start lies in the window. Radar sites are not in sectors: the sector parameter is unused.
-- grain: one row per (site, estimation window, radar site)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $site (VARCHAR, NULL = every site)
-- source table: radar_bias_by_site (written by `surveil calibrate-radars`)
SELECT
    site::VARCHAR                                           AS site,           -- site (deployment)
    site_id::VARCHAR                                        AS site_id,
    make_timestamp((time_ns // 1000)::BIGINT)::TIMESTAMP    AS window_start_utc,
    make_timestamp((end_time_ns // 1000)::BIGINT)::TIMESTAMP AS window_end_utc,
    reports_used::BIGINT                                    AS reports_used,
    reports_rejected::BIGINT                                AS reports_rejected,   -- outliers
    ships_used::BIGINT                                      AS ais_ships,
    round(range_bias_m, 2)::DOUBLE                          AS range_bias_m,
    round(range_bias_ci_low_m, 2)::DOUBLE                   AS range_ci_low_m,
    round(range_bias_ci_high_m, 2)::DOUBLE                  AS range_ci_high_m,
    round(azimuth_bias_deg, 4)::DOUBLE                      AS azimuth_bias_deg,
    round(azimuth_bias_ci_low_deg, 4)::DOUBLE               AS azimuth_ci_low_deg,
    round(azimuth_bias_ci_high_deg, 4)::DOUBLE              AS azimuth_ci_high_deg,
    round(time_offset_s, 3)::DOUBLE                         AS time_offset_s,
    round(time_offset_ci_low_s, 3)::DOUBLE                  AS time_ci_low_s,
    round(time_offset_ci_high_s, 3)::DOUBLE                 AS time_ci_high_s,
    round(range_gain * 1e3, 3)::DOUBLE                      AS range_gain_m_per_km,  -- NULL: estimated before the gain was
    round(range_gain_ci_low * 1e3, 3)::DOUBLE               AS range_gain_ci_low_m_per_km,
    round(range_gain_ci_high * 1e3, 3)::DOUBLE              AS range_gain_ci_high_m_per_km,
    round(rms_range_residual_m, 2)::DOUBLE                  AS rms_range_residual_m,
    round(rms_azimuth_residual_deg, 4)::DOUBLE              AS rms_azimuth_residual_deg,
    round(reduced_chi2, 3)::DOUBLE                          AS reduced_chi2
FROM radar_bias_by_site
WHERE time_ns >= $start_ns
  AND time_ns < $end_ns
  AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
ORDER BY site, time_ns, site_id;
