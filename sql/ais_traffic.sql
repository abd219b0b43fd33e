-- name: ais_traffic
-- description: the AIS traffic picture: vessels, messages and message rate in total, per
--   station class (class A, class B, base station, AtoN, SAR aircraft: from the message
--   type, ITU-R M.1371-5 Annex 8), per message type, per time source, per hour and per
--   sector, the share of vessels that sent static data (messages 5, 24, 19, or an AIS
--   CSV's static columns), and the busiest vessels. Rows whose time is synthetic (a file
--   without any time) count as messages but give no rate and no hour.
-- grain: one row per (site, breakdown, key); breakdown = total | class | msg_type |
--   time_source | hour | sector | vessel (the $top_n busiest)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $site_polygons (the config's sectors, bound by the runner),
--         $top_n (BIGINT, default 20)
-- source tables: ais_reports, ais_static, ais_other_messages (written by `surveil ingest`)
WITH polys AS (   -- the config's polygon edges (pipeline/reports.py: SiteGeometry)
    SELECT unnest(CAST($site_polygons AS STRUCT(kind VARCHAR, name VARCHAR, ord INTEGER,
                  lat1 DOUBLE, lon1 DOUBLE, lat2 DOUBLE, lon2 DOUBLE)[]), recursive := true)
),
msgs AS (   -- every message once: position reports, static messages, every other type
    SELECT site, time_ns, mmsi, msg_type, ais_class AS station_class, lat_deg, lon_deg,
           time_source, TRUE AS vessel
    FROM ais_reports
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
    UNION ALL   -- 19 is in ais_reports too; a CSV row's static columns are not a message
    SELECT site, time_ns, mmsi, msg_type, ais_class, NULL, NULL, time_source, TRUE
    FROM ais_static
    WHERE time_ns >= $start_ns AND time_ns < $end_ns AND msg_type IN (5, 24)
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
    UNION ALL
    SELECT site, time_ns, mmsi, msg_type, coalesce(ais_class, 'other'), lat_deg, lon_deg,
           time_source, FALSE
    FROM ais_other_messages
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
pts AS (SELECT DISTINCT lat_deg, lon_deg FROM msgs WHERE lat_deg IS NOT NULL),
crossings AS (   -- even-odd rule: the edges a ray east of the point crosses
    SELECT p.lat_deg, p.lon_deg, e.name, e.ord
    FROM pts AS p JOIN polys AS e
      ON e.kind = 'sector'
     AND p.lat_deg >= least(e.lat1, e.lat2) AND p.lat_deg < greatest(e.lat1, e.lat2)
     AND p.lon_deg < e.lon1 + (p.lat_deg - e.lat1) * (e.lon2 - e.lon1) / (e.lat2 - e.lat1)
),
in_sector AS (   -- a point belongs to the first sector (config order) that holds it
    SELECT lat_deg, lon_deg, arg_min(name, ord) AS sector
    FROM (SELECT lat_deg, lon_deg, name, ord FROM crossings
          GROUP BY ALL HAVING count(*) % 2 = 1) AS odd
    GROUP BY lat_deg, lon_deg
),
m AS (
    SELECT msgs.*,
           CASE WHEN msgs.lat_deg IS NULL THEN '(no position)'
                ELSE coalesce(s.sector, '(outside sectors)') END AS sector,
           (time_source LIKE 'none:%' OR time_source LIKE '%:undated%') AS synthetic
    FROM msgs LEFT JOIN in_sector AS s USING (lat_deg, lon_deg)
),
vessel_sectors AS (   -- the sectors each MMSI reported a position in
    SELECT DISTINCT site, mmsi, sector FROM m WHERE lat_deg IS NOT NULL
),
kept AS (   -- $sector: the messages of the vessels seen in it (positions: in it)
    SELECT m.* FROM m
    WHERE CAST($sector AS VARCHAR) IS NULL
       OR (m.lat_deg IS NOT NULL AND m.sector = CAST($sector AS VARCHAR))
       OR (m.lat_deg IS NULL AND EXISTS (
               SELECT 1 FROM vessel_sectors AS v
               WHERE v.site = m.site AND v.mmsi = m.mmsi AND v.sector = CAST($sector AS VARCHAR)))
),
with_static AS (   -- vessels with static data in the window (any static row, CSV included)
    SELECT DISTINCT site, mmsi FROM ais_static
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
),
names AS (
    SELECT site, mmsi, arg_max(shipname, time_ns) AS name FROM ais_static
    WHERE time_ns >= $start_ns AND time_ns < $end_ns AND shipname IS NOT NULL
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
    GROUP BY site, mmsi
),
keyed AS (   -- each message under each breakdown it counts in
    SELECT site, mmsi, vessel, time_ns, synthetic, 'total' AS breakdown, 'all' AS key FROM kept
    UNION ALL SELECT site, mmsi, vessel, time_ns, synthetic, 'class', station_class FROM kept
    UNION ALL SELECT site, mmsi, vessel, time_ns, synthetic, 'msg_type',
                     lpad(CAST(msg_type AS VARCHAR), 2, '0') FROM kept
    UNION ALL SELECT site, mmsi, vessel, time_ns, synthetic, 'time_source',
                     coalesce(time_source, '(unknown)') FROM kept
    UNION ALL SELECT site, mmsi, vessel, time_ns, synthetic, 'hour',
                     strftime(date_trunc('hour', make_timestamp(time_ns // 1000)), '%Y-%m-%dT%H:00Z')
              FROM kept WHERE NOT synthetic
    UNION ALL SELECT site, mmsi, vessel, time_ns, synthetic, 'sector', sector FROM kept
              WHERE lat_deg IS NOT NULL
    UNION ALL SELECT site, mmsi, vessel, time_ns, synthetic, 'vessel', CAST(mmsi AS VARCHAR)
              FROM kept WHERE vessel
),
agg AS (
    SELECT k.site, k.breakdown, k.key,
           count(DISTINCT k.mmsi) FILTER (WHERE k.vessel) AS vessels,
           count(DISTINCT k.mmsi) AS stations,
           count(*) AS messages,
           count(*) FILTER (WHERE NOT k.synthetic) AS timed,
           min(k.time_ns) FILTER (WHERE NOT k.synthetic) AS first_ns,
           max(k.time_ns) FILTER (WHERE NOT k.synthetic) AS last_ns,
           count(DISTINCT k.mmsi) FILTER (WHERE k.vessel AND w.mmsi IS NOT NULL) AS with_static
    FROM keyed AS k LEFT JOIN with_static AS w ON w.site = k.site AND w.mmsi = k.mmsi
    GROUP BY k.site, k.breakdown, k.key
),
ranked AS (
    SELECT agg.*, row_number() OVER (PARTITION BY site ORDER BY messages DESC, key) AS busy
    FROM agg WHERE breakdown = 'vessel'
),
result AS (
SELECT
    a.site::VARCHAR                                                  AS site,              -- site (deployment)
    a.breakdown::VARCHAR                                             AS breakdown,         -- total | class | msg_type | time_source | hour | sector | vessel
    a.key::VARCHAR                                                   AS key,               -- class (A, B, base_station, aton, sar_aircraft, other), message id, time source, hour (UTC), sector, MMSI
    n.name::VARCHAR                                                  AS name,              -- vessel rows: its latest ship name
    a.vessels::BIGINT                                                AS vessels,           -- distinct MMSIs of vessels (class A/B messages)
    a.stations::BIGINT                                               AS stations,          -- distinct MMSIs of every sender
    a.messages::BIGINT                                               AS messages,          -- AIS messages (a multi-part message once)
    round(nullif(a.timed, 0) / greatest((a.last_ns - a.first_ns) / 3.6e12, 1.0 / 60), 1)::DOUBLE
                                                                     AS messages_per_hour, -- over the span of its timed messages (>= 1 min); NULL: synthetic times only
    round(a.with_static / nullif(a.vessels, 0), 3)::DOUBLE           AS static_share,      -- share of its vessels that sent static data in the window
    (a.messages - a.timed)::BIGINT                                   AS synthetic_messages,-- messages whose time is synthetic (no time in their file)
    make_timestamp((a.first_ns // 1000)::BIGINT)::TIMESTAMP          AS first_utc,         -- first timed message
    make_timestamp((a.last_ns // 1000)::BIGINT)::TIMESTAMP           AS last_utc           -- last timed message
FROM agg AS a
LEFT JOIN ranked AS r ON r.site = a.site AND r.breakdown = a.breakdown AND r.key = a.key
LEFT JOIN names AS n ON a.breakdown = 'vessel' AND n.site = a.site AND CAST(n.mmsi AS VARCHAR) = a.key
WHERE a.breakdown <> 'vessel' OR r.busy <= $top_n
)
SELECT * FROM result
ORDER BY site,
         list_position(['total', 'class', 'msg_type', 'time_source', 'hour', 'sector', 'vessel'], breakdown),
         CASE WHEN breakdown = 'vessel' THEN -messages END NULLS FIRST,
         key;
