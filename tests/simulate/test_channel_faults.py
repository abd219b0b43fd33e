"""Channel faults of the `channel` simulator ([[channel_faults]], issue 22): each fault
does what it says to the reports of its channel and nothing else (a faulty run and the
fault-free run share every noise sample), and its truth is written."""

from __future__ import annotations

import math

import numpy as np
import polars as pl
import pytest

from pipeline.config import ConfigError
from pipeline.decode.ais import decode_ais_sentences
from pipeline.families import config_from_mapping
from pipeline.maritime.config import ChannelFault, channel_faults, with_faults, without_faults
from pipeline.simulate.channel import simulate_channel
from pipeline.simulate.channel_faults import in_azimuths
from pipeline.units import NS

START = 1_768_435_200 * NS
DURATION_S = 420.0
SEED = 5


def run(cfg, *faults: ChannelFault):
    return simulate_channel(with_faults(cfg, faults), start_ns=START, duration_s=DURATION_S,
                            seed=SEED)


@pytest.fixture(scope="module")
def clean(cfg):
    return simulate_channel(without_faults(cfg), start_ns=START, duration_s=DURATION_S,
                            seed=SEED)


def ais_rows(sc) -> pl.DataFrame:
    s = sc.ais_sentences
    rep, _, _ = decode_ais_sentences([x.encode() for x in s["sentence"].to_list()],
                                     s["log_time_ns"].to_numpy(), source_file="t", topic="t")
    return pl.from_arrow(rep).select("time_ns", "mmsi", "lat_deg", "lon_deg")


def window(f: ChannelFault) -> pl.Expr:
    return pl.col("time_ns").is_between(START + round(f.start_s * NS),
                                        START + round(f.end_s * NS), closed="left")


def test_default_schedule_parses_every_kind(cfg):
    from pipeline.simulate.scenarios import with_scenario

    kinds = {f.kind for f in channel_faults(with_scenario(cfg, ["channel"]))}
    assert kinds == {"radar_outage", "radar_blank", "radar_range_bias", "radar_azimuth_bias",
                     "radar_time_offset", "radar_noise", "ais_offset", "ais_stuck",
                     "ais_mmsi_swap", "ais_spoof"}


@pytest.mark.parametrize("entry, message", [
    ({"kind": "radar_range_bias", "site_id": "R9", "start_s": 0, "duration_s": 1}, "site_id"),
    ({"kind": "radar_range_bias", "site_id": "R1", "start_s": 0, "duration_s": 1, "bias": 5},
     "unknown key"),
    ({"kind": "ais_offset", "sector": "nowhere", "start_s": 0, "duration_s": 1}, "sector"),
    ({"kind": "meteor", "start_s": 0, "duration_s": 1}, "kind"),
    ({"kind": "ais_spoof", "start_s": 0, "duration_s": 1}, "mmsi"),
    ({"kind": "radar_noise", "site_id": "R1", "start_s": 0, "duration_s": 1, "factor": 0.5},
     "factor"),
])
def test_bad_fault_entries_fail_the_load(cfg, entry, message, tmp_path):
    import tomllib

    from pipeline.families import with_scenario_files

    scenario = tmp_path / "scenario.toml"
    scenario.write_text("[[channel_faults]]\n" + "\n".join(
        f"{k} = {v!r}".replace("'", '"') for k, v in entry.items()) + "\n", encoding="utf-8")
    assert tomllib.loads(scenario.read_text())["channel_faults"] == [entry]
    with pytest.raises(ConfigError, match=message):
        with_scenario_files(cfg, [scenario])
    with pytest.raises(ConfigError, match="is a simulator setting"):  # never in a site config
        config_from_mapping({**cfg.sections, "channel_faults": [entry]})


def test_no_schedule_is_the_fault_free_scenario(cfg, clean):
    again = run(cfg)
    assert again.radar_reports.equals(clean.radar_reports)
    assert again.ais_sentences.equals(clean.ais_sentences)
    assert again.fault_truth.height == 0


