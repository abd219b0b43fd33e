-- name: false_tracks
-- description: false and extra targets (issue 37): system tracks that never had a
--   reference (no truth vessel, or no reconstructed reference, within the scoring gate
--   at any of their epochs) and the share of track time without a reference, per sector.
--   Against the reconstructed reference a track without one is either false or a vessel
--   without AIS (the reference column says which reference the window was scored
--   against); against truth it is false.
-- grain: one row per (site, sector)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source tables: system_tracks, track_errors (written by `surveil batch`)
WITH st AS (
    SELECT site, time_ns, system_track_id, coalesce(sector, '(outside sectors)') AS sector
    FROM system_tracks
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
scored AS (
    SELECT DISTINCT site, time_ns, system_track_id, reference
    FROM track_errors
    WHERE source = 'fused' AND time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
kind AS (SELECT site, mode(reference ORDER BY reference) AS reference FROM scored GROUP BY site),
per_track AS (
    SELECT s.site, s.system_track_id, mode(s.sector ORDER BY s.sector) AS sector, count(*) AS epochs,
           count(e.time_ns) AS scored_epochs
    FROM st AS s
    LEFT JOIN scored AS e USING (site, time_ns, system_track_id)
    GROUP BY s.site, s.system_track_id
)
SELECT
    t.site::VARCHAR                                                   AS site,
    t.sector::VARCHAR                                                 AS sector,           -- the track's most frequent sector
    coalesce(any_value(k.reference), '(none)')::VARCHAR               AS reference,        -- truth | reconstructed | (none)
    count(*)::BIGINT                                                  AS tracks,
    (count(*) FILTER (WHERE t.scored_epochs = 0))::BIGINT             AS tracks_without_reference,
    round(avg(CASE WHEN t.scored_epochs = 0 THEN 1.0 ELSE 0.0 END), 4)::DOUBLE AS false_track_share,
    sum(t.epochs)::BIGINT                                             AS track_epochs,
    round(1.0 - sum(t.scored_epochs) / nullif(sum(t.epochs), 0), 4)::DOUBLE
                                                                      AS unreferenced_epoch_share
FROM per_track AS t
LEFT JOIN kind AS k USING (site)
GROUP BY t.site, t.sector
ORDER BY site, sector;
