-- name: channel_faults_by_sector
-- description: airfield channel integrity per sector and channel (airfield paper eq. 21-23):
--   share of checks flagged (eta = 1), exclusion episodes of one channel for one target,
--   channel-wide fault episodes (epochs where at least half of the channel's targets in the
--   sector are excluded), their total and longest duration, and the share of target-time
--   the channel was excluded.
-- grain: one row per (sector, channel)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector)
-- source table: channel_health (written by `surveil batch`, airfield family)
WITH h AS (
    SELECT
        coalesce(sector, '(outside sectors)') AS sector,
        channel,
        sensor_kind,
        track_id,
        time_ns,
        eta,
        excluded
    FROM channel_health
    WHERE time_ns >= $start_ns
      AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
),
step AS (   -- the filter epoch, ns (smallest spacing of one target's rows)
    SELECT coalesce(min(dt), 1000000000) AS step_ns
    FROM (
        SELECT time_ns - lag(time_ns) OVER (PARTITION BY track_id, channel ORDER BY time_ns) AS dt
        FROM h
    ) AS d
    WHERE dt > 0
),
marked AS (   -- gaps and islands: a new episode starts at an excluded row whose predecessor was not
    SELECT
        h.*,
        CASE WHEN excluded AND (
                 coalesce(NOT lag(excluded) OVER w, TRUE)
                 OR time_ns - lag(time_ns) OVER w > (SELECT step_ns FROM step))
             THEN 1 ELSE 0 END AS starts
    FROM h
    WINDOW w AS (PARTITION BY sector, channel, track_id ORDER BY time_ns)
),
numbered AS (
    SELECT marked.*, sum(starts) OVER (PARTITION BY sector, channel, track_id ORDER BY time_ns) AS ep
    FROM marked
),
target_episodes AS (
    SELECT sector, channel, track_id, ep, count(*) AS epochs
    FROM numbered
    WHERE excluded
    GROUP BY sector, channel, track_id, ep
),
per_epoch AS (   -- channel-wide: at least half of the channel's targets in the sector excluded
    SELECT sector, channel, time_ns, avg(CASE WHEN excluded THEN 1.0 ELSE 0.0 END) >= 0.5 AS down
    FROM h
    GROUP BY sector, channel, time_ns
),
per_epoch_marked AS (
    SELECT
        per_epoch.*,
        CASE WHEN down AND (
                 coalesce(NOT lag(down) OVER w, TRUE)
                 OR time_ns - lag(time_ns) OVER w > (SELECT step_ns FROM step))
             THEN 1 ELSE 0 END AS starts
    FROM per_epoch
    WINDOW w AS (PARTITION BY sector, channel ORDER BY time_ns)
),
channel_episodes AS (
    SELECT sector, channel, ep, count(*) AS epochs
    FROM (
        SELECT *, sum(starts) OVER (PARTITION BY sector, channel ORDER BY time_ns) AS ep
        FROM per_epoch_marked
    ) AS x
    WHERE down
    GROUP BY sector, channel, ep
),
checks AS (
    SELECT
        sector,
        channel,
        any_value(sensor_kind) AS sensor_kind,
        count(*) AS rows_total,
        count(eta) AS decisions,
        count(*) FILTER (WHERE eta = 1) AS flagged,
        count(*) FILTER (WHERE excluded) AS excluded_rows
    FROM h
    GROUP BY sector, channel
),
te AS (
    SELECT sector, channel, count(*) AS n, sum(epochs) AS total, max(epochs) AS longest
    FROM target_episodes GROUP BY sector, channel
),
ce AS (
    SELECT sector, channel, count(*) AS n, sum(epochs) AS total, max(epochs) AS longest
    FROM channel_episodes GROUP BY sector, channel
)
SELECT
    c.sector::VARCHAR                                                    AS sector,            -- airfield sector
    c.channel::VARCHAR                                                   AS channel,           -- sensor id
    c.sensor_kind::VARCHAR                                               AS sensor_kind,       -- smr | mlat | vasn
    c.decisions::BIGINT                                                  AS decisions,         -- checks with an eta
    round(c.flagged / nullif(c.decisions, 0), 5)::DOUBLE                 AS flagged_share,     -- share with eta = 1 (healthy: ~q)
    coalesce(te.n, 0)::BIGINT                                            AS target_episodes,   -- exclusion runs of one target
    round(coalesce(te.total, 0) * s.step_ns / 1e9, 1)::DOUBLE            AS target_excluded_s, -- their summed duration, s
    round(coalesce(te.longest, 0) * s.step_ns / 1e9, 1)::DOUBLE          AS target_longest_s,  -- longest, s
    coalesce(ce.n, 0)::BIGINT                                            AS channel_episodes,  -- channel-wide fault episodes
    round(coalesce(ce.total, 0) * s.step_ns / 1e9, 1)::DOUBLE            AS channel_fault_s,   -- their total duration, s
    round(coalesce(ce.longest, 0) * s.step_ns / 1e9, 1)::DOUBLE          AS channel_longest_s, -- longest, s
    round(c.excluded_rows / nullif(c.rows_total, 0), 5)::DOUBLE          AS excluded_share     -- share of target-time excluded
FROM checks AS c
CROSS JOIN step AS s
LEFT JOIN te ON te.sector = c.sector AND te.channel = c.channel
LEFT JOIN ce ON ce.sector = c.sector AND ce.channel = c.channel
ORDER BY sector, channel;
