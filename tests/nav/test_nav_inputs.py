"""pipeline.nav.inputs: raw navigation rows -> the filter grid, fix validity, modes."""

from __future__ import annotations

import math

import numpy as np
import polars as pl

from pipeline.nav.inputs import NS, emergency_steps, segments

T0 = 1_768_435_200 * NS


def _gnss(rows: list[tuple]) -> pl.DataFrame:
    return pl.DataFrame(rows, schema={
        "time_ns": pl.Int64, "platform_id": pl.String, "lat_deg": pl.Float64,
        "lon_deg": pl.Float64, "fix_quality": pl.Int16, "fix_valid": pl.Boolean,
        "sog_mps": pl.Float64, "cog_rad": pl.Float64}, orient="row")


def _empty(cols: dict) -> pl.DataFrame:
    return pl.DataFrame(schema={"time_ns": pl.Int64, "platform_id": pl.String, **cols})


HEAD = {"heading_rad": pl.Float64, "is_magnetic": pl.Boolean}
LOG = {"speed_water_mps": pl.Float64}
GYRO = {"accel_signal_rad": pl.Float64, "amplifier_rad": pl.Float64}


def test_binning_validity_and_velocity():
    s = NS
    gnss = _gnss([
        (T0 + 1 * s, "A", 46.0, 30.0, 1, None, None, None),  # GGA
        (T0 + 1 * s, "A", 46.0, 30.0, None, True, 2.0, math.pi / 2),  # RMC, same step
        (T0 + 2 * s, "A", None, None, 0, None, None, None),  # GGA quality 0
        (T0 + 2 * s, "A", None, None, None, False, None, None),  # RMC status V
        (T0 + 4 * s, "A", 46.1, 30.1, None, True, 1.0, 0.0),  # RMC only: status A
    ])
    heading = pl.DataFrame({"time_ns": [T0 + s, T0 + 3 * s, T0 + 3 * s], "platform_id": "A",
                            "heading_rad": [0.5, 1.0, 2.0], "is_magnetic": [None, True, False]})
    gyro = pl.DataFrame({"time_ns": [T0 + 500_000_000, T0 + s], "platform_id": "A",
                         "accel_signal_rad": [0.1, 0.3], "amplifier_rad": [0.01, 0.02]})
    (seg,) = segments(gnss, heading, _empty(LOG), gyro, step_s=1.0, max_gap_s=600.0)
    k = {int((t - T0) // NS): i for i, t in enumerate(seg.times_ns)}
    assert seg.platform_id == "A"
    assert seg.fix_valid[k[1]] and not seg.fix_valid[k[2]] and seg.fix_valid[k[4]]
    assert seg.gnss_msg[k[2]] and not seg.gnss_msg[k[3]]
    assert np.allclose([seg.vel_east_mps[k[1]], seg.vel_north_mps[k[1]]], [2.0, 0.0])
    assert np.isnan(seg.vel_east_mps[k[2]])
    assert seg.heading_rad[k[3]] == 2.0  # the magnetic heading is not used
    assert seg.accel_signal_rad[k[1]] == 0.2 and seg.amplifier_rad[k[1]] == 0.02  # mean, last
    emergency, last = emergency_steps(seg, timeout_s=1.5)
    assert not emergency[k[1]] and not emergency[k[2]] and emergency[k[3]]
    assert last[k[3]] == k[1] and not emergency[k[4]]


def test_a_long_silence_starts_a_new_segment_per_vessel():
    s = NS
    gnss = _gnss([(T0 + i * s, p, 46.0, 30.0, 1, None, 1.0, 0.0) for p in "AB"
                  for i in (*range(5), *range(1000, 1005))])
    segs = segments(gnss, _empty(HEAD), _empty(LOG), _empty(GYRO), step_s=1.0,
                    max_gap_s=600.0)
    assert [(g.platform_id, g.n) for g in segs] == [("A", 5), ("A", 5), ("B", 5), ("B", 5)]
