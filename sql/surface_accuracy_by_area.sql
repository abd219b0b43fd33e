-- name: surface_accuracy_by_area
-- description: airfield surface surveillance accuracy per ED-87 area (manoeuvring area,
--   apron taxiways, stands): 95th-percentile horizontal error of each channel's reports and
--   of the fused tracks against the reference, probability of identification (fused, over
--   cooperative targets), share of updates after a gap of 3-5 s and of more than 5 s, beside
--   the ED-87 requirements per area and the sensor level (ED-116/117), bound from the
--   config's [requirements] (shipped: 95% <= 12 / 20 / 25 m, 7.5 m; P(ID) >= 0.999).
-- grain: one row per (site, area, source); source = a channel's sensor id or 'fused'
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $ed87_manoeuvring_p95_m, $ed87_apron_taxiway_p95_m, $ed87_stand_p95_m,
--         $sensor_p95_m, $p_identification_min (DOUBLE, from [requirements])
-- source tables: airfield_tracks, channel_health (written by `surveil batch`)
WITH updates AS (   -- one row per update of a target by a source
    SELECT site, coalesce(area, '(outside areas)') AS area, channel AS source, track_id, time_ns,
           error_m, CAST(NULL AS BOOLEAN) AS identity_correct, CAST(NULL AS BOOLEAN) AS cooperative,
           coalesce(error_model, 'config') AS error_model
    FROM channel_health
    WHERE report_x_m IS NOT NULL
      AND time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
    UNION ALL
    SELECT site, coalesce(area, '(outside areas)'), 'fused', track_id, time_ns, error_m,
           identity_correct, cooperative, NULL
    FROM airfield_tracks
    WHERE n_channels > 0
      AND time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
gaps AS (
    SELECT *, (time_ns - lag(time_ns) OVER (PARTITION BY site, source, track_id ORDER BY time_ns)) / 1e9 AS gap_s
    FROM updates
),
req AS (
    SELECT * FROM (VALUES ('manoeuvring', CAST($ed87_manoeuvring_p95_m AS DOUBLE)),
                          ('apron_taxiway', CAST($ed87_apron_taxiway_p95_m AS DOUBLE)),
                          ('stand', CAST($ed87_stand_p95_m AS DOUBLE)))
        AS r(area, ed87_p95_m)
)
SELECT
    g.site::VARCHAR                                                           AS site,              -- site (deployment)
    g.area::VARCHAR                                                           AS area,              -- manoeuvring | apron_taxiway | stand
    g.source::VARCHAR                                                         AS source,            -- sensor id or 'fused'
    count(*)::BIGINT                                                          AS updates,           -- target updates
    count(g.error_m)::BIGINT                                                  AS scored,            -- updates with a reference
    round(quantile_cont(g.error_m, 0.95), 2)::DOUBLE                          AS p95_error_m,       -- 95th percentile error, m
    round(sqrt(avg(g.error_m * g.error_m)), 2)::DOUBLE                        AS rms_error_m,       -- RMS error, m
    any_value(r.ed87_p95_m)::DOUBLE                                           AS ed87_p95_req_m,    -- ED-87 95% requirement, m
    (quantile_cont(g.error_m, 0.95) <= any_value(r.ed87_p95_m))::BOOLEAN      AS meets_ed87,        -- p95 within it
    CAST($sensor_p95_m AS DOUBLE)                                             AS sensor_p95_req_m,  -- ED-116/117 sensor level, m
    (quantile_cont(g.error_m, 0.95) <= CAST($sensor_p95_m AS DOUBLE))::BOOLEAN AS meets_sensor_level,
    round(avg(CASE WHEN g.identity_correct THEN 1.0 ELSE 0.0 END)
          FILTER (WHERE g.cooperative), 5)::DOUBLE                            AS p_identification,  -- fused, cooperative targets
    (count(*) FILTER (WHERE g.cooperative))::BIGINT                           AS id_samples,        -- updates behind p_identification
    CAST($p_identification_min AS DOUBLE)                                     AS p_id_req,          -- ED-87
    (avg(CASE WHEN g.identity_correct THEN 1.0 ELSE 0.0 END) FILTER (WHERE g.cooperative)
        >= CAST($p_identification_min AS DOUBLE))::BOOLEAN                    AS meets_p_id,        -- NULL: no cooperative target
    round(avg(CASE WHEN g.gap_s >= 3 AND g.gap_s <= 5 THEN 1.0 ELSE 0.0 END)
          FILTER (WHERE g.gap_s IS NOT NULL), 5)::DOUBLE                      AS gap_3_5s_share,    -- updates after a 3-5 s gap
    round(avg(CASE WHEN g.gap_s > 5 THEN 1.0 ELSE 0.0 END)
          FILTER (WHERE g.gap_s IS NOT NULL), 5)::DOUBLE                      AS gap_over_5s_share, -- updates after a > 5 s gap
    CASE WHEN g.source = 'fused'
         THEN (SELECT string_agg(DISTINCT channel || ': ' || coalesce(error_model, 'config'), '; '
                                 ORDER BY channel || ': ' || coalesce(error_model, 'config'))
               FROM channel_health AS c
               WHERE c.site = g.site AND c.time_ns >= $start_ns AND c.time_ns < $end_ns)
         ELSE string_agg(DISTINCT g.error_model, '; ') END::VARCHAR           AS error_model        -- the channel's error model: config, fit [..] (surveil calibrate) or 'default ...' (its kind's, scaled to the data); fused: every channel's
FROM gaps AS g
LEFT JOIN req AS r ON r.area = g.area
GROUP BY g.site, g.area, g.source
ORDER BY g.site, g.area, (g.source = 'fused') DESC, g.source;
