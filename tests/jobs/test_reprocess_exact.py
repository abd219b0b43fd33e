"""Reprocess is exact (issue 17, item 2): a sub-window reprocess, aligned or not, in any
order, leaves every table equal to the single-pass result row for row; system track ids
continue across a window's leading edge."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import polars as pl
import pytest
from polars.testing import assert_frame_equal

from jobs.batch import run_batch
from jobs.reprocess import run_reprocess
from pipeline.families import FAMILIES, family
from pipeline.units import NS
from pipeline.warehouse.delta import read_table, table_path

DERIVED = [name for fam in FAMILIES for name in fam.outputs]
MIN = 60 * NS
UNIT_SETTLE_S = 0.0


def snapshot(warehouse, names=(*DERIVED, "batch_units")) -> dict[str, pl.DataFrame]:
    out = {}
    for name in names:
        t = pl.from_arrow(read_table(warehouse, name))
        if name == "batch_units":
            t = t.drop("committed_at_ns", "window_start_ns", "window_end_ns")  # bookkeeping
        out[name] = t.sort(t.columns) if t.height else t
    return out


def assert_same(got: dict[str, pl.DataFrame], want: dict[str, pl.DataFrame], label: str):
    for name in want:
        try:
            assert_frame_equal(got[name], want[name])
        except AssertionError as exc:
            raise AssertionError(f"{label}: table {name} differs: {exc}") from None


def test_sub_window_reprocess_gives_the_single_pass_rows(e2e, tmp_path):
    """Was: siap_by_sector kept the whole-window rows beside the sub-window's (truth
    epochs doubled) and the sub-window's system tracks got new ids."""
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    single = snapshot(wh)
    assert single["siap_by_sector"].height > 0 and single["system_tracks"].height > 0
    t0 = e2e.start_ns  # 00:50; the maritime units are [00:50, 01:00) and [01:00, 01:10)
    t1, t2 = t0 + 10 * MIN, e2e.end_ns  # (no nav data: no nav unit over the whole window)
    windows = [(t0 + 12 * MIN, t0 + 15 * MIN, t1, t2),          # inside the second unit
               (t0, t0 + 10 * MIN, t0, t1),                      # the first unit, aligned
               (t0 + 5 * MIN + 7 * NS, t0 + 15 * MIN, t0, t2)]  # across the seam
    for start, end, lo, hi in windows:
        res = run_reprocess(e2e.cfg, wh, start_ns=start, end_ns=end, executor_kind="serial")
        assert res.exit_code == 0, res.render()
        assert (res.batch.start_ns, res.batch.end_ns) == (lo, hi)  # the units it overlaps
        assert_same(snapshot(wh), single, f"after reprocess [{start}, {end})")
    truth_epochs = pl.from_arrow(read_table(wh, "siap_by_sector"))["truth_epochs"].sum()
    assert truth_epochs == single["siap_by_sector"]["truth_epochs"].sum()


def test_windows_batched_apart_continue_ids_and_reprocess_keeps_them(e2e, tmp_path):
    """Two consecutive batches (a nightly increment) give the maritime tables of one
    pass: the second window's first unit is stitched to the rows committed before it.
    A reprocess inside the second window then re-runs exactly its units (whole) and
    changes nothing. The gaps family runs one unit per batch window (its particle
    filters need continuity), so its rows follow the batch windows: it is compared with
    itself, not with the single pass."""
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    single = snapshot(wh)
    for name in (*DERIVED, "batch_units"):
        shutil.rmtree(table_path(wh, name), ignore_errors=True)
    seam = e2e.start_ns + 10 * MIN  # 01:00
    for start, end in ((e2e.start_ns, seam), (seam, e2e.end_ns)):
        res = run_batch(e2e.cfg, wh, start_ns=start, end_ns=end, executor_kind="serial")
        assert res.exit_code == 0 and res.requested is None, res.render()
    maritime = family("maritime").outputs
    apart = snapshot(wh)
    assert_same({n: apart[n] for n in maritime}, {n: single[n] for n in maritime},
                 "two windows vs one pass")
    ids = apart["system_tracks"]["system_track_id"]
    assert ids.n_unique() == single["system_tracks"]["system_track_id"].n_unique()

    res = run_reprocess(e2e.cfg, wh, start_ns=seam + 2 * MIN, end_ns=seam + 5 * MIN,
                        executor_kind="serial")
    assert res.exit_code == 0, res.render()
    assert (res.batch.start_ns, res.batch.end_ns) == (seam, e2e.end_ns)  # whole units
    assert_same(snapshot(wh), apart, "reprocess inside the second window")


