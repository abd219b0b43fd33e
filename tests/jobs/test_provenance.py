"""Config provenance (issue 35, item 5; pipeline/batch/provenance.py): each committed unit
records the digest of the config its family read; `surveil run` batches again the
windows of another config (was: "nothing to do" after a config change, rows of three
configs side by side); reports and the audit name the digests and warn when a window
mixes configs."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import polars as pl
import pytest

from jobs.simulate import run_simulate
from pipeline.batch import run_batch
from pipeline.batch.nightly import run_nightly
from pipeline.batch.provenance import current_digests, family_digest, window_digests
from pipeline.families import FAMILIES, config_from_mapping, family, load_config
from pipeline.resources import resource_path
from pipeline.units import NS
from pipeline.warehouse.delta import read_table
from tests.site_configs import demo_raw, write_config

START_NS = 1_768_438_200 * NS  # 2026-01-15T00:50:00Z
DURATION_S = 1200.0  # two files, two hours
END_NS = START_NS + round(DURATION_S * NS)
HOUR = 3600 * NS


def with_sections(raw: dict, **sections) -> dict:
    return {**raw, **sections}


def stricter(raw: dict) -> dict:
    """A changed association config (the maritime family reads it)."""
    return with_sections(raw, association={**raw["association"], "gate_probability": 0.99})


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("prov") / "archive"
    run_simulate("channel-clean", DURATION_S, 7, root, load_config(), start_ns=START_NS)
    return root


def test_each_unit_records_the_digest_of_what_its_family_read():
    cfg = load_config()
    raw = demo_raw()
    now = current_digests(cfg)
    assert set(now) == {f.name for f in FAMILIES} and all(len(d) == 16 for d in now.values())
    # the same config written otherwise (a default spelt out, keys reordered): same digests
    spelt = with_sections(raw, association={**dict(reversed(raw["association"].items()))},
                          ais={**raw["ais"], "gate_probability": 0.999})
    assert current_digests(config_from_mapping(spelt)) == now
    # an association change is the maritime family's only
    changed = current_digests(config_from_mapping(stricter(raw)))
    assert changed["maritime"] != now["maritime"]
    assert {k: v for k, v in changed.items() if k != "maritime"} == {
        k: v for k, v in now.items() if k != "maritime"}
    # a sector change: every family that reads the sectors, not the airfield
    moved = [dict(s) for s in raw["sectors"]]
    moved[0]["polygon"] = [[a + 0.001, b] for a, b in moved[0]["polygon"]]
    sect = current_digests(config_from_mapping(with_sections(raw, sectors=moved)))
    assert {k for k in now if sect[k] != now[k]} == {"maritime", "gaps", "nav"}
    # the simulator's fault schedule is read by no batch: no digest changes
    world = tomllib.loads((resource_path("config") / "scenarios" / "channel.toml").read_text())
    faults = [dict(f) for f in world["channel_faults"]]
    assert current_digests(config_from_mapping(with_sections(raw, channel_faults=faults),
                                               scenario=True)) == now
    faults[0]["start_s"] += 60.0
    assert current_digests(config_from_mapping(with_sections(raw, channel_faults=faults),
                                               scenario=True)) == now


def test_the_batch_records_the_digest_and_run_rebatches_a_changed_config(tmp_path, archive):
    """After a config change `surveil run` batches the windows of the old config again
    (was: "nothing to do"); its rows are those of a fresh batch with the new config, and
    the next run has nothing to do."""
    cfg, wh = load_config(), tmp_path / "wh"
    first = run_nightly(cfg, wh, folders=[str(archive)], executor_kind="serial")
    assert first.exit_code == 0, first.render()
    units = pl.from_arrow(read_table(wh, "batch_units"))
    want = {f: family_digest(cfg, family(f)) for f in units["family"].unique()}
    assert units["config_digest"].to_list() == [want[f] for f in units["family"]]
    assert run_nightly(cfg, wh, folders=[str(archive)], executor_kind="serial").nothing_to_do

    new = config_from_mapping(stricter(demo_raw()), "stricter")
    again = run_nightly(new, wh, folders=[str(archive)], executor_kind="serial")
    assert not again.nothing_to_do and again.exit_code == 0, again.render()
    hour0 = START_NS // HOUR * HOUR
    assert again.windows == [(hour0, hour0 + 2 * HOUR)]
    assert any("another config" in line for line in again.stale)
    units = pl.from_arrow(read_table(wh, "batch_units"))
    assert set(units["config_digest"]) == set(current_digests(new, [
        family(f) for f in units["family"].unique()]).values())
    assert run_nightly(new, wh, folders=[str(archive)], executor_kind="serial").nothing_to_do
    # the same rows as a warehouse batched once with the new config
    fresh = tmp_path / "fresh"
    assert run_nightly(new, fresh, folders=[str(archive)],
                       executor_kind="serial").exit_code == 0
    for name in ("associations", "system_tracks", "track_errors",
                 "maritime_channel_health"):
        a, b = (pl.from_arrow(read_table(w, name)) for w in (wh, fresh))
        assert a.equals(b), name


def test_reports_and_the_audit_name_the_digests_and_warn_of_a_mix(tmp_path, archive):
    """The first hour batched with one config, the second with another: the report names
    both digests and warns that the window mixes them; the audit page says it too."""
    old_raw, new_raw = demo_raw(), stricter(demo_raw())
    cfg_old = config_from_mapping(old_raw)
    wh = tmp_path / "wh"
    assert run_nightly(cfg_old, wh, folders=[str(archive)], executor_kind="serial",
                       ).exit_code == 0
    hour1 = START_NS // HOUR * HOUR + HOUR
    cfg_new = config_from_mapping(new_raw)
    assert run_batch(cfg_new, wh, start_ns=hour1, end_ns=hour1 + HOUR,
                     executor_kind="serial").committed
    digests = window_digests(wh, START_NS, END_NS, families=["maritime"])
    old_d, new_d = family_digest(cfg_old, family("maritime")), family_digest(
        cfg_new, family("maritime"))
    assert digests["config_digest"].to_list() == [old_d, new_d]

    config = write_config(new_raw, tmp_path / "new.toml")

    def surveil(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "jobs.cli", "--config", str(config),
                               "--warehouse", str(wh), *args],
                              capture_output=True, text=True, timeout=600)

    window = ["--from", "2026-01-15T00:00:00Z", "--to", "2026-01-15T02:00:00Z"]
    res = surveil("report", "accuracy_by_sector", *window, "--format", "csv")
    assert res.returncode == 0, res.stderr
    assert old_d in res.stderr and new_d in res.stderr
    assert "WARNING: site channel-clean, maritime: the window's rows come from 2 configs" \
        in res.stderr
    assert "current config" in res.stderr
    assert old_d not in res.stdout  # the CSV stays data
    one = surveil("report", "accuracy_by_sector", "--from", "2026-01-15T01:00:00Z",
                  "--to", "2026-01-15T02:00:00Z")
    assert new_d in one.stderr and "WARNING" not in one.stderr
    out = tmp_path / "audit"
    aud = surveil("audit", *window, "--out", str(out))
    assert aud.returncode == 0, aud.stderr
    assert "WARNING: site channel-clean, maritime" in aud.stdout
    page = next(out.glob("*.html")).read_text()
    assert old_d in page and new_d in page and "provenance-warning" in page
