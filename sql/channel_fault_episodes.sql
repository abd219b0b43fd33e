-- name: channel_fault_episodes
-- description: every channel fault episode of every sensor family with its evidence
--   (issue 22): a run of decisions after which the channel was excluded (airfield: at
--   least half of its targets in the sector), in one sector; its start, end and duration,
--   decisions and flags in it, the mean NIS per degree of freedom, and what the tests
--   estimated: a radar's range bias, azimuth bias and time offset (registration test),
--   ships it missed, the time since its last scan; an AIS transponder's offset from the
--   radar-only track; an airfield channel's innovation. `isolated` marks an episode of
--   one flagged decision followed by readmission: at the nominal rate q, a false alarm.
-- grain: one row per (site, family, sector, channel, episode)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source tables: channel_health (airfield), maritime_channel_health (maritime),
--   nav_solution (nav)
WITH d AS (
    SELECT site, 'airfield' AS family, sensor_kind, channel, sector, track_id AS unit, time_ns,
           eta, excluded, "check" AS chk, nis / dof AS nis_per_dof, innovation_m,
           NULL::DOUBLE AS range_bias_m, NULL::DOUBLE AS azimuth_bias_rad,
           NULL::DOUBLE AS time_offset_s, NULL::DOUBLE AS offset_east_m,
           NULL::DOUBLE AS offset_north_m, NULL::INTEGER AS missed,
           NULL::INTEGER AS expected, NULL::DOUBLE AS scan_gap_s
    FROM channel_health
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
    UNION ALL
    SELECT site, 'maritime', sensor_kind, channel, sector, '', time_ns, eta, excluded, "check",
           nis / nullif(dof, 0), innovation_m, range_bias_m, azimuth_bias_rad, time_offset_s,
           offset_east_m, offset_north_m, missed, expected, scan_gap_s
    FROM maritime_channel_health
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
    UNION ALL
    SELECT site, 'nav', 'gnss', platform_id, sector, '', time_ns, gnss_eta, gnss_excluded,
           CASE WHEN mode = 'emergency' THEN 'outage' WHEN gate = 'reject' THEN 'gate'
                ELSE 'position' END,
           gnss_nis / 2.0, NULL, NULL, NULL, NULL, NULL, NULL, NULL, NULL, NULL
    FROM nav_solution
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (gnss_eta IS NOT NULL OR gnss_excluded)
),
h AS (
    SELECT * REPLACE (coalesce(sector, '(outside sectors)') AS sector,
                      coalesce(excluded, FALSE) AS excluded)
    FROM d
    WHERE (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
step AS (   -- each channel's decision step, ns (median spacing of one unit's decisions)
    SELECT site, family, channel, coalesce(median(dt) FILTER (WHERE dt > 0), 1000000000)::BIGINT AS step_ns
    FROM (SELECT site, family, channel, time_ns - lag(time_ns) OVER (
              PARTITION BY site, family, sector, channel, unit ORDER BY time_ns) AS dt FROM h) AS g
    GROUP BY site, family, channel
),
per_time AS (   -- the channel is down at a time when at least half of its targets are excluded
    SELECT site, family, sector, channel, time_ns, avg(CASE WHEN excluded THEN 1.0 ELSE 0.0 END) >= 0.5 AS down
    FROM h
    GROUP BY site, family, sector, channel, time_ns
),
marked AS (
    SELECT p.*, s.step_ns,
           CASE WHEN down AND (
                    coalesce(NOT lag(down) OVER w, TRUE)
                    OR time_ns - lag(time_ns) OVER w > 3 * s.step_ns)
                THEN 1 ELSE 0 END AS starts
    FROM per_time AS p JOIN step AS s USING (site, family, channel)
    WINDOW w AS (PARTITION BY p.site, p.family, p.sector, p.channel ORDER BY p.time_ns)
),
episodes AS (
    SELECT site, family, sector, channel, ep, min(time_ns) AS start_ns,
           max(time_ns) + any_value(step_ns) AS end_ns
    FROM (SELECT marked.*, sum(starts) OVER (PARTITION BY site, family, sector, channel
                                             ORDER BY time_ns) AS ep FROM marked) AS x
    WHERE down
    GROUP BY site, family, sector, channel, ep
),
evidence AS (   -- the decisions of the channel in the sector inside the episode (a radar's first
                -- flag, radar_confirm scans before, is not counted)
    SELECT e.site, e.family, e.sector, e.channel, e.start_ns, e.end_ns,
           any_value(h.sensor_kind) AS sensor_kind,
           count(h.eta) AS decisions,
           count(*) FILTER (WHERE h.eta = 1) AS flags,
           avg(h.nis_per_dof) FILTER (WHERE h.eta = 1) AS mean_nis_per_dof,
           avg(h.innovation_m) FILTER (WHERE h.eta = 1) AS innovation_m,
           avg(h.range_bias_m) FILTER (WHERE h.eta = 1) AS range_bias_m,
           degrees(avg(h.azimuth_bias_rad) FILTER (WHERE h.eta = 1)) AS azimuth_bias_deg,
           avg(h.time_offset_s) FILTER (WHERE h.eta = 1) AS time_offset_s,
           avg(h.offset_east_m) FILTER (WHERE h.eta = 1) AS offset_east_m,
           avg(h.offset_north_m) FILTER (WHERE h.eta = 1) AS offset_north_m,
           sum(h.missed) FILTER (WHERE h.eta = 1) AS missed,
           sum(h.expected) FILTER (WHERE h.eta = 1) AS expected,
           max(h.scan_gap_s) FILTER (WHERE h.eta = 1) AS max_scan_gap_s,
           string_agg(DISTINCT h.chk, ',' ORDER BY h.chk) FILTER (WHERE h.eta = 1) AS checks
    FROM episodes AS e
    JOIN h ON h.site = e.site AND h.family = e.family AND h.sector = e.sector AND h.channel = e.channel
          AND h.time_ns >= e.start_ns AND h.time_ns < e.end_ns
    GROUP BY e.site, e.family, e.sector, e.channel, e.start_ns, e.end_ns
)
SELECT
    site::VARCHAR                                               AS site,              -- site (deployment)
    family::VARCHAR                                             AS family,            -- airfield | maritime | nav
    sector::VARCHAR                                             AS sector,            -- sector of the decisions
    sensor_kind::VARCHAR                                        AS sensor_kind,       -- smr | mlat | vasn | radar | ais | gnss
    channel::VARCHAR                                            AS channel,           -- sensor id, radar site, MMSI, platform
    start_ns::BIGINT                                            AS start_ns,          -- first decision after which it was excluded, ns UTC
    end_ns::BIGINT                                              AS end_ns,            -- last one plus one decision step, ns UTC
    make_timestamp((start_ns // 1000)::BIGINT)::VARCHAR         AS start_utc,         -- start, UTC
    round((end_ns - start_ns) / 1e9, 1)::DOUBLE                 AS duration_s,        -- duration, s
    decisions::BIGINT                                           AS decisions,         -- decisions in it
    flags::BIGINT                                               AS flags,             -- of those with eta = 1
    (flags <= 1)::BOOLEAN                                       AS isolated,          -- one flag, then readmission
    checks::VARCHAR                                             AS checks,            -- which tests flagged (nis, bias, coverage, scan, ais, ais_unmatched, gate, position, outage)
    round(mean_nis_per_dof, 2)::DOUBLE                          AS mean_nis_per_dof,  -- mean NIS / dof of the flagged decisions (healthy: ~1)
    round(range_bias_m, 1)::DOUBLE                              AS range_bias_m,      -- radar: estimated range bias, m
    round(azimuth_bias_deg, 3)::DOUBLE                          AS azimuth_bias_deg,  -- radar: estimated azimuth bias, deg
    round(time_offset_s, 2)::DOUBLE                             AS time_offset_s,     -- radar: estimated time offset, s
    missed::BIGINT                                              AS missed,            -- radar: ships missed (summed over flagged epochs)
    expected::BIGINT                                            AS expected,          -- radar: ships other channels saw in its range
    round(max_scan_gap_s, 1)::DOUBLE                            AS max_scan_gap_s,    -- radar: longest time without a scan, s
    round(offset_east_m, 1)::DOUBLE                             AS offset_east_m,     -- AIS: mean offset from the radar-only track, east, m
    round(offset_north_m, 1)::DOUBLE                            AS offset_north_m,    -- AIS: ... north, m
    round(innovation_m, 1)::DOUBLE                              AS innovation_m       -- AIS, airfield: mean |innovation|, m
FROM evidence
ORDER BY site, start_ns, family, sector, channel;
