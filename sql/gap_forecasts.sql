-- name: gap_forecasts
-- description: where vessels that went silent probably are: for every vessel in a data
--   gap (no AIS and no identified radar track for longer than [gaps] gap_threshold_s),
--   the bootstrap particle filter's forecast at each configured lead time and at the
--   reappearance (distributed maritime observation paper, eq. 3-7): mean position, its
--   1-sigma ellipse axes, the size of the 90% region, the most likely named zone and
--   the probability of every zone (share of particles in it), whether the admissible
--   area constrained the forecast, and, when the log has truth (or at the reappearance,
--   the reappearing message), the error and whether the true position fell in the 90%
--   region and how probable its zone was.
-- grain: one row per (site, vessel, gap, forecast time)
-- params: $start_ns (BIGINT, inclusive, on the forecast time), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector; the sector of the forecast mean),
--         $site (VARCHAR, NULL = every site)
-- source table: gap_forecasts (written by `surveil batch`, family "gaps")
WITH f AS (
    SELECT *
    FROM gap_forecasts
    WHERE forecast_time_ns >= $start_ns
      AND forecast_time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
axes AS (   -- eigenvalues of the 2x2 position covariance: the sigma ellipse's semi-axes
    SELECT
        *,
        (sigma_x_m * sigma_x_m + sigma_y_m * sigma_y_m) / 2.0 AS half_trace_m2,
        sqrt(power((sigma_x_m * sigma_x_m - sigma_y_m * sigma_y_m) / 2.0, 2)
             + cov_xy_m2 * cov_xy_m2) AS half_gap_m2
    FROM f
)
SELECT
    site::VARCHAR                                                    AS site,           -- site (deployment)
    mmsi::BIGINT                                                     AS mmsi,
    make_timestamp((gap_start_ns // 1000)::BIGINT)::TIMESTAMP        AS gap_start_utc,
    make_timestamp((gap_end_ns // 1000)::BIGINT)::TIMESTAMP          AS gap_end_utc,    -- NULL: still open
    make_timestamp((forecast_time_ns // 1000)::BIGINT)::TIMESTAMP    AS forecast_utc,
    round(lead_s / 60.0, 1)::DOUBLE                                  AS lead_min,
    forecast_kind::VARCHAR                                           AS forecast_kind,  -- offset | gap_end
    coalesce(sector, '(outside sectors)')::VARCHAR                   AS sector,
    round(lat_deg, 6)::DOUBLE                                        AS lat_deg,        -- particle mean
    round(lon_deg, 6)::DOUBLE                                        AS lon_deg,
    round(sqrt(half_trace_m2 + half_gap_m2), 1)::DOUBLE              AS sigma_major_m,
    round(sqrt(greatest(half_trace_m2 - half_gap_m2, 0.0)), 1)::DOUBLE AS sigma_minor_m,
    round(region_radius_m, 1)::DOUBLE                                AS region90_radius_m,  -- radius of a circle of the region's area
    round(region_area_m2 / 1e6, 3)::DOUBLE                           AS region90_area_km2,
    most_likely_zone::VARCHAR                                        AS most_likely_zone,
    round(most_likely_zone_probability, 3)::DOUBLE                   AS most_likely_zone_p,
    zone_probabilities_json::VARCHAR                                 AS zone_probabilities, -- JSON: zone -> probability
    constraint_status::VARCHAR                                       AS constraint_status,  -- off | inactive | active | replenished | infeasible
    round(constraint_mass_removed, 3)::DOUBLE                        AS p_model_ran_aground,
    round(effective_sample_size, 0)::DOUBLE                          AS ess,
    reference::VARCHAR                                               AS reference,      -- truth | observation | NULL
    round(error_m, 1)::DOUBLE                                        AS error_m,        -- mean to reference
    true_in_region::BOOLEAN                                          AS true_in_region90,
    true_zone::VARCHAR                                               AS true_zone,
    round(true_zone_probability, 3)::DOUBLE                          AS true_zone_p
FROM axes
ORDER BY site, forecast_utc, mmsi, gap_start_utc, forecast_kind;
