"""Many sites, one warehouse (issue 17, item 4): every raw and derived row carries its
site; the batch runs each site alone (ids unique per site), ``--site`` on batch and
reprocess touches only that site, reports group by site, ``import --site`` and the MCAP
metadata name a file's site.

The defect: the gaps scenario ingested into the channel warehouse (both start at the same
time, truth ids collide) mixed silently: fused RMS 34.8 -> 389.7 m, ID correctness
0.99 -> 0.68. Now each site's figures in the shared warehouse equal its own warehouse's.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import polars as pl
import pyarrow as pa
import pyarrow.compute as pc
import pytest
from click.testing import CliRunner
from deltalake import DeltaTable, write_deltalake
from mcap.reader import make_reader
from polars.testing import assert_frame_equal

from jobs.batch import run_batch
from jobs.cli import cli
from jobs.common import UsageError, refuse_pre_sites
from jobs.reprocess import run_reprocess
from jobs.simulate import run_simulate
from pipeline import tables
from pipeline.convert.importer import run_import
from pipeline.families import FAMILIES
from pipeline.ingest.driver import IngestUsageError, run_ingest
from pipeline.io.mcap_site import declared_site
from pipeline.reports import open_warehouse, run_named_report
from pipeline.warehouse.delta import read_table, table_exists, table_path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "decode"))
from nmea_builders import sentence

GAPS_S = 600.0
HOUR = 3600 * 10**9
DERIVED = [name for fam in FAMILIES for name in fam.outputs]


def _figures(wh: Path) -> dict[str, tuple[float, float]]:
    """site -> (fused RMS against truth, m; SIAP ID correctness, all sectors)."""
    con = open_warehouse(wh)
    try:
        rms = con.sql("SELECT site, sqrt(avg(error_m * error_m)) FROM track_errors "
                      "WHERE source = 'fused' AND reference = 'truth' GROUP BY site").fetchall()
    finally:
        con.close()
    siap = pl.from_arrow(run_named_report(wh, "siap_by_sector")).filter(
        pl.col("sector") == "(all sectors)")
    ident = dict(zip(siap["site"], siap["id_correctness"], strict=True))
    return {site: (round(r, 1), ident[site]) for site, r in rms}


def _site_rows(wh: Path, site: str) -> dict[str, pl.DataFrame]:
    """Every derived table's rows of ``site``, sorted by the table's key."""
    out = {}
    for name in DERIVED:
        frame = pl.from_arrow(read_table(wh, name, site=site))
        out[name] = frame.sort(frame.columns)
    return out


def _site_files(wh: Path, site: str) -> dict[str, set[str]]:
    """Per derived table, the data files (of the current snapshot) holding ``site``'s
    rows only, by the files' ``site`` statistics: untouched files are the same bytes."""
    out = {}
    for name in DERIVED:
        if not table_exists(wh, name):
            continue
        adds = pa.table(DeltaTable(str(table_path(wh, name))).get_add_actions(flatten=True))
        keep = pc.and_(pc.equal(adds["min.site"], site), pc.equal(adds["max.site"], site))
        out[name] = set(adds.filter(keep)["path"].to_pylist())
    return out


def _same_rows(a: dict[str, pl.DataFrame], b: dict[str, pl.DataFrame]) -> list[str]:
    """Names of the tables whose rows differ (floats to 1e-9 relative: a sum's last bit
    depends on the order polars' threads add in)."""
    differ = []
    for name in a:
        try:
            assert_frame_equal(a[name], b[name], check_exact=False, rel_tol=1e-9)
        except AssertionError:
            differ.append(name)
    return differ


