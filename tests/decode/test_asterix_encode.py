"""CAT010 encoder: every field round-trips through asterix_decoder and through the ingest
decoder (pipeline.decode.asterix) into airfield_obs."""

from __future__ import annotations

import math

import asterix
import numpy as np
import polars as pl
import pytest

from pipeline.decode import asterix_encode as cat010
from pipeline.decode.asterix import decode_asterix
from pipeline.units import NS

T0 = 1_768_435_200 * NS + 3600 * NS  # 01:00:00 UTC


def mlat_reports(n: int = 4) -> cat010.Cat010Reports:
    rng = np.random.default_rng(1)
    return cat010.Cat010Reports(
        kind="mlat", sac=0, sic=20, time_ns=T0 + np.arange(n) * NS // 2,
        track_number=np.arange(n) + 4090, sigma_x_m=np.full(n, 2.75),
        sigma_y_m=np.full(n, 2.25), cov_xy_m2=np.full(n, -0.5), last=np.arange(n) == n - 1,
        x_m=np.round(rng.uniform(-2000, 2000, n)), y_m=np.round(rng.uniform(-500, 900, n)),
        vx_mps=np.round(rng.uniform(-70, 70, n) * 4) / 4,
        vy_mps=np.round(rng.uniform(-9, 9, n) * 4) / 4,
        target_address=np.array([0x4CA123, 0xABCDEF, 0x000001, 0xFFFFFF])[:n],
        callsign=np.array(["AFL1234", "VEH01", "SWEEP1", "A 9"])[:n],
        target_type=np.array(["aircraft", "vehicle", "vehicle", ""])[:n])


def smr_reports(n: int = 4) -> cat010.Cat010Reports:
    rng = np.random.default_rng(2)
    return cat010.Cat010Reports(
        kind="smr", sac=0, sic=10, time_ns=np.full(n, T0), track_number=np.arange(n) + 100,
        sigma_x_m=np.full(n, 2.5), sigma_y_m=np.full(n, 2.0), cov_xy_m2=np.full(n, 0.25),
        last=np.zeros(n, bool), range_m=np.round(rng.uniform(50, 3000, n)),
        azimuth_rad=cat010.quantise_azimuth(rng.uniform(0, 2 * math.pi, n)),
        speed_mps=cat010.quantise(rng.uniform(0, 70, n), cat010.GS_LSB_MPS),
        course_rad=cat010.quantise_azimuth(rng.uniform(0, 2 * math.pi, n)))


def parsed(blocks: list[bytes]) -> list[dict]:
    return [rec for b in blocks for rec in asterix.parse(b)]


def test_mlat_fields_round_trip_through_asterix_decoder():
    r = mlat_reports()
    _, blocks = cat010.encode_blocks(r, np.zeros(4, int))  # one block
    assert len(blocks) == 1 and blocks[0][0] == 10
    assert int.from_bytes(blocks[0][1:3], "big") == len(blocks[0])
    recs = parsed(blocks)
    assert len(recs) == 4
    for i, rec in enumerate(recs):
        assert rec["I010"]["SIC"]["val"] == 20 and rec["I000"]["MsgTyp"]["val"] == 1
        assert rec["I020"]["TYP"]["val"] == 1 and rec["I020"]["GBS"]["val"] == 1
        assert rec["I140"]["ToD"]["val"] == pytest.approx(3600.0 + 0.5 * i)
        assert rec["I042"]["X"]["val"] == r.x_m[i] and rec["I042"]["Y"]["val"] == r.y_m[i]
        assert rec["I202"]["Vx"]["val"] == r.vx_mps[i]
        assert rec["I161"]["TrkNb"]["val"] == r.track_number[i]
        assert rec["I170"]["TRE"]["val"] == int(r.last[i])
        assert int(rec["I220"]["TAddr"]["val"], 16) == r.target_address[i]
        assert rec["I245"]["TId"]["val"].rstrip() == r.callsign[i]
        assert rec["I500"]["Qx"]["val"] == 2.75 and rec["I500"]["Qxy"]["val"] == -0.5
    assert [rec["I020"]["TOT"]["val"] for rec in recs] == [1, 2, 2, 0]