def test_changed_rows_at_a_windows_end_carry_on_into_the_next_units(e2e, tmp_path):
    """Was: a reprocess that changed the rows at its window's end (new data, another
    config) left the units after it continuing the old ids: a track break at the edge.
    Now the next committed units are batched again until a window ends as before: here
    the second window, so both windows equal one pass under the new config."""
    strict, seam, wh, one = _two_windows_and_a_new_config(e2e, tmp_path)
    maritime = family("maritime").outputs
    before = snapshot(wh, maritime)
    res = run_batch(strict, wh, start_ns=e2e.start_ns, end_ns=seam, executor_kind="serial")
    assert res.exit_code == 0, res.render()
    (summary,) = res.by_site.values()
    assert [(c.start_ns, c.end_ns) for c in summary.continued] == [(seam, e2e.end_ns)]
    assert "batched again" in res.render()
    after = snapshot(wh, maritime)
    assert not after["system_tracks"].equals(before["system_tracks"])  # the config mattered
    assert run_batch(strict, one, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                     executor_kind="serial").exit_code == 0
    assert_same(after, snapshot(one, maritime), "reprocess with a new config vs one pass")
    # the same batch again changes nothing at the edge: no continuation
    res = run_batch(strict, wh, start_ns=e2e.start_ns, end_ns=seam, executor_kind="serial")
    assert [c for s in res.by_site.values() for c in s.continued] == []


def test_a_window_nothing_continues_reads_no_rows_at_its_end(e2e, tmp_path, monkeypatch):
    """A window with no committed unit starting at its end (a site batched in time
    order) reads no seam there, before or after its commit, and promises nothing
    (``_continue/``); one with units after it compares its end's rows (as above)."""
    import pipeline.batch.driver

    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    for name in (*DERIVED, "batch_units"):
        shutil.rmtree(table_path(wh, name), ignore_errors=True)
    read_at: list[int] = []
    digests = pipeline.batch.driver.trailing_digests

    def counted(warehouse, fams, end_ns, site):
        read_at.append(end_ns)
        return digests(warehouse, fams, end_ns, site)

    monkeypatch.setattr(pipeline.batch.driver, "trailing_digests", counted)
    seam = e2e.start_ns + 10 * MIN
    for start, end in ((e2e.start_ns, seam), (seam, e2e.end_ns)):
        assert run_batch(e2e.cfg, wh, start_ns=start, end_ns=end,
                         executor_kind="serial").exit_code == 0
    assert read_at == [] and not (wh / "_continue").exists()
    res = run_batch(e2e.cfg, wh, start_ns=e2e.start_ns, end_ns=seam, executor_kind="serial")
    assert res.exit_code == 0 and read_at == [seam, seam]
    assert [c for s in res.by_site.values() for c in s.continued] == []  # ends as before


class _Killed(BaseException):
    pass


