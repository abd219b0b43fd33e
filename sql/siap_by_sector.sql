-- name: siap_by_sector
-- description: SIAP measures of the fused picture against simulated truth per sector:
--   completeness, ambiguity, spuriousness, position and velocity accuracy, rate of track
--   number change, track swaps, longest track segment, ID completeness / correctness /
--   ambiguity (MMSI, ships carrying AIS). Sums of the batch work units that start in the
--   window are added before dividing, so any window and the '(all sectors)' row are exact.
--   Without truth the truths are the reconstructed references of the vessels carrying AIS
--   (issue 37; column reference): a track of a ship without AIS is then spurious.
-- grain: one row per (site, reference, sector), plus one '(all sectors)' row per (site, reference)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source table: siap_by_sector (written by `surveil batch`)
WITH rows_in AS (
    SELECT * REPLACE (coalesce(reference, 'truth') AS reference),
           coalesce(sector, '(outside sectors)') AS sector_name
    FROM siap_by_sector
    WHERE time_ns >= $start_ns
      AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
sums AS (
    SELECT
        site,
        reference,
        coalesce(sector_name, '(all sectors)')     AS sector,
        sum(truth_epochs)                          AS j,
        sum(tracked_truth_epochs)                  AS jt,
        sum(track_epochs)                          AS n,
        sum(associated_track_epochs)               AS na,
        sum(spurious_track_epochs)                 AS ns,
        sum(sum_position_error_m)                  AS pa,
        sum(sum_velocity_error_mps)                AS va,
        sum(track_number_changes)                  AS changes,
        sum(track_swaps)                           AS swaps,
        sum(tracked_time_s)                        AS tt,
        sum(truth_time_s)                          AS t,
        sum(longest_segment_s)                     AS tl,
        sum(id_truth_epochs)                       AS id_jt,
        sum(id_unknown_epochs)                     AS id_ju,
        sum(id_correct_epochs)                     AS id_jc,
        sum(id_ambiguous_epochs)                   AS id_ja
    FROM rows_in
    GROUP BY GROUPING SETS ((site, reference, sector_name), (site, reference))
)
SELECT
    site::VARCHAR                                                AS site,
    sector::VARCHAR                                              AS sector,
    reference::VARCHAR                                           AS reference,          -- truth | reconstructed
    j::BIGINT                                                    AS truth_epochs,       -- sum of J
    round(jt / nullif(j, 0), 4)::DOUBLE                          AS completeness,       -- target 1
    round(na / nullif(jt, 0), 4)::DOUBLE                         AS ambiguity,          -- target 1
    round(ns / nullif(n, 0), 4)::DOUBLE                          AS spuriousness,       -- target 0
    round(pa / nullif(na, 0), 2)::DOUBLE                         AS position_accuracy_m,
    round(va / nullif(na, 0), 3)::DOUBLE                         AS velocity_accuracy_mps,
    changes::BIGINT                                              AS track_number_changes,
    round(changes * 3600.0 / nullif(tt, 0), 3)::DOUBLE           AS changes_per_h,      -- R, target 0
    swaps::BIGINT                                                AS track_swaps,        -- close ships swapped
    round(tl / nullif(t, 0), 4)::DOUBLE                          AS longest_segment,    -- LS, target 1
    round((id_jt - id_ju) / nullif(id_jt, 0), 4)::DOUBLE         AS id_completeness,    -- target 1
    round(id_jc / nullif(id_jt, 0), 4)::DOUBLE                   AS id_correctness,     -- target 1
    round(id_ja / nullif(id_jt, 0), 4)::DOUBLE                   AS id_ambiguity        -- target 0
FROM sums
WHERE j IS NOT NULL
ORDER BY site, reference, (sector = '(all sectors)'), sector;
