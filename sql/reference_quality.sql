-- name: reference_quality
-- description: the reconstructed references (issue 37, table reference_tracks) and the
--   accuracy of the AIS reports scored against them: per AIS class, the vessels and
--   reports, the reports gated out as outliers, the references' own 95% error, the AIS
--   position sigma estimated per vessel, and each report's error against a reference
--   made without it (the leave-one-out residual: RMS and 95th percentile over the
--   reports kept). On an AIS-only site this is the accuracy report that has rows.
-- grain: one row per (site, AIS class)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $site (VARCHAR, NULL = every site)
-- source table: reference_tracks (written by `surveil batch`)
SELECT
    site::VARCHAR                                                        AS site,
    coalesce(ais_class, '(unknown)')::VARCHAR                            AS ais_class,
    count(DISTINCT reference_id)::BIGINT                                 AS vessels,
    count(*)::BIGINT                                                     AS reports,
    (count(*) FILTER (WHERE outlier))::BIGINT                            AS outliers,
    round(avg(CASE WHEN outlier THEN 1.0 ELSE 0.0 END), 5)::DOUBLE       AS outlier_share,
    round(avg(p95_m) FILTER (WHERE NOT outlier), 2)::DOUBLE              AS reference_p95_m,     -- mean own 95% error at the reports
    round(median(sigma_position_m) FILTER (WHERE NOT outlier), 2)::DOUBLE AS ais_sigma_m,        -- estimated per vessel, median
    round(sqrt(avg(loo_residual_m * loo_residual_m) FILTER (WHERE NOT outlier)), 2)::DOUBLE
                                                                         AS ais_rms_error_m,     -- vs the reference without the report
    round(quantile_cont(loo_residual_m, 0.95) FILTER (WHERE NOT outlier), 2)::DOUBLE
                                                                         AS ais_p95_error_m,
    round(avg(manoeuvre_probability) FILTER (WHERE NOT outlier), 3)::DOUBLE AS manoeuvre_share  -- mean IMM manoeuvre probability
FROM reference_tracks
WHERE time_ns >= $start_ns
  AND time_ns < $end_ns
  AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
GROUP BY site, ais_class
ORDER BY site, ais_class;
