"""Work units sized by data volume: cuts from the time column, a batch over many units
commits the same association rows as over one, and a unit's seam stays on disk."""

from __future__ import annotations

import dataclasses
import itertools
import pickle
import shutil

import numpy as np
import polars as pl

from pipeline.batch import driver, plan, seams, worker
from pipeline.families import FAMILIES
from pipeline.family import Window
from pipeline.maritime.stitch import unit_seam
from pipeline.units import NS
from pipeline.warehouse.delta import read_table, volume_cuts


def test_volume_cuts_balance_rows() -> None:
    """Whole-second cuts, the fewest pieces of at most max_rows (one second's rows
    over), none when the rows fit in one."""
    per_s = np.array([10] * 100 + [40] * 100 + [10] * 200)  # 7000 rows over 400 s
    start = 1_000 * NS
    cuts = volume_cuts(per_s, start, 2000)
    assert len(cuts) == 3 and all((c - start) % NS == 0 for c in cuts)
    edges = [0, *((c - start) // NS for c in cuts), per_s.size]
    per = [int(per_s[a:b].sum()) for a, b in itertools.pairwise(edges)]
    assert sum(per) == 7000 and max(per) <= 2000 + 40
    assert volume_cuts(per_s, start, 10_000) == []


def test_many_units_same_association_rows(e2e, tmp_path, monkeypatch) -> None:
    """The e2e window cut two ways, by the hour and into ~6 units by volume: the same
    association rows, system track ids included (was: the same (epoch, site, track) rows
    but >= 85 % of local tracks keeping one id, each unit starting its association
    afresh), and the same fused errors against truth. On a copy of the warehouse (the
    e2e one stays hour-cut for the other tests)."""
    wh = tmp_path / "warehouse"
    shutil.copytree(e2e.warehouse, wh)
    rows = read_table(wh, "radar_tracks", start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                      columns=["time_ns"], sort=False).num_rows
    assert rows > 0
    hourly = _run(e2e, wh)
    small = dataclasses.replace(FAMILIES[0], unit_rows=rows // 6)
    monkeypatch.setattr(driver, "family", lambda name: small)
    monkeypatch.setattr(worker, "family", lambda name: small)
    cut = _run(e2e, wh, min_units=6)
    a, b = cut["a"], hourly["a"]
    assert a.sort(a.columns).equals(b.sort(b.columns))
    assert _kept_one_id(a) == _kept_one_id(b) > 0.85
    assert cut["rms"] == hourly["rms"]


def _run(e2e, wh, min_units: int = 1) -> dict:
    s = driver.run_batch(e2e.cfg, wh, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                        executor_kind="serial", families=("maritime",))
    assert s.committed and s.units_total >= min_units
    a = pl.from_arrow(read_table(wh, "associations", start_ns=e2e.start_ns, end_ns=e2e.end_ns))
    err = pl.from_arrow(read_table(wh, "track_errors", start_ns=e2e.start_ns,
                                   end_ns=e2e.end_ns)).filter(pl.col("source") == "fused")
    tracks = pl.from_arrow(read_table(wh, "system_tracks", start_ns=e2e.start_ns,
                                      end_ns=e2e.end_ns, columns=["system_track_id", "time_ns"]))
    assert tracks.height and not tracks.is_duplicated().any()  # one ship per id and epoch
    return {"a": a, "rms": float(np.sqrt((err["error_m"] ** 2).mean()))}


def _kept_one_id(a: pl.DataFrame) -> float:
    """Share of (site, local track) pairs that kept a single system track id."""
    ids = a.group_by("site_id", "local_track_id").agg(pl.col("system_track_id").n_unique())
    return float((ids["system_track_id"] == 1).mean())


def test_a_units_seam_stays_in_its_folder_until_the_join(e2e, tmp_path) -> None:
    """The manifest a worker returns names its seam's file (the driver reads a window's
    seams one pair at a time; a region day's held 2 GB in the driver): the file holds
    the stage's seam rows, and the manifest pickles small."""
    t0 = e2e.start_ns + 600 * NS
    unit = worker.BatchUnit(str(e2e.warehouse), str(tmp_path / "staging"), t0, t0 + 600 * NS,
                           e2e.cfg)
    m = worker.run_unit(unit)
    assert isinstance(m.seam, worker.SeamFile)
    fam = worker.family("maritime")
    inputs = worker.read_inputs(fam, e2e.warehouse, e2e.cfg, Window(t0, t0 + 600 * NS))
    expected = unit_seam(fam.stage(inputs, Window(t0, t0 + 600 * NS), e2e.cfg))
    assert expected.height > 100
    assert m.seam.read().equals(expected)
    assert len(pickle.dumps(m)) < 4096
    joined = seams.Seams([m.seam, expected])
    assert len(joined) == 2 and joined[0].equals(joined[1])


def test_a_wave_of_fewer_units_than_workers_is_granted_their_idle_cores(e2e, tmp_path) -> None:
    """A reprocessed hour's one gaps unit runs after its maritime wave with the pool's
    other worker idle: it gets that worker's threads (the process pool only)."""
    def units(n: int) -> list[worker.BatchUnit]:
        return [worker.BatchUnit(str(e2e.warehouse), str(tmp_path), i, i + 1, e2e.cfg, "gaps")
                for i in range(n)]

    def threads(us: list[worker.BatchUnit]) -> list[int]:
        return [u.cfg.execution.threads_per_worker for u in us]

    assert e2e.cfg.execution.threads_per_worker == 1
    assert threads(plan.granted(units(1), "process", 2)) == [2]
    assert threads(plan.granted(units(2), "process", 5)) == [2, 2]
    assert threads(plan.granted(units(2), "process", 2)) == [1, 1]
    assert threads(plan.granted(units(1), "ray", 2)) == [1]
    assert threads(plan.granted(units(1), "serial", 1)) == [1]
    granted = plan.granted(units(1), "process", 2)[0]
    assert granted.cfg.region == e2e.cfg.region and granted.start_ns == 0
