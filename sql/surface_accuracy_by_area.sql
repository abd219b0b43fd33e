-- name: surface_accuracy_by_area
-- description: airfield surface surveillance accuracy per ED-87 area (manoeuvring area,
--   apron taxiways, stands): 95th-percentile and RMS horizontal error of each channel's
--   reports and of the fused tracks against the reference (simulated truth when the log
--   has it, else the reconstructed reference: the fused filter smoothed, issue 37),
--   probability of identification (fused, over cooperative targets; needs truth), share
--   of updates after a gap of 3-5 s and of more than 5 s, beside the ED-87 requirements
--   per area and the sensor level (ED-116/117), bound from the config's [requirements]
--   (shipped: 95% <= 12 / 20 / 25 m, 7.5 m; P(ID) >= 0.999). Against the reconstructed
--   reference p95_error_m and rms_error_m estimate the TRUE error: the mean squared error
--   against the reference plus each row's reference_correction_m2 (the smoother shares
--   the data it is compared with), and the 95th percentile of the true error's posterior:
--   given the data, e = d + eps with eps ~ N(0, P_ref) (isotropic, trace from the
--   correction), evaluated on 32 fixed equal-weight draws of a standard 2-D normal (8
--   Rayleigh-quantile radii x 4 angles, second moment 1 per axis); the *_vs_reference_m
--   columns are the uncorrected figures (pipeline/airfield/reference.py).
-- grain: one row per (site, area, source, reference); source = a channel's sensor id or 'fused'
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $ed87_manoeuvring_p95_m, $ed87_apron_taxiway_p95_m, $ed87_stand_p95_m,
--         $sensor_p95_m, $p_identification_min (DOUBLE, from [requirements])
-- source tables: airfield_tracks, channel_health (written by `surveil batch`)
WITH updates AS (   -- one row per update of a target by a source
    SELECT site, coalesce(area, '(outside areas)') AS area, channel AS source, track_id, time_ns,
           error_m, CAST(NULL AS BOOLEAN) AS identity_correct, CAST(NULL AS BOOLEAN) AS cooperative,
           reference, coalesce(reference_correction_m2, 0.0) AS corr, reference_p95_m,
           coalesce(error_model, 'config') AS error_model
    FROM channel_health
    WHERE report_x_m IS NOT NULL
      AND time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
    UNION ALL
    SELECT site, coalesce(area, '(outside areas)'), 'fused', track_id, time_ns, error_m,
           identity_correct, cooperative, reference, coalesce(reference_correction_m2, 0.0),
           reference_p95_m, NULL
    FROM airfield_tracks
    WHERE n_channels > 0
      AND time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
gaps AS (
    SELECT *, (time_ns - lag(time_ns) OVER (PARTITION BY site, source, track_id ORDER BY time_ns)) / 1e9 AS gap_s
    FROM updates
),
req AS (
    SELECT * FROM (VALUES ('manoeuvring', CAST($ed87_manoeuvring_p95_m AS DOUBLE)),
                          ('apron_taxiway', CAST($ed87_apron_taxiway_p95_m AS DOUBLE)),
                          ('stand', CAST($ed87_stand_p95_m AS DOUBLE)))
        AS r(area, ed87_p95_m)
),
agg AS (
    SELECT
        g.site, g.area, g.source, coalesce(any_value(g.reference), '(none)') AS reference,
        count(*) AS updates,
        count(g.error_m) AS scored,
        quantile_cont(g.error_m, 0.95) AS p95_raw,
        sqrt(avg(g.error_m * g.error_m)) AS rms_raw,
        sqrt(greatest(avg(g.error_m * g.error_m + g.corr) FILTER (WHERE g.error_m IS NOT NULL), 0.0))
            AS rms_true,
        avg(g.reference_p95_m) AS ref_p95,
        any_value(r.ed87_p95_m) AS ed87_p95_m,
        avg(CASE WHEN g.identity_correct THEN 1.0 ELSE 0.0 END) FILTER (WHERE g.cooperative
            AND g.identity_correct IS NOT NULL) AS p_id,
        count(*) FILTER (WHERE g.cooperative AND g.identity_correct IS NOT NULL) AS id_samples,
        avg(CASE WHEN g.gap_s >= 3 AND g.gap_s <= 5 THEN 1.0 ELSE 0.0 END)
            FILTER (WHERE g.gap_s IS NOT NULL) AS gap35,
        avg(CASE WHEN g.gap_s > 5 THEN 1.0 ELSE 0.0 END) FILTER (WHERE g.gap_s IS NOT NULL) AS gap5,
        string_agg(DISTINCT g.error_model, '; ') AS channel_error_model
    FROM gaps AS g
    LEFT JOIN req AS r ON r.area = g.area
    GROUP BY g.site, g.area, g.source, coalesce(g.reference, '(none)')
),
draws AS (   -- standard 2-D normal, 32 equal-weight points (header)
    SELECT * FROM (VALUES
        (0.367193, 0.000000), (0.000000, 0.367193), (-0.367193, 0.000000), (-0.000000, -0.367193),
        (0.465719, 0.465719), (-0.465719, 0.465719), (-0.465719, -0.465719), (0.465719, -0.465719),
        (0.884754, 0.000000), (0.000000, 0.884754), (-0.884754, 0.000000), (-0.000000, -0.884754),
        (0.775248, 0.775248), (-0.775248, 0.775248), (-0.775248, -0.775248), (0.775248, -0.775248),
        (1.314174, 0.000000), (0.000000, 1.314174), (-1.314174, 0.000000), (-0.000000, -1.314174),
        (1.102269, 1.102269), (-1.102269, 1.102269), (-1.102269, -1.102269), (1.102269, -1.102269),
        (1.870075, 0.000000), (0.000000, 1.870075), (-1.870075, 0.000000), (-0.000000, -1.870075),
        (1.701814, 1.701814), (-1.701814, 1.701814), (-1.701814, -1.701814), (1.701814, -1.701814)
    ) AS u(u1, u2)
),
post AS (   -- the posterior 95th percentile of |e| (rows the smoother used: corr > 0)
    SELECT g.site, g.area, g.source, coalesce(g.reference, '(none)') AS reference,
           quantile_cont(sqrt(power(g.error_m + sqrt(greatest(g.corr, 0.0) / 2.0) * u.u1, 2)
                              + greatest(g.corr, 0.0) / 2.0 * u.u2 * u.u2), 0.95) AS p95_true
    FROM gaps AS g CROSS JOIN draws AS u
    WHERE g.error_m IS NOT NULL
    GROUP BY g.site, g.area, g.source, coalesce(g.reference, '(none)')
),
est AS (
    SELECT a.*, p.p95_true FROM agg AS a
    LEFT JOIN post AS p USING (site, area, source, reference)
)
SELECT
    site::VARCHAR                                                         AS site,              -- site (deployment)
    area::VARCHAR                                                         AS area,              -- manoeuvring | apron_taxiway | stand
    source::VARCHAR                                                       AS source,            -- sensor id or 'fused'
    reference::VARCHAR                                                    AS reference,         -- truth | reconstructed | (none)
    updates::BIGINT                                                       AS updates,           -- target updates
    scored::BIGINT                                                        AS scored,            -- updates with a reference
    round(p95_true, 2)::DOUBLE                                            AS p95_error_m,       -- 95th percentile error, m (estimate of the true one)
    round(rms_true, 2)::DOUBLE                                            AS rms_error_m,       -- RMS error, m (idem)
    round(p95_raw, 2)::DOUBLE                                             AS p95_vs_reference_m, -- uncorrected, against the reference
    round(rms_raw, 2)::DOUBLE                                             AS rms_vs_reference_m,
    round(ref_p95, 2)::DOUBLE                                             AS reference_p95_m,   -- the reference's own 95% error (0: truth)
    ed87_p95_m::DOUBLE                                                    AS ed87_p95_req_m,    -- ED-87 95% requirement, m
    (p95_true <= ed87_p95_m)::BOOLEAN                                     AS meets_ed87,        -- p95 within it
    CAST($sensor_p95_m AS DOUBLE)                                         AS sensor_p95_req_m,  -- ED-116/117 sensor level, m
    (p95_true <= CAST($sensor_p95_m AS DOUBLE))::BOOLEAN                  AS meets_sensor_level,
    round(p_id, 5)::DOUBLE                                                AS p_identification,  -- fused, cooperative targets (truth)
    id_samples::BIGINT                                                    AS id_samples,        -- updates behind p_identification
    CAST($p_identification_min AS DOUBLE)                                 AS p_id_req,          -- ED-87
    (p_id >= CAST($p_identification_min AS DOUBLE))::BOOLEAN              AS meets_p_id,        -- NULL: no cooperative target / no truth
    round(gap35, 5)::DOUBLE                                               AS gap_3_5s_share,    -- updates after a 3-5 s gap
    round(gap5, 5)::DOUBLE                                                AS gap_over_5s_share, -- updates after a > 5 s gap
    CASE WHEN source = 'fused'
         THEN (SELECT string_agg(DISTINCT c.channel || ': ' || coalesce(c.error_model, 'config'), '; '
                                 ORDER BY c.channel || ': ' || coalesce(c.error_model, 'config'))
               FROM channel_health AS c
               WHERE c.site = est.site AND c.time_ns >= $start_ns AND c.time_ns < $end_ns)
         ELSE channel_error_model END::VARCHAR                           AS error_model        -- the channel's error model: config, fit [..] (surveil calibrate) or 'default ...' (its kind's, scaled to the data); fused: every channel's
FROM est
ORDER BY site, area, reference, (source = 'fused') DESC, source;
