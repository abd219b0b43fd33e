-- name: ais_quality
-- description: AIS data quality per transponder (MMSI), summarised per site, sector and
--   hour; worst transponders first. Each check and its source:
--   * reporting interval against the nominal one for the sender's class, speed, course
--     change and navigational status: ITU-R M.1371-5 Annex 1 §4.2, Table 1 (class A: 3 min
--     at anchor/moored <= 3 kn, 10 s at 0-14 kn, 3 1/3 s turning, 6 s at 14-23 kn, 2 s
--     turning or > 23 kn) and Table 2 (class B "CS": 3 min <= 2 kn, 30 s above); message
--     27: 3 min (Annex 4). "Changing course": COG changed by more than 5 deg within 30 s
--     (IEC 61993-2's 5 deg test). Conforming: within the nominal interval plus the
--     selection interval (SI = 20 % of it, M.1371-5 Annex 2 §3.3.4.2: $interval_slack)
--     plus 1 s; intervals longer than $gap_s are coverage gaps, not checked;
--   * MMSI validity and kind (ITU-R M.585-9 Annex 1): ship MIDXXXXXX, group 0MIDXXXXX,
--     coast/base station 00MIDXXXX, SAR aircraft 111MIDXXX, AtoN 99MIDXXXX, craft of a
--     parent ship 98MIDXXXX, handheld 8MIDXXXXX, AIS-SART 970, MOB 972, EPIRB 974; MID in
--     201-775 (the maritime identification digits of ITU's MID table); a kind that does
--     not fit the messages sent (message 4/11 from a non-base station, 21 from a non-AtoN,
--     9 from a non-SAR aircraft, position reports from a base station or AtoN);
--   * IMO number check digit (IMO Res. A.1078(28), ship identification number scheme:
--     7 digits, (7 d1 + 6 d2 + 5 d3 + 4 d4 + 3 d5 + 2 d6) mod 10 = d7), dimensions and ship
--     type present in the static data (messages 5, 24; M.1371-5 Annex 8);
--   * position jumps: consecutive positions farther apart than $min_jump_m at an implied
--     speed above $max_speed_kn;
--   * positions on land where the site declares land (inside a [gaps] island polygon: the
--     [gaps] admissible areas are where forecasts may go, not every water, so a position
--     outside them is not taken for land); NULL without any;
--   * SOG and COG against the track between consecutive reports (tolerances ours:
--     $sog_tol_kn and $cog_tol_deg plus 3 sigma of the track's own noise from a GNSS
--     position sigma $gnss_sigma_m);
--   * one MMSI from two transponders: reports that jump away and come back, i.e. the
--     report after an impossible jump is consistent with one 2 or 3 reports before
--     (Global Fishing Watch flags spoofed or shared MMSIs as spatially inconsistent
--     segments overlapping in time); $min_returns such returns flag it; more than one
--     ship name in the static data is shown beside;
--   * clock offset between the reception time and the report's own second (utc_second,
--     M.1371-5 Annex 2 §3.3.7.2), on reports whose reception time is their own (not
--     interpolated, not synthetic); late: more than $late_s after it, early: before.
--   Reports with synthetic times (a file without any time) are not checked in time; the
--   interval, SOG and COG checks take only times good to a second (a reception time of
--   their own, or one interpolated and moved to the report's utc_second).
-- grain: one row per (site, level, sector, hour, mmsi); level = site | sector_hour |
--   transponder (sector and hour NULL except for sector_hour, mmsi only for transponder)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $site_polygons (the config's sectors and coastline, bound by the runner),
--         $max_speed_kn (DOUBLE, default 50), $min_jump_m (DOUBLE, default 1000),
--         $gap_s (DOUBLE, default 600), $interval_slack (DOUBLE, default 0.2),
--         $min_conformance (DOUBLE, default 0.9), $sog_tol_kn (DOUBLE, default 3),
--         $cog_tol_deg (DOUBLE, default 30), $gnss_sigma_m (DOUBLE, default 10),
--         $late_s (DOUBLE, default 5), $min_returns (BIGINT, default 3)
-- source tables: ais_reports, ais_static, ais_other_messages (written by `surveil ingest`)
WITH polys AS (   -- the config's polygon edges (pipeline/reports.py: SiteGeometry)
    SELECT unnest(CAST($site_polygons AS STRUCT(kind VARCHAR, name VARCHAR, ord INTEGER,
                  lat1 DOUBLE, lon1 DOUBLE, lat2 DOUBLE, lon2 DOUBLE)[]), recursive := true)
),
coast AS (SELECT count(*) FILTER (WHERE kind = 'land') > 0 AS declared FROM polys),
pos0 AS (
    SELECT site, mmsi, time_ns, msg_type, ais_class, lat_deg, lon_deg, sog_mps / 0.514444 AS sog_kn,
           degrees(cog_rad) AS cog_deg, nav_status, utc_second, time_source,
           coalesce(time_source LIKE 'none:%' OR time_source LIKE '%:undated%', FALSE) AS synthetic,
           -- a time good to a second: its own, or interpolated and moved to its utc_second
           coalesce(time_source NOT LIKE 'interpolated:%' OR time_source LIKE '%+utc_second', TRUE)
               AS precise
    FROM ais_reports
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
pts AS (SELECT DISTINCT lat_deg, lon_deg FROM pos0),
crossings AS (   -- even-odd rule: the edges a ray east of the point crosses
    SELECT p.lat_deg, p.lon_deg, e.kind, e.name, e.ord
    FROM pts AS p JOIN polys AS e
      ON p.lat_deg >= least(e.lat1, e.lat2) AND p.lat_deg < greatest(e.lat1, e.lat2)
     AND p.lon_deg < e.lon1 + (p.lat_deg - e.lat1) * (e.lon2 - e.lon1) / (e.lat2 - e.lat1)
),
inside AS (
    SELECT lat_deg, lon_deg, kind, name, ord FROM crossings
    GROUP BY ALL HAVING count(*) % 2 = 1
),
place AS (
    SELECT p.lat_deg, p.lon_deg,
           coalesce((SELECT arg_min(i.name, i.ord) FROM inside AS i WHERE i.kind = 'sector'
                     AND i.lat_deg = p.lat_deg AND i.lon_deg = p.lon_deg), '(outside sectors)') AS sector,
           CASE WHEN NOT (SELECT declared FROM coast) THEN NULL
                ELSE EXISTS (SELECT 1 FROM inside AS i WHERE i.kind = 'land'
                             AND i.lat_deg = p.lat_deg AND i.lon_deg = p.lon_deg) END AS on_land
    FROM pts AS p
),
pos AS (   -- each report with the ones before it (per site and MMSI, in time order)
    SELECT r.*, pl.sector, pl.on_land,
           lag(time_ns, 1) OVER w AS t1, lag(lat_deg, 1) OVER w AS la1, lag(lon_deg, 1) OVER w AS lo1,
           lag(sog_kn, 1) OVER w AS sog1, lag(cog_deg, 1) OVER w AS cog1,
           lag(msg_type, 1) OVER w AS type1, lag(ais_class, 1) OVER w AS class1,
           lag(nav_status, 1) OVER w AS status1, lag(synthetic, 1) OVER w AS synthetic1,
           lag(precise, 1) OVER w AS precise1,
           lag(time_ns, 2) OVER w AS t2, lag(lat_deg, 2) OVER w AS la2, lag(lon_deg, 2) OVER w AS lo2,
           lag(cog_deg, 2) OVER w AS cog2,
           lag(time_ns, 3) OVER w AS t3, lag(lat_deg, 3) OVER w AS la3, lag(lon_deg, 3) OVER w AS lo3
    FROM pos0 AS r JOIN place AS pl USING (lat_deg, lon_deg)
    WINDOW w AS (PARTITION BY r.site, r.mmsi ORDER BY r.time_ns, r.lat_deg, r.lon_deg)
),
geo AS (   -- great-circle distance (R = 6,371,008.8 m, haversine) and bearing to each earlier report
    SELECT *,
           (time_ns - t1) / 1e9 AS dt_s, (time_ns - t2) / 1e9 AS dt2_s, (time_ns - t3) / 1e9 AS dt3_s,
           2 * 6371008.8 * asin(sqrt(pow(sin(radians(lat_deg - la1) / 2), 2) + cos(radians(la1))
               * cos(radians(lat_deg)) * pow(sin(radians(lon_deg - lo1) / 2), 2))) AS d_m,
           2 * 6371008.8 * asin(sqrt(pow(sin(radians(lat_deg - la2) / 2), 2) + cos(radians(la2))
               * cos(radians(lat_deg)) * pow(sin(radians(lon_deg - lo2) / 2), 2))) AS d2_m,
           2 * 6371008.8 * asin(sqrt(pow(sin(radians(lat_deg - la3) / 2), 2) + cos(radians(la3))
               * cos(radians(lat_deg)) * pow(sin(radians(lon_deg - lo3) / 2), 2))) AS d3_m,
           (degrees(atan2(sin(radians(lon_deg - lo1)) * cos(radians(lat_deg)),
                          cos(radians(la1)) * sin(radians(lat_deg))
                          - sin(radians(la1)) * cos(radians(lat_deg)) * cos(radians(lon_deg - lo1))))
            + 360) % 360 AS bearing_deg
    FROM pos
),
checks AS (
    SELECT *,
           d_m / greatest(dt_s, 1.0) / 0.514444 AS implied_kn,
           -- ITU-R M.1371-5 Annex 1, Tables 1 and 2: the interval the previous report promised
           CASE WHEN type1 = 27 THEN 180.0
                WHEN class1 = 'B' THEN CASE WHEN sog1 <= 2 THEN 180.0 WHEN sog1 > 2 THEN 30.0 END
                WHEN status1 IN (1, 5) AND sog1 <= 3 THEN 180.0
                WHEN sog1 <= 14 THEN CASE WHEN turning THEN 10.0 / 3 ELSE 10.0 END
                WHEN sog1 <= 23 THEN CASE WHEN turning THEN 2.0 ELSE 6.0 END
                WHEN sog1 > 23 THEN 2.0 END AS nominal_s
    FROM (SELECT *, coalesce(abs(((cog1 - cog2) + 540) % 360 - 180) > 5
                             AND (t1 - t2) <= 30e9, FALSE) AS turning FROM geo) AS g
),
flags AS (
    SELECT site, mmsi, time_ns, sector, on_land, synthetic, implied_kn, ais_class, time_source,
           (t1 IS NOT NULL AND precise AND precise1 AND NOT synthetic AND NOT synthetic1
            AND dt_s > 0 AND dt_s <= $gap_s AND nominal_s IS NOT NULL) AS interval_checked,
           dt_s <= nominal_s * (1 + $interval_slack) + 1 AS interval_ok,
           (t1 IS NOT NULL AND d_m > $min_jump_m AND implied_kn > $max_speed_kn) AS jump,
           -- back where it was 2 or 3 reports ago: a second transponder, not one bad fix
           (t1 IS NOT NULL AND d_m > $min_jump_m AND implied_kn > $max_speed_kn
            AND ((t2 IS NOT NULL AND (d2_m <= $min_jump_m OR d2_m / greatest(dt2_s, 1.0) / 0.514444 <= $max_speed_kn))
              OR (t3 IS NOT NULL AND (d3_m <= $min_jump_m OR d3_m / greatest(dt3_s, 1.0) / 0.514444 <= $max_speed_kn))))
                AS return_,
           (t1 IS NOT NULL AND precise AND precise1 AND NOT synthetic AND NOT synthetic1
            AND dt_s >= 2 AND dt_s <= $gap_s AND sog_kn IS NOT NULL AND sog1 IS NOT NULL
            AND NOT (d_m > $min_jump_m AND implied_kn > $max_speed_kn)) AS speed_checked,
           abs((sog_kn + sog1) / 2 - d_m / dt_s / 0.514444)
               > $sog_tol_kn + 3 * sqrt(2) * $gnss_sigma_m / dt_s / 0.514444 AS sog_bad,
           (t1 IS NOT NULL AND precise AND precise1 AND NOT synthetic AND NOT synthetic1
            AND dt_s <= $gap_s AND cog_deg IS NOT NULL AND cog1 IS NOT NULL AND (sog_kn + sog1) / 2 > 2
            AND d_m > 6 * $gnss_sigma_m
            AND NOT (d_m > $min_jump_m AND implied_kn > $max_speed_kn)) AS cog_checked,
           abs(((bearing_deg - degrees(atan2(sin(radians(cog_deg)) + sin(radians(cog1)),
                                             cos(radians(cog_deg)) + cos(radians(cog1))))) + 540) % 360 - 180)
               > $cog_tol_deg + degrees(atan(3 * sqrt(2) * $gnss_sigma_m / d_m)) AS cog_bad,
           (utc_second IS NOT NULL AND NOT synthetic AND time_source NOT LIKE 'interpolated:%'
            AND time_source NOT LIKE 'csv:%') AS clock_checked,
           ((time_ns % 60000000000) / 1e9 - utc_second)
               - 60 * round(((time_ns % 60000000000) / 1e9 - utc_second) / 60) AS clock_off_s
    FROM checks
),
stat AS (   -- each MMSI's static data in the window
    SELECT site, mmsi, arg_max(shipname, time_ns) FILTER (WHERE shipname IS NOT NULL) AS name,
           count(DISTINCT shipname) AS names, max(imo) AS imo,
           bool_or(length_m IS NOT NULL AND width_m IS NOT NULL) AS has_dimensions,
           bool_or(ship_type IS NOT NULL) AS has_ship_type
    FROM ais_static
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
    GROUP BY site, mmsi
),
other AS (
    SELECT site, mmsi, time_ns, msg_type, ais_class, lat_deg, lon_deg
    FROM ais_other_messages
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
senders AS (   -- what each MMSI sent: position reports, base station, AtoN, SAR reports
    SELECT site, mmsi, bool_or(kind = 'position') AS positions, bool_or(kind = 'base_station') AS base,
           bool_or(kind = 'aton') AS aton, bool_or(kind = 'sar_aircraft') AS sar,
           mode(cls ORDER BY cls) FILTER (WHERE cls IN ('A', 'B')) AS vessel_class
    FROM (SELECT site, mmsi, 'position' AS kind, ais_class AS cls FROM pos0
          UNION ALL SELECT site, mmsi, coalesce(ais_class, 'other'), NULL FROM other
          UNION ALL SELECT site, mmsi, 'static', NULL FROM stat) AS s
    GROUP BY site, mmsi
),
tp AS (   -- ITU-R M.585-9 Annex 1 identities; IMO check digit (IMO Res. A.1078(28))
    SELECT s.*, st.name, st.names, st.imo, st.has_dimensions, st.has_ship_type,
           CASE WHEN s.mmsi BETWEEN 201000000 AND 775999999 THEN 'ship'
                WHEN s.mmsi BETWEEN 20100000 AND 77599999 THEN 'group'
                WHEN s.mmsi BETWEEN 2010000 AND 7759999 THEN 'coast_station'
                WHEN s.mmsi BETWEEN 111201000 AND 111775999 THEN 'sar_aircraft'
                WHEN s.mmsi BETWEEN 992010000 AND 997759999 THEN 'aton'
                WHEN s.mmsi BETWEEN 982010000 AND 987759999 THEN 'auxiliary'
                WHEN s.mmsi BETWEEN 970000000 AND 970999999 THEN 'sart'
                WHEN s.mmsi BETWEEN 972000000 AND 972999999 THEN 'mob'
                WHEN s.mmsi BETWEEN 974000000 AND 974999999 THEN 'epirb'
                WHEN s.mmsi BETWEEN 820100000 AND 877599999 THEN 'handheld'
                ELSE 'invalid' END AS mmsi_kind,
           CASE WHEN st.imo IS NULL THEN NULL
                WHEN st.imo NOT BETWEEN 1000000 AND 9999999 THEN FALSE
                ELSE (7 * (st.imo // 1000000 % 10) + 6 * (st.imo // 100000 % 10)
                      + 5 * (st.imo // 10000 % 10) + 4 * (st.imo // 1000 % 10)
                      + 3 * (st.imo // 100 % 10) + 2 * (st.imo // 10 % 10)) % 10 = st.imo % 10
                END AS imo_valid
    FROM senders AS s LEFT JOIN stat AS st USING (site, mmsi)
),
tp2 AS (
    SELECT *, mmsi_kind <> 'invalid' AS mmsi_valid,
           mmsi_kind <> 'invalid' AND (
               (base AND mmsi_kind <> 'coast_station') OR (aton AND mmsi_kind <> 'aton')
               OR (sar AND mmsi_kind <> 'sar_aircraft')
               OR (positions AND mmsi_kind IN ('coast_station', 'aton', 'sar_aircraft'))) AS kind_mismatch,
           positions AND name IS NULL AND imo IS NULL AND has_dimensions IS NULL AS no_static
    FROM tp
),
per_mmsi AS (   -- window-level figures of each MMSI (the transponder's verdicts)
    SELECT site, mmsi,
           sum(CASE WHEN return_ THEN 1 ELSE 0 END) AS returns,
           count(*) FILTER (WHERE interval_checked) AS ic,
           count(*) FILTER (WHERE interval_checked AND interval_ok) AS iok,
           count(*) FILTER (WHERE jump) AS jumps,
           count(*) FILTER (WHERE on_land) AS land,
           count(*) FILTER (WHERE speed_checked AND sog_bad) AS sog_bad,
           count(*) FILTER (WHERE cog_checked AND cog_bad) AS cog_bad,
           count(*) FILTER (WHERE clock_checked AND abs(clock_off_s) > $late_s) AS clock_bad
    FROM flags GROUP BY site, mmsi
),
verdict AS (
    SELECT t.*, coalesce(p.returns, 0) >= $min_returns AS shared,
           concat_ws(',',
               CASE WHEN NOT t.mmsi_valid THEN 'mmsi_invalid' END,
               CASE WHEN t.kind_mismatch THEN 'mmsi_kind' END,
               CASE WHEN t.imo_valid = FALSE THEN 'imo_check_digit' END,
               CASE WHEN t.no_static THEN 'no_static' END,
               CASE WHEN t.positions AND NOT t.no_static AND t.vessel_class IS NOT NULL
                         AND NOT coalesce(t.has_dimensions, FALSE) THEN 'no_dimensions' END,
               CASE WHEN t.positions AND NOT t.no_static AND NOT coalesce(t.has_ship_type, FALSE)
                    THEN 'no_ship_type' END,
               CASE WHEN p.ic >= 3 AND p.iok < $min_conformance * p.ic THEN 'interval' END,
               CASE WHEN p.jumps > 0 THEN 'position_jump' END,
               CASE WHEN p.land > 0 THEN 'on_land' END,
               CASE WHEN p.sog_bad > 0 THEN 'sog_track' END,
               CASE WHEN p.cog_bad > 0 THEN 'cog_track' END,
               CASE WHEN coalesce(p.returns, 0) >= $min_returns THEN 'two_transponders' END,
               CASE WHEN p.clock_bad > 0 THEN 'clock' END) AS failed
    FROM tp2 AS t LEFT JOIN per_mmsi AS p USING (site, mmsi)
),
rows_ AS (   -- every message once; position reports carry the checks
    SELECT f.site, f.mmsi, f.time_ns, f.sector, TRUE AS is_pos, f.on_land, f.synthetic,
           f.interval_checked, f.interval_ok, f.jump, f.implied_kn, f.return_, f.speed_checked,
           f.sog_bad, f.cog_checked, f.cog_bad, f.clock_checked, f.clock_off_s
    FROM flags AS f
    UNION ALL
    SELECT o.site, o.mmsi, o.time_ns, '(no position)', FALSE, NULL, FALSE, FALSE, NULL, FALSE,
           NULL, FALSE, FALSE, NULL, FALSE, NULL, FALSE, NULL
    FROM other AS o
),
kept AS (
    SELECT r.*, v.mmsi_valid, v.kind_mismatch, v.imo_valid, v.no_static, v.shared, v.failed,
           v.positions, v.has_dimensions, v.has_ship_type, v.vessel_class,
           strftime(date_trunc('hour', make_timestamp(r.time_ns // 1000)), '%Y-%m-%dT%H:00Z') AS hour
    FROM rows_ AS r JOIN verdict AS v USING (site, mmsi)
    WHERE CAST($sector AS VARCHAR) IS NULL OR r.sector = CAST($sector AS VARCHAR)
),
grouped AS (
    SELECT site,
           CASE WHEN grouping(mmsi) = 0 THEN 'transponder'
                WHEN grouping(sector) = 0 THEN 'sector_hour' ELSE 'site' END AS level,
           sector, CASE WHEN grouping(hour) = 0 AND NOT bool_and(synthetic) THEN hour END AS hour, mmsi,
           count(DISTINCT mmsi) AS transponders,
           count(*) AS messages,
           count(*) FILTER (WHERE is_pos) AS position_reports,
           count(DISTINCT mmsi) FILTER (WHERE NOT mmsi_valid) AS invalid_mmsi,
           count(DISTINCT mmsi) FILTER (WHERE kind_mismatch) AS kind_mismatch,
           count(DISTINCT mmsi) FILTER (WHERE imo_valid = FALSE) AS bad_imo,
           count(DISTINCT mmsi) FILTER (WHERE no_static) AS no_static,
           count(DISTINCT mmsi) FILTER (WHERE positions AND NOT no_static AND vessel_class IS NOT NULL
                                        AND NOT coalesce(has_dimensions, FALSE)) AS no_dimensions,
           count(DISTINCT mmsi) FILTER (WHERE positions AND NOT no_static
                                        AND NOT coalesce(has_ship_type, FALSE)) AS no_ship_type,
           count(*) FILTER (WHERE interval_checked) AS intervals_checked,
           count(*) FILTER (WHERE interval_checked AND interval_ok) AS intervals_conforming,
           count(*) FILTER (WHERE jump) AS jumps,
           max(implied_kn) FILTER (WHERE jump) AS max_jump_kn,
           count(*) FILTER (WHERE is_pos AND on_land IS NOT NULL) AS land_checked,
           count(*) FILTER (WHERE on_land) AS on_land,
           count(*) FILTER (WHERE speed_checked) AS sog_checked,
           count(*) FILTER (WHERE speed_checked AND sog_bad) AS sog_mismatch,
           count(*) FILTER (WHERE cog_checked) AS cog_checked,
           count(*) FILTER (WHERE cog_checked AND cog_bad) AS cog_mismatch,
           count(*) FILTER (WHERE return_) AS returns,
           count(DISTINCT mmsi) FILTER (WHERE shared) AS two_transponders,
           count(*) FILTER (WHERE clock_checked) AS clock_checked,
           median(clock_off_s) FILTER (WHERE clock_checked) AS median_clock_offset_s,
           count(*) FILTER (WHERE clock_checked AND clock_off_s > $late_s) AS late_reports,
           count(*) FILTER (WHERE clock_checked AND clock_off_s < -$late_s) AS early_reports,
           count(DISTINCT mmsi) FILTER (WHERE failed <> '') AS with_problems
    FROM kept
    GROUP BY GROUPING SETS ((site), (site, sector, hour), (site, mmsi))
),
result AS (
    SELECT g.*, v.mmsi_kind, v.vessel_class, v.name, v.names, v.imo, v.imo_valid, v.failed,
           CASE WHEN g.level = 'transponder' THEN
               length(v.failed) - length(replace(v.failed, ',', '')) + (v.failed <> '')::INTEGER END
               AS problems
    FROM grouped AS g LEFT JOIN verdict AS v ON g.level = 'transponder' AND v.site = g.site
                                             AND v.mmsi = g.mmsi
)
SELECT
    site::VARCHAR                                                     AS site,                 -- site (deployment)
    level::VARCHAR                                                    AS level,                -- site | sector_hour | transponder
    sector::VARCHAR                                                   AS sector,               -- sector_hour: sector of the positions ('(no position)': other messages)
    hour::VARCHAR                                                     AS hour_utc,             -- sector_hour: UTC hour
    mmsi::BIGINT                                                      AS mmsi,                 -- transponder: MMSI
    name::VARCHAR                                                     AS name,                 -- transponder: latest ship name
    mmsi_kind::VARCHAR                                                AS mmsi_kind,            -- transponder: ITU-R M.585 kind of the MMSI (invalid: no pattern)
    vessel_class::VARCHAR                                             AS ais_class,            -- transponder: class of its position reports
    problems::INTEGER                                                 AS problems,             -- transponder: checks failed
    failed::VARCHAR                                                   AS checks_failed,        -- transponder: which
    with_problems::BIGINT                                             AS transponders_with_problems, -- transponders failing any check
    transponders::BIGINT                                              AS transponders,         -- distinct MMSIs
    messages::BIGINT                                                  AS messages,             -- messages (positions and other types)
    position_reports::BIGINT                                          AS position_reports,     -- position reports
    invalid_mmsi::BIGINT                                              AS invalid_mmsi,         -- MMSIs of no ITU-R M.585 pattern
    kind_mismatch::BIGINT                                             AS mmsi_kind_mismatch,   -- MMSIs whose kind does not fit their messages
    bad_imo::BIGINT                                                   AS bad_imo,              -- IMO numbers failing the check digit
    no_static::BIGINT                                                 AS no_static,            -- vessels without static data
    no_dimensions::BIGINT                                             AS no_dimensions,        -- vessels whose static data has no dimensions
    no_ship_type::BIGINT                                              AS no_ship_type,         -- ... no ship type
    intervals_checked::BIGINT                                         AS intervals_checked,    -- reporting intervals with a nominal one
    round(intervals_conforming / nullif(intervals_checked, 0), 3)::DOUBLE AS interval_conformance, -- share within the nominal interval (+ SI + 1 s)
    jumps::BIGINT                                                     AS position_jumps,       -- impossible jumps
    round(max_jump_kn, 0)::DOUBLE                                     AS max_jump_kn,          -- fastest implied speed of a jump, kn
    land_checked::BIGINT                                              AS land_checked,         -- positions tested against the coastline (0: none declared)
    on_land::BIGINT                                                   AS positions_on_land,    -- positions on land
    sog_checked::BIGINT                                               AS sog_checked,          -- report pairs whose SOG was compared with the track
    sog_mismatch::BIGINT                                              AS sog_mismatch,         -- ... beyond the tolerance
    cog_checked::BIGINT                                               AS cog_checked,          -- report pairs whose COG was compared with the track
    cog_mismatch::BIGINT                                              AS cog_mismatch,         -- ... beyond the tolerance
    returns::BIGINT                                                   AS jump_returns,         -- jumps back to where it was 2-3 reports before
    two_transponders::BIGINT                                          AS two_transponders,     -- MMSIs flagged as sent by two transponders
    names::BIGINT                                                     AS ship_names,           -- transponder: distinct ship names it sent
    imo::BIGINT                                                       AS imo,                  -- transponder: IMO number
    imo_valid::BOOLEAN                                                AS imo_valid,            -- transponder: check digit right (NULL: no IMO)
    clock_checked::BIGINT                                             AS clock_checked,        -- reports with an own reception time and utc_second
    round(median_clock_offset_s, 2)::DOUBLE                           AS median_clock_offset_s,-- reception second minus utc_second, s (wrapped to +-30)
    late_reports::BIGINT                                              AS late_reports,         -- received more than $late_s after their second
    early_reports::BIGINT                                             AS early_reports         -- received more than $late_s before it (a clock off)
FROM result
ORDER BY site, list_position(['site', 'sector_hour', 'transponder'], level), sector, hour_utc,
         problems DESC, position_reports DESC, mmsi;
