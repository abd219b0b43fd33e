"""The maritime stage cut into units gives the rows of one pass (issue 17 item 2, issue
19 item 4), on the channel scenario WITH its fault schedule: units cut inside a radar
bias, an AIS offset, a frozen AIS, a radar outage and an MMSI swap. Each unit tracks a
lead-in and a look-ahead beyond its window (pairings, integrity state and identity votes
carried over the seam) and the stitch continues the ids of the unit before."""

from __future__ import annotations

from itertools import pairwise

import polars as pl
import pytest
from maritime_helpers import T0_NS, scenario_tables
from polars.testing import assert_frame_equal

from pipeline.batch.seams import Joiner
from pipeline.batch.summary import BatchSummary
from pipeline.batch.worker import SeamFile, UnitManifest, finalize_unit
from pipeline.families import family, load_config
from pipeline.family import Window, relabel
from pipeline.maritime.stage import stage
from pipeline.maritime.stitch import join_units, unit_seam
from pipeline.units import NS

PER_EPOCH = ("associations", "system_tracks", "identifications", "track_errors",
             "maritime_channel_health", "sensor_registration")
START_S, END_S = 300, 2300
CUTS_S = (450, 750, 1290, 1500, 1830)  # inside faults (config/surveil.toml)


@pytest.fixture(scope="module")
def scenario():
    cfg = load_config()
    radar, ais, truth = scenario_tables(cfg, duration_s=2400.0, seed=11, faults=True)
    return cfg, {"radar_tracks": radar, "ais_reports": ais, "truth": truth}


def batch_by_units(scenario, cuts_s) -> dict[str, pl.DataFrame]:
    """The stage over each unit, ids stitched as the batch stitches them."""
    cfg, inputs = scenario
    edges = [T0_NS + s * NS for s in (START_S, *cuts_s, END_S)]
    outs = [stage(inputs, Window(a, b), cfg) for a, b in pairwise(edges)]
    maps = join_units([unit_seam(o) for o in outs])
    return {name: pl.concat([relabel(o[name], m) if m else o[name]
                             for o, m in zip(outs, maps, strict=True)])
            for name in PER_EPOCH}


def test_units_cut_inside_faults_give_the_one_pass_rows(scenario):
    one = batch_by_units(scenario, ())
    cut = batch_by_units(scenario, CUTS_S)
    assert one["maritime_channel_health"]["eta"].sum() > 0  # faults were detected
    assert one["system_tracks"]["mmsi"].is_not_null().mean() > 0.5
    # registration corrected the faulted radars and fused them (issue 38): corrected
    # before the association (the second pass), they pass the integrity test
    applied = (one["sensor_registration"].filter("registration_applied")
               .select("time_ns", "site_id").unique())
    assert applied.height and one["associations"].join(
        applied, on=["time_ns", "site_id"])["used"].mean() > 0.5
    for name in PER_EPOCH:
        a, b = (t.sort(t.columns) for t in (cut[name], one[name]))
        try:
            assert_frame_equal(a, b)
        except AssertionError as exc:
            key = [c for c in b.columns if b[c].dtype != pl.Float64]
            only_cut = a.join(b, on=key, how="anti", nulls_equal=True)
            only_one = b.join(a, on=key, how="anti", nulls_equal=True)
            raise AssertionError(f"{name} differs: {only_cut.height} rows only in the cut "
                                 f"batch, {only_one.height} only in one pass:\n"
                                 f"{only_cut.head(8)}\n{only_one.head(8)}\n{exc}") from None


