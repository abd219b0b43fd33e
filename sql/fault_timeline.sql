-- name: fault_timeline
-- description: channel faults on one timeline: airfield channel-wide fault episodes
--   (epochs where at least half of the channel's targets are excluded by the integrity
--   check, airfield paper eq. 21-23) and own-ship GNSS outages (gyro/GNSS/log paper:
--   emergency mode). Each row is one episode with its start, end and duration.
-- grain: one row per (site, lane, episode); lane = airfield channel or "GNSS <platform>"
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source tables: channel_health, nav_outages (written by `surveil batch`)
WITH h AS (
    SELECT site, channel, sensor_kind, time_ns, excluded
    FROM channel_health
    WHERE time_ns >= $start_ns
      AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
step AS (   -- the filter epoch, ns
    SELECT coalesce(min(dt), 1000000000) AS step_ns
    FROM (SELECT time_ns - lag(time_ns) OVER (PARTITION BY site, channel ORDER BY time_ns) AS dt
          FROM (SELECT DISTINCT site, channel, time_ns FROM h) AS d) AS x
    WHERE dt > 0
),
per_epoch AS (
    SELECT site, channel, any_value(sensor_kind) AS sensor_kind, time_ns,
           avg(CASE WHEN excluded THEN 1.0 ELSE 0.0 END) >= 0.5 AS down
    FROM h
    GROUP BY site, channel, time_ns
),
marked AS (
    SELECT *,
           CASE WHEN down AND (coalesce(NOT lag(down) OVER w, TRUE)
                               OR time_ns - lag(time_ns) OVER w > (SELECT step_ns FROM step))
                THEN 1 ELSE 0 END AS starts
    FROM per_epoch
    WINDOW w AS (PARTITION BY site, channel ORDER BY time_ns)
),
episodes AS (
    SELECT site, channel, any_value(sensor_kind) AS sensor_kind, min(time_ns) AS start_ns,
           max(time_ns) + (SELECT step_ns FROM step) AS end_ns
    FROM (SELECT *, sum(starts) OVER (PARTITION BY site, channel ORDER BY time_ns) AS ep
          FROM marked) AS x
    WHERE down
    GROUP BY site, channel, ep
),
outages AS (
    SELECT site, 'GNSS ' || platform_id AS lane, 'gnss outage (' || kind || ')' AS kind,
           start_ns, end_ns
    FROM nav_outages
    WHERE start_ns < $end_ns
      AND end_ns >= $start_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
)
SELECT
    site::VARCHAR                                                    AS site,        -- site (deployment)
    lane::VARCHAR                                                    AS lane,        -- channel or GNSS of a platform
    kind::VARCHAR                                                    AS kind,        -- what failed
    make_timestamp((start_ns // 1000)::BIGINT)::TIMESTAMP            AS start_utc,
    make_timestamp((end_ns // 1000)::BIGINT)::TIMESTAMP              AS end_utc,
    round((end_ns - start_ns) / 1e9, 1)::DOUBLE                      AS duration_s
FROM (
    SELECT site, channel AS lane, sensor_kind || ' channel excluded' AS kind, start_ns, end_ns
    FROM episodes
    UNION ALL
    SELECT site, lane, kind, start_ns, end_ns FROM outages
) AS all_episodes
ORDER BY site, lane, start_utc;
