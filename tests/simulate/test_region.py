"""The `region` scenario: traffic plan, sensors, streaming writer, config file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pyais
import pytest
from mcap.reader import make_reader

from jobs.common import UsageError
from jobs.simulate import DEFAULT_START_NS, run_simulate
from pipeline.families import load_config
from pipeline.frames import enu_to_polar, geodetic_to_enu
from pipeline.simulate.region import SLICE_S, RegionSimulation, TrafficPlan
from pipeline.simulate.region_layout import region_config, region_layout, toml_text
from pipeline.units import NS

SHIPS, RADARS, SEED = 60, 3, 5


def _simulate(n_ships: int = SHIPS, duration_s: float = 1200.0, seed: int = SEED):
    sim = RegionSimulation(region_layout(RADARS), n_ships=n_ships, seed=seed,
                           start_ns=DEFAULT_START_NS, duration_s=duration_s)
    return list(sim.slices())


@pytest.fixture(scope="module")
def slices():
    return _simulate()


def test_slices_cover_the_run_in_order(slices) -> None:
    assert [s.start_ns for s in slices] == [DEFAULT_START_NS + k * SLICE_S * NS for k in (0, 1)]
    for s in slices:
        for frame, col in ((s.radar_reports, "log_time_ns"), (s.ais_sentences, "log_time_ns"),
                           (s.truth, "time_ns")):
            t = frame[col]
            assert t.min() >= s.start_ns and t.max() < s.end_ns


def test_deterministic_and_a_prefix_of_longer_runs(slices) -> None:
    again = _simulate(duration_s=600.0)
    for a, b in ((slices[0].radar_reports, again[0].radar_reports),
                 (slices[0].ais_sentences, again[0].ais_sentences),
                 (slices[0].truth, again[0].truth)):
        assert a.equals(b)
    other = _simulate(duration_s=600.0, seed=SEED + 1)
    assert not other[0].truth.equals(slices[0].truth)


def test_radar_reports_are_truth_plus_site_noise(slices) -> None:
    """Measured (not coasted) reports: range error against the followed vessel's truth
    (interpolated at the sweep time) ~ N(0, sigma_range)."""
    layout = region_layout(RADARS)
    radar = pl.concat([s.radar_reports.with_columns(s.radar_vessel) for s in slices])
    truth = pl.concat([s.truth for s in slices])
    assert radar["site_id"].n_unique() == RADARS
    for site in layout.sites:
        r = radar.filter((pl.col("site_id") == site.site_id) & (pl.col("status") != "coasting"))
        assert (r["range_m"] <= site.max_range_m + 100).all()
        assert r["sigma_range_m"].unique().to_list() == [site.sigma_range_m]
        assert ((r["log_time_ns"] >= r["time_ns"])
                & (r["log_time_ns"] - r["time_ns"] <= site.scan_period_s * NS)).all()
        errors = []
        for (vid,), g in r.group_by(["vessel_id"]):
            tv = truth.filter(pl.col("vessel_id") == vid).sort("time_ns")
            t = g["time_ns"].to_numpy()
            inside = (t >= tv["time_ns"][0]) & (t <= tv["time_ns"][-1])
            lat = np.interp(t, tv["time_ns"].to_numpy(), tv["lat_deg"].to_numpy())
            lon = np.interp(t, tv["time_ns"].to_numpy(), tv["lon_deg"].to_numpy())
            e, n = geodetic_to_enu(lat, lon, site.lat_deg, site.lon_deg)
            rng, _ = enu_to_polar(e, n)
            errors.append((g["range_m"].to_numpy() - rng)[inside])
        err = np.concatenate(errors)
        assert err.size > 500
        assert abs(err.mean()) < 0.2 * site.sigma_range_m
        assert 0.8 < err.std() / site.sigma_range_m < 1.25


def test_track_ids_continue_across_slices(slices) -> None:
    a, b = slices[0].radar_reports, slices[1].radar_reports
    for site in ("R1", "R2"):
        last = a.filter(pl.col("site_id") == site)["track_id"].unique()
        nxt = b.filter(pl.col("site_id") == site)["track_id"].unique()
        assert len(set(last.to_list()) & set(nxt.to_list())) > 0.5 * last.len()


def test_ais_sentences_decode_and_mix_classes(slices) -> None:
    ais = pl.concat([s.ais_sentences for s in slices])
    types: dict[int, int] = {}
    for m in pyais.IterMessages([s for s in ais["sentence"].to_list()]):
        t = m.decode().msg_type
        types[t] = types.get(t, 0) + 1
    assert types.get(1, 0) > 100 and types.get(18, 0) > 0 and types.get(5, 0) > 0
    assert types.get(24, 0) > 0
    # ships at anchor report navigational status 1
    status = {m.decode().status for m in pyais.IterMessages(ais["sentence"].to_list()[:2000])
              if m.decode().msg_type in (1, 3)}
    assert 1 in {int(s) for s in status}


def test_ships_without_ais_in_truth(slices) -> None:
    truth = pl.concat([s.truth for s in slices])
    per_vessel = truth.group_by("vessel_id").agg(pl.col("mmsi").first())
    share = per_vessel["mmsi"].is_null().mean()
    assert 0.03 < share < 0.4


def test_density_peaks_over_the_day() -> None:
    """The plan alone (no sensors): ships in the scene per hour swing around the mean."""
    plan = TrafficPlan(400, seed=3, start_ns=DEFAULT_START_NS)
    counts = []
    for h in range(24):
        t = h * 3600.0 + 1800.0
        counts.append(sum(v.t_enter_s <= t < v.t_exit_s for v in plan.active(t - 1, t + 1)))
    counts = np.array(counts)
    assert 300 < counts.mean() < 520
    assert counts.max() / counts.min() > 1.3
    kinds = {v.kind for v in plan.vessels}
    assert {"transit", "arrival", "anchor", "departure", "craft", "ferry"} <= kinds


def test_config_file_loads_and_round_trips(tmp_path: Path) -> None:
    doc = region_config(region_layout(4))
    path = tmp_path / "r.toml"
    path.write_text(toml_text(doc, header="test"))
    cfg = load_config(path)
    assert [s.site_id for s in cfg.radar_sites] == ["R1", "R2", "R3", "R4"]
    assert len(cfg.fairway_legs) == 9 and len(cfg.sectors) >= 8
    assert {s.scan_period_s for s in cfg.radar_sites} == {3.0, 4.0, 2.5}


def test_archive_and_config_written_by_simulate(tmp_path: Path) -> None:
    files = run_simulate("region", 900.0, 2, tmp_path, load_config(), ships=25, radars=2)
    assert [f.name for f in files] == ["region_20260115T000000Z.mcap"]
    cfg = load_config(tmp_path / "region.toml")
    assert len(cfg.radar_sites) == 2
    with files[0].open("rb") as f:
        reader = make_reader(f)
        topics = {c.topic for c in reader.get_summary().channels.values()}
        times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
    assert topics == {"/radar/R1/tracks", "/radar/R2/tracks", "/ais/nmea", "/truth/vessels"}
    assert times == sorted(times)


def test_scenario_options_are_checked(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="--ships"):
        run_simulate("channel", 60.0, 1, tmp_path, load_config(), ships=10)
    with pytest.raises(UsageError, match="at least 1"):
        run_simulate("region", 60.0, 1, tmp_path, load_config(), radars=0)
