-- name: target_drilldown
-- description: the referenced targets that cost the verdicts most, worst first (issue
--   37): per target, its fused points scored and their RMS / 95th percentile / worst
--   error, the radar points scored, the radars' missed scans of it and their PD, and the
--   changes of its fused track number; ordered by the 95th percentile of its fused error
--   (then missed scans). Against simulated truth, else the reconstructed reference
--   (reference_id: truth vessel id, or MMSI).
-- grain: one row per (site, reference, target), the $top worst per site
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $top (BIGINT, default 20)
-- source tables: track_errors, radar_detection (written by `surveil batch`)
WITH e AS (
    SELECT site, reference, reference_id, source, time_ns, system_track_id, error_m,
           coalesce(sector, '(outside sectors)') AS sector
    FROM track_errors
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
fused AS (
    SELECT site, reference, reference_id, mode(sector ORDER BY sector) AS sector, count(*) AS fused_points,
           sqrt(avg(error_m * error_m)) AS rms, quantile_cont(error_m, 0.95) AS p95,
           max(error_m) AS worst, count(DISTINCT system_track_id) AS system_tracks
    FROM e WHERE source = 'fused'
    GROUP BY site, reference, reference_id
),
radar AS (
    SELECT site, reference, reference_id, count(*) AS radar_points
    FROM e WHERE source <> 'fused'
    GROUP BY site, reference, reference_id
),
det AS (
    SELECT site, reference, reference_id, sum(expected_scans) AS expected,
           sum(detected_scans) AS detected
    FROM radar_detection
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
    GROUP BY site, reference, reference_id
),
ranked AS (
    SELECT f.*, coalesce(r.radar_points, 0) AS radar_points, d.expected, d.detected,
           row_number() OVER (PARTITION BY f.site ORDER BY f.p95 DESC,
                              coalesce(d.expected - d.detected, 0) DESC, f.reference_id) AS rank
    FROM fused AS f
    LEFT JOIN radar AS r USING (site, reference, reference_id)
    LEFT JOIN det AS d USING (site, reference, reference_id)
)
SELECT
    site::VARCHAR                                           AS site,
    rank::BIGINT                                            AS rank,            -- 1 = worst
    reference::VARCHAR                                      AS reference,       -- truth | reconstructed
    reference_id::BIGINT                                    AS reference_id,    -- truth vessel id or MMSI
    sector::VARCHAR                                         AS sector,          -- its most frequent sector
    fused_points::BIGINT                                    AS fused_points,
    round(rms, 2)::DOUBLE                                   AS rms_error_m,
    round(p95, 2)::DOUBLE                                   AS p95_error_m,
    round(worst, 2)::DOUBLE                                 AS max_error_m,
    radar_points::BIGINT                                    AS radar_points,
    (expected - detected)::BIGINT                           AS missed_scans,    -- all radars
    round(detected / nullif(expected, 0), 4)::DOUBLE        AS pd,
    (system_tracks - 1)::BIGINT                             AS extra_track_numbers -- system tracks beyond the first
FROM ranked
WHERE rank <= $top
ORDER BY site, rank;
