-- name: nav_heading_error
-- description: own-ship heading error over time (gyro/GNSS/log paper): per 10-s step,
--   the integrated solution's heading error and the gyrocompass alone against truth
--   (simulated logs), the filter's own 1-sigma, and the share of steps in emergency mode
--   (no valid GNSS fix).
-- grain: one row per (site, platform, 10-s step)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source table: nav_solution (written by `surveil batch`, family nav)
SELECT
    site::VARCHAR                                                               AS site,
    platform_id::VARCHAR                                                        AS platform_id,
    make_timestamp(((time_ns // 10000000000) * 10000000)::BIGINT)::TIMESTAMP    AS time_utc,            -- start of the step
    round(degrees(avg(heading_error_rad)), 4)::DOUBLE                           AS heading_error_deg,   -- integrated (truth)
    round(degrees(avg(gyro_heading_error_rad)), 4)::DOUBLE                      AS gyro_error_deg,      -- gyro alone (truth)
    round(degrees(avg(sigma_heading_rad)), 4)::DOUBLE                           AS sigma_heading_deg,   -- filter 1-sigma
    round(avg(CASE WHEN mode = 'emergency' THEN 1.0 ELSE 0.0 END), 2)::DOUBLE   AS emergency_share,
    bool_and(converged)::BOOLEAN                                                AS converged
FROM nav_solution
WHERE time_ns >= $start_ns
  AND time_ns < $end_ns
  AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
  AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
GROUP BY site, platform_id, time_ns // 10000000000
ORDER BY site, platform_id, time_utc;
