-- name: gap_forecast_calibration
-- description: how good the data-gap forecasts were where a reference exists (simulated
--   truth, or the reappearing message at the gap end): per lead-time band, the share of
--   references inside the forecast's 90% region (should be near 0.90), the error of the
--   particle mean (median, RMS, 95th percentile), the mean forecast probability of the
--   zone the vessel was actually in, and how often the most likely zone was the right one.
-- grain: one row per (site, lead band, reference kind)
-- params: $start_ns (BIGINT, inclusive, on the forecast time), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector; the sector of the forecast mean),
--         $site (VARCHAR, NULL = every site)
-- source table: gap_forecasts (written by `surveil batch`, family "gaps")
WITH f AS (
    SELECT
        *,
        CASE
            WHEN lead_s <= 600 THEN '00-10 min'
            WHEN lead_s <= 1200 THEN '10-20 min'
            WHEN lead_s <= 1800 THEN '20-30 min'
            WHEN lead_s <= 2700 THEN '30-45 min'
            ELSE '45+ min'
        END AS lead_band
    FROM gap_forecasts
    WHERE forecast_time_ns >= $start_ns
      AND forecast_time_ns < $end_ns
      AND reference IS NOT NULL
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
)
SELECT
    site::VARCHAR                                                     AS site,          -- site (deployment)
    lead_band::VARCHAR                                                AS lead_band,
    reference::VARCHAR                                                AS reference,     -- truth | observation
    count(*)::BIGINT                                                  AS forecasts,
    count(DISTINCT (mmsi, gap_start_ns))::BIGINT                      AS gaps,
    round(avg(CASE WHEN true_in_region THEN 1.0 ELSE 0.0 END), 3)::DOUBLE AS in_region90_share,
    round(median(error_m), 1)::DOUBLE                                 AS error_median_m,
    round(sqrt(avg(error_m * error_m)), 1)::DOUBLE                    AS error_rms_m,
    round(quantile_cont(error_m, 0.95), 1)::DOUBLE                    AS error_p95_m,
    round(median(region_radius_m), 1)::DOUBLE                         AS region90_radius_median_m,
    round(avg(true_zone_probability), 3)::DOUBLE                      AS true_zone_p_mean,
    round(avg(CASE WHEN most_likely_zone = true_zone THEN 1.0 ELSE 0.0 END), 3)::DOUBLE
                                                                      AS most_likely_zone_hit
FROM f
GROUP BY site, lead_band, reference
ORDER BY site, lead_band, reference;
