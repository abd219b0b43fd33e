-- name: dubious_tracks
-- description: reference-free dubious tracks (issue 37, OpenATS COMPASS's "dubious
--   targets"): fused system tracks whose own kinematics are impossible for a ship:
--   speed over $max_speed_mps, acceleration (change of speed between consecutive epochs)
--   over $max_accel_mps2, or turn rate over $max_turn_rate_deg_s while moving at least
--   $turn_min_speed_mps (the course of a stopped ship is noise). Needs no reference: it
--   works on any archive. Per sector: tracks, dubious tracks and the worst values.
-- grain: one row per (site, sector)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $max_speed_mps (DOUBLE, default 25), $max_accel_mps2 (DOUBLE, default 1),
--         $max_turn_rate_deg_s (DOUBLE, default 10), $turn_min_speed_mps (DOUBLE, default 1)
-- source table: system_tracks (written by `surveil batch`)
WITH s AS (
    SELECT site, system_track_id, time_ns, coalesce(sector, '(outside sectors)') AS sector,
           speed_mps, course_rad,
           lag(time_ns) OVER w AS t0, lag(speed_mps) OVER w AS v0, lag(course_rad) OVER w AS c0
    FROM system_tracks
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
    WINDOW w AS (PARTITION BY site, system_track_id ORDER BY time_ns)
),
k AS (
    SELECT *,
           (speed_mps - v0) / ((time_ns - t0) / 1e9) AS accel,
           CASE WHEN speed_mps >= $turn_min_speed_mps AND v0 >= $turn_min_speed_mps THEN
               degrees(abs(((course_rad - c0 + 3 * pi()) % (2 * pi())) - pi()))
               / ((time_ns - t0) / 1e9) END AS turn
    FROM s
),
per_track AS (
    SELECT site, system_track_id, mode(sector ORDER BY sector) AS sector,
           max(speed_mps) AS vmax,
           max(abs(accel)) FILTER (WHERE t0 IS NOT NULL AND time_ns > t0) AS amax,
           max(turn) FILTER (WHERE t0 IS NOT NULL AND time_ns > t0) AS tmax
    FROM k
    GROUP BY site, system_track_id
)
SELECT
    site::VARCHAR                                                       AS site,
    sector::VARCHAR                                                     AS sector,
    count(*)::BIGINT                                                    AS tracks,
    (count(*) FILTER (WHERE vmax > $max_speed_mps OR amax > $max_accel_mps2
                            OR tmax > $max_turn_rate_deg_s))::BIGINT      AS dubious_tracks,
    round(avg(CASE WHEN vmax > $max_speed_mps OR amax > $max_accel_mps2
                        OR tmax > $max_turn_rate_deg_s THEN 1.0 ELSE 0.0 END), 4)::DOUBLE AS dubious_share,
    (count(*) FILTER (WHERE vmax > $max_speed_mps))::BIGINT             AS over_speed,
    (count(*) FILTER (WHERE amax > $max_accel_mps2))::BIGINT            AS over_acceleration,
    (count(*) FILTER (WHERE tmax > $max_turn_rate_deg_s))::BIGINT       AS over_turn_rate,
    round(max(vmax), 2)::DOUBLE                                         AS max_speed_mps,
    round(max(amax), 3)::DOUBLE                                         AS max_accel_mps2,
    round(max(tmax), 2)::DOUBLE                                         AS max_turn_rate_deg_s
FROM per_track
GROUP BY site, sector
ORDER BY site, sector;