@pytest.fixture(scope="module")
def two_sites(e2e, tmp_path_factory):
    """The channel-clean warehouse (site 'channel-clean') with the gaps scenario (site
    'gaps', same start, colliding truth ids) and the channel scenario (site 'channel',
    another seed: colliding track numbers and truth ids) ingested and batched into it;
    and each of those two alone in a warehouse of its own."""
    root = tmp_path_factory.mktemp("sites")
    gaps = run_simulate("gaps", GAPS_S, 3, root / "gaps", e2e.cfg, start_ns=e2e.start_ns)
    chan = run_simulate("channel", GAPS_S, 8, root / "channel", e2e.cfg,
                        start_ns=e2e.start_ns)
    alone = {}
    for site, files in (("gaps", gaps), ("channel", chan)):
        wh = alone[site] = root / f"{site}-alone"
        assert run_ingest(files, e2e.cfg, wh, executor="serial").exit_code == 0
        assert run_batch(e2e.cfg, wh, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                         executor_kind="serial").exit_code == 0
    shared = root / "shared"
    shutil.copytree(e2e.warehouse, shared)
    ingest = run_ingest([*gaps, *chan], e2e.cfg, shared, executor="serial")
    assert ingest.exit_code == 0 and not ingest.overlaps, ingest.render()  # three sites
    batch = run_batch(e2e.cfg, shared, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                      executor_kind="serial")
    assert batch.exit_code == 0, batch.render()
    assert sorted(batch.by_site) == ["channel", "channel-clean", "gaps"]
    return gaps, alone, shared


def test_simulated_scenarios_name_their_site(e2e, two_sites):
    gaps, _, _ = two_sites
    assert {declared_site(p) for p in e2e.archive} == {"channel-clean"}
    assert {declared_site(p) for p in gaps} == {"gaps"}


def test_every_raw_and_derived_row_carries_its_site(e2e, two_sites):
    _, _, shared = two_sites
    for name, spec in tables.table_specs().items():
        if spec.kind in ("raw", "derived"):
            assert spec.schema.field("site").nullable is False, name
    for name in ("radar_tracks", "ais_reports", "truth", "ingest_ledger", "mcap_index",
                 *DERIVED, "batch_units"):
        sites = set(read_table(shared, name, columns=["site"])["site"].to_pylist())
        assert sites <= {"channel-clean", "channel", "gaps"} and None not in sites, (name, sites)
    assert set(read_table(shared, "truth", columns=["site"])["site"].to_pylist()) == {
        "channel-clean", "channel", "gaps"}


def test_two_scenarios_in_one_warehouse_do_not_mix(e2e, two_sites):
    """The issue's case: per site, the shared warehouse's fused RMS and ID correctness
    (and every derived row) equal each scenario's own warehouse. Before: the channel
    site's fused RMS went from ~35 m to ~390 m and its ID correctness from 0.99 to 0.68."""
    _, alone, shared = two_sites
    both = _figures(shared)
    # the gaps scenario has AIS only: no fused track of its own
    assert set(both) == {"channel-clean", "channel"}
    assert both == {**_figures(e2e.warehouse), **_figures(alone["channel"])}, both
    assert both["channel-clean"][0] < 60.0 and both["channel-clean"][1] > 0.95
    for site in ("gaps", "channel"):
        assert not _same_rows(_site_rows(shared, site), _site_rows(alone[site], site)), site
    assert not _same_rows(_site_rows(shared, "channel-clean"),
                          _site_rows(e2e.warehouse, "channel-clean"))


def test_reports_group_by_site_and_site_filters(e2e, two_sites):
    _, _, shared = two_sites
    every = pl.from_arrow(run_named_report(shared, "accuracy_by_sector"))
    assert set(every["site"]) == {"channel-clean", "channel"}  # apart, never summed
    one = pl.from_arrow(run_named_report(shared, "accuracy_by_sector", site="channel"))
    assert set(one["site"]) == {"channel"}
    assert one.equals(every.filter(pl.col("site") == "channel"))
    res = CliRunner().invoke(cli, ["--warehouse", str(shared), "report", "accuracy_by_sector",
                                   "--site", "channel-clean", "--format", "csv"])
    assert res.exit_code == 0, res.output
    assert "channel-clean" in res.output and "\nchannel," not in res.output
    bad = CliRunner().invoke(cli, ["--warehouse", str(shared), "report", "accuracy_by_sector",
                                   "--site", "no such/site"])
    assert bad.exit_code == 2


