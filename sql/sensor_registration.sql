-- name: sensor_registration
-- description: online registration and estimated accuracy of each radar (issue 38;
--   pipeline/maritime/registration.py) per site and sector over the window: the range
--   bias, azimuth bias, clock offset and range gain (m per km) the batch estimated from
--   the channel integrity's leave-one-out residuals (AIS-identified ships, radar-radar
--   overlap), their mean and the mean of their 95 % intervals (estimate -/+ 1.96 sigma)
--   over the epochs, the share of epochs the estimate was applied to the reports before
--   fusion and the share it was the sector's own (the site's sectors differ; else the
--   site's, the same in each of its sectors), the factors on the site's stated range,
--   azimuth, speed and course variances the stated-accuracy check found (means; 1 = as
--   stated: a site noisier than its sigmas for minutes on end), the variance scale on
--   top of them (mean and largest; 1 = the stated or so scaled sigmas) and the share of
--   epochs it was estimated, the share of the
--   estimate's tracks tested against AIS and of radar-radar pairs without AIS, and the
--   share of epochs the radar was fused although the integrity excluded it (its
--   corrected and rescaled residuals passed).
-- grain: one row per (site, radar site, sector)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source table: sensor_registration (written by `surveil batch`)
SELECT
    site::VARCHAR                                              AS site,
    site_id::VARCHAR                                           AS site_id,
    coalesce(sector, '(outside sectors)')::VARCHAR             AS sector,
    count(*)::BIGINT                                           AS epochs,
    round(avg(registration_applied::INTEGER), 4)::DOUBLE       AS registration_applied_share,
    round(avg((registration_scope = 'sector')::INTEGER), 4)::DOUBLE AS sector_registration_share,
    round(avg(range_bias_m), 2)::DOUBLE                        AS range_bias_m,
    round(avg(range_bias_m - 1.959964 * sigma_range_bias_m), 2)::DOUBLE AS range_ci_low_m,
    round(avg(range_bias_m + 1.959964 * sigma_range_bias_m), 2)::DOUBLE AS range_ci_high_m,
    round(avg(degrees(azimuth_bias_rad)), 4)::DOUBLE           AS azimuth_bias_deg,
    round(avg(degrees(azimuth_bias_rad - 1.959964 * sigma_azimuth_bias_rad)), 4)::DOUBLE
                                                               AS azimuth_ci_low_deg,
    round(avg(degrees(azimuth_bias_rad + 1.959964 * sigma_azimuth_bias_rad)), 4)::DOUBLE
                                                               AS azimuth_ci_high_deg,
    round(avg(time_offset_s), 3)::DOUBLE                       AS time_offset_s,
    round(avg(time_offset_s - 1.959964 * sigma_time_offset_s), 3)::DOUBLE AS time_ci_low_s,
    round(avg(time_offset_s + 1.959964 * sigma_time_offset_s), 3)::DOUBLE AS time_ci_high_s,
    round(avg(1000 * range_gain), 3)::DOUBLE                              AS range_gain_m_per_km,
    round(avg(1000 * (range_gain - 1.959964 * sigma_range_gain)), 3)::DOUBLE AS range_gain_ci_low_m_per_km,
    round(avg(1000 * (range_gain + 1.959964 * sigma_range_gain)), 3)::DOUBLE AS range_gain_ci_high_m_per_km,
    round(avg(stated_range_variance_scale), 3)::DOUBLE         AS stated_range_scale_mean,    -- NULL: batched before the per-axis check
    round(avg(stated_azimuth_variance_scale), 3)::DOUBLE       AS stated_azimuth_scale_mean,
    round(avg(stated_speed_variance_scale), 3)::DOUBLE         AS stated_speed_scale_mean,    -- NULL: batched before the velocity check
    round(avg(stated_course_variance_scale), 3)::DOUBLE        AS stated_course_scale_mean,
    round(avg(variance_scale), 3)::DOUBLE                      AS variance_scale_mean,
    round(max(variance_scale), 3)::DOUBLE                      AS variance_scale_max,
    round(avg(scale_applied::INTEGER), 4)::DOUBLE              AS scale_applied_share,
    round(sum(tracks_ais)::DOUBLE / nullif(sum(tracks), 0), 4)::DOUBLE AS ais_track_share,
    round(sum(tracks_pair)::DOUBLE / nullif(sum(tracks), 0), 4)::DOUBLE AS pair_track_share,
    round(avg(readmitted::INTEGER), 4)::DOUBLE                 AS readmitted_share
FROM sensor_registration
WHERE time_ns >= $start_ns
  AND time_ns < $end_ns
  AND (CAST($sector AS VARCHAR) IS NULL OR coalesce(sector, '(outside sectors)') = CAST($sector AS VARCHAR))
  AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
GROUP BY site, site_id, coalesce(sector, '(outside sectors)')
ORDER BY site, site_id, sector;
