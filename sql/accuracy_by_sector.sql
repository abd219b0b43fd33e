-- name: accuracy_by_sector
-- description: horizontal position accuracy of each radar's synchronised picture and of
--   the fused picture, per sector, against the reference: simulated truth when the log
--   has it, else the reconstructed reference (each AIS vessel's smoothed trajectory,
--   issue 37; rows of older batches: the identified ship's own AIS positions), with the
--   reference's own mean 95% error.
-- grain: one row per (site, sector, source, reference)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source table: track_errors (written by `surveil batch`)
WITH points AS (
    SELECT
        site,
        coalesce(sector, '(outside sectors)') AS sector,
        source,
        reference,
        error_m,
        nees,
        reference_p95_m
    FROM track_errors
    WHERE time_ns >= $start_ns
      AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
)
SELECT
    site::VARCHAR                                     AS site,          -- site (deployment)
    sector::VARCHAR                                   AS sector,        -- sector polygon name
    source::VARCHAR                                   AS source,        -- radar site id or 'fused'
    reference::VARCHAR                                AS reference,     -- truth | reconstructed | ais
    count(*)::BIGINT                                  AS samples,       -- synchronised points
    round(sqrt(avg(error_m * error_m)), 2)::DOUBLE    AS rms_error_m,   -- RMS horizontal error, m
    round(quantile_cont(error_m, 0.95), 2)::DOUBLE    AS p95_error_m,   -- 95th percentile, m
    round(max(error_m), 2)::DOUBLE                    AS max_error_m,   -- worst point, m
    round(avg(nees), 3)::DOUBLE                       AS mean_nees,     -- ~2 when sigmas are honest
    round(avg(reference_p95_m), 2)::DOUBLE            AS reference_p95_m  -- the reference's own 95% error, m (0: truth)
FROM points
GROUP BY site, sector, source, reference
ORDER BY site, sector, reference, (source = 'fused') DESC, source;
