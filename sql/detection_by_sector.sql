-- name: detection_by_sector
-- description: probability of detection of each radar from its update intervals, as
--   OpenATS COMPASS counts it (issue 37): the scans expected while a referenced target was
--   within the radar's range and those with an update of it, PD = detected / expected,
--   per radar, sector and target class (AIS class A / B; 'none': a vessel without AIS,
--   known from truth only) and over all classes; against simulated truth when the log has
--   it, else the reconstructed references (vessels carrying AIS). Beside the VTS figure of
--   [requirements.vts] (IMO MSC.192(79): a target is tracked when seen on 5 of 10 scans,
--   PD per scan >= 0.5) and whether it is met.
-- grain: one row per (site, sector, radar, reference, target class), plus '(all classes)'
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $vts_min_detection (DOUBLE, from [requirements])
-- source table: radar_detection (written by `surveil batch`)
WITH cells AS (
    SELECT site, coalesce(sector, '(outside sectors)') AS sector, site_id, reference,
           coalesce(target_class, '(unknown)') AS target_class, reference_id,
           expected_scans, detected_scans
    FROM radar_detection
    WHERE time_ns >= $start_ns
      AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
sums AS (
    SELECT site, sector, site_id, reference,
           coalesce(target_class, '(all classes)') AS target_class,
           count(DISTINCT reference_id) AS targets,
           sum(expected_scans) AS expected, sum(detected_scans) AS detected
    FROM cells
    GROUP BY GROUPING SETS ((site, sector, site_id, reference, target_class),
                            (site, sector, site_id, reference))
)
SELECT
    site::VARCHAR                                            AS site,           -- site (deployment)
    sector::VARCHAR                                          AS sector,         -- sector of the target at the scan
    site_id::VARCHAR                                         AS radar,          -- radar site
    reference::VARCHAR                                       AS reference,      -- truth | reconstructed
    target_class::VARCHAR                                    AS target_class,   -- A | B | none | (all classes)
    targets::BIGINT                                          AS targets,        -- referenced targets in range
    expected::BIGINT                                         AS expected_scans, -- scans while in range
    (expected - detected)::BIGINT                            AS missed_scans,   -- scans without an update
    round(detected / nullif(expected, 0), 5)::DOUBLE         AS pd,             -- probability of detection per scan
    CAST($vts_min_detection AS DOUBLE)                       AS pd_req,         -- IMO MSC.192(79): 5 of 10 scans
    (detected / nullif(expected, 0) >= CAST($vts_min_detection AS DOUBLE))::BOOLEAN AS meets_vts
FROM sums
ORDER BY site, sector, radar, reference, (target_class = '(all classes)') DESC, target_class;
