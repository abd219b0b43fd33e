-- name: radar_coverage
-- description: coverage map of each radar (issue 37): probability of detection from its
--   update intervals per range/azimuth cell of the radar (cells of [reference]
--   coverage_range_bin_m by coverage_azimuth_bin_deg, azimuth clockwise from true north),
--   against simulated truth when the log has it, else the reconstructed references. A
--   blind sector or a range hole is a run of cells with low PD; `hole` marks a cell below
--   $hole_pd with at least $min_scans expected scans.
-- grain: one row per (site, radar, reference, range cell, azimuth cell)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $hole_pd (DOUBLE, default 0.5), $min_scans (BIGINT, default 20)
-- source table: radar_detection (written by `surveil batch`)
SELECT
    site::VARCHAR                                              AS site,            -- site (deployment)
    site_id::VARCHAR                                           AS radar,           -- radar site
    reference::VARCHAR                                         AS reference,       -- truth | reconstructed
    range_bin_m::DOUBLE                                        AS range_from_m,    -- cell: range from, m
    azimuth_bin_deg::DOUBLE                                    AS azimuth_from_deg, -- cell: azimuth from, deg
    count(DISTINCT reference_id)::BIGINT                       AS targets,         -- referenced targets seen in the cell
    sum(expected_scans)::BIGINT                                AS expected_scans,
    sum(detected_scans)::BIGINT                                AS detected_scans,
    round(sum(detected_scans) / nullif(sum(expected_scans), 0), 4)::DOUBLE AS pd,
    (sum(expected_scans) >= $min_scans
     AND sum(detected_scans) / nullif(sum(expected_scans), 0) < $hole_pd)::BOOLEAN AS hole
FROM radar_detection
WHERE time_ns >= $start_ns
  AND time_ns < $end_ns
  AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
  AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
GROUP BY site, site_id, reference, range_bin_m, azimuth_bin_deg
ORDER BY site, radar, reference, range_from_m, azimuth_from_deg;