def test_smr_fields_round_trip_through_asterix_decoder():
    r = smr_reports()
    _, blocks = cat010.encode_blocks(r, r.time_ns)
    for i, rec in enumerate(parsed(blocks)):
        assert rec["I020"]["TYP"]["val"] == 3  # PSR
        assert rec["I040"]["RHO"]["val"] == r.range_m[i]
        assert math.radians(rec["I040"]["Theta"]["val"]) == pytest.approx(r.azimuth_rad[i])
        assert rec["I200"]["GS"]["val"] * 1852.0 == pytest.approx(r.speed_mps[i])
        assert "I245" not in rec and "I042" not in rec


def test_round_trip_into_airfield_obs_through_the_ingest_decoder():
    rm, rs = mlat_reports(), smr_reports()
    _, bm = cat010.encode_blocks(rm, np.zeros(4, int))
    _, bs = cat010.encode_blocks(rs, rs.time_ns)
    out = decode_asterix(bm + bs, np.array([T0 + NS, T0 + NS]), source_file="x.mcap",
                         topic="/airfield/x/cat010")
    assert out.rejects.num_rows == 0
    obs = pl.from_arrow(out.obs)
    mlat = obs.filter(pl.col("sensor_kind") == "mlat").sort("track_number")
    np.testing.assert_array_equal(mlat["time_ns"], rm.time_ns)
    np.testing.assert_array_equal(mlat["x_m"], rm.x_m)
    np.testing.assert_array_equal(mlat["vy_mps"], rm.vy_mps)
    np.testing.assert_array_equal(mlat["target_address"], rm.target_address)
    assert mlat["callsign"].to_list() == ["AFL1234", "VEH01", "SWEEP1", "A 9"]
    np.testing.assert_array_equal(mlat["sigma_x_m"], 2.75)
    smr = obs.filter(pl.col("sensor_kind") == "smr").sort("track_number")
    np.testing.assert_array_equal(smr["range_m"], rs.range_m)
    np.testing.assert_allclose(smr["azimuth_rad"], rs.azimuth_rad, atol=1e-12)
    speed = np.hypot(smr["vx_mps"].to_numpy(), smr["vy_mps"].to_numpy())
    np.testing.assert_allclose(speed, rs.speed_mps, atol=1e-9)
    assert smr["sac"].to_list() == [0] * 4 and smr["sic"].to_list() == [10] * 4


def test_a_long_update_is_split_into_blocks_under_65535_bytes():
    n = 2000  # 37-byte records: 74 kB
    base = mlat_reports(1)
    r = cat010.Cat010Reports(
        kind="mlat", sac=0, sic=20, time_ns=np.full(n, T0), track_number=np.arange(n) % 4096,
        sigma_x_m=np.ones(n), sigma_y_m=np.ones(n), cov_xy_m2=np.zeros(n),
        last=np.zeros(n, bool), x_m=np.zeros(n), y_m=np.zeros(n), vx_mps=np.zeros(n),
        vy_mps=np.zeros(n), target_address=np.full(n, base.target_address[0]),
        callsign=np.full(n, "X"), target_type=np.full(n, "aircraft"))
    _, blocks = cat010.encode_blocks(r, r.time_ns)
    assert len(blocks) == 2 and all(len(b) <= 65535 for b in blocks)
    assert sum(len(asterix.parse(b)) for b in blocks) == n


@pytest.mark.parametrize(("field", "value", "match"), [
    ("track_number", 4096, "12 bits"),
    ("x_m", 40000.0, "X out of range"),
    ("target_address", 1 << 24, "target address"),
])
def test_values_that_do_not_fit_are_refused(field, value, match):
    r = mlat_reports(1)
    bad = cat010.Cat010Reports(**{**r.__dict__, field: np.array([value])})
    with pytest.raises(ValueError, match=match):
        cat010.encode_records(bad)


def test_a_callsign_outside_the_icao_alphabet_is_refused():
    r = mlat_reports(1)
    with pytest.raises(ValueError, match="six-bit"):
        cat010.encode_records(cat010.Cat010Reports(**{**r.__dict__,
                                                      "callsign": np.array(["AB-12"])}))
