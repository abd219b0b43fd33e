-- name: track_continuity
-- description: continuity of the fused picture on each referenced target (issue 37):
--   gaps in its fused track longer than $max_gap_s (a target is referenced on both sides,
--   gaps longer than $reference_gap_s are the reference's own silences and not counted),
--   track breaks (the target's primary system track, the nearest one, changes number),
--   the rate of track number change per hour of target time, track swaps (two targets
--   exchanging their tracks within $swap_window_s: one swap per exchanged pair; IALA
--   G1111: none), and extra tracks (epochs where more than one system track holds the
--   target); against simulated truth, else the reconstructed references (the vessels
--   carrying AIS). The swap count is judged against [requirements.vts] max_track_swaps.
-- grain: one row per (site, sector, reference)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $max_gap_s (DOUBLE, default 12), $reference_gap_s (DOUBLE, default 200),
--         $swap_window_s (DOUBLE, default 60)
-- source table: track_errors (written by `surveil batch`)
WITH f AS (
    SELECT site, time_ns, reference, reference_id, system_track_id, error_m,
           coalesce(sector, '(outside sectors)') AS sector
    FROM track_errors
    WHERE source = 'fused'
      AND time_ns >= $start_ns
      AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
per_epoch AS (   -- per target and epoch: the tracks holding it, its primary (nearest) one
    SELECT site, reference, reference_id, time_ns,
           arg_min(sector, error_m) AS sector,
           count(*) AS n_tracks,
           arg_min(system_track_id, error_m) AS primary_track
    FROM f
    GROUP BY site, reference, reference_id, time_ns
),
seq AS (
    SELECT *,
           (time_ns - lag(time_ns) OVER w) / 1e9 AS dt_s,
           lag(primary_track) OVER w AS prev_track
    FROM per_epoch
    WINDOW w AS (PARTITION BY site, reference, reference_id ORDER BY time_ns)
),
period AS (   -- the epoch period of each site: the median step
    SELECT site, coalesce(median(dt_s) FILTER (WHERE dt_s > 0), 0) AS epoch_s
    FROM seq GROUP BY site
),
changes AS (
    SELECT site, reference, reference_id, time_ns, sector,
           prev_track AS from_track, primary_track AS to_track
    FROM seq
    WHERE prev_track IS NOT NULL AND prev_track <> primary_track
      AND dt_s <= $reference_gap_s
),
swaps AS (
    SELECT a.site, a.reference, a.sector,
           count(DISTINCT (a.reference_id, b.reference_id, a.from_track, a.to_track)) AS n
    FROM changes AS a
    JOIN changes AS b
      ON a.site = b.site AND a.reference = b.reference
     AND a.from_track = b.to_track AND a.to_track = b.from_track
     AND a.reference_id < b.reference_id
     AND abs(a.time_ns - b.time_ns) <= CAST(round($swap_window_s * 1e9) AS BIGINT)
    GROUP BY a.site, a.reference, a.sector
),
per_sector AS (
    SELECT s.site, s.sector, s.reference,
           count(DISTINCT s.reference_id) AS targets,
           count(*) AS target_epochs,
           count(*) FILTER (WHERE s.dt_s > $max_gap_s AND s.dt_s <= $reference_gap_s) AS gaps,
           max(s.dt_s) FILTER (WHERE s.dt_s <= $reference_gap_s) AS longest_gap_s,
           count(*) FILTER (WHERE s.prev_track IS NOT NULL AND s.prev_track <> s.primary_track
                            AND s.dt_s <= $reference_gap_s) AS track_changes,
           count(*) FILTER (WHERE s.n_tracks > 1) AS extra_track_epochs,
           any_value(p.epoch_s) AS epoch_s
    FROM seq AS s JOIN period AS p USING (site)
    GROUP BY s.site, s.sector, s.reference
)
SELECT
    c.site::VARCHAR                                                  AS site,
    c.sector::VARCHAR                                                AS sector,
    c.reference::VARCHAR                                             AS reference,         -- truth | reconstructed
    c.targets::BIGINT                                                AS targets,           -- referenced targets tracked
    c.target_epochs::BIGINT                                          AS target_epochs,     -- (target, epoch) with a fused track
    round(c.target_epochs * c.epoch_s / 3600.0, 3)::DOUBLE           AS target_hours,
    c.gaps::BIGINT                                                   AS gaps,              -- longer than $max_gap_s
    round(c.gaps / nullif(c.target_epochs, 0), 6)::DOUBLE            AS gap_probability,   -- per target epoch
    round(c.longest_gap_s, 1)::DOUBLE                                AS longest_gap_s,
    c.track_changes::BIGINT                                          AS track_changes,     -- breaks: primary track number changed
    round(c.track_changes * 3600.0 / nullif(c.target_epochs * c.epoch_s, 0), 3)::DOUBLE
                                                                     AS changes_per_h,     -- rate of track number change
    coalesce(w.n, 0)::BIGINT                                         AS track_swaps,       -- IALA G1111: 0
    round(c.extra_track_epochs / nullif(c.target_epochs, 0), 5)::DOUBLE AS extra_track_share -- epochs with > 1 track on the target
FROM per_sector AS c
LEFT JOIN swaps AS w USING (site, reference, sector)
ORDER BY site, reference, sector;
