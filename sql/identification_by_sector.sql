-- name: identification_by_sector
-- description: share of fused-track time with the correct MMSI, a wrong MMSI or no MMSI,
--   per sector. With truth, "correct" means the MMSI of the simulated vessel the fused
--   point follows; ships without AIS count as correct when they carry no MMSI. The vessel
--   a point follows: where it carries an MMSI that is not the nearest vessel's
--   (track_errors), the vessel most of its fused radar members' local tracks were
--   scored against over the window (the vessels of the fused points they were in) (a radar tracker's track follows one ship; ties: the
--   smaller id), so
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
WITH scored AS (  -- the window's scored fused points, every sector (owners span them)
    SELECT
        s.site,
        s.time_ns,
        s.system_track_id,
        s.sector AS raw_sector,
        coalesce(s.sector, '(outside sectors)') AS sector,
        s.mmsi,
        e.reference,
        e.reference_id,
        e.reference_mmsi
    FROM system_tracks AS s
    JOIN track_errors AS e
      ON e.site = s.site
     AND e.time_ns = s.time_ns
     AND e.system_track_id = s.system_track_id
     AND e.source = 'fused'
    WHERE s.time_ns >= $start_ns
      AND s.time_ns < $end_ns
      AND (CAST($site AS VARCHAR) IS NULL OR s.site = CAST($site AS VARCHAR))
),
fused AS (
    SELECT * FROM scored
    WHERE CAST($sector AS VARCHAR) IS NULL OR raw_sector = CAST($sector AS VARCHAR)
),
suspect AS (  -- points the nearest vessel judges wrong: the followed one decides
    SELECT site, time_ns, system_track_id
    FROM fused
    WHERE reference = 'truth' AND mmsi IS NOT NULL AND mmsi IS DISTINCT FROM reference_mmsi
),
members AS (  -- their fused radar members
    SELECT a.site, a.time_ns, a.system_track_id, a.site_id, a.local_track_id
    FROM associations AS a
    SEMI JOIN suspect AS s USING (site, time_ns, system_track_id)
    WHERE a.time_ns >= $start_ns AND a.time_ns < $end_ns AND a.used
),
owner AS (  -- the vessel each of their local tracks was scored against most often (a
            -- radar point is scored against its fused point's vessel)
    SELECT a.site, a.site_id, a.local_track_id,
           mode(sc.reference_id ORDER BY sc.reference_id) AS vessel_id
    FROM associations AS a
    SEMI JOIN (SELECT DISTINCT site, site_id, local_track_id FROM members) AS m
        USING (site, site_id, local_track_id)
    JOIN scored AS sc USING (site, time_ns, system_track_id)
    WHERE a.time_ns >= $start_ns AND a.time_ns < $end_ns AND sc.reference = 'truth'
    GROUP BY a.site, a.site_id, a.local_track_id
),
followed AS (
    SELECT m.site, m.time_ns, m.system_track_id,
           mode(o.vessel_id ORDER BY o.vessel_id) AS vessel_id
    FROM members AS m
    JOIN owner AS o USING (site, site_id, local_track_id)
    GROUP BY m.site, m.time_ns, m.system_track_id
),
vessel AS (  -- the MMSI of each followed vessel (null: no AIS aboard), one row each
    SELECT sc.site, sc.reference_id AS vessel_id, min(sc.reference_mmsi) AS mmsi
    FROM scored AS sc
    SEMI JOIN (SELECT DISTINCT site, vessel_id FROM followed) AS f
        ON f.site = sc.site AND f.vessel_id = sc.reference_id
    WHERE sc.reference = 'truth'
    GROUP BY sc.site, sc.reference_id
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