def test_units_joined_as_they_finish_get_the_relabelling_of_one_join(scenario, tmp_path):
    """The batch finalises a unit as soon as it and the units before it are done
    (``pipeline.batch.seams.Joiner``): the join chained over the units in the order they finish
    gives each unit the relabelling the join of every seam at once gives it. Each unit's
    seam is a file in its staging folder, which its finalisation removes, here at once
    (as a worker may before the next unit is joined)."""
    cfg, inputs = scenario
    edges = [T0_NS + s * NS for s in (START_S, *CUTS_S, END_S)]
    seams = [unit_seam(stage(inputs, Window(a, b), cfg)) for a, b in pairwise(edges)]
    whole = join_units(seams)
    assert whole[0] is None and whole[2] and whole[4]  # chains start at both kinds
    folders = [tmp_path / f"unit-{k}" for k in range(len(seams))]
    for folder, seam in zip(folders, seams, strict=True):
        folder.mkdir()
        SeamFile.write(seam, folder / "_seam.arrow")
    joiner = Joiner(family("maritime"), edges[:-1], BatchSummary(start_ns=edges[0],
                                                                  end_ns=edges[-1]), None)
    finished = [0, 2, 1, 4, 3, 5]  # completion order: joins chained at units 0, 2 and 4
    got: dict[int, object] = {}
    for done, k in enumerate(finished):
        unit = UnitManifest("maritime", edges[k], {}, SeamFile(str(folders[k] / "_seam.arrow")),
                            staging_dir=str(folders[k]))
        for t in joiner.ready(unit):  # a unit is joined once every unit before it is done
            i = edges.index(t.manifest.start_ns)
            assert set(range(i + 1)) <= set(finished[: done + 1])
            got[i] = t.mapping
            finalize_unit(t)
            assert not folders[i].exists()
    assert sorted(got) == list(range(len(seams)))
    assert [got[i] for i in range(len(seams))] == whole


def test_units_of_a_family_without_a_join_are_finalised_as_each_finishes():
    """A family without ``join_units`` (airfield, nav, gaps) has nothing to relabel: a
    unit finished before the units ahead of it is finalised at once (was: it waited for
    them, time order, as a joined family's must)."""
    fam = family("airfield")
    assert fam.join_units is None
    starts = [T0_NS + k * 3600 * NS for k in range(3)]
    joiner = Joiner(fam, starts, BatchSummary(start_ns=starts[0], end_ns=starts[-1]), None)
    for k in (2, 0, 1):
        tasks = joiner.ready(UnitManifest("airfield", starts[k], {}))
        assert [(t.manifest.start_ns, t.mapping) for t in tasks] == [(starts[k], None)]


def _seam_rows(part: str, rows: list[tuple[int, str | None, int | None, int]]) -> pl.DataFrame:
    return pl.DataFrame(rows, schema={"time_ns": pl.Int64, "site_id": pl.Utf8,
                                      "local_track_id": pl.Int64,
                                      "system_track_id": pl.Int64},
                        orient="row").with_columns(part=pl.lit(part))


def test_a_lead_in_track_continuing_nothing_never_takes_an_id_of_the_unit_before():
    """Unit k+1's lead-in starts cold: its track B born in the lead-in may get the id
    unit k gave another ship born in the same ms (the same rank among other births),
    while its track A continues that very id. Seen on the region day: two ships 44 km
    apart under one system_track_id at one epoch. B gets an id of its own, born at its
    first row in the window; A continues P."""
    birth_ms = 1_768_436_980_000
    p = birth_ms * 1_000_000 + 1  # unit k's id P; in unit k+1 B's native id is P too
    a = birth_ms * 1_000_000 + 0
    t0, t1, first_b = (birth_ms + 20_000) * 1_000_000, (birth_ms + 24_000) * 1_000_000, \
        (birth_ms + 60_000) * 1_000_000
    unit_k = _seam_rows("tail", [(t0, "R1", 7, p), (t1, "R1", 7, p)])
    unit_k1 = pl.concat([
        _seam_rows("head", [(t0, "R1", 7, a), (t1, "R1", 7, a), (t1, "R3", 2, p)]),
        _seam_rows("born", [(first_b, None, None, a), (first_b, None, None, p)]),
    ])
    maps = join_units([unit_k, unit_k1])
    assert maps[0] is None
    relabelled = maps[1]["system_track_id"]
    assert relabelled[a] == p
    own = relabelled[p]
    assert own not in (a, p) and own // 1_000_000 == first_b // 1_000_000
    assert relabel(unit_k1, maps[1])["system_track_id"].n_unique() == 2


def test_cut_units_never_give_two_tracks_one_id_at_one_epoch(scenario):
    cut = batch_by_units(scenario, CUTS_S)["system_tracks"]
    assert cut.height and cut.select("system_track_id", "time_ns").is_duplicated().sum() == 0