@pytest.mark.parametrize("resumed_by", ["batch", "run"])
def test_a_job_killed_before_its_chain_leaves_it_to_the_next_batch(e2e, tmp_path,
                                                                   monkeypatch, resumed_by):
    """The chain above is promised in ``_continue/`` before the window's commit: killed
    right after the commit (before the units after it were batched again), the next
    batch of the site finds the rows at the window's end changed and runs the chain
    first; a job killed before its commit leaves a record the next batch drops."""
    import pipeline.batch.driver
    strict, seam, wh, one = _two_windows_and_a_new_config(e2e, tmp_path)
    maritime = family("maritime").outputs

    def kill_at(name: str):
        def crash(point: str) -> None:
            if point == name:
                raise _Killed(point)
        return crash

    monkeypatch.setattr(pipeline.batch.driver, "crash_point", kill_at("batch.continuation"))
    with pytest.raises(_Killed):
        run_batch(strict, wh, start_ns=e2e.start_ns, end_ns=seam, executor_kind="serial")
    monkeypatch.setattr(pipeline.batch.driver, "crash_point", lambda point: None)
    assert len(list((wh / "_continue").glob("*.json"))) == 1
    if resumed_by == "batch":  # the next batch of the site (the first window again)
        res = run_batch(strict, wh, start_ns=e2e.start_ns, end_ns=seam,
                        executor_kind="serial")
        assert [(c.start_ns, c.end_ns) for r in res.resumed for c in r.continued] == [
            (seam, e2e.end_ns)]
        assert "a killed job left the units after" in res.render()
    else:  # the nightly run: no file changed, no window pending, the chain is run
        from pipeline.batch.nightly import run_nightly
        res = run_nightly(strict, wh, folders=[str(Path(e2e.archive[0]).parent)],
                          executor_kind="serial")
        assert res.windows == [(seam, e2e.end_ns)] and not res.files
    assert res.exit_code == 0, res.render()
    assert list((wh / "_continue").glob("*.json")) == []
    assert run_batch(strict, one, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                     executor_kind="serial").exit_code == 0
    assert_same(snapshot(wh, maritime), snapshot(one, maritime), "after the resumed chain")


def test_a_chain_that_fails_in_a_nightly_run_is_tried_once_in_it(e2e, tmp_path, monkeypatch):
    """Was: ``surveil run`` ran a killed job's chain, and when it failed, ran it again
    inside its batch of each pending window. Now the run tries it once; the record stays
    for the next run, and the pending window is still batched."""
    import pipeline.batch.driver
    import pipeline.batch.nightly
    import pipeline.batch.worker
    strict, seam, wh, _ = _two_windows_and_a_new_config(e2e, tmp_path)

    def crash(point: str) -> None:
        if point == "batch.continuation":
            raise _Killed(point)

    monkeypatch.setattr(pipeline.batch.driver, "crash_point", crash)
    with pytest.raises(_Killed):
        run_batch(strict, wh, start_ns=e2e.start_ns, end_ns=seam, executor_kind="serial")
    monkeypatch.setattr(pipeline.batch.driver, "crash_point", lambda point: None)
    run_unit, tried = pipeline.batch.worker.run_unit, []

    def failing_after_the_seam(unit):  # the chain's units fail, the pending window's run
        if unit.start_ns >= seam:
            tried.append((unit.family, unit.start_ns))
            raise RuntimeError("chain unit fails")
        return run_unit(unit)

    monkeypatch.setattr(pipeline.batch.worker, "run_unit", failing_after_the_seam)
    site = pipeline.batch.sites_in(wh, e2e.start_ns, seam)[0]
    monkeypatch.setattr(pipeline.batch.nightly, "pending_by_site",
                        lambda w: {site: [(e2e.start_ns, seam)]})
    # the stricter config would also make every window of the old one pending
    # (tests/jobs/test_provenance.py): the chain alone is under test here
    monkeypatch.setattr(pipeline.batch.nightly, "stale_spans", lambda w, cfg: [])
    res = pipeline.batch.nightly.run_nightly(strict, wh, folders=[str(Path(e2e.archive[0]).parent)],
                               executor_kind="serial")
    assert res.exit_code != 0 and any("chain unit fails" in f for f in res.failures)
    assert res.windows == [(seam, e2e.end_ns), (e2e.start_ns, seam)]
    assert len(tried) == len(set(tried)) > 0  # each unit of the chain tried once
    assert len(list((wh / "_continue").glob("*.json"))) == 1


def _two_windows_and_a_new_config(e2e, tmp_path):
    """(a stricter association config, the seam at 01:00, a warehouse with the e2e
    window batched as two windows [00:50, 01:00) and [01:00, 01:10), a warehouse with
    the raw tables only)."""
    from pipeline.families import config_from_mapping

    strict = config_from_mapping(
        {**e2e.cfg.sections,
         "association": {**e2e.cfg.section("association"), "gate_probability": 0.9,
                         "max_speed_difference_mps": 1.0}},
        e2e.cfg.source)
    seam = e2e.start_ns + 10 * MIN
    wh, one = tmp_path / "wh", tmp_path / "one"
    for path in (wh, one):
        shutil.copytree(e2e.warehouse, path)
        for name in (*DERIVED, "batch_units"):
            shutil.rmtree(table_path(path, name), ignore_errors=True)
    for start, end in ((e2e.start_ns, seam), (seam, e2e.end_ns)):
        assert run_batch(e2e.cfg, wh, start_ns=start, end_ns=end,
                         executor_kind="serial").exit_code == 0
    return strict, seam, wh, one


