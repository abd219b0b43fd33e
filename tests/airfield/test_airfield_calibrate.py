"""`calibrate`: AR error models fitted against the reference recover the simulated ones;
stored fits round-trip into the filter's models."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from airfield_helpers import START_NS, acfg

from pipeline.airfield.calibrate import calibrate, model_from_rows, stored_models
from pipeline.airfield.frames import sensor_rows, to_common_frame
from pipeline.simulate.airfield import simulate_airfield
from pipeline.tables import conform
from pipeline.units import NS

Z_999 = 3.2905


@pytest.fixture(scope="module")
def af(cfg):
    return acfg(cfg).with_faults(())


@pytest.fixture(scope="module")
def fitted(af):
    sc = simulate_airfield(af, start_ns=START_NS, duration_s=900.0, seed=31)
    obs = to_common_frame(sensor_rows(sc.reports, af), af)
    return calibrate(obs, sc.truth, af, start_ns=sc.start_ns, end_ns=sc.end_ns)


def truth_model(af, key: str):
    sid, quantity = key.split("/")
    s = af.sensor(sid)
    return s.position_model if quantity == "position" else s.velocity_model


def test_every_channel_is_fitted_with_the_order_bic_picks(af, fitted):
    _, fits = fitted
    assert set(fits) == {"SMR1/position", "MLAT1/position", "VASN1/position", "VASN1/velocity"}
    for key, fit in fits.items():
        assert fit.model.order == truth_model(af, key).order, (key, fit.bic_by_order)
        assert fit.n_rows > 3000


def test_fitted_coefficients_cover_the_simulated_ones(af, fitted):
    _, fits = fitted
    for key, fit in fits.items():
        true = truth_model(af, key)
        z = np.abs(fit.model.B - true.B) / fit.se_b
        assert z.max() < Z_999, (key, z)
        lo, hi = fit.gamma_ci
        tril = np.tril_indices(2)
        # Gamma intervals are 95%: allow one of the three entries of one fit to miss
        assert ((true.Gamma[tril] < lo[tril]) | (true.Gamma[tril] > hi[tril])).sum() <= 1


def test_rows_are_the_sensor_error_models_table(fitted):
    rows, fits = fitted
    table = conform("sensor_error_models", rows)
    assert table.num_rows == rows.height == 3 * (8 + 3) + (4 + 3)
    b = rows.filter((pl.col("sensor_id") == "SMR1") & (pl.col("term") == "B"))
    assert (b["ci_low"] < b["value"]).all() and (b["value"] < b["ci_high"]).all()
    assert b["bic_by_order"][0].startswith("1:")
    back = model_from_rows(rows.filter((pl.col("sensor_id") == "MLAT1")
                                       & (pl.col("quantity") == "position")))
    np.testing.assert_allclose(back.B, fits["MLAT1/position"].model.B)
    np.testing.assert_allclose(back.Gamma, fits["MLAT1/position"].model.Gamma)


def test_the_filter_takes_the_latest_fit_before_the_window_end(af, fitted):
    rows, fits = fitted
    fit_end = int(rows["fit_end_ns"][0])
    later = rows.with_columns(
        (pl.col("fit_start_ns") + 3600 * NS).alias("fit_start_ns"),
        (pl.col("fit_end_ns") + 3600 * NS).alias("fit_end_ns"),
        pl.when(pl.col("term") == "B").then(pl.col("value") * 0.5).otherwise(pl.col("value"))
        .alias("value"))
    both = pl.concat([rows, later])
    m = stored_models(both, af, fit_end + 60 * NS)  # the later fit is not over yet
    np.testing.assert_allclose(m.position["SMR1"].B, fits["SMR1/position"].model.B)
    m2 = stored_models(both, af, fit_end + 7200 * NS)
    np.testing.assert_allclose(m2.position["SMR1"].B, 0.5 * fits["SMR1/position"].model.B)
    assert m2.source["SMR1"].startswith("fit [")
    m0 = stored_models(both, af, fit_end - 1)  # nothing stored yet: the config's models
    assert m0.source["SMR1"] == "config"
    np.testing.assert_array_equal(m0.position["SMR1"].B, af.sensor("SMR1").position_model.B)
