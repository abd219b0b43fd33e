-- name: surface_detection_by_area
-- description: probability of a target report per update interval on the airfield
--   (issue 37; ED-87 as encoded in OpenATS COMPASS): per ED-87 area and source, the
--   update intervals ([requirements.ed87_update_period_s]: 1 / 1 / 5 s) of each fused
--   target's life and those with a report of the source. A channel is expected only
--   where it can see: the SMR every target, the MLAT the targets with a Mode S address,
--   the VASN the moving ones (>= 0.5 m/s: it hears engines); 'fused' is a fused update
--   from any channel, judged against [requirements.ed87_report_probability]
--   (0.99 / 0.90 / 0.95). Expected intervals come from the fused targets' lives, so the
--   figures are the same against truth and against the reconstructed reference.
-- grain: one row per (site, area, source)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $ed87_manoeuvring_update_s, $ed87_apron_taxiway_update_s, $ed87_stand_update_s,
--         $ed87_manoeuvring_report_p, $ed87_apron_taxiway_report_p, $ed87_stand_report_p
--         (DOUBLE, from [requirements])
-- source tables: airfield_tracks, channel_health (written by `surveil batch`)
WITH req AS (
    SELECT * FROM (VALUES
        ('manoeuvring', CAST($ed87_manoeuvring_update_s AS DOUBLE), CAST($ed87_manoeuvring_report_p AS DOUBLE)),
        ('apron_taxiway', CAST($ed87_apron_taxiway_update_s AS DOUBLE), CAST($ed87_apron_taxiway_report_p AS DOUBLE)),
        ('stand', CAST($ed87_stand_update_s AS DOUBLE), CAST($ed87_stand_report_p AS DOUBLE)))
        AS r(area, update_s, report_p)
),
trk AS (
    SELECT t.site, t.track_id, t.time_ns, coalesce(t.area, '(outside areas)') AS area,
           t.target_address IS NOT NULL AS addressed,
           sqrt(t.vx_mps * t.vx_mps + t.vy_mps * t.vy_mps) AS speed, t.n_channels,
           t.time_ns // CAST(round(coalesce(r.update_s, 1.0) * 1e9) AS BIGINT) AS slot
    FROM airfield_tracks AS t
    LEFT JOIN req AS r ON r.area = t.area
    WHERE t.time_ns >= $start_ns AND t.time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR t.sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR t.site = CAST($site AS VARCHAR))
),
chan AS (
    SELECT DISTINCT site, channel, sensor_kind
    FROM channel_health
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
),
slots AS (   -- per (target, slot): its area, whether addressed / moving at some epoch of it
    SELECT site, track_id, slot, arg_min(area, time_ns) AS area, bool_or(addressed) AS addressed,
           bool_or(speed >= 0.5) AS moving, bool_or(n_channels > 0) AS fused_update
    FROM trk GROUP BY site, track_id, slot
),
expected AS (
    SELECT s.site, s.area, c.channel AS source, s.track_id, s.slot
    FROM slots AS s JOIN chan AS c USING (site)
    WHERE c.sensor_kind = 'smr' OR (c.sensor_kind = 'mlat' AND s.addressed)
       OR (c.sensor_kind = 'vasn' AND s.moving)
    UNION ALL
    SELECT site, area, 'fused', track_id, slot FROM slots
),
got AS (
    SELECT DISTINCT h.site, h.channel AS source, h.track_id, t.slot
    FROM channel_health AS h
    JOIN trk AS t ON t.site = h.site AND t.track_id = h.track_id AND t.time_ns = h.time_ns
    WHERE h.report_x_m IS NOT NULL
    UNION ALL
    SELECT site, 'fused', track_id, slot FROM slots WHERE fused_update
)
SELECT
    e.site::VARCHAR                                                     AS site,
    e.area::VARCHAR                                                     AS area,
    e.source::VARCHAR                                                   AS source,          -- sensor id or 'fused'
    count(DISTINCT e.track_id)::BIGINT                                  AS targets,
    count(*)::BIGINT                                                    AS expected_intervals,
    count(g.slot)::BIGINT                                               AS reported_intervals,
    round(count(g.slot) / nullif(count(*), 0), 5)::DOUBLE               AS pd,               -- per update interval
    any_value(r.update_s)::DOUBLE                                       AS update_period_s,
    CASE WHEN e.source = 'fused' THEN any_value(r.report_p) END::DOUBLE AS ed87_report_p_req,
    CASE WHEN e.source = 'fused' THEN count(g.slot) / nullif(count(*), 0) >= any_value(r.report_p)
         END::BOOLEAN                                                   AS meets_ed87
FROM expected AS e
LEFT JOIN got AS g USING (site, source, track_id, slot)
LEFT JOIN req AS r ON r.area = e.area
GROUP BY e.site, e.area, e.source
ORDER BY site, area, (source = 'fused') DESC, source;