def test_batch_and_reprocess_of_one_site_leave_the_other_untouched(e2e, two_sites,
                                                                    tmp_path):
    _, _, shared = two_sites
    wh = tmp_path / "wh"
    shutil.copytree(shared, wh)
    gaps_before = _site_rows(wh, "gaps")
    gaps_files = _site_files(wh, "gaps")
    chan8_before = _site_rows(wh, "channel")
    chan8_files = _site_files(wh, "channel")
    gaps_ledger = pl.from_arrow(read_table(wh, "ingest_ledger", site="gaps"))
    gaps_units = pl.from_arrow(read_table(wh, "batch_units", site="gaps"))
    chan_before = _site_rows(wh, "channel-clean")
    s = run_batch(e2e.cfg, wh, start_ns=e2e.start_ns + 300 * 10**9,
                  end_ns=e2e.start_ns + 900 * 10**9, executor_kind="serial",
                  site="channel-clean")
    assert s.exit_code == 0 and list(s.by_site) == ["channel-clean"], s.render()
    assert not _same_rows(_site_rows(wh, "gaps"), gaps_before)
    assert not _same_rows(_site_rows(wh, "channel"), chan8_before)
    assert _site_files(wh, "gaps") == gaps_files  # the same files: byte-identical
    assert _site_files(wh, "channel") == chan8_files
    assert not _same_rows(_site_rows(wh, "channel-clean"), chan_before)
    chan_files = _site_files(wh, "channel-clean")
    r = run_reprocess(e2e.cfg, wh, start_ns=e2e.start_ns + 300 * 10**9,
                      end_ns=e2e.start_ns + 900 * 10**9, executor_kind="serial", site="gaps")
    assert r.exit_code == 0, r.render()
    assert list(r.batch.by_site) == ["gaps"]
    assert not _same_rows(_site_rows(wh, "channel-clean"), chan_before)
    assert _site_files(wh, "channel-clean") == chan_files
    assert not _same_rows(_site_rows(wh, "channel"), chan8_before)
    assert _site_files(wh, "channel") == chan8_files
    assert not _same_rows(_site_rows(wh, "gaps"), gaps_before)  # exact reprocess
    # the other site's ledger rows and units were not rewritten either
    assert pl.from_arrow(read_table(wh, "ingest_ledger", site="channel-clean")).height == len(
        e2e.archive)
    assert pl.from_arrow(read_table(wh, "ingest_ledger", site="gaps")).select(
        "source_file", "sha256").equals(gaps_ledger.select("source_file", "sha256"))
    assert set(pl.from_arrow(read_table(wh, "batch_units", site="gaps"))["family"]) == set(
        gaps_units["family"])


def test_overlaps_are_flagged_within_one_site_only(e2e, two_sites, tmp_path):
    _, _, shared = two_sites
    wh = tmp_path / "wh"
    shutil.copytree(shared, wh)
    assert read_table(wh, "source_overlaps").num_rows == 0  # two sites: normal
    # a second gaps source (another seed) over the same times: same site, it mixes
    other = run_simulate("gaps", GAPS_S, 4, tmp_path / "other", e2e.cfg,
                         start_ns=e2e.start_ns)
    summary = run_ingest(other, e2e.cfg, wh, executor="serial")
    assert summary.overlaps and "WARNING: two sources overlap" in summary.render()
    rows = pl.from_arrow(read_table(wh, "source_overlaps"))
    assert set(rows["site"]) == {"gaps"}
    assert set(rows["other_file"]) <= set(
        read_table(wh, "ingest_ledger", site="gaps")["source_file"].to_pylist())


