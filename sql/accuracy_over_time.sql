-- name: accuracy_over_time
-- description: horizontal position error of the fused picture and of each radar's
--   synchronised picture per minute (all sectors together, or one): 95th percentile, RMS
--   and sample count, against the reference (truth, else AIS). The audit's "error over
--   time" chart.
-- grain: one row per (site, minute, source)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source table: track_errors (written by `surveil batch`)
SELECT
    site::VARCHAR                                     AS site,          -- site (deployment)
    make_timestamp(((time_ns // 60000000000) * 60000000)::BIGINT)::TIMESTAMP AS minute_utc,  -- start of the minute
    source::VARCHAR                                   AS source,        -- radar site id or 'fused'
    count(*)::BIGINT                                  AS samples,       -- synchronised points
    round(quantile_cont(error_m, 0.95), 2)::DOUBLE    AS p95_error_m,   -- 95th percentile, m
    round(sqrt(avg(error_m * error_m)), 2)::DOUBLE    AS rms_error_m    -- RMS horizontal error, m
FROM track_errors
WHERE time_ns >= $start_ns
  AND time_ns < $end_ns
  AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
  AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
GROUP BY site, time_ns // 60000000000, source
ORDER BY site, minute_utc, (source = 'fused') DESC, source;
