-- name: map_tracks
-- description: the window's tracks for a map, thinned to one point per track every
--   $step_s seconds: fused system tracks and each radar's synchronised tracks (regional
--   ENU, plus WGS-84 for the fused), AIS positions by MMSI, airfield fused surface
--   tracks. Rows of one track are in time order; a map draws each (layer, track) as a line.
-- grain: one row per (site, layer, track, thinned time)
-- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive),
--         $sector (VARCHAR, NULL = every sector), $site (VARCHAR, NULL = every site),
--         $step_s (DOUBLE, default 20, >= 0.001)
-- source tables: system_tracks, associations, ais_reports, airfield_tracks
WITH pts AS (
    SELECT site, 'fused' AS layer, CAST(system_track_id AS VARCHAR) AS track, time_ns,
           lat_deg, lon_deg, x_enu_m, y_enu_m, sector
    FROM system_tracks
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
    UNION ALL
    SELECT site, 'radar ' || site_id, site_id || '-' || CAST(local_track_id AS VARCHAR), time_ns,
           NULL, NULL, x_enu_m, y_enu_m, sector
    FROM associations
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
    UNION ALL
    SELECT site, 'ais', CAST(mmsi AS VARCHAR), time_ns, lat_deg, lon_deg, NULL, NULL, NULL
    FROM ais_reports
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
    UNION ALL
    SELECT site, 'airfield', track_id, time_ns, lat_deg, lon_deg, NULL, NULL, sector
    FROM airfield_tracks
    WHERE time_ns >= $start_ns AND time_ns < $end_ns
),
thinned AS (
    SELECT *, time_ns // CAST(round($step_s * 1e9) AS BIGINT) AS slot
    FROM pts
    WHERE (CAST($sector AS VARCHAR) IS NULL OR sector = CAST($sector AS VARCHAR))
      AND (CAST($site AS VARCHAR) IS NULL OR site = CAST($site AS VARCHAR))
)
SELECT
    site::VARCHAR               AS site,       -- site (deployment)
    layer::VARCHAR              AS layer,      -- fused | radar <site> | ais | airfield
    track::VARCHAR              AS track,      -- system track id, <site>-<local id>, MMSI, airfield track id
    min(time_ns)::BIGINT        AS time_ns,    -- first point of the slot, ns UTC
    arg_min(lat_deg, time_ns)::DOUBLE AS lat_deg,   -- WGS-84, deg (NULL for radar layers)
    arg_min(lon_deg, time_ns)::DOUBLE AS lon_deg,
    arg_min(x_enu_m, time_ns)::DOUBLE AS x_enu_m,   -- regional ENU east, m (NULL for ais, airfield)
    arg_min(y_enu_m, time_ns)::DOUBLE AS y_enu_m
FROM thinned
GROUP BY site, layer, track, slot
ORDER BY site, layer, track, time_ns;
