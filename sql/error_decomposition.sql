-- name: error_decomposition
-- description: position error decomposed (issue 37): along and across the reference's
--   course (mean = bias, RMS) for every source, and for each radar its range error and
--   azimuth error seen from its site (mean, RMS, 95th percentile of the magnitude),
--   against simulated truth, else the reconstructed reference. Beside the VTS figures of
--   [requirements.vts] (IMO MSC.192(79): 95 % of ranges within 50 m or 1 % of the range,
--   bearings within 2 deg): the share of a radar's points within the range limit and
--   whether its bearing 95th percentile is within the limit.
-- grain: one row per (site, sector, source, reference)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $vts_range_p95_m, $vts_range_p95_share, $vts_bearing_p95_deg (DOUBLE, from [requirements])
-- source table: track_errors (written by `surveil batch`)
WITH pts AS (
    SELECT site, coalesce(sector, '(outside sectors)') AS sector, source, reference,
           along_track_error_m AS al, across_track_error_m AS ac, range_error_m AS re,
           degrees(azimuth_error_rad) AS ae, reference_range_m AS rr
    FROM track_errors
    WHERE time_ns >= $start_ns
      AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
)
SELECT
    site::VARCHAR                                        AS site,                  -- site (deployment)
    sector::VARCHAR                                      AS sector,
    source::VARCHAR                                      AS source,                -- radar site id or 'fused'
    reference::VARCHAR                                   AS reference,             -- truth | reconstructed
    count(*)::BIGINT                                     AS samples,
    count(al)::BIGINT                                    AS moving_samples,        -- reference at >= 0.5 m/s
    round(avg(al), 2)::DOUBLE                            AS along_mean_m,          -- > 0: ahead of the target
    round(sqrt(avg(al * al)), 2)::DOUBLE                 AS along_rms_m,
    round(avg(ac), 2)::DOUBLE                            AS across_mean_m,         -- > 0: to its starboard
    round(sqrt(avg(ac * ac)), 2)::DOUBLE                 AS across_rms_m,
    round(avg(re), 2)::DOUBLE                            AS range_mean_m,          -- radars: > 0 too far
    round(sqrt(avg(re * re)), 2)::DOUBLE                 AS range_rms_m,
    round(quantile_cont(abs(re), 0.95), 2)::DOUBLE       AS range_p95_m,
    round(avg(CASE WHEN abs(re) <= greatest(CAST($vts_range_p95_m AS DOUBLE),
                                            CAST($vts_range_p95_share AS DOUBLE) * rr)
                   THEN 1.0 ELSE 0.0 END) FILTER (WHERE re IS NOT NULL), 4)::DOUBLE
                                                         AS range_within_vts_share, -- IMO: >= 0.95
    round(avg(ae), 4)::DOUBLE                            AS azimuth_mean_deg,      -- > 0: clockwise
    round(sqrt(avg(ae * ae)), 4)::DOUBLE                 AS azimuth_rms_deg,
    round(quantile_cont(abs(ae), 0.95), 4)::DOUBLE       AS azimuth_p95_deg,
    CAST($vts_bearing_p95_deg AS DOUBLE)                 AS azimuth_p95_req_deg,   -- IMO MSC.192(79)
    (quantile_cont(abs(ae), 0.95) <= CAST($vts_bearing_p95_deg AS DOUBLE))::BOOLEAN AS meets_vts_bearing
FROM pts
GROUP BY site, sector, source, reference
ORDER BY site, sector, reference, (source = 'fused') DESC, source;
