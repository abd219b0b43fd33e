-- name: cross_track_by_leg
-- description: cross-track deviation error from the fairway axis per leg, for each radar
--   and for the fused picture (multi-radar paper eq. 1-6, figures 1-2): RMS of the error,
--   the 60-s sliding RMS (mean, 95th percentile, worst), the expected sigma, and each
--   radar's observation aspect (0 deg = looking along the fairway) and range. The last
--   column compares, at each epoch where the fused point and every radar of the track are
--   present, the fused 60-s RMS with the best radar's.
-- grain: one row per (site, leg, source)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source table: cross_track_by_leg (written by `surveil batch`)
WITH best AS (   -- per epoch and track: fused sliding RMS vs the best radar's
    SELECT
        site,
        leg_id,
        max(CASE WHEN source = 'fused' THEN rms_error_60s_m END)   AS fused_rms,
        min(CASE WHEN source <> 'fused' THEN rms_error_60s_m END)  AS best_radar_rms,
        max(CASE WHEN source = 'fused' THEN n_sources END)         AS n_fused,
        count(*) FILTER (WHERE source <> 'fused')                  AS n_radars
    FROM (   -- each aggregate reads the table itself: a CTE read twice is materialised
             -- by DuckDB, a day's 49 M rows held in memory (sql/README.md)
        SELECT site, time_ns, system_track_id, leg_id, source, n_sources, rms_error_60s_m
        FROM cross_track_by_leg
        WHERE time_ns >= $start_ns
          AND time_ns < $end_ns
          AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
          AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
    )
    GROUP BY site, time_ns, system_track_id, leg_id
),
share AS (
    SELECT site, leg_id,
           avg(CASE WHEN fused_rms <= best_radar_rms THEN 1.0 ELSE 0.0 END) AS not_worse
    FROM best
    WHERE fused_rms IS NOT NULL AND n_radars >= 2 AND n_fused = n_radars
    GROUP BY site, leg_id
)
SELECT
    p.site::VARCHAR                                               AS site,
    p.leg_id::VARCHAR                                             AS leg_id,
    p.source::VARCHAR                                             AS source,          -- site id or 'fused'
    count(*)::BIGINT                                              AS samples,
    round(sqrt(avg(p.cross_track_error_m ^ 2)), 2)::DOUBLE         AS rms_error_m,     -- all points of the leg
    round(avg(p.rms_error_60s_m), 2)::DOUBLE                      AS mean_rms_60s_m,
    round(quantile_cont(p.rms_error_60s_m, 0.95), 2)::DOUBLE      AS p95_rms_60s_m,
    round(max(p.rms_error_60s_m), 2)::DOUBLE                      AS max_rms_60s_m,
    round(sqrt(avg(p.sigma_cross_track_m ^ 2)), 2)::DOUBLE        AS rms_sigma_m,     -- expected, eq. 2-4
    round(avg(p.aspect_deg), 1)::DOUBLE                           AS mean_aspect_deg, -- radars only
    round(min(p.range_m))::DOUBLE                                 AS min_range_m,
    round(max(p.range_m))::DOUBLE                                 AS max_range_m,
    CASE WHEN p.source = 'fused' THEN round(any_value(s.not_worse), 4) END::DOUBLE
                                                                  AS fused_not_worse_share
FROM (
    SELECT site, time_ns, system_track_id, leg_id, source, n_sources, cross_track_error_m,
           rms_error_60s_m, sigma_cross_track_m, aspect_deg, range_m
    FROM cross_track_by_leg
    WHERE time_ns >= $start_ns
      AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
) AS p
LEFT JOIN share AS s USING (site, leg_id)
GROUP BY p.site, p.leg_id, p.source
ORDER BY p.site, p.leg_id, (p.source = 'fused') DESC, p.source;
