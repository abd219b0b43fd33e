-- name: registration_over_time
-- description: each radar's online registration and estimated accuracy per minute
--   (issue 38; pipeline/maritime/registration.py): the range bias, azimuth bias, clock
--   offset and range gain (m per km) the batch estimated (reported - true) with their
--   95 % intervals (estimate -/+ 1.96 sigma, means over the minute's epochs and sectors),
--   the share of epochs the estimate was applied to the reports before fusion, the
--   largest factors on the site's stated range and azimuth variances and the larger
--   of its speed and course variances' (the stated-accuracy check; 1 = as stated), the
--   largest variance scale of the radar's sectors on top of them (1 = the stated or so
--   scaled sigmas) and the share of epochs it was fused although the integrity excluded it: the site's
--   registration (registered_sector NULL) and, where the site's sectors differ, each
--   sector's own (registered_sector: its name) in rows of their own. The audit's
--   registration time series.
-- grain: one row per (site, radar site, registered sector or NULL, minute)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source table: sensor_registration (written by `surveil batch`)
SELECT
    site::VARCHAR                                                         AS site,
    site_id::VARCHAR                                                      AS site_id,
    CASE WHEN registration_scope = 'sector'
         THEN coalesce(sector, '(outside sectors)') END::VARCHAR          AS registered_sector,
    make_timestamp(((time_ns // 60000000000) * 60000000)::BIGINT)::TIMESTAMP AS minute_utc,  -- start of the minute
    count(DISTINCT time_ns)::BIGINT                                       AS epochs,
    round(avg(registration_applied::INTEGER), 4)::DOUBLE                  AS registration_applied_share,
    round(avg(range_bias_m), 2)::DOUBLE                                   AS range_bias_m,
    round(avg(range_bias_m - 1.959964 * sigma_range_bias_m), 2)::DOUBLE   AS range_ci_low_m,
    round(avg(range_bias_m + 1.959964 * sigma_range_bias_m), 2)::DOUBLE   AS range_ci_high_m,
    round(avg(degrees(azimuth_bias_rad)), 4)::DOUBLE                      AS azimuth_bias_deg,
    round(avg(degrees(azimuth_bias_rad - 1.959964 * sigma_azimuth_bias_rad)), 4)::DOUBLE
                                                                          AS azimuth_ci_low_deg,
    round(avg(degrees(azimuth_bias_rad + 1.959964 * sigma_azimuth_bias_rad)), 4)::DOUBLE
                                                                          AS azimuth_ci_high_deg,
    round(avg(time_offset_s), 3)::DOUBLE                                  AS time_offset_s,
    round(avg(time_offset_s - 1.959964 * sigma_time_offset_s), 3)::DOUBLE AS time_ci_low_s,
    round(avg(time_offset_s + 1.959964 * sigma_time_offset_s), 3)::DOUBLE AS time_ci_high_s,
    round(avg(1000 * range_gain), 3)::DOUBLE                              AS range_gain_m_per_km,
    round(avg(1000 * (range_gain - 1.959964 * sigma_range_gain)), 3)::DOUBLE AS range_gain_ci_low_m_per_km,
    round(avg(1000 * (range_gain + 1.959964 * sigma_range_gain)), 3)::DOUBLE AS range_gain_ci_high_m_per_km,
    round(max(stated_range_variance_scale), 3)::DOUBLE                    AS stated_range_scale_max,  -- NULL: batched before the per-axis check
    round(max(stated_azimuth_variance_scale), 3)::DOUBLE                  AS stated_azimuth_scale_max,
    round(greatest(max(stated_speed_variance_scale), max(stated_course_variance_scale)), 3)::DOUBLE
                                                                          AS stated_velocity_scale_max,  -- the larger of speed and course
    round(max(variance_scale), 3)::DOUBLE                                 AS variance_scale_max,
    round(avg(readmitted::INTEGER), 4)::DOUBLE                            AS readmitted_share
FROM sensor_registration
WHERE time_ns >= $start_ns
  AND time_ns < $end_ns
  AND (CAST($sector AS VARCHAR) IS NULL OR coalesce(sector, '(outside sectors)') = CAST($sector AS VARCHAR))
  AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
GROUP BY site, site_id, registered_sector, time_ns // 60000000000
ORDER BY site, site_id, registered_sector NULLS FIRST, minute_utc;