def test_import_site_and_ingest_site(e2e, tmp_path):
    src = tmp_path / "in" / "bridge.nmea"
    src.parent.mkdir()
    src.write_bytes(b"\n".join(
        sentence(f"GPRMC,1200{s:02d},A,4807.038,N,01131.000,E,5.0,84.4,150126,,")
        for s in range(10)) + b"\n")
    named = run_import([src], tmp_path / "named", cfg=e2e.cfg, site="bridge-7")
    out = Path(named.imported[0].output)
    with open(out, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert meta["surveil.import"]["site"] == "bridge-7"
    assert declared_site(out) == "bridge-7"
    wh = tmp_path / "wh"
    assert run_ingest([out], e2e.cfg, wh, executor="serial").exit_code == 0
    assert set(read_table(wh, "nav_gnss", columns=["site"])["site"].to_pylist()) == {"bridge-7"}
    # the command's --site contradicting the file's metadata: exit 2, nothing read
    with pytest.raises(IngestUsageError, match="contradicts"):
        run_ingest([out], e2e.cfg, tmp_path / "wh2", site="harbour")
    # a file naming no site: --site, else the default
    plain = run_import([src], tmp_path / "plain", cfg=e2e.cfg)
    bare = Path(plain.imported[0].output)
    assert declared_site(bare) is None
    run_ingest([bare], e2e.cfg, tmp_path / "wh3", executor="serial", site="harbour")
    assert set(read_table(tmp_path / "wh3", "nav_gnss")["site"].to_pylist()) == {"harbour"}
    run_ingest([bare], e2e.cfg, tmp_path / "wh4", executor="serial")
    assert set(read_table(tmp_path / "wh4", "nav_gnss")["site"].to_pylist()) == {
        tables.default_site()}
    res = CliRunner().invoke(cli, ["import", str(src), "--out", str(tmp_path / "cli"),
                                   "--site", "bridge-8"])
    assert res.exit_code == 0, res.output
    assert declared_site(tmp_path / "cli" / out.name) == "bridge-8"


def test_a_warehouse_written_before_sites_is_refused(tmp_path):
    ledger = tmp_path / "old" / "tables" / "ingest_ledger"
    write_deltalake(str(ledger), pa.table({"source_file": ["/a.mcap"], "size_bytes": [1]}))
    with pytest.raises(UsageError, match="before rows carried their site"):
        refuse_pre_sites(tmp_path / "old")
    res = subprocess.run([sys.executable, "-m", "jobs.cli", "--warehouse",
                          str(tmp_path / "old"), "report", "accuracy_by_sector"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "rebuild it" in res.stderr, res.stderr


def test_run_batches_each_sites_pending_windows_alone_and_site_limits_it(e2e, tmp_path):
    """Was: ``surveil run`` had no --site, and a pending window of one site was batched
    for every site with data in it. Now each site's pending windows are its own, and
    ``run --site`` names the site of bare files and batches only that site."""
    from pipeline.batch.nightly import run_nightly
    from pipeline.batch.pending import pending_by_site

    src = tmp_path / "in" / "bridge.nmea"
    src.parent.mkdir()
    src.write_bytes(b"\n".join(
        sentence(f"GPRMC,1200{s:02d},A,4807.038,N,01131.000,E,5.0,84.4,150126,,")
        for s in range(10)) + b"\n")
    bare = tmp_path / "bare"
    run_import([src], bare, cfg=e2e.cfg)
    wh = tmp_path / "wh"  # the e2e files ingested, not batched: channel-clean pending
    assert run_ingest(e2e.archive, e2e.cfg, wh, executor="serial").exit_code == 0
    hour0 = e2e.start_ns // HOUR * HOUR
    assert pending_by_site(wh) == {"channel-clean": [(hour0, hour0 + 2 * HOUR)]}
    res = run_nightly(e2e.cfg, wh, folders=[str(bare)], executor_kind="serial",
                      site="harbour")
    assert res.exit_code == 0, res.render()
    assert [list(b.by_site) for b in res.batches] == [["harbour"]]
    assert list(pending_by_site(wh)) == ["channel-clean"]
    assert set(read_table(wh, "batch_units")["site"].to_pylist()) == {"harbour"}
    # without --site: the bare file is unchanged; channel-clean's windows, and only
    # those, are batched (harbour's is not batched again)
    res = run_nightly(e2e.cfg, wh, folders=[str(bare)], executor_kind="serial")
    assert res.exit_code == 0 and res.files_skipped == 1, res.render()
    assert [list(b.by_site) for b in res.batches] == [["channel-clean"]]
    assert pending_by_site(wh) == {}
