"""`ownship` scenario: the paper's kinematics and roll, the sensors, NMEA 0183 sentences
(decoded by the project's NMEA decoder) and the MCAP archive."""

from __future__ import annotations

import dataclasses
import math
from functools import reduce

import numpy as np
import polars as pl
import pytest
from mcap.reader import make_reader

from jobs.simulate import run_simulate
from pipeline.decode.nmea import decode_nmea_sentences
from pipeline.simulate.ownship import (
    CHANNELS,
    KNOT_MPS,
    OwnshipScenarioConfig,
    _gyro_and_roll,
    gnss_sentences,
    hdt_sentences,
    kinematics,
    simulate_ownship,
    vhw_sentences,
)
from pipeline.units import NS

START = 1_768_435_200 * NS


@pytest.fixture(scope="module")
def scenario():
    return simulate_ownship(OwnshipScenarioConfig(), start_ns=START, duration_s=1800.0, seed=3)


def test_kinematics_follow_paper_eq5_and_a_full_turn():
    c = OwnshipScenarioConfig()
    t = np.array([0.0, 100.0, 180.0, 500.0, 900.0, 1020.0, 1140.0, 1500.0])
    k = kinematics(t, c)
    assert np.allclose(k["V"], [0.0, 5.0, 9.0, 9.0, 9.0, 9.0, 9.0, 9.0])
    assert np.allclose(k["W"][:2], 0.05) and np.allclose(k["W"][2:], 0.0)
    turn = np.unwrap(kinematics(np.arange(900.0, 1141.0), c)["K"])
    assert turn[-1] - turn[0] == pytest.approx(2 * math.pi)  # 360 deg in 240 s
    assert k["K"][0] == k["K"][-1] == pytest.approx(c.initial_heading_rad)
    assert np.allclose(k["a_s"][(t >= 900) & (t < 1140)], 9.0 * 2 * math.pi / 240)


def test_roll_has_the_paper_correlation():
    """K(tau) = D e^(-mu|tau|) (cos nu tau + mu/nu sin nu|tau|) (eq. 6), estimated over
    long seeded runs at tau = 0 and 5 s (half a period: negative)."""
    c = OwnshipScenarioConfig()
    r = c.roll
    n, h = 60_000, 0.5
    kin = {"K": np.zeros(n), "W": np.zeros(n), "a_s": np.zeros(n)}
    phi = np.concatenate([
        _gyro_and_roll(np.random.default_rng(s), kin, h, 0.8, c.gyro, r, 0.0)[:, 3]
        for s in range(3)])

    def model(tau: float) -> float:
        mu, nu = r.irregularity_per_s, r.frequency_radps
        return r.variance_rad2 * math.exp(-mu * tau) * (
            math.cos(nu * tau) + mu / nu * math.sin(nu * tau))

    assert np.var(phi) == pytest.approx(model(0.0), rel=0.15)
    lag = 10  # 5 s
    emp = np.mean(phi[:-lag] * phi[lag:])
    assert emp == pytest.approx(model(5.0), rel=0.2) and emp < 0


def test_gyro_alone_errs_by_more_than_10_deg_under_roll_and_the_turn(scenario):
    alpha = np.degrees(scenario.truth["gyro_error_rad"].to_numpy())
    assert np.abs(alpha).max() > 10.0
    t = np.arange(1, alpha.size + 1)
    assert np.abs(alpha[t < 900]).max() < np.abs(alpha[(t >= 900) & (t < 1200)]).max()


