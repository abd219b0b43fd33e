"""A one-unit-per-window family owns no unit where it has no input rows (issue 19): the
``nav`` family (``unit_s = None``) over an archive without own-ship data planned one unit
over the whole batch window, so a reprocess of any sub-window widened to all of it (the
24 h region day: a 1-hour reprocess re-ran the day)."""

from __future__ import annotations

import shutil
from dataclasses import replace

import polars as pl

from jobs.reprocess import run_reprocess
from pipeline import tables
from pipeline.batch import run_batch
from pipeline.batch.pending import pending_windows
from pipeline.batch.plan import owned_window, plan_units, unit_is_live
from pipeline.families import family
from pipeline.family import TableInput
from pipeline.units import NS
from pipeline.warehouse.delta import read_table, replace_window
from tests.jobs.test_reprocess_exact import DERIVED, assert_same, snapshot

MIN = 60 * NS


def _units(wh) -> pl.DataFrame:
    return pl.from_arrow(read_table(wh, "batch_units")).sort("family", "start_ns")


def test_no_nav_data_no_nav_unit_and_a_reprocess_is_not_widened_by_nav(e2e, tmp_path):
    """The e2e archive holds radars and AIS, no own-ship data: the batch records no nav
    unit, and a reprocess inside the second hour re-runs only that hour's units (was:
    the whole batch window, the nav unit's) with every table as the single pass."""
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    assert read_table(wh, "nav_gnss").num_rows == 0
    units = _units(wh)
    assert "nav" not in units["family"].to_list()
    assert "maritime" in units["family"].to_list()
    single = snapshot(wh, DERIVED)
    hour1 = e2e.start_ns + 10 * MIN  # 01:00; the data is 00:50 - 01:10
    res = run_reprocess(e2e.cfg, wh, start_ns=hour1 + 2 * MIN, end_ns=hour1 + 5 * MIN,
                        executor_kind="serial")
    assert res.exit_code == 0, res.render()
    assert (res.batch.start_ns, res.batch.end_ns) == (hour1, e2e.end_ns)
    assert_same(snapshot(wh, DERIVED), single, "reprocess of 3 minutes of the second hour")
    keys = ["family", "start_ns", "end_ns"]
    assert _units(wh).select(keys).equals(units.select(keys))  # the same units
    assert pending_windows(wh) == []  # `surveil run` finds nothing left to batch


def test_a_nav_unit_recorded_without_input_rows_does_not_widen(e2e, tmp_path):
    """A warehouse batched before the fix holds a nav unit over the whole window: it
    owns no rows (no nav input in it), so it neither widens nor cuts a reprocess."""
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    site = tables.default_site()
    legacy = pl.DataFrame({"start_ns": [e2e.start_ns], "end_ns": [e2e.end_ns],
                           "family": ["nav"], "window_start_ns": [e2e.start_ns],
                           "window_end_ns": [e2e.end_ns], "committed_at_ns": [0]})
    both = pl.concat([pl.from_arrow(read_table(wh, "batch_units")).drop(
        "site", "date", strict=False), legacy], how="diagonal_relaxed")
    replace_window(wh, "batch_units", tables.conform("batch_units", both, site=site),
                   start_ns=e2e.start_ns, end_ns=e2e.end_ns, site=site)
    hour1 = e2e.start_ns + 10 * MIN
    lo, hi, cuts = owned_window(wh, hour1 + 2 * MIN, hour1 + 5 * MIN, site)
    assert (lo, hi) == (e2e.start_ns, e2e.end_ns)  # the widening the defect made
    lo, hi, cuts = owned_window(wh, hour1 + 2 * MIN, hour1 + 5 * MIN, site,
                                unit_is_live(wh, e2e.cfg, site))
    assert (lo, hi) == (hour1, e2e.end_ns) and "nav" not in cuts
    res = run_batch(e2e.cfg, wh, start_ns=hour1 + 2 * MIN, end_ns=hour1 + 5 * MIN,
                    executor_kind="serial")
    assert res.exit_code == 0 and (res.start_ns, res.end_ns) == (hour1, e2e.end_ns)


def test_a_one_unit_family_with_input_rows_still_gets_its_whole_window_unit(e2e, tmp_path):
    """The rule looks at rows, not at the family: a one-unit-per-window family reading a
    table with rows in the window plans one unit over it; over a window of the same
    table without rows, none."""
    nav = family("nav")
    ais_like = replace(nav, name="ais_like",
                       inputs=lambda cfg: (TableInput("ais_reports", before_s=60.0),))
    wh, cfg = e2e.warehouse, e2e.cfg
    units = plan_units(wh, cfg, e2e.start_ns, e2e.end_ns, tmp_path, (nav, ais_like))
    assert [(u.family, u.start_ns, u.end_ns) for u in units] == [
        ("ais_like", e2e.start_ns, e2e.end_ns)]
    later = e2e.end_ns + 60 * MIN  # no row there (its margin reaches no row either)
    assert plan_units(wh, cfg, later, later + 60 * MIN, tmp_path, (nav, ais_like)) == []


def test_an_hourly_family_plans_units_only_in_hours_with_input_rows(e2e, tmp_path):
    """Batch cost follows the data (issue 34): the e2e archive has no airfield sensor, and
    radar/AIS rows only in 00:50-01:10. Over 22:00-03:00 the maritime family plans units
    in the two hours with rows, the airfield family none (was: one unit per hour of the
    window per family: 10 units of nothing); the tables are those of a batch over the two
    hours alone. (The gaps family reads maritime's system_tracks, unknown before the
    batch runs: its hourly units are still planned.)"""
    hour = 60 * MIN
    first, last = e2e.start_ns // hour * hour, (e2e.end_ns - 1) // hour * hour + hour
    wide, tight = tmp_path / "wide", tmp_path / "tight"
    for wh in (wide, tight):
        shutil.copytree(e2e.warehouse, wh)
        for name in (*DERIVED, "batch_units"):
            shutil.rmtree(wh / "tables" / name, ignore_errors=True)
    units = plan_units(wide, e2e.cfg, first - 2 * hour, last + 2 * hour, tmp_path / "staging")
    assert {u.start_ns // hour for u in units if u.family == "maritime"} == {
        first // hour, first // hour + 1}
    assert not [u for u in units if u.family == "airfield"]
    for wh, (start, end) in ((wide, (first - 2 * hour, last + 2 * hour)), (tight, (first, last))):
        res = run_batch(e2e.cfg, wh, start_ns=start, end_ns=end, executor_kind="serial")
        assert res.exit_code == 0, res.render()
    assert_same(snapshot(wide, DERIVED), snapshot(tight, DERIVED), "empty hours around the data")
    maritime = [pl.col("family") == "maritime"]
    keys = ["start_ns", "end_ns"]
    assert _units(wide).filter(maritime).select(keys).equals(
        _units(tight).filter(maritime).select(keys))
