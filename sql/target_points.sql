-- name: target_points
-- description: the tracks of the $top worst referenced targets of target_drilldown for
--   the audit's drill-down map (issue 37): at each scored epoch the reference position
--   and the fused position (regional ENU), thinned to one point per target every
--   $step_s seconds.
-- grain: one row per (site, target, thinned epoch)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $top (BIGINT, default 5), $step_s (DOUBLE, default 20, >= 0.001)
-- source tables: track_errors, system_tracks (written by `surveil batch`)
WITH e AS (
    SELECT t.site, t.reference, t.reference_id, t.time_ns, t.system_track_id, t.error_m,
           s.x_enu_m, s.y_enu_m, t.error_east_m, t.error_north_m
    FROM track_errors AS t
    JOIN system_tracks AS s
      ON s.site = t.site AND s.time_ns = t.time_ns AND s.system_track_id = t.system_track_id
    WHERE t.source = 'fused' AND t.time_ns >= $start_ns AND t.time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR t.sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR t.site = CAST($site AS VARCHAR))
),
worst AS (
    SELECT site, reference, reference_id,
           row_number() OVER (PARTITION BY site ORDER BY quantile_cont(error_m, 0.95) DESC,
                              reference_id) AS rank
    FROM e GROUP BY site, reference, reference_id
)
SELECT
    e.site::VARCHAR                                     AS site,
    w.rank::BIGINT                                      AS rank,          -- 1 = worst
    e.reference_id::BIGINT                              AS reference_id,
    min(e.time_ns)::BIGINT                              AS time_ns,
    arg_min(e.x_enu_m - e.error_east_m, e.time_ns)::DOUBLE  AS reference_x_m,  -- regional ENU
    arg_min(e.y_enu_m - e.error_north_m, e.time_ns)::DOUBLE AS reference_y_m,
    arg_min(e.x_enu_m, e.time_ns)::DOUBLE               AS fused_x_m,
    arg_min(e.y_enu_m, e.time_ns)::DOUBLE               AS fused_y_m,
    arg_min(e.error_m, e.time_ns)::DOUBLE               AS error_m
FROM e JOIN worst AS w USING (site, reference, reference_id)
WHERE w.rank <= $top
GROUP BY e.site, w.rank, e.reference_id, e.time_ns // CAST(round($step_s * 1e9) AS BIGINT)
ORDER BY site, rank, time_ns;
