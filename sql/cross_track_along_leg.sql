-- name: cross_track_along_leg
-- description: cross-track deviation error along each fairway leg, fused against each
--   radar (multi-radar paper, figures 1-2): per 500-m stretch of the leg (by the
--   reference position along it), the mean and the 95th percentile of the 60-s sliding
--   RMS error, with the radars' mean observation aspect (0 deg: looking along the leg).
-- grain: one row per (site, leg, source, 500-m stretch)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source table: cross_track_by_leg (written by `surveil batch`)
SELECT
    site::VARCHAR                                              AS site,
    leg_id::VARCHAR                                            AS leg_id,
    source::VARCHAR                                            AS source,           -- site id or 'fused'
    (floor(along_track_m / 500.0) * 0.5 + 0.25)::DOUBLE        AS along_track_km,   -- middle of the stretch, km from the leg start
    count(*)::BIGINT                                           AS samples,
    round(avg(rms_error_60s_m), 2)::DOUBLE                     AS mean_rms_60s_m,   -- mean 60-s RMS error, m
    round(quantile_cont(rms_error_60s_m, 0.95), 2)::DOUBLE     AS p95_rms_60s_m,    -- its 95th percentile, m
    round(sqrt(avg(sigma_cross_track_m ^ 2)), 2)::DOUBLE       AS rms_sigma_m,      -- expected (eq. 2-4), m
    round(avg(aspect_deg), 1)::DOUBLE                          AS mean_aspect_deg   -- radars only
FROM cross_track_by_leg
WHERE time_ns >= $start_ns
  AND time_ns < $end_ns
  AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
  AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
GROUP BY site, leg_id, source, floor(along_track_m / 500.0)
ORDER BY site, leg_id, (source = 'fused') DESC, source, along_track_km;