def test_a_reprocess_cuts_volume_units_where_the_single_pass_cut_them(e2e, tmp_path,
                                                                      monkeypatch):
    """Was: a reprocess cut a volume-cut family (maritime, ``unit_rows``) over its own
    widened window, not where the units it replaces were cut: other units, other rows
    where the unit overlap is not exact (``unit_settle_s = 0``), and the trailing-edge
    chain re-batching every later window (the 24 h region day's 1-hour reprocess ran
    half the day again). Now the cuts are a function of each hour's rows: the e2e window
    in ~8 volume units, reprocessed over unaligned sub-windows across several of them,
    keeps every table and ``batch_units`` row for row and continues nothing."""
    import pipeline.batch.driver
    import pipeline.batch.plan
    import pipeline.families
    from pipeline.families import config_from_mapping

    cfg = config_from_mapping(
        {**e2e.cfg.sections, "channel_integrity": {
            **e2e.cfg.section("channel_integrity"), "unit_settle_s": UNIT_SETTLE_S}},
        e2e.cfg.source)
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    for name in (*DERIVED, "batch_units"):
        shutil.rmtree(table_path(wh, name), ignore_errors=True)
    rows = read_table(wh, "radar_tracks", start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                      columns=["time_ns"], sort=False).num_rows
    small = tuple(replace(f, unit_rows=rows // 8) if f.name == "maritime" else f
                  for f in FAMILIES)
    monkeypatch.setattr(pipeline.families, "FAMILIES", small, raising=False)
    monkeypatch.setattr(pipeline.batch.driver, "FAMILIES", small)
    monkeypatch.setattr(pipeline.batch.plan, "FAMILIES", small)
    res = run_batch(cfg, wh, start_ns=e2e.start_ns, end_ns=e2e.end_ns, executor_kind="serial")
    assert res.exit_code == 0, res.render()
    single = snapshot(wh)
    edges = single["batch_units"].filter(pl.col("family") == "maritime")["start_ns"].sort()
    assert edges.len() >= 6
    t0 = e2e.start_ns
    for start, end in ((t0 + 3 * MIN + 11 * NS, t0 + 14 * MIN + 5 * NS),   # across 01:00
                       (t0 + 1 * MIN, t0 + 7 * MIN),
                       (t0 + 12 * MIN + 30 * NS, e2e.end_ns - 17 * NS)):
        res = run_reprocess(cfg, wh, start_ns=start, end_ns=end, executor_kind="serial")
        assert res.exit_code == 0, res.render()
        spanned = edges.filter((edges > res.batch.start_ns) & (edges < res.batch.end_ns))
        assert spanned.len() >= 1  # the reprocess re-ran several volume units
        assert [c for s in res.batch.by_site.values() for c in s.continued] == []
        assert_same(snapshot(wh), single, f"after reprocess [{start}, {end})")


def test_the_seam_before_a_window_reads_only_the_columns_it_compares(e2e):
    """The committed rows before a window are read with the family's ``seam_columns``
    (4 of the associations' columns, ~6x less work than all): the seam is the same."""
    from pipeline.batch.seams import stored_before
    from pipeline.maritime.stitch import SEAM_COLUMNS

    fam = family("maritime")
    edge = e2e.start_ns + 10 * MIN
    stored = stored_before(e2e.warehouse, fam, edge)
    assert stored["associations"].columns == list(SEAM_COLUMNS)
    full = pl.from_arrow(read_table(e2e.warehouse, "associations",
                                    start_ns=edge - round(fam.stitch_lookback_s * NS),
                                    end_ns=edge))
    assert full.width > len(SEAM_COLUMNS)
    got, want = fam.unit_seam(stored), fam.unit_seam({"associations": full})
    assert got.height > 0
    assert_frame_equal(got.sort(got.columns), want.sort(want.columns))
