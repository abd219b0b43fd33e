"""`surveil export`: the MCAP file read back with `mcap` and the protobuf schemas holds
every warehouse point of the window, on its source's topic, at the track time."""

from __future__ import annotations

import json
from collections import defaultdict

import numpy as np
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from pipeline.export import write_export
from pipeline.frames import enu_to_geodetic
from pipeline.warehouse.delta import read_table


def test_export_round_trips(e2e, tmp_path):
    out = tmp_path / "window.mcap"
    summary = write_export(e2e.cfg, e2e.warehouse, out, start_ns=e2e.start_ns, end_ns=e2e.end_ns)
    got: dict[str, list] = defaultdict(list)
    schemas: dict[str, str] = {}
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            schemas[channel.topic] = schema.name
            assert channel.message_encoding == "protobuf"
            got[channel.topic].append((message.log_time, decoded))
    assert {t: len(v) for t, v in got.items()} == summary.messages

    # every fused point: LocationFix with the track id as frame, at the track time
    st = read_table(e2e.warehouse, "system_tracks", start_ns=e2e.start_ns, end_ns=e2e.end_ns)
    want = sorted(zip(st["time_ns"].to_pylist(), map(str, st["system_track_id"].to_pylist()),
                      st["lat_deg"].to_pylist(), st["lon_deg"].to_pylist(),
                      st["sigma_x_m"].to_pylist(), strict=True))
    have = sorted((t, m.frame_id, m.latitude, m.longitude, m.position_covariance[0] ** 0.5)
                  for t, m in got["/fused/location"])
    assert schemas["/fused/location"] == "foxglove.LocationFix"
    assert len(have) == len(want) > 1000
    for h, w in zip(have, want, strict=True):
        assert h[:4] == w[:4] and abs(h[4] - w[4]) < 1e-9
    assert all(m.timestamp.seconds * 10**9 + m.timestamp.nanos == t
               for t, m in got["/fused/location"])

    # each radar's synchronised points, one topic per site, ENU -> WGS-84
    assoc = read_table(e2e.warehouse, "associations", start_ns=e2e.start_ns, end_ns=e2e.end_ns)
    lat, lon = enu_to_geodetic(assoc["x_enu_m"].to_numpy(), assoc["y_enu_m"].to_numpy(),
                               e2e.cfg.region.origin_lat_deg, e2e.cfg.region.origin_lon_deg)
    for site in sorted(set(assoc["site_id"].to_pylist())):
        mask = np.asarray(assoc["site_id"].to_pylist()) == site
        want_r = sorted(zip(assoc["time_ns"].to_numpy()[mask].tolist(),
                            [f"{site}-{v}" for v in assoc["local_track_id"].to_numpy()[mask]],
                            lat[mask].tolist(), lon[mask].tolist(), strict=True))
        have_r = sorted((t, m.frame_id, m.latitude, m.longitude)
                        for t, m in got[f"/radar/{site}/location"])
        assert have_r == want_r

    # AIS positions by MMSI
    ais = read_table(e2e.warehouse, "ais_reports", start_ns=e2e.start_ns, end_ns=e2e.end_ns)
    assert sorted((t, m.frame_id, m.latitude, m.longitude) for t, m in got["/ais/location"]) \
        == sorted(zip(ais["time_ns"].to_pylist(), map(str, ais["mmsi"].to_pylist()),
                      ais["lat_deg"].to_pylist(), ais["lon_deg"].to_pylist(), strict=True))

    # geometry: GeoJSON of every sector and leg; the scene in the regional ENU frame
    (t0, geo), = got["/geometry"]
    assert t0 == e2e.start_ns and schemas["/geometry"] == "foxglove.GeoJSON"
    names = {f["properties"]["name"] for f in json.loads(geo.geojson)["features"]}
    assert {s.name for s in e2e.cfg.sectors} | {leg.leg_id for leg in e2e.cfg.fairway_legs} <= names
    assert schemas["/fused/scene"] == "foxglove.SceneUpdate"
    scene_ids = {e.id for _, m in got["/fused/scene"] for e in m.entities}
    assert scene_ids == {f"fused/{i}" for i in set(st["system_track_id"].to_pylist())}
    assert all(e.frame_id == "region_enu" for _, m in got["/fused/scene"] for e in m.entities)
    times = [t for topic in got for t, _ in got[topic]]
    assert min(times) >= e2e.start_ns and max(times) < e2e.end_ns
