-- name: radar_accuracy_by_range
-- description: each radar's accuracy per range band from its site (issue 38 item 2,
--   estimated sensor accuracy per range band): its points' range error and azimuth error
--   (mean = bias, RMS, 95th percentile of the magnitude), the cross-range error (range x
--   azimuth error, m) and the mean NEES of its points with the covariance it stated
--   (its sigmas as reported), against simulated truth, else the reconstructed reference.
--   stated_variance_scale = mean NEES / 2: the factor the stated covariance needs in
--   that band (1 = right; the batch's stated-accuracy check scales a site's range and
--   azimuth sigmas once over every range, docs/integrity.md section 9: a band far from
--   the others says the radar's accuracy changes with range beyond its sigmas' model).
--   Against the reconstructed reference the reference's own error is in the error
--   (reference_p95_m says how much), so the scale reads a little high.
-- grain: one row per (site, radar site, reference, range band)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $range_band_m (DOUBLE, default 4000, >= 100)
-- source table: track_errors (written by `surveil batch`)
WITH pts AS (
    SELECT site, source, reference, range_error_m AS re, azimuth_error_rad AS ae,
           reference_range_m AS rr, nees, reference_p95_m,
           floor(reference_range_m / CAST($range_band_m AS DOUBLE))::BIGINT AS band
    FROM track_errors
    WHERE time_ns >= $start_ns
      AND time_ns < $end_ns
      AND source <> 'fused'
      AND reference_range_m IS NOT NULL
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
)
SELECT
    site::VARCHAR                                              AS site,
    source::VARCHAR                                            AS site_id,          -- the radar
    reference::VARCHAR                                         AS reference,        -- truth | reconstructed
    (band * CAST($range_band_m AS DOUBLE))::DOUBLE             AS range_from_m,
    ((band + 1) * CAST($range_band_m AS DOUBLE))::DOUBLE       AS range_to_m,
    count(*)::BIGINT                                           AS samples,
    round(avg(re), 2)::DOUBLE                                  AS range_mean_m,     -- > 0: too far
    round(sqrt(avg(re * re)), 2)::DOUBLE                       AS range_rms_m,
    round(quantile_cont(abs(re), 0.95), 2)::DOUBLE             AS range_p95_m,
    round(degrees(avg(ae)), 4)::DOUBLE                         AS azimuth_mean_deg, -- > 0: clockwise
    round(degrees(sqrt(avg(ae * ae))), 4)::DOUBLE              AS azimuth_rms_deg,
    round(sqrt(avg((rr * ae) * (rr * ae))), 2)::DOUBLE         AS cross_range_rms_m,
    round(avg(nees), 3)::DOUBLE                                AS nees_mean,        -- 2 = as stated
    round(avg(nees) / 2, 3)::DOUBLE                            AS stated_variance_scale,
    round(quantile_cont(reference_p95_m, 0.5), 2)::DOUBLE      AS reference_p95_m   -- median; 0: truth
FROM pts
GROUP BY site, source, reference, band
ORDER BY site, site_id, reference, range_from_m;
