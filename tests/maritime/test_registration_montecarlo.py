"""Registration where no ship carries AIS and per sector where a radar's error differs
(issue 38 item 1; slow, seeded Monte Carlo of ``pipeline.experiments.registration_no_ais``
and ``registration_sectors``): the radar-radar pairs find the faulted radar of two,
correct it, and correct nothing else; a fault over part of a radar's rotation is
registered per sector, no worse than one registration per site, and a fault at every
azimuth keeps one.

Run: .venv/bin/pytest -m slow tests/maritime/test_registration_montecarlo.py -s (6 seeds
each; the docs' tables are `python -m bench.registration_no_ais --runs 30` and
`python -m bench.registration_sectors --runs 30`)."""

from __future__ import annotations

from types import ModuleType

import polars as pl
import pytest

from pipeline.experiments import registration_no_ais, registration_sectors


def _summary(experiment: ModuleType, seeds: range) -> pl.DataFrame:
    """``experiment``'s summary table over ``seeds`` and every fault (printed with -s)."""
    rows = pl.DataFrame([experiment.run_one((s, i)) for i in range(len(experiment.FAULTS))
                         for s in seeds])
    out = experiment.summarise(rows)
    with pl.Config(tbl_cols=-1, tbl_width_chars=250):
        print("\n", out)
    return out


@pytest.fixture(scope="module")
def table() -> pl.DataFrame:
    return _summary(registration_no_ais, range(2000, 2006))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["radar_range_bias", "radar_azimuth_bias", "radar_range_gain"])
def test_the_faulted_radar_is_found_and_corrected_without_ais(table, kind):
    r = table.filter(pl.col("kind") == kind).row(0, named=True)
    assert r["rms_on_m"] < 0.7 * r["rms_off_m"], r
    assert r["p95_on_le_off"] == 1.0 and r["duplicates_on"] < r["duplicates_off"], r
    assert r["within_95"] >= 5 / 6 and r["applied_mid"] >= 5 / 6, r
    assert r["other_site_applied_share"] < 0.02 and r["before_applied_share"] < 0.02, r


@pytest.mark.slow
def test_a_clock_offset_is_not_corrected_without_ais(table):
    # only the two clocks' difference is observable from the pairs: nothing is applied,
    # and the picture is left as it was (docs/integrity.md §9, Limits)
    r = table.filter(pl.col("kind") == "radar_time_offset").row(0, named=True)
    assert r["applied_mid"] == 0.0 and r["rms_on_m"] == r["rms_off_m"], r
    assert r["within_95"] >= 5 / 6, r


@pytest.fixture(scope="module")
def by_sector() -> pl.DataFrame:
    return _summary(registration_sectors, range(3000, 3006))


@pytest.mark.slow
@pytest.mark.parametrize("fault", ["azimuth_bias_in_50_140_deg", "range_bias_in_50_140_deg"])
def test_a_fault_over_part_of_the_rotation_is_registered_per_sector(by_sector, fault):
    r = by_sector.filter(pl.col("fault") == fault).row(0, named=True)
    assert r["p95_sector_le_site"] == 1.0 and r["rms_sector_m"] < 0.9 * r["rms_site_m"], r
    assert r["sector_share_fault"] > 0.3 and r["sector_share_before"] == 0.0, r


@pytest.mark.slow
def test_a_fault_at_every_azimuth_is_registered_per_site(by_sector):
    r = by_sector.filter(pl.col("fault") == "azimuth_bias_everywhere").row(0, named=True)
    assert r["sector_share_fault"] == 0.0 and r["rms_sector_m"] == r["rms_site_m"], r
