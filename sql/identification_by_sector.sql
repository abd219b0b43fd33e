-- name: identification_by_sector
-- description: share of fused-track time with the correct MMSI, a wrong MMSI or no MMSI,
--   per sector. With truth, "correct" means the MMSI of the simulated vessel the fused
--   point belongs to; ships without AIS count as correct when they carry no MMSI. Without
--   truth, against the reconstructed reference (issue 37: the AIS vessel the fused point
--   was scored against), "correct" means that vessel's MMSI and "wrong" another one: the
--   probabilities of correct and of false identification (ships without AIS have no
--   reference then and are not counted). Rows of older batches (reference ais):
--   "correct" means consistent, the track's majority MMSI in the window.
--   Fused points come at uniform synchronised epochs, so shares of points are shares of time.
-- grain: one row per (site, sector, vessel_class, reference)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source tables: system_tracks, track_errors (written by `surveil batch`)
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
    FROM fused AS f
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
