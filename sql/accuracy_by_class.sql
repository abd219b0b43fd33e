-- name: accuracy_by_class
-- description: horizontal position accuracy per target class (issue 37): the errors of
--   accuracy_by_sector split by the AIS class of the reference vessel (A / B; 'no AIS'
--   for a vessel without AIS, known from truth only) and by its ship type group from its
--   static data (ITU-R M.1371 ship and cargo type, tens digit: 3x special craft, 5x
--   pilot/tug/port, 6x passenger, 7x cargo, 8x tanker, ...; from its static messages
--   within a day of the window, which AIS repeats every 6 min; '(no static data)' when it
--   sent none). Against simulated truth, else the reconstructed reference.
-- grain: one row per (site, source, reference, AIS class, ship type group)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source tables: track_errors, ais_reports, ais_static
WITH e AS (
    SELECT site, source, reference, reference_mmsi, error_m, reference_p95_m
    FROM track_errors
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
cls AS (
    SELECT site, mmsi, mode(ais_class ORDER BY ais_class) AS ais_class
    FROM ais_reports
    WHERE time_ns >= $start_ns - 3600000000000 AND time_ns < $end_ns
    GROUP BY site, mmsi
),
typ AS (
    SELECT site, mmsi, mode(ship_type ORDER BY ship_type) AS ship_type
    FROM ais_static
    WHERE ship_type IS NOT NULL
      AND time_ns >= $start_ns - 86400000000000 AND time_ns < $end_ns + 86400000000000
    GROUP BY site, mmsi
),
j AS (
    SELECT e.*,
           CASE WHEN e.reference_mmsi IS NULL THEN 'no AIS'
                ELSE coalesce(c.ais_class, '(unknown)') END AS ais_class,
           CASE WHEN e.reference_mmsi IS NULL OR t.ship_type IS NULL THEN '(no static data)'
                ELSE CAST((t.ship_type // 10) * 10 AS VARCHAR) || '-'
                     || CAST((t.ship_type // 10) * 10 + 9 AS VARCHAR) END AS ship_type_group
    FROM e
    LEFT JOIN cls AS c ON c.site = e.site AND c.mmsi = e.reference_mmsi
    LEFT JOIN typ AS t ON t.site = e.site AND t.mmsi = e.reference_mmsi
)
SELECT
    site::VARCHAR                                     AS site,
    source::VARCHAR                                   AS source,          -- radar site id or 'fused'
    reference::VARCHAR                                AS reference,       -- truth | reconstructed
    ais_class::VARCHAR                                AS ais_class,       -- A | B | no AIS
    ship_type_group::VARCHAR                          AS ship_type_group, -- ITU-R M.1371 type code range
    count(DISTINCT reference_mmsi)::BIGINT            AS vessels,         -- with an MMSI
    count(*)::BIGINT                                  AS samples,
    round(sqrt(avg(error_m * error_m)), 2)::DOUBLE    AS rms_error_m,
    round(quantile_cont(error_m, 0.95), 2)::DOUBLE    AS p95_error_m,
    round(avg(reference_p95_m), 2)::DOUBLE            AS reference_p95_m  -- the reference's own 95% error
FROM j
GROUP BY site, source, reference, ais_class, ship_type_group
ORDER BY site, reference, (source = 'fused') DESC, source, ais_class, ship_type_group;
