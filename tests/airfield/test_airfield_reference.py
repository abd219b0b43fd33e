"""The airfield's reconstructed reference (issue 37, pipeline/airfield/reference.py): the
RTS smoother of the fused filter, its honesty against the simulated truth, and scoring
against it when the truth is withheld (the correction for the data it shares)."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from pipeline.airfield.reference import smooth
from pipeline.airfield.score import MAX_REFERENCE_P95_M, reference_frame
from pipeline.airfield.stage import airfield_stage
from pipeline.families import load_config
from pipeline.simulate.airfield import simulate_airfield
from pipeline.units import NS

T0_NS = 1_768_435_200 * NS
MODELS = pl.DataFrame(schema={"fit_start_ns": pl.Int64, "fit_end_ns": pl.Int64,
                              "sensor_id": pl.String})


@pytest.fixture(scope="module")
def scene():
    acfg = load_config(None).family("airfield").with_faults(())
    sc = simulate_airfield(acfg, start_ns=T0_NS, duration_s=900.0, seed=21)
    with_truth = airfield_stage(sc.reports, sc.truth, MODELS, acfg, start_ns=sc.start_ns,
                                end_ns=sc.end_ns)
    without = airfield_stage(sc.reports, None, MODELS, acfg, start_ns=sc.start_ns,
                             end_ns=sc.end_ns)
    return acfg, sc, with_truth, without


def _truth_at(acfg, sc, with_truth, frame: pl.DataFrame) -> pl.DataFrame:
    """``frame`` (time_ns, track_id, x_m, y_m, ...) with the truth position of the target
    its track follows (the truth path's match)."""
    ref = reference_frame(sc.truth, acfg)
    match = with_truth.tracks.select("track_id", "truth_target_id").unique("track_id")
    return (frame.join(match, on="track_id").join(
        ref.select("time_ns", pl.col("target_id").alias("truth_target_id"), "tx_m", "ty_m"),
        on=["time_ns", "truth_target_id"]))


def test_the_smoother_is_better_than_the_filter_and_its_covariance_is_honest(scene):
    acfg, sc, with_truth, _ = scene
    ref = with_truth.reference
    assert ref.height == with_truth.tracks.height
    j = _truth_at(acfg, sc, with_truth, ref)
    ex, ey = j["x_m"] - j["tx_m"], j["y_m"] - j["ty_m"]
    nees = (ex**2 * j["sigma_y_m"] ** 2 - 2 * ex * ey * j["cov_xy_m2"] + ey**2
            * j["sigma_x_m"] ** 2) / (j["sigma_x_m"] ** 2 * j["sigma_y_m"] ** 2
                                      - j["cov_xy_m2"] ** 2)
    ok = j["p95_m"] <= MAX_REFERENCE_P95_M
    rms_smooth = float(np.sqrt((ex**2 + ey**2).filter(ok).mean()))
    rms_filter = float(np.sqrt((with_truth.tracks.filter(pl.col("n_channels") > 0)["error_m"]
                                ** 2).mean()))
    assert rms_smooth < 0.8 * rms_filter
    assert 0.9 < float(nees.filter(ok).mean()) < 3.0  # (measured 1.18: a little pessimistic)
    inside = (np.hypot(ex, ey) <= j["p95_m"]).filter(ok).mean()
    assert 0.88 < inside < 0.99


def test_filter_error_equals_its_distance_to_the_smoother_plus_the_smoother_variance(scene):
    """For the smoother of the same model and data, e_s is orthogonal to the data, so
    E|e_f|^2 = E|x_f - x_s|^2 + tr P_s (pipeline/airfield/reference.py): the correction
    the reports apply. Without it the fused error would read ~30 % low."""
    _acfg, _sc, with_truth, without = scene
    t = with_truth.tracks.filter((pl.col("n_channels") > 0) & pl.col("error_m").is_not_null())
    r = without.tracks.filter((pl.col("n_channels") > 0) & pl.col("error_m").is_not_null())
    j = t.select("time_ns", "track_id", pl.col("error_m").alias("e_true")).join(
        r.select("time_ns", "track_id", "error_m", "reference_correction_m2"),
        on=["time_ns", "track_id"])
    true_ms = float((j["e_true"] ** 2).mean())
    raw_ms = float((j["error_m"] ** 2).mean())
    corrected_ms = float((j["error_m"] ** 2 + j["reference_correction_m2"]).mean())
    assert raw_ms < 0.8 * true_ms
    assert abs(corrected_ms / true_ms - 1.0) < 0.15


def test_without_truth_the_rows_say_which_reference_and_how_to_correct(scene):
    _, _, _, without = scene
    tr, h = without.tracks, without.health
    assert set(tr["reference"].drop_nulls()) == {"reconstructed"}
    assert tr["identity_correct"].null_count() == tr.height  # no truth: no judgement
    scored = h.filter(pl.col("error_m").is_not_null())
    used, unused = scored.filter(pl.col("used")), scored.filter(~pl.col("used"))
    assert (used["reference_correction_m2"] > 0).all()
    if unused.height:
        assert (unused["reference_correction_m2"] < 0).all()
    assert (scored["reference_p95_m"] <= MAX_REFERENCE_P95_M).all()
    assert without.reference.height == tr.height


def test_smooth_needs_a_recorded_run(scene):
    from pipeline.airfield.fusion import FilterRun

    _, _, _with_truth, _ = scene

    class _Out:
        x_full = None
        P_full = None

    with pytest.raises(ValueError, match="recorded"):
        smooth(FilterRun(None, _Out(), None, NS))  # type: ignore[arg-type]
