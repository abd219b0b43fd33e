-- name: latency_by_sensor
-- description: latency of each radar and of the fused picture (issue 37, as OpenATS
--   COMPASS estimates it): a source whose positions are late by dt lies dt x speed
--   behind the reference along its course, so latency = -along-track error / speed,
--   here the least-squares slope -sum(a v) / sum(v^2) over the points whose reference
--   moves at >= $min_speed_mps (a clock offset, a late time stamp, a slow tracker), with
--   its standard error and 95 % interval; against simulated truth, else the
--   reconstructed reference.
-- grain: one row per (site, source, reference)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $min_speed_mps (DOUBLE, default 2)
-- source table: track_errors (written by `surveil batch`)
WITH fit AS (   -- one pass: the slope and, from the same sums, the residual variance
    SELECT site, source, reference, count(*) AS n, sum(v * v) AS svv, sum(a * v) AS sav,
           sum(a * a) AS saa
    FROM (SELECT site, source, reference, along_track_error_m AS a, reference_speed_mps AS v
          FROM track_errors
          WHERE time_ns >= $start_ns
            AND time_ns < $end_ns
            AND along_track_error_m IS NOT NULL
            AND reference_speed_mps >= $min_speed_mps
            AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
            AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR)))
    GROUP BY site, source, reference
),
est AS (   -- a = -latency v + noise: latency = -sav / svv, residual sum saa - sav^2 / svv
    SELECT *, -sav / nullif(svv, 0) AS latency_s,
           greatest(saa - sav * sav / nullif(svv, 0), 0) / nullif(n - 1, 0) AS s2
    FROM fit
)
SELECT
    site::VARCHAR                                          AS site,          -- site (deployment)
    source::VARCHAR                                        AS source,        -- radar site id or 'fused'
    reference::VARCHAR                                     AS reference,     -- truth | reconstructed
    n::BIGINT                                              AS samples,       -- moving points
    round(latency_s, 3)::DOUBLE                            AS latency_s,     -- > 0: positions late
    round(sqrt(s2 / svv), 3)::DOUBLE                       AS latency_se_s,  -- standard error
    round(latency_s - 1.96 * sqrt(s2 / svv), 3)::DOUBLE    AS latency_ci_low_s,
    round(latency_s + 1.96 * sqrt(s2 / svv), 3)::DOUBLE    AS latency_ci_high_s
FROM est
ORDER BY site, reference, (source = 'fused') DESC, source;
