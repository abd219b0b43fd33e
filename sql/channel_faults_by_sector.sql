-- name: channel_faults_by_sector
-- description: channel integrity of every sensor family per sector and channel (airfield
--   paper eq. 21-23; issue 22): airfield SMR/MLAT/VASN per target (channel_health), coastal
--   radars per sector and AIS transponders per report (maritime_channel_health), the own
--   ship's GNSS per fix (nav_solution). Share of decisions flagged (eta = 1) beside the
--   nominal false-alarm probability q, exclusion episodes of one channel for one target,
--   channel-wide fault episodes (epochs where at least half of the channel's targets in
--   the sector are excluded; radar, AIS and GNSS are tested once per sector and epoch, so
--   there the two are the same), their total and longest duration, and the share of
--   decisions after which the channel was excluded. p_chance: the probability of at least
--   as many flags from false alarms alone (Poisson, mean decisions x q): a channel in
--   fault has p_chance ~0, a healthy one shows a flagged share above q now and then.
-- grain: one row per (site, sector, family, channel)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site)
-- source tables: channel_health (airfield family), maritime_channel_health (maritime
--   family), nav_solution (nav family), all written by `surveil batch`
WITH d AS (   -- every decision of every family: one unit = one target (airfield) or the channel
    SELECT site, 'airfield' AS family, sensor_kind, channel, sector, track_id AS unit, time_ns,
           eta, excluded,
           (1.0 - exp(-d1 / 2.0)) + exp(-d2 / 2.0) AS q,     -- chi2(2): P(xi <= d1) + P(xi >= d2)
           coalesce(error_model, 'config') AS error_model
    FROM channel_health
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
    UNION ALL
    SELECT site, 'maritime', sensor_kind, channel, sector, '', time_ns, eta, excluded, q,
           CASE WHEN sensor_kind = 'radar' THEN 'reported sigmas' END
    FROM maritime_channel_health
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
    UNION ALL
    SELECT site, 'nav', 'gnss', platform_id, sector, '', time_ns, gnss_eta, gnss_excluded, gnss_q,
           NULL
    FROM nav_solution
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (gnss_eta IS NOT NULL OR gnss_excluded)
),
h AS (
    SELECT site, family, sensor_kind, channel, coalesce(sector, '(outside sectors)') AS sector,
           unit, time_ns, eta, coalesce(excluded, FALSE) AS excluded, q, error_model
    FROM d
    WHERE (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
gaps AS (   -- time to the previous decision of the same unit, and whether it excluded
    SELECT h.*, time_ns - lag(time_ns) OVER w AS dt, lag(excluded) OVER w AS excluded_before
    FROM h
    WINDOW w AS (PARTITION BY site, family, sector, channel, unit ORDER BY time_ns)
),
step AS (   -- each channel's decision step, ns (median spacing of one unit's decisions)
    SELECT site, family, channel, coalesce(median(dt) FILTER (WHERE dt > 0), 1000000000)::BIGINT AS step_ns
    FROM gaps
    GROUP BY site, family, channel
),
marked AS (   -- gaps and islands: an episode starts at an excluded decision after a non-excluded one or a gap
    SELECT g.*, s.step_ns,
           CASE WHEN excluded AND (coalesce(NOT excluded_before, TRUE) OR dt > 3 * s.step_ns)
                THEN 1 ELSE 0 END AS starts
    FROM gaps AS g JOIN step AS s USING (site, family, channel)
),
target_episodes AS (
    SELECT site, family, sector, channel, unit, ep,
           max(time_ns) - min(time_ns) + any_value(step_ns) AS dur_ns
    FROM (SELECT marked.*, sum(starts) OVER (PARTITION BY site, family, sector, channel, unit
                                             ORDER BY time_ns) AS ep FROM marked) AS x
    WHERE excluded
    GROUP BY site, family, sector, channel, unit, ep
),
per_time AS (   -- channel-wide: at least half of the channel's targets in the sector excluded
    SELECT site, family, sector, channel, time_ns, avg(CASE WHEN excluded THEN 1.0 ELSE 0.0 END) >= 0.5 AS down
    FROM h
    GROUP BY site, family, sector, channel, time_ns
),
per_time_marked AS (
    SELECT p.*, s.step_ns,
           CASE WHEN down AND (
                    coalesce(NOT lag(down) OVER w, TRUE)
                    OR time_ns - lag(time_ns) OVER w > 3 * s.step_ns)
                THEN 1 ELSE 0 END AS starts
    FROM per_time AS p JOIN step AS s USING (site, family, channel)
    WINDOW w AS (PARTITION BY p.site, p.family, p.sector, p.channel ORDER BY p.time_ns)
),
channel_episodes AS (
    SELECT site, family, sector, channel, ep, max(time_ns) - min(time_ns) + any_value(step_ns) AS dur_ns
    FROM (SELECT per_time_marked.*, sum(starts) OVER (PARTITION BY site, family, sector, channel
                                                      ORDER BY time_ns) AS ep
          FROM per_time_marked) AS x
    WHERE down
    GROUP BY site, family, sector, channel, ep
),
checks AS (
    SELECT site, family, sector, channel,
           any_value(sensor_kind) AS sensor_kind,
           count(*) AS rows_total,
           count(eta) AS decisions,
           count(*) FILTER (WHERE eta = 1) AS flagged,
           avg(q) AS q,
           count(*) FILTER (WHERE excluded) AS excluded_rows,
           string_agg(DISTINCT h.error_model, '; ') AS models
    FROM h
    GROUP BY site, family, sector, channel
),
chance AS (   -- P(X >= flagged), X ~ Poisson(decisions q): 1 - sum_{j < flagged} pmf(j)
    SELECT c.site, c.family, c.sector, c.channel,
           greatest(0.0, 1.0 - coalesce(sum(exp(-lam + j * ln(lam) - lgamma(j + 1))), 0.0)) AS p
    FROM (SELECT *, decisions * q AS lam FROM checks WHERE decisions > 0) AS c
    LEFT JOIN LATERAL (SELECT unnest(range(c.flagged)) AS j) AS r ON TRUE
    GROUP BY c.site, c.family, c.sector, c.channel
),
te AS (
    SELECT site, family, sector, channel, count(*) AS n, sum(dur_ns) AS total, max(dur_ns) AS longest
    FROM target_episodes GROUP BY site, family, sector, channel
),
ce AS (
    SELECT site, family, sector, channel, count(*) AS n, sum(dur_ns) AS total, max(dur_ns) AS longest
    FROM channel_episodes GROUP BY site, family, sector, channel
)
SELECT
    c.site::VARCHAR                                                AS site,              -- site (deployment)
    c.sector::VARCHAR                                              AS sector,            -- sector (airfield or VTS)
    c.family::VARCHAR                                              AS family,            -- airfield | maritime | nav
    c.sensor_kind::VARCHAR                                         AS sensor_kind,       -- smr | mlat | vasn | radar | ais | gnss
    c.channel::VARCHAR                                             AS channel,           -- sensor id, radar site, MMSI, platform
    c.decisions::BIGINT                                            AS decisions,         -- checks with an eta
    round(c.flagged / nullif(c.decisions, 0), 5)::DOUBLE           AS flagged_share,     -- share with eta = 1 (healthy: ~q)
    round(c.q, 5)::DOUBLE                                          AS q,                 -- nominal false-alarm probability of a decision
    round(p.p, 6)::DOUBLE                                          AS p_chance,          -- P(this many flags or more | false alarms only)
    coalesce(te.n, 0)::BIGINT                                      AS target_episodes,   -- exclusion runs of one target
    round(coalesce(te.total, 0) / 1e9, 1)::DOUBLE                  AS target_excluded_s, -- their summed duration, s
    round(coalesce(te.longest, 0) / 1e9, 1)::DOUBLE                AS target_longest_s,  -- longest, s
    coalesce(ce.n, 0)::BIGINT                                      AS channel_episodes,  -- channel-wide fault episodes
    round(coalesce(ce.total, 0) / 1e9, 1)::DOUBLE                  AS channel_fault_s,   -- their total duration, s
    round(coalesce(ce.longest, 0) / 1e9, 1)::DOUBLE                AS channel_longest_s, -- longest, s
    round(c.excluded_rows / nullif(c.rows_total, 0), 5)::DOUBLE    AS excluded_share,    -- share of decisions excluded
    c.models::VARCHAR                                              AS error_model        -- airfield: the channel's error model (config, fit [..], or 'default ...': its kind's, scaled to the data); radar: reported sigmas
FROM checks AS c
LEFT JOIN chance AS p ON p.site = c.site AND p.family = c.family AND p.sector = c.sector AND p.channel = c.channel
LEFT JOIN te ON te.site = c.site AND te.family = c.family AND te.sector = c.sector AND te.channel = c.channel
LEFT JOIN ce ON ce.site = c.site AND ce.family = c.family AND ce.sector = c.sector AND ce.channel = c.channel
ORDER BY site, sector, family, sensor_kind, channel;
