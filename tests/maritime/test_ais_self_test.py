"""The AIS kinematic self-test on real receivers' times (issue 36, item 6;
pipeline/maritime/integrity.py ``self_test``, ``fix_time``): a report is tested at the
second its time stamp gives, with a time variance from its ``time_source``; the step is
taken on the ellipsoid where the ship is, a long-range message 27 is no fix, and a
report's variance adds a white-noise acceleration between the two reports."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import polars as pl
import pymap3d as pm
import pytest

from pipeline.families import load_config
from pipeline.filters.quantiles import chi2_ppf
from pipeline.maritime.config import maritime_config
from pipeline.maritime.integrity import self_test
from pipeline.units import NS

T0_NS = 1_700_000_040 * NS  # a whole minute


@pytest.fixture(scope="module")
def ic():
    return maritime_config(load_config()).integrity


def track(fix_s: np.ndarray, *, speed_mps: float = 10.0, course_deg: float = 90.0,
          lat0_deg: float = 50.0, lon0_deg: float = -1.0) -> tuple[np.ndarray, np.ndarray]:
    """A straight track on the ellipsoid: each fix the previous one moved on by the
    speed x dt along the course in the local ENU frame of the previous fix."""
    lat, lon = [lat0_deg], [lon0_deg]
    c = np.radians(course_deg)
    for d in np.diff(fix_s):
        la, lo, _ = pm.enu2geodetic(speed_mps * d * np.sin(c), speed_mps * d * np.cos(c), 0.0,
                                    lat[-1], lon[-1], 0.0)
        lat.append(float(la))
        lon.append(float(lo))
    return np.array(lat), np.array(lon)


def reports(fix_s: np.ndarray, recv_s: np.ndarray, *, utc_second: np.ndarray | None = None,
            time_source: str = "tag_block:c", msg_type: np.ndarray | None = None,
            speed_mps: float = 10.0, course_deg: float = 90.0, lat0_deg: float = 50.0,
            lon0_deg: float = -1.0) -> pl.DataFrame:
    lat, lon = track(fix_s, speed_mps=speed_mps, course_deg=course_deg, lat0_deg=lat0_deg,
                     lon0_deg=lon0_deg)
    n = fix_s.size
    second = (np.floor(fix_s).astype(np.int64) + T0_NS // NS) % 60
    return pl.DataFrame({
        "time_ns": T0_NS + np.round(recv_s * NS).astype(np.int64), "mmsi": 235000001,
        "lat_deg": lat, "lon_deg": lon, "sog_mps": speed_mps,
        "cog_rad": np.radians(course_deg),
        "msg_type": np.ones(n, np.int16) if msg_type is None else msg_type,
        "utc_second": second if utc_second is None else utc_second,
        "time_source": time_source,
    }, schema_overrides={"msg_type": pl.Int16, "utc_second": pl.Int16})


def test_a_report_is_tested_at_the_second_its_time_stamp_gives(ic):
    """Fixes every 10 s received 0-8 s later (a network feed's latency): at their time
    stamps the reports agree with their SOG; at their reception times (no stamp: 60)
    the same positions are 80 m off."""
    fix = np.arange(0.0, 200.0, 10.0)
    late = np.tile([0.0, 8.0, 3.0, 6.0], 5)
    on_fix = self_test(reports(fix, fix + late), ic)
    assert on_fix["self_xi"].drop_nulls().len() == fix.size - 1
    assert on_fix["self_xi"].max() < 1.0
    np.testing.assert_array_equal(on_fix["fix_ns"].to_numpy() - T0_NS,
                                  np.round(fix * NS).astype(np.int64) + NS // 2)
    unstamped = self_test(reports(fix, fix + late, utc_second=np.full(fix.size, 60)), ic)
    assert (unstamped["self_xi"].drop_nulls() > chi2_ppf(1.0 - ic.ais_q, 2)).mean() > 0.5


def test_the_time_variance_follows_the_time_source(ic):
    """Recomputed inline (fix_time): a stamped report received 0.4 s into its second,
    to the millisecond, is known to within those 0.4 s; in whole seconds, or
    interpolated, to its second; without a stamp the reception time carries the
    position's age (+ 1/12 s^2 in whole seconds); interpolated without one: none."""
    one = np.array([0.0])
    age2 = ic.ais_sigma_report_age_s**2
    cases = [
        ("csv:Time", 0, 0.4, 0.4**2 / 12, 0.2),
        ("tag_block:c", 0, 0.0, 1 / 12, 0.5),
        ("interpolated:nmea:RMC+utc_second", 0, 0.0, 1 / 12, 0.5),
        ("csv:Time", 60, 0.4, age2, 0.4),
        ("tag_block:c", 60, 0.0, age2 + 1 / 12, 0.0),
        ("nais:epoch", 61, 0.0, age2 + 1 / 12, 0.0),
        ("interpolated:nmea:RMC", 60, 0.0, None, 0.0),
    ]
    for src, second, recv_s, var, fix_s in cases:
        r = self_test(reports(one, one + recv_s, utc_second=np.array([second]),
                              time_source=src), ic)
        got = r["time_var_s2"][0]
        assert (got is None) if var is None else got == pytest.approx(var), src
        assert (r["fix_ns"][0] - T0_NS) / NS == pytest.approx(fix_s), src


def test_the_step_is_taken_on_the_ellipsoid_where_the_ship_is(ic):
    """A straight track far from any site origin (a feed spanning a hemisphere: 60 S,
    course 045): every report agrees with its SOG and COG, whatever the region."""
    fix = np.arange(0.0, 300.0, 10.0)
    r = self_test(reports(fix, fix, course_deg=45.0, lat0_deg=-60.0, lon0_deg=150.0), ic)
    xi = r["self_xi"].drop_nulls()
    assert xi.len() == fix.size - 1 and xi.max() < 1e-3


def test_a_long_range_message_is_no_fix(ic):
    """Message 27 (position to 1/10 min, no time stamp) between two message 1: not
    tested, and the next report is tested against the message 1 before it."""
    fix = np.array([0.0, 10.0, 20.0])
    r = reports(fix, fix, msg_type=np.array([1, 27, 1], np.int16))
    r = r.with_columns(pl.when(pl.col("msg_type") == 27).then(pl.col("lat_deg") + 1 / 600)
                       .otherwise(pl.col("lat_deg")).alias("lat_deg"))
    out = self_test(r, ic)
    assert out["self_xi"][1] is None and not out["jump"][1]
    assert out["self_xi"][2] < 1e-3  # 20 s against the first report


def test_a_stuck_position_fails_at_its_first_report(ic):
    """The frozen GNSS of the simulator's ``ais_stuck``: SOG says 5 m/s, the position
    stays where it was 10 s ago."""
    fix = np.arange(0.0, 60.0, 10.0)
    r = reports(fix, fix + 0.3, speed_mps=5.0)
    lat, lon = r["lat_deg"].to_numpy().copy(), r["lon_deg"].to_numpy().copy()
    lat[3:], lon[3:] = lat[2], lon[2]
    out = self_test(r.with_columns(pl.Series("lat_deg", lat), pl.Series("lon_deg", lon)), ic)
    xi = out["self_xi"].to_numpy()
    assert (xi[:3][1:] < 1.0).all()
    assert (xi[3:] > chi2_ppf(1.0 - ic.ais_q, 2)).all()


def test_fault_free_reports_fail_at_q(ic):
    """The model recomputed by drawing its own errors: 3 m GNSS, SOG and COG noise of
    the config, fixes at random instants received 0-1.2 s later to the millisecond with
    a time stamp, straight courses (no manoeuvre term): the share above
    chi2_2(1 - q) is q."""
    rng = np.random.default_rng(3)
    ships, n = 400, 60
    fix = np.cumsum(rng.uniform(2.0, 30.0, (n, ships)), axis=0)
    speed, course = rng.uniform(0.5, 12.0, ships), rng.uniform(0, 2 * np.pi, ships)
    lat, lon = np.empty((n, ships)), np.empty((n, ships))
    lat[0], lon[0] = rng.uniform(-60, 60, ships), rng.uniform(-180, 180, ships)
    for k in range(1, n):  # each fix moved on from the previous one, on the ellipsoid
        d = speed * (fix[k] - fix[k - 1])
        lat[k], lon[k], _ = pm.enu2geodetic(d * np.sin(course), d * np.cos(course), 0.0,
                                            lat[k - 1], lon[k - 1], 0.0)
    sp = ic.ais_sigma_position_m
    lat, lon, _ = pm.enu2geodetic(rng.normal(0, sp, (n, ships)), rng.normal(0, sp, (n, ships)),
                                  0.0, lat, lon, 0.0)
    recv = fix + rng.uniform(0.0, 1.2, (n, ships))
    frame = pl.DataFrame({
        "time_ns": T0_NS + np.round(recv * NS).astype(np.int64).ravel(),
        "mmsi": np.broadcast_to(np.arange(ships), (n, ships)).ravel(),
        "lat_deg": lat.ravel(), "lon_deg": lon.ravel(),
        "sog_mps": (speed + rng.normal(0, ic.ais_sigma_sog_mps, (n, ships))).ravel(),
        "cog_rad": (course + rng.normal(0, ic.ais_sigma_cog_rad, (n, ships))).ravel(),
        "utc_second": ((np.floor(fix).astype(np.int64) + T0_NS // NS) % 60).ravel(),
        "time_source": "csv:Time",
    }, schema_overrides={"utc_second": pl.Int16})
    xi = self_test(frame, replace(ic, ais_manoeuvre_psd_m2_s3=0.0))["self_xi"]
    xi = xi.drop_nulls().to_numpy()
    share = (xi >= chi2_ppf(1.0 - ic.ais_q, 2)).mean()
    assert xi.size > 20_000
    assert 0.7 * ic.ais_q < share < 1.3 * ic.ais_q, share
