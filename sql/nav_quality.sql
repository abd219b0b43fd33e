-- name: nav_quality
-- description: own-ship integrated navigation (gyro/GNSS/log paper) per vessel and
--   sector: heading error of the integrated solution and of the gyro alone against
--   truth (simulated logs), else innovation statistics of the GNSS acceleration; eq. 3
--   gate rejections; emergency-mode share; GNSS outages and their dead-reckoning error.
-- grain: one row per (site, platform_id, sector)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source tables: nav_solution, nav_outages (written by `surveil batch`, family nav)
WITH steps AS (
    SELECT
        site,
        platform_id,
        coalesce(sector, '(outside sectors)') AS sector,
        mode,
        converged,
        gate,
        heading_error_rad,
        gyro_heading_error_rad,
        w_innovation_mps2,
        w_innovation_sigma_mps2,
        nis
    FROM nav_solution
    WHERE time_ns >= $start_ns
      AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
per_vessel AS (
    SELECT
        site,
        platform_id,
        sector,
        count(*) AS steps,
        count(*) FILTER (WHERE converged) AS converged_steps,
        sqrt(avg(heading_error_rad * heading_error_rad) FILTER (WHERE converged)) AS h_rms,
        max(abs(heading_error_rad)) FILTER (WHERE converged) AS h_max,
        max(abs(gyro_heading_error_rad)) AS gyro_max,
        sqrt(avg(gyro_heading_error_rad * gyro_heading_error_rad)) AS gyro_rms,
        count(*) FILTER (WHERE gate = 'pass') AS gate_pass,
        count(*) FILTER (WHERE gate = 'reject') AS gate_reject,
        count(*) FILTER (WHERE mode = 'emergency') AS emergency_steps,
        avg(w_innovation_mps2 / w_innovation_sigma_mps2) FILTER (WHERE gate = 'pass') AS innov_mean,
        avg(power(w_innovation_mps2 / w_innovation_sigma_mps2, 2)) FILTER (WHERE gate = 'pass') AS innov_sq,
        avg(nis) AS mean_nis
    FROM steps
    GROUP BY site, platform_id, sector
),
outages AS (
    SELECT
        site,
        platform_id,
        coalesce(sector, '(outside sectors)') AS sector,
        count(*) AS n,
        sum(duration_s) AS total_s,
        max(duration_s) AS longest_s,
        max(dr_error_m) AS worst_dr_m,
        max(dr_error_m / dr_bound_m) AS worst_ratio
    FROM nav_outages
    WHERE start_ns >= $start_ns
      AND start_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
    GROUP BY site, platform_id, sector
)
SELECT
    coalesce(v.site, o.site)::VARCHAR                AS site,               -- site (deployment)
    coalesce(v.platform_id, o.platform_id)::VARCHAR AS platform_id,        -- vessel
    coalesce(v.sector, o.sector)::VARCHAR            AS sector,             -- sector polygon
    coalesce(v.steps, 0)::BIGINT                     AS steps,              -- filter steps
    coalesce(v.converged_steps, 0)::BIGINT           AS converged_steps,    -- after convergence_s
    round(degrees(v.h_rms), 4)::DOUBLE               AS heading_rms_deg,    -- integrated, converged (truth)
    round(degrees(v.h_max), 4)::DOUBLE               AS heading_max_deg,    -- integrated, converged (truth)
    round(degrees(v.gyro_rms), 3)::DOUBLE            AS gyro_rms_deg,       -- gyro alone (truth)
    round(degrees(v.gyro_max), 3)::DOUBLE            AS gyro_max_deg,       -- gyro alone (truth)
    round(v.innov_mean, 3)::DOUBLE                   AS w_innovation_mean,  -- mean normalised W innovation (~0)
    round(v.innov_sq, 3)::DOUBLE                     AS w_innovation_nis,   -- its mean square (~1 when honest)
    round(v.mean_nis, 3)::DOUBLE                     AS mean_nis,           -- mean NIS of the updates
    coalesce(v.gate_pass, 0)::BIGINT                 AS gate_pass,          -- GNSS fixes through eq. 3
    coalesce(v.gate_reject, 0)::BIGINT               AS gate_reject,        -- GNSS fixes rejected by the gate
    round(coalesce(v.emergency_steps, 0) / greatest(coalesce(v.steps, 0), 1), 4)::DOUBLE
                                                     AS emergency_share,    -- share of steps in emergency mode
    coalesce(o.n, 0)::BIGINT                         AS outages,            -- outages starting here
    round(coalesce(o.total_s, 0), 1)::DOUBLE         AS outage_total_s,     -- their total duration, s
    round(o.longest_s, 1)::DOUBLE                    AS outage_longest_s,   -- longest, s
    round(o.worst_dr_m, 2)::DOUBLE                   AS worst_dr_error_m,   -- DR error at an outage end, m
    round(o.worst_ratio, 3)::DOUBLE                  AS worst_dr_error_to_bound  -- <= 1: inside the bound
FROM per_vessel v
FULL OUTER JOIN outages o
    ON v.site = o.site AND v.platform_id = o.platform_id AND v.sector = o.sector
ORDER BY site, platform_id, sector;