@pytest.mark.parametrize("kind, column, field, value", [
    ("radar_range_bias", "range_m", "range_bias_m", 80.0),
    ("radar_azimuth_bias", "azimuth_rad", "azimuth_bias_rad", math.radians(1.0)),
    ("radar_time_offset", "time_ns", "time_offset_s", 5.0),
])
def test_biases_add_exactly_their_value_during_the_fault(cfg, clean, kind, column, field, value):
    f = ChannelFault(kind, 120.0, 90.0, site_id="R2", **{field: value})
    sc = run(cfg, f)
    key = ["site_id", "track_id", "log_time_ns"]
    j = sc.radar_reports.join(clean.radar_reports, on=key, suffix="_clean")
    assert j.height == clean.radar_reports.height  # the tracker's life is unchanged
    diff = (j[column] - j[f"{column}_clean"]).to_numpy().astype(float)
    if column == "time_ns":
        diff /= NS
    if column == "azimuth_rad":
        diff = np.mod(diff + np.pi, 2 * np.pi) - np.pi
    on = ((j["site_id"] == "R2") & j.select(
        (pl.col("time_ns_clean") >= START + 120 * NS) & (pl.col("time_ns_clean") < START + 210 * NS)
    ).to_series()).to_numpy()
    measured = (j["status"] != "coasting").to_numpy()  # a coast predicts from a biased report
    assert (on & measured).sum() > 50
    np.testing.assert_allclose(diff[on & measured], value, atol=1e-6)
    np.testing.assert_allclose(diff[~on & measured], 0.0, atol=1e-9)
    assert sc.fault_truth.select("channel", "kind", "value").row(0) == ("R2", kind, value)


def test_range_gain_scales_the_true_range_during_the_fault(cfg, clean):
    f = ChannelFault("radar_range_gain", 120.0, 90.0, site_id="R2", range_gain=0.006)
    sc = run(cfg, f)
    j = sc.radar_reports.join(clean.radar_reports, on=["site_id", "track_id", "log_time_ns"],
                              suffix="_clean")
    assert j.height == clean.radar_reports.height
    measured = (pl.col("status") != "coasting") & (pl.col("site_id") == "R2")
    on = j.filter(measured & window(f))
    assert on.height > 50
    # faulty - clean = gain x the true range; the clean range is it within its 15 m noise
    ratio = ((on["range_m"] - on["range_m_clean"]) / on["range_m_clean"]).to_numpy()
    np.testing.assert_allclose(ratio, 0.006, rtol=0.03)
    off = j.filter(measured & ~window(f))
    assert (off["range_m"] - off["range_m_clean"]).abs().max() < 1e-9
    assert sc.fault_truth.select("channel", "kind", "value", "unit").row(0) == (
        "R2", "radar_range_gain", 0.006, "ratio")


def test_a_range_bias_with_azimuths_acts_there_only(cfg, clean):
    # an error over part of the rotation (from 300 through north to 30 deg, wrapping)
    f = ChannelFault("radar_range_bias", 120.0, 90.0, site_id="R2", range_bias_m=100.0,
                     azimuth_from_rad=math.radians(300), azimuth_to_rad=math.radians(30))
    sc = run(cfg, f)
    j = sc.radar_reports.join(clean.radar_reports, on=["site_id", "track_id", "log_time_ns"],
                              suffix="_clean")
    assert j.height == clean.radar_reports.height
    r = j.filter((pl.col("status") != "coasting") & (pl.col("site_id") == "R2") & window(f))
    # the clean azimuth is the true one within its noise: keep the reports well inside or out
    az = np.degrees(r["azimuth_rad_clean"].to_numpy())
    inside = in_azimuths(np.radians(az), math.radians(302), math.radians(28))
    outside = ~in_azimuths(np.radians(az), math.radians(298), math.radians(32))
    diff = (r["range_m"] - r["range_m_clean"]).to_numpy()
    assert inside.sum() > 20 and outside.sum() > 20
    np.testing.assert_allclose(diff[inside], 100.0, atol=1e-6)
    np.testing.assert_allclose(diff[outside], 0.0, atol=1e-9)
    assert sc.fault_truth["detail"].item() == "azimuth 300.0-30.0 deg"


def test_noise_scales_the_errors(cfg, clean):
    f = ChannelFault("radar_noise", 120.0, 90.0, site_id="R1", factor=4.0)
    j = run(cfg, f).radar_reports.join(clean.radar_reports, on=["site_id", "track_id",
                                                                  "log_time_ns"])
    on = j.filter((pl.col("site_id") == "R1") & window(f) & (pl.col("status") != "coasting"))
    off = j.filter((pl.col("site_id") == "R1") & ~window(f) & (pl.col("status") != "coasting"))
    # the faulty minus the clean range error is 3 x the clean noise (same draws)
    assert (on["range_m"] - on["range_m_right"]).std() > 2 * 15.0
    assert (off["range_m"] - off["range_m_right"]).abs().max() < 1e-9


