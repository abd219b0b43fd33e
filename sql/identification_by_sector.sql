-- name: identification_by_sector
-- description: share of fused-track time with the correct MMSI, a wrong MMSI or no MMSI,
--   per sector. With truth, "correct" means the MMSI of the simulated vessel the fused
--   point follows; ships without AIS count as correct when they carry no MMSI. The vessel
--   a point follows: where the nearest vessel (track_errors) is not the one whose MMSI it
--   carries, the vessel most of its fused radar members' local tracks were scored against
--   over the window (a radar tracker's track follows one ship; ties: the smaller id), so
--   a ship sailing closer to another than the track's error does not flip the verdict
--   from epoch to epoch (docs/maritime.md, "Two judges"); elsewhere the nearest. Without
--   truth, against the reconstructed reference (issue 37: the AIS vessel the fused point
--   was scored against), "correct" means that vessel's MMSI and "wrong" another one: the
--   probabilities of correct and of false identification (ships without AIS have no
--   reference then and are not counted). Rows of older batches (reference ais):
--   "correct" means consistent, the track's majority MMSI in the window.
--   Fused points come at uniform synchronised epochs, so shares of points are shares of time.
-- grain: one row per (site, sector, vessel_class, reference)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source tables: system_tracks, track_errors, associations (written by `surveil batch`)
WITH fused AS (
    SELECT
        s.site,
        s.time_ns,
        s.system_track_id,
        coalesce(s.sector, '(outside sectors)') AS sector,
        s.mmsi,
        e.reference,
        e.reference_mmsi
    FROM system_tracks AS s
    JOIN track_errors AS e
      ON e.site = s.site
     AND e.time_ns = s.time_ns
     AND e.system_track_id = s.system_track_id
     AND e.source = 'fused'
    WHERE s.time_ns >= $start_ns
      AND s.time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR s.sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR s.site = CAST($site AS VARCHAR))
),
suspect AS (  -- points the nearest vessel judges not correct: the followed one decides
    SELECT site, time_ns, system_track_id
    FROM fused
    WHERE reference = 'truth' AND mmsi IS DISTINCT FROM reference_mmsi
),
members AS (  -- their fused radar members
    SELECT a.site, a.time_ns, a.system_track_id, a.site_id, a.local_track_id
    FROM associations AS a
    SEMI JOIN suspect AS s USING (site, time_ns, system_track_id)
    WHERE a.time_ns >= $start_ns AND a.time_ns < $end_ns AND a.used
),
owner AS (  -- the vessel each of their local tracks was scored against most often
    SELECT a.site, a.site_id, a.local_track_id,
           mode(e.reference_id ORDER BY e.reference_id) AS vessel_id
    FROM associations AS a
    SEMI JOIN (SELECT DISTINCT site, site_id, local_track_id FROM members) AS m
        USING (site, site_id, local_track_id)
    JOIN track_errors AS e
      ON e.site = a.site
     AND e.time_ns = a.time_ns
     AND e.system_track_id = a.system_track_id
     AND e.source = a.site_id
    WHERE a.time_ns >= $start_ns AND a.time_ns < $end_ns
      AND e.time_ns >= $start_ns AND e.time_ns < $end_ns
      AND e.reference = 'truth'
    GROUP BY a.site, a.site_id, a.local_track_id
),
followed AS (
    SELECT m.site, m.time_ns, m.system_track_id,
           mode(o.vessel_id ORDER BY o.vessel_id) AS vessel_id
    FROM members AS m
    JOIN owner AS o USING (site, site_id, local_track_id)
    GROUP BY m.site, m.time_ns, m.system_track_id
),
vessel AS (  -- the MMSI of each followed vessel (null: no AIS aboard)
    SELECT DISTINCT e.site, e.reference_id AS vessel_id, e.reference_mmsi AS mmsi
    FROM track_errors AS e
    SEMI JOIN (SELECT DISTINCT site, vessel_id FROM followed) AS f
        ON f.site = e.site AND f.vessel_id = e.reference_id
    WHERE e.time_ns >= $start_ns AND e.time_ns < $end_ns
      AND e.reference = 'truth' AND e.source = 'fused'
),
judged_fused AS (
    SELECT f.site, f.time_ns, f.system_track_id, f.sector, f.mmsi, f.reference,
           CASE WHEN fo.vessel_id IS NULL THEN f.reference_mmsi ELSE v.mmsi END
               AS reference_mmsi
    FROM fused AS f
    LEFT JOIN followed AS fo USING (site, time_ns, system_track_id)
    LEFT JOIN vessel AS v ON v.site = fo.site AND v.vessel_id = fo.vessel_id
),
majority AS (
    SELECT site, system_track_id, mode(mmsi ORDER BY mmsi) AS majority_mmsi
    FROM fused
    WHERE mmsi IS NOT NULL
    GROUP BY site, system_track_id
),
judged AS (
    SELECT
        f.site,
        f.sector,
        CASE
            WHEN f.reference = 'ais' THEN 'ais-identified (no truth)'
            WHEN f.reference_mmsi IS NULL THEN 'no AIS aboard'
            ELSE 'AIS aboard'
        END AS vessel_class,
        CASE
            WHEN f.reference = 'truth' AND f.reference_mmsi IS NULL
                THEN CASE WHEN f.mmsi IS NULL THEN 'correct' ELSE 'wrong' END
            WHEN f.mmsi IS NULL THEN 'none'
            WHEN f.reference = 'truth' AND f.mmsi = f.reference_mmsi THEN 'correct'
            WHEN f.reference = 'reconstructed' AND f.mmsi = f.reference_mmsi THEN 'correct'
            WHEN f.reference = 'ais' AND f.mmsi = m.majority_mmsi THEN 'correct'
            ELSE 'wrong'
        END AS verdict,
        f.reference
    FROM judged_fused AS f
    LEFT JOIN majority AS m USING (site, system_track_id)
)
SELECT
    site::VARCHAR                                                     AS site,
    sector::VARCHAR                                                   AS sector,
    vessel_class::VARCHAR                                             AS vessel_class,
    reference::VARCHAR                                                AS reference,     -- truth | reconstructed | ais
    count(*)::BIGINT                                                  AS samples,       -- fused points
    round(avg(CASE WHEN verdict = 'correct' THEN 1 ELSE 0 END), 4)::DOUBLE AS correct_share,
    round(avg(CASE WHEN verdict = 'wrong' THEN 1 ELSE 0 END), 4)::DOUBLE   AS wrong_share,
    round(avg(CASE WHEN verdict = 'none' THEN 1 ELSE 0 END), 4)::DOUBLE    AS none_share
FROM judged
GROUP BY site, sector, vessel_class, reference
ORDER BY site, sector, vessel_class, reference;
