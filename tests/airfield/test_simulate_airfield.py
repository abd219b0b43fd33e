"""The `airfield` scenario simulator: traffic, sensor visibility, coloured errors, faults
and wire quantisation."""

from __future__ import annotations

import math

import numpy as np
import polars as pl
import pytest
from airfield_helpers import START_NS, acfg, seconds
from polars.testing import assert_frame_equal

from pipeline.airfield.config import FaultConfig
from pipeline.airfield.frames import assign_areas
from pipeline.decode import asterix_encode as cat010
from pipeline.filters.ar_errors import stationary_covariance
from pipeline.simulate.airfield import Move, simulate_airfield, speed_profile

DURATION_S = 600.0
SEED = 21


@pytest.fixture(scope="module")
def af(cfg):
    return acfg(cfg)


@pytest.fixture(scope="module")
def clean(af):
    return simulate_airfield(af.with_faults(()), start_ns=START_NS, duration_s=DURATION_S,
                             seed=SEED)


def test_same_seed_same_scene_other_seed_other_scene(af, clean):
    again = simulate_airfield(af.with_faults(()), start_ns=START_NS, duration_s=DURATION_S,
                              seed=SEED)
    assert_frame_equal(again.truth, clean.truth)
    assert_frame_equal(again.reports, clean.reports)
    other = simulate_airfield(af.with_faults(()), start_ns=START_NS, duration_s=DURATION_S,
                              seed=SEED + 1)
    assert not other.reports["err_x_m"].equals(clean.reports["err_x_m"])


def test_traffic_has_parked_taxiing_and_runway_targets(af, clean):
    tr = clean.truth.with_columns((pl.col("vx_mps") ** 2 + pl.col("vy_mps") ** 2).sqrt()
                                  .alias("speed"))
    kinds = set(clean.targets["kind"])
    assert kinds == {"aircraft", "vehicle"}
    parked = tr.filter(~pl.col("engines_on")).group_by("target_id").len()
    assert parked.filter(pl.col("len") >= 300).height >= 4  # long engines-off periods
    assert tr["speed"].max() > 60.0  # landing / take-off roll on the runway
    _, area = assign_areas(tr["x_m"].to_numpy(), tr["y_m"].to_numpy(), af)
    assert set(area) >= {"manoeuvring", "apron_taxiway", "stand"}
    assert np.mean(area == None) < 0.01  # noqa: E711 - the layout lies in the polygons


def test_speed_profile_respects_turn_and_rate_limits():
    m = Move(((0.0, 0.0), (300.0, 0.0), (300.0, 300.0)), (9.0, 9.0), radius_m=40.0)
    prof = speed_profile(m)
    assert prof.v_mps[0] == 0.0 and prof.v_mps[-1] == 0.0
    assert prof.v_mps.max() == pytest.approx(9.0)
    t = np.arange(0.0, prof.duration_s, 0.5)
    x, y, vx, vy = prof.at(t)
    v = np.hypot(vx, vy)
    on_arc = (x > 259.9) & (y < 40.1)
    assert v[on_arc].max() <= math.sqrt(40.0) + 1e-6  # a_lat 1 m/s^2 on a 40 m arc
    assert np.abs(np.diff(v) / 0.5).max() <= 1.0 + 1e-6  # within the move's accel/decel


def test_visibility_follows_the_sensor_physics(clean):
    j = clean.reports.join(clean.truth, on=["time_ns", "target_id"], suffix="_t")
    by = {k: g for (k,), g in j.group_by(["sensor_kind"])}
    assert by["vasn"]["engines_on"].all()  # blind to engines off
    assert by["mlat"]["transponder_on"].all()  # cooperative targets only
    assert (~by["smr"]["engines_on"]).sum() > 1000  # the SMR sees parked aircraft
    for kind in ("smr", "mlat"):  # detection probability < 1
        assert by[kind].height < clean.truth.height


def test_errors_have_the_configured_stationary_spread(af, clean):
    for s in af.sensors:
        e = clean.reports.filter(pl.col("sensor_id") == s.sensor_id).select(
            "err_x_m", "err_y_m").to_numpy()
        want = np.sqrt(np.diag(stationary_covariance(s.position_model))[:2])
        np.testing.assert_allclose(e.std(axis=0), want, rtol=0.2)


def test_wire_values_are_on_the_cat010_grid(clean):
    smr = clean.reports.filter(pl.col("sensor_kind") == "smr")
    mlat = clean.reports.filter(pl.col("sensor_kind") == "mlat")
    np.testing.assert_array_equal(smr["range_m"], np.round(smr["range_m"]))
    steps = smr["azimuth_rad"].to_numpy() / cat010.THETA_LSB_RAD
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    np.testing.assert_array_equal(mlat["x_m"], np.round(mlat["x_m"]))
    np.testing.assert_array_equal(mlat["vx_mps"] * 4, np.round(mlat["vx_mps"] * 4))
    assert smr["track_number"].max() < 4096 and mlat["callsign"].null_count() == 0


def test_injected_faults(af):
    faults = (FaultConfig("jam", "SMR1", 100.0, 60.0), FaultConfig("bias", "MLAT1", 200.0, 60.0),
              FaultConfig("dropout", "VASN1", 300.0, 60.0))
    sc = simulate_airfield(af.with_faults(faults), start_ns=START_NS, duration_s=400.0,
                           seed=SEED)
    r = seconds(sc.reports)

    def window(sid, a, b):
        return r.filter((pl.col("sensor_id") == sid) & (pl.col("t_s") >= a) & (pl.col("t_s") < b))

    jam, calm = window("SMR1", 100, 160), window("SMR1", 0, 100)
    ratio = jam["err_x_m"].std() / calm["err_x_m"].std()
    assert 7.0 < ratio < 13.0  # error std x10
    bias = window("MLAT1", 200, 260).select(pl.col("err_x_m").mean(), pl.col("err_y_m").mean())
    assert bias.item(0, 0) == pytest.approx(30 * math.sin(math.radians(45)), abs=3.0)
    assert bias.item(0, 1) == pytest.approx(30 * math.cos(math.radians(45)), abs=3.0)
    assert window("VASN1", 300, 360).height == 0
    assert window("VASN1", 360, 400).height > 0