def test_outage_publishes_no_scan(cfg, clean):
    f = ChannelFault("radar_outage", 120.0, 90.0, site_id="R1")
    r = run(cfg, f).radar_reports
    log = pl.col("log_time_ns").is_between(START + 120 * NS, START + 210 * NS, closed="left")
    assert r.filter((pl.col("site_id") == "R1") & log).height == 0
    assert r.filter((pl.col("site_id") == "R2") & log).height == clean.radar_reports.filter(
        (pl.col("site_id") == "R2") & log).height
    # after it, R1's tracks start again as new ones
    after = r.filter((pl.col("site_id") == "R1") & (pl.col("log_time_ns") >= START + 210 * NS))
    assert after.height > 0 and "new" in set(after["status"])


def test_blank_sector_only_coasts(cfg, clean):
    f = ChannelFault("radar_blank", 120.0, 90.0, site_id="R2", azimuth_from_rad=math.radians(240),
                     azimuth_to_rad=math.radians(285))
    r = run(cfg, f).radar_reports.filter((pl.col("site_id") == "R2") & window(f))
    inside = in_azimuths(r["azimuth_rad"].to_numpy(), f.azimuth_from_rad, f.azimuth_to_rad)
    assert inside.sum() > 0  # coasted reports (predictions) still come for 2 scans
    assert set(r.filter(pl.Series(inside))["status"]) <= {"coasting"}
    assert "confirmed" in set(r.filter(pl.Series(~inside))["status"])


def test_ais_faults(cfg, clean):
    faults = (
        ChannelFault("ais_offset", 120.0, 90.0, east_m=0.0, north_m=250.0),
        ChannelFault("ais_stuck", 120.0, 90.0),
        ChannelFault("ais_mmsi_swap", 120.0, 90.0),
        ChannelFault("ais_spoof", 120.0, 90.0, mmsi=272999001, start_lat_deg=46.392,
                     start_lon_deg=30.870, course_rad=math.radians(90.0), speed_mps=6.0),
    )
    sc = run(cfg, *faults)
    truth = sc.fault_truth
    assert truth.height == 5  # a swap is two channels
    assert truth["start_ns"].unique().to_list() == [START + 120 * NS]
    a, c = ais_rows(sc), ais_rows(clean)
    f = faults[0]
    by_kind = {k: g for (k,), g in truth.group_by(["kind"])}
    m_off = by_kind["ais_offset"]["mmsi"].item()
    j = a.filter(pl.col("mmsi") == m_off).join(c, on=["time_ns", "mmsi"], suffix="_c")
    dn = (j["lat_deg"] - j["lat_deg_c"]).to_numpy() * 111_100.0
    on = j.select(window(f)).to_series().to_numpy()
    assert on.sum() >= 5
    np.testing.assert_allclose(dn[on], 250.0, atol=1.0)
    np.testing.assert_allclose(dn[~on], 0.0, atol=0.01)
    m_stuck = by_kind["ais_stuck"]["mmsi"].item()
    s = a.filter((pl.col("mmsi") == m_stuck) & window(f))
    assert s["lat_deg"].std() * 111_100 < 10 and s["lon_deg"].std() * 77_000 < 10
    swapped = by_kind["ais_mmsi_swap"]["mmsi"].to_list()
    for m in swapped:  # in the window each MMSI sits where the other ship was
        other = next(x for x in swapped if x != m)
        mine = a.filter((pl.col("mmsi") == m) & window(f)).sort("time_ns")
        theirs = c.filter((pl.col("mmsi") == other) & window(f)).sort("time_ns")
        assert mine.height > 3
        assert abs(mine["lat_deg"].mean() - theirs["lat_deg"].mean()) < 0.002
    ghost = a.filter(pl.col("mmsi") == 272999001)
    assert ghost.height >= 8 and ghost.select(window(f)).to_series().all()
    assert c.filter(pl.col("mmsi") == 272999001).height == 0