def test_gnss_outages_outliers_and_log(scenario):
    g = scenario.gnss
    t = (g["time_ns"].to_numpy() - START) / NS
    out = (g["fix_quality"] == 0).to_numpy()
    expect = ((t > 960) & (t <= 990)) | ((t > 1320) & (t <= 1440))
    assert (out == expect).all()
    assert g.filter(pl.col("fix_quality") == 0)["lat_deg"].null_count() == out.sum()
    idx = np.flatnonzero(g["is_outlier"].to_numpy())
    assert idx.size == 6 and np.diff(idx).min() >= 10 and not out[idx].any()
    truth = scenario.truth
    lg = scenario.speed_log["speed_water_mps"].to_numpy() - truth["speed_water_mps"].to_numpy()
    assert np.mean(lg) == pytest.approx(0.2, abs=0.05)  # bias
    assert np.std(lg) == pytest.approx(0.5, rel=0.1)
    ok = ~out & ~g["is_outlier"].to_numpy()
    dv = g["sog_mps"].to_numpy()[ok] - truth["sog_mps"].to_numpy()[ok]
    assert np.std(dv) == pytest.approx(0.053, rel=0.35)


def _xor(body: str) -> int:
    return reduce(lambda a, ch: a ^ ord(ch), body, 0)


def test_nmea_sentences_have_valid_checksums_and_decode_back(scenario):
    gnss = gnss_sentences(scenario.gnss)
    lines = pl.concat([gnss, hdt_sentences(scenario.gyro_heading),
                       vhw_sentences(scenario.speed_log)])["sentence"].to_list()
    for s in lines[:: max(1, len(lines) // 400)]:  # an independent per-sentence check
        body, ck = s[1:].split("*")
        assert int(ck, 16) == _xor(body)
    kinds = pl.Series([s[3:6] for s in gnss["sentence"].to_list()]).value_counts()
    n = dict(zip(kinds[""].to_list(), kinds["count"].to_list(), strict=True))
    assert n["GGA"] == n["RMC"] == 1800 and n["VTG"] == 1800 - 150
    # the project's decoder reads them back to the simulated values
    dec = decode_nmea_sentences(
        [s.encode() for s in gnss["sentence"].to_list()], gnss["time_ns"].to_numpy(),
        source_file="sim", topic="/ownship/gnss/nmea", platform_id="ownship")
    assert dec["rejects"].num_rows == 0
    rows = pl.from_arrow(dec["nav_gnss"])
    rmc = rows.filter(pl.col("sentence") == "RMC").sort("time_ns")
    sim = scenario.gnss.sort("time_ns")
    assert rmc["time_ns"].to_list() == sim["time_ns"].to_list()
    valid = sim["fix_quality"].to_numpy() > 0
    assert np.allclose(rmc["lat_deg"].to_numpy()[valid], sim["lat_deg"].to_numpy()[valid],
                       atol=1e-7)
    assert np.allclose(rmc["sog_mps"].to_numpy()[valid], sim["sog_mps"].to_numpy()[valid],
                       atol=0.0006 * KNOT_MPS)
    gga = rows.filter(pl.col("sentence") == "GGA").sort("time_ns")
    assert (gga["fix_quality"].to_numpy() == sim["fix_quality"].to_numpy()).all()


def test_archive_channels_metadata_and_determinism(tmp_path, cfg):
    c = dataclasses.replace(OwnshipScenarioConfig())
    a = run_simulate("ownship", 120.0, 9, tmp_path / "a", cfg, start_ns=START)
    b = run_simulate("ownship", 120.0, 9, tmp_path / "b", cfg, start_ns=START)
    assert [p.name for p in a] == ["ownship_20260115T000000Z.mcap"]
    assert a[0].read_bytes() == b[0].read_bytes()
    with open(a[0], "rb") as f:
        summary = make_reader(f).get_summary()
    chans = {ch.topic: ch for ch in summary.channels.values()}
    assert set(chans) == {t for t, _, _ in CHANNELS}
    assert all(ch.metadata == {"platform_id": c.platform_id} for ch in chans.values())
    assert chans["/ownship/gnss/nmea"].message_encoding == "nmea0183"
    names = {summary.schemas[ch.schema_id].name for ch in chans.values() if ch.schema_id}
    assert names == {"surveil.GyroSignals", "surveil.OwnshipTruth", "surveil.FaultTruth"}
    assert summary.statistics.message_count == 120 * 3 + 120 * 4  # GGA RMC VTG + 4 channels
